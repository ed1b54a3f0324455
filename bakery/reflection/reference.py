"""Ground truth: brute-force integration of the reflection equation over a full-resolution quadrature.

E0(v, n, α) = Σ_t L(l_t) f_DV(v, n, l_t, α) ⟨l_t, n⟩ Ω_t          ([SHExp] Eq. 6, 8)
E1(v, n, α) = Σ_t L(l_t) f_DV(v, n, l_t, α) (1 − v·h_t)⁵ ⟨l_t, n⟩ Ω_t   ([SHExp] Eq. 7)
E = F0 E0 + (1 − F0) E1                                                ([SHExp] Eq. 5, exact for Schlick F)

Batched over M (v, n, α) rows: per chunk of rows the cosines n·l and v·l are two matrix products (m, 3)·(3, T),
the half-vector cosines follow in closed form, and the radiance sum is one matrix product (m, T)·(T, C).

Derivation (half-vector cosines without forming h)
    |v + l|² = 2 + 2 v·l, so v·h = √((1 + v·l)/2) and n·h = (n·v + n·l) / (2 v·h).

Notation
    M rows (v, n, α); T quadrature samples (texel directions l_t, exact solid angles Ω_t); C channels.

References
    [SHExp] Silvennoinen et al., HPG 2025 (seed 000).
"""

from __future__ import annotations

import numpy as np

from bakery.brdf.ggx import ggx_distribution, smith_visibility_correlated
from bakery.sphere.grid import SphericalSamples

#: Elements (rows × samples) per chunk; bounds the temporary memory at ~100 MB in float32.
_CHUNK_ELEMENTS = 4_000_000
#: Tile of the float32 path (rows × texels = 256k elements, 1 MB per temporary).
_TILE_ROWS = 32
_TILE_TEXELS = 8192


