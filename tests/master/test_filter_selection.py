"""The blend of the filtered and the raw running means (master/filter_selection.py): what the
filter pass sums, what the blend computes, and what it does to a real scene's accumulation."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.codec import encode
from igi.common.lights import LUMINANCE_WEIGHTS
from igi.common.params import make_params, params_to_dict
from igi.master.accumulation import Accumulator
from igi.master.edge_stopping import EdgeStoppingGuide, _cells, image_layout
from igi.master.filter_selection import MIN_FRAMES, select
from igi.master.frame_assembly import FrameAssembler
from tests.master.test_edge_stopping import _step_frames

LUM = np.array(LUMINANCE_WEIGHTS)


def _box(a: np.ndarray, r: int) -> np.ndarray:
    """Mean over the (2r+1)² window, clipped to the image (the pixels inside only)."""
    H, W = a.shape
    out = np.empty_like(a)
    for y in range(H):
        for x in range(W):
            out[y, x] = a[max(0, y - r):y + r + 1, max(0, x - r):x + r + 1].mean()
    return out


def _shares(sh: np.ndarray, sh2: np.ndarray, count: int, c: float, reach: int) -> tuple:
    """Image-order sums (H, W, 3), (H, W) as ``shares_learnt`` gives them for a frame in image order."""
    H, W = sh2.shape
    return (np.ascontiguousarray(sh.reshape(H * W, 3).T[None]), sh2.reshape(1, H * W), image_layout((H, W)),
            count, c, reach, lambda shape: np.empty((4,) + shape, np.float32), (H, W))


def _image_order(guide: EdgeStoppingGuide, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The guide's share sums in image order, (H, W, 3) and (H, W)."""
    sh, sh2, layout = guide.shares_learnt()[:3]
    at = _cells(layout, shape)
    return sh[at[0], :, at[1]], sh2[at]


def _select_reference(mean, sh, sh2, count, c, reach):
    d = (sh @ LUM) / count
    v = np.maximum(sh2 / count - d * d, 0.0) / (count - 1)
    b2 = np.maximum(_box(d * d - (c + 2.0 / (count - 1)) * v, reach), 0.0)
    vp = _box(v, reach)
    a = np.where(b2 > 0, b2 / np.where(b2 > 0, b2 + vp, 1.0), 0.0)
    return (mean - _box(a, 1)[..., None] * sh / count).astype(np.float32)


def test_the_blend_is_the_documented_formula_on_random_sums():
    rng = np.random.default_rng(3)
    H, W, n = 9, 13, 7
    shares = rng.normal(0.0, 1.0, (n, H, W, 3)) + rng.normal(0.0, 2.0, (H, W, 1)) * (rng.random((H, W, 1)) < 0.3)
    sh, sh2 = shares.sum(0), ((shares @ LUM) ** 2).sum(0)
    mean = rng.random((H, W, 3)).astype(np.float32)
    for c, reach in ((1.5, 2), (0.5, 1), (4.0, 3)):
        got = select(mean, _shares(sh, sh2, n, c, reach))
        np.testing.assert_allclose(got, _select_reference(mean, sh, sh2, n, c, reach), rtol=1e-6, atol=1e-6)


