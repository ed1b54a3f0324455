"""The brightest texels of a capture as analytic directional lights (beyond [SHExp]; its Sec. 5.4 names small bright
suns and α < 0.25 as the limits of a band-limited log-space model).

A sun or a lamp is a few texels carrying most of the flux. In log space its highlight is a narrow, very high peak
that 33 coefficients cannot hold, and the fit spends its capacity there. We take such texels out of the capture,
store each cluster as a directional light (direction, flux), fit the SH exponential to the remainder and add the
lights back analytically at reconstruction — with the same BRDF, exactly:

    E(v, n, α, F0) = E_shexp(remainder) + Σ_k Φ_k · f_DV(v, n, l_k, α) ⟨n, l_k⟩₊ · (F0 + (1 − F0)(1 − v·h_k)⁵)
                                                                              ([SHExp] Eq. 1–8 for a delta light)

Extraction (deterministic, per probe)
    mean radiance L̄ = Σ_t Ω_t Y(L_t) / 4π; candidates: texels with Y(L_t) > ``threshold`` · L̄, brightest first.
    Greedy clusters: the brightest unassigned candidate seeds a cluster that takes every candidate within
    ``radius_deg`` of the seed; at most ``max_lights`` clusters (later candidates stay in the environment).
    Light k: Φ_k = Σ Ω_t L_t (RGB flux, radiance × sr), l_k = normalise(Σ Ω_t Y(L_t) d_t). Its texels are set to
    zero in the remainder, so remainder flux + Σ Φ_k = capture flux exactly. (The fit does not copy the capture:
    it subtracts the removed texels' splatted flux, :func:`bakery.reflection.shexp.splat_flux`.)
    A delta light is the limit of the cluster for lobes much wider than the cluster (a 0.5° sun, ≤ 3° lamps vs
    a GGX lobe of ~15° at α = 0.25).

Notation: P probes, K = ``max_lights``, M evaluation rows. Unused light slots have zero flux.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.reflection.reference import fdv_cosine_weights
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles

#: Smallest GGX α a light is evaluated at (Filament's minimum perceptual roughness 0.045 → α ≈ 0.002): a delta
#: light under a mirror is a measure-zero spike; below ~0.1 the lobe is narrower than a cluster and the delta
#: approximation is coarse anyway (the SH exponential has the same lower limit, [SHExp] Sec. 5.4).
MIN_ALPHA = 0.002


@lru_cache(maxsize=4)
def _texel_geometry(face_size: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel-centre directions (T, 3) and solid angles (T,) of a cube grid (cached, read-only)."""
    dirs = cube_texel_directions(face_size).reshape(-1, 3)
    omega = cube_texel_solid_angles(face_size).reshape(-1)
    dirs.setflags(write=False)
    omega.setflags(write=False)
    return dirs, omega


def extract_lights(
    cubes: np.ndarray, max_lights: int, threshold: float, radius_deg: float
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Captures (P, 6, N, N, 3) → light directions (P, K, 3) float32, light flux (P, K, 3) float32 and the
    lights' texels (probe index (R,), flat texel index (R,) into 6·N·N), which the remainder sets to zero
    (module doc "Extraction"; :func:`remove_texels` makes the remainder, the fit subtracts them instead)."""
    cubes = np.asarray(cubes, dtype=np.float32)
    p, n = cubes.shape[0], cubes.shape[2]
    dirs, omega = _texel_geometry(n)
    cos_radius = np.cos(np.radians(radius_deg))
    radiance = cubes.reshape(p, -1, 3)
    directions = np.zeros((p, max_lights, 3), np.float32)
    directions[:, :, 1] = 1.0  # unused slots: +Y with zero flux
    flux = np.zeros((p, max_lights, 3), np.float32)
    lum = (radiance.reshape(-1, 3) @ LUMINANCE_WEIGHTS.astype(np.float32)).reshape(p, -1)  # (P, T), one GEMV
    mean = (lum @ omega.astype(np.float32)).astype(np.float64) / (4.0 * np.pi)  # (P,)
    removed_probe, removed_texel = [], []
    for i in range(p):
        candidates = np.flatnonzero(lum[i] > threshold * mean[i])
        if candidates.size == 0 or max_lights == 0:
            continue
        candidates = candidates[np.argsort(-lum[i, candidates], kind="stable")]  # brightest first, ties by index
        free = np.ones(candidates.size, bool)
        for k in range(max_lights):
            seeds = np.flatnonzero(free)
            if seeds.size == 0:
                break
            seed = candidates[seeds[0]]
            take = free & (dirs[candidates] @ dirs[seed] >= cos_radius)
            members = candidates[take]
            free &= ~take
            weights = omega[members] * lum[i, members]
            centre = weights @ dirs[members]
            directions[i, k] = centre / np.linalg.norm(centre)
            flux[i, k] = omega[members] @ radiance[i, members].astype(np.float64)
            removed_probe.append(np.full(members.size, i))
            removed_texel.append(members)
    removed = (np.concatenate(removed_probe) if removed_probe else np.zeros(0, np.int64),
               np.concatenate(removed_texel) if removed_texel else np.zeros(0, np.int64))
    return directions, flux, removed


def remove_texels(cubes: np.ndarray, removed: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The remainder: a copy of ``cubes`` (P, 6, N, N, 3) with the ``removed`` texels set to zero."""
    out = np.array(cubes, dtype=np.float32, copy=True)
    out.reshape(out.shape[0], -1, 3)[removed[0], removed[1]] = 0.0
    return out


def evaluate_light_parts(
    directions: np.ndarray, flux: np.ndarray, view: np.ndarray, normal: np.ndarray, alpha: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Base and Fresnel-tail radiance (E0, E1), each (P, M, 3), of the lights (P, K, 3) at rows (M, 3), (M, 3), (M,):
    Σ_k Φ_k f_DV⟨n, l_k⟩₊ and Σ_k Φ_k f_DV⟨n, l_k⟩₊ (1 − v·h_k)⁵ ([SHExp] Eq. 6–7 for delta lights); α clamped at
    ``MIN_ALPHA``."""
    directions = np.asarray(directions, dtype=np.float64)
    flux = np.asarray(flux, dtype=np.float64)
    alpha = np.maximum(np.asarray(alpha, dtype=np.float64), MIN_ALPHA)
    base_out, tail_out = [], []
    for dirs_p, flux_p in zip(directions, flux, strict=True):
        base, tail = fdv_cosine_weights(dirs_p, np.ones(len(dirs_p)), view, normal, alpha, tail=True)  # (M, K)
        base_out.append(base @ flux_p)
        tail_out.append(tail @ flux_p)
    return np.stack(base_out), np.stack(tail_out)


def evaluate_lights(
    directions: np.ndarray, flux: np.ndarray, view: np.ndarray, normal: np.ndarray, alpha: np.ndarray,
    f0: np.ndarray,
) -> np.ndarray:
    """Specular radiance (P, M, 3) of the lights (P, K, 3) at rows (M, 3), (M, 3), (M,), F0 (M,) or (M, 3):
    Φ · f_DV ⟨n, l⟩₊ · (F0 + (1 − F0)(1 − v·h)⁵) per light (module doc), summed; α clamped at ``MIN_ALPHA``."""
    f0 = np.asarray(f0, dtype=np.float64)
    f0 = f0[:, None] if f0.ndim == 1 else f0
    base, tail = evaluate_light_parts(directions, flux, view, normal, alpha)
    return f0 * base + (1.0 - f0) * tail
