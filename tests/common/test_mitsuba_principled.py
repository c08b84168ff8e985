"""Mitsuba's principled BSDF becomes the nearest of igi's kinds (common.mitsuba_principled): a
rough plastic of its GGX roughness² and η whose diffuse layer has the principled diffuse lobe's
mean albedo, a rough conductor where metallic, a dielectric where transmissive — each with a
warning naming what was approximated."""
from __future__ import annotations

import re

import numpy as np
import pytest

from igi.common import bsdf
from igi.common.mitsuba_principled import plastic_layer_albedo, principled_diffuse_albedo, principled_eta
from igi.common.mitsuba_xml import load_mitsuba
from igi.common.scene import (DIELECTRIC, DIFFUSE, PLASTIC, ROUGHCONDUCTOR, ROUGHDIELECTRIC, ROUGHPLASTIC,
                              THINDIELECTRIC, Material, SceneError)
from tests.common.test_mitsuba_xml import line_of, scene_file


def _material(tmp_path, bsdf_xml: str) -> tuple[Material, list[str], object]:
    p = scene_file(tmp_path, f'<shape type="cube">{bsdf_xml}</shape>')
    s = load_mitsuba(p)
    return s.materials[0], s.warnings, p


def _layer_albedo(mat: Material, mu: np.ndarray, n: int = 96) -> np.ndarray:
    """(len(mu), 3) the directional albedo of ``mat``'s diffuse layer at incidence cos θ = ``mu``:
    f cos θ_o (common.bsdf.eval) summed over a midpoint grid of outgoing directions — another
    quadrature than the module's own (its importance-sampled estimate)."""
    m = len(mu)
    sp = bsdf.split_layer(bsdf.gather([mat], np.zeros(m * 2 * n * n, np.int64), None), np.ones(m * 2 * n * n, bool))
    co = (np.arange(n) + 0.5) / n
    ph = (np.arange(2 * n) + 0.5) * (np.pi / n)
    c, f = np.meshgrid(co, ph, indexing="ij")
    so = np.sqrt(1 - c * c)
    wo = np.stack([so * np.cos(f), so * np.sin(f), c], -1).reshape(-1, 3)
    wi = np.stack([np.sqrt(1 - mu * mu), np.zeros(m), mu], -1)
    vals = bsdf.eval(sp, np.repeat(wi, len(wo), axis=0), np.tile(wo, (m, 1)))
    return vals.reshape(m, len(wo), 3).sum(axis=1) * (1.0 / n) * (np.pi / n)


def _mean_layer_albedo(mat: Material, n: int = 12) -> np.ndarray:
    mu = (np.arange(n) + 0.5) / n
    return (_layer_albedo(mat, mu) * (2 * mu / n)[:, None]).sum(axis=0)


def test_principled_eta_is_mitsubas_from_specular():
    assert principled_eta(0.5) == pytest.approx(1.5, abs=2e-3)  # F0 0.04: glass
    f0 = 0.08 * 0.3
    eta = principled_eta(0.3)
    assert ((eta - 1) / (eta + 1)) ** 2 == pytest.approx(f0)


def test_principled_diffuse_albedo_is_burleys_lambert_less_its_fresnel_plus_retro_reflection():
    # roughness 0: (1 - F_i/2)(1 - F_o/2) alone; over wo it gives (1 - F_i/2)(1 - 1/42), and the
    # mean of F_i = (1 - μ)^5 over incidence weighted 2μ is 1/21
    mean_fi = 2 * (1 / 6 - 1 / 7)
    assert principled_diffuse_albedo(0.0) == pytest.approx((1 - mean_fi / 2) * (1 - 1 / 42), rel=2e-3)
    a = [principled_diffuse_albedo(r) for r in (0.0, 0.5, 1.0)]
    assert a[0] < a[1] < a[2] < 1.1  # retro-reflection grows with roughness


