"""igi bench quality / compare: outputs, Pareto front, reduced-resolution reference comparison."""
from __future__ import annotations

import argparse
import importlib.util
import json
import math

import numpy as np
import pytest

from tests.support.paths import SHARED

CORNELL = SHARED / "scenes" / "cornell-box" / "scene.xml"
needs_shared = pytest.mark.skipif(not (CORNELL.exists() and (SHARED / "references" / "cornell-box.exr").exists()),
                                  reason="shared scenes/references not present")


def parse(module, argv):
    p = argparse.ArgumentParser()
    module.add_arguments(p)
    return p.parse_args([str(a) for a in argv])


# ---------------------------------------------------------------------------- pure helpers

def test_block_average_is_the_reduced_render_exactly():
    """A pixel of a k-times smaller render is the k×k box average of the full-resolution
    pixels: the reduced reference must be exactly that, for every block."""
    from igi.bench.quality import downscale_factor, reduced_reference

    rng = np.random.default_rng(1)
    full = rng.random((12, 18, 3)).astype(np.float32) * 5
    k = downscale_factor(18, 12, scale=1 / 3)
    assert k == 3
    small = reduced_reference(full, k)
    assert small.shape == (4, 6, 3)
    for y in range(4):
        for x in range(6):
            np.testing.assert_allclose(small[y, x], full[3 * y:3 * y + 3, 3 * x:3 * x + 3].mean(axis=(0, 1)),
                                       rtol=1e-6)
    # a render that IS the box-filtered full image scores 0 against the reduced reference
    from igi.common.metrics import relmse

    boxed = full.reshape(4, 3, 6, 3, 3).mean(axis=(1, 3))
    assert relmse(boxed, small) == pytest.approx(0.0, abs=1e-12)
    assert downscale_factor(18, 12, width=6) == 3 and downscale_factor(18, 12, height=4) == 3
    assert downscale_factor(18, 12) == 1


def test_downscale_factor_rejects_non_dividing_sizes():
    from igi.bench.quality import BenchError, downscale_factor

    for kw in ({"scale": 0.4}, {"width": 7}, {"width": 9, "height": 3}, {"scale": 0.2}):
        with pytest.raises(BenchError):
            downscale_factor(18, 12, **kw)


def test_pareto_front_is_non_dominated_and_complete():
    from igi.bench.quality import dominated, pareto_front

    rng = np.random.default_rng(7)
    pts = [{"time_s": float(t), "relmse": float(e)} for t, e in rng.random((40, 2))]
    front = pareto_front(pts)
    assert front, "a non-empty set has a front"
    for i in range(len(pts)):
        assert (i in front) == (not dominated(pts, i)), i
    times = [pts[i]["time_s"] for i in front]
    errs = [pts[i]["relmse"] for i in front]
    assert times == sorted(times) and errs == sorted(errs, reverse=True)


def test_bias_noise_fit_recovers_the_model():
    from igi.bench.quality import fit_bias_noise

    f = np.arange(1, 33)
    fit = fit_bias_noise(f, 0.002 + 0.03 / f)
    assert fit["bias"] == pytest.approx(0.002, rel=1e-6)
    assert fit["noise_1frame"] == pytest.approx(0.03, rel=1e-6)
    assert fit_bias_noise([4], [0.1]) is None


def test_sweep_values_follow_the_declared_defaults():
    from igi.common.params import PARAM_BY_NAME, make_params
    from igi.bench.quality import BenchError, make_configs, parse_sweeps

    d = PARAM_BY_NAME["indirect_vpls"].default
    sweeps = parse_sweeps(["indirect-vpls=x2,7", "interleave=1"])
    assert sweeps[0] == ("indirect_vpls", [max(1, round(2 * d)), 7])
    configs = make_configs(make_params(), sweeps)
    assert configs[0]["label"] == "base" and configs[0]["overrides"] == {}
    labels = [c["label"] for c in configs]
    assert len(labels) == len(set(labels))
    for bad in (["nonsense=1"], ["clamp=x2"], ["frames=1,2"], ["interleave"]):
        with pytest.raises(BenchError):
            parse_sweeps(bad)
    with pytest.raises(BenchError):
        make_configs(make_params(), parse_sweeps(["interleave=99"]))


# ---------------------------------------------------------------------------- the bench, end to end

@needs_shared
def test_quality_bench_on_cornell_box(tmp_path):
    from igi.bench import quality as bq

    args = parse(bq, ["cornell-box", "--width", 64, "--height", 64, "--frames", "2",
                      "--sweep", "indirect_vpls=x0.5,x2", "-o", tmp_path])
    assert bq.run(args) == 0
    data = json.loads((tmp_path / "bench-quality.json").read_text())
    for key in ("machine", "settings", "scenes", "timing", "command"):
        assert key in data
    assert data["machine"]["cores"] >= 1 and data["machine"]["cpu"] is not None
    s = data["scenes"]["cornell-box"]
    assert s["resolution"] == [64, 64] and s["downscale"] == 8
    assert "block-averaged 8x8" in s["reference_comparison"]
    assert len(s["configs"]) == 3 and len(s["points"]) == 3
    for p in s["points"]:
        for m in ("time_s", "relmse", "rmse", "relmse_block4"):
            assert math.isfinite(p[m]) and p[m] >= 0, (m, p)
        assert p["relmse"] < 1.0, "a 64x64 Cornell box is not that far from its reference"
        if data["settings"]["flip"]:
            assert 0 <= p["flip"] <= 1
        else:
            assert p["flip"] is None
    for metric, front in s["pareto"].items():
        if metric == "flip" and not data["settings"]["flip"]:
            assert front == []
            continue
        assert front
        for i in front:
            assert not bq.dominated(s["points"], i, "time_s", metric)
    png = tmp_path / "bench-quality.png"
    assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (tmp_path / "bench-quality.md").read_text()
    assert "| configuration |" in md and "★" in md


