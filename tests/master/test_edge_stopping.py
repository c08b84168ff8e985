"""The discontinuity buffer's edge-stopping guide (master/edge_stopping.py): what it learns from
the frames accumulated so far, and what it does to the filter."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.codec import encode
from igi.common.lights import LUMINANCE_WEIGHTS
from igi.common.frame import TileBuffers
from igi.common.params import make_params, params_to_dict
from igi.master.edge_stopping import MIN_FRAMES, EdgeStoppingGuide
from igi.master.frame_assembly import FrameAssembler, task_tiles


def test_the_guide_is_the_earlier_frames_mean_and_k_standard_errors_once_it_has_enough():
    rng = np.random.default_rng(1)
    frames = rng.gamma(2.0, 1.0, (7, 5, 4))
    g = EdgeStoppingGuide().track("view")
    for i, f in enumerate(frames):
        assert (g.tolerances(2.0, f.shape) is None) == (i < MIN_FRAMES)
        g.add(f)
    mean, tol = g.tolerances(2.0, (5, 4))
    np.testing.assert_allclose(mean, frames.mean(0), rtol=1e-6)
    np.testing.assert_allclose(tol, 2.0 * frames.std(0, ddof=1) / np.sqrt(len(frames)), rtol=1e-5)
    assert g.tolerances(0.0, (5, 4)) is None  # off
    assert g.tolerances(2.0, (4, 5)) is None  # another resolution: nothing learnt for it
    assert g.track("view").count == 7 and g.track("moved").count == 0  # a new view starts over
    bad = frames[0].copy()
    bad[0, 0], bad[1, 1] = np.nan, np.inf
    g.add(bad)
    assert g.count == 1 and np.isfinite(g._s1).all()  # non-finite luminance counts as 0


def _step_frames(count: int, seed: int, w: int = 24, h: int = 12, n: int = 3):
    """Frames of one plane (continuous depth and normal everywhere) whose irradiance steps from
    1 to 4 at x = w/2, with noise of 30% per pixel: the filter's window straddles the step."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        frame = []
        for t in task_tiles(w, h, n, 16):
            xs, ys = t.pixels(n, w, h)
            p = len(xs)
            level = np.where(xs < w // 2, 1.0, 4.0)[:, None]
            irr = (level * (1.0 + 0.3 * rng.standard_normal((p, 3)))).astype(np.float32)
            frame.append((t, TileBuffers(np.ones((p, 3), np.float32), irr, np.zeros((p, 3), np.float32),
                                         np.ones(p, np.float32), np.tile(np.float32([0, 0, 1]), (p, 1)))))
        yield frame


@pytest.mark.parametrize("path", ["wire", "float"])
def test_a_learnt_edge_stops_the_filter_and_flat_noise_is_still_averaged(path):
    """An irradiance step on one plane: the unguided filter blurs it (the columns beside it mix
    1 and 4); once the guide has seen a few frames it keeps the step within the noise, while
    away from it the guided filter averages as many neighbours as before (the noise stays down)."""
    w, h, n = 24, 12, 3
    params = params_to_dict(make_params(interleave=n, filter_frames=-1))
    guide = EdgeStoppingGuide().track("view")
    for i, frame in enumerate(_step_frames(12, seed=4)):
        asm, plain = FrameAssembler(w, h, n), FrameAssembler(w, h, n)
        for t, b in frame:
            if path == "wire":
                asm.add_wire(t, encode(b))
                plain.add_wire(t, encode(b))
            else:
                asm.add(t, b)
                plain.add(t, b)
        img, ref = asm.image(params, i, guide), plain.image(params, i)
        if i < MIN_FRAMES:
            np.testing.assert_array_equal(img, ref)  # nothing learnt yet: the plain filter
    edge = slice(w // 2 - 1, w // 2 + 1)  # the columns either side of the step
    truth = np.where(np.arange(w) < w // 2, 1.0, 4.0)
    plain_err = np.abs(ref[:, edge, 0].mean(0) - truth[edge])
    guided_err = np.abs(img[:, edge, 0].mean(0) - truth[edge])
    assert plain_err.min() > 0.8 and guided_err.max() < 0.2  # blurred by ~1 of 3; kept
    flat = (slice(None), slice(2, w // 2 - 3))
    assert img[flat][..., 0].std() < 1.3 * ref[flat][..., 0].std()  # still averaged


def test_without_accumulation_the_guide_is_ignored():
    """Every frame of a view without accumulation is the same: no variance to learn, so the guide
    must neither guide nor learn (a zero variance would stop the filter at every difference)."""
    w, h, n = 24, 12, 3
    params = params_to_dict(make_params(interleave=n, accumulate=False))
    guide = EdgeStoppingGuide().track("view")
    frame = next(_step_frames(1, seed=2))
    images = []
    for _ in range(MIN_FRAMES + 2):
        asm = FrameAssembler(w, h, n)
        for t, b in frame:
            asm.add(t, b)
        images.append(asm.image(params, 0, guide))
    assert guide.count == 0
    for img in images[1:]:
        np.testing.assert_array_equal(img, images[0])


def _guided_reference(b: dict, mean: np.ndarray, tol: np.ndarray, window: int, dt: float, nt: float) -> np.ndarray:
    """The guided discontinuity buffer written out per pixel (no lobes): a pixel averages its own
    irradiance and that of each neighbour with continuous depth and normal whose guide mean is
    within tol_j + tol_c of its own; radiance = reflectance × that + unfiltered."""
    from tests.support.oracle_master import continuous_neighbours

    H, W = b["depth"].shape
    out = np.empty((H, W, 3))
    for y in range(H):
        for x in range(W):
            acc, cnt = b["irradiance"][y, x].astype(np.float64), 1
            if np.isfinite(b["depth"][y, x]):
                for j, i in continuous_neighbours(b, y, x, window, dt, nt):
                    if abs(mean[j, i] - mean[y, x]) <= tol[j, i] + tol[y, x]:
                        acc, cnt = acc + b["irradiance"][j, i], cnt + 1
            out[y, x] = b["reflectance"][y, x] * acc / cnt + b["unfiltered"][y, x]
    return out


@pytest.mark.parametrize("path", ["wire", "float"])
def test_a_frame_is_guided_by_the_frames_before_it_not_by_itself(path):
    """A guided frame is the rule written out per pixel with the guide of the frames *before* it
    (its own noise must not pick its neighbours), on both ways into the assembler, at a size the
    interleave does not divide; with the frame's own luminance in the guide it would differ."""
    import copy

    w, h, n = 25, 13, 3
    params = params_to_dict(make_params(interleave=n))
    frames = list(_step_frames(MIN_FRAMES + 2, seed=9, w=w, h=h, n=n))
    guide = EdgeStoppingGuide().track("view")

    def assembler(frame):
        asm = FrameAssembler(w, h, n)
        for t, b in frame:
            if path == "wire":
                asm.add_wire(t, encode(b))
            else:
                asm.add(t, b)
        return asm

    for i, frame in enumerate(frames[:-1]):
        assembler(frame).image(params, i, guide)
    before = copy.deepcopy(guide)
    last = len(frames) - 1
    img = assembler(frames[-1]).image(params, last, guide)
    assert guide.count == before.count + 1
    bufs = assembler(frames[-1]).buffers
    mean, tol = before.tolerances(params["filter_guide"], (h, w))
    dt, nt = params["depth_threshold"], params["normal_threshold"]
    np.testing.assert_allclose(img, _guided_reference(bufs, mean, tol, n, dt, nt), rtol=1e-5, atol=1e-6)
    with_itself = copy.deepcopy(before)
    k = params["filter_guide"]
    with_itself.add(guide.sums(k, (h, w))[0] - before.sums(k, (h, w))[0])  # the frame's own luminance, learnt first
    mean2, tol2 = with_itself.tolerances(params["filter_guide"], (h, w))
    assert not np.allclose(img, _guided_reference(bufs, mean2, tol2, n, dt, nt), rtol=1e-5, atol=1e-6)


def test_on_the_cornell_box_the_guided_accumulation_is_closer_to_the_reference():
    """The discontinuity buffer's blur is a bias accumulation keeps (here with the filter never
    faded, ``filter_frames`` -1): at the box's corners and the blocks' shadow edges. The guide,
    learning them over the frames, brings 24 frames of cornell-box at 128×128 closer to the
    Mitsuba reference (block-averaged to that size)."""
    from igi.common.image_io import read_image
    from igi.common.loader import load_scene
    from igi.common.metrics import block_average, relmse
    from igi.master.inprocess import render_local
    from igi.worker.renderer import Renderer
    from tests.support.paths import REFERENCES, SCENES

    name = "cornell-box"
    scene = load_scene(SCENES / name / "scene.xml")
    ref = read_image(REFERENCES / f"{name}.exr")[..., :3]
    ref = block_average(ref, ref.shape[1] // 128)
    r = Renderer(scene)
    err = {k: relmse(render_local(scene, {"filter_guide": k, "filter_frames": -1}, 24, width=ref.shape[1],
                                  height=ref.shape[0], renderer=r), ref) for k in (0.0, 2.0)}
    print(f"relMSE unguided {err[0.0]:.3g}, guided {err[2.0]:.3g}")
    assert err[2.0] < 0.8 * err[0.0]


@pytest.mark.parametrize("select", [0.0, 1.5])
def test_a_guided_irradiance_filter_does_not_fade_and_the_lobes_only_without_the_selection(select):
    """Past ``filter_frames`` an unguided filter has faded to the raw irradiance (its blur would
    be a bias forever); a guided one keeps averaging (its blur shrinks with the noise). The split
    lobes, which no guide watches, fade without ``filter_select``; with it they keep averaging too
    (the running mean takes back their measured bias: master/filter_selection.py)."""
    import copy

    from tests.master.test_frame_assembly import _lobe_reference

    w, h, n = 24, 12, 3
    params = params_to_dict(make_params(interleave=n, consistent=True, filter_frames=4, filter_select=select))
    guide = EdgeStoppingGuide().track("view")
    frames = list(_step_frames(MIN_FRAMES + 3, seed=5))

    def assembled(frame, lobes=None):
        asm = FrameAssembler(w, h, n)
        for i, (t, b) in enumerate(frame):
            lobe = None if lobes is None else lobes[i]
            asm.add(t, TileBuffers(b.reflectance, b.irradiance, b.unfiltered, b.depth, b.normal, lobe))
        return asm

    for i, frame in enumerate(frames[:-1]):
        assembled(frame).image(params, i, guide)
    rng = np.random.default_rng(6)
    lobes = [np.where(rng.random((len(b), 1)) < 0.5, rng.random((len(b), 3)), -1.0).astype(np.float32)
             for _, b in frames[-1]]
    late, fade = 40, (4 / 41 if select == 0 else 1.0)  # far past the fade
    lobed = assembled(frames[-1], lobes)
    bufs = lobed.buffers
    before = copy.deepcopy(guide)
    img = lobed.image(params, late, guide)
    guided = assembled(frames[-1]).image(params, late, before)
    faded = assembled(frames[-1]).image(params, late)
    flat = (slice(None), slice(2, w // 2 - 3))
    raw = bufs["irradiance"][flat][..., 0].std()
    assert faded[flat][..., 0].std() > 0.8 * raw  # unguided: faded to the raw noise
    assert guided[flat][..., 0].std() < 0.5 * raw  # guided: still averaged
    np.testing.assert_allclose(img - guided, _lobe_reference(bufs, n, params["depth_threshold"],
                                                             params["normal_threshold"], fade), atol=1e-5)


def test_the_filter_pass_writes_the_next_frames_guide_as_the_sums_give_it():
    """The pass that learns a frame also writes the next frame's guide (no pass of its own over
    the sums): bit for bit what ``guide_cells`` computes from the sums, for every frame from the
    first guided one on; the sums are each pixel's own, whatever the planes' layout; and a guide
    changed by ``add`` (sums the written guide never saw) is computed afresh, not read stale."""
    from igi.master.kernels.discontinuity import guide_cells

    w, h, n = 25, 13, 3
    params = params_to_dict(make_params(interleave=n))
    k = params["filter_guide"]
    guide = EdgeStoppingGuide().track("view")
    lum = []
    for i, frame in enumerate(_step_frames(MIN_FRAMES + 3, seed=5, w=w, h=h, n=n)):
        asm = FrameAssembler(w, h, n)
        for t, b in frame:
            asm.add_wire(t, encode(b))
        asm.image(params, i, guide)
        irr = asm.buffers["irradiance"].astype(np.float64)
        lum.append(irr @ np.array(LUMINANCE_WEIGHTS))
        if guide.count < MIN_FRAMES:
            continue
        kk, count, gm, gt = guide._read
        assert (kk, count) == (k, guide.count)
        ref_m, ref_t = np.empty_like(gm), np.empty_like(gt)
        guide_cells(guide._s1.ravel(), guide._s2.ravel(), float(guide.count), k, ref_m.ravel(), ref_t.ravel())
        np.testing.assert_array_equal(gm, ref_m)
        np.testing.assert_array_equal(gt, ref_t)
        s1, s2, m = guide.sums(k, (h, w))
        np.testing.assert_allclose(s1, np.sum(lum, 0), rtol=1e-5)  # pixel by pixel, in image order
        np.testing.assert_allclose(s2, np.sum(np.square(lum), 0), rtol=1e-5)
    mean_before, _ = guide.tolerances(k, (h, w))
    guide.add(np.full((h, w), 100.0))
    mean_after, _ = guide.tolerances(k, (h, w))
    np.testing.assert_allclose(mean_after, (mean_before * (guide.count - 1) + 100.0) / guide.count, rtol=1e-5)
