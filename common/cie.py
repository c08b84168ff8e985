"""Colorimetry for Mitsuba's ``<spectrum>`` values: a spectrum to linear sRGB as Mitsuba 3's RGB
variants convert one (``spectrum_list_to_srgb``), so a scene given in spectra renders in igi with the
colours it has in Mitsuba.

- A sampled spectrum ``"λ₁:v₁, λ₂:v₂, …"`` (nm, ascending) is linearly interpolated, integrated
  against the CIE 1931 2° colour-matching functions over 360–830 nm (1,000 steps; zero outside the
  given wavelengths) and taken from XYZ to linear sRGB. A reflectance is weighed by the D65
  illuminant (a flat 0.5 is grey 0.5) and clamped to [0, 1]; an emitter's spectrum is light as it
  is (a flat one is the equal-energy illuminant, pink beside sRGB's white) and clamped at 0.
- A uniform ``<spectrum value="v"/>``: grey v in a reflectance, v × :data:`EQUAL_ENERGY_SRGB` in an
  emitter.

Data: CIE 015:2004 (1931 standard observer and illuminant D65 at 5 nm, linearly interpolated),
normalized as Mitsuba 3 does (within 1e-5 of Mitsuba 3.9.1's own conversion)."""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

CIE_MIN, CIE_MAX = 360.0, 830.0
WAVELENGTHS = np.arange(CIE_MIN, CIE_MAX + 1.0, 5.0)  # the tables' 95 wavelengths (nm)
_STEPS = 1000
Y_NORMALIZATION = 1.0 / 106.7502593994140625  # Mitsuba's: a flat unit spectrum has luminance 1
D65_NORMALIZATION = 1.0 / 98.99741751876255  # Mitsuba's: D65 about 1 in the visible range

# CIE XYZ -> linear sRGB (D65), the matrix Mitsuba 3 converts with.
XYZ_TO_LINEAR_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                               [-0.969256, 1.875991, 0.041556],
                               [0.055648, -0.204043, 1.057311]])
# The equal-energy illuminant at unit luminance (XYZ = 1, 1, 1) in linear sRGB: (1.2048, 0.9483, 0.9089).
EQUAL_ENERGY_SRGB = XYZ_TO_LINEAR_SRGB @ np.ones(3)

