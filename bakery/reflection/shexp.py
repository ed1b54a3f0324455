"""SH exponentials for glossy reflection ([SHExp] Sec. 4), fitted as fixed linear operators (method notes §4).

Model ([SHExp] Eq. 9–12)
    E0(v, n, α) ≈ P(r, α) · Q(h_r, α),  r = reflect(v, n),  h_r = (n + r)/|n + r|                (Eq. 9–10)
    P = exp(⟨vMF(1/α) ⊙ Y(r), p⟩),  Q = exp(⟨vMF(1/α) ⊙ Y(h_r), q⟩)                            (Eq. 11)
    vMF_l(κ) = exp(−l(l+1) / (2κ)) = exp(−l(l+1) α / 2)                                        (Eq. 12)
    p: bands 0..p_band ((p_band+1)² coefficients); q: bands 1..q_band (no DC, Sec. 4.1 last paragraph).
    Fresnel: E = F0·E0 + (1 − F0)·E1, E1 ≈ E0 · τ(n·v, α) with the shared tail table (Eq. 5, 15; τ as defined
    in :mod:`bakery.reflection.tables`).

Fit as fixed linear operators (Eq. 13–14)
    The (v, n, α) design does not depend on the environment, so with the capture's flux F (T, 3P) splatted onto
    the fit grid ("Fit grid" below):
        E0_samples = W · F            W[m, c] = f_DV(v_m, n_m, l_c, α_m) ⟨l_c, n_m⟩₊       (M, T)    (Eq. 6)
        [p; q]     = A⁺ · log(max(E0_samples, floor))                                   (33, M)    (Eq. 13–14)
    A[m] = [vMF(α_m) ⊙ Y(r_m), vMF(α_m) ⊙ Y(h_r,m)[1:]] (Eq. 14). W, A⁺ (and the weighted solve's fixed pieces)
    are built once per settings and cached; a batch of P probes is splat (GEMM) → W·F (GEMM) → log → solve (GEMM).

Albedo normalisation (beyond the paper; ``albedo_normalized``, default on)
    Under constant radiance c, rotational symmetry forces p, q to their DC terms, so the paper's model is a
    constant while the truth is c·a(n·v, α), a = A + B the f_DV albedo (0.33 … 1 for α ∈ [0.2, 1]): the model
    spends its bands on the albedo instead of the lighting. We fit log(E0 / a(n·v, α)) instead (a from the shared
    DFG table, a fixed per-row offset: [p; q] = A⁺ · (log E0 − log a)) and reconstruct
        E = exp(⟨…, p⟩ + ⟨…, q⟩) · (F0·A + B)(n·v, α),
    which equals a·PQ·(F0 + (1 − F0)·τ) with the consistent tail ratio τ = B/(A + B): the same Fresnel treatment
    as Eq. 5/15, now exact for constant radiance. ``albedo_normalized=False`` is the paper's formulation
    (E = PQ·(F0 + (1 − F0) τ)). Both are measured in docs/reflection.md.

Log guard
    Black or near-black hemispheres are real (E0 = 0 makes log undefined). Every sample is floored at
    floor = max(ε_rel · mean(E0 of the probe over all samples and channels), ε_abs), ε_rel = 1e-4, ε_abs = 1e-12,
    before the log. The floor is relative so that it is scale invariant (fit(c·L) = fit(L) + log c on the DC term)
    and probe-wide (not per channel) so that a channel that is absent stays ~1e-4 below the others instead of
    pulling the log to −∞. An all-black probe gives E0 ≡ ε_abs, i.e. finite coefficients evaluating to ~1e-12.

Design (paper Sec. 5.1: 64 normals × 64 views × 4 α ∈ [0.2, 1])
    normals: Fibonacci set; views: a Fibonacci set over the hemisphere of each normal (n·v ≥ 0.02), turned about
    the normal by the golden angle per normal so that the local view sets do not repeat; α: uniform in
    [alpha_min, alpha_max]. Deterministic: no random numbers.

Fit grid (multi-resolution splat; method notes §4 "lower mip levels for rough α")
    E0 at a design row is Σ_t w(l_t) Ω_t L_t with the smooth kernel w = f_DV⟨l, n⟩ (per steradian). We interpolate
    w bilinearly (in cube-face coordinates) from the nodes of a coarse grid, w(l_t) ≈ Σ_c b_ct w(l_c), so that
        E0 ≈ Σ_c w(l_c) F_c,   F_c = Σ_t b_ct Ω_t L_t                                                 (splat)
    F is the capture's flux *splatted* bilinearly onto the coarse nodes: exact total flux, and a sun between
    nodes keeps its centroid (a box filter would move it to a texel centre: measured 4–9 % fit error vs the
    plain fit on ``park``/``sunrise`` at 32², 1 % with the splat). The splat is separable per face once Ω is
    applied (Ω·L for a few faces at a time, in cache; along rows by windows — N = S·g: every node takes the same
    taps of its ≤ 2S nearest rows, :func:`_row_window`; a dense GEMM per face otherwise — then one GEMM along
    columns; coarser grids are splatted from the finest grid's flux). The node grid follows the lobe width (∝ α):
    ``fit_face_size`` for α < 2·0.2, halved per doubling of α beyond 0.2, never below ``min_fit_face_size`` (default design: 16, 8, 8, 8 for α = 0.2, 0.47,
    0.73, 1) — rows of one α slab use one grid, so W is a few dense blocks (4096 × 1536, 12288 × 384):
    11 M multiply-adds per channel instead of 100 M for a dense 32² grid. Measured in docs/reflection.md against
    the plain fit (E0 by brute force over every capture texel, :func:`plain_e0_samples`).
    Cubic (Catmull–Rom) coarse splats were measured and rejected: lower error on the 11 shared maps (max 3.9 % /
    mean 1.7 % vs 4.7 / 2.1 %, or today's error with 0.77× the multiply-adds on grids 16, 7, 5, 4), but their
    negative taps make E0 negative on rows that face away from a sun, and with it the luminance row weights.

Weighted solve (beyond the paper; ``fit = "weighted"``, default)
    The log-space fit is a proxy for linear MSE (paper Sec. 5.3): a linear error δE ≈ E·δlog E, so a plain log fit
    gives a dark row as much say as a bright one. We weight each row by its luminance (the IRLS weight halfway
    between the log fit, weight 1, and first-order linear MSE, weight E²; measured: E¹ beats both):
        [p; q] = argmin Σ_m w_m (A_m x − log E0_m)²,  w_m = Y(E0_m) / mean_m Y(E0_m) + w_min            (Eq. 13–14)
    solved per probe by the normal equations G x = Aᵀ W y. w_min = 1e-2 keeps G well conditioned when a sun makes
    a few rows dominate; as an *additive* floor it keeps w linear in the flux, w = Y(W·F)/mean + w_min, so the
    batch's Gram matrices are fixed operators applied to the splatted luminance flux,
        G_p = Σ_blocks [(A ⊙ A)ᵀ_rows · W_block] · Y(F_block,p) / mean_p + w_min · AᵀA    ((A ⊙ A): products
    A_mi A_mj, i ≤ j), ~1 M multiply-adds per probe instead of 9 M over the rows; the solve stays
    GEMM → log → GEMM. ``fit = "log"`` is the paper's unweighted fit (A⁺ · log E0).

Fused fit (:func:`fit_shexp`; :func:`fit_shexp_stepwise` is the same solve one full pass per step)
    Everything but W·F and the log is a fixed linear map of the flux, so it is precomposed: the probe means of E0
    and of Y(E0) (log floor, row-weight normaliser) are (1ᵀW)·F / M, the albedo term Aᵀ W log a is
    Σ_b [Aᵀ diag(log a) W_b] · Y(F_b) / mean + w_min Aᵀ log a, and the Gram as above. What is left runs over row
    chunks of ~2 MB (E0 chunk = W_rows·F, luminance, weights, floor, log, weighting in place, += Aᵀ_rows · chunk),
    so the (M, 3P) samples never exist and the temporaries stay in cache; columns are (channel, probe) so the
    weights broadcast over contiguous probes. Measured by :mod:`bakery.bench.shexp_fit` (batch 64, 6×128²).
    W is half zero (⟨l, n⟩₊: a row's lower hemisphere) and full rank (all 1536 / 384 singular values above 1e-7
    of the largest; at 1e-3 still 1498 / 384, the hemisphere edge is sharp), so W·F runs over *tiles*
    (:func:`weight_tiles`): the rows of two neighbouring normals (32 Fibonacci clusters) times the nodes where any
    of them is non-zero, F gathered to those nodes: 0.58× the multiply-adds of the dense blocks, same products
    (single normals: 0.5×, but GEMMs too small to gain).
    Per normal, though, a slab can be low-rank: at α = 1, D = 1/π and V = ½/(n·l + n·v), so the kernel is
    n·l / (2π (n·l + n·v)) — one function of n·l per view, a Cauchy-like family of numerical rank 9–10 over
    the 64 views at 1e-7 (α ≤ 0.73: full, 64). Such a slab runs as U·(Vᵀ·F) (:func:`low_rank_slabs`: truncated
    SVD per normal, ‖ΔW_k‖_F ≤ 1e-7 ‖W_k‖_F), one GEMM over Vᵀ stacked for all normals and a batch of
    (n_views × r) products: 0.3× the slab's tile multiply-adds (default design: the α = 1 slab; W·F 19.3 → 17.4 M
    per probe). What remains is that GEMM (1.1 G multiply-adds per 64 probes) and the splat: Ω varies per texel
    and is not separable (rank 5 to float32), so Ω·L is formed once — a pass over the capture, memory-bound —
    before the windowed row splat (2S multiply-adds per texel and channel instead of the dense GEMM's g).

Notation
    M design rows, T fit-grid texels, P probes, C = 3 channels, K_p = (p_band+1)², K_q = (q_band+1)² − 1.

References
    [SHExp] Silvennoinen, Sloan, Iwanicki, Nowrouzezahrai, HPG 2025 (seed 000).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import lru_cache
from typing import Literal

import numpy as np
from numpy.lib.stride_tricks import as_strided

from bakery.brdf.ggx import reflect
from bakery.brdf.sampling import to_world
from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.reflection.reference import _weights_float32
from bakery.reflection.tables import OperatorCache
from bakery.sh.basis import evaluate_sh_basis, sh_bands
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.fibonacci import GOLDEN_ANGLE, fibonacci_directions

EPS_REL = 1e-4
EPS_ABS = 1e-12
#: Weighted solve: every row weight gets this fraction of the mean weight added (module doc "Weighted solve").
WEIGHT_MIN = 1e-2
#: Luminance used for the row weights (the bake's working space, :mod:`bakery.conventions`).
LUMINANCE = LUMINANCE_WEIGHTS.astype(np.float32)
#: Rows with α < 2·FINEST_GRID_ALPHA use the finest fit grid; it halves per doubling of α beyond (module doc).
FINEST_GRID_ALPHA = 0.2
FIT_MODES = ("weighted", "log")


@dataclass(frozen=True)
class SHExpFitFields:
    """The model orders, fit design, fit grid and solve of an SH-exp fit: the one home of these fields and their
    defaults, shared by :class:`SHExpSettings` and the encodings' recipe parameters
    (:class:`bakery.encodings.shexp.SHExp.Params` derives from it)."""

    p_band: int = 4
    q_band: int = 2
    n_normals: int = 64
    n_views: int = 64
    n_alphas: int = 4
    alpha_min: float = 0.2
    alpha_max: float = 1.0
    fit_face_size: int = 16
    min_fit_face_size: int = 8
    fit: Literal["weighted", "log"] = "weighted"
    albedo_normalized: bool = True


@dataclass(frozen=True)
class SHExpSettings(SHExpFitFields):
    """Model orders, fit design, fit grid and solve (all recorded in the store's ``settings``)."""

    alpha_spacing: str = "linear"

    def __post_init__(self) -> None:
        if self.fit not in FIT_MODES:
            raise ValueError(f"shexp fit must be one of {FIT_MODES}, got {self.fit!r}")
        if not 1 <= self.min_fit_face_size <= self.fit_face_size:
            raise ValueError(f"need 1 <= min_fit_face_size <= fit_face_size, got {self.min_fit_face_size}, "
                             f"{self.fit_face_size}")

    @classmethod
    def from_fields(cls, source: SHExpFitFields, **overrides: object) -> SHExpSettings:
        """Settings with every :class:`SHExpFitFields` field of ``source`` (e.g. an encoding's Params), then
        ``overrides``."""
        values = {f.name: getattr(source, f.name) for f in fields(SHExpFitFields)}
        return cls(**{**values, **overrides})

    @property
    def p_count(self) -> int:
        return (self.p_band + 1) ** 2

    @property
    def q_count(self) -> int:
        return (self.q_band + 1) ** 2 - 1

    @property
    def coefficient_count(self) -> int:
        return self.p_count + self.q_count


def vmf_band_factors(alpha: np.ndarray, max_band: int) -> np.ndarray:
    """vMF_l(1/α) = exp(−l(l+1)α/2) per flat SH index: α (...,) → (..., (L+1)²)  ([SHExp] Eq. 12)."""
    l = sh_bands(max_band)  # noqa: E741
    return np.exp(-0.5 * (l * (l + 1))[None, :] * np.asarray(alpha, dtype=np.float64).reshape(-1, 1)).reshape(
        np.shape(alpha) + (l.size,)
    )


def half_reflection(view: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """r = reflect(v, n) and h_r = (n + r)/|n + r| ([SHExp] Eq. 10): (..., 3) each."""
    r = reflect(view, normal)
    hr = np.asarray(normal, dtype=np.float64) + r
    hr /= np.maximum(np.linalg.norm(hr, axis=-1, keepdims=True), 1e-12)
    return r, hr


def design_matrix(view: np.ndarray, normal: np.ndarray, alpha: np.ndarray, settings: SHExpSettings) -> np.ndarray:
    """Rows [vMF ⊙ Y(r), (vMF ⊙ Y(h_r))[1:]] (M, K_p + K_q) of [SHExp] Eq. 14."""
    r, hr = half_reflection(view, normal)
    a = np.asarray(alpha, dtype=np.float64).reshape(-1)
    yp = evaluate_sh_basis(r.reshape(-1, 3), settings.p_band) * vmf_band_factors(a, settings.p_band)
    yq = evaluate_sh_basis(hr.reshape(-1, 3), settings.q_band) * vmf_band_factors(a, settings.q_band)
    return np.concatenate([yp, yq[:, 1:]], axis=1)


def design_alphas(settings: SHExpSettings) -> np.ndarray:
    """The design's α values (n_alphas,), ascending."""
    if settings.alpha_spacing == "linear":  # paper Sec. 5.1: uniform in α
        return np.linspace(settings.alpha_min, settings.alpha_max, settings.n_alphas)
    if settings.alpha_spacing == "perceptual":  # uniform in r = √α
        return np.linspace(np.sqrt(settings.alpha_min), np.sqrt(settings.alpha_max), settings.n_alphas) ** 2
    raise ValueError(f"unknown alpha_spacing {settings.alpha_spacing!r}")


def fit_design(settings: SHExpSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (v, n, α) design: views (M, 3), normals (M, 3), α (M,), M = n_alphas·n_normals·n_views (α slowest)."""
    normals = fibonacci_directions(settings.n_normals)
    # Fibonacci hemisphere (z = 1 − (i + ½)/n_views keeps n·v ≥ 1/(2 n_views) > 0), turned per normal.
    i = np.arange(settings.n_views)
    z = np.maximum(1.0 - (i + 0.5) / settings.n_views, 0.02)
    phi = i * GOLDEN_ANGLE
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    turn = np.arange(settings.n_normals)[:, None] * GOLDEN_ANGLE
    local = np.stack([rho * np.cos(phi + turn), rho * np.sin(phi + turn), np.broadcast_to(z, turn.shape[:1] + z.shape)], -1)
    views = to_world(local, normals[:, None, :])  # (n_normals, n_views, 3)
    alphas = design_alphas(settings)
    v = np.broadcast_to(views, (settings.n_alphas,) + views.shape).reshape(-1, 3)
    n = np.broadcast_to(normals[:, None, :], views.shape)
    n = np.broadcast_to(n, (settings.n_alphas,) + views.shape).reshape(-1, 3)
    a = np.repeat(alphas, settings.n_normals * settings.n_views)
    return np.ascontiguousarray(v), np.ascontiguousarray(n), a


def slab_face_sizes(settings: SHExpSettings, capture_face_size: int | None = None) -> tuple[int, ...]:
    """Fit-grid face size per design α (module doc "Fit grid"): ``fit_face_size`` halved ⌊log2(α/0.2)⌋ times
    (none below α = 0.4), at least ``min_fit_face_size``, at most the capture's face size."""
    sizes = []
    for alpha in design_alphas(settings):
        halvings = max(0, int(np.floor(np.log2(max(alpha, 1e-12) / FINEST_GRID_ALPHA) + 1e-9)))
        face = max(settings.min_fit_face_size, settings.fit_face_size >> halvings)
        sizes.append(min(face, capture_face_size) if capture_face_size else face)
    return tuple(sizes)


def splat_taps(face_size: int, grid_size: int, index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 1-D bilinear splat in face coordinates: fine texel i sits at coarse position x = (i + ½)·g/n − ½ and
    goes to nodes ⌊x⌋ and ⌊x⌋ + 1 (clamped at the face edge) with weights 1 − {x} and {x}.
    index (R,) → lower node (R,), upper node (R,), upper weight {x} (R,)."""
    x = (np.asarray(index) + 0.5) * grid_size / face_size - 0.5
    x0 = np.floor(x)
    frac = x - x0
    x0 = x0.astype(np.int64)
    return np.clip(x0, 0, grid_size - 1), np.clip(x0 + 1, 0, grid_size - 1), frac


@lru_cache(maxsize=16)
def splat_matrix(face_size: int, grid_size: int) -> np.ndarray:
    """1-D bilinear splat (grid_size, face_size) float32 (:func:`splat_taps`); every column sums to 1, so the
    splat preserves flux exactly."""
    cols = np.arange(face_size)
    lower, upper, frac = splat_taps(face_size, grid_size, cols)
    b = np.zeros((grid_size, face_size))
    np.add.at(b, (lower, cols), 1.0 - frac)
    np.add.at(b, (upper, cols), frac)
    b = b.astype(np.float32)
    b.setflags(write=False)
    return b


@lru_cache(maxsize=4)
def _solid_angle_rows(face_size: int) -> np.ndarray:
    """The texel solid angles of one face with every entry repeated per channel, Ω_ij (N, 3N) float32: multiplies
    a face's interleaved RGB rows in place of a broadcast."""
    omega = np.repeat(cube_texel_solid_angles(face_size)[0], 3, axis=1).astype(np.float32)  # the same on every face
    omega.setflags(write=False)
    return omega


@lru_cache(maxsize=8)
def _node_splat(grid_size: int, coarse_size: int) -> np.ndarray:
    """Column splat of node flux from grid g to a coarser grid, kron(Bᵀ, I₃) (3g, 3g') float32."""
    ops = np.kron(splat_matrix(grid_size, coarse_size).T, np.eye(3, dtype=np.float32)).astype(np.float32)
    ops.setflags(write=False)
    return ops


def splat_flux(cubes: np.ndarray, grids: tuple[int, ...],
               removed: tuple[np.ndarray, np.ndarray] | None = None) -> dict[int, np.ndarray]:
    """Captures (P, 6, N, N, 3) → flux splatted onto each node grid g: {g: (6·g², 3P) float32}, rows
    (face, row, column), columns (probe, channel) (module doc "Fit grid").

    The finest grid comes from the capture in two GEMM passes: Ω·L per chunk of faces (in cache) and the row
    splat of each face, then the column splat of every row at once; coarser grids are splatted from the finest
    grid's flux (flux stays exact; the coarse grids serve the wide lobes). ``removed`` = (probe index (R,), flat
    texel index (R,) into 6·N·N): texels treated as black (their splatted flux is subtracted — the capture is not copied)."""
    return _splat_flux(cubes, grids, removed, channel_major=False)


def _splat_flux(cubes: np.ndarray, grids: tuple[int, ...], removed: tuple[np.ndarray, np.ndarray] | None,
                channel_major: bool) -> dict[int, np.ndarray]:
    """:func:`splat_flux`; ``channel_major`` orders the columns (channel, probe) instead of (probe, channel)."""
    cubes = np.asarray(cubes, dtype=np.float32)
    p, n = cubes.shape[0], cubes.shape[2]
    grids = tuple(sorted(set(grids), reverse=True))
    finest = grids[0]
    faces = cubes.reshape(p * 6, n, 3 * n)  # (6P, N rows, 3N) view
    omega = _solid_angle_rows(n)
    by_rows = np.empty((p * 6, finest, 3 * n), dtype=np.float32)  # Σ_i B_ai Ω_ij L_ij per face
    chunk = max(1, _SPLAT_CHUNK_FLOATS // (3 * n * n))
    window = _row_window(n, finest)
    if window is None:  # N not a multiple of g: the dense row splat (g, N) as a GEMM per face
        rows_splat = splat_matrix(n, finest)
        flux = np.empty((min(chunk, p * 6), n, 3 * n), dtype=np.float32)
        for q0 in range(0, p * 6, chunk):  # Ω·L stays in cache for the row GEMM
            q1 = min(q0 + chunk, p * 6)
            np.multiply(faces[q0:q1], omega, out=flux[: q1 - q0])
            np.matmul(rows_splat, flux[: q1 - q0], out=by_rows[q0:q1])
    else:  # N = S·g: node a's rows are the window of padded rows [S·a, S·a + len(taps)) (:func:`_row_window`)
        taps, before, after = window
        padded = np.empty((min(chunk, p * 6), before + n + after, 3 * n), dtype=np.float32)
        rows_stride = padded.strides[1]
        for q0 in range(0, p * 6, chunk):  # Ω·L stays in cache for the windowed row splat
            q1 = min(q0 + chunk, p * 6)
            q = q1 - q0
            np.multiply(faces[q0:q1], omega, out=padded[:q, before : before + n])
            padded[:q, :before] = padded[:q, before : 2 * before][:, ::-1]  # mirrored rows: the clamped edge taps
            padded[:q, before + n :] = padded[:q, before + n - after : before + n][:, ::-1]
            windows = as_strided(padded, shape=(q, finest, taps.size, 3 * n),
                                 strides=(padded.strides[0], n // finest * rows_stride, rows_stride, padded.strides[2]),
                                 writeable=False)
            np.matmul(taps, windows, out=by_rows[q0:q1])  # (q, g, 3N): one tap vector · window per node
    nodes = (by_rows.reshape(-1, 3 * n) @ _node_splat(n, finest)).reshape(p * 6, finest, 3 * finest)  # Σ_j B_bj (…)
    if removed is not None and len(removed[0]):
        nodes -= _removed_flux(cubes, removed, finest)
    out = {}
    for g in grids:
        if g != finest:  # from the finest grid's flux: (6P, g_f, 3g_f) → (6P, g, 3g)
            coarse = (nodes.reshape(-1, 3 * finest) @ _node_splat(finest, g)).reshape(p * 6, finest, 3 * g)
            grid = np.matmul(splat_matrix(finest, g), coarse)
        else:
            grid = nodes
        order = (1, 2, 3, 4, 0) if channel_major else (1, 2, 3, 0, 4)  # → (face, row, column, …)
        out[g] = np.ascontiguousarray(grid.reshape(p, 6, g, g, 3).transpose(order)).reshape(6 * g * g, 3 * p)
    return out


@lru_cache(maxsize=8)
def _row_window(face_size: int, grid_size: int) -> tuple[np.ndarray, int, int] | None:
    """The row splat of N = S·g texels onto g nodes as one window of taps per node: node a takes the padded rows
    [S·a, S·a + W) with the same taps (W,) float32 for every a — the bilinear tap 1 − |x − a| of
    :func:`splat_taps` at x = (i + ½)/S − ½ — and the face's rows mirrored ``before`` rows below row 0 and
    ``after`` above row N − 1:
    a mirrored row sits at x' = −1 − x (or 2g − 1 − x), so it gives node 0 (or g − 1) the tap the clamp of
    :func:`splat_taps` adds. 2S multiply-adds per texel and channel instead of the dense (g, N) GEMM's g.
    Returns (taps, before, after), or None when N is not a multiple of g (no common window)."""
    if face_size % grid_size:
        return None
    s = face_size // grid_size
    offsets = np.arange(-s, 2 * s)  # rows S·a + offset around node a, a superset of its support
    taps = np.maximum(0.0, 1.0 - np.abs((offsets + 0.5) / s - 0.5))
    support = np.flatnonzero(taps)
    first, last = offsets[support[0]], offsets[support[-1]]
    window = taps[support[0] : support[-1] + 1].astype(np.float32)
    window.setflags(write=False)
    return window, int(-first), int(s * (grid_size - 1) + last + 1 - face_size)


#: Floats of Ω·L per chunk of faces in :func:`splat_flux` (128 k: 512 kB, two faces at 128², in L2 with the
#: capture rows being read; 1–8 faces measured: 2–3 fastest, within 10 %).
_SPLAT_CHUNK_FLOATS = 1 << 17


def _removed_flux(cubes: np.ndarray, removed: tuple[np.ndarray, np.ndarray], grid_size: int) -> np.ndarray:
    """The splatted flux of the ``removed`` texels on grid g, laid out like :func:`splat_flux`'s intermediate
    (6P, g, 3g): each texel's Ω·L lands on its 2 × 2 nodes with the bilinear splat weights (scatter-add)."""
    p, n = cubes.shape[0], cubes.shape[2]
    probe, texel = (np.asarray(x, dtype=np.int64) for x in removed)
    face, row, col = texel // (n * n), (texel // n) % n, texel % n
    flux = cube_texel_solid_angles(n)[0][row, col, None] * cubes[probe, face, row, col]  # (R, 3) Ω L

    r0, r1, fr = splat_taps(n, grid_size, row)
    c0, c1, fc = splat_taps(n, grid_size, col)
    wr0, wr1, wc0, wc1 = 1.0 - fr, fr, 1.0 - fc, fc
    out = np.zeros(grid_size * p * 6 * grid_size * 3)
    q = probe * 6 + face
    for a, wa in ((r0, wr0), (r1, wr1)):
        for b, wb in ((c0, wc0), (c1, wc1)):
            base = ((q * grid_size + a) * grid_size + b) * 3
            for c in range(3):
                out += np.bincount(base + c, weights=wa * wb * flux[:, c], minlength=out.size)
    return out.reshape(p * 6, grid_size, 3 * grid_size).astype(np.float32)


@dataclass(frozen=True)
class WeightBlock:
    """Rows [start, stop) of the design (whole α slabs) on node grid ``face_size``: W (rows, 6·g²) float32 =
    f_DV(v, n, l_c, α)⟨l_c, n⟩₊ at the nodes (per steradian; Ω is in the splatted flux)."""

    start: int
    stop: int
    face_size: int
    weights: np.ndarray


@dataclass(frozen=True)
class WeightTile:
    """The rows of one W block whose normals share a cluster, restricted to the nodes where any of them is
    non-zero (module doc "Fused fit": W is zero wherever ⟨l, n⟩ ≤ 0). ``rows`` (R,) ascending design rows,
    ``nodes`` (T_k,) ascending node indices of grid ``face_size``; ``weights`` (R, T_k) = W[rows][:, nodes]
    float32 (every omitted entry of those rows is exactly 0), ``design_t`` (K, R) = Aᵀ[:, rows] and ``pinv``
    (K, R) = A⁺[:, rows] float32."""

    face_size: int
    rows: np.ndarray
    nodes: np.ndarray
    weights: np.ndarray
    design_t: np.ndarray
    pinv: np.ndarray


@dataclass(frozen=True)
class LowRankSlab:
    """One α slab of a W block whose rows are low-rank per design normal, W·F = U·(Vᵀ·F) (module doc "Fused fit").
    ``rows`` (R,) = the slab's design rows (normal-major: R = n_normals·n_views); per normal k, W[rows of k] ≈
    ``left[k]`` (n_views, r) · ``right[k·r : (k+1)·r]`` (r, 6g²), float32, r the largest rank of the slab's
    normals (padded with zero columns); ``design_t`` (K, R) = Aᵀ[:, rows] and ``pinv`` (K, R) = A⁺[:, rows]."""

    face_size: int
    rows: np.ndarray
    left: np.ndarray
    right: np.ndarray
    design_t: np.ndarray
    pinv: np.ndarray

    @property
    def rank(self) -> int:
        return int(self.left.shape[2])


@dataclass(frozen=True)
class SHExpOperators:
    """Cached fixed operators of one settings: the W blocks, A (M, K), A⁺ (K, M) float32, the products
    A_mi A_mj (i ≤ j) transposed (K(K+1)/2, M) float32 for the weighted normal equations, the per-row log-albedo
    offset (M,) (zeros unless ``albedo_normalized``) with its image A⁺·log a (K,), Aᵀ (K, M) and Aᵀ diag(log a)
    (K, M) float32."""

    blocks: tuple[WeightBlock, ...]
    design: np.ndarray
    pinv: np.ndarray
    pair_products_t: np.ndarray
    log_albedo: np.ndarray
    pinv_log_albedo: np.ndarray
    design_t: np.ndarray
    albedo_design_t: np.ndarray
    gram_operators: tuple[np.ndarray, ...]
    design_gram_upper: np.ndarray
    #: per W block, its column sums 1ᵀW (6g²,) float32: Σ_m E0_m = (1ᵀW)·F without forming E0 (fused fit)
    column_sums: tuple[np.ndarray, ...] = ()
    #: per W block, Aᵀ diag(log a) W (K, 6g²) float32: Aᵀ W log a = Σ_b (…)·Y(F_b)/mean + w_min Aᵀ log a (fused fit)
    albedo_flux_operators: tuple[np.ndarray, ...] = ()
    #: the W blocks cut into normal-cluster tiles without their zero columns (:func:`weight_tiles`; fused fit)
    tiles: tuple[WeightTile, ...] = ()
    #: the α slabs whose W·F runs as U·(Vᵀ·F) instead of tiles (:func:`low_rank_slabs`; fused fit)
    low_rank: tuple[LowRankSlab, ...] = ()


#: Shared table resolution used by the albedo normalisation (same table as the encodings store).
TABLE_SIZE = 64
TABLE_SAMPLES = 64


def design_albedo(view: np.ndarray, normal: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """f_DV albedo a = A + B (M,) at (n·v, α) from the shared DFG table (bilinear)."""
    from bakery.reflection.tables import compute_dfg_tables, lookup_table

    tables = compute_dfg_tables(TABLE_SIZE, TABLE_SAMPLES)
    nv = np.clip(np.sum(np.asarray(view) * np.asarray(normal), axis=-1), 0.0, 1.0)
    return lookup_table(tables.albedo, nv, np.asarray(alpha, dtype=np.float64))


def _kernel_at_nodes(v: np.ndarray, n: np.ndarray, a: np.ndarray, face_size: int) -> np.ndarray:
    """f_DV⟨l, n⟩₊ (m, 6g²) float32 at the node directions of grid ``face_size`` ([SHExp] Eq. 6 per steradian)."""
    dirs = cube_texel_directions(face_size).reshape(-1, 3)
    l_t = np.ascontiguousarray(dirs.T.astype(np.float32))
    ones = np.ones(dirs.shape[0], dtype=np.float32)
    out = np.empty((v.shape[0], dirs.shape[0]), dtype=np.float32)
    rows = max(1, 1_000_000 // dirs.shape[0])
    for s in range(0, v.shape[0], rows):
        sl = slice(s, s + rows)
        out[sl] = _weights_float32(l_t, ones, v[sl], n[sl], a[sl])[0]
    return out


def _design_blocks(settings: SHExpSettings, faces: tuple[int, ...]) -> tuple[WeightBlock, ...]:
    """W blocks for the design of ``settings`` on per-slab grids ``faces`` (cached on disk by the encoding layer)."""
    v, n, a = fit_design(settings)
    per_slab = settings.n_normals * settings.n_views
    blocks, slab = [], 0
    while slab < len(faces):
        last = slab
        while last + 1 < len(faces) and faces[last + 1] == faces[slab]:
            last += 1
        start, stop = slab * per_slab, (last + 1) * per_slab
        key = "shexp-W-v2-" + repr((settings.n_normals, settings.n_views, settings.n_alphas, settings.alpha_min,
                                     settings.alpha_max, settings.alpha_spacing, slab, last, faces[slab]))
        weights = OperatorCache.load(key)
        if weights is None:
            sl = slice(start, stop)
            weights = OperatorCache.save(key, _kernel_at_nodes(v[sl], n[sl], a[sl], faces[slab]))
        weights = np.asarray(weights)
        weights.setflags(write=False)
        blocks.append(WeightBlock(start, stop, faces[slab], weights))
        slab = last + 1
    return tuple(blocks)


#: Normals per tile of the fused fit's W·F: 2 (32 clusters of the 64-normal design; 16 clusters: 5 % slower).
NORMALS_PER_TILE = 2


def weight_tiles(settings: SHExpSettings, blocks: tuple[WeightBlock, ...], design_t: np.ndarray,
                 pinv: np.ndarray, skip_slabs: tuple[int, ...] = ()) -> tuple[WeightTile, ...]:
    """Cut every W block into tiles of the rows whose normals lie nearest the same of ⌈n_normals / 2⌉ Fibonacci
    directions, each keeping only the nodes where one of its rows is non-zero. W is zero on the lower hemisphere
    of a row's normal (⟨l, n⟩₊), so a tile of nearby normals drops about 40 % of the block (the union of their
    hemispheres): W·F costs 0.58× the dense multiply-adds on the default design, with the same products.
    ``skip_slabs``: α slabs (design order) left out of the tiles (their W·F runs through :func:`low_rank_slabs`)."""
    per_normal = settings.n_views
    per_slab = settings.n_normals * per_normal
    normals = fit_design(settings)[1][::per_normal][: settings.n_normals]  # (n_normals, 3), the slab order
    centres = fibonacci_directions(max(1, -(-settings.n_normals // NORMALS_PER_TILE)))
    cluster = np.argmax(normals @ centres.T, axis=1)  # (n_normals,) nearest centre
    layout = []  # (block, design rows, nodes) per tile
    for block in blocks:
        kept = [s for s in range(block.start // per_slab, block.stop // per_slab) if s not in skip_slabs]
        local = (np.array(kept)[:, None, None] * per_slab - block.start
                 + np.arange(per_slab).reshape(1, settings.n_normals, per_normal))
        for k in np.unique(cluster) if kept else ():
            rows = np.sort(local[:, cluster == k].ravel())  # rows of the block, ascending
            layout.append((block, rows, np.flatnonzero((block.weights[rows] != 0).any(axis=0))))
    # every tile's W in one cached array: the workers of a bake map the same pages (one copy in memory and cache)
    key = "shexp-W-v2-tiles-v1-" + repr((settings.n_normals, settings.n_views, settings.n_alphas, settings.alpha_min,
                                      settings.alpha_max, settings.alpha_spacing,
                                      tuple(b.face_size for b in blocks), NORMALS_PER_TILE)) + (
                                      f"-skip{skip_slabs}" if skip_slabs else "")
    sizes = [rows.size * nodes.size for _, rows, nodes in layout]
    flat = OperatorCache.load(key)
    if flat is None or flat.shape != (sum(sizes),):
        flat = OperatorCache.save(key, np.concatenate([b.weights[rows][:, nodes].ravel() for b, rows, nodes in layout]))
    flat = np.asarray(flat)
    tiles, offset = [], 0
    for (block, rows, nodes), size in zip(layout, sizes, strict=True):
        weights = flat[offset : offset + size].reshape(rows.size, nodes.size)
        offset += size
        design_rows = rows + block.start
        tile = WeightTile(block.face_size, design_rows, nodes, weights,
                          np.ascontiguousarray(design_t[:, design_rows]), np.ascontiguousarray(pinv[:, design_rows]))
        for array in (tile.rows, tile.nodes, tile.weights, tile.design_t, tile.pinv):
            array.setflags(write=False)
        tiles.append(tile)
    return tuple(tiles)


#: A slab's normals are factored to ‖W_k − U_k V_kᵀ‖_F ≤ 1e-7 ‖W_k‖_F (W_k: the normal's rows): every entry then
#: within ~1e-6 of its row's largest, the order of the float32 rounding of the products themselves.
LOW_RANK_TOLERANCE = 1e-7
#: ... and only when the factored product costs at most this fraction of the tiles' multiply-adds for those rows.
LOW_RANK_MAX_COST = 0.5


def low_rank_slabs(settings: SHExpSettings, blocks: tuple[WeightBlock, ...], design_t: np.ndarray,
                   pinv: np.ndarray) -> tuple[LowRankSlab, ...]:
    """The α slabs whose W is low-rank per design normal (module doc "Fused fit"), factored by a truncated SVD
    (float64) of each normal's n_views rows over the nodes of its upper hemisphere: W_k = U_k Σ_k V_kᵀ, keeping
    the smallest rank r_k with Σ_{i>r_k} σ_i² ≤ (``LOW_RANK_TOLERANCE``·‖W_k‖_F)². A slab is factored when
    n_normals·r·(n_views + 6g²) multiply-adds (r = max_k r_k; Vᵀ stacked over every node, zero off the
    hemisphere: one GEMM) are at most ``LOW_RANK_MAX_COST`` of the tiles' (its rows × their hemisphere nodes).
    Cached like the tiles (one entry per slab: [r, U…, V…], [0] when the slab stays in the tiles)."""
    n_normals, n_views = settings.n_normals, settings.n_views
    per_slab = n_normals * n_views
    out = []
    for block in blocks:
        nodes = block.weights.shape[1]
        for slab in range(block.start // per_slab, block.stop // per_slab):
            key = "shexp-W-v2-lowrank-v1-" + repr((settings.n_normals, settings.n_views, settings.n_alphas,
                                                   settings.alpha_min, settings.alpha_max, settings.alpha_spacing,
                                                   slab, block.face_size, LOW_RANK_TOLERANCE, LOW_RANK_MAX_COST))
            flat = OperatorCache.load(key)
            if flat is None:
                flat = OperatorCache.save(key, _factor_slab(block, slab * per_slab - block.start, n_normals,
                                                            n_views))
            flat = np.asarray(flat)
            rank = int(flat[0])
            if rank == 0:
                continue
            split = 1 + n_normals * n_views * rank
            rows = np.arange(slab * per_slab, (slab + 1) * per_slab)
            factored = LowRankSlab(block.face_size, rows, flat[1:split].reshape(n_normals, n_views, rank),
                                   flat[split:].reshape(n_normals * rank, nodes),
                                   np.ascontiguousarray(design_t[:, rows]), np.ascontiguousarray(pinv[:, rows]))
            for array in (factored.rows, factored.design_t, factored.pinv):
                array.setflags(write=False)
            out.append(factored)
    return tuple(out)


def _factor_slab(block: WeightBlock, start: int, n_normals: int, n_views: int) -> np.ndarray:
    """[r, U (n_normals, n_views, r), Vᵀ (n_normals·r, 6g²)] flat float32 for the slab at block row ``start``, or
    [0] when factoring does not pay (:func:`low_rank_slabs`)."""
    weights = block.weights[start : start + n_normals * n_views].reshape(n_normals, n_views, -1)
    factors, tile_macs = [], 0
    for w in weights.astype(np.float64):
        support = np.flatnonzero(w.any(axis=0))  # the nodes of the normal's upper hemisphere
        u, sigma, vt = np.linalg.svd(w[:, support], full_matrices=False)
        tail = np.sqrt(np.cumsum((sigma**2)[::-1])[::-1])  # tail[i] = ‖σ_i, σ_i+1, …‖
        rank = int(np.count_nonzero(tail > LOW_RANK_TOLERANCE * tail[0]))
        factors.append((u[:, :rank] * sigma[:rank], vt[:rank], support))
        tile_macs += n_views * support.size
    rank = max(f[0].shape[1] for f in factors)
    if n_normals * rank * (n_views + weights.shape[2]) > LOW_RANK_MAX_COST * tile_macs:
        return np.zeros(1, dtype=np.float32)
    left = np.zeros((n_normals, n_views, rank))
    right = np.zeros((n_normals, rank, weights.shape[2]))
    for k, (u, vt, support) in enumerate(factors):
        left[k, :, : u.shape[1]] = u
        right[k, : vt.shape[0], support] = vt.T
    return np.concatenate([[rank], left.ravel(), right.ravel()]).astype(np.float32)


@lru_cache(maxsize=8)
def build_operators(settings: SHExpSettings, capture_face_size: int | None = None) -> SHExpOperators:
    """Build the W blocks, A, A⁺ and the pair products once per settings and capture face size (cached in memory,
    and on disk through :class:`OperatorCache` — a bake's workers load them instead of each spending ≈ 1 s)."""
    faces = slab_face_sizes(settings, capture_face_size)
    blocks = _design_blocks(settings, faces)
    names = [*_DERIVED_OPERATORS, *(f"{kind}{b}" for kind in _PER_BLOCK_OPERATORS for b in range(len(blocks)))]
    key = "shexp-W-v2-derived-v1-" + repr((settings, faces))
    derived = {name: OperatorCache.load(f"{key}-{name}") for name in names}
    if any(array is None for array in derived.values()):
        derived = {name: OperatorCache.save(f"{key}-{name}", array)
                   for name, array in _derived_operators(settings, blocks).items()}
    derived = {name: np.asarray(array) for name, array in derived.items()}
    for array in derived.values():
        array.setflags(write=False)
    per_block = {kind: tuple(derived[f"{kind}{b}"] for b in range(len(blocks))) for kind in _PER_BLOCK_OPERATORS}
    low_rank = low_rank_slabs(settings, blocks, derived["design_t"], derived["pinv"])
    per_slab = settings.n_normals * settings.n_views
    tiles = weight_tiles(settings, blocks, derived["design_t"], derived["pinv"],
                         tuple(int(s.rows[0]) // per_slab for s in low_rank))
    return SHExpOperators(blocks, derived["design"], derived["pinv"], derived["pair_products_t"],
                          derived["log_albedo"], derived["pinv_log_albedo"], derived["design_t"],
                          derived["albedo_design_t"], per_block["gram"], derived["design_gram_upper"],
                          per_block["column_sums"], per_block["albedo_flux"], tiles, low_rank)


#: The environment-independent arrays :func:`_derived_operators` builds once per settings (besides W), and those it
#: builds per W block (names suffixed with the block's index).
_DERIVED_OPERATORS = ("design", "pinv", "pair_products_t", "log_albedo", "pinv_log_albedo", "design_t",
                      "albedo_design_t", "design_gram_upper")
_PER_BLOCK_OPERATORS = ("gram", "column_sums", "albedo_flux")


def _derived_operators(settings: SHExpSettings, blocks: tuple[WeightBlock, ...]) -> dict[str, np.ndarray]:
    """A (M, K), A⁺ (K, M) float32, the pair products, the log albedo and, per W block, the fused fit's fixed
    operators (:class:`SHExpOperators`)."""
    v, n, a = fit_design(settings)
    design = design_matrix(v, n, a, settings)
    pinv = np.linalg.pinv(design).astype(np.float32)  # A⁺ of [SHExp] Eq. 14
    i, j = np.triu_indices(design.shape[1])
    products = design[:, i] * design[:, j]  # (M, K(K+1)/2) float64: A_mi A_mj, i ≤ j
    pair_products_t = np.ascontiguousarray(products.T, dtype=np.float32)  # G = Aᵀ diag(w) A
    if settings.albedo_normalized:
        log_albedo = np.log(np.maximum(design_albedo(v, n, a), 1e-6)).astype(np.float32)
    else:
        log_albedo = np.zeros(v.shape[0], np.float32)
    design_t = np.ascontiguousarray(design.T, dtype=np.float32)  # Aᵀ (K, M)
    albedo_design_t = np.ascontiguousarray(design.T * log_albedo[None, :], dtype=np.float32)  # Aᵀ diag(log a)
    out = {"design": design, "pinv": pinv, "pair_products_t": pair_products_t, "log_albedo": log_albedo,
           "pinv_log_albedo": (pinv @ log_albedo).astype(np.float32), "design_t": design_t,
           "albedo_design_t": albedo_design_t, "design_gram_upper": products.sum(axis=0)}  # AᵀA, i ≤ j
    # The luminance weights are linear in the flux (w = Y(W·F)/mean + w_min), so the batch Gram is
    # Σ_blocks [(A ⊙ A)ᵀ_rows · W_block] · Y(F_block) / mean + w_min · AᵀA: fixed (K(K+1)/2, 6g²) operators.
    for b, block in enumerate(blocks):
        weights = block.weights.astype(np.float64)
        out[f"gram{b}"] = (products[block.start : block.stop].T @ weights).astype(np.float32)
        out[f"column_sums{b}"] = weights.sum(axis=0).astype(np.float32)
        out[f"albedo_flux{b}"] = (albedo_design_t[:, block.start : block.stop].astype(np.float64)
                                  @ block.weights).astype(np.float32)
    return out


def design_e0_samples(cubes: np.ndarray, settings: SHExpSettings,
                      removed: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """E0 at the design rows through the splatted multi-resolution grids (module doc "Fit grid"): (M, 3P);
    ``removed`` texels count as black (:func:`splat_flux`)."""
    return _samples_and_flux(cubes, settings, removed)[0]


def _samples_and_flux(cubes: np.ndarray, settings: SHExpSettings,
                      removed: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    cubes = np.asarray(cubes, dtype=np.float32)
    ops = build_operators(settings, int(cubes.shape[2]))
    flux = splat_flux(cubes, tuple(b.face_size for b in ops.blocks), removed)
    e0 = np.empty((ops.design.shape[0], 3 * cubes.shape[0]), dtype=np.float32)
    for block in ops.blocks:
        np.matmul(block.weights, flux[block.face_size], out=e0[block.start : block.stop])  # W · F (GEMM)
    return e0, flux


def plain_e0_samples(cubes: np.ndarray, settings: SHExpSettings) -> np.ndarray:
    """The plain formulation: E0 at the design rows by brute force over every capture texel (exact solid angles,
    :func:`bakery.reflection.reference.integrate_reflection`): (M, 3P) float64. Ground truth for the fit grid."""
    from bakery.reflection.reference import integrate_reflection
    from bakery.sphere.grid import SphericalSamples

    cubes = np.asarray(cubes, dtype=np.float32)
    n = cubes.shape[2]
    dirs = cube_texel_directions(n).reshape(-1, 3)
    omega = cube_texel_solid_angles(n).reshape(-1)
    v, nrm, a = fit_design(settings)
    out = [integrate_reflection(SphericalSamples(dirs, omega, cube.reshape(-1, 3)), v, nrm, a)[0] for cube in cubes]
    return np.concatenate(out, axis=1)


def log_e0(e0: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Guarded log of E0 samples (M, 3P) (module doc "Log guard") and the floored samples: both (M, 3P)."""
    e0 = np.asarray(e0)
    column_sums = np.ones(e0.shape[0], dtype=e0.dtype) @ e0  # (3P,) GEMV
    mean = column_sums.astype(np.float64).reshape(p, 3).sum(axis=1) / (3 * e0.shape[0])  # (P,)
    floor = np.repeat(np.maximum(EPS_REL * mean, EPS_ABS).astype(e0.dtype), 3)  # (3P,)
    floored = np.maximum(e0, floor[None, :])
    return np.log(floored), floored


def row_weights(e0: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights (M, P) of the weighted solve, w = Y(E0) / mean_m Y(E0) + ``WEIGHT_MIN``, and the means (P,)
    (an additive floor keeps w linear in the flux, so the batch Gram is a fixed operator; module doc)."""
    lum = np.asarray(e0, dtype=np.float32) @ _luminance_operator(p)  # (M, P), one GEMM
    mean = np.maximum(np.ones(lum.shape[0], dtype=lum.dtype) @ lum / lum.shape[0], np.float32(EPS_ABS))
    lum /= mean[None, :]
    lum += np.float32(WEIGHT_MIN)
    return lum, mean


@lru_cache(maxsize=8)
def _luminance_operator(p: int) -> np.ndarray:
    """kron(I_P, Y) (3P, P) float32: interleaved RGB columns → luminance per probe."""
    op = np.kron(np.eye(p, dtype=np.float32), LUMINANCE[:, None]).astype(np.float32)
    op.setflags(write=False)
    return op


def solve_coefficients(log_samples: np.ndarray, operators: SHExpOperators, p: int,
                       weights: np.ndarray | None = None, gram_upper: np.ndarray | None = None) -> np.ndarray:
    """[p; q] = argmin Σ_m w_m (A_m x − (log E0 − log a)_m)² ([SHExp] Eq. 13–14; a ≡ 1 unless albedo-normalised):
    log samples (M, 3P), weights (M, P) or None (unweighted: A⁺·(…)) → (P, K, 3). ``gram_upper`` (P, K(K+1)/2):
    Aᵀ diag(w) A if already known (:func:`fit_shexp` gets it from the flux), else one GEMM over the rows."""
    log_samples = np.asarray(log_samples, dtype=np.float32)
    if weights is None:
        coeffs = operators.pinv @ log_samples  # (K, 3P)
        coeffs -= operators.pinv_log_albedo[:, None]
        return coeffs.reshape(-1, p, 3).transpose(1, 0, 2).astype(np.float32)
    k = operators.design.shape[1]
    weights = np.asarray(weights, dtype=np.float32)
    if gram_upper is None:
        gram_upper = (operators.pair_products_t @ weights).T.astype(np.float64)  # (P, K(K+1)/2): Aᵀ diag(w) A
    gram = np.zeros((p, k, k))
    i, j = np.triu_indices(k)
    gram[:, i, j] = gram_upper
    gram[:, j, i] = gram_upper
    weighted = np.repeat(weights, 3, axis=1)  # (M, 3P)
    weighted *= log_samples
    rhs = (operators.design_t @ weighted).reshape(k, p, 3)  # Aᵀ W log E0
    rhs -= (operators.albedo_design_t @ weights)[:, :, None]  # − Aᵀ W log a
    return np.linalg.solve(gram, rhs.transpose(1, 0, 2).astype(np.float64)).astype(np.float32)


def solve_from_samples(e0: np.ndarray, settings: SHExpSettings, operators: SHExpOperators) -> np.ndarray:
    """Coefficients (P, K, 3) from E0 samples (M, 3P) alone: guarded log, then the weighted or plain solve."""
    p = e0.shape[1] // 3
    logs, _ = log_e0(e0, p)
    weights = row_weights(e0, p)[0] if settings.fit == "weighted" else None
    return solve_coefficients(logs, operators, p, weights)


def fit_shexp(cubes: np.ndarray, settings: SHExpSettings,
              removed: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Fit P captures (P, 6, N, N, 3) → coefficients (P, K_p + K_q, 3) float32: splat → GEMM → log → GEMM.
    ``removed`` = (probe index, flat texel index) arrays of texels fitted as black (:func:`splat_flux`).

    Fused over row chunks (module doc "Fused fit"); the same least squares as :func:`fit_shexp_stepwise`."""
    cubes = np.asarray(cubes, dtype=np.float32)
    ops = build_operators(settings, int(cubes.shape[2]))
    p = cubes.shape[0]
    # flux with channel-major columns (c, p): the row weights (r, P) then broadcast over contiguous P
    flux = _splat_flux(cubes, tuple(b.face_size for b in ops.blocks), removed, channel_major=True)
    m, k = ops.design.shape
    # row means of E0 per (channel, probe) from the flux: Σ_m (W·F)_m = (1ᵀW)·F
    total = sum(c.astype(np.float64) @ flux[b.face_size] for c, b in zip(ops.column_sums, ops.blocks, strict=True))
    mean = total.reshape(3, p).sum(axis=0) / (3 * m)  # (P,) over rows and channels (module doc "Log guard")
    floor = np.tile(np.maximum(EPS_REL * mean, EPS_ABS).astype(np.float32), 3)  # (3P,)
    weighted = settings.fit == "weighted"
    if weighted:
        lum_flux = {g: np.matmul(LUMINANCE, f.reshape(-1, 3, p)) for g, f in flux.items()}  # Y(F) (6g², P)
        lum_mean = np.maximum(LUMINANCE.astype(np.float64) @ total.reshape(3, p) / m, EPS_ABS)  # (P,)
        inv_mean = (1.0 / lum_mean).astype(np.float32)
    rows = int(np.clip(_CHUNK_FLOATS // (3 * p), 64, 4096))
    e0 = np.empty((max(rows, settings.n_views), 3 * p), dtype=np.float32)  # a chunk holds one normal's views
    w = np.empty((e0.shape[0], p), dtype=np.float32)
    part = np.empty((k, 3 * p), dtype=np.float32)
    rhs = np.zeros((k, 3 * p))  # float64 accumulator over the chunks

    def accumulate(e: np.ndarray, right: np.ndarray) -> None:
        """rhs += Aᵀ_rows · (w ⊙ log max(E0, floor)) (or A⁺_rows · log …) for one chunk E0 (rows, 3P)."""
        if weighted:  # w = Y(E0)/mean + w_min of the unfloored samples
            ww = w[: e.shape[0]]
            np.matmul(LUMINANCE, e.reshape(-1, 3, p), out=ww)
            ww *= inv_mean
            ww += np.float32(WEIGHT_MIN)
        np.maximum(e, floor, out=e)  # log guard
        np.log(e, out=e)
        if weighted:
            e.reshape(-1, 3, p)[...] *= ww[:, None, :]  # W log E0
        np.matmul(right, e, out=part)
        np.add(rhs, part, out=rhs)

    gathered = np.empty((max((t.nodes.size for t in ops.tiles), default=0), 3 * p), dtype=np.float32)
    for tile in ops.tiles:
        # F at its nodes (mode 'clip': the indices are in range, and 'raise' would buffer the output)
        f = np.take(flux[tile.face_size], tile.nodes, axis=0, out=gathered[: tile.nodes.size], mode="clip")
        right = tile.design_t if weighted else tile.pinv  # Aᵀ (weighted normal equations) or A⁺ (plain log fit)
        for r0 in range(0, tile.rows.size, rows):
            r1 = min(r0 + rows, tile.rows.size)
            e = e0[: r1 - r0]
            np.matmul(tile.weights[r0:r1], f, out=e)  # E0 = W·F (GEMM over the tile's non-zero nodes)
            accumulate(e, right[:, r0:r1])
    for slab in ops.low_rank:  # E0 = U·(Vᵀ·F) per normal: one GEMM, then a batch of (n_views, r)·(r, 3P)
        projected = (slab.right @ flux[slab.face_size]).reshape(settings.n_normals, slab.rank, 3 * p)
        right = slab.design_t if weighted else slab.pinv
        normals = max(1, rows // settings.n_views)
        for k0 in range(0, settings.n_normals, normals):
            k1 = min(k0 + normals, settings.n_normals)
            e = e0[: (k1 - k0) * settings.n_views]
            np.matmul(slab.left[k0:k1], projected[k0:k1], out=e.reshape(k1 - k0, settings.n_views, 3 * p))
            accumulate(e, right[:, k0 * settings.n_views : k1 * settings.n_views])
    rhs = rhs.reshape(k, 3, p)
    if not weighted:
        return np.ascontiguousarray((rhs - ops.pinv_log_albedo[:, None, None]).transpose(2, 0, 1), dtype=np.float32)
    # Aᵀ W log a and Aᵀ W A from the luminance flux (w is linear in it; module doc "Weighted solve")
    albedo = sum(o @ lum_flux[b.face_size] for o, b in zip(ops.albedo_flux_operators, ops.blocks, strict=True))
    albedo = albedo * inv_mean[None, :] + np.float32(WEIGHT_MIN) * ops.albedo_design_t.sum(axis=1)[:, None]
    gram = sum(g @ lum_flux[b.face_size] for g, b in zip(ops.gram_operators, ops.blocks, strict=True))
    gram_upper = (gram.T.astype(np.float64) / lum_mean[:, None]) + WEIGHT_MIN * ops.design_gram_upper[None, :]
    return _solve_normal_equations(gram_upper, (rhs - albedo[:, None, :]).transpose(0, 2, 1), k)


#: Floats per row chunk of the fused fit's E0 (512 k: 2 MB, one L2; the chunk and its log stay in cache).
_CHUNK_FLOATS = 1 << 19


def _solve_normal_equations(gram_upper: np.ndarray, rhs: np.ndarray, k: int) -> np.ndarray:
    """Solve G x = b per probe: upper triangles (P, K(K+1)/2) float64, right-hand sides (K, P, 3) → (P, K, 3)."""
    p = gram_upper.shape[0]
    gram = np.empty((p, k, k))
    i, j = np.triu_indices(k)
    gram[:, i, j] = gram_upper
    gram[:, j, i] = gram_upper
    return np.linalg.solve(gram, rhs.transpose(1, 0, 2).astype(np.float64)).astype(np.float32)


def fit_shexp_stepwise(cubes: np.ndarray, settings: SHExpSettings,
              removed: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """:func:`fit_shexp` step by step (one full pass over the (M, 3P) samples per step; the 1.1 formulation,
    kept for the bench and as the batched reference of the fused fit): splat → W·F → log → weights → solve."""
    cubes = np.asarray(cubes, dtype=np.float32)
    ops = build_operators(settings, int(cubes.shape[2]))
    e0, flux = _samples_and_flux(cubes, settings, removed)
    p = cubes.shape[0]
    logs, _ = log_e0(e0, p)
    if settings.fit != "weighted":
        return solve_coefficients(logs, ops, p)
    weights, mean = row_weights(e0, p)
    luminance = _luminance_operator(p)
    gram = sum(g @ (flux[b.face_size] @ luminance) for g, b in zip(ops.gram_operators, ops.blocks, strict=True))
    gram_upper = (gram / mean[None, :]).T.astype(np.float64) + WEIGHT_MIN * ops.design_gram_upper[None, :]
    return solve_coefficients(logs, ops, p, weights, gram_upper)


def _reference_fit_shexp(cubes: np.ndarray, settings: SHExpSettings, plain: bool = False) -> np.ndarray:
    """Per-probe fit with a direct least-squares solve (lstsq on √w·A, float64) of the same samples — or, with
    ``plain``, of the plain brute-force samples (:func:`plain_e0_samples`)."""
    cubes = np.asarray(cubes, dtype=np.float32)
    ops = build_operators(settings, int(cubes.shape[2]))
    out = []
    for cube in cubes:
        e0 = plain_e0_samples(cube[None], settings) if plain else design_e0_samples(cube[None], settings)
        logs, _ = log_e0(e0.astype(np.float32), 1)
        target = logs.astype(np.float64) - ops.log_albedo[:, None]
        if settings.fit == "weighted":
            root = np.sqrt(row_weights(e0.astype(np.float32), 1)[0].astype(np.float64))  # (M, 1)
            coeffs, *_ = np.linalg.lstsq(ops.design * root, target * root, rcond=None)
        else:
            coeffs, *_ = np.linalg.lstsq(ops.design, target, rcond=None)
        out.append(coeffs.astype(np.float32))
    return np.stack(out)


def evaluate_pq(coefficients: np.ndarray, view: np.ndarray, normal: np.ndarray, alpha: np.ndarray, settings: SHExpSettings) -> np.ndarray:
    """P·Q (P, M, 3) = exp(A(v, n, α) · [p; q]) ([SHExp] Eq. 9–11) for coefficients (P, K, 3)."""
    a = np.broadcast_to(np.asarray(alpha, dtype=np.float64).reshape(-1), (np.asarray(view).reshape(-1, 3).shape[0],))
    design = design_matrix(np.asarray(view).reshape(-1, 3), np.asarray(normal).reshape(-1, 3), a, settings)
    return np.exp(np.einsum("mk,pkc->pmc", design, np.asarray(coefficients, dtype=np.float64)))


def evaluate_e0(coefficients: np.ndarray, view: np.ndarray, normal: np.ndarray, alpha: np.ndarray, settings: SHExpSettings) -> np.ndarray:
    """Base reflectance E0 (P, M, 3): P·Q, times the albedo a(n·v, α) when albedo-normalised."""
    pq = evaluate_pq(coefficients, view, normal, alpha, settings)
    if not settings.albedo_normalized:
        return pq
    v = np.asarray(view, dtype=np.float64).reshape(-1, 3)
    a = np.broadcast_to(np.asarray(alpha, dtype=np.float64).reshape(-1), (v.shape[0],))
    return pq * design_albedo(v, np.asarray(normal, dtype=np.float64).reshape(-1, 3), a)[None, :, None]


def clamped_pq(coefficients: np.ndarray, view: np.ndarray, normal: np.ndarray, alpha: np.ndarray,
               settings: SHExpSettings, alpha_range: np.ndarray | None = None) -> np.ndarray:
    """P·Q (P, M, 3) with α clamped per probe into its fitted range ``alpha_range`` (P, 2) = [α_lo, α_hi] (None:
    the settings' [alpha_min, alpha_max]): outside the fitted range the model is evaluated at the range's end, never
    extrapolated (below α_lo the vMF factors would let the log-space peak grow without bound: +364 % at α = 0 with
    peaks 8× the reference maximum, issue 12). Probes with equal ranges share one design matrix."""
    coefficients = np.asarray(coefficients, dtype=np.float64)
    a = np.asarray(alpha, dtype=np.float64).reshape(-1)
    if alpha_range is None:
        alpha_range = np.tile([settings.alpha_min, settings.alpha_max], (coefficients.shape[0], 1))
    ranges = np.asarray(alpha_range, dtype=np.float64).reshape(-1, 2)
    out = np.empty((coefficients.shape[0], a.shape[0], coefficients.shape[-1]))
    unique, inverse = np.unique(ranges, axis=0, return_inverse=True)
    for u, (lo, hi) in enumerate(unique):
        probes = np.flatnonzero(inverse.reshape(-1) == u)
        out[probes] = evaluate_pq(coefficients[probes], view, normal, np.clip(a, lo, hi), settings)
    return out


def evaluate_shexp(
    coefficients: np.ndarray,
    table: np.ndarray,
    view: np.ndarray,
    normal: np.ndarray,
    alpha: np.ndarray,
    f0: np.ndarray,
    settings: SHExpSettings,
    alpha_range: np.ndarray | None = None,
) -> np.ndarray:
    """Specular radiance E (P, M, 3) from coefficients (P, K, 3).

    Albedo-normalised: E = P·Q · (F0·A + B)(n·v, α), ``table`` the DFG table (Nα, Nv, 2).
    Paper: E = P·Q · (F0 + (1 − F0) τ(n·v, α)) ([SHExp] Eq. 5, 15), ``table`` the Fresnel-tail table (Nα, Nv).
    α must be in [0, 1] (ValueError otherwise); P·Q is evaluated at α clamped into each probe's fitted range
    (:func:`clamped_pq`), the table at the material's α; views below the horizon are clamped to it
    (:mod:`bakery.reflection.validation`).
    """
    from bakery.reflection.tables import lookup_table
    from bakery.reflection.validation import check_rows, clamp_view_to_horizon

    v, n, a = check_rows(view, normal, alpha)
    v = clamp_view_to_horizon(v, n)
    pq = clamped_pq(coefficients, v, n, a, settings, alpha_range)
    nv = np.clip(np.sum(v * n, axis=-1), 0.0, 1.0)
    f0 = np.asarray(f0, dtype=np.float64)
    f0 = f0[:, None] if f0.ndim == 1 else np.broadcast_to(f0, (v.shape[0], 3))
    if settings.albedo_normalized:
        ab = lookup_table(table, nv, a)  # (M, 2): A, B
        return pq * (f0 * ab[:, 0:1] + ab[:, 1:2])[None]
    tau = lookup_table(table, nv, a)  # (M,)
    return pq * (f0 + (1.0 - f0) * tau[:, None])[None]
