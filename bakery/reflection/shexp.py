"""SH exponentials for glossy reflection ([SHExp] Sec. 4), fitted as fixed linear operators (method notes §4).

Model ([SHExp] Eq. 9–12)
    E0(v, n, α) ≈ P(r, α) · Q(h_r, α),  r = reflect(v, n),  h_r = (n + r)/|n + r|                (Eq. 9–10)
    P = exp(⟨vMF(1/α) ⊙ Y(r), p⟩),  Q = exp(⟨vMF(1/α) ⊙ Y(h_r), q⟩)                            (Eq. 11)
    vMF_l(κ) = exp(−l(l+1) / (2κ)) = exp(−l(l+1) α / 2)                                        (Eq. 12)
    p: bands 0..p_band ((p_band+1)² coefficients); q: bands 1..q_band (no DC, Sec. 4.1 last paragraph).
    Fresnel: E = F0·E0 + (1 − F0)·E1, E1 ≈ E0 · τ(n·v, α) with the shared tail table (Eq. 5, 15; τ as defined
    in :mod:`bakery.reflection.tables`).

Fit as fixed linear operators (Eq. 13–14)
    The (v, n, α) design does not depend on the environment, so with the capture L (T, 3P) on the fit grid:
        E0_samples = W · L            W[m, t] = f_DV(v_m, n_m, l_t, α_m) ⟨l_t, n_m⟩ Ω_t   (M, T)    (Eq. 6)
        [p; q]     = A⁺ · log(max(E0_samples, floor))                                   (33, M)    (Eq. 13–14)
    A[m] = [vMF(α_m) ⊙ Y(r_m), vMF(α_m) ⊙ Y(h_r,m)[1:]] (Eq. 14). W and A⁺ are built once per settings and cached;
    a batch of P probes is GEMM → log → GEMM.

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

Fit grid
    W is dense over the capture resampled (area-weighted, flux preserving) to ``fit_face_size`` (default 32: the
    GGX lobe at α = 0.2 spans several 2.8° texels). Dense W is (M, 6·32²) = 16384 × 6144 float32 (400 MB).

Fast path (``fit_fast``): W acts through SH to band ``fast_band`` on a clamped capture, plus the ``fast_sparse``
    brightest texels exactly: L = min(L, c) + (L − c)₊ with c the luminance of the (k+1)-th brightest texel;
    E0 ≈ (W·Y_F)·(Yᵀ Ω min(L, c)) + W[:, top k]·(L − c)₊[top k]. Truncated SH of a bounded signal rings
    mildly; the sun's flux goes through the exact columns (method notes §4: SH alone fails on ``park``).

Notation
    M design rows, T fit-grid texels, P probes, C = 3 channels, K_p = (p_band+1)², K_q = (q_band+1)² − 1.

References
    [SHExp] Silvennoinen, Sloan, Iwanicki, Nowrouzezahrai, HPG 2025 (seed 000).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import sparse

from bakery.brdf.ggx import reflect
from bakery.brdf.sampling import to_world
from bakery.reflection.reference import _weights_float32
from bakery.reflection.tables import OperatorCache
from bakery.sh.basis import evaluate_sh_basis, sh_bands
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.fibonacci import GOLDEN_ANGLE, fibonacci_directions

EPS_REL = 1e-4
EPS_ABS = 1e-12


@dataclass(frozen=True)
class SHExpSettings:
    """Model orders, fit design and fit grid (all recorded in the store's ``settings``)."""

    p_band: int = 4
    q_band: int = 2
    n_normals: int = 64
    n_views: int = 64
    n_alphas: int = 4
    alpha_min: float = 0.2
    alpha_max: float = 1.0
    fit_face_size: int = 32
    fast_band: int = 12
    fast_sparse: int = 32
    albedo_normalized: bool = True
    alpha_spacing: str = "linear"

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
    if settings.alpha_spacing == "linear":  # paper Sec. 5.1: uniform in α
        alphas = np.linspace(settings.alpha_min, settings.alpha_max, settings.n_alphas)
    elif settings.alpha_spacing == "perceptual":  # uniform in r = √α
        alphas = np.linspace(np.sqrt(settings.alpha_min), np.sqrt(settings.alpha_max), settings.n_alphas) ** 2
    else:
        raise ValueError(f"unknown alpha_spacing {settings.alpha_spacing!r}")
    v = np.broadcast_to(views, (settings.n_alphas,) + views.shape).reshape(-1, 3)
    n = np.broadcast_to(normals[:, None, :], views.shape)
    n = np.broadcast_to(n, (settings.n_alphas,) + views.shape).reshape(-1, 3)
    a = np.repeat(alphas, settings.n_normals * settings.n_views)
    return np.ascontiguousarray(v), np.ascontiguousarray(n), a


@dataclass(frozen=True)
class SHExpOperators:
    """Cached fixed operators of one settings: W (M, T) float32, A (M, K), A⁺ (K, M) float32,
    the fast-path pieces W·Y_F (M, K_F) and the weighted basis Yᵀ Ω (K_F, T), and the per-row log-albedo
    offset (M,) (zeros unless ``albedo_normalized``) with its image A⁺·log a (K,)."""

    weights: np.ndarray
    design: np.ndarray
    pinv: np.ndarray
    weights_sh: np.ndarray
    projector: np.ndarray
    log_albedo: np.ndarray
    pinv_log_albedo: np.ndarray


#: Shared table resolution used by the albedo normalisation (same table as the encodings store).
TABLE_SIZE = 64
TABLE_SAMPLES = 64


def design_albedo(view: np.ndarray, normal: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """f_DV albedo a = A + B (M,) at (n·v, α) from the shared DFG table (bilinear)."""
    from bakery.reflection.tables import compute_dfg_tables, lookup_table

    tables = compute_dfg_tables(TABLE_SIZE, TABLE_SAMPLES)
    nv = np.clip(np.sum(np.asarray(view) * np.asarray(normal), axis=-1), 0.0, 1.0)
    return lookup_table(tables.albedo, nv, np.asarray(alpha, dtype=np.float64))


def weights_key(settings: SHExpSettings) -> str:
    """Stable identity of W: the design and fit-grid fields it depends on, and the formulation's version."""
    return "shexp-W-v1-" + repr((settings.n_normals, settings.n_views, settings.n_alphas, settings.alpha_min,
                                  settings.alpha_max, settings.alpha_spacing, settings.fit_face_size))


@lru_cache(maxsize=4)
def _design_weights(settings: SHExpSettings) -> np.ndarray:
    """W (M, T) float32 for the design and fit grid of ``settings`` (cached on those fields only)."""
    key = weights_key(settings)
    cached = OperatorCache.load(key)
    if cached is not None:
        return cached
    v, n, a = fit_design(settings)
    f = settings.fit_face_size
    dirs = cube_texel_directions(f).reshape(-1, 3)
    omega = cube_texel_solid_angles(f).reshape(-1)
    l_t = np.ascontiguousarray(dirs.T.astype(np.float32))
    weights = np.empty((v.shape[0], dirs.shape[0]), dtype=np.float32)
    rows = max(1, 1_000_000 // dirs.shape[0])
    for s in range(0, v.shape[0], rows):
        sl = slice(s, s + rows)
        weights[sl] = _weights_float32(l_t, omega, v[sl], n[sl], a[sl])[0]  # W of [SHExp] Eq. 6 (f_DV⟨l,n⟩Ω)
    weights = OperatorCache.save(key, weights)
    weights.setflags(write=False)
    return weights


def _weights_key(settings: SHExpSettings) -> SHExpSettings:
    from dataclasses import replace

    return replace(settings, p_band=4, q_band=2, fast_band=12, fast_sparse=32, albedo_normalized=True)


@lru_cache(maxsize=4)
def build_operators(settings: SHExpSettings) -> SHExpOperators:
    """Build W, A, A⁺ (and the fast-path operators) once per settings (cached; W is shared by settings that differ
    only in model orders or normalisation)."""
    v, n, a = fit_design(settings)
    f = settings.fit_face_size
    dirs = cube_texel_directions(f).reshape(-1, 3)
    omega = cube_texel_solid_angles(f).reshape(-1)
    weights = _design_weights(_weights_key(settings))
    design = design_matrix(v, n, a, settings)
    pinv = np.linalg.pinv(design).astype(np.float32)  # A⁺ of [SHExp] Eq. 14
    basis = evaluate_sh_basis(dirs, settings.fast_band)  # (T, K_F)
    weights_sh = (weights @ basis.astype(np.float32)).astype(np.float32)  # W · Y_F
    projector = (basis * omega[:, None]).T.astype(np.float32)  # Yᵀ Ω
    if settings.albedo_normalized:
        log_albedo = np.log(np.maximum(design_albedo(v, n, a), 1e-6)).astype(np.float32)
    else:
        log_albedo = np.zeros(v.shape[0], np.float32)
    pinv_log_albedo = (pinv @ log_albedo).astype(np.float32)
    for array in (design, pinv, weights_sh, projector, log_albedo, pinv_log_albedo):
        array.setflags(write=False)
    return SHExpOperators(weights, design, pinv, weights_sh, projector, log_albedo, pinv_log_albedo)


@lru_cache(maxsize=2)
def _weights_transposed(settings: SHExpSettings) -> np.ndarray:
    """Wᵀ (T, M), contiguous rows = columns of W (fast path only; built on first use)."""
    wt = np.ascontiguousarray(_design_weights(_weights_key(settings)).T)
    wt.setflags(write=False)
    return wt


@lru_cache(maxsize=8)
def downsample_operator(face_size: int, fit_face_size: int) -> sparse.csr_matrix:
    """Sparse (T_fit, T) operator of the solid-angle-weighted block average from the capture grid to the fit grid
    (flux preserving: row t_fit holds Ω_t / Σ Ω over the block)."""
    b = face_size // fit_face_size
    omega = cube_texel_solid_angles(face_size)  # (6, N, N)
    face, row, col = np.meshgrid(np.arange(6), np.arange(face_size), np.arange(face_size), indexing="ij")
    target = ((face * fit_face_size + row // b) * fit_face_size + col // b).reshape(-1)
    area = np.bincount(target, weights=omega.reshape(-1), minlength=6 * fit_face_size**2)
    values = (omega.reshape(-1) / area[target]).astype(np.float32)
    return sparse.csr_matrix((values, (target, np.arange(target.size))), shape=(area.size, target.size))


def _fit_grid_radiance(cubes: np.ndarray, settings: SHExpSettings) -> np.ndarray:
    """Captures (P, 6, N, N, 3) → fit-grid radiance (T, 3P) float32: solid-angle-weighted block average
    (flux preserving; N must be fit_face_size times an integer)."""
    cubes = np.asarray(cubes, dtype=np.float32)
    p, n, f = cubes.shape[0], cubes.shape[2], settings.fit_face_size
    if n < f or n % f:
        raise ValueError(f"capture face size {n} must be a multiple of fit_face_size {f}")
    flat = cubes.reshape(p, -1, 3)
    if n > f:
        op = downsample_operator(n, f)
        flat = np.stack([op @ flat[i] for i in range(p)])  # per probe: sparse (T_fit, T) · (T, 3)
    return np.ascontiguousarray(flat.transpose(1, 0, 2).reshape(-1, 3 * p), dtype=np.float32)


def log_e0(e0: np.ndarray, p: int) -> np.ndarray:
    """Guarded log of E0 samples (M, 3P) (module doc "Log guard")."""
    e = e0.reshape(e0.shape[0], p, 3)
    floor = np.maximum(EPS_REL * e.mean(axis=(0, 2), dtype=np.float64), EPS_ABS).astype(e.dtype)  # (P,)
    return np.log(np.maximum(e, floor[None, :, None])).reshape(e0.shape[0], 3 * p)


def solve_coefficients(log_samples: np.ndarray, operators: SHExpOperators, p: int) -> np.ndarray:
    """[p; q] = A⁺ · (log E0 − log a) ([SHExp] Eq. 13–14; a ≡ 1 unless albedo-normalised): (M, 3P) → (P, K, 3)."""
    coeffs = operators.pinv @ np.asarray(log_samples, dtype=np.float32)  # (K, 3P)
    coeffs -= operators.pinv_log_albedo[:, None]
    return coeffs.reshape(-1, p, 3).transpose(1, 0, 2).astype(np.float32)


def _reference_e0_samples(cubes: np.ndarray, settings: SHExpSettings) -> np.ndarray:
    """Dense E0 samples W · L: (M, 3P) float32."""
    ops = build_operators(settings)
    return ops.weights @ _fit_grid_radiance(cubes, settings)


def fast_e0_samples(cubes: np.ndarray, settings: SHExpSettings) -> np.ndarray:
    """E0 samples through truncated SH plus the sparse brightest texels (module doc "Fast path"): (M, 3P)."""
    ops = build_operators(settings)
    x = _fit_grid_radiance(cubes, settings)  # (T, 3P)
    p = x.shape[1] // 3
    t = x.shape[0]
    lum = x.reshape(t, p, 3) @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)  # (T, P)
    k = min(settings.fast_sparse, t - 1)
    top = np.argpartition(-lum, k, axis=0)[: k + 1]  # (k+1, P) unordered
    top_lum = np.take_along_axis(lum, top, axis=0)
    order = np.argsort(-top_lum, axis=0)
    top = np.take_along_axis(top, order, axis=0)
    clamp = np.take_along_axis(lum, top[k : k + 1], axis=0)[0]  # (P,) luminance of the (k+1)-th texel
    scale = np.minimum(1.0, clamp[None, :] / np.maximum(lum, 1e-30))  # keep chromaticity: L·min(1, c/lum)
    smooth = (x.reshape(t, p, 3) * scale[..., None]).reshape(t, 3 * p)
    e0 = ops.weights_sh @ (ops.projector @ smooth)  # (M, 3P)
    residual = x.reshape(t, p, 3) - smooth.reshape(t, p, 3)
    idx = top[:k]  # (k, P)
    weights_t = _weights_transposed(settings)
    for j in range(p):  # per probe (not per sample): k exact columns of W
        cols = weights_t[idx[:, j]]  # (k, M), contiguous rows of Wᵀ
        e0[:, 3 * j : 3 * j + 3] += cols.T @ residual[idx[:, j], j]
    return e0


def fit_shexp(cubes: np.ndarray, settings: SHExpSettings, fast: bool = False) -> np.ndarray:
    """Fit P captures (P, 6, N, N, 3) → coefficients (P, K_p + K_q, 3) float32: GEMM → log → GEMM."""
    cubes = np.asarray(cubes)
    p = cubes.shape[0]
    e0 = fast_e0_samples(cubes, settings) if fast else _reference_e0_samples(cubes, settings)
    return solve_coefficients(log_e0(e0, p), build_operators(settings), p)


def _reference_fit_shexp(cubes: np.ndarray, settings: SHExpSettings) -> np.ndarray:
    """Per-probe dense fit with a direct least-squares solve (lstsq on A), the plain formulation."""
    ops = build_operators(settings)
    out = []
    for cube in np.asarray(cubes):
        e0 = _reference_e0_samples(cube[None], settings)
        target = log_e0(e0, 1).astype(np.float64) - ops.log_albedo[:, None]
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


def evaluate_shexp(
    coefficients: np.ndarray,
    table: np.ndarray,
    view: np.ndarray,
    normal: np.ndarray,
    alpha: np.ndarray,
    f0: np.ndarray,
    settings: SHExpSettings,
) -> np.ndarray:
    """Specular radiance E (P, M, 3) from coefficients (P, K, 3).

    Albedo-normalised: E = P·Q · (F0·A + B)(n·v, α), ``table`` the DFG table (Nα, Nv, 2).
    Paper: E = P·Q · (F0 + (1 − F0) τ(n·v, α)) ([SHExp] Eq. 5, 15), ``table`` the Fresnel-tail table (Nα, Nv).
    """
    from bakery.reflection.tables import lookup_table

    v = np.asarray(view, dtype=np.float64).reshape(-1, 3)
    n = np.asarray(normal, dtype=np.float64).reshape(-1, 3)
    a = np.broadcast_to(np.asarray(alpha, dtype=np.float64).reshape(-1), (v.shape[0],))
    pq = evaluate_pq(coefficients, v, n, a, settings)
    nv = np.clip(np.sum(v * n, axis=-1), 0.0, 1.0)
    f0 = np.asarray(f0, dtype=np.float64)
    f0 = f0[:, None] if f0.ndim == 1 else np.broadcast_to(f0, (v.shape[0], 3))
    if settings.albedo_normalized:
        ab = lookup_table(table, nv, a)  # (M, 2): A, B
        return pq * (f0 * ab[:, 0:1] + ab[:, 1:2])[None]
    tau = lookup_table(table, nv, a)  # (M,)
    return pq * (f0 + (1.0 - f0) * tau[:, None])[None]
