"""Error against a reference image (docs/accuracy.md): relMSE, RMSE, block-averaged relMSE, FLIP."""
from __future__ import annotations

import numpy as np


def relmse(img: np.ndarray, ref: np.ndarray, eps: float = 0.01) -> float:
    """mean over pixels and channels of (x - ref)^2 / (ref^2 + eps)."""
    img = np.asarray(img, np.float64)
    ref = np.asarray(ref, np.float64)
    if img.shape != ref.shape:
        raise ValueError(f"image shape {img.shape} differs from reference shape {ref.shape}")
    return float(np.mean((img - ref) ** 2 / (ref * ref + eps)))


def rmse(img: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((np.asarray(img, np.float64) - np.asarray(ref, np.float64)) ** 2)))


def block_average(img: np.ndarray, block: int) -> np.ndarray:
    """Average over block x block pixel squares (crops the remainder): measures the lighting
    and divides a noisy reference's per-pixel noise by ~block²."""
    h, w = img.shape[:2]
    h2, w2 = h - h % block, w - w % block
    x = np.asarray(img[:h2, :w2], np.float64)
    return x.reshape(h2 // block, block, w2 // block, block, -1).mean(axis=(1, 3))


def relmse_blocks(img: np.ndarray, ref: np.ndarray, block: int = 4) -> float:
    return relmse(block_average(img, block), block_average(ref, block))


def flip(img: np.ndarray, ref: np.ndarray) -> float | None:
    """Mean HDR-FLIP error (flip-evaluator package) or None when it is not installed."""
    try:
        import flip_evaluator as fe  # type: ignore
    except ImportError:
        return None
    err, mean, _ = fe.evaluate(np.asarray(ref, np.float32), np.asarray(img, np.float32), "HDR")
    return float(mean)
