"""Ground truth: brute-force integration of the reflection equation over a full-resolution quadrature.

E0(v, n, α) = Σ_t L(l_t) f_DV(v, n, l_t, α) ⟨l_t, n⟩ Ω_t          ([SHExp] Eq. 6, 8)
E1(v, n, α) = Σ_t L(l_t) f_DV(v, n, l_t, α) (1 − v·h_t)⁵ ⟨l_t, n⟩ Ω_t   ([SHExp] Eq. 7)
E = F0 E0 + (1 − F0) E1                                                ([SHExp] Eq. 5, exact for Schlick F)

Batched over M (v, n, α) rows: per chunk of rows the cosines n·l and v·l are two matrix products (m, 3)·(3, T),
the half-vector cosines follow in closed form, and the radiance sum is one matrix product (m, T)·(T, C).

Derivation (half-vector cosines without forming h)
    |v + l|² = 2 + 2 v·l, so v·h = √((1 + v·l)/2) and n·h = (n·v + n·l) / (2 v·h).

Converged reference of a piecewise-constant image (:func:`converged_reflection`)
    An environment image is texels of constant radiance over their exact footprints, and the ground truth is the
    integral of that function, E0 = Σ_t L_t W_t with W_t = ∫_texel f_DV⟨n, l⟩ dl (E1 likewise), not the
    texel-centre quadrature above. The centres are right where the integrand is smooth across a texel and wrong
    where the GGX lobe is narrow on the texel's scale: on coarse images (a uniform 64 × 32 sky at α = 0.02 gave E0
    off by up to 3.1 against an albedo of ~1), and at grazing views, where the lobe in l is 2(v·h)α wide across
    the plane of incidence (a uniform 1024 × 512 sky: 0.28 at n·v = 0.05, α = 0.02). So per row:
    * every texel's centre term in float32 tiles (as :func:`integrate_reflection`);
    * for each (row, texel) pair where the integrand varies on the texel's scale the centre term is replaced by
      W_t integrated over a quadtree of the texel (:class:`TexelRadiance` maps in-texel coordinates to directions
      and solid-angle density): a cell is split while its sides e/√2 (e its longest chord) exceed
      (v·h)·max(α/8, θ_h/8), i.e. 1/8 of the integrand's scale there — α at the lobe's peak, the distance
      θ_h = ∠(n, h) (at the cell's nearest point) in the tail, compressed by v·h = √((1 + v·l)/2) ≥ VH_FLOOR
      across the plane of incidence —, and while it straddles the horizon of n (the kink of ⟨n, l⟩₊) with
      e > 1/16; each leaf is integrated by the 2 × 2 Gauss–Legendre rule, a texel's solid angles scaled to its
      exact Ω_t. Measured against the independent quadratures of the tests: the white furnace within 5e-4
      (4.6e-4; 1/16 and midpoint leaves, version 2: 4.3e-4; 1/16 and Gauss: 4e-5; 1/8 with midpoint leaves in the
      tail fails, 3e-3), the one-texel sun's E0 within 1e-5 (version 2: 2.6e-4);
    * α = 0 (the mirror, :func:`mirror_reflection`): E0 = L(r), E1 = L(r)(1 − n·v)⁵ with L(r) the radiance of the
      texel containing r — the limit α → 0 of the integral of the piecewise-constant image (f_DV⟨n, l⟩ tends to
      δ(l − r)), not an interpolation of it.
    The pair's replaced centre term is the float32 one that was summed (at grazing views 1 + v·l is small and
    float32 moves D at the peak by several per cent). Validated in tests/math/test_reflection_reference_converged.py
    against closed forms and independent quadratures (white furnace at α = 0.02…1 and n·v ≥ 0.05 on 64 × 32 and
    1024 × 512 skies within 1e-3 of the GGX albedo; a linear sky; a one-texel sun integrated exactly). GGX VNDF
    importance sampling of the texels (what the report used for narrow lobes before) is exact for smooth skies but
    misses a bright texel in the lobe's tail: 4096 samples per row left a relative MSE of 0.17 on the Poly Haven
    `park` (sun) at α = 0.02. Cost: the centre pass plus the cells, ~15 k per row on a 32 × 16 image (~20 ms);
    on a 1024 × 512 image the centre pass dominates. The image side (texel geometry, the texel lookup) is
    :mod:`bakery.environment.reflection_reference`. The idealised split-sum's kernel K_α(r, l) ∝ D(h)⟨r, l⟩₊
    (v = n = r) is integrated the same way (:func:`converged_prefiltered`).

Notation
    M rows (v, n, α); T quadrature samples (texel directions l_t, exact solid angles Ω_t); C channels.

References
    [SHExp] Silvennoinen et al., HPG 2025 (seed 000).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from bakery.brdf.ggx import ggx_distribution, reflect, smith_visibility_correlated
from bakery.reflection.splitsum import _kernel_profile
from bakery.sphere.grid import SphericalSamples

#: Elements (rows × samples) per chunk; bounds the temporary memory at ~100 MB in float32.
_CHUNK_ELEMENTS = 4_000_000
#: Tile of the float32 path (rows × texels = 256k elements, 1 MB per temporary).
_TILE_ROWS = 32
_TILE_TEXELS = 8192
#: Converged reference (module doc): cells at most 1/TEXELS_PER_LOBE of the lobe's width (v·h)α and
#: 1/TEXELS_PER_TAIL of the tail's scale (v·h)θ_h a side; the floor of v·h; the deepest split of a texel
#: (2^MAX_LEVELS cells a side).
TEXELS_PER_LOBE = 8
TEXELS_PER_TAIL = 8
VH_FLOOR = 0.05
MAX_LEVELS = 12
#: Cells straddling the horizon of n are split down to this chord (radians; module doc).
HORIZON_EXTENT = 1.0 / 16.0
#: Bumped whenever :func:`converged_reflection` of unchanged inputs changes (caches of it key on it): 1 texel
#: centres (and a bilinear mirror in the reflection bench), 2 adaptive sub-texels, the mirror's containing texel,
#: 3 cells at 1/8 of the integrand's scale integrated by 2 × 2 Gauss–Legendre (within 8e-4 of 2, relative MSE
#: ≤ 4e-7 on the bench's `park` rows, ~2× faster).
REFERENCE_METHOD_VERSION = 3
#: The 2 × 2 Gauss–Legendre nodes of a cell, in its own coordinates (weights ¼).
_GAUSS_2X2 = [(0.5 + x / (2.0 * np.sqrt(3.0)), 0.5 + y / (2.0 * np.sqrt(3.0))) for x in (-1, 1) for y in (-1, 1)]
#: (row, texel) pairs refined at a time, cells evaluated at a time.
_PAIR_CHUNK = 1 << 15
_CELL_CHUNK = 1 << 18


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


# ------------------------------------------------------------------------------------------- converged reference
class TexelRadiance(Protocol):
    """A radiance that is constant over each texel's exact footprint (an environment image, a cube map), as the
    converged reference reads it (module doc "Converged reference")."""

    @property
    def samples(self) -> SphericalSamples:
        """One sample per texel: its centre direction, exact solid angle and radiance (texel index = sample index)."""

    @property
    def texel_extents(self) -> np.ndarray:
        """(T,) the longest chord of each texel (its larger diagonal), radians."""

    def texel_points(self, texels: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Directions (K, 3) at in-texel coordinates (a, b) ∈ [0, 1]² of ``texels`` (K,) (a along rows, b along
        columns; (½, ½) the centre) and the solid angle per unit in-texel area there (K,) (0 outside the image's
        valid domain), so that Ω_t = ∫∫ density da db."""

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """(M, C) radiance of the texel containing each unit direction (M, 3)."""


