"""Rotation of real SH coefficients, band by band.

Each band's rotation D_l (2l+1 × 2l+1) is the linear map with Y_l(R⁻¹ω)·f = Y_l(ω)·(D_l f) for every ω: it is
recovered exactly (to rounding) by least squares over a fixed set of 4(2l+1) well-spread directions, since the
identity is linear in f and Y_l(R⁻¹ω) lies in the span of band l. A rotated function f'(ω) = f(R⁻¹ω) has
coefficients f' = D f.
"""

from __future__ import annotations

from math import sqrt

import numpy as np

from bakery.sh.basis import evaluate_sh_basis, sh_count
from bakery.sphere.fibonacci import fibonacci_directions


def sh_rotation_matrix(rotation: np.ndarray, max_band: int) -> np.ndarray:
    """Block-diagonal SH rotation ((L+1)², (L+1)²) for a 3×3 rotation matrix R (f'(ω) = f(R⁻¹ω))."""
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise ValueError("sh_rotation_matrix needs a proper 3x3 rotation matrix")
    n = sh_count(max_band)
    out = np.zeros((n, n))
    samples = fibonacci_directions(max(16, 4 * (2 * max_band + 1)))
    basis = evaluate_sh_basis(samples, max_band)
    basis_rotated = evaluate_sh_basis(samples @ r, max_band)  # rows: Y(R⁻¹ ω) since (R⁻¹ω)ᵀ = ωᵀ R
    for l in range(max_band + 1):  # noqa: E741
        s = slice(l * l, (l + 1) ** 2)
        # Y_l(ω) D_l = Y_l(R⁻¹ω)  →  D_l = lstsq(Y_l(ω), Y_l(R⁻¹ω)); f' = D_l f.
        solution, *_ = np.linalg.lstsq(basis[:, s], basis_rotated[:, s], rcond=None)
        out[s, s] = solution
    return out


def rotate_sh(coefficients: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Rotate SH coefficients (..., K, C) so the function becomes f(R⁻¹ω)."""
    k = coefficients.shape[-2]
    d = sh_rotation_matrix(rotation, int(round(sqrt(k))) - 1)
    return np.einsum("ij,...jc->...ic", d, coefficients)
