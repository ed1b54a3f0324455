"""Zonal convolution, the cosine lobe, and zonal-harmonic expansions.

References
    [ZH3] Roughton et al. 2024, "ZH3: Quadratic Zonal Harmonics" (seed 001).
    [RH01] Ramamoorthi & Hanrahan 2001, "An efficient representation for irradiance environment maps" (and seed 003
    App. A): the clamped-cosine kernel's band factors.
"""

from __future__ import annotations

from math import factorial, pi, sqrt

import numpy as np

from bakery.sh.basis import evaluate_sh_basis, sh_bands


def cosine_lobe_band_factors(max_band: int) -> np.ndarray:
    """A_l, l = 0..L, of the clamped cosine max(0, n·ω): π, 2π/3, π/4, 0, −π/24, … ([RH01] Eq. 8–9).

    A_l = 0 for odd l > 1; for even l, A_l = 2π (−1)^{l/2−1} / ((l+2)(l−1)) · l! / (2^l ((l/2)!)²).
    """
    factors = np.zeros(max_band + 1)
    for l in range(max_band + 1):  # noqa: E741
        if l == 1:
            factors[l] = 2.0 * pi / 3.0
        elif l % 2 == 0:
            half = l // 2
            factors[l] = (
                2.0 * pi * (-1.0) ** (half - 1) / ((l + 2) * (l - 1)) * factorial(l) / (2.0**l * factorial(half) ** 2)
            )
    return factors


def convolve_zonal(coefficients: np.ndarray, zonal_coefficients: np.ndarray) -> np.ndarray:
    """Convolve SH (..., K, C) with a zonal kernel given by its ZH coefficients h_l (L+1,).

    (f * h)_l^m = √(4π/(2l+1)) · h_l · f_l^m ([ZH3] Eq. 2).
    """
    k = coefficients.shape[-2]
    max_band = int(round(sqrt(k))) - 1
    bands = sh_bands(max_band)
    scale = np.sqrt(4.0 * pi / (2.0 * bands + 1.0)) * np.asarray(zonal_coefficients)[bands]
    return coefficients * scale[:, None]


def irradiance_sh_from_radiance_sh(radiance_sh: np.ndarray) -> np.ndarray:
    """Irradiance SH (..., K, C) = A_l · radiance SH (cosine-lobe convolution; [RH01] Eq. 7)."""
    k = radiance_sh.shape[-2]
    max_band = int(round(sqrt(k))) - 1
    return radiance_sh * cosine_lobe_band_factors(max_band)[sh_bands(max_band)][:, None]


def zonal_to_sh(zonal_coefficients: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """SH coefficients (..., K) of a zonal function with SH-zonal coefficients z_l (..., L+1) about unit ``axis`` (..., 3).

    f_l^m = z_l · √(4π/(2l+1)) · Y_l^m(axis) (rotation of a zonal harmonic; [ZH3] Sec. 2.1).
    """
    z = np.asarray(zonal_coefficients, dtype=np.float64)
    max_band = z.shape[-1] - 1
    bands = sh_bands(max_band)
    basis = evaluate_sh_basis(axis, max_band)
    return z[..., bands] * np.sqrt(4.0 * pi / (2.0 * bands + 1.0)) * basis
