"""Real orthonormal spherical harmonics to any band, evaluated as polynomials of Cartesian directions.

Convention (:mod:`bakery.conventions`): Condon–Shortley phase, index k = l(l+1) + m, so that
Y1,-1 = -c·y, Y1,0 = c·z, Y1,1 = -c·x with c = √(3/4π) (ZH3 paper, seed 001, Eq. 4) and band 2 is Eq. 5.

Derivation
    Y_l^m = √2 K_l^m P_l^m(z) cos(mφ) (m > 0), √2 K_l^|m| P_l^|m|(z) sin(|m|φ) (m < 0), K_l^0 P_l(z) (m = 0),
    K_l^m = √((2l+1)(l−|m|)! / (4π (l+|m|)!)) (ZH3 paper Eq. 1). Writing P_l^m(z) = (1−z²)^{m/2} Q_l^m(z) and
    (1−z²)^{m/2} (cos mφ, sin mφ) = (Re, Im)(x + iy)^m turns every Y_l^m into a polynomial in x, y, z with
        Q_m^m = (−1)^m (2m−1)!!,  Q_{m+1}^m = (2m+1) z Q_m^m,
        Q_l^m = ((2l−1) z Q_{l−1}^m − (l+m−1) Q_{l−2}^m) / (l−m)          (associated Legendre recurrence).
"""

from __future__ import annotations

from functools import lru_cache
from math import factorial, pi, sqrt

import numpy as np


def sh_count(max_band: int) -> int:
    """Number of coefficients of bands 0..max_band: (L+1)²."""
    return (max_band + 1) ** 2


def sh_index(l: int, m: int) -> int:  # noqa: E741 - l is the paper's band symbol
    """Flat index k = l(l+1) + m."""
    return l * (l + 1) + m


def sh_bands(max_band: int) -> np.ndarray:
    """Band l of every flat index (L+1)²."""
    return np.concatenate([np.full(2 * l + 1, l) for l in range(max_band + 1)])  # noqa: E741


@lru_cache(maxsize=None)
def normalization(l: int, m: int) -> float:  # noqa: E741
    """K_l^m of ZH3 paper Eq. 1."""
    m = abs(m)
    return sqrt((2 * l + 1) * factorial(l - m) / (4 * pi * factorial(l + m)))


def evaluate_sh_basis(directions: np.ndarray, max_band: int) -> np.ndarray:
    """All basis functions of bands 0..L at unit directions (..., 3) → (..., (L+1)²), float64."""
    d = np.asarray(directions, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out = np.empty(d.shape[:-1] + (sh_count(max_band),))
    # (x + iy)^m as real and imaginary parts.
    re = [np.ones_like(x)]
    im = [np.zeros_like(x)]
    for _ in range(max_band):
        re.append(re[-1] * x - im[-1] * y)
        im.append(re[-2] * y + im[-1] * x)
    double_factorial = 1.0
    for m in range(max_band + 1):
        if m > 0:
            double_factorial *= 2 * m - 1
        q_prev = np.full_like(z, (-1.0) ** m * double_factorial)  # Q_m^m
        q_curr = None
        for l in range(m, max_band + 1):  # noqa: E741
            if l == m:
                q = q_prev
            elif l == m + 1:
                q_curr = (2 * m + 1) * z * q_prev
                q = q_curr
            else:
                q_next = ((2 * l - 1) * z * q_curr - (l + m - 1) * q_prev) / (l - m)
                q_prev, q_curr = q_curr, q_next
                q = q_next
            k = normalization(l, m)
            if m == 0:
                out[..., sh_index(l, 0)] = k * q
            else:
                out[..., sh_index(l, m)] = sqrt(2.0) * k * q * re[m]
                out[..., sh_index(l, -m)] = sqrt(2.0) * k * q * im[m]
    return out


def evaluate_sh(coefficients: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Reconstruct SH functions at directions.

    Args:
        coefficients: (P, K, C) coefficients of P functions with C channels, K = (L+1)².
        directions: (N, 3) unit directions.
    Returns:
        (P, N, C) values.
    """
    k = coefficients.shape[-2]
    max_band = int(round(sqrt(k))) - 1
    basis = evaluate_sh_basis(directions, max_band)  # (N, K)
    return np.einsum("nk,pkc->pnc", basis, coefficients)