def reference_method(source: TexelRadiance, alpha: float) -> dict[str, int | str]:
    """How :func:`converged_reflection` integrates at ``alpha``: {"method": "mirror" | "adaptive", "subdivision":
    the finest split of a texel side at the lobe's peak seen along n (v·h = 1; grazing views split further), "samples":
    texel centres per row (plus the cells of the texels near the lobe)}."""
    if alpha <= 0:
        return {"method": "mirror", "subdivision": 1, "samples": 1}
    extent = float(np.max(source.texel_extents))
    split = TEXELS_PER_LOBE * extent / (np.sqrt(2.0) * alpha)
    return {"method": "adaptive", "subdivision": int(2 ** max(0, int(np.ceil(np.log2(max(split, 1.0)))))),
            "samples": int(source.samples.count)}


def _lobe_cells(nl: np.ndarray, vl: np.ndarray, nv: np.ndarray, a: np.ndarray, extent: np.ndarray) -> np.ndarray:
    """Whether a cell of longest chord ``extent`` centred at l must be split (module doc, "Converged reference"):
    with v·h = √((1 + v·l)/2) (floored at VH_FLOOR) and θ_h = ∠(n, h) less the cell's reach in h, e/(4 v·h), the
    cell is split while its sides e/√2 exceed (v·h)·max(α/TEXELS_PER_LOBE, θ_h/TEXELS_PER_TAIL) and it reaches above
    the horizon (n·l > −e); a cell straddling the horizon (|n·l| < e, where ⟨n, l⟩₊ has its kink) while
    e > HORIZON_EXTENT. Elementwise (broadcasting) over any float dtype."""
    vh = np.maximum(np.sqrt(np.clip(0.5 * (1.0 + vl), 0.0, 1.0)), VH_FLOOR)
    nh = np.clip((nv + nl) / (2.0 * vh), -1.0, 1.0)
    side = extent / (np.sqrt(2.0) * vh)
    reach = TEXELS_PER_TAIL * side  # the tail term: θ_near < reach ⇔ side > θ_near / TEXELS_PER_TAIL
    limit = np.minimum(extent / (4.0 * vh) + reach, np.pi)
    lobe = (TEXELS_PER_LOBE * side > a) & (nh > np.cos(limit)) & (nl > -extent)
    return lobe | ((np.abs(nl) < extent) & (extent > HORIZON_EXTENT))