@pytest.mark.parametrize("roughness", [0.2, 0.6])
def test_a_dielectric_principled_is_a_rough_plastic_with_its_lobe_and_its_diffuse_albedo(tmp_path, roughness):
    base = (0.2, 0.5, 0.8)
    mat, warnings, p = _material(tmp_path, f"""<bsdf type="principled">
        <rgb name="base_color" value="{base[0]}, {base[1]}, {base[2]}"/>
        <float name="roughness" value="{roughness}"/><float name="specular" value="0.6"/></bsdf>""")
    assert mat.kind == ROUGHPLASTIC and mat.distribution == "ggx"
    assert mat.alpha == pytest.approx(roughness ** 2)
    assert mat.int_ior / mat.ext_ior == pytest.approx(principled_eta(0.6))
    np.testing.assert_allclose(mat.specular.rgb, 1.0)
    # the layer reflects what the principled diffuse lobe reflects, colour by colour
    np.testing.assert_allclose(_mean_layer_albedo(mat), np.array(base) * principled_diffuse_albedo(roughness),
                               rtol=0.03)
    assert f"bsdf 'principled' is approximated at {p}:{line_of(p, 'principled')}, as a rough plastic" in "\n".join(
        warnings)


def test_a_rough_coats_layer_never_reflects_more_than_it_receives(tmp_path):
    # at roughness 1 the coat lets little through at grazing angles: matching the mean alone would
    # make a white layer reflect 1.3 straight on; it is capped at 1 there, and says so
    mat, warnings, _p = _material(tmp_path, """<bsdf type="principled">
        <rgb name="base_color" value="1, 1, 1"/><float name="roughness" value="1"/></bsdf>""")
    mu = np.array([0.05, 0.3, 0.6, 0.97])
    a = _layer_albedo(mat, mu)[:, 1]
    assert a.max() <= 1.02 and a.max() > 0.9, a
    assert "of the principled lobe's (rough coat)" in "\n".join(warnings)


def test_a_smooth_principled_is_a_smooth_plastic_and_a_textured_base_colour_is_scaled_texel_by_texel(tmp_path):
    from igi.common.image_io import write_exr

    img = np.random.default_rng(1).random((4, 4, 3)).astype(np.float32)
    write_exr(tmp_path / "base.exr", img)
    mat, _w, _p = _material(tmp_path, """<bsdf type="principled">
        <texture type="bitmap" name="base_color"><string name="filename" value="base.exr"/></texture>
        <float name="roughness" value="0"/></bsdf>""")
    assert mat.kind == PLASTIC
    scale = principled_diffuse_albedo(0.0) / plastic_layer_albedo(mat)[0]
    np.testing.assert_allclose(mat.diffuse.image, img * scale, rtol=1e-6)


def test_metallic_and_transmissive_principled_and_what_they_drop_are_named(tmp_path):
    metal, w, _p = _material(tmp_path, """<bsdf type="principled">
        <rgb name="base_color" value="0.9, 0.6, 0.3"/><float name="metallic" value="0.8"/>
        <float name="roughness" value="0.3"/><float name="clearcoat" value="0.5"/></bsdf>""")
    assert metal.kind == ROUGHCONDUCTOR and metal.alpha == pytest.approx(0.09)
    np.testing.assert_allclose(metal.specular.rgb, (0.9, 0.6, 0.3))
    np.testing.assert_array_equal(metal.eta, 0.0)  # Fresnel 1: the colour is the reflectance
    text = "\n".join(w)
    assert "as a rough conductor (clearcoat 0.5 dropped; metallic 0.8 rounded)" in text
    glass, w, _p = _material(tmp_path, """<bsdf type="principled">
        <rgb name="base_color" value="0.81, 1, 1"/><float name="spec_trans" value="1"/>
        <float name="eta" value="1.33"/><float name="roughness" value="0.3"/></bsdf>""")
    assert glass.kind == ROUGHDIELECTRIC and glass.int_ior / glass.ext_ior == pytest.approx(1.33)
    assert glass.alpha == pytest.approx(0.09) and glass.distribution == "ggx"
    np.testing.assert_allclose(glass.specular_transmittance.rgb, (0.9, 1, 1))
    assert "as a rough dielectric" in "\n".join(w)
    smooth, _w, _p = _material(tmp_path, """<bsdf type="principled"><float name="spec_trans" value="1"/>
        <float name="roughness" value="0.01"/></bsdf>""")
    assert smooth.kind == DIELECTRIC  # α 1e-4: Mitsuba's lobe clamps it to 1e-3, a near-delta
    thinner, w, _p = _material(tmp_path, """<bsdf type="principled"><float name="eta" value="0.8"/></bsdf>""")
    assert thinner.int_ior / thinner.ext_ior == pytest.approx(1.001)
    assert "eta 0.8 raised to 1.001" in "\n".join(w)
    # Mitsuba weighs transmission by (1 - metallic): a transmissive metal is a metal
    metal, _w, _p = _material(tmp_path, """<bsdf type="principled"><float name="metallic" value="1"/>
        <float name="spec_trans" value="1"/></bsdf>""")
    assert metal.kind == ROUGHCONDUCTOR


