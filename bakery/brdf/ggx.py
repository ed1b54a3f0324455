"""Cook-Torrance / GGX terms of seed 000 (Silvennoinen et al., HPG 2025), Eq. 2–8.

Notation (paper symbols)
    n, v, l, h   normal, view (towards the viewer), light, half vector h = (v + l)/|v + l|
    α            GGX roughness (not perceptual; α = r²)
    D(h, α)      GGX normal distribution, ∫ D(h)(n·h) dω_h = 1 over the hemisphere
    V(v, n, l)   normalised visibility G / (4 (n·v)(n·l)) (Eq. 3), height-correlated Smith G
    F(F0, v, h)  Schlick Fresnel (Eq. 4)

All functions take cosines (arrays broadcast together) and return float64 arrays of the broadcast shape; values
outside the hemisphere (cos ≤ 0) give 0, never NaN.

References
    [SHExp] Silvennoinen, Sloan, Iwanicki, Nowrouzezahrai, "Spherical Harmonic Exponentials for Efficient Glossy
        Reflections", HPG 2025 (seed 000).
    [WMLT07] Walter et al., "Microfacet Models for Refraction through Rough Surfaces", EGSR 2007 (GGX D, Λ).
    [Hei14] Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 2014 (Eq. 99:
        height-correlated G2 = 1 / (1 + Λ(v) + Λ(l))).
    [Sch94] Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", 1994.
"""

from __future__ import annotations

import numpy as np

_TINY = 1e-12


def _check_alpha(alpha: np.ndarray) -> np.ndarray:
    a = np.asarray(alpha, dtype=np.float64)
    if np.any(~(a > 0.0)):
        raise ValueError("GGX alpha must be > 0 (use a small value such as 1e-4 for a mirror)")
    return a


def ggx_distribution(n_dot_h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """GGX D(h, α) = α² / (π ((n·h)² (α² − 1) + 1)²) for n·h > 0, else 0 ([WMLT07] Eq. 33; [SHExp] Eq. 2)."""
    a2 = _check_alpha(alpha) ** 2
    c = np.asarray(n_dot_h, dtype=np.float64)
    denom = (c * c) * (a2 - 1.0) + 1.0
    return np.where(c > 0.0, a2 / (np.pi * denom * denom), 0.0)


def ggx_lambda(n_dot_w: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Smith Λ(w) = (−1 + √(1 + α² tan²θ)) / 2 for GGX ([Hei14] Eq. 72)."""
    a2 = _check_alpha(alpha) ** 2
    c = np.clip(np.asarray(n_dot_w, dtype=np.float64), _TINY, 1.0)
    tan2 = (1.0 - c * c) / (c * c)
    return 0.5 * (np.sqrt(1.0 + a2 * tan2) - 1.0)


def smith_g1(n_dot_w: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Masking G1(w) = 1 / (1 + Λ(w)) for n·w > 0, else 0 ([Hei14] Eq. 43)."""
    c = np.asarray(n_dot_w, dtype=np.float64)
    return np.where(c > 0.0, 1.0 / (1.0 + ggx_lambda(c, alpha)), 0.0)


def smith_visibility_correlated(n_dot_v: np.ndarray, n_dot_l: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """V = G2 / (4 (n·v)(n·l)) with height-correlated G2 ([SHExp] Eq. 3; [Hei14] Eq. 99).

    Closed form (Lagarde & de Rousiers 2014): V = ½ / ((n·l)√((n·v)²(1−α²)+α²) + (n·v)√((n·l)²(1−α²)+α²)).
    Zero where n·v ≤ 0 or n·l ≤ 0.
    """
    a2 = _check_alpha(alpha) ** 2
    nv = np.asarray(n_dot_v, dtype=np.float64)
    nl = np.asarray(n_dot_l, dtype=np.float64)
    nvc = np.maximum(nv, 0.0)
    nlc = np.maximum(nl, 0.0)
    gv = nlc * np.sqrt(nvc * nvc * (1.0 - a2) + a2)
    gl = nvc * np.sqrt(nlc * nlc * (1.0 - a2) + a2)
    return np.where((nv > 0.0) & (nl > 0.0), 0.5 / np.maximum(gv + gl, _TINY), 0.0)


def fresnel_schlick(f0: np.ndarray, v_dot_h: np.ndarray) -> np.ndarray:
    """Schlick F = F0 + (1 − F0)(1 − v·h)⁵ ([SHExp] Eq. 4; [Sch94])."""
    c = np.clip(np.asarray(v_dot_h, dtype=np.float64), 0.0, 1.0)
    return np.asarray(f0, dtype=np.float64) + (1.0 - np.asarray(f0, dtype=np.float64)) * (1.0 - c) ** 5


def reflect(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Mirror direction r = 2(n·v)n − v of v (towards the viewer) about n: (..., 3) → (..., 3)."""
    v = np.asarray(v, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    return 2.0 * np.sum(n * v, axis=-1, keepdims=True) * n - v
