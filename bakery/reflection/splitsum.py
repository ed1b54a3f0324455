"""Split-sum prefiltered chain ([Kar13]; [SHExp] Sec. 3.2): one cube map per roughness level with v = n, plus DFG.

Chain layout (recorded in the store, see ``schemas/store-reflection.md``)
    Cube maps on the bake grid conventions (face order/orientation of :mod:`bakery.conventions`).
    Level i of ``n_levels`` holds perceptual roughness r_i = i / (n_levels − 1), GGX α_i = r_i² (r_0 = 0 is the
    mirror level = the capture itself); face size N_i = max(N >> i, min_face_size) (paper: 32×32 minimum).
    Runtime level coordinate: x = √α · (n_levels − 1), linear between the two nearest levels, bilinear within a
    face: a trilinear lookup at the mirror direction r = reflect(v, n), then × (F0·A + B)(n·v, α) from the DFG table.

Prefilter kernel (v = n, [Kar13] p. 4): the GGX-importance-sampled estimator Σ L(l_k)⟨n,l_k⟩ / Σ ⟨n,l_k⟩ with
    l_k = reflect(n, h_k), h_k ~ D(h)(n·h), converges to the normalised zonal kernel
        K_α(n, l) = D(h) ⟨n, l⟩₊ / ∫ D(h) ⟨n, l⟩₊ dω_l,   h = (n + l)/|n + l|, n·h = √((1 + n·l)/2),
    since pdf_l = D(h)(n·h)/(4 v·h) = D(h)/4 when v = n.

Formulations
    ``_reference_prefilter_level`` — plain: 1024 Hammersley GGX samples per output texel, bilinear lookups in the
        full-resolution base level (the paper's comparison setting).
    ``prefilter_chain`` — fast, per level (seed 003 §6, frequency vs angular prefiltering):
        * rough levels: SH domain. K_α is zonal, so (Funk–Hecke) the prefiltered SH is λ_l · L_lm with
          λ_l = 2π ∫ K_α(t) P_l(t) dt (t = n·l), computed by Gauss–Legendre quadrature; bands up to the smallest
          L_max with λ_l < ``sh_tolerance`` for all l > L_max. Used when L_max ≤ ``max_sh_band``. One projection
          (from the capture or its area-weighted mip of face ≤ 128) serves every SH level.
        * sharp levels, ``formulation="operator"`` (default): the level is a fixed linear operator of the capture,
          y = A x, A sparse: the exact normalised kernel over an adaptive quadtree of the capture's mip pyramid,
          rows summing to 1 (:mod:`bakery.reflection.prefilter_operator`; built once per (α, sizes, τ, κ), cached
          on disk, applied to a whole batch as one sparse × dense product), on the capture without its brightest
          texels, which are added exactly (:func:`_prefilter_sharp_batch`). Measured (128², α = 0.04 → 64²,
          relative MSE vs the dense quadrature at 1000 texels; ``bakery.bench.splitsum``): StinsonBeach 3.7e-8,
          park 5.6e-8, city 1.5e-6 vs FIS 7.0e-3, 2.6e-2, 1.7e-4; 27 vs 2 600 ms per probe (batch 16 vs 1).
        * sharp levels, ``formulation="fis"``: filtered importance sampling ([KC08]) with ``fis_samples`` Hammersley
          samples, each read from the source mip whose texel solid angle matches the sample's,
          lod = ½ log2(Ω_s / Ω_p) + 1 (kept as the comparison formulation).
        * α = 0: copy of the capture (area-weighted downsample when the level is smaller).
    ``prefilter_batch`` — the chains of P probes at once (operator formulation: SH projection, SH evaluation and the
        sparse products each one matrix product over the batch's P·C columns; bit-identical per probe).
    ``prefilter_level`` / ``prefilter_bandwidth_chain`` / ``prefilter_bandwidth_batch`` — the bandwidth chain of the
        hybrid encoding (section "Bandwidth chain" below): levels and face sizes from the kernel order F_ε(α)
        ([Seed003] §5.1), log-α runtime mapping, sharp levels by the operator (or FIS) of the capture without its
        bright texels + those texels exactly.

References
    [Kar13] Karis, "Real Shading in Unreal Engine 4", SIGGRAPH 2013 course notes.
    [SHExp] Silvennoinen et al., HPG 2025 (seed 000), Sec. 3.2.
    [KC08] Křivánek & Colbert, "Real-time Shading with Filtered Importance Sampling", EGSR 2008, Eq. 13.
    [Seed003] seed 003 §5–6: per-band scaling vs angular-domain filtering; crossover by kernel bandwidth.
    [BH86] Barnes & Hut, Nature 1986: the quadtree opening criterion of the sparse operator.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import eval_legendre, roots_legendre

from bakery.brdf.ggx import ggx_distribution
from bakery.brdf.sampling import sample_ggx_ndf, to_world
from bakery.reflection.blocks import in_column_blocks
from bakery.sh.basis import evaluate_sh_basis, sh_bands
from bakery.sh.projection import CubeSHProjector
from bakery.sphere.cubemap import (
    cube_mean_texel_solid_angle,
    cube_texel_directions,
    cube_texel_solid_angles,
    resample_cube,
    sample_cube_bilinear,
)


@dataclass(frozen=True)
class SplitSumSettings:
    """Chain parameters. ``face_size``: level-0 size (the bake grid N). ``formulation`` of the sharp levels:
    "operator" (sparse kernel operator, :mod:`bakery.reflection.prefilter_operator`, with ``operator_tolerance`` τ
    and ``operator_core`` κ, applied to the capture without its ≤ ``operator_max_bright`` texels brighter than
    ``operator_bright_threshold`` × the mean, which are added exactly) or "fis" (filtered importance sampling with
    ``fis_samples``)."""

    face_size: int = 128
    n_levels: int = 6
    min_face_size: int = 32
    fis_samples: int = 128
    max_sh_band: int = 32
    sh_tolerance: float = 1e-3
    formulation: str = "operator"
    operator_tolerance: float = 1.5
    operator_core: float = 3.0
    operator_bright_threshold: float = 50.0
    operator_max_bright: int = 256

    def level_alphas(self) -> np.ndarray:
        """GGX α_i = (i / (n_levels − 1))² of every level."""
        r = np.arange(self.n_levels) / max(self.n_levels - 1, 1)
        return r * r

    def level_sizes(self) -> tuple[int, ...]:
        """Face size of every level: max(N >> i, min(min_face_size, N))."""
        floor = min(self.min_face_size, self.face_size)
        return tuple(max(self.face_size >> i, floor) for i in range(self.n_levels))

    def level_coordinate(self, alpha: np.ndarray) -> np.ndarray:
        """Continuous level x = √α (n_levels − 1) ∈ [0, n_levels − 1] (the recorded roughness↔level mapping)."""
        return np.clip(np.sqrt(np.asarray(alpha, dtype=np.float64)), 0.0, 1.0) * (self.n_levels - 1)


def hammersley(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Hammersley points (u1, u2) (count,), u1 = (i + ½)/count, u2 = radical inverse base 2 of i."""
    i = np.arange(count, dtype=np.uint64)
    bits = i.copy()
    bits = ((bits << np.uint64(16)) | (bits >> np.uint64(16))) & np.uint64(0xFFFFFFFF)
    bits = ((bits & np.uint64(0x55555555)) << np.uint64(1)) | ((bits & np.uint64(0xAAAAAAAA)) >> np.uint64(1))
    bits = ((bits & np.uint64(0x33333333)) << np.uint64(2)) | ((bits & np.uint64(0xCCCCCCCC)) >> np.uint64(2))
    bits = ((bits & np.uint64(0x0F0F0F0F)) << np.uint64(4)) | ((bits & np.uint64(0xF0F0F0F0)) >> np.uint64(4))
    bits = ((bits & np.uint64(0x00FF00FF)) << np.uint64(8)) | ((bits & np.uint64(0xFF00FF00)) >> np.uint64(8))
    return (np.arange(count) + 0.5) / count, bits.astype(np.float64) / 2.0**32