def _tiles(samples: SphericalSamples, extents: np.ndarray, v: np.ndarray, n: np.ndarray, a: np.ndarray,
           weights: Callable):  # noqa: ANN202 - generator
    """Texel-centre pass in float32 tiles (rows × texels): yields (row slice, texel slice, weight matrices, pairs)
    with pairs (rows, texels, their centre weights) the (row, texel) pairs :func:`_lobe_cells` splits. The centre
    weights are the tile's own (float32, as summed), so that replacing them is exact whatever their rounding (at
    grazing views 1 + v·l is small and float32 moves D by several per cent at the peak)."""
    l_t = np.ascontiguousarray(np.asarray(samples.directions, dtype=np.float32).T)
    l_t /= np.maximum(np.linalg.norm(l_t, axis=0, keepdims=True), np.float32(1e-30))
    omega = np.asarray(samples.solid_angles, dtype=np.float32)
    ext = np.asarray(extents, dtype=np.float32)
    for t0 in range(0, samples.count, _TILE_TEXELS):
        tt = slice(t0, t0 + _TILE_TEXELS)
        for start in range(0, len(v), _TILE_ROWS):
            s = slice(start, start + _TILE_ROWS)
            w = weights(l_t[:, tt], omega[tt], v[s], n[s], a[s])
            nl = n[s].astype(np.float32) @ l_t[:, tt]
            vl = v[s].astype(np.float32) @ l_t[:, tt]
            nv = np.sum(n[s] * v[s], axis=1).astype(np.float32)[:, None]
            rows, cols = np.nonzero(_lobe_cells(nl, vl, nv, a[s].astype(np.float32)[:, None], ext[tt][None, :]))
            yield s, tt, w, (rows + start, cols + t0, [x[rows, cols].astype(np.float64) for x in w])