@needs_shared
def test_quality_bench_is_registered_in_the_cli():
    from igi.master.cli import bench_parser, build_parser

    args = build_parser().parse_args(["bench", "quality", "cornell-box", "--frames", "1,4", "--scale", "0.5"])
    assert args.bench == "quality" and args.bench_args == ["cornell-box", "--frames", "1,4", "--scale", "0.5"]
    args = bench_parser("quality").parse_args(args.bench_args)
    assert args.func.__module__ == "igi.bench.quality"
    args = bench_parser("compare").parse_args(["cornell-box", "--budgets", "0.25,1"])
    assert args.func.__module__ == "igi.bench.compare"


def _tiny_scene():
    from igi.common.loader import load_scene

    return load_scene(CORNELL)


@needs_shared
def test_orbit_cameras():
    from igi.bench.compare import orbit_cameras

    scene = _tiny_scene()
    m0 = np.asarray(scene.camera.to_world, np.float64).reshape(4, 4)
    cams = orbit_cameras(scene, 5, 1.0)
    np.testing.assert_allclose(cams[2], m0, atol=1e-12)  # the middle frame is the scene camera
    for c in cams:
        np.testing.assert_allclose(c[:3, :3].T @ c[:3, :3], m0[:3, :3].T @ m0[:3, :3], atol=1e-9)
    angles = [math.degrees(math.acos(np.clip(np.dot(a[:3, 2], b[:3, 2]) /
                                             (np.linalg.norm(a[:3, 2]) * np.linalg.norm(b[:3, 2])), -1, 1)))
              for a, b in zip(cams, cams[1:])]
    np.testing.assert_allclose(angles, 1.0, atol=1e-6)


@needs_shared
@pytest.mark.skipif(importlib.util.find_spec("mitsuba") is None, reason="mitsuba not installed (extra [peers])")
def test_compare_bench_against_mitsuba(tmp_path):
    from igi.bench import compare as bc

    args = parse(bc, ["cornell-box", "--width", 32, "--height", 32, "--budgets", "0.05,0.1", "--converged-frames", 1,
                      "--flicker-frames", 2, "--path-ref-spp", 2, "-o", tmp_path])
    assert bc.run(args) == 0
    data = json.loads((tmp_path / "bench-compare.json").read_text())
    s = data["scenes"]["cornell-box"]
    if not data["settings"]["mitsuba"]["ok"]:
        pytest.skip(f"no Mitsuba variant renders here: {data['settings']['mitsuba'].get('reason')}")
    assert data["settings"]["mitsuba"]["variant"] in ("llvm_ad_rgb", "scalar_rgb")
    assert [r["budget_s"] for r in s["igi"]["budgets"]] == [0.05, 0.1]
    for r in s["mitsuba"]["budgets"]:
        assert r["spp"] >= 1 and math.isfinite(r["relmse"])
    fl = s["flicker"]["cases"]
    assert fl["static_fixed_seed"]["igi"]["mean_abs_change"] == pytest.approx(0.0, abs=1e-6)
    assert fl["static_new_seeds"]["igi"]["mean_abs_change"] > 0
    assert "mitsuba" in fl["orbit_fixed_seed"]
    assert (tmp_path / "bench-compare.md").exists()


@needs_shared
def test_compare_bench_on_worker_processes_scores_the_same_image_and_reports_start_up(tmp_path):
    """--workers N: igi's budget runs go through a real master and N worker processes; the
    running means are the in-process render's (same specs and tiles), start-up is apart."""
    from igi.bench import compare as bc
    from igi.master.inprocess import render_local

    args = parse(bc, ["cornell-box", "--width", 32, "--height", 32, "--budgets", "0.05", "--converged-frames", 3,
                      "--bias-frames", 0, "--flicker-frames", 0, "--no-mitsuba", "--workers", 1, "-o", tmp_path])
    assert bc.run(args) == 0
    data = json.loads((tmp_path / "bench-compare.json").read_text())
    ig = data["scenes"]["cornell-box"]["igi"]
    assert data["settings"]["igi_workers"] == 1 and ig["workers"] == 1 and ig["startup_s"] > 0
    assert "worker process" in data["timing"]["igi"]
    conv = ig["converged"]
    assert conv["frames"] >= 3 and [c[0] for c in ig["curve"]] == list(range(1, conv["frames"] + 1))
    setup = bc.bq.SceneSetup("cornell-box", False, 32, 32, None, None, False)
    params = bc.bq.base_params(args)
    local = render_local(setup.scene, params, frames=conv["frames"], width=32, height=32)
    assert conv["relmse"] == pytest.approx(setup.evaluator.relmse(local), rel=1e-6)
    with pytest.raises(bc.bq.BenchError, match="--clock wall"):
        bc.run_compare(parse(bc, ["cornell-box", "--workers", 1, "--clock", "cpu", "--no-mitsuba"]))
