"""Image files: 8-bit/16-bit PNG and JPEG via Pillow, OpenEXR via the ``OpenEXR`` package.

``read_image`` returns linear RGB float32 (H, W, 3), row 0 = top of the image. 8- and 16-bit
images are sRGB-decoded with the exact sRGB EOTF, as Mitsuba 3 does for bitmaps with
``raw=false`` (checked against Mitsuba 3.9.1: identical to float32 rounding). EXR data is
taken as linear.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .scene import SceneError


def srgb_to_linear(c):
    """The sRGB EOTF (IEC 61966-2-1), elementwise on values in [0, 1]."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    """The sRGB OETF (inverse of :func:`srgb_to_linear`), elementwise; input clipped to [0, 1]."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


_LUT8 = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)


def _read_exr(path: Path) -> np.ndarray:
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            ch = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except Exception as e:  # the C++ library raises plain RuntimeError/OSError
        raise SceneError(f"{path}: cannot read OpenEXR file ({e})") from None
    if not ch:
        raise SceneError(f"{path}: OpenEXR file has no channels")

    def pick(*names):
        for n in names:
            for key in ch:
                if key == n or key.endswith("." + n):
                    return ch[key]
        return None

    r, g, b = pick("R", "r"), pick("G", "g"), pick("B", "b")
    if r is not None and g is not None and b is not None:
        rgb = np.stack([r, g, b], axis=-1)
    else:
        y = pick("Y", "y", "L")
        if y is None:
            y = next(iter(ch.values()))
        rgb = np.repeat(np.asarray(y)[..., None], 3, axis=-1)
    return np.ascontiguousarray(rgb, dtype=np.float32)


def read_image(path, raw: bool = False) -> np.ndarray:
    """Read an image as linear RGB float32 (H, W, 3).

    ``raw=True`` skips the sRGB decoding of 8/16-bit images (Mitsuba's ``raw`` bitmap flag).
    Alpha channels are dropped; grayscale is replicated to RGB.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    if path.suffix.lower() == ".exr":
        return _read_exr(path)
    if path.suffix.lower() in (".hdr", ".pic", ".rgbe"):
        return _read_rgbe(path)
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.float64)
                a = a / (65535.0 if mode.startswith("I;16") or a.max() > 255 else 255.0)
                a = np.repeat(a[..., None], 3, axis=-1)
                return np.ascontiguousarray(a if raw else srgb_to_linear(a), dtype=np.float32)
            if mode == "F":
                a = np.asarray(im, dtype=np.float32)
                return np.ascontiguousarray(np.repeat(a[..., None], 3, axis=-1))
            if mode != "RGB":
                im = im.convert("RGB")
            a8 = np.asarray(im, dtype=np.uint8)
    except (UnidentifiedImageError, OSError, ValueError) as e:
        raise SceneError(f"{path}: cannot read image ({e})") from None
    if raw:
        return (a8.astype(np.float32) / np.float32(255.0)).reshape(a8.shape)
    return _LUT8[a8]


def _read_rgbe(path: Path) -> np.ndarray:
    """A Radiance RGBE (.hdr) image — the other HDR format of environment maps — as linear RGB
    float32, through OpenCV's reader (Pillow has none)."""
    import cv2

    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if a is None or a.ndim != 3 or a.shape[2] < 3 or a.dtype != np.float32:
        raise SceneError(f"{path}: cannot read image (not a Radiance RGBE file)")
    return np.ascontiguousarray(a[..., 2::-1])  # BGR -> RGB


def write_exr(path, rgb) -> None:
    """Write linear RGB float32 (H, W, 3) as a ZIP-compressed scanline OpenEXR file."""
    import OpenEXR

    a = np.ascontiguousarray(np.asarray(rgb, dtype=np.float32))
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"write_exr expects (H, W, 3), got {a.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": a}) as f:
        f.write(str(path))


def to_srgb8(rgb_linear, exposure: float = 0.0) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB: scale by 2^exposure, clip to [0, 1], sRGB OETF, round."""
    a = np.asarray(rgb_linear, dtype=np.float64) * (2.0 ** exposure)
    a = np.nan_to_num(a, nan=0.0, posinf=1.0, neginf=0.0)
    return np.round(linear_to_srgb(a) * 255.0).astype(np.uint8)


def write_png(path, rgb_linear, exposure: float = 0.0) -> None:
    """Write linear RGB (H, W, 3) as an 8-bit sRGB PNG (see :func:`to_srgb8`)."""
    from PIL import Image

    a = np.asarray(rgb_linear)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"write_png expects (H, W, 3), got {a.shape}")
    Image.fromarray(to_srgb8(a, exposure)).save(str(path))
