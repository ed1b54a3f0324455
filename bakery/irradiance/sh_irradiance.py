"""Irradiance of radiance SH (bands ≤ 2) as a function of the normal, and its quadratic-polynomial form.

Notation
    f        radiance SH coefficients (P, K, C), K = 4 (SH2) or 9 (SH3), convention of :mod:`bakery.conventions`
    A_l      clamped-cosine band factors π, 2π/3, π/4 ([RH01] Eq. 8; seed 003 App. A)
    E(n)     irradiance = Σ_lm A_l f_lm Y_lm(n)

Derivation (quadratic form)
    For l ≤ 2 every Y_lm is a polynomial of degree ≤ 2 in n, so on |n| = 1
        E(n) = c + bᵀn + nᵀ M n
    with (c2 = √(15/4π), c20 = √(5/16π), c22 = √(15/16π), c1 = √(3/4π), g_lm = A_l f_lm):
        c = A_0 f_00/(2√π) − c20 g_20
        b = c1 (−g_11, −g_1−1, g_10)
        M = [[ c22 g_22,   c2 g_2−2/2, −c2 g_21/2],
             [ c2 g_2−2/2, −c22 g_22,  −c2 g_2−1/2],
             [−c2 g_21/2,  −c2 g_2−1/2, 3 c20 g_20]]
    (ZH3 paper Eq. 4–5 for the polynomials.)
"""

from __future__ import annotations

from math import pi, sqrt

import numpy as np

from bakery.sh.basis import evaluate_sh_basis
from bakery.sh.convolution import cosine_lobe_band_factors, irradiance_sh_from_radiance_sh

C1 = sqrt(3.0 / (4.0 * pi))
C2 = sqrt(15.0 / (4.0 * pi))
C20 = sqrt(5.0 / (16.0 * pi))
C22 = sqrt(15.0 / (16.0 * pi))


def evaluate_sh_irradiance(radiance_sh: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance (P, N, C) at unit normals (N, 3) from radiance SH (P, K, C), K ∈ {1, 4, 9, …}."""
    irradiance_sh = irradiance_sh_from_radiance_sh(radiance_sh)
    k = radiance_sh.shape[-2]
    basis = evaluate_sh_basis(normals, int(round(sqrt(k))) - 1)
    return np.einsum("nk,pkc->pnc", basis, irradiance_sh)


def irradiance_quadratic_form(radiance_sh: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(c (P, C), b (P, C, 3), M (P, C, 3, 3)) with E(n) = c + bᵀn + nᵀMn on the unit sphere (module doc)."""
    f = np.asarray(radiance_sh, dtype=np.float64)
    p, k, ch = f.shape
    if k < 9:
        f = np.concatenate([f, np.zeros((p, 9 - k, ch))], axis=1)
    a = cosine_lobe_band_factors(2)
    g = f * a[[0, 1, 1, 1, 2, 2, 2, 2, 2]][None, :, None]
    c = g[:, 0] / (2.0 * sqrt(pi)) - C20 * g[:, 6]
    b = C1 * np.stack([-g[:, 3], -g[:, 1], g[:, 2]], axis=-1)
    m = np.zeros((p, ch, 3, 3))
    m[..., 0, 0] = C22 * g[:, 8]
    m[..., 1, 1] = -C22 * g[:, 8]
    m[..., 2, 2] = 3.0 * C20 * g[:, 6]
    m[..., 0, 1] = m[..., 1, 0] = C2 * g[:, 4] / 2.0
    m[..., 1, 2] = m[..., 2, 1] = -C2 * g[:, 5] / 2.0
    m[..., 0, 2] = m[..., 2, 0] = -C2 * g[:, 7] / 2.0
    return c, b, m


def minimum_on_sphere(c: np.ndarray, b: np.ndarray, m: np.ndarray, iterations: int = 80) -> np.ndarray:
    """Exact minimum over |n| = 1 of c + bᵀn + nᵀMn, batched: c (...), b (..., 3), M (..., 3, 3) symmetric → (...).

    Derivation (trust-region subproblem on the sphere). With M = QΛQᵀ (λ₀ ≤ λ₁ ≤ λ₂) and β = Qᵀb, stationarity
    gives y_i = β_i / (2(μ − λ_i)) for the multiplier μ; the global minimum has μ ≤ λ₀ and Σ y_i² = 1. The
    left side grows monotonically on μ ∈ [λ₀ − |β|/2, λ₀), so μ is found by bisection. In the "hard case"
    (β₀ ≈ 0) μ = λ₀ and y₀ = ±√(1 − Σ_{i>0} y_i²). The result is checked against the six eigen-directions.
    """
    lam, q = np.linalg.eigh(m)
    beta = np.einsum("...ji,...j->...i", q, b)
    lo = lam[..., 0] - 0.5 * np.linalg.norm(beta, axis=-1) - 1e-300
    hi = lam[..., 0].copy()
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        gap = lam - mid[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            phi = np.sum(np.where(gap > 0, beta**2 / (4.0 * gap**2), np.inf), axis=-1)
        too_far = phi > 1.0
        hi = np.where(too_far, mid, hi)
        lo = np.where(too_far, lo, mid)
    mu = lo
    gap = lam - mu[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        y = np.where(gap > 1e-300, -beta / (2.0 * gap), 0.0)
    rest = np.sum(y[..., 1:] ** 2, axis=-1)
    y0 = -np.sign(np.where(beta[..., 0] == 0, 1.0, beta[..., 0])) * np.sqrt(np.clip(1.0 - rest, 0.0, None))
    y = np.concatenate([y0[..., None], y[..., 1:]], axis=-1)
    y = y / np.maximum(np.linalg.norm(y, axis=-1, keepdims=True), 1e-300)
    value = np.sum(lam * y * y + beta * y, axis=-1)
    # Safety net: the six eigen-directions ±q_i.
    for sign in (1.0, -1.0):
        value = np.minimum(value, np.min(lam + sign * beta, axis=-1))
    return c + value


def minimum_sh_irradiance(radiance_sh: np.ndarray) -> np.ndarray:
    """Exact minimum over all normals of the irradiance of radiance SH (bands ≤ 2): (P, K, C) → (P, C)."""
    c, b, m = irradiance_quadratic_form(radiance_sh)
    return minimum_on_sphere(c, b, m)