def test_a_bias_beyond_the_noise_gives_the_raw_mean_and_pure_noise_keeps_the_filtered_one():
    """Left half: the filter's share is a bias of 0.3 with noise 0.1 a frame — after 64 frames the
    blend takes (almost) all of it back, the raw mean. Right half: the share is noise of 0.3 about
    0 — the filtered mean stays (a false alarm here and there takes back little)."""
    rng = np.random.default_rng(4)
    H, W, n = 16, 32, 64
    bias = np.where(np.arange(W) < W // 2, 0.3, 0.0)[None, :, None]
    noise = np.where(np.arange(W) < W // 2, 0.1, 0.3)[None, None, :, None]
    shares = bias[None] + noise * rng.standard_normal((n, H, W, 1)) * np.ones(3)
    sh, sh2 = shares.sum(0), ((shares @ LUM) ** 2).sum(0)
    mean = np.full((H, W, 3), 1.0, np.float32)
    out = select(mean, _shares(sh, sh2, n, 1.5, 2))
    taken = (mean - out)[..., 0] / (sh[..., 0] / n)  # the blend weight a per pixel
    left, right = taken[:, 3:W // 2 - 3], taken[:, W // 2 + 3:]
    assert left.min() > 0.97
    assert np.median(right) == 0.0 and right.mean() < 0.1


def test_fireflies_beside_a_wall_leave_every_pixel_between_its_filtered_and_raw_means():
    """The weights are a convex blend wherever the sums' magnitudes differ by 1e10 (a firefly's
    share beside a flat wall's): each output pixel lies between its filtered and raw means."""
    rng = np.random.default_rng(5)
    H, W, n = 40, 60, 9
    shares = 0.01 * rng.standard_normal((n, H, W, 3)) + 0.02
    hot = rng.random((n, H, W)) < 0.01
    shares[hot] += rng.choice([-1.0, 1.0], size=(hot.sum(), 1)) * 10.0 ** rng.uniform(3, 8, (hot.sum(), 1))
    sh, sh2 = shares.sum(0), ((shares @ LUM) ** 2).sum(0)
    mean = (1.0 + rng.random((H, W, 3))).astype(np.float32)
    out = select(mean, _shares(sh, sh2, n, 1.5, 2)).astype(np.float64)
    raw = mean - sh / n
    lo, hi = np.minimum(mean, raw), np.maximum(mean, raw)
    tol = 1e-6 * np.maximum(np.abs(lo), np.abs(hi)) + 1e-6
    assert np.isfinite(out).all()
    assert ((out >= lo - tol) & (out <= hi + tol)).all()


def test_few_frames_none_off_or_another_shape_leave_the_mean_as_it_is():
    mean = np.ones((4, 5, 3), np.float32)
    sh, sh2 = np.ones((4, 5, 3)), np.ones((4, 5))
    assert select(mean, None) is mean
    assert select(mean, _shares(sh, sh2, MIN_FRAMES - 1, 1.5, 2)) is mean
    assert select(mean, _shares(sh, sh2, 10, 0.0, 2)) is mean
    assert select(mean, _shares(np.ones((5, 4, 3)), np.ones((5, 4)), 10, 1.5, 2)) is mean  # another size
    assert select(mean, _shares(sh, sh2, 10, 1.5, 2)) is not mean


@pytest.mark.parametrize("path", ["wire", "float"])
def test_the_filter_pass_sums_each_pixels_filtered_less_raw_radiance(path):
    """The shares the pass adds are the frame's filtered image less the same frame composed from
    its raw irradiance (window 1), pixel for pixel, and their luminance squared — including the
    split lobes' share."""
    w, h, n = 24, 12, 3
    params = params_to_dict(make_params(interleave=n))
    raw_params = dict(params, filter_window=1)
    guide = EdgeStoppingGuide().track("view")
    rng = np.random.default_rng(8)
    shares, total = [], 0
    for i, frame in enumerate(_step_frames(MIN_FRAMES + 2, seed=7, w=w, h=h, n=n)):
        asm, raw = FrameAssembler(w, h, n), FrameAssembler(w, h, n)
        for t, b in frame:
            lobe = np.where(rng.random((len(b), 1)) < 0.4, rng.random((len(b), 3)), -1.0).astype(np.float32)
            b = type(b)(b.reflectance, b.irradiance, b.unfiltered, b.depth, b.normal, lobe)
            for a in (asm, raw):
                a.add_wire(t, encode(b)) if path == "wire" else a.add(t, b)
        img = asm.image(params, i, guide).astype(np.float64)
        shares.append(img - raw.image(raw_params, i).astype(np.float64))
        total += 1
    count, c, reach = guide.shares_learnt()[3:6]
    assert (count, c, reach) == (total, params["filter_select"], n // 2)
    sh, sh2 = _image_order(guide, (h, w))
    np.testing.assert_allclose(sh, np.sum(shares, 0), atol=1e-5)
    np.testing.assert_allclose(sh2, np.sum([(s @ LUM) ** 2 for s in shares], 0), rtol=1e-4, atol=1e-8)
    assert np.abs(sh).max() > 0.1  # the step and the lobes: the filter did move pixels


def test_the_blend_reads_interleaved_planes_as_their_image_order():
    """Sums a guide learnt in the planes' layout of a 3×3 interleave (wire frames, bordered
    planes) blend exactly as the same sums in image order."""
    w, h, n = 25, 13, 3
    params = params_to_dict(make_params(interleave=n))
    guide, acc = EdgeStoppingGuide().track("view"), Accumulator()
    for i, frame in enumerate(_step_frames(MIN_FRAMES + 4, seed=11, w=w, h=h, n=n)):
        asm = FrameAssembler(w, h, n)
        for t, b in frame:
            asm.add_wire(t, encode(b))
        acc.add(asm.image(params, i, guide))
    shares = guide.shares_learnt()
    assert shares[2][0] == n  # the planes' layout, not image order
    sh, sh2 = _image_order(guide, (h, w))
    count, c, reach = shares[3:6]
    mean = acc.mean()
    got = acc.mean(guide)
    np.testing.assert_allclose(got, _select_reference(mean, sh, sh2, count, c, reach), rtol=1e-5, atol=1e-6)
    assert np.abs(got - mean).max() > 1e-3  # the step's edge: the blend moved pixels


def test_a_view_without_the_selection_after_one_with_it_reports_no_shares():
    w, h, n = 24, 12, 3
    guide = EdgeStoppingGuide()
    for key, c in (("first", 1.5), ("second", 0.0)):
        guide.track(key)
        params = params_to_dict(make_params(interleave=n, filter_select=c))
        for i, frame in enumerate(_step_frames(MIN_FRAMES, seed=12, w=w, h=h, n=n)):
            asm = FrameAssembler(w, h, n)
            for t, b in frame:
                asm.add(t, b)
            asm.image(params, i, guide)
        assert (guide.shares_learnt() is None) == (c == 0.0)


def test_a_moving_cameras_frame_adds_no_shares_and_the_frames_after_it_do():
    """A moving view's frame (shown once: ``moving_camera``) skips the share sums (and a reset
    with nothing summed leaves them be); the frames that accumulate after it on the same view
    sum theirs — the blend's mean share is then theirs, of the same expectation."""
    w, h, n = 24, 12, 3
    base = params_to_dict(make_params(interleave=n))
    guide = EdgeStoppingGuide().track("view")
    for i, frame in enumerate(_step_frames(MIN_FRAMES + 1, seed=13, w=w, h=h, n=n)):
        asm = FrameAssembler(w, h, n)
        for t, b in frame:
            asm.add(t, b)
        asm.image(dict(base, moving_camera=i == 0), i, guide)
        if i == 0:
            assert guide.shares_learnt() is None and guide.count == 1
    learnt = guide.shares_learnt()
    assert learnt is not None and learnt[3] == MIN_FRAMES and guide.count == MIN_FRAMES + 1
    assert learnt[0].any()


def test_the_plain_mean_callback_gets_the_mean_without_the_blend():
    """The CLI's noise estimate takes the running mean apart frame by frame: it must get the plain
    mean (``on_plain_mean``), which the blend's changing weights would break — the same images the
    selection turned off gives."""
    from igi.master.inprocess import render_local
    from tests.support.scenes_synthetic import furnace_box

    scene = furnace_box(0.5, 1.0, 20, 16)
    plain, blended, off = [], [], []
    render_local(scene, {"filter_select": 1.5}, 6, on_frame=lambda i, m: blended.append(m.copy()),
                 on_plain_mean=lambda i, m: plain.append(m.copy()))
    render_local(scene, {"filter_select": 0.0}, 6, on_frame=lambda i, m: off.append(m.copy()))
    assert len(plain) == len(off) == 6
    for a, b in zip(plain, off):
        np.testing.assert_array_equal(a, b)


def test_the_shares_start_over_with_the_view_and_a_new_shape():
    w, h, n = 24, 12, 3
    params = params_to_dict(make_params(interleave=n))
    guide = EdgeStoppingGuide().track("view")
    for i, frame in enumerate(_step_frames(MIN_FRAMES, seed=9, w=w, h=h, n=n)):
        asm = FrameAssembler(w, h, n)
        for t, b in frame:
            asm.add(t, b)
        asm.image(params, i, guide)
    assert guide.shares_learnt()[3] == MIN_FRAMES
    assert guide.track("moved").shares_learnt() is None
    assert not guide._share.any() and not guide._share2.any()  # zeroed in place
    guide.learner((h + 1, w), (1, 0, w, 1, (h + 1) * w))
    assert guide.shares_learnt() is None and guide._share is None


def test_filter_select_0_adds_no_shares_and_the_accumulation_is_the_plain_mean():
    w, h, n = 24, 12, 3
    params = params_to_dict(make_params(interleave=n, filter_select=0.0))
    guide, acc = EdgeStoppingGuide().track("view"), Accumulator()
    for i, frame in enumerate(_step_frames(MIN_FRAMES + 2, seed=10, w=w, h=h, n=n)):
        asm = FrameAssembler(w, h, n)
        for t, b in frame:
            asm.add(t, b)
        acc.add(asm.image(params, i, guide))
    assert guide.shares_learnt() is None
    np.testing.assert_array_equal(acc.mean(guide), acc.mean())


def test_a_sun_lit_scene_accumulates_closer_to_the_reference_with_the_blend():
    """Under a map's sun the filter's blur of the terminator and the shadow edges is the largest
    error of a short accumulation (tests/data/envmap/outdoor.xml, 24 frames at 80×60 against the
    Mitsuba reference block-averaged to that size): the blend takes it back."""
    from igi.common.image_io import read_image
    from igi.common.loader import load_scene
    from igi.common.metrics import block_average, relmse
    from igi.master.inprocess import render_local
    from igi.worker.renderer import Renderer
    from tests.support.paths import ROOT

    folder = ROOT / "tests" / "data" / "envmap"
    scene = load_scene(folder / "outdoor.xml")
    ref = block_average(read_image(folder / "outdoor_ref.exr")[..., :3], 2)
    r = Renderer(scene)
    err = {c: relmse(render_local(scene, {"filter_select": c}, 24, width=ref.shape[1], height=ref.shape[0],
                                  renderer=r), ref) for c in (0.0, 1.5)}
    print(f"relMSE filtered {err[0.0]:.3g}, blended {err[1.5]:.3g}")
    assert err[1.5] < 0.85 * err[0.0]  # measured: 0.00312 -> 0.00240


def test_on_the_cornell_box_the_blend_costs_nothing_where_the_filter_is_right():
    """Where the filter's bias is small (cornell-box: 16 frames at 128×128, its flat walls), the
    blend must not give back the raw noise: no worse than the filtered mean."""
    from igi.common.image_io import read_image
    from igi.common.loader import load_scene
    from igi.common.metrics import block_average, relmse
    from igi.master.inprocess import render_local
    from igi.worker.renderer import Renderer
    from tests.support.paths import REFERENCES, SCENES

    scene = load_scene(SCENES / "cornell-box" / "scene.xml")
    ref = read_image(REFERENCES / "cornell-box.exr")[..., :3]
    ref = block_average(ref, ref.shape[1] // 128)
    r = Renderer(scene)
    err = {c: relmse(render_local(scene, {"filter_select": c}, 16, width=ref.shape[1], height=ref.shape[0],
                                  renderer=r), ref) for c in (0.0, 1.5)}
    print(f"relMSE filtered {err[0.0]:.3g}, blended {err[1.5]:.3g}")
    assert err[1.5] <= 1.02 * err[0.0]
