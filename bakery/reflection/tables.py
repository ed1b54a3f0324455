"""Tables shared by all probes: the split-sum DFG scale/bias and the Fresnel-tail ratio, over (n·v, α).

Split-sum DFG ([Kar13]; [SHExp] Sec. 3.2): with F = F0 + (1 − F0) F_c, F_c = (1 − v·h)⁵,
    ∫ f ⟨l, n⟩ dω = F0 · A(n·v, α) + B(n·v, α),
    A = ∫ f_DV (1 − F_c) ⟨l, n⟩ dω   (scale),      B = ∫ f_DV F_c ⟨l, n⟩ dω   (bias).
Base albedo of f_DV is A + B (≤ 1; < 1 at high α from single-scattering energy loss).

Fresnel tail ([SHExp] Eq. 15): E1 ≈ E0 · τ(n·v, α). The paper writes τ = ∫ f_DV F_c ⟨l, n⟩ dω = B, derived "by
assuming a constant environment light L approximated by E0". Under a constant environment L, E0 = L (A + B) and
E1 = L·B exactly, so the consistent ratio is τ = B / (A + B); we store this ratio (it makes the white-furnace case
exact; the two differ by the factor A + B, i.e. only where the base albedo is below 1). ``tail_mode="paper"``
builds the literal Eq. 15 table instead, for comparison.

Quadrature (deterministic, importance-mapped)
    h on a K×K grid of (u1, u2) (Gauss–Legendre in u1, midpoint in u2) pushed through the visible-normal sampler ([Hei18], pdf_h = D_v(h) =
    G1(v)(v·h)D(h)/(n·v)); with dω_l = 4 (v·h) dω_h ([WMLT07] Eq. 14) the integrand f_DV ⟨l, n⟩ / pdf_l becomes
    4 V (n·l)(n·v) / G1(v) = G2/G1 — smooth, so the rule converges fast (K = 64: ~1e-3 absolute or better).

Layout (what the store holds; engine-style, row = α, column = n·v)
    texel (i, j) of an (Nα, Nv) table sits at α_i = (i + ½)/Nα, (n·v)_j = (j + ½)/Nv; lookups clamp to the texel
    centres and interpolate bilinearly (like a GPU with clamp-to-edge addressing).

References
    [Kar13] Karis, "Real Shading in Unreal Engine 4", SIGGRAPH 2013 course notes.
    [SHExp] Silvennoinen et al., HPG 2025 (seed 000).
    [WMLT07] Walter et al., EGSR 2007.
    [Hei18] Heitz, JCGT 2018 (visible-normal sampling).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from bakery.brdf.ggx import smith_g1, smith_visibility_correlated
from bakery.brdf.sampling import sample_ggx_vndf


@dataclass(frozen=True)
class DFGTables:
    """dfg: (Nα, Nv, 2) float32 [A scale, B bias]; fresnel_tail: (Nα, Nv) float32 τ; axes as in the module doc."""

    dfg: np.ndarray
    fresnel_tail: np.ndarray

    @property
    def albedo(self) -> np.ndarray:
        """Base albedo A + B (Nα, Nv)."""
        return self.dfg[..., 0] + self.dfg[..., 1]


def integrate_dfg(n_dot_v: np.ndarray, alpha: np.ndarray, samples_per_axis: int = 64) -> np.ndarray:
    """(A, B) of the module doc at broadcast (n·v, α) pairs → (..., 2), by the importance-mapped quadrature."""
    nv = np.clip(np.asarray(n_dot_v, dtype=np.float64), 1e-4, 1.0)
    a = np.asarray(alpha, dtype=np.float64)
    nv, a = np.broadcast_arrays(nv, a)
    shape = nv.shape
    nv = nv.reshape(-1, 1)
    a = a.reshape(-1, 1)
    k = samples_per_axis
    # Gauss–Legendre nodes in u1 (radial; the integrand is smooth in u1 away from the horizon) and the midpoint
    # rule in the periodic u2 (exact for trigonometric polynomials).
    x, wx = np.polynomial.legendre.leggauss(k)
    u1, u2 = np.meshgrid(0.5 * (x + 1.0), (np.arange(k) + 0.5) / k, indexing="ij")
    wq = np.broadcast_to(0.5 * wx[:, None] / k, u1.shape).reshape(1, -1)
    u1, u2 = u1.reshape(1, -1), u2.reshape(1, -1)
    out = np.empty((nv.shape[0], 2))
    chunk = max(1, 2_000_000 // (k * k))
    for s in range(0, nv.shape[0], chunk):
        sl = slice(s, s + chunk)
        v = np.concatenate([np.sqrt(1.0 - nv[sl] ** 2), np.zeros_like(nv[sl]), nv[sl]], axis=1)[:, None, :]
        h = sample_ggx_vndf(v, u1, u2, a[sl])  # (m, K², 3), local frame
        vh = np.sum(v * h, axis=-1)
        l = 2.0 * vh[..., None] * h - v  # noqa: E741
        nl = l[..., 2]
        # f_DV ⟨l,n⟩ / pdf_l = 4 V (n·l)(n·v) / G1(v)  (module doc)
        weight = np.where(
            (nl > 0) & (vh > 0),
            4.0 * smith_visibility_correlated(nv[sl], nl, a[sl]) * nl * nv[sl] / smith_g1(nv[sl], a[sl]),
            0.0,
        )
        fc = (1.0 - np.clip(vh, 0.0, 1.0)) ** 5
        out[sl, 0] = np.sum(wq * weight * (1.0 - fc), axis=1)
        out[sl, 1] = np.sum(wq * weight * fc, axis=1)
    return out.reshape(shape + (2,))


class OperatorCache:
    """Where environment-independent operators (DFG tables, the SH-exponential W) live between processes. The math
    does no I/O: by default they are cached in memory only; the encoding layer installs ``load(key) -> array |
    None`` / ``save(key, array) -> array`` backed by memory-mapped files (:mod:`bakery.operator_cache`), so every
    worker process of a bake shares one copy instead of rebuilding it."""

    load = staticmethod(lambda key: None)
    save = staticmethod(lambda key, array: array)


@lru_cache(maxsize=8)
def compute_dfg_tables(size: int = 64, samples_per_axis: int = 64, tail_mode: str = "ratio") -> DFGTables:
    """Build the DFG and Fresnel-tail tables (Nα = Nv = ``size``); cached. ``tail_mode``: "ratio" or "paper"."""
    key = f"dfg-v1-{size}-{samples_per_axis}"
    ab = OperatorCache.load(key)
    if ab is None:
        centres = (np.arange(size) + 0.5) / size
        alpha, nv = np.meshgrid(centres, centres, indexing="ij")
        ab = OperatorCache.save(key, integrate_dfg(nv, alpha, samples_per_axis))
    ab = np.asarray(ab)
    if tail_mode == "ratio":
        tail = ab[..., 1] / np.maximum(ab[..., 0] + ab[..., 1], 1e-12)  # τ = B/(A+B), see module doc
    elif tail_mode == "paper":
        tail = ab[..., 1]  # [SHExp] Eq. 15 literally
    else:
        raise ValueError(f"unknown tail_mode {tail_mode!r}")
    dfg = ab.astype(np.float32)
    dfg.setflags(write=False)
    tail = tail.astype(np.float32)
    tail.setflags(write=False)
    return DFGTables(dfg=dfg, fresnel_tail=tail)


def lookup_table(table: np.ndarray, n_dot_v: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Bilinear, clamp-to-edge lookup of an (Nα, Nv[, C]) table at (n·v, α) (...,) → (...[, C])."""
    table = np.asarray(table, dtype=np.float64)
    n_a, n_v = table.shape[:2]
    x = np.clip(np.asarray(n_dot_v, dtype=np.float64) * n_v - 0.5, 0.0, n_v - 1.0)
    y = np.clip(np.asarray(alpha, dtype=np.float64) * n_a - 0.5, 0.0, n_a - 1.0)
    x, y = np.broadcast_arrays(x, y)
    x0 = np.minimum(np.floor(x).astype(np.int64), n_v - 1)
    y0 = np.minimum(np.floor(y).astype(np.int64), n_a - 1)
    x1 = np.minimum(x0 + 1, n_v - 1)
    y1 = np.minimum(y0 + 1, n_a - 1)
    fx = x - x0
    fy = y - y0
    if table.ndim == 3:
        fx = fx[..., None]
        fy = fy[..., None]
    top = table[y0, x0] * (1 - fx) + table[y0, x1] * fx
    bottom = table[y1, x0] * (1 - fx) + table[y1, x1] * fx
    return top * (1 - fy) + bottom * fy