def test_principledthin_is_a_two_sided_sheet(tmp_path):
    glass, _w, _p = _material(tmp_path, """<bsdf type="principledthin"><float name="spec_trans" value="1"/>
        <rgb name="base_color" value="0.81, 1, 1"/></bsdf>""")
    assert glass.kind == THINDIELECTRIC
    np.testing.assert_allclose(glass.specular_transmittance.rgb, (0.81, 1, 1))  # base_color itself
    sheet, w, _p = _material(tmp_path, """<bsdf type="principledthin"><rgb name="base_color" value="0.5, 0.5, 0.5"/>
        <float name="roughness" value="0.4"/><float name="diffuse_transmittance_sampling_rate" value="1"/></bsdf>""")
    assert sheet.kind == DIFFUSE and sheet.twosided
    np.testing.assert_allclose(sheet.diffuse.rgb, 0.5 * principled_diffuse_albedo(0.4))
    assert not any("unsupported parameter" in x for x in w)


def test_out_of_range_principled_values_are_clamped_and_named(tmp_path):
    mat, w, _p = _material(tmp_path, """<bsdf type="principled"><float name="roughness" value="-0.5"/>
        <float name="metallic" value="1.5"/></bsdf>""")
    assert mat.kind == ROUGHCONDUCTOR and mat.alpha == pytest.approx(1e-3)
    text = "\n".join(w)
    assert "roughness -0.5 clamped to [0, 1]" in text and "metallic 1.5 clamped to [0, 1]" in text


def test_principled_in_twosided_keeps_twosided_and_defaults_are_mitsubas(tmp_path):
    mat, _w, _p = _material(tmp_path, '<bsdf type="twosided"><bsdf type="principled"/></bsdf>')
    assert mat.twosided and mat.kind == ROUGHPLASTIC
    assert mat.alpha == pytest.approx(0.25) and mat.int_ior / mat.ext_ior == pytest.approx(principled_eta(0.5))
    np.testing.assert_allclose(mat.diffuse.rgb, 0.5 * principled_diffuse_albedo(0.5) / plastic_layer_albedo(mat)[0])


@pytest.mark.parametrize("body, text", [
    ('<float name="eta" value="1.5"/><float name="specular" value="0.5"/>', "takes 'eta' or 'specular', not both"),
    ('<float name="specular" value="13"/>', "'specular' 13 must be in [0, 12.5)"),
    ('<float name="eta" value="-1"/>', "index of refraction -1 must be a positive number"),
    ('<float name="roughness" value="x"/>', "value 'x' is not a number"),
])
def test_bad_principled_parameters_name_the_problem_and_line(tmp_path, body, text):
    p = scene_file(tmp_path, f'<shape type="cube"><bsdf type="principled">{body}</bsdf></shape>')
    with pytest.raises(SceneError, match=re.escape(text)):
        load_mitsuba(p)


def test_a_principled_scene_renders_finite_and_lit(tmp_path):
    from igi.master.inprocess import render_local

    p = scene_file(tmp_path, """
        <sensor type="perspective"><float name="fov" value="60"/>
            <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
            <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="16"/></film>
        </sensor>
        <shape type="sphere"><bsdf type="principled"><float name="roughness" value="0.3"/></bsdf></shape>
        <emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>""")
    img = render_local(load_mitsuba(p), {"photons": 0}, 2)
    assert np.all(np.isfinite(img))
    # the ball under a white sky reflects about its albedo: base 0.5 plus a coat of a few percent
    centre = img[6:10, 10:14].mean()
    assert 0.4 < centre < 0.75, centre
