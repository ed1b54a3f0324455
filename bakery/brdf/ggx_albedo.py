"""Directional albedo of the GGX lobe the capture shades, tabulated over (n·v, α): what MaterialX's layering and
energy compensation need (:mod:`bakery.capture.bsdf`, "MaterialX layering").

With Schlick's F = F0 + (F90 − F0)(1 − v·h)⁵ and f_DV = D·G2/(4 (n·v)(n·l)) (GGX D, height-correlated Smith G2,
:mod:`bakery.brdf.ggx`),

    E(μ, α; F0, F90) = ∫ F·f_DV (n·l) dl = F0·A(μ, α) + F90·B(μ, α),
    A = ∫ f_DV (1 − (1 − v·h)⁵)(n·l) dl,   B = ∫ f_DV (1 − v·h)⁵ (n·l) dl,   μ = n·v,

and E_ss = A + B is the white lobe's single-scattering albedo (F ≡ 1). MaterialX's pbrlib writes the same split,
``mx_ggx_dir_albedo(NdotV, alpha, F0, F90)`` = F0·AB.x + F90·AB.y, computed there by a rational fit
(``mx_ggx_dir_albedo_analytic``), a baked table or a 64-sample Monte Carlo estimate; here A and B are integrated for
the capture's own lobe, so a lobe's compensation 1 + F·(1 − E_ss)/E_ss makes a white conductor's albedo 1 to the
table's accuracy.

Quadrature (as :func:`bakery.reflection.tables.integrate_dfg`): half vectors from the visible-normal sampler
([Hei18]) on a Gauss–Legendre × midpoint grid of its uniform numbers, where f_DV (n·l)/pdf_l = G2/G1(v); the lobe
is symmetric about the plane of v and n, so half the azimuths are enough. Table: nodes at √μ = j/32 and √α =
i/32 (α clamped to ≥ 10⁻³ as the capture clamps it, μ = 0 evaluated at 10⁻⁶), looked up bilinearly in (√μ, √α):
E_ss within 2·10⁻³ of a converged quadrature for μ ≥ 0.025, A and B within 3·10⁻³ each (up to 2·10⁻² for
near-mirror lobes, α < 0.02, closer than μ = 0.025 to grazing; tests/capture/test_mtlx_layering.py). MaterialX's
rational fit is up to 0.064 from the same integral (near-mirror lobes at grazing views; 0.034 for roughness ≥ 0.3,
0.011 at normal incidence), over μ ≥ 0.05. Built once per process on first use (≈ 0.1 s).

References
    [Hei18] Heitz, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4), 2018.
    [Tur19] Turquin, "Practical multiple scattering compensation for microfacet models", 2019.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from bakery.brdf.ggx import smith_g1, smith_visibility_correlated
from bakery.brdf.sampling import sample_ggx_vndf

#: Table intervals along √(n·v) and √α (nodes 0 … TABLE_STEPS)
TABLE_STEPS = 32
#: Quadrature nodes per axis of the sampler's (u1, half of u2) square
_NODES = 32
#: The capture's floor on α (bakery.capture.bsdf.MIN_ALPHA) and on n·v
_MIN_ALPHA = 1e-3
_MIN_NV = 1e-6


def integrate(n_dot_v: np.ndarray, alpha: np.ndarray, nodes: int = _NODES) -> np.ndarray:
    """(A, B) (..., 2) of the module doc at broadcast (n·v, α) pairs, by the visible-normal quadrature with
    ``nodes`` Gauss–Legendre nodes in u1 and ``nodes``/2 midpoints in the half range of u2 (float64)."""
    nv = np.clip(np.asarray(n_dot_v, dtype=np.float64), _MIN_NV, 1.0)
    a = np.asarray(alpha, dtype=np.float64)
    nv, a = np.broadcast_arrays(nv, a)
    shape = nv.shape
    nv, a = nv.reshape(-1, 1), a.reshape(-1, 1)
    x, wx = np.polynomial.legendre.leggauss(nodes)
    half = max(nodes // 2, 1)
    # φ = 2π·u2 ∈ (−π/2, π/2): the mirror image in the plane of v (φ → π − φ) has the same integrand
    u1, u2 = np.meshgrid(0.5 * (x + 1.0), -0.25 + (np.arange(half) + 0.5) / (2 * half), indexing="ij")
    weight = np.broadcast_to(0.5 * wx[:, None] / half, u1.shape).reshape(1, -1)
    u1, u2 = u1.reshape(1, -1), u2.reshape(1, -1)
    out = np.empty((nv.shape[0], 2))
    chunk = max(1, 1_000_000 // u1.size)
    for s in range(0, nv.shape[0], chunk):
        part = slice(s, s + chunk)
        c, al = nv[part], a[part]
        v = np.concatenate([np.sqrt(1.0 - c * c), np.zeros_like(c), c], axis=1)[:, None, :]
        h = sample_ggx_vndf(v, u1, u2, al)
        vh = np.sum(v * h, axis=-1)
        nl = 2.0 * vh * h[..., 2] - c  # (2 (v·h) h − v)·n
        ratio = np.where((nl > 0) & (vh > 0), 4.0 * smith_visibility_correlated(c, np.maximum(nl, 1e-12), al)
                         * nl * c / smith_g1(c, al), 0.0)  # f_DV (n·l)/pdf_l = G2/G1(v)
        tail = (1.0 - np.clip(vh, 0.0, 1.0)) ** 5
        out[part, 0] = np.sum(weight * ratio * (1.0 - tail), axis=1)
        out[part, 1] = np.sum(weight * ratio * tail, axis=1)
    return out.reshape(shape + (2,))


@lru_cache(maxsize=1)
def albedo_table() -> np.ndarray:
    """(2, N, N) float64: A and B (module doc) at √α = i/(N − 1) (rows) and √(n·v) = j/(N − 1) (columns),
    N = TABLE_STEPS + 1."""
    grid = np.arange(TABLE_STEPS + 1) / TABLE_STEPS
    root_alpha, root_nv = np.meshgrid(grid, grid, indexing="ij")
    ab = integrate(root_nv * root_nv, np.maximum(root_alpha * root_alpha, _MIN_ALPHA))
    table = np.ascontiguousarray(np.moveaxis(ab, -1, 0))
    table.setflags(write=False)
    return table


@lru_cache(maxsize=4)
def _flat(dtype: np.dtype) -> np.ndarray:
    return np.ascontiguousarray(albedo_table().reshape(2, -1), dtype=dtype)


def lookup(n_dot_v: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A and B (module doc) at n·v and α (broadcast arrays), bilinear in (√(n·v), √α), in n·v's float dtype."""
    nv = np.asarray(n_dot_v)
    dtype = nv.dtype if nv.dtype in (np.float32, np.float64) else np.dtype(np.float64)
    steps = dtype.type(TABLE_STEPS)
    x = np.sqrt(np.clip(nv, 0, 1).astype(dtype, copy=False)) * steps
    y = np.sqrt(np.clip(np.asarray(alpha, dtype=dtype), 0, 1)) * steps
    x, y = np.broadcast_arrays(x, y)
    j = np.minimum(x.astype(np.int64), TABLE_STEPS - 1)
    i = np.minimum(y.astype(np.int64), TABLE_STEPS - 1)
    fx, fy = x - j.astype(dtype), y - i.astype(dtype)
    k = i * (TABLE_STEPS + 1) + j
    out = []
    for row in _flat(dtype):
        t00, t01 = np.take(row, k), np.take(row, k + 1)
        t10, t11 = np.take(row, k + TABLE_STEPS + 1), np.take(row, k + TABLE_STEPS + 2)
        top = t00 + (t01 - t00) * fx
        out.append(top + (t10 + (t11 - t10) * fx - top) * fy)
    return out[0], out[1]