X_BAR = np.array([
    0.0001299, 0.0002321, 0.0004149, 0.0007416, 0.001368, 0.002236, 0.004243, 0.00765,
    0.01431, 0.02319, 0.04351, 0.07763, 0.13438, 0.21477, 0.2839, 0.3285,
    0.34828, 0.34806, 0.3362, 0.3187, 0.2908, 0.2511, 0.19536, 0.1421,
    0.09564, 0.05795, 0.03201, 0.0147, 0.0049, 0.0024, 0.0093, 0.0291,
    0.06327, 0.1096, 0.1655, 0.22575, 0.2904, 0.3597, 0.43345, 0.51205,
    0.5945, 0.6784, 0.7621, 0.8425, 0.9163, 0.9786, 1.0263, 1.0567,
    1.0622, 1.0456, 1.0026, 0.9384, 0.85445, 0.7514, 0.6424, 0.5419,
    0.4479, 0.3608, 0.2835, 0.2187, 0.1649, 0.1212, 0.0874, 0.0636,
    0.04677, 0.0329, 0.0227, 0.01584, 0.0113592, 0.00811092, 0.00579035, 0.00410946,
    0.00289933, 0.00204919, 0.00143997, 0.000999949, 0.000690079, 0.000476021, 0.000332301, 0.000234826,
    0.00016615, 0.000117413, 8.30753e-05, 5.87065e-05, 4.15099e-05, 2.93533e-05, 2.06738e-05, 1.45598e-05,
    1.0254e-05, 7.22146e-06, 5.08587e-06, 3.58165e-06, 2.52252e-06, 1.77651e-06, 1.25114e-06,
])
Y_BAR = np.array([
    3.917e-06, 6.965e-06, 1.239e-05, 2.202e-05, 3.9e-05, 6.4e-05, 0.00012, 0.000217,
    0.000396, 0.00064, 0.00121, 0.00218, 0.004, 0.0073, 0.0116, 0.01684,
    0.023, 0.0298, 0.038, 0.048, 0.06, 0.0739, 0.09098, 0.1126,
    0.13902, 0.1693, 0.20802, 0.2586, 0.323, 0.4073, 0.503, 0.6082,
    0.71, 0.7932, 0.862, 0.91485, 0.954, 0.9803, 0.99495, 1,
    0.995, 0.9786, 0.952, 0.9154, 0.87, 0.8163, 0.757, 0.6949,
    0.631, 0.5668, 0.503, 0.4412, 0.381, 0.321, 0.265, 0.217,
    0.175, 0.1382, 0.107, 0.0816, 0.061, 0.04458, 0.032, 0.0232,
    0.017, 0.01192, 0.00821, 0.005723, 0.004102, 0.002929, 0.002091, 0.001484,
    0.001047, 0.00074, 0.00052, 0.0003611, 0.0002492, 0.0001719, 0.00012, 8.48e-05,
    6e-05, 4.24e-05, 3e-05, 2.12e-05, 1.499e-05, 1.06e-05, 7.4657e-06, 5.2578e-06,
    3.7029e-06, 2.6078e-06, 1.8366e-06, 1.2934e-06, 9.1093e-07, 6.4153e-07, 4.5181e-07,
])
Z_BAR = np.array([
    0.0006061, 0.001086, 0.001946, 0.003486, 0.00645, 0.01055, 0.02005, 0.03621,
    0.06785, 0.1102, 0.2074, 0.3713, 0.6456, 1.03905, 1.3856, 1.62296,
    1.74706, 1.7826, 1.77211, 1.7441, 1.6692, 1.5281, 1.28764, 1.0419,
    0.81295, 0.6162, 0.46518, 0.3533, 0.272, 0.2123, 0.1582, 0.1117,
    0.07825, 0.05725, 0.04216, 0.02984, 0.0203, 0.0134, 0.00875, 0.00575,
    0.0039, 0.00275, 0.0021, 0.0018, 0.00165, 0.0014, 0.0011, 0.001,
    0.0008, 0.0006, 0.00034, 0.00024, 0.00019, 0.0001, 5e-05, 3e-05,
    2e-05, 1e-05, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0,
])
D65 = np.array([
    46.6383, 49.3637, 52.0891, 51.0323, 49.9755, 52.3118, 54.6482, 68.7015,
    82.7549, 87.1204, 91.486, 92.4589, 93.4318, 90.057, 86.6823, 95.7736,
    104.865, 110.936, 117.008, 117.41, 117.812, 116.336, 114.861, 115.392,
    115.923, 112.367, 108.811, 109.082, 109.354, 108.578, 107.802, 106.296,
    104.79, 106.239, 107.689, 106.047, 104.405, 104.225, 104.046, 102.023,
    100, 98.1671, 96.3342, 96.0611, 95.788, 92.2368, 88.6856, 89.3459,
    90.0062, 89.8026, 89.5991, 88.6489, 87.6987, 85.4936, 83.2886, 83.4939,
    83.6992, 81.863, 80.0268, 80.1207, 80.2146, 81.2462, 82.2778, 80.281,
    78.2842, 74.0027, 69.7213, 70.6652, 71.6091, 72.979, 74.349, 67.9765,
    61.604, 65.7448, 69.8856, 72.4863, 75.087, 69.3398, 63.5927, 55.0054,
    46.4182, 56.6118, 66.8054, 65.0941, 63.3828, 63.8434, 64.304, 61.8779,
    59.4519, 55.7054, 51.959, 54.6998, 57.4406, 58.8765, 60.3125,
])


def spectrum_to_linear_srgb(wavelengths: ArrayLike, values: ArrayLike, emitted: bool) -> tuple[np.ndarray, bool]:
    """A sampled spectrum -> (linear sRGB, whether it was clamped into gamut). ``wavelengths``
    (nm) must be strictly increasing, two or more, and with ``values`` finite (the scene loader
    checks them). ``emitted``: an emitter's light (no illuminant, unbounded) rather than a
    reflectance (under D65, bounded by 1)."""
    wl = np.asarray(wavelengths, np.float64)
    v = np.asarray(values, np.float64)
    w = CIE_MIN + np.arange(_STEPS) / (_STEPS - 1) * (CIE_MAX - CIE_MIN)
    w = w[(w >= wl[0]) & (w <= wl[-1])]
    s = np.interp(w, wl, v)
    if not emitted:
        s = s * np.interp(w, WAVELENGTHS, D65) * D65_NORMALIZATION
    xyz = np.array([np.dot(s, np.interp(w, WAVELENGTHS, t)) for t in (X_BAR, Y_BAR, Z_BAR)])
    rgb = XYZ_TO_LINEAR_SRGB @ (xyz * (CIE_MAX - CIE_MIN) / _STEPS * Y_NORMALIZATION)
    clamped = np.clip(rgb, 0.0, None if emitted else 1.0)
    return clamped, bool(np.any(clamped != rgb))
