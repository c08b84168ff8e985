"""A task's per-pixel buffers from its end points (worker.renderer.render_tile's last step),
compiled: one pass over the end points instead of a dozen masked copies and an ``np.add.at``.

Each pixel's main, filterable end point writes its reflectance (albedo × throughput) and
irradiance; every other end point adds throughput × albedo × irradiance to the pixel's
unfiltered radiance, in end-point order (the same float64 sums as numpy's ``add.at``).
"""
from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def compose(pixel, main, albedo, throughput, irr, refl_out, irr_out, unf_out) -> None:
    """``refl_out``/``irr_out`` (P, 3) float64, zero where no main end point writes;
    ``unf_out`` (P, 3) float64 holding the eye paths' unfiltered radiance, added to in place."""
    for e in range(pixel.shape[0]):
        px = pixel[e]
        if main[e]:
            for c in range(3):
                refl_out[px, c] = albedo[e, c] * throughput[e, c]
                irr_out[px, c] = irr[e, c]
        else:
            for c in range(3):
                unf_out[px, c] += throughput[e, c] * albedo[e, c] * irr[e, c]


@njit(cache=True, nogil=True, error_model="numpy")
def filter_lobes(pixel, carry, unf_out, lobe_out) -> None:
    """Move the unfiltered radiance of each pixel whose main end point is flagged in ``carry``
    (a split smooth plastic's diffuse layer: the pixel's unfiltered radiance is its lobe's) to
    its lobe (``lobe_out`` (P, 3), NO_LOBE elsewhere), which the discontinuity buffer averages
    over the neighbours that have one."""
    for e in range(pixel.shape[0]):
        if not carry[e]:
            continue
        px = pixel[e]
        for c in range(3):
            lobe_out[px, c] = unf_out[px, c]
            unf_out[px, c] = 0.0