def _kernel_profile(t: np.ndarray, alpha: float) -> np.ndarray:
    """Unnormalised K_α as a function of t = n·l: D(√((1+t)/2)) · t₊ (module doc)."""
    return ggx_distribution(np.sqrt(np.clip(0.5 * (1.0 + t), 0.0, 1.0)), alpha) * np.maximum(t, 0.0)


_BAND_CAP = 64


def _gauss_legendre(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights (count,) on [−1, 1], through the operator cache: computing 4000 of them
    takes 0.3 s (an eigenvalue problem), which every worker process paid again for every reflection encoding."""
    from bakery.reflection.tables import OperatorCache

    key = f"gauss-legendre-v1-{count}"
    rule = OperatorCache.load(key)
    if rule is None:
        rule = OperatorCache.save(key, np.stack(roots_legendre(count)))
    return np.asarray(rule[0]), np.asarray(rule[1])


@lru_cache(maxsize=1)
def _band_quadrature() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss–Legendre in the angle θ ∈ [0, π/2] (2000 nodes; resolves the peak at t = 1 for small α): nodes t = cos θ
    (n,), weights dθ·sin θ (n,) and P_l(t) (_BAND_CAP + 1, n), the same for every α (computing the nodes takes
    0.13 s)."""
    x, w = _gauss_legendre(2000)
    theta = 0.25 * np.pi * (x + 1.0)
    t = np.cos(theta)
    legendre = eval_legendre(np.arange(_BAND_CAP + 1)[:, None], t[None, :])
    for array in (t, legendre):
        array.setflags(write=False)
    return t, w * 0.25 * np.pi * np.sin(theta), legendre


@lru_cache(maxsize=64)
def _band_factors_cached(alpha: float) -> np.ndarray:
    t, angle_weight, legendre = _band_quadrature()
    weight = angle_weight * _kernel_profile(t, alpha)
    lam = legendre @ weight
    lam = lam / lam[0]
    lam.setflags(write=False)
    return lam


def kernel_band_factors(alpha: float, max_band: int = _BAND_CAP) -> np.ndarray:
    """λ_l = 2π ∫ K_α(t) P_l(t) dt, l = 0..max_band (≤ 64), normalised so λ_0 = 1 (Funk–Hecke; [Seed003] Eq. 5)."""
    if max_band > _BAND_CAP:
        raise ValueError(f"max_band must be <= {_BAND_CAP}")
    return _band_factors_cached(float(alpha))[: max_band + 1]


def sh_band_limit(alpha: float, tolerance: float, cap: int = _BAND_CAP) -> int:
    """Smallest L with |λ_l| < tolerance for all l in (L, cap]; cap + 1 if none."""
    lam = np.abs(kernel_band_factors(float(alpha), cap))
    above = np.flatnonzero(lam >= tolerance)
    return int(above[-1]) if above.size else 0


#: SH-domain levels project from the mip of at most this face size (64 moved suns by up to a texel: 7% error at
#: α = 0.16 on park; 128 keeps it < 1%).
SH_PROJECTION_FACE = 128


def _project_sh(cube: np.ndarray, max_band: int) -> np.ndarray:
    """Radiance SH (K, C) of a cube, from its mip of face ≤ SH_PROJECTION_FACE (one GEMM)."""
    small = resample_cube(cube, min(cube.shape[1], SH_PROJECTION_FACE))
    if small.shape[1] % 2 == 0:  # the same sums through the cube's reflection symmetry: 1/8 the basis and work
        return _cached_cube_projector(small.shape[1], max_band).project(small)
    weighted = _cached_weighted_basis(small.shape[1], max_band)
    return weighted.T @ small.reshape(-1, small.shape[-1]).astype(np.float32)


@lru_cache(maxsize=16)
def _cached_cube_projector(face_size: int, max_band: int) -> CubeSHProjector:
    """The reflection-symmetric projector of an even face size (:class:`bakery.sh.projection.CubeSHProjector`)."""
    return CubeSHProjector(cube_texel_directions(face_size).reshape(-1, 3),
                           cube_texel_solid_angles(face_size).reshape(-1), max_band)


def _prefilter_sh(cube: np.ndarray, alpha: float, out_size: int, max_band: int,
                  coeffs: np.ndarray | None = None) -> np.ndarray:
    """SH-domain level: project (or reuse ``coeffs`` of ≥ max_band), scale band l by λ_l, evaluate at the level's
    texel centres. (6, N, N, C) → (6, out, out, C)."""
    k = (max_band + 1) ** 2
    if coeffs is None:
        coeffs = _project_sh(cube, max_band)
    scaled = coeffs[:k].astype(np.float64) * kernel_band_factors(float(alpha), max_band)[sh_bands(max_band)][:, None]
    out = _cached_basis(out_size, max_band) @ scaled  # [Seed003] Eq. 5: per-band scaling
    return out.reshape(6, out_size, out_size, -1)


@lru_cache(maxsize=16)
def _cached_weighted_basis(face_size: int, max_band: int) -> np.ndarray:
    """Y_lm(c_i) Ω_i (texels, K) float32 for odd face sizes (even ones: :func:`_cached_cube_projector`), built in
    chunks of texels (the float64 basis of a whole 128² cube at band 25 alone would be 0.5 GB; the chunks keep
    the peak at the float32 result)."""
    directions = cube_texel_directions(face_size).reshape(-1, 3)
    omega = cube_texel_solid_angles(face_size).reshape(-1, 1)
    b = np.empty((directions.shape[0], (max_band + 1) ** 2), dtype=np.float32)
    for s in range(0, directions.shape[0], 8192):
        b[s : s + 8192] = evaluate_sh_basis(directions[s : s + 8192], max_band) * omega[s : s + 8192]
    b.setflags(write=False)
    return b


@lru_cache(maxsize=16)
def _cached_basis(face_size: int, max_band: int) -> np.ndarray:
    b = evaluate_sh_basis(cube_texel_directions(face_size).reshape(-1, 3), max_band)
    b.setflags(write=False)
    return b


def _sample_directions(normals: np.ndarray, alpha: float, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GGX samples with v = n: l (T, S, 3), weight ⟨n, l⟩₊ (T, S), and pdf_l (S,) (v = n: pdf_l = D/4)."""
    u1, u2 = hammersley(count)
    h = sample_ggx_ndf(u1, u2, alpha)  # (S, 3), local frame
    l_local = 2.0 * h[:, 2:3] * h - np.array([0.0, 0.0, 1.0])  # reflect n = +z about h
    nl = np.maximum(l_local[:, 2], 0.0)
    pdf_l = ggx_distribution(h[:, 2], alpha) / 4.0  # pdf_h/(4 v·h) with v·h = n·h  ([WMLT07] Eq. 14)
    l_world = to_world(l_local[None, :, :], normals[:, None, :])
    return l_world, np.broadcast_to(nl, l_world.shape[:2]), pdf_l


def _reference_prefilter_level(cube: np.ndarray, alpha: float, out_size: int, samples: int = 1024) -> np.ndarray:
    """Plain formulation: ``samples`` GGX samples per texel, bilinear lookups in ``cube`` ([Kar13] listing
    "PrefilterEnvMap"). cube (6, N, N, C) → (6, out, out, C) float64."""
    normals = cube_texel_directions(out_size).reshape(-1, 3)
    if alpha <= 0.0:
        return resample_cube(cube, out_size).astype(np.float64)
    out = np.empty((normals.shape[0], cube.shape[-1]))
    chunk = max(1, 2_000_000 // samples)
    for s in range(0, normals.shape[0], chunk):
        l_world, nl, _ = _sample_directions(normals[s : s + chunk], alpha, samples)
        values = sample_cube_bilinear(cube, l_world)  # (t, S, C)
        out[s : s + chunk] = np.einsum("ts,tsc->tc", nl, values) / nl.sum(axis=1)[:, None]
    return out.reshape(6, out_size, out_size, -1)


def _exact_prefilter_level(cube: np.ndarray, alpha: float, out_size: int) -> np.ndarray:
    """Dense quadrature of the normalised kernel over every texel of ``cube`` (exact solid angles): the
    ground truth both formulations are measured against. (6, N, N, C) → (6, out, out, C) float64."""
    if alpha <= 0.0:
        return resample_cube(cube, out_size).astype(np.float64)
    n = cube.shape[1]
    src = cube_texel_directions(n).reshape(-1, 3)
    omega = cube_texel_solid_angles(n).reshape(-1)
    radiance = cube.reshape(-1, cube.shape[-1]).astype(np.float64)
    normals = cube_texel_directions(out_size).reshape(-1, 3)
    out = np.empty((normals.shape[0], radiance.shape[1]))
    chunk = max(1, 4_000_000 // src.shape[0])
    for s in range(0, normals.shape[0], chunk):
        k = _kernel_profile(normals[s : s + chunk] @ src.T, alpha) * omega
        out[s : s + chunk] = (k @ radiance) / k.sum(axis=1)[:, None]
    return out.reshape(6, out_size, out_size, -1)


def _prefilter_fis(mips: list[np.ndarray], alpha: float, out_size: int, samples: int,
                   lod_bias: float = 1.0) -> np.ndarray:
    """Filtered importance sampling ([KC08] Eq. 13): each sample reads the mip whose texel matches its solid angle.

    The sample set is the same for every output texel (fixed Hammersley set in the local frame), so each sample's
    lod is a constant and the lookups are grouped by mip level: one vectorised lookup per (level, sample group).
    """
    base = mips[0].shape[1]
    normals = cube_texel_directions(out_size).reshape(-1, 3)
    l_world, nl, pdf_l = _sample_directions(normals, alpha, samples)
    omega_s = 1.0 / (samples * np.maximum(pdf_l, 1e-30))
    omega_p = cube_mean_texel_solid_angle(base)
    lod = np.clip(0.5 * np.log2(omega_s / omega_p) + lod_bias, 0.0, len(mips) - 1.0)  # [KC08] Eq. 13 (+1 bias)
    lo = np.floor(lod).astype(np.int64)
    frac = lod - lo
    acc = np.zeros((normals.shape[0], mips[0].shape[-1]))
    for level in np.unique(np.concatenate([lo, np.minimum(lo + 1, len(mips) - 1)])):
        w_lo = np.where(lo == level, 1.0 - frac, 0.0) + np.where(np.minimum(lo + 1, len(mips) - 1) == level, frac, 0.0)
        use = np.flatnonzero(w_lo > 0)
        if use.size == 0:
            continue
        values = sample_cube_bilinear(mips[level], l_world[:, use])  # (T, s, C)
        acc += np.einsum("ts,tsc->tc", nl[:, use] * w_lo[use], values)
    acc /= nl.sum(axis=1)[:, None]
    return acc.reshape(6, out_size, out_size, -1)


def build_mips(cube: np.ndarray) -> list[np.ndarray]:
    """Area-weighted mip chain of a cube map down to 1×1 faces."""
    mips = [np.asarray(cube, dtype=np.float32)]
    while mips[-1].shape[1] > 1 and mips[-1].shape[1] % 2 == 0:
        mips.append(resample_cube(mips[-1], mips[-1].shape[1] // 2))
    return mips


def level_formulation(settings: SplitSumSettings, alpha: float) -> str:
    """"copy", "sh", or for sharp levels ``settings.formulation`` ("operator" or "fis") (module doc)."""
    if alpha <= 0.0:
        return "copy"
    if sh_band_limit(alpha, settings.sh_tolerance) <= settings.max_sh_band:
        return "sh"
    return settings.formulation


def _check_formulation(formulation: str) -> None:
    if formulation not in ("operator", "fis"):
        raise ValueError(f"formulation must be 'operator' or 'fis', got {formulation!r}")


def _operator_settings(settings):
    from bakery.reflection.prefilter_operator import OperatorSettings

    return OperatorSettings(tolerance=float(settings.operator_tolerance), core=float(settings.operator_core))


def _sharp_operator(alpha: float, out_size: int, face_size: int, tolerance: float, core: float):
    """The cached sparse operator of a sharp level (memory, then the on-disk :class:`OperatorCache`, else built)."""
    from bakery.reflection.prefilter_operator import (
        OperatorSettings,
        cached_prefilter_operator,
    )

    return cached_prefilter_operator(float(alpha), int(out_size), int(face_size),
                                     OperatorSettings(tolerance=float(tolerance), core=float(core)))


def _as_channels(cubes: np.ndarray) -> np.ndarray:
    """(P, 6, N, N, C) → (6, N, N, P·C): the probes side by side as channels (every per-channel operation of the
    chain then runs once for the batch; column q·C + c is probe q, channel c)."""
    p, _, n, _, c = cubes.shape
    return np.ascontiguousarray(np.moveaxis(cubes, 0, -2).reshape(6, n, n, p * c))


def _from_channels(level: np.ndarray, probes: int) -> np.ndarray:
    """(6, n, n, P·C) → (P, 6, n, n, C) float32."""
    _, n, _, pc = level.shape
    return np.ascontiguousarray(np.moveaxis(level.reshape(6, n, n, probes, pc // probes), 3, 0), dtype=np.float32)


class _SHLevels:
    """The SH-domain levels of P captures (P, 6, N, N, C), the suns apart: the captures without their ≤
    ``operator_max_bright`` texels brighter than ``operator_bright_threshold`` × the mean are projected once (one
    GEMM for the batch, up to ``band``) and scaled per band ([Seed003] Eq. 5); the bright texels are added exactly
    (:func:`_prefilter_bright_exact`, normalised by Z(α) as the SH factors are by λ_0).

    Why: the kernel's bands are cut where |λ_l| < ``sh_tolerance``, and a sun's SH rings with lobes of about that
    fraction of its peak — measured at face 64 on ``sunrise``/``park`` (2/6 bright texels), levels α = 0.16…1:
    relative MSE 2e-6…3e-5 against the exact level, and the darkest texels 47 % below the truth (0.0052 against
    0.0097; a quarter of the texels negative on a 0.1 sky with a 1e6 sun); with the sun apart 9e-10…1.5e-8 and the
    minimum right. Maps without bright texels are unchanged (``city``: 0 bright texels)."""

    def __init__(self, cubes: np.ndarray, band: int, settings) -> None:  # noqa: ANN001 - either chain's settings
        self.cubes = cubes
        splits = [_bright_split(c, settings.operator_bright_threshold, settings.operator_max_bright) for c in cubes]
        self.bright = [b for b, _ in splits]
        self.wide = _as_channels(np.stack([r for _, r in splits]).astype(np.float32)) if any(
            b.size for b in self.bright) else _as_channels(cubes)
        # fixed-width column blocks: a probe's levels depend on its capture alone, not on its batch (PROBE_BLOCK)
        self.coeffs = in_column_blocks(lambda columns: _project_sh(columns, band), self.wide)

    def level(self, alpha: float, size: int, band: int) -> np.ndarray:
        """(P, 6, size, size, C) float32."""
        scaled = in_column_blocks(lambda coeffs: _prefilter_sh(None, alpha, size, band, coeffs), self.coeffs)
        smooth = _from_channels(scaled, len(self.cubes))
        for i, bright in enumerate(self.bright):
            if bright.size:
                smooth[i] += _prefilter_bright_exact(self.cubes[i], bright, alpha, size).astype(np.float32)
        return smooth


def prefilter_chain(cube: np.ndarray, settings: SplitSumSettings) -> list[np.ndarray]:
    """Fast chain: list of (6, N_i, N_i, C) float32 levels for one capture cube (6, N, N, C)."""
    cube = np.asarray(cube, dtype=np.float32)
    if cube.shape[1] != settings.face_size:
        raise ValueError(f"cube face size {cube.shape[1]} != settings.face_size {settings.face_size}")
    return [level[0] for level in prefilter_batch(cube[None], settings)]


def _prefilter_chain_fis(cube: np.ndarray, settings: SplitSumSettings) -> list[np.ndarray]:
    """The chain of one capture with the sharp levels by filtered importance sampling (``formulation="fis"``)."""
    mips = build_mips(cube)
    kinds = [level_formulation(settings, float(a)) for a in settings.level_alphas()]
    bands = [sh_band_limit(float(a), settings.sh_tolerance) for a, k in zip(settings.level_alphas(), kinds) if k == "sh"]
    sh_levels = _SHLevels(cube[None], max(bands), settings) if bands else None  # one projection, the suns apart
    levels = []
    for alpha, size, kind in zip(settings.level_alphas(), settings.level_sizes(), kinds, strict=True):
        if kind == "copy":
            level = resample_cube(cube, size)
        elif kind == "sh":
            level = sh_levels.level(float(alpha), size, sh_band_limit(float(alpha), settings.sh_tolerance))[0]
        else:
            level = _prefilter_fis(mips, float(alpha), size, settings.fis_samples)
        levels.append(np.asarray(level, dtype=np.float32))
    return levels


def _reference_prefilter_chain(cube: np.ndarray, settings: SplitSumSettings, samples: int = 1024) -> list[np.ndarray]:
    """Plain chain: every level by ``samples``-sample GGX importance sampling of the base level."""
    cube = np.asarray(cube, dtype=np.float32)
    return [
        _reference_prefilter_level(cube, float(a), s, samples).astype(np.float32)
        for a, s in zip(settings.level_alphas(), settings.level_sizes(), strict=True)
    ]


def prefilter_batch(cubes: np.ndarray, settings: SplitSumSettings) -> list[np.ndarray]:
    """Chains of P probes: list over levels of (P, 6, N_i, N_i, C) float32.

    ``formulation="operator"``: the batch is one matrix of P·C columns — SH levels by one projection GEMM and one
    evaluation GEMM per level, sharp levels by one sparse × dense product per level
    (:mod:`bakery.reflection.prefilter_operator`); every column is computed independently, so a probe's chain is
    bit-identical whatever else is in its batch (tested). ``"fis"``: per probe, :func:`_prefilter_chain_fis`."""
    cubes = np.asarray(cubes, dtype=np.float32)
    if cubes.ndim != 5 or cubes.shape[2] != settings.face_size:
        raise ValueError(f"cubes must be (P, 6, {settings.face_size}, {settings.face_size}, C), got {cubes.shape}")
    _check_formulation(settings.formulation)
    if settings.formulation == "fis":
        chains = [_prefilter_chain_fis(c, settings) for c in cubes]
        return [np.stack([chain[i] for chain in chains]) for i in range(len(settings.level_sizes()))]
    alphas = [float(a) for a in settings.level_alphas()]
    kinds = [level_formulation(settings, a) for a in alphas]
    bands = [sh_band_limit(a, settings.sh_tolerance) for a, k in zip(alphas, kinds) if k == "sh"]
    sh_levels = _SHLevels(cubes, max(bands), settings) if bands else None  # one projection for every SH level
    sharp = [k for k, kind in enumerate(kinds) if kind == "operator"]
    sizes = settings.level_sizes()
    done = dict(zip(sharp, _prefilter_sharp_batch(cubes, [alphas[k] for k in sharp], [sizes[k] for k in sharp],
                                                  settings) if sharp else [], strict=True))
    levels = []
    for k, (alpha, size, kind) in enumerate(zip(alphas, sizes, kinds, strict=True)):
        if kind == "copy":
            levels.append(np.stack([resample_cube(c, size) for c in cubes]).astype(np.float32))
        elif kind == "sh":
            levels.append(sh_levels.level(alpha, size, sh_band_limit(alpha, settings.sh_tolerance)))
        else:
            levels.append(done[k])
    return levels


def sample_chain(levels: list[np.ndarray], settings: SplitSumSettings, directions: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Trilinear lookup of one probe's chain (levels (6, N_i, N_i, C)) at directions (M, 3), α (M,) → (M, C)."""
    x = settings.level_coordinate(alpha)
    lo = np.minimum(np.floor(x).astype(np.int64), settings.n_levels - 1)
    hi = np.minimum(lo + 1, settings.n_levels - 1)
    f = (x - lo)[:, None]
    out = np.zeros((directions.shape[0], levels[0].shape[-1]))
    for i, level in enumerate(levels):
        w = np.where(lo == i, 1.0 - f[:, 0], 0.0) + np.where(hi == i, f[:, 0], 0.0)
        use = np.flatnonzero(w > 0)
        if use.size:
            out[use] += w[use, None] * sample_cube_bilinear(level.astype(np.float32), directions[use])
    return out


def evaluate_split_sum(
    levels: list[np.ndarray],
    settings: SplitSumSettings,
    dfg: np.ndarray,
    view: np.ndarray,
    normal: np.ndarray,
    alpha: np.ndarray,
    f0: np.ndarray,
) -> np.ndarray:
    """Engine-style reconstruction for P probes: levels[i] (P, 6, N_i, N_i, C); view, normal (M, 3); α (M,);
    F0 (M,) or (M, C) → E (P, M, C) = prefiltered(r, α) · (F0·A + B)(n·v, α)  ([Kar13]; [SHExp] Sec. 3.2).
    α outside [0, 1] or non-finite raises ValueError; views below the horizon are clamped to it
    (:mod:`bakery.reflection.validation`)."""
    from bakery.brdf.ggx import reflect
    from bakery.reflection.tables import lookup_table
    from bakery.reflection.validation import check_rows, clamp_view_to_horizon

    v, n, a = check_rows(view, normal, alpha)  # α ∈ [0, 1] or ValueError; n·v ≤ 0 → horizon
    v = clamp_view_to_horizon(v, n)
    r = reflect(v, n)
    nv = np.clip(np.sum(n * v, axis=-1), 0.0, 1.0)
    ab = lookup_table(dfg, nv, a)  # (M, 2)
    f0 = np.asarray(f0, dtype=np.float64)
    f0 = f0[:, None] if f0.ndim == 1 else np.broadcast_to(f0, (v.shape[0], levels[0].shape[-1]))
    specular = f0 * ab[:, 0:1] + ab[:, 1:2]
    p = levels[0].shape[0]
    out = np.stack([sample_chain([lv[i] for lv in levels], settings, r, a) for i in range(p)])
    return out * specular[None]


# ================================================================================================================
# Bandwidth chain (issue 12): the sharp split-sum chain of the hybrid encoding, levels and sizes from the kernel's
# bandwidth ([Seed003] §5.1) instead of a fixed halving chain.
#
#   order        F_ε(α) = smallest band F with Σ_{l≤F} (2l+1) λ_l(α)² ≥ (1 − ε) Σ_l (2l+1) λ_l(α)²   ([Seed003] §5.1:
#                the kernel keeps 1 − ε of its energy; ε = ``band_energy`` = 1e-2)
#   face size    level k ≥ 1 has face N_k = N >> (k − 1) (N = capture face) and holds the α whose order fits it,
#                F_ε(α_k) = N_k / ``oversampling`` (1.25; measured: bilinear reconstruction of the level then adds
#                ≤ 5e-4 relative MSE on the shared maps). Level 0 is α = 0, the capture itself.
#   spacing      one level per halving of the face: for small α, λ_l(α) ≈ f(l α) (scale invariant), so α_k ≈ 2 α_{k−1}
#                and the chain is geometric in α. Between levels the blend is linear in log α: for a scale-invariant
#                kernel the interpolation error depends only on the ratio α_{k+1}/α_k, and log-α weights are within
#                1.0–2× of the per-α optimal weight (frequency-domain analysis for environment spectra l^0…l^−2,
#                docs/reflection.md); linear-in-α weights are 2–5× worse.
#   runtime      x(α) = k + log(α/α_k) / log(α_{k+1}/α_k) for α_k ≤ α < α_{k+1} (k ≥ 1); below α_1, between the
#                capture and level 1, x = α/α_1 (linear: measured better than log there); x clamped to [0, L − 1].
# ================================================================================================================

#: Quadrature nodes and the band cap of the high-band kernel factors (cubic node mapping resolves α ≥ 0.003).
_HI_NODES = 4000
_HI_CAP = 2048
#: Below this α the order is extrapolated by scale invariance, F_ε(α) = F_ε(α_ref) α_ref / α.
_HI_ALPHA_REF = 0.008


@lru_cache(maxsize=1)
def _high_quadrature() -> tuple[np.ndarray, np.ndarray]:
    """The high-band rule, the same for every α: nodes t = cos θ (_HI_NODES,) and weights (u-measure × Jacobian ×
    sin θ) for θ = (π/2) u³, u ∈ [0, 1] Gauss–Legendre: once per process (the nodes through the operator cache), not
    once per α (a worker recomputed the 4000 nodes, 0.3 s, for every level of every reflection encoding: 1.3 s per
    encoding on a cold process, 2.5× the wall of the outdoor example's bake)."""
    x, w = _gauss_legendre(_HI_NODES)
    u = 0.5 * (x + 1.0)
    theta = 0.5 * np.pi * u**3
    t, weight = np.cos(theta), 0.5 * w * 1.5 * np.pi * u**2 * np.sin(theta)
    for array in (t, weight):
        array.setflags(write=False)
    return t, weight


@lru_cache(maxsize=128)
def _band_factors_high(alpha: float, cap: int | None = None) -> np.ndarray:
    """λ_l (cap + 1,) of the normalised kernel K_α up to a high band (default cap ≈ 12/α, where λ_l < 1e-5):
    Gauss–Legendre in u with θ = (π/2) u³ (nodes concentrate where the peak is), Legendre polynomials by the
    three-term recurrence."""
    cap = int(min(_HI_CAP, np.ceil(12.0 / max(alpha, 1e-6)) + 16)) if cap is None else cap
    t, rule = _high_quadrature()
    weight = rule * _kernel_profile(t, alpha)
    out = np.empty(cap + 1)
    p0, p1 = np.ones_like(t), t.copy()
    out[0], out[1] = weight.sum(), p1 @ weight
    for l in range(2, cap + 1):  # noqa: E741 - recurrence over bands, vectorised over the nodes
        p0, p1 = p1, ((2 * l - 1) * t * p1 - (l - 1) * p0) / l
        out[l] = p1 @ weight
    out = out / out[0]
    out.setflags(write=False)
    return out


def _order_exact(alpha: float, band_energy: float) -> float:
    """F_ε(α) from the band factors, fractional (the cumulative energy interpolated between bands)."""
    lam = _band_factors_high(float(alpha))
    energy = np.cumsum((2 * np.arange(lam.size) + 1) * lam * lam)
    target = (1.0 - band_energy) * energy[-1]
    k = int(np.argmax(energy >= target))
    if k == 0:
        return 0.0
    return float(k - 1 + (target - energy[k - 1]) / (energy[k] - energy[k - 1]))


@lru_cache(maxsize=8)
def _order_table(band_energy: float) -> tuple[np.ndarray, np.ndarray]:
    """(log α, log F_ε) on 33 log-spaced α ∈ [α_ref, 1] (F_ε decreases monotonically with α)."""
    from bakery.reflection.tables import OperatorCache

    alphas = np.geomspace(_HI_ALPHA_REF, 1.0, 33)
    key = f"ggx-kernel-order-v1-{band_energy!r}-{_HI_NODES}"
    orders = OperatorCache.load(key)
    if orders is None:  # ~10 s once; cached on disk by the encoding layer like every operator
        orders = OperatorCache.save(key, np.array([_order_exact(float(a), band_energy) for a in alphas]))
    return np.log(alphas), np.log(np.maximum(np.asarray(orders, dtype=np.float64), 1e-3))


def kernel_order(alpha: float, band_energy: float = 1e-2) -> float:
    """F_ε(α): the band below which the kernel keeps 1 − ε of its energy Σ (2l+1) λ_l² ([Seed003] §5.1),
    fractional; log-log interpolated on a table of exact values; below the table's α_ref extrapolated by scale
    invariance, F_ε(α) = F_ε(α_ref) α_ref / α (module section "Bandwidth chain")."""
    if alpha <= 0.0:
        return float("inf")
    log_a, log_f = _order_table(float(band_energy))
    if alpha < _HI_ALPHA_REF:
        return float(np.exp(log_f[0]) * _HI_ALPHA_REF / alpha)
    return float(np.exp(np.interp(np.log(alpha), log_a, log_f)))


def alpha_for_order(order: float, band_energy: float = 1e-2) -> float:
    """The α whose order F_ε(α) is ``order`` (inverse of :func:`kernel_order`), in (0, 1]."""
    log_a, log_f = _order_table(float(band_energy))
    if order <= np.exp(log_f[-1]):
        return 1.0
    if order >= np.exp(log_f[0]):
        return float(_HI_ALPHA_REF * np.exp(log_f[0]) / order)
    return float(np.exp(np.interp(np.log(order), log_f[::-1], log_a[::-1])))


@dataclass(frozen=True)
class BandwidthChainSettings:
    """The bandwidth chain (module section above). ``face_size`` N: the capture's face (level 0 = α 0 at N);
    ``alpha_top``: the chain holds levels until one reaches it; level sizes never drop below ``min_face_size``
    (then α doubles per level). Sharp levels: ``formulation`` "operator" (texels brighter than
    ``operator_bright_threshold`` × the mean exactly, the rest by the sparse kernel operator with
    ``operator_tolerance``, ``operator_core``) or "fis" (``bright_threshold``, ``fis_samples``, ``fis_lod_bias``).
    ``gap_levels`` G: G more levels at α_1·2^(−G), …, α_1/4, α_1/2, all at N, between the capture and the first
    kernel level (indices 1 … G; the blend of the capture with level 1 is the chain's weakest region; what they buy
    and cost: the ``gap_level`` and ``gap_levels`` parameters of :class:`bakery.encodings.hybrid.SHExpHybrid` and
    docs/reflection.md)."""

    face_size: int = 128
    alpha_top: float = 0.5
    band_energy: float = 1e-2
    oversampling: float = 1.25
    min_face_size: int = 4
    fis_samples: int = 256
    fis_lod_bias: float = 0.0
    max_sh_band: int = 32
    sh_tolerance: float = 1e-3
    bright_threshold: float = 10.0
    formulation: str = "operator"
    operator_tolerance: float = 1.0
    operator_core: float = 2.0
    operator_bright_threshold: float = 50.0
    operator_max_bright: int = 256
    gap_levels: int = 0

    def levels(self) -> tuple[tuple[float, int], ...]:
        """((α_k, N_k), …) for k = 0 … L − 1 (α_0 = 0 at N)."""
        return _chain_levels(self.face_size, self.alpha_top, self.band_energy, self.oversampling, self.min_face_size,
                             self.gap_levels)

    def level_alphas(self) -> np.ndarray:
        return np.array([a for a, _ in self.levels()])

    def level_sizes(self) -> tuple[int, ...]:
        return tuple(s for _, s in self.levels())

    @property
    def n_levels(self) -> int:
        return len(self.levels())

    def level_coordinate(self, alpha: np.ndarray) -> np.ndarray:
        """x(α) ∈ [0, L − 1] (module section "runtime"): log-linear between stored level α's."""
        return level_coordinate(self.level_alphas(), alpha)


@lru_cache(maxsize=64)
def _chain_levels(face_size: int, alpha_top: float, band_energy: float, oversampling: float,
                  min_face_size: int, gap_levels: int = 0) -> tuple[tuple[float, int], ...]:
    levels = [(0.0, int(face_size))]
    size = int(face_size)
    while levels[-1][0] < alpha_top and len(levels) < 16 - gap_levels:  # ≤ 16 levels (the shaders')
        if len(levels) > 1:
            size = max(size // 2, min(min_face_size, face_size))
        alpha = alpha_for_order(size / oversampling, band_energy)
        if len(levels) > 1 and alpha <= 1.0001 * levels[-1][0]:  # face floored: continue geometrically
            alpha = 2.0 * levels[-1][0]
        levels.append((float(round(min(alpha, 1.0), 6)), size))
        if alpha >= 1.0:
            break
    if len(levels) > 1:  # α_1/2, α_1/4, … at N: the capture ↔ level 1 blend halved in α per gap level
        gaps = [(float(round(levels[1][0] / 2.0 ** j, 6)), int(face_size)) for j in range(gap_levels, 0, -1)]
        levels[1:1] = gaps
    return tuple(levels)


def level_coordinate(level_alphas: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Continuous level x (...) of α (...) for a chain with level α's (L,) (α_0 = 0 < α_1 < …): piecewise linear
    in log α between levels k ≥ 1, x = α/α_1 below α_1 (the capture is not a member of the kernel family, so the
    scale-invariance argument for log weights does not hold there; measured on 4 maps: linear weights 2.9× / 2.8× the
    idealised split-sum at α = 0.005 / 0.01 vs 4.1× / 13.9× with x = 1 + log2(α/α_1)), clamped to [0, L − 1]."""
    la = np.asarray(level_alphas, dtype=np.float64)
    a = np.asarray(alpha, dtype=np.float64)
    if la.size == 1:
        return np.zeros_like(a)
    logs = np.log(la[1:])
    la_a = np.log(np.maximum(a, 1e-30))
    x = np.interp(la_a, logs, np.arange(1, la.size, dtype=np.float64))  # clamps to [1, L − 1] outside
    below = a < la[1]
    return np.where(below, np.clip(a / la[1], 0.0, 1.0), x)  # capture ↔ level 1: linear in α (measured)


def _bright_split(cube: np.ndarray, threshold: float, max_texels: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices (B,) of the texels brighter (luminance) than ``threshold`` × the mean radiance (at most the
    ``max_texels`` brightest, ties by index; ascending), and the remainder cube (6, N, N, C) with them set to zero."""
    from bakery.conventions import LUMINANCE_WEIGHTS

    n = cube.shape[1]
    omega = cube_texel_solid_angles(n).reshape(-1)
    flat = cube.reshape(-1, cube.shape[-1])
    lum = flat[:, :3] @ LUMINANCE_WEIGHTS if flat.shape[1] >= 3 else flat[:, 0]
    mean = float(lum @ omega) / (4.0 * np.pi)
    bright = np.flatnonzero(lum > threshold * max(mean, 1e-30))
    if max_texels is not None and bright.size > max_texels:
        bright = np.sort(bright[np.argsort(-lum[bright], kind="stable")[:max_texels]])
    remainder = flat.copy()
    remainder[bright] = 0.0
    return bright, remainder.reshape(cube.shape)


@lru_cache(maxsize=64)
def _kernel_norm(alpha: float) -> float:
    """Z(α) = ∫ K_α dω over the sphere (unnormalised profile :func:`_kernel_profile`), by the high-band quadrature."""
    t, rule = _high_quadrature()
    return float(2.0 * np.pi * np.sum(rule * _kernel_profile(t, alpha)))


def _prefilter_bright_exact(cube: np.ndarray, bright: np.ndarray, alpha: float, out_size: int,
                            norms: np.ndarray | None = None) -> np.ndarray:
    """Exact contribution Σ_b K_α(d·l_b) Ω_b L_b / Z of the bright texels at every texel centre of the output
    level: (6, out, out, C) float64 (one GEMM per chunk of output texels). Z = Z(α) (the sphere integral), or the
    per-texel normalisers ``norms`` (6 out²,) of the operator the remainder goes through."""
    from bakery.reflection.prefilter_operator import (
        _texel_geometry,  # cached centres and solid angles
    )

    n = cube.shape[1]
    out_dirs = _texel_geometry(out_size)[0]
    src = _texel_geometry(n)[0][bright]
    flux = cube.reshape(-1, cube.shape[-1])[bright].astype(np.float64) * _texel_geometry(n)[1][bright, None]
    out = np.zeros((out_dirs.shape[0], cube.shape[-1]))
    if bright.size == 0:
        return out.reshape(6, out_size, out_size, -1)
    from bakery.reflection.prefilter_operator import _kernel

    z = _kernel_norm(float(alpha)) if norms is None else np.asarray(norms)[:, None]
    chunk = max(1, 4_000_000 // bright.size)
    for s in range(0, out_dirs.shape[0], chunk):
        k = _kernel(out_dirs[s : s + chunk] @ src.T, float(alpha))  # = _kernel_profile, fewer passes
        out[s : s + chunk] = k @ flux
    return (out / z).reshape(6, out_size, out_size, -1)


def prefilter_level(cube: np.ndarray, alpha: float, out_size: int, settings: BandwidthChainSettings | None = None,
                    ) -> np.ndarray:
    """One level of the bandwidth chain: ∫ L K_α(d, l) dω at the texel centres of an ``out_size`` cube, from one
    capture (6, N, N, C) → (6, out, out, C) float32. A clean function of (capture, α, size).

    * α = 0: the capture (area-weighted resample to ``out_size`` if smaller).
    * kernel band (λ_l < ``sh_tolerance`` beyond) ≤ ``max_sh_band``: per-band scaling in the SH domain
      ([Seed003] Eq. 5) of the capture without its bright texels, which are added exactly (:class:`_SHLevels`).
    * sharper, ``formulation="operator"`` (default): the texels brighter than ``operator_bright_threshold`` (50) ×
      the mean exactly (dense quadrature of the normalised kernel over them), the rest by the sparse kernel operator
      (:mod:`bakery.reflection.prefilter_operator`, τ = ``operator_tolerance``, κ = ``operator_core``). Without the
      split the operator's merged tail leaves move a sun's tail weight by up to τ: relative MSE 2e-4 on
      StinsonBeach at α = 0.04 (τ = 1.5, κ = 3) vs 4e-8 with it (``bakery.bench.splitsum``); the bright texels are
      divided by the operator's row normalisers S(d) (:func:`_prefilter_sharp_batch`).
    * sharper, ``formulation="fis"``: the texels brighter than ``bright_threshold`` × the mean exactly, the rest by
      filtered importance sampling ([KC08], ``fis_samples`` = 256 with lod bias ``fis_lod_bias`` = 0 instead of 128
      and +1) — the sun is what made plain FIS fail (57 % error at α = 0.04 on ``park``), the remainder's dynamic
      range is ≤ the threshold. Measured against the exact level (relative MSE at 400 texels, α = 0.038 at 64²):
      ``city`` 1.7e-4 (128 samples, +1) → 6.3e-6; ``park`` 5.2e-2 (plain FIS) → 3e-6.
    """
    s = settings or BandwidthChainSettings(face_size=int(cube.shape[1]))
    cube = np.asarray(cube, dtype=np.float32)
    if alpha <= 0.0:
        return resample_cube(cube, out_size)
    band = sh_band_limit(float(alpha), s.sh_tolerance)
    if band <= s.max_sh_band:
        return _SHLevels(cube[None], band, s).level(float(alpha), out_size, band)[0]
    _check_formulation(s.formulation)
    if s.formulation == "operator":
        return _prefilter_sharp_batch(cube[None], [float(alpha)], [int(out_size)], s)[0][0]
    bright, remainder = _bright_split(cube, s.bright_threshold)
    level = _prefilter_fis(build_mips(remainder), float(alpha), out_size, s.fis_samples, s.fis_lod_bias)
    level += _prefilter_bright_exact(cube, bright, float(alpha), out_size)
    return level.astype(np.float32)


def _prefilter_sharp_batch(cubes: np.ndarray, alphas: list[float], sizes: list[int], settings) -> list[np.ndarray]:
    """Sharp levels (α_k, N_k) of P captures (P, 6, N, N, C) by the operator formulation (:func:`prefilter_level`;
    ``settings``: a :class:`SplitSumSettings` or :class:`BandwidthChainSettings`): one bright split per probe (at
    most ``operator_max_bright`` texels above ``operator_bright_threshold`` × the mean), one pyramid of the
    remainders, one sparse product per level, the bright texels exactly per probe, divided by the operator's row
    normalisers S(d) (the discrete ∫ K_α dω of the dense quadrature: Z(α), the continuous one, is 2× off when the
    lobe is narrower than a texel — 107 % L1 error at α = 0.011 on a 32² capture with a sun).
    → list of (P, 6, N_k, N_k, C) float32."""
    from bakery.reflection.prefilter_operator import (
        apply_prefilter_operator,
        cached_row_norms,
        stack_pyramid,
    )

    n = cubes.shape[2]
    splits = [_bright_split(c, settings.operator_bright_threshold, settings.operator_max_bright) for c in cubes]
    pyramid = stack_pyramid(np.stack([remainder for _, remainder in splits]))
    out = []
    for alpha, size in zip(alphas, sizes, strict=True):
        op_settings = _operator_settings(settings)
        op = _sharp_operator(alpha, size, n, settings.operator_tolerance, settings.operator_core)
        level = apply_prefilter_operator(op, pyramid, n, size, cubes.shape[-1])
        if any(bright.size for bright, _ in splits):
            norms = cached_row_norms(alpha, size, n, op_settings)
            level = level.astype(np.float64)
            for i, (bright, _) in enumerate(splits):
                if bright.size:
                    level[i] += _prefilter_bright_exact(cubes[i], bright, alpha, size, norms)
        out.append(np.asarray(level, dtype=np.float32))
    return out


def prefilter_bandwidth_batch(cubes: np.ndarray, settings: BandwidthChainSettings,
                              first_level: int = 0, skip: tuple[int, ...] = ()) -> list[np.ndarray | None]:
    """Levels (P, 6, N_k, N_k, C) float32 of P captures (P, 6, N, N, C) for k ≥ ``first_level`` (None below and
    for the levels in ``skip``, which are not needed).
    Operator formulation: SH levels by one projection of the batch, sharp levels by
    :func:`_prefilter_sharp_batch`; each probe's levels are bit-identical whatever its batch (tested)."""
    cubes = np.asarray(cubes, dtype=np.float32)
    if cubes.ndim != 5 or cubes.shape[2] != settings.face_size:
        raise ValueError(f"cubes must be (P, 6, {settings.face_size}, {settings.face_size}, C), got {cubes.shape}")
    _check_formulation(settings.formulation)
    levels = settings.levels()
    if settings.formulation == "fis":
        chains = [prefilter_bandwidth_chain(c, settings, first_level) for c in cubes]
        return [None if k < first_level or k in skip else np.stack([chain[k] for chain in chains])
                for k in range(len(levels))]
    bands = [sh_band_limit(a, settings.sh_tolerance) for k, (a, _) in enumerate(levels)
             if k >= first_level and k not in skip and a > 0]
    bands = [b for b in bands if b <= settings.max_sh_band]
    sh_levels = _SHLevels(cubes, max(bands), settings) if bands else None  # one projection serves every SH level
    out: list[np.ndarray | None] = [None] * len(levels)
    sharp = []
    for k, (a, size) in enumerate(levels):
        if k < first_level or k in skip:
            continue
        if a <= 0.0:
            out[k] = np.stack([resample_cube(c, size) for c in cubes]).astype(np.float32)
        elif sh_band_limit(a, settings.sh_tolerance) <= settings.max_sh_band:
            out[k] = sh_levels.level(a, size, sh_band_limit(a, settings.sh_tolerance))
        else:
            sharp.append(k)
    if sharp:
        for k, level in zip(sharp, _prefilter_sharp_batch(cubes, [levels[k][0] for k in sharp],
                                                          [levels[k][1] for k in sharp], settings), strict=True):
            out[k] = level
    return out


def prefilter_bandwidth_chain(cube: np.ndarray, settings: BandwidthChainSettings,
                              first_level: int = 0) -> list[np.ndarray | None]:
    """Levels (6, N_k, N_k, C) float32 of one capture for k ≥ ``first_level`` (None below: not needed)."""
    cube = np.asarray(cube, dtype=np.float32)
    if cube.shape[1] != settings.face_size:
        raise ValueError(f"cube face size {cube.shape[1]} != settings.face_size {settings.face_size}")
    if settings.formulation == "operator":
        return [None if level is None else level[0]
                for level in prefilter_bandwidth_batch(cube[None], settings, first_level)]
    return [None if k < first_level else prefilter_level(cube, a, size, settings)
            for k, (a, size) in enumerate(settings.levels())]


def sample_levels(levels: list[np.ndarray], x: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Lookup of one probe's chain (levels (6, N_k, N_k, C), any sizes) at continuous levels x (M,) and directions
    (M, 3): linear between ⌊x⌋ and ⌊x⌋ + 1, bilinear within a face → (M, C) float64."""
    n_levels = len(levels)
    lo = np.minimum(np.floor(x).astype(np.int64), n_levels - 1)
    hi = np.minimum(lo + 1, n_levels - 1)
    f = x - lo
    out = np.zeros((directions.shape[0], levels[0].shape[-1]))
    for i, level in enumerate(levels):
        w = np.where(lo == i, 1.0 - f, 0.0) + np.where(hi == i, f, 0.0)
        use = np.flatnonzero(w > 0)
        if use.size:
            out[use] += w[use, None] * sample_cube_bilinear(np.asarray(level, dtype=np.float32), directions[use])
    return out
