"""Sharp prefilter levels as fixed sparse linear operators of the capture: the normalised GGX kernel K_α (v = n)
integrated over an adaptive quadtree of the capture's mip pyramid ([Seed003] §6.2: angular-domain cost O(W S²)
per output texel, here cut to O(log S) by merging far texels; [KC08]: read a coarser mip where the kernel is wide).

Once α, the capture face N and the output face n are fixed, a level is y = A x: x stacks the area-weighted mip
pyramid of the capture (mip m has face N_m = N >> m, its texels are the columns of A), y the output texels (rows).

Notation
    d            output texel centre (the normal n = v = r of the level)
    K_α(d, l)    D(h) ⟨d, l⟩₊, h = (d + l)/|d + l| (unnormalised; :func:`bakery.reflection.splitsum._kernel_profile`)
    Ω_j, c_j     solid angle and centre direction of texel j; ρ_j = ∠(d, c_j); r_j = its angular radius (the largest
                 angle from c_j to a corner, an upper bound on ∠(c_j, l) for l in the texel)
    τ, κ, s      opening tolerance (``tolerance``), core radius in units of α (``core``), subsample depth
    S(d)         row normaliser Σ_j w_j(d) (≈ the dense quadrature's Σ_i K_α(d, c_i) Ω_i)

Method
    1. Quadtree (Barnes–Hut style opening [BH86], breadth first, vectorised over a chunk of output texels): the roots
       are the texels of the coarsest mip; a node j at mip m > 0 is *opened* (replaced by its 4 children at m − 1)
       unless  r_j · g(ρ_j − r_j) ≤ τ  and  ρ_j − r_j ≥ κ α,  with g(ρ) = (ρ + α)/(α² + ρ²/4).
       Derivation: ln K_α = −2 ln(α² cos²(ρ/2) + sin²(ρ/2)) + ln cos ρ, so |∂ ln K_α/∂ρ| ≈ ρ/(α² + ρ²/4) ≤ 1/α
       (largest at ρ = 2α), ≈ 4/ρ in the tail; g ≥ that bound, and adds α to the numerator so the flat peak (where
       the curvature 1/α² matters) is not merged: a leaf is a node across which ln K_α changes by ≲ τ. Within the
       core ρ < κ α every texel of the capture is its own leaf (measured: merging there is what costs accuracy on
       high-frequency environments; τ alone at 0.5 gives 4e-4 relative MSE on ``park``, κ = 3 with τ = 1.5 8e-5).
       Mip-0 nodes are always leaves; nodes with ρ_j − r_j ≥ π/2 lie wholly below the horizon (K_α = 0) and are
       dropped. Every capture texel lies in exactly one leaf or dropped node: the leaves tile the hemisphere.
    2. Leaf weight: the kernel summed over the leaf's 4^s descendants at mip max(m − s, 0) (s = ``sub_depth`` = 2),
           w_j(d) = Σ_{i ∈ desc(j)} K_α(d, c_i) Ω_i ,
       so a mip-0 leaf has exactly the dense quadrature's weight K_α(d, c_j) Ω_j
       (:func:`bakery.reflection.splitsum._exact_prefilter_level`) and a merged leaf ≈ its texels' total weight
       (K_α at the leaf centre alone, s = 0, puts convex tail leaves 0.3–0.6 % low); it multiplies the mip's
       area-weighted mean Σ L_i Ω_i / Σ Ω_i of the leaf's capture texels. Leaves with w = 0 are dropped.
    3. Rows normalised:  A_dj = w_j(d) / S(d), S(d) = Σ_j' w_j'(d)  ⇒  Σ_j A_dj = 1 (float32 data; each row's
       rounding residual is put into its largest weight, |Σ_j A_dj − 1| ≲ 1e-9): a constant environment is returned
       to float32 rounding. S(d) is kept (:func:`cached_row_norms`) for texels added exactly outside the operator.
    4. y = A x for P probes at once: x is (columns, P·C) (one column per probe channel); scipy's CSR × dense product
       accumulates every column independently in the row's index order, so a probe's result is bit-identical
       whatever the batch (tested).
    5. Cube symmetry: K_α is rotation invariant and each proper rotation R_f of the cube taking face 0 onto face f
       maps texels onto texels at every mip, so only face 0's rows A₀ are built and stored; face f is
       y[texel of R_f d] = A₀ x[texel of R_f c] (one gather of x per face): 1/6 of the memory and build time.

Cost (default split-sum level α = 0.04, 128² capture → 64²): ≈ 800 nnz per row ([Seed003] §6.2: the angular-domain
cost O(W S²) per output texel — W S² ≈ 10⁴ texels in the lobe's hemisphere at 128² — drops to O(log S / τ²) leaves);
the residual against the dense quadrature is the covariance of K_α and L within merged leaves. Measured in
``bakery.bench.splitsum`` and bounded in ``tests/math/test_prefilter_operator.py``.

References
    [KC08]    Křivánek & Colbert, "Real-time Shading with Filtered Importance Sampling", EGSR 2008, Eq. 13 (read the
              mip whose texel matches the kernel's footprint).
    [Seed003] Ramamoorthi & Hanrahan, "Frequency Space Environment Map Rendering", SIGGRAPH 2002, §6.2 (angular vs
              frequency domain prefiltering cost: angular wins for sharp lobes, frequency for rough ones).
    [BH86]    Barnes & Hut, "A hierarchical O(N log N) force-calculation algorithm", Nature 1986 (opening criterion).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.sparse as sp

from bakery.sphere.cubemap import (
    cube_face_uv_to_direction,
    cube_texel_directions,
    cube_texel_solid_angles,
    direction_to_cube_texel,
)

#: Formulation version: part of every cache key (bump when the construction changes).
OPERATOR_VERSION = 1


@dataclass(frozen=True)
class OperatorSettings:
    """Quadtree parameters (module doc): opening tolerance τ, core radius κ (in units of α; mip-0 leaves only within
    ρ < κ α), subsample depth s of the leaf weights, output rows per build chunk."""

    tolerance: float = 2.0
    core: float = 2.0
    sub_depth: int = 2
    chunk_rows: int = 1024

    def key(self) -> str:
        return f"tau{self.tolerance!r}-core{self.core!r}-sub{self.sub_depth}"


def pyramid_sizes(face_size: int) -> tuple[int, ...]:
    """Face sizes N_m of the mip pyramid: N, N/2, … while even, down to 1 (as ``splitsum.build_mips``)."""
    sizes = [int(face_size)]
    while sizes[-1] > 1 and sizes[-1] % 2 == 0:
        sizes.append(sizes[-1] // 2)
    return tuple(sizes)


def pyramid_offsets(face_size: int) -> np.ndarray:
    """Row offset of mip m in the stacked pyramid x (len(sizes) + 1,): Σ_{m' < m} 6 N_m'²."""
    sizes = np.array(pyramid_sizes(face_size), dtype=np.int64)
    return np.concatenate([[0], np.cumsum(6 * sizes * sizes)])


@lru_cache(maxsize=32)
def _texel_geometry(face_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres c (6N², 3), solid angles Ω (6N²,) and angular radii r (6N²,) (largest angle centre → corner)."""
    centres = cube_texel_directions(face_size).reshape(-1, 3)
    omega = cube_texel_solid_angles(face_size).reshape(-1)
    edges = np.linspace(-1.0, 1.0, face_size + 1)
    faces = np.broadcast_to(np.arange(6)[:, None, None], (6, face_size, face_size))
    radius = np.zeros(centres.shape[0])
    for dv in (0, 1):
        for du in (0, 1):
            v, u = np.meshgrid(edges[dv : dv + face_size], edges[du : du + face_size], indexing="ij")
            corner = cube_face_uv_to_direction(faces, u[None], v[None]).reshape(-1, 3)
            radius = np.maximum(radius, np.arccos(np.clip(np.sum(corner * centres, axis=1), -1.0, 1.0)))
    for a in (centres, omega, radius):
        a.setflags(write=False)
    return centres, omega, radius


def _kernel(t: np.ndarray, alpha: float) -> np.ndarray:
    """K_α as a function of t = d·l: D(h) t₊ with (n·h)² = (1 + t)/2 (the profile of ``splitsum._kernel_profile``,
    without its argument checks; [WMLT07] Eq. 33: D = α² / (π ((n·h)² (α² − 1) + 1)²))."""
    a2 = alpha * alpha
    denom = 0.5 * (1.0 + t) * (a2 - 1.0) + 1.0
    return np.where(t > 0.0, a2 / (np.pi * denom * denom) * t, 0.0)


def _children(texel: np.ndarray, size: int) -> np.ndarray:
    """Flat indices (len, 4) at face 2·``size`` of the children of texels ``texel`` at face ``size``."""
    face, rem = np.divmod(texel, size * size)
    row, col = np.divmod(rem, size)
    fine = 2 * size
    base = face * fine * fine + 2 * row * fine + 2 * col
    return base[:, None] + np.array([0, 1, fine, fine + 1])[None]


def _build_chunk(normals: np.ndarray, alpha: float, face_size: int,
                 settings: OperatorSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(local row, column, weight) of the leaves of the output texels ``normals`` (T, 3) (module doc, steps 1–2)."""
    sizes = pyramid_sizes(face_size)
    offsets = pyramid_offsets(face_size)
    top = len(sizes) - 1
    rows = np.repeat(np.arange(normals.shape[0]), 6 * sizes[top] ** 2)
    nodes = np.tile(np.arange(6 * sizes[top] ** 2), normals.shape[0])
    core = settings.core * alpha
    out_r, out_c, out_w = [], [], []
    for m in range(top, -1, -1):
        centres, omega, radius = _texel_geometry(sizes[m])
        cos_rho = np.einsum("ij,ij->i", normals[rows], centres[nodes])
        rho_min = np.maximum(np.arccos(np.clip(cos_rho, -1.0, 1.0)) - radius[nodes], 0.0)
        keep = rho_min < 0.5 * np.pi  # else wholly below the horizon: K_α = 0
        rows, nodes, rho_min, cos_rho = rows[keep], nodes[keep], rho_min[keep], cos_rho[keep]
        if m == 0:
            leaf = np.ones(rows.shape, bool)
        else:  # step 1: r_j g(ρ_j − r_j) ≤ τ outside the core
            g = (rho_min + alpha) / (alpha * alpha + 0.25 * rho_min * rho_min)
            leaf = (radius[nodes] * g <= settings.tolerance) & (rho_min >= core)
        depth = min(settings.sub_depth, m)
        if depth == 0 or not leaf.any():
            weight = _kernel(cos_rho[leaf], alpha) * omega[nodes[leaf]]  # step 2: K_α(d, c_j) Ω_j
        else:  # step 2: Σ_i K_α(d, c_i) Ω_i over the leaf's 4^s descendants at mip m − s
            desc = nodes[leaf]
            for q in range(depth):
                desc = _children(desc.reshape(-1), sizes[m - q]).reshape(desc.shape[0] if q == 0 else -1, 4)
            desc = desc.reshape(leaf.sum(), -1)
            sub_c, sub_o, _ = _texel_geometry(sizes[m - depth])
            d_leaf = normals[rows[leaf]]
            weight = np.zeros(desc.shape[0])
            for q in range(desc.shape[1]):
                weight += _kernel(np.einsum("ij,ij->i", d_leaf, sub_c[desc[:, q]]), alpha) * sub_o[desc[:, q]]
        positive = weight > 0.0  # leaves wholly below the horizon carry no weight
        out_r.append(rows[leaf][positive])
        out_c.append(offsets[m] + nodes[leaf][positive])
        out_w.append(weight[positive])
        rows, nodes = rows[~leaf], nodes[~leaf]
        if rows.size == 0:
            break
        rows = np.repeat(rows, 4)
        nodes = _children(nodes, sizes[m]).reshape(-1)  # mip m − 1
    return np.concatenate(out_r), np.concatenate(out_c), np.concatenate(out_w)


def build_prefilter_operator(alpha: float, out_size: int, face_size: int,
                             settings: OperatorSettings = OperatorSettings()) -> sp.csr_matrix:
    """A₀ (n², columns of the pyramid of an N = ``face_size`` capture) float32 CSR: the rows of the output texels
    of face 0 (+X), each summing to 1 (module doc); the other faces are A₀ applied to the rotated pyramid
    (:func:`apply_prefilter_operator`, step 5)."""
    return _build_operator(alpha, out_size, face_size, settings)[0]


def _build_operator(alpha: float, out_size: int, face_size: int,
                    settings: OperatorSettings) -> tuple[sp.csr_matrix, np.ndarray]:
    """(A₀, S₀ (n²,) float64): the operator and each face-0 row's normaliser S(d) = Σ_j w_j(d) (step 3)."""
    if not alpha > 0.0:
        raise ValueError(f"alpha must be > 0 (α = 0 is the capture itself), got {alpha}")
    normals = cube_texel_directions(out_size)[0].reshape(-1, 3)
    n_cols = int(pyramid_offsets(face_size)[-1])
    data, indices, counts, norms = [], [], [], []
    for s in range(0, normals.shape[0], settings.chunk_rows):
        chunk = normals[s : s + settings.chunk_rows]
        r, c, w = _build_chunk(chunk, float(alpha), int(face_size), settings)
        order = np.lexsort((c, r))
        r, c, w = r[order], c[order], w[order]
        norms.append(np.bincount(r, weights=w, minlength=chunk.shape[0]))
        w = w / norms[-1][r]  # step 3: Σ_j A_dj = 1
        data.append(w)
        indices.append(c)
        counts.append(np.bincount(r, minlength=chunk.shape[0]))
    indptr = np.concatenate([[0], np.cumsum(np.concatenate(counts))])
    w32 = np.concatenate(data).astype(np.float32)
    # float32 rows: put each row's rounding residual 1 − Σ w into its largest weight (residual ≤ ½ ulp of it)
    rows = np.repeat(np.arange(normals.shape[0]), np.diff(indptr))
    if np.any(np.diff(indptr) == 0):
        raise ValueError("a row of the operator has no leaf (empty hemisphere?)")
    peak = np.lexsort((-w32, rows))[indptr[:-1]]  # rows ascending, weights descending: each row's largest first
    residual = 1.0 - np.bincount(rows, weights=w32.astype(np.float64), minlength=normals.shape[0])
    w32[peak] = (w32[peak].astype(np.float64) + residual).astype(np.float32)
    matrix = sp.csr_matrix((w32, np.concatenate(indices).astype(np.int32), indptr.astype(np.int32)),
                           shape=(normals.shape[0], n_cols))
    return matrix, np.concatenate(norms)


#: Proper rotations R_f of the cube taking face 0 (+X) onto face f (face order of :mod:`bakery.conventions`).
_FACE_ROTATIONS = np.array([
    [[1, 0, 0], [0, 1, 0], [0, 0, 1]],     # +X
    [[-1, 0, 0], [0, 1, 0], [0, 0, -1]],   # -X: 180° about y
    [[0, -1, 0], [1, 0, 0], [0, 0, 1]],    # +Y: +90° about z
    [[0, 1, 0], [-1, 0, 0], [0, 0, 1]],    # -Y: -90° about z
    [[0, 0, -1], [0, 1, 0], [1, 0, 0]],    # +Z: -90° about y
    [[0, 0, 1], [0, 1, 0], [-1, 0, 0]],    # -Z: +90° about y
], dtype=np.float64)


@lru_cache(maxsize=16)
def _face_permutations(face_size: int, out_size: int) -> tuple[np.ndarray, np.ndarray]:
    """(gather (6, columns), place (6, n²)): x_f = x[gather[f]] is the pyramid seen from face f
    (x_f[j] = x[index of R_f c_j]), and row i of A₀ x_f is output texel place[f, i] (the texel of R_f d_i)."""
    sizes = pyramid_sizes(face_size)
    offsets = pyramid_offsets(face_size)
    gather = np.empty((6, int(offsets[-1])), dtype=np.int64)
    out_dirs = cube_texel_directions(out_size)[0].reshape(-1, 3)
    place = np.empty((6, out_dirs.shape[0]), dtype=np.int64)
    for f, rot in enumerate(_FACE_ROTATIONS):
        for m, size in enumerate(sizes):
            face, row, col = direction_to_cube_texel(_texel_geometry(size)[0] @ rot.T, size)
            gather[f, offsets[m] : offsets[m + 1]] = offsets[m] + (face * size + row) * size + col
        face, row, col = direction_to_cube_texel(out_dirs @ rot.T, out_size)
        place[f] = (face * out_size + row) * out_size + col
    for a in (gather, place):
        a.setflags(write=False)
    return gather, place


def _downsample(cube: np.ndarray) -> np.ndarray:
    """Area-weighted 2 × 2 box (6, M, M, K) → (6, M/2, M/2, K): L_J = Σ L_i Ω_i / Σ Ω_i (as ``resample_cube``),
    summed in a fixed order per element (so every column is independent of the others)."""
    m = cube.shape[1]
    omega = cube_texel_solid_angles(m)[0].astype(np.float32)
    o = [omega[a::2, b::2, None] for a in (0, 1) for b in (0, 1)]
    f = [cube[:, a::2, b::2] * o[2 * a + b] for a in (0, 1) for b in (0, 1)]
    return ((f[0] + f[1]) + (f[2] + f[3])) / ((o[0] + o[1]) + (o[2] + o[3]))


def stack_pyramid(cubes: np.ndarray) -> np.ndarray:
    """x (columns, P·C) float32: the mip pyramid (module doc) of captures (P, 6, N, N, C), probe-major columns."""
    cubes = np.asarray(cubes, dtype=np.float32)
    p, _, n, _, c = cubes.shape
    level = np.ascontiguousarray(np.moveaxis(cubes, 0, -2).reshape(6, n, n, p * c))
    parts = [level.reshape(-1, p * c)]
    for _ in pyramid_sizes(n)[1:]:
        level = _downsample(level)
        parts.append(level.reshape(-1, p * c))
    return np.concatenate(parts, axis=0)


def apply_prefilter_operator(matrix: sp.csr_matrix, pyramid: np.ndarray, face_size: int, out_size: int,
                             channels: int) -> np.ndarray:
    """y = A x (module doc, steps 4–5) → (P, 6, n, n, C) float32 for a pyramid from :func:`stack_pyramid` of
    captures of face ``face_size`` and the face-0 operator ``matrix`` of :func:`build_prefilter_operator`."""
    gather, place = _face_permutations(int(face_size), int(out_size))
    p = pyramid.shape[1] // channels
    y = np.empty((6 * out_size * out_size, pyramid.shape[1]), dtype=np.float32)
    for f in range(6):
        y[place[f]] = matrix @ pyramid[gather[f]]
    return np.moveaxis(y.reshape(6, out_size, out_size, p, channels), 3, 0)


def _operator_key(alpha: float, out_size: int, face_size: int, settings: OperatorSettings) -> str:
    return (f"ggx-prefilter-operator-v{OPERATOR_VERSION}-alpha{float(alpha)!r}-out{int(out_size)}-"
            f"face{int(face_size)}-{settings.key()}")


@lru_cache(maxsize=16)
def _cached_parts(alpha: float, out_size: int, face_size: int,
                  settings: OperatorSettings) -> tuple[sp.csr_matrix, np.ndarray]:
    from bakery.reflection.tables import OperatorCache

    key = _operator_key(alpha, out_size, face_size, settings)
    matrix = load_sparse(key, OperatorCache.load)
    norms = OperatorCache.load(f"{key}#rownorm") if matrix is not None else None
    if matrix is None or norms is None or norms.shape != (matrix.shape[0],):
        built, norms = _build_operator(alpha, out_size, face_size, settings)
        matrix = save_sparse(key, built, OperatorCache.save)
        norms = OperatorCache.save(f"{key}#rownorm", norms)
    return matrix, np.asarray(norms)


def cached_prefilter_operator(alpha: float, out_size: int, face_size: int,
                              settings: OperatorSettings = OperatorSettings()) -> sp.csr_matrix:
    """:func:`build_prefilter_operator` through the process's memory and the shared on-disk operator cache
    (:class:`bakery.reflection.tables.OperatorCache`, checksummed memory-mapped arrays; see :func:`save_sparse`);
    a missing or damaged part rebuilds the operator (and its row normalisers, :func:`cached_row_norms`)."""
    return _cached_parts(float(alpha), int(out_size), int(face_size), settings)[0]


def cached_row_norms(alpha: float, out_size: int, face_size: int,
                     settings: OperatorSettings = OperatorSettings()) -> np.ndarray:
    """S(d) (6 n²,) float64 at every output texel (flat cube order): the row normalisers of step 3, i.e. the
    discrete ∫ K_α dω over the leaves (with ``sub_depth`` ≥ 1 within ~1e-4 of the dense quadrature's Σ K_α Ω over
    every capture texel), from face 0's by the cube symmetry (step 5). Bright texels treated exactly are divided
    by it so that they are weighted like the rest of their row."""
    norms = _cached_parts(float(alpha), int(out_size), int(face_size), settings)[1]
    _, place = _face_permutations(int(face_size), int(out_size))
    out = np.empty(6 * out_size * out_size)
    for f in range(6):
        out[place[f]] = norms
    return out


cached_prefilter_operator.cache_clear = _cached_parts.cache_clear  # type: ignore[attr-defined]


# ---------------------------------------------------------------------------------------------- cache (no I/O here)
def save_sparse(key: str, matrix: sp.csr_matrix, save: Callable[[str, np.ndarray], np.ndarray]) -> sp.csr_matrix:
    """Store a CSR matrix through an array cache ``save(key, array) -> array`` as four checksummed arrays
    (``key#shape``, ``#indptr``, ``#indices``, ``#data``) and return it backed by what ``save`` returned."""
    matrix = matrix.tocsr()
    header = np.array([matrix.shape[0], matrix.shape[1], matrix.nnz], dtype=np.int64)
    parts = {name: save(f"{key}#{name}", np.ascontiguousarray(part)) for name, part in
             (("data", matrix.data), ("indices", matrix.indices), ("indptr", matrix.indptr))}
    save(f"{key}#shape", header)
    stored = _assemble(header, parts)
    return matrix if stored is None else stored


def load_sparse(key: str, load: Callable[[str], np.ndarray | None]) -> sp.csr_matrix | None:
    """The CSR matrix stored by :func:`save_sparse`, or None if any part is missing, failed its checksum (the
    cache removes it) or does not fit the others."""
    header = load(f"{key}#shape")
    if header is None:
        return None
    parts = {name: load(f"{key}#{name}") for name in ("data", "indices", "indptr")}
    if any(part is None for part in parts.values()):
        return None
    return _assemble(np.asarray(header), parts)


def _assemble(header: np.ndarray, parts: dict[str, np.ndarray]) -> sp.csr_matrix | None:
    rows, cols, nnz = (int(v) for v in header)
    data, indices, indptr = parts["data"], parts["indices"], parts["indptr"]
    if data.shape != (nnz,) or indices.shape != (nnz,) or indptr.shape != (rows + 1,) or int(indptr[0]) != 0 \
            or int(indptr[-1]) != nnz:
        return None
    if indices.dtype != np.int32 or indptr.dtype != np.int32:
        return None
    return sp.csr_matrix((data, indices, indptr), shape=(rows, cols), copy=False)  # memory-mapped, no copy