def _refine_pairs(source: TexelRadiance, pairs: list, v: np.ndarray, n: np.ndarray, a: np.ndarray,
                  kernel: Callable, radiance: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per row (M,): Σ over its refined texels of (exact-footprint integral − centre weight) × L_t, per output of
    ``kernel`` ((M, C) each), and the same without L ((M,) each)."""
    rows = np.concatenate([p[0] for p in pairs])
    texels = np.concatenate([p[1] for p in pairs])
    centre = [np.concatenate([p[2][j] for p in pairs]) for j in range(len(pairs[0][2]))] if pairs else []
    channels = radiance.shape[1]
    weighted = [np.zeros((len(v), channels)) for _ in centre]
    plain = [np.zeros(len(v)) for _ in centre]
    for c0 in range(0, rows.size, _PAIR_CHUNK):
        c = slice(c0, c0 + _PAIR_CHUNK)
        exact = _refined(source, rows[c], texels[c], v, n, a, kernel)
        for j, w in enumerate(exact):
            d = w - centre[j][c]
            plain[j] += np.bincount(rows[c], weights=d, minlength=len(v))
            for ch in range(channels):
                weighted[j][:, ch] += np.bincount(rows[c], weights=d * radiance[texels[c], ch], minlength=len(v))
    return weighted, plain


def _fdv_pairs(v: np.ndarray, n: np.ndarray, a: np.ndarray,
               l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # noqa: E741
    """f_DV(v, n, l, α)⟨n, l⟩₊ and its Fresnel tail × (1 − v·h)⁵, elementwise over (K, 3) rows (float64)."""
    nl, vl, nv = (np.einsum("ij,ij->i", x, y) for x, y in ((n, l), (v, l), (n, v)))
    vh = np.sqrt(np.clip(0.5 * (1.0 + vl), 0.0, 1.0))
    nh = (nv + nl) / np.maximum(2.0 * vh, 1e-12)
    w = ggx_distribution(nh, a) * smith_visibility_correlated(nv, nl, a) * np.maximum(nl, 0.0)
    return w, w * np.clip(1.0 - vh, 0.0, 1.0) ** 5


def _kernel_pairs(v: np.ndarray, n: np.ndarray, a: np.ndarray, l: np.ndarray) -> tuple[np.ndarray]:  # noqa: E741
    """The split-sum kernel K_α(r, l) (v = n = r), elementwise over (K, 3) rows."""
    return (_kernel_profile(np.einsum("ij,ij->i", n, l), a),)


def _refined(source: TexelRadiance, rows: np.ndarray, texels: np.ndarray, v: np.ndarray, n: np.ndarray,
             a: np.ndarray, kernel: Callable) -> list[np.ndarray]:
    """Per (row, texel) pair (K,): the exact-footprint integral W = ∫_texel g(l) dl of each output g of ``kernel``,
    by splitting the texel into a quadtree of cells down to where :func:`_lobe_cells` stops (at most 2^MAX_LEVELS
    cells a side; depth first in chunks, so memory stays bounded). A cell's chord is that of its own corner
    directions (a mapping can be far from linear inside a texel: the rim of a mirrored ball); each leaf is
    integrated by the 2 × 2 Gauss–Legendre rule in texel coordinates (g × solid-angle density at the nodes), and a
    pair's solid angles are scaled to sum to Ω_t exactly."""
    k = rows.size
    vr, nr, ar = v[rows], n[rows], a[rows]
    nv = np.einsum("ij,ij->i", nr, vr)
    sums: list[np.ndarray] = []
    area = np.zeros(k)

    def distance(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        d = x - y
        return np.sqrt(np.einsum("ij,ij->i", d, d))

    def descend(level: int, pair: np.ndarray, a0: np.ndarray, b0: np.ndarray, corners: dict, centre: np.ndarray,
                centre_held: np.ndarray) -> None:
        """Split the cells (pair, origin (a0, b0), side 2^(1−level), ``corners`` {(i, j): (direction (P, 3), holds
        radiance (P,))} at (a0 + i·side, b0 + j·side), i, j ∈ {0, 1}, centre direction (P, 3) and whether it holds
        radiance (P,)) into their four children and integrate or split those. A child's chord is the longer diagonal
        of its corner directions; it is split only if its centre or a corner holds radiance (a disc map's rim texels
        are partly outside the disc). Only the four edge midpoints are new: the corners come from the parent."""
        nonlocal sums
        side = 0.5 ** (level - 1)
        half = 0.5 * side
        # the cell's 3 × 3 grid, (i, j) at i/2, j/2 of a side
        points = {(2 * i, 2 * j): corners[i, j][0] for i in (0, 1) for j in (0, 1)}
        held = {(2 * i, 2 * j): corners[i, j][1] for i in (0, 1) for j in (0, 1)}
        points[1, 1], held[1, 1] = centre, centre_held
        for i, j in ((0, 1), (1, 0), (2, 1), (1, 2)):
            points[i, j], density = source.texel_points(texels[pair], a0 + 0.5 * i * side, b0 + 0.5 * j * side)
            held[i, j] = density > 0
        # the four children of every cell, child (i, j) of cell q at 4q + 2i + j
        chord = np.stack([np.maximum(distance(points[i, j], points[i + 1, j + 1]),
                                     distance(points[i, j + 1], points[i + 1, j])) for i in (0, 1) for j in (0, 1)],
                         axis=1).reshape(-1)
        reaches = np.stack([held[i, j] | held[i + 1, j + 1] | held[i, j + 1] | held[i + 1, j]
                            for i in (0, 1) for j in (0, 1)], axis=1).reshape(-1)
        children = [(i, j) for i in (0, 1) for j in (0, 1)]  # child (i, j)'s corner (u, w) is grid point (i+u, j+w)
        child_corners = {(u, w): (np.stack([points[i + u, j + w] for i, j in children], axis=1).reshape(-1, 3),
                                  np.stack([held[i + u, j + w] for i, j in children], axis=1).reshape(-1))
                         for u, w in children}
        pair = np.repeat(pair, 4)
        a0 = np.repeat(a0, 4) + np.tile([0.0, 0.0, half, half], a0.size)
        b0 = np.repeat(b0, 4) + np.tile([0.0, half, 0.0, half], b0.size)
        for c0 in range(0, pair.size, _CELL_CHUNK):
            c = slice(c0, c0 + _CELL_CHUNK)
            p = pair[c]
            directions, density = source.texel_points(texels[p], a0[c] + 0.5 * half, b0[c] + 0.5 * half)
            split = np.zeros(p.size, dtype=bool)
            if level < MAX_LEVELS:
                nl = np.einsum("ij,ij->i", nr[p], directions)
                vl = np.einsum("ij,ij->i", vr[p], directions)
                split = _lobe_cells(nl, vl, nv[p], ar[p], chord[c]) & ((density > 0) | reaches[c])
            leaf = np.flatnonzero(~split)
            pl = p[leaf]
            for x, y in _GAUSS_2X2:  # each leaf by the 2 × 2 Gauss–Legendre rule (fourth order)
                points, density_g = source.texel_points(texels[pl], a0[c][leaf] + x * half, b0[c][leaf] + y * half)
                solid = density_g * (0.25 * half * half)
                values = kernel(vr[pl], nr[pl], ar[pl], points)
                if not sums:
                    sums = [np.zeros(k) for _ in values]
                for m, g in enumerate(values):
                    sums[m] += np.bincount(pl, weights=g * solid, minlength=k)
                area[:] += np.bincount(pl, weights=solid, minlength=k)
            if split.any():
                q = np.flatnonzero(split)
                cq = c0 + q
                descend(level + 1, p[q], a0[cq], b0[cq],
                        {key: (d[cq], h[cq]) for key, (d, h) in child_corners.items()}, directions[q], density[q] > 0)

    zero = np.zeros(k)
    corners = {}
    for i in (0, 1):
        for j in (0, 1):
            direction, density = source.texel_points(texels, zero + i, zero + j)
            corners[i, j] = (direction, density > 0)
    centre, centre_density = source.texel_points(texels, zero + 0.5, zero + 0.5)
    descend(1, np.arange(k), zero, zero, corners, centre, centre_density > 0)
    omega_t = np.asarray(source.samples.solid_angles, dtype=np.float64)[texels]
    scale = np.where(area > 0, omega_t / np.where(area > 0, area, 1.0), 0.0)
    return [total * scale for total in sums]


def converged_reflection(source: TexelRadiance, view: np.ndarray, normal: np.ndarray,
                         alpha: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """(E0, E1) (M, C) of the piecewise-constant ``source`` at rows (v, n, α), α a scalar or (M,) (module doc
    "Converged reference"): texel centres in float32 tiles, plus per (row, texel) pair near the lobe the difference
    between the texel's exact-footprint integral (adaptive sub-texels, float64) and its centre value; α = 0: the
    mirror, the texel containing r."""
    v, n = np.asarray(view, dtype=np.float64).reshape(-1, 3), np.asarray(normal, dtype=np.float64).reshape(-1, 3)
    a = np.broadcast_to(np.asarray(alpha, dtype=np.float64).reshape(-1), (v.shape[0],)).copy()
    if n.shape != v.shape or np.any(~(a >= 0)):
        raise ValueError("view and normal must both be (M, 3) and alpha ≥ 0")
    samples = source.samples
    radiance = np.asarray(samples.radiance, dtype=np.float64)
    e0, e1 = np.zeros((len(v), radiance.shape[1])), np.zeros((len(v), radiance.shape[1]))
    mirror = a <= 0
    if mirror.any():
        e0[mirror], e1[mirror] = mirror_reflection(source.radiance, v[mirror], n[mirror])
    rough = np.flatnonzero(~mirror)
    if rough.size == 0:
        return e0, e1
    vr, nr, ar = v[rough], n[rough], a[rough]
    r32 = radiance.astype(np.float32)
    out0, out1 = np.zeros((rough.size, radiance.shape[1])), np.zeros((rough.size, radiance.shape[1]))
    pairs = []
    for s, tt, (w0, w1), found in _tiles(samples, source.texel_extents, vr, nr, ar, _weights_float32):
        out0[s] += w0 @ r32[tt]
        out1[s] += w1 @ r32[tt]
        pairs.append(found)
    (d0, d1), _ = _refine_pairs(source, pairs, vr, nr, ar, _fdv_pairs, radiance)
    out0 += d0
    out1 += d1
    e0[rough], e1[rough] = out0, out1
    return e0, e1


def converged_prefiltered(source: TexelRadiance, directions: np.ndarray, alpha: float) -> np.ndarray:
    """∫ K_α(r, l) L(l) dl / ∫ K_α(r, l) dl (M, C): the normalised split-sum kernel (v = n = r) applied to the
    piecewise-constant ``source`` at unit directions r (M, 3), α > 0, converged as :func:`converged_reflection`
    (texel centres plus the exact-footprint correction of the texels near the lobe)."""
    if not alpha > 0:
        raise ValueError("alpha must be > 0 (α = 0 is the mirror)")
    r = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    a = np.full(len(r), float(alpha))
    samples = source.samples
    radiance = np.asarray(samples.radiance, dtype=np.float64)
    num, den = np.zeros((len(r), radiance.shape[1])), np.zeros(len(r))

    def kernel_weights(l_t, omega, v, n, a):  # noqa: ANN001, ANN202, E741 - the float32 tile kernel
        k = _kernel_profile((n.astype(np.float32) @ l_t).astype(np.float64), a[:, None])
        return (k * omega,)

    pairs = []
    for s, tt, (k,), found in _tiles(samples, source.texel_extents, r, r, a, kernel_weights):
        num[s] += k @ radiance[tt]
        den[s] += k.sum(axis=1)
        pairs.append(found)
    (d,), (plain,) = _refine_pairs(source, pairs, r, r, a, _kernel_pairs, radiance)
    num += d
    den += plain
    return num / den[:, None]


def mirror_reflection(lookup: Callable[[np.ndarray], np.ndarray], view: np.ndarray, normal: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(E0, E1) (M, C) at α = 0: L(r) and L(r)(1 − n·v)⁵, L the texel containing r (``lookup``; module doc)."""
    v, n = np.asarray(view, dtype=np.float64).reshape(-1, 3), np.asarray(normal, dtype=np.float64).reshape(-1, 3)
    radiance = np.asarray(lookup(reflect(v, n)), dtype=np.float64)
    nv = np.clip(np.sum(v * n, axis=1), 0.0, 1.0)[:, None]
    return radiance, radiance * (1.0 - nv) ** 5
