"""Image reading/writing: OpenEXR round trip, sRGB conversion as Mitsuba 3 does it."""
import numpy as np
import pytest
from PIL import Image

from igi.common.image_io import linear_to_srgb, read_image, srgb_to_linear, to_srgb8, write_exr, write_png
from igi.common.scene import SceneError


def test_exr_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(1)
    img = (rng.random((7, 11, 3)) * 50).astype(np.float32)
    img[0, 0] = [0.0, 1e-8, 65000.0]
    p = tmp_path / "a.exr"
    write_exr(p, img)
    back = read_image(p)
    assert back.dtype == np.float32 and back.shape == (7, 11, 3)
    np.testing.assert_array_equal(back, img)


def test_srgb_eotf_values_match_mitsuba_bitmap_decoding():
    # Mitsuba 3.9.1's bitmap texture (raw=false) returns these for 8-bit values 0, 1, 11, 50, 128, 200, 255
    mitsuba = [0.0, 0.0003035269910469651, 0.003346540965139866, 0.031895995140075684,
               0.21586041152477264, 0.5775807499885559, 1.0]
    ours = srgb_to_linear(np.array([0, 1, 11, 50, 128, 200, 255]) / 255.0)
    np.testing.assert_allclose(ours, mitsuba, rtol=2e-6, atol=1e-9)
    # the linear segment below 0.04045
    assert srgb_to_linear(0.04) == pytest.approx(0.04 / 12.92)


def test_srgb_oetf_inverts_eotf():
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)
    assert linear_to_srgb(2.0) == pytest.approx(1.0)  # clipped
    assert linear_to_srgb(0.001) == pytest.approx(0.001 * 12.92)


def test_read_png_linearizes_and_keeps_row_order(tmp_path):
    a = np.zeros((2, 3, 3), np.uint8)
    a[0, 0] = [255, 128, 0]
    a[1, 2] = [10, 20, 30]
    Image.fromarray(a).save(tmp_path / "t.png")
    img = read_image(tmp_path / "t.png")
    assert img.dtype == np.float32 and img.shape == (2, 3, 3)
    np.testing.assert_allclose(img[0, 0], srgb_to_linear(np.array([255, 128, 0]) / 255), rtol=1e-6)
    np.testing.assert_allclose(img[1, 2], srgb_to_linear(np.array([10, 20, 30]) / 255), rtol=1e-6)
    raw = read_image(tmp_path / "t.png", raw=True)
    np.testing.assert_allclose(raw[0, 0], [1.0, 128 / 255, 0.0], rtol=1e-6)


def test_grayscale_and_alpha_images_become_rgb(tmp_path):
    Image.fromarray(np.full((2, 2), 128, np.uint8)).save(tmp_path / "g.png")
    Image.fromarray(np.full((2, 2, 4), 200, np.uint8)).save(tmp_path / "a.png")
    g = read_image(tmp_path / "g.png")
    assert g.shape == (2, 2, 3) and np.allclose(g, srgb_to_linear(128 / 255))
    a = read_image(tmp_path / "a.png")
    assert a.shape == (2, 2, 3) and np.allclose(a, srgb_to_linear(200 / 255))


def test_write_png_round_trips_within_quantization(tmp_path):
    lin = srgb_to_linear(np.linspace(0, 1, 12).reshape(2, 2, 3)).astype(np.float32)
    write_png(tmp_path / "o.png", lin)
    back = np.asarray(Image.open(tmp_path / "o.png"))
    np.testing.assert_array_equal(back, np.round(np.linspace(0, 255, 12)).reshape(2, 2, 3).astype(np.uint8))
    # exposure +1 doubles the linear value; values above 1 clip to 255
    assert to_srgb8(np.full((1, 1, 3), 0.25), exposure=1.0)[0, 0, 0] == to_srgb8(np.full((1, 1, 3), 0.5))[0, 0, 0]
    assert to_srgb8(np.full((1, 1, 3), 7.0))[0, 0, 0] == 255
    assert to_srgb8(np.full((1, 1, 3), np.nan))[0, 0, 0] == 0


def test_missing_or_corrupt_images_raise_scene_error(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        read_image(tmp_path / "nope.png")
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(SceneError, match="bad.png"):
        read_image(tmp_path / "bad.png")
    (tmp_path / "bad.exr").write_bytes(b"not an exr")
    with pytest.raises(SceneError, match="bad.exr"):
        read_image(tmp_path / "bad.exr")


def _write_rgbe(path, rgb: np.ndarray) -> None:
    """A flat (uncompressed) Radiance RGBE file written from its definition, row 0 at the top."""
    h, w, _ = rgb.shape
    v = rgb.max(axis=2)
    m, e = np.frexp(v)
    scale = np.where(v > 0, m * 256.0 / np.where(v > 0, v, 1), 0.0)
    px = np.zeros((h, w, 4), np.uint8)
    px[..., :3] = np.clip(rgb * scale[..., None], 0, 255).astype(np.uint8)
    px[..., 3] = np.where(v > 0, e + 128, 0).astype(np.uint8)
    head = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode()
    path.write_bytes(head + px.tobytes())


def test_radiance_hdr_images_read_as_linear_rgb_in_row_order(tmp_path):
    rng = np.random.default_rng(2)
    img = np.exp2(rng.integers(-6, 12, (5, 9, 1))) * rng.uniform(0.5, 1.0, (5, 9, 3))
    img[0, 0] = [4000.0, 3600.0, 3000.0]  # a sun
    img[4, 8] = [0.0, 0.0, 0.0]
    p = tmp_path / "sky.hdr"
    _write_rgbe(p, img)
    back = read_image(p)
    assert back.dtype == np.float32 and back.shape == (5, 9, 3)
    # one shared exponent: each channel within a step of 1/256 of the pixel's brightest
    tol = img.max(axis=2, keepdims=True) / 128
    assert np.all(np.abs(back - img) <= tol)
    bad = tmp_path / "bad.hdr"
    bad.write_bytes(b"not an image")
    with pytest.raises(SceneError, match="bad.hdr"):
        read_image(bad)
