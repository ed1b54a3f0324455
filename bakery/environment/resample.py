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

Peaks (the sun)
    A ratio filter with a global scale mis-assigns a sun's flux: a sun texel whose sub-texels quantise its cube
    texel's coverage by ±15 % gains or loses 15 % of the sun, and the global scale then spreads that error over the
    whole sphere (measured: E at the normals facing away from Stinson Beach's sun 3 % low at face 64). So the part
    of every texel above :data:`PEAK_RATIO` × the environment's mean luminance is splatted as **flux**, apart: its
    exact flux L·Ω is split over 16 × 16 sub-texels by their solid angle and each cube texel's share divided by
    the texel's exact solid angle. The rest — the whole image when nothing is that bright, which then resamples
    exactly as before — takes the filter above or the gather below.

Gather (mirrored ball)
    A mirrored ball's pixels all hold the same solid angle (16/(W·H)), but towards the rim each is stretched
    radially over degrees (the last pixel ring of a 1024² ball spans 7°), so splatted sub-texels leave stripes of
    cube texels empty. There each cube texel instead averages the image at g × g stratified directions inside it
    (nearest source pixel, g = 4), which is exact for the image's piecewise-constant radiance up to the strata.
    The source's texel solid angles count each rim pixel's part inside the disc (sub-sampled) and sum to 4π, so
    the flux the final scale matches is the image's own (a constant image stays that constant at every size).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.environment.layouts import (
    DISC_LAYOUTS,
    EnvironmentImage,
    direction_to_disc,
    disc_texel_solid_angles,
    equirect_texel_solid_angles,
    layout_directions_and_density,
    layout_inside,
    vertical_cross_face_size,
)
from bakery.irradiance.reference import BinnedQuadrature, binned_quadrature_of_bands
from bakery.sphere.cubemap import cube_face_uv_to_direction, cube_texel_solid_angles, direction_to_cube_texel
from bakery.sphere.grid import SphericalSamples

_MAX_SUBSAMPLES = 16
#: Bumped whenever the resampling of an unchanged image changes its result; image probes and non-latlong domes
#: hash it, so their stores re-bake once (2: peaks splatted as flux, the mirrored ball's gather; 3: the disc maps'
#: texel solid angles integrated and normalised to 4π, and integer files decoded by their transfer function,
#: :func:`bakery.environment.io.read_environment`; 4: files read upright by their orientation — Radiance resolution
#: lines other than "-Y +X", TIFF/EXIF Orientation —, on OpenEXR's display window, and non-Rec.709 primaries
#: converted).
RESAMPLE_MODEL_VERSION = 4
#: Luminance above this multiple of the environment's mean is a peak, resampled as flux (module docstring).
PEAK_RATIO = 50.0
_PEAK_SUBSAMPLES = 16
#: Texels per band of rows :func:`environment_samples` builds at a time.
_SAMPLE_BAND_TEXELS = 1_000_000


def source_texel_solid_angles(image: EnvironmentImage) -> np.ndarray:
    """Solid angle (H, W) of every source texel, summing to 4π: exact for equirect, cube and vertical cross (0 in
    its empty cells); for the disc maps (angular, mirrored ball) the layout's Jacobian integrated over each texel's
    part inside the disc and normalised to 4π (:func:`bakery.environment.layouts.disc_texel_solid_angles`; 0 off
    the disc)."""
    h, w = image.height, image.width
    if image.layout == "equirect":
        return equirect_texel_solid_angles(h, w)
    if image.layout == "cube":
        n = w
        return cube_texel_solid_angles(n).reshape(6 * n, n)
    if image.layout in DISC_LAYOUTS:
        return disc_texel_solid_angles(image.layout, h, w)
    rows, cols = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    n = vertical_cross_face_size(h, w)
    face = np.tile(cube_texel_solid_angles(n)[0], (4, 3))  # every face has the same texel solid angles
    return np.where(layout_inside("vertical_cross", rows, cols, h, w), face, 0.0)


