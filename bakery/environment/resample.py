"""Resampling an environment image to the bake grid, and its full-resolution quadrature.

The bake grid is a cube map (:mod:`bakery.sphere.cubemap`) with exact texel solid angles.

Filter (energy preserving)
    Each source texel is split into s × s sub-texels; each carries radiance L and weight w = dΩ/dA · ΔA (its solid
    angle). Sub-texels are splatted into the cube texel containing their centre, and the cube texel's radiance is
    Σ w·L / Σ w: an area-weighted box filter. Σ w over a cube texel approximates its exact solid angle, so the flux
    ∫ L dΩ is preserved up to the sub-texel quantisation of texel borders; a final per-channel scale makes the
    total flux over the cube (exact texel solid angles) equal the source's exactly. s is chosen so that every cube texel
    receives at least ~4 sub-texels (s = ⌈2·√(cube texels / source texels)⌉, 1 ≤ s ≤ 16); cube texels that still
    receive nothing (only possible at extreme up-sampling) take a bilinear-like nearest sub-texel value.
"""

from __future__ import annotations

import math

import numpy as np

from bakery.environment.layouts import (
    EnvironmentImage,
    angular_inside,
    equirect_texel_solid_angles,
    layout_directions_and_density,
)
from bakery.sphere.cubemap import cube_texel_solid_angles, direction_to_cube_texel
from bakery.sphere.grid import SphericalSamples

_MAX_SUBSAMPLES = 16


def source_texel_solid_angles(image: EnvironmentImage) -> np.ndarray:
    """Solid angle (H, W) of every source texel: exact for equirect and cube, centre-density for angular maps."""
    h, w = image.height, image.width
    if image.layout == "equirect":
        return equirect_texel_solid_angles(h, w)
    if image.layout == "cube":
        n = w
        return cube_texel_solid_angles(n).reshape(6 * n, n)
    rows, cols = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    _, density = layout_directions_and_density("angular", rows, cols, h, w)
    return density


def environment_samples(image: EnvironmentImage) -> SphericalSamples:
    """Full-resolution quadrature of the environment: one sample per valid texel (exact solid angles)."""
    h, w = image.height, image.width
    rows, cols = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    directions, _ = layout_directions_and_density(image.layout, rows, cols, h, w)
    omega = source_texel_solid_angles(image)
    valid = omega > 0
    if image.layout == "angular":
        valid &= angular_inside(rows, cols, h, w)
    return SphericalSamples(
        directions=directions[valid].astype(np.float64),
        solid_angles=omega[valid].astype(np.float64),
        radiance=image.pixels[valid].astype(np.float64),
    )


def supersampling_factor(image: EnvironmentImage, face_size: int) -> int:
    """Sub-texels per source texel side so that each cube texel gets ≥ ~4 sub-texels."""
    ratio = 6.0 * face_size * face_size / (image.height * image.width)
    return int(min(_MAX_SUBSAMPLES, max(1, math.ceil(2.0 * math.sqrt(ratio)))))


def resample_to_cube(image: EnvironmentImage, face_size: int) -> np.ndarray:
    """Area-weighted box-filter resampling of ``image`` to a cube map (6, N, N, 3) float32 (see module doc)."""
    h, w = image.height, image.width
    s = supersampling_factor(image, face_size)
    flux = np.zeros((6 * face_size * face_size, 3))
    weight = np.zeros(6 * face_size * face_size)
    offsets = (np.arange(s) + 0.5) / s
    # One row band at a time keeps memory at O(W·s²) per band.
    band = max(1, int(2_000_000 // max(1, w * s * s)))
    for r0 in range(0, h, band):
        r1 = min(h, r0 + band)
        rows = (np.arange(r0, r1)[:, None] + offsets[None, :]).reshape(-1)
        cols = (np.arange(w)[:, None] + offsets[None, :]).reshape(-1)
        rr, cc = np.meshgrid(rows, cols, indexing="ij")
        directions, density = layout_directions_and_density(image.layout, rr, cc, h, w)
        area = 1.0 / (s * s)
        wgt = density * area
        if image.layout == "angular":
            wgt = np.where(angular_inside(rr, cc, h, w), wgt, 0.0)
        pix = np.repeat(np.repeat(image.pixels[r0:r1], s, axis=0), s, axis=1)
        face, row, col = direction_to_cube_texel(directions, face_size)
        index = ((face * face_size + row) * face_size + col).reshape(-1)
        wf = wgt.reshape(-1)
        weight += np.bincount(index, weights=wf, minlength=weight.size)
        for c in range(3):
            flux[:, c] += np.bincount(index, weights=wf * pix[..., c].reshape(-1), minlength=weight.size)
    cube = np.zeros_like(flux)
    filled = weight > 0
    cube[filled] = flux[filled] / weight[filled, None]
    if not filled.all():
        cube = _fill_empty_texels(cube, filled, face_size)
    # Global renormalisation: Σ_j L_j Ω_j (exact cube solid angles) = Σ_i L_i Ω_i (source), per channel. A constant
    # environment is left unchanged (both sides are c·4π); the box filter's local weights only redistribute.
    source_flux = environment_samples(image).flux()
    cube_flux = cube_texel_solid_angles(face_size).reshape(-1) @ cube
    scale = np.where(cube_flux > 0, source_flux / np.where(cube_flux > 0, cube_flux, 1.0), 1.0)
    return (cube * scale).reshape(6, face_size, face_size, 3).astype(np.float32)


def _fill_empty_texels(cube: np.ndarray, filled: np.ndarray, face_size: int) -> np.ndarray:
    from bakery.sphere.cubemap import cube_texel_directions

    directions = cube_texel_directions(face_size).reshape(-1, 3)
    source = directions[filled]
    for i in np.flatnonzero(~filled):
        cube[i] = cube[filled][np.argmax(source @ directions[i])]
    return cube


def cube_samples(cube: np.ndarray) -> SphericalSamples:
    """Quadrature of a bake-grid cube map (6, N, N, C) with exact texel solid angles."""
    from bakery.sphere.cubemap import cube_texel_directions

    n = cube.shape[1]
    return SphericalSamples(
        directions=cube_texel_directions(n).reshape(-1, 3),
        solid_angles=cube_texel_solid_angles(n).reshape(-1),
        radiance=np.asarray(cube, dtype=np.float64).reshape(6 * n * n, -1),
    )