def _prepare_rows(view: np.ndarray, normal: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v = np.asarray(view, dtype=np.float64).reshape(-1, 3)
    n = np.asarray(normal, dtype=np.float64).reshape(-1, 3)
    a = np.broadcast_to(np.asarray(alpha, dtype=np.float64).reshape(-1), (v.shape[0],))
    if n.shape != v.shape:
        raise ValueError(f"view {v.shape} and normal {n.shape} must both be (M, 3)")
    if np.any(~(a > 0)):
        raise ValueError("alpha must be > 0")
    return v, n, a


def fdv_cosine_weights(
    directions: np.ndarray,
    solid_angles: np.ndarray,
    view: np.ndarray,
    normal: np.ndarray,
    alpha: np.ndarray,
    tail: bool = False,
    dtype: type = np.float64,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Quadrature weights w[m, t] = f_DV(v_m, n_m, l_t, α_m) ⟨l_t, n_m⟩ Ω_t ([SHExp] Eq. 6, 8).

    Args:
        directions: (T, 3) sample directions l_t; solid_angles: (T,) Ω_t.
        view, normal: (M, 3) unit vectors (view towards the viewer); alpha: (M,) GGX α.
        tail: also return the Fresnel-tail weights w[m, t] (1 − v·h)⁵ ([SHExp] Eq. 7).
    Returns:
        (M, T) weights (and (M, T) tail weights) in ``dtype``.
    """
    v, n, a = _prepare_rows(view, normal, alpha)
    l = np.asarray(directions, dtype=np.float64)  # noqa: E741 - paper symbol
    # unit l: n·h below assumes |l| = 1, and stored float32 light directions are off by ~1e-8, which where the
    # light faces the view (1 + v·l → 0, grazing highlights) moved n·h enough to change D 2-10× at α = 0.05
    l = l / np.maximum(np.linalg.norm(l, axis=1, keepdims=True), 1e-300)  # noqa: E741
    omega = np.asarray(solid_angles, dtype=np.float64)
    nl = n @ l.T
    vl = v @ l.T
    nv = np.sum(n * v, axis=1)[:, None]
    vh = np.sqrt(np.clip(0.5 * (1.0 + vl), 0.0, 1.0))
    nh = (nv + nl) / np.maximum(2.0 * vh, 1e-12)
    a_col = a[:, None]
    w = ggx_distribution(nh, a_col) * smith_visibility_correlated(nv, nl, a_col) * np.maximum(nl, 0.0) * omega
    w = w.astype(dtype, copy=False)
    if tail:
        return w, (w * (1.0 - vh) ** 5).astype(dtype, copy=False)
    return w


def _weights_float32(
    l_t: np.ndarray, omega: np.ndarray, v: np.ndarray, n: np.ndarray, a: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Lean float32 version of :func:`fdv_cosine_weights` with ``tail=True`` (same formulas, in-place
    operations; the hot loop of the reference). l_t (3, T) float32; v, n (m, 3); a (m,) → (m, T) twice.

    With c = n·l, e = v·l, a2 = α²: (n·h)² = (n·v + c)² / (2 (1 + e)), D = a2 / (π ((n·h)²(a2 − 1) + 1)²),
    V = ½ / (c √((n·v)²(1−a2)+a2) + (n·v) √(c²(1−a2)+a2)), w = D V c Ω (c > 0), tail = (1 − √((1+e)/2))⁵.
    """
    f32 = np.float32
    nl = n.astype(f32) @ l_t
    vl = v.astype(f32) @ l_t
    nv = np.sum(n * v, axis=1).astype(f32)[:, None]
    a2 = (a * a).astype(f32)[:, None]
    np.maximum(nl, 0.0, out=nl)
    # (n·h)²
    nh2 = nv + nl
    nh2 *= nh2
    one_e = vl + f32(1.0)
    np.maximum(one_e, f32(1e-12), out=one_e)
    nh2 /= one_e
    nh2 *= f32(0.5)
    # D denominator: π ((n·h)²(a2−1)+1)²
    nh2 *= a2 - f32(1.0)
    nh2 += f32(1.0)
    nh2 *= nh2
    nh2 *= f32(np.pi)
    # V denominator: c √(nv²(1−a2)+a2) + nv √(c²(1−a2)+a2)
    gv = np.sqrt(nv * nv * (f32(1.0) - a2) + a2)
    gl = nl * nl
    gl *= f32(1.0) - a2
    gl += a2
    np.sqrt(gl, out=gl)
    gl *= np.maximum(nv, f32(0.0))
    gl += nl * gv
    # w = D V c Ω = a2 · ½ c Ω / (π(...)² · (V-denominator))
    gl *= nh2
    np.maximum(gl, f32(1e-30), out=gl)
    w = nl * (f32(0.5) * omega.astype(f32))
    w *= a2
    w /= gl
    if np.any(nv <= 0):
        w *= (nv > 0).astype(f32)
    # Fresnel tail (1 − v·h)⁵, v·h = √((1 + e)/2)
    one_e *= f32(0.5)
    np.sqrt(one_e, out=one_e)
    np.subtract(f32(1.0), one_e, out=one_e)
    np.maximum(one_e, f32(0.0), out=one_e)
    t2 = one_e * one_e
    t2 *= t2
    t2 *= one_e
    t2 *= w
    return w, t2


def integrate_reflection(
    samples: SphericalSamples,
    view: np.ndarray,
    normal: np.ndarray,
    alpha: np.ndarray,
    dtype: type = np.float32,
) -> tuple[np.ndarray, np.ndarray]:
    """Base and Fresnel-tail reflectance (E0, E1), each (M, C), by brute force over ``samples``.

    Rows are processed in chunks so that the temporary (m, T) arrays stay ~100 MB; ``dtype`` sets the precision of
    the weight matrices (accumulation of the radiance sum is in float64 for float64 input, else float32).
    """
    v, n, a = _prepare_rows(view, normal, alpha)
    m_total = v.shape[0]
    t = samples.count
    radiance = np.asarray(samples.radiance, dtype=dtype)
    e0 = np.empty((m_total, radiance.shape[1]))
    e1 = np.empty_like(e0)
    if dtype != np.float32:
        chunk = max(1, _CHUNK_ELEMENTS // max(t, 1))
        for start in range(0, m_total, chunk):
            s = slice(start, start + chunk)
            w0, w1 = fdv_cosine_weights(samples.directions, samples.solid_angles, v[s], n[s], a[s], tail=True)
            e0[s] = w0 @ radiance
            e1[s] = w1 @ radiance
        return e0, e1
    # float32 hot path: tiles of (rows × texels) small enough to stay in cache.
    l_t = np.ascontiguousarray(np.asarray(samples.directions, dtype=np.float32).T)
    omega = np.asarray(samples.solid_angles, dtype=np.float32)
    e0[:] = 0.0
    e1[:] = 0.0
    for t0 in range(0, t, _TILE_TEXELS):
        tt = slice(t0, t0 + _TILE_TEXELS)
        for start in range(0, m_total, _TILE_ROWS):
            s = slice(start, start + _TILE_ROWS)
            w0, w1 = _weights_float32(l_t[:, tt], omega[tt], v[s], n[s], a[s])
            e0[s] += w0 @ radiance[tt]
            e1[s] += w1 @ radiance[tt]
    return e0, e1


def reflected_radiance(e0: np.ndarray, e1: np.ndarray, f0: np.ndarray) -> np.ndarray:
    """E = F0·E0 + (1 − F0)·E1 ([SHExp] Eq. 5); F0 broadcasts against (..., C)."""
    f0 = np.asarray(f0, dtype=np.float64)
    if f0.ndim == 1 and e0.ndim == 2 and f0.shape[0] == e0.shape[0]:
        f0 = f0[:, None]
    return f0 * e0 + (1.0 - f0) * e1
