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
        * sharp levels: filtered importance sampling ([KC08]) with ``fis_samples`` Hammersley samples, each read
          from the source mip whose texel solid angle matches the sample's, lod = ½ log2(Ω_s / Ω_p) + 1.
        * α = 0: copy of the capture (area-weighted downsample when the level is smaller).

References
    [Kar13] Karis, "Real Shading in Unreal Engine 4", SIGGRAPH 2013 course notes.
    [SHExp] Silvennoinen et al., HPG 2025 (seed 000), Sec. 3.2.
    [KC08] Křivánek & Colbert, "Real-time Shading with Filtered Importance Sampling", EGSR 2008, Eq. 13.
    [Seed003] seed 003 §5–6: per-band scaling vs angular-domain filtering; crossover by kernel bandwidth.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import eval_legendre, roots_legendre

from bakery.brdf.ggx import ggx_distribution
from bakery.brdf.sampling import sample_ggx_ndf, to_world
from bakery.sh.basis import evaluate_sh_basis, sh_bands
from bakery.sphere.cubemap import (
    cube_mean_texel_solid_angle,
    cube_texel_directions,
    cube_texel_solid_angles,
    resample_cube,
    sample_cube_bilinear,
)


@dataclass(frozen=True)
class SplitSumSettings:
    """Chain parameters. ``face_size``: level-0 size (the bake grid N)."""

    face_size: int = 128
    n_levels: int = 6
    min_face_size: int = 32
    fis_samples: int = 128
    max_sh_band: int = 32
    sh_tolerance: float = 1e-3

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


@lru_cache(maxsize=64)
def _band_factors_cached(alpha: float) -> np.ndarray:
    # Gauss–Legendre in the angle θ ∈ [0, π/2] resolves the peak at t = 1 for small α.
    x, w = roots_legendre(2000)
    theta = 0.25 * np.pi * (x + 1.0)
    t = np.cos(theta)
    weight = w * 0.25 * np.pi * np.sin(theta) * _kernel_profile(t, alpha)
    lam = eval_legendre(np.arange(_BAND_CAP + 1)[:, None], t[None, :]) @ weight
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
    weighted = _cached_weighted_basis(small.shape[1], max_band)
    return weighted.T @ small.reshape(-1, small.shape[-1]).astype(np.float32)


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
    b = (evaluate_sh_basis(cube_texel_directions(face_size).reshape(-1, 3), max_band)
         * cube_texel_solid_angles(face_size).reshape(-1, 1)).astype(np.float32)
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


def _prefilter_fis(mips: list[np.ndarray], alpha: float, out_size: int, samples: int) -> np.ndarray:
    """Filtered importance sampling ([KC08] Eq. 13): each sample reads the mip whose texel matches its solid angle.

    The sample set is the same for every output texel (fixed Hammersley set in the local frame), so each sample's
    lod is a constant and the lookups are grouped by mip level: one vectorised lookup per (level, sample group).
    """
    base = mips[0].shape[1]
    normals = cube_texel_directions(out_size).reshape(-1, 3)
    l_world, nl, pdf_l = _sample_directions(normals, alpha, samples)
    omega_s = 1.0 / (samples * np.maximum(pdf_l, 1e-30))
    omega_p = cube_mean_texel_solid_angle(base)
    lod = np.clip(0.5 * np.log2(omega_s / omega_p) + 1.0, 0.0, len(mips) - 1.0)  # [KC08] Eq. 13 (+1 bias)
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
    """"copy", "sh" or "fis" for a level of roughness α (module doc)."""
    if alpha <= 0.0:
        return "copy"
    return "sh" if sh_band_limit(alpha, settings.sh_tolerance) <= settings.max_sh_band else "fis"


def prefilter_chain(cube: np.ndarray, settings: SplitSumSettings) -> list[np.ndarray]:
    """Fast chain: list of (6, N_i, N_i, C) float32 levels for one capture cube (6, N, N, C)."""
    cube = np.asarray(cube, dtype=np.float32)
    if cube.shape[1] != settings.face_size:
        raise ValueError(f"cube face size {cube.shape[1]} != settings.face_size {settings.face_size}")
    mips = build_mips(cube)
    kinds = [level_formulation(settings, float(a)) for a in settings.level_alphas()]
    bands = [sh_band_limit(float(a), settings.sh_tolerance) for a, k in zip(settings.level_alphas(), kinds) if k == "sh"]
    coeffs = _project_sh(cube, max(bands)) if bands else None  # one projection for every SH level
    levels = []
    for alpha, size, kind in zip(settings.level_alphas(), settings.level_sizes(), kinds, strict=True):
        if kind == "copy":
            level = resample_cube(cube, size)
        elif kind == "sh":
            band = sh_band_limit(float(alpha), settings.sh_tolerance)
            level = _prefilter_sh(cube, float(alpha), size, band, coeffs)
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
    """Chains of P probes: list over levels of (P, 6, N_i, N_i, C) float32."""
    chains = [prefilter_chain(c, settings) for c in np.asarray(cubes)]
    return [np.stack([chain[i] for chain in chains]) for i in range(settings.n_levels)]


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
    F0 (M,) or (M, C) → E (P, M, C) = prefiltered(r, α) · (F0·A + B)(n·v, α)  ([Kar13]; [SHExp] Sec. 3.2)."""
    from bakery.brdf.ggx import reflect
    from bakery.reflection.tables import lookup_table

    v = np.asarray(view, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    a = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (v.shape[0],))
    r = reflect(v, n)
    nv = np.clip(np.sum(n * v, axis=-1), 0.0, 1.0)
    ab = lookup_table(dfg, nv, a)  # (M, 2)
    f0 = np.asarray(f0, dtype=np.float64)
    f0 = f0[:, None] if f0.ndim == 1 else np.broadcast_to(f0, (v.shape[0], levels[0].shape[-1]))
    specular = f0 * ab[:, 0:1] + ab[:, 1:2]
    p = levels[0].shape[0]
    out = np.stack([sample_chain([lv[i] for lv in levels], settings, r, a) for i in range(p)])
    return out * specular[None]