def environment_sample_bands(image: EnvironmentImage, omega: np.ndarray | None = None) -> Iterator[SphericalSamples]:
    """The samples of :func:`environment_samples` as consecutive bands of rows (about ``_SAMPLE_BAND_TEXELS`` texels
    each), in the same order; ``omega``: the image's :func:`source_texel_solid_angles` if already computed."""
    h, w = image.height, image.width
    omega = source_texel_solid_angles(image) if omega is None else omega
    valid = omega > 0  # zero off the disc and in the cross's empty cells
    band = max(1, _SAMPLE_BAND_TEXELS // max(1, w))
    for r0 in range(0, h, band):
        r1 = min(h, r0 + band)
        keep = valid[r0:r1]
        rows, cols = np.meshgrid(np.arange(r0, r1) + 0.5, np.arange(w) + 0.5, indexing="ij")
        directions = layout_directions_and_density(image.layout, rows[keep], cols[keep], h, w)[0]
        yield SphericalSamples(directions=directions, solid_angles=omega[r0:r1][keep],
                               radiance=image.pixels[r0:r1][keep].astype(np.float64))


def environment_samples(image: EnvironmentImage) -> SphericalSamples:
    """Full-resolution quadrature of the environment: one sample per valid texel (exact solid angles).

    Built band by band (:func:`environment_sample_bands`) and joined: an 8192 × 4096 latlong's samples are 1.9 GB
    (the whole-image grids of positions and directions took 4.6 GB at the peak before). The bake holds
    :func:`environment_reference` instead; the report and the benches use these."""
    bands = list(environment_sample_bands(image))
    return SphericalSamples(directions=np.concatenate([b.directions for b in bands]),
                            solid_angles=np.concatenate([b.solid_angles for b in bands]),
                            radiance=np.concatenate([b.radiance for b in bands]))


def environment_reference(image: EnvironmentImage) -> BinnedQuadrature:
    """The full-resolution quadrature of the environment as the bake's reference diagnostics read it
    (:class:`bakery.irradiance.reference.BinnedQuadrature`: the brightest texels as they are, the others binned),
    built band by band: 1.4 MB held per image, whose samples would be 1.9 GB for an 8192 × 4096 latlong (a batch
    of 16 such images held 30 GB before; ``docs/performance.md``, "Large images")."""
    omega = source_texel_solid_angles(image)
    valid = omega > 0
    band = max(1, _SAMPLE_BAND_TEXELS // max(1, image.width))
    luminance = np.concatenate([image.pixels[r0:r0 + band][valid[r0:r0 + band]].astype(np.float64)
                                @ LUMINANCE_WEIGHTS for r0 in range(0, image.height, band)])
    return binned_quadrature_of_bands(environment_sample_bands(image, omega), luminance * omega[valid])


def supersampling_factor(image: EnvironmentImage, face_size: int) -> int:
    """Sub-texels per source texel side so that each cube texel gets ≥ ~4 sub-texels."""
    ratio = 6.0 * face_size * face_size / (image.height * image.width)
    return int(min(_MAX_SUBSAMPLES, max(1, math.ceil(2.0 * math.sqrt(ratio)))))


def resample_to_cube(image: EnvironmentImage, face_size: int) -> np.ndarray:
    """Resampling of ``image`` to a cube map (6, N, N, 3) float32: its peaks as flux, the rest by the area-weighted
    box filter (the gather for a mirrored ball), flux-exact per channel (module docstring)."""
    smooth, peaks = split_peaks(image)
    body = _gather_disc(smooth, face_size) if image.layout == "mirrored_ball" else _splat_ratio(smooth, face_size)
    cube = _renormalised(smooth, body, face_size)
    if peaks is not None:
        cube = cube + _splat_flux(image, peaks, face_size)
    return cube.reshape(6, face_size, face_size, 3).astype(np.float32)


@dataclass(frozen=True)
class Peaks:
    """The part of an environment's brightest texels above :data:`PEAK_RATIO` × its mean luminance.

    Attributes:
        rows, cols: (P,) integer pixel positions.
        radiance: (P, 3) float64 radiance above the threshold (same chromaticity as the texel).
        solid_angles: (P,) the texels' solid angles.
    """

    rows: np.ndarray
    cols: np.ndarray
    radiance: np.ndarray
    solid_angles: np.ndarray


def split_peaks(image: EnvironmentImage) -> tuple[EnvironmentImage, Peaks | None]:
    """``image`` with every texel's luminance clamped to PEAK_RATIO × the mean, and the part clamped off."""
    omega = source_texel_solid_angles(image)
    # in float32 (no float64 copy of the whole image: 800 MB for an 8K latlong), summed below in float64
    luminance = np.maximum(image.pixels @ LUMINANCE_WEIGHTS.astype(np.float32), 0.0).astype(np.float64)
    mean = float(np.sum(luminance * omega)) / (4.0 * np.pi)
    threshold = PEAK_RATIO * mean
    mask = (luminance > threshold) & (omega > 0)
    if mean <= 0 or not mask.any():
        return image, None
    rows, cols = np.nonzero(mask)
    keep = threshold / luminance[mask]  # (P,) the clamped share
    texels = image.pixels[mask].astype(np.float64)
    smooth = image.pixels.copy()
    smooth[mask] = (texels * keep[:, None]).astype(np.float32)
    peaks = Peaks(rows, cols, texels - smooth[mask].astype(np.float64), omega[mask])
    return EnvironmentImage(smooth, image.layout, image.source), peaks


def _splat_flux(image: EnvironmentImage, peaks: Peaks, face_size: int) -> np.ndarray:
    """Radiance (6·N·N, 3) of the peaks' exact flux L·Ω split over sub-texels by solid angle, ÷ the cube texels'."""
    h, w = image.height, image.width
    s = _PEAK_SUBSAMPLES
    offsets = (np.arange(s) + 0.5) / s
    flux = np.zeros((6 * face_size * face_size, 3))
    chunk = max(1, 1_000_000 // (s * s))
    for start in range(0, len(peaks.rows), chunk):
        part = slice(start, start + chunk)
        rr = (peaks.rows[part, None, None] + offsets[None, :, None] + 0.0 * offsets[None, None, :]).reshape(-1, s * s)
        cc = (peaks.cols[part, None, None] + 0.0 * offsets[None, :, None] + offsets[None, None, :]).reshape(-1, s * s)
        directions, density = layout_directions_and_density(image.layout, rr, cc, h, w)
        density = np.where(layout_inside(image.layout, rr, cc, h, w), density, 0.0)
        share = density / np.maximum(density.sum(axis=1, keepdims=True), 1e-300)  # (P, s²), rows sum to 1
        face, row, col = direction_to_cube_texel(directions.reshape(-1, 3), face_size)
        index = (face * face_size + row) * face_size + col
        texel_flux = peaks.radiance[part] * peaks.solid_angles[part, None]  # (P, 3)
        for c in range(3):
            flux[:, c] += np.bincount(index, weights=(share * texel_flux[:, c:c + 1]).reshape(-1),
                                      minlength=flux.shape[0])
    return flux / cube_texel_solid_angles(face_size).reshape(-1, 1)


def _splat_ratio(image: EnvironmentImage, face_size: int) -> np.ndarray:
    """The area-weighted box filter of the module docstring: radiance (6·N·N, 3), before the global scale."""
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
        inside = layout_inside(image.layout, rr, cc, h, w)  # sub-texels off the disc / cross carry nothing
        directions, density = layout_directions_and_density(image.layout, rr[inside], cc[inside], h, w)
        pix = np.repeat(np.repeat(image.pixels[r0:r1], s, axis=0), s, axis=1)[inside]
        face, row, col = direction_to_cube_texel(directions, face_size)
        index = (face * face_size + row) * face_size + col
        wf = density / (s * s)
        weight += np.bincount(index, weights=wf, minlength=weight.size)
        for c in range(3):
            flux[:, c] += np.bincount(index, weights=wf * pix[:, c], minlength=weight.size)
    cube = np.zeros_like(flux)
    filled = weight > 0
    cube[filled] = flux[filled] / weight[filled, None]
    if not filled.all():
        cube = _fill_empty_texels(cube, filled, face_size)
    return cube


def _gather_disc(image: EnvironmentImage, face_size: int, strata: int = 4) -> np.ndarray:
    """Mean radiance (6·N·N, 3) of a disc map at strata × strata stratified directions in each cube texel."""
    h, w = image.height, image.width
    fine = face_size * strata
    centres = (np.arange(fine) + 0.5) / fine * 2.0 - 1.0
    v, u = np.meshgrid(centres, centres, indexing="ij")
    cube = np.empty((6, face_size, face_size, 3))
    for face in range(6):  # one face of N·g × N·g directions at a time
        rows, cols = direction_to_disc(image.layout, cube_face_uv_to_direction(np.full(u.shape, face), u, v), h, w)
        texels = image.pixels[np.clip(rows.astype(np.int64), 0, h - 1), np.clip(cols.astype(np.int64), 0, w - 1)]
        cube[face] = texels.reshape(face_size, strata, face_size, strata, 3).mean(axis=(1, 3), dtype=np.float64)
    return cube.reshape(-1, 3)


def _renormalised(image: EnvironmentImage, cube: np.ndarray, face_size: int) -> np.ndarray:
    """``cube`` (6·N·N, 3) scaled per channel to the flux of ``image``."""
    # Global renormalisation: Σ_j L_j Ω_j (exact cube solid angles) = Σ_i L_i Ω_i (source), per channel. A constant
    # environment is left unchanged (both sides are c·4π); the box filter's local weights only redistribute.
    omega = source_texel_solid_angles(image)
    valid = omega > 0  # environment_samples(image).flux(), without the directions
    source_flux = omega[valid].astype(np.float64) @ image.pixels[valid].astype(np.float64)
    cube_flux = cube_texel_solid_angles(face_size).reshape(-1) @ cube
    scale = np.where(cube_flux > 0, source_flux / np.where(cube_flux > 0, cube_flux, 1.0), 1.0)
    return cube * scale


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
