"""The dome (environment): filtered texel radiance for probe texels, the sun as an explicit light, and importance
sampling of the rest for surfaces.

Orientation
    A UsdLux DomeLight's latlong texture follows the OpenEXR latlong convention in the dome's local frame
    (pole = local +Y, longitude 0 = local +Z, longitude +π/2 = local +X): exactly bakery's equirect convention
    (:mod:`bakery.conventions`). :class:`bakery.capture.scene.Dome` carries the dome-local → bake orthogonal matrix
    R (a rotation, or a reflection when the dome's transform mirrors: Hydra mirrors the sky then), so a bake
    direction ω looks up the texture at Rᵀω = R⁻¹ω.

Split: sun + rest
    The brightest texels (radiance luminance > :data:`SUN_RATIO` × the dome's mean, brightest first, at most
    :data:`SUN_SOLID_ANGLE` sr in total, and at least the brightest texel) are the **sun**; everything else is the
    **rest**. Both are exact parts of the same image (rest + sun = dome, texel for texel).

What a probe texel sees (:meth:`DomeSampler.filtered_cube`, :meth:`DomeSampler.sun_points`)
    A probe texel's value is the mean radiance over its solid angle. For the rest of the dome this is the image
    integrated over the texel — area-weighted and flux-exact, the same box filter as environment-image bakes
    (:func:`bakery.environment.resample.resample_to_cube`), with the dome's rotation applied to every sub-texel —
    times the fraction of the texel's primary rays that escape the scene. The sun is cut into sub-texel points
    (s × s per texel, each with its exact share of the flux), each tested for visibility from the probe with a shadow
    ray and splatted **bilinearly** into the bake cube (weights summing to one, so flux is exact and the splat
    keeps the flux centroid instead of moving it to a texel centre).

Surfaces (pbrt-v4 style triples: sample, pdf, lookup)
    The rest is importance-sampled with p_k ∝ luminance_k · Ω_k (Ω_k exact texel solid angle), a point uniform in
    the texel's pixel area; the solid-angle pdf at that point is p_k / (dΩ/dA) with dΩ/dA the layout's density. The
    sun is sampled alone in the same way (next-event estimation of an explicit light). Lookups are nearest-texel,
    which makes L/pdf exactly consistent with the sampled texel. Layouts other than equirect are first resampled to a
    cube (:func:`bakery.environment.resample.resample_to_cube`) and sampled as cube texels.
"""

from __future__ import annotations

import math

import numpy as np

from bakery.capture.scene import Dome
from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.environment.layouts import (
    EnvironmentImage,
    direction_to_equirect,
    equirect_density,
    equirect_directions,
    equirect_texel_solid_angles,
)
from bakery.environment.resample import resample_to_cube
from bakery.sphere.cubemap import (
    cube_face_uv_to_direction,
    cube_texel_density,
    cube_texel_solid_angles,
    direction_to_cube_face_uv,
    direction_to_cube_texel,
)

#: A texel is part of the sun if its radiance luminance exceeds this many times the dome's mean radiance luminance.
SUN_RATIO = 50.0
#: Largest total solid angle of the sun texels (sr): about a 3.2° cone — suns, not bright skies.
SUN_SOLID_ANGLE = 0.01
#: Largest number of sun sub-texel points traced from each probe (s is reduced to stay below it).
SUN_POINTS = 4096
#: Forward steps from a guide-table entry before a sample falls back to a binary search (:class:`_Distribution`).
GUIDE_STEPS = 2


class _Distribution:
    """A discrete distribution over texels with probabilities ∝ weights: inverse-CDF sampling, k = the first index
    with cdf[k] > u, found from a guide table (Chen & Asau 1974).

    ``guide[g]`` is the answer for u = g/G (G a power of two ≥ K, so g = ⌊u·G⌋ is exact and guide[g] ≤ k); a
    sample starts there and steps forward :data:`GUIDE_STEPS` times, and the rare ones still short of k (many
    texels of tiny probability in one guide cell) are binary-searched. The index is exactly that of a binary
    search of the CDF, in a few gathers instead of log₂ K cache-missing steps."""

    def __init__(self, weights: np.ndarray) -> None:
        total = float(weights.sum())
        self.empty = not np.isfinite(total) or total <= 0
        self.probability = weights / total if not self.empty else np.zeros_like(weights)
        self.cdf = np.cumsum(self.probability)
        if self.cdf.size:
            self.cdf[-1] = 1.0
        cells = 1 << max(0, self.cdf.size - 1).bit_length()
        self._cells = float(cells)
        self._guide = np.minimum(np.searchsorted(self.cdf, np.arange(cells) / cells, side="right"),
                                 max(self.cdf.size - 1, 0))

    def sample(self, u: np.ndarray) -> np.ndarray:
        """Texel indices (M,) of uniform numbers u (M,) in [0, 1)."""
        if self.cdf.size == 0:
            return np.zeros(np.shape(u), dtype=np.int64)
        k = np.take(self._guide, (u * self._cells).astype(np.int64))
        for _ in range(GUIDE_STEPS):
            k += np.take(self.cdf, k) <= u
        short = np.flatnonzero(np.take(self.cdf, k) <= u)
        if short.size:
            k[short] = np.searchsorted(self.cdf, np.take(u, short), side="right")
        return np.minimum(k, self.cdf.size - 1)


def bilinear_weights(directions: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Where a bilinear splat at ``directions`` (M, 3) lands in a flat N cube (6·N·N texels): texel indices (4, M)
    and weights (4, M) of the four texels around each direction, summing to one.

    Neighbours across a face edge are found by extending the face plane and mapping the neighbour's centre direction
    back to the cube (so the splat is seamless)."""
    face, u, v = direction_to_cube_face_uv(directions)
    x = (u + 1.0) * 0.5 * n - 0.5
    y = (v + 1.0) * 0.5 * n - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    index = np.zeros((4,) + face.shape, dtype=np.int64)
    weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    for k, (dx, dy) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        cx, cy = x0 + dx, y0 + dy
        inside = (cx >= 0) & (cx < n) & (cy >= 0) & (cy < n)
        ii = np.flatnonzero(inside)
        index[k, ii] = (face[ii] * n + cy[ii].astype(np.int64)) * n + cx[ii].astype(np.int64)
        oo = np.flatnonzero(~inside)
        if oo.size:
            uc = 2.0 * (cx[oo] + 0.5) / n - 1.0
            vc = 2.0 * (cy[oo] + 0.5) / n - 1.0
            f2, r2, c2 = direction_to_cube_texel(cube_face_uv_to_direction(face[oo], uc, vc), n)
            index[k, oo] = (f2 * n + r2) * n + c2
    return index, weight


def splat_bilinear(flux_cube: np.ndarray, directions: np.ndarray, flux: np.ndarray) -> None:
    """Add ``flux`` (M, C) at ``directions`` (M, 3) into a flat cube of texel fluxes (6·N·N, C), bilinearly
    (:func:`bilinear_weights`: the weights sum to one, so the total is exact, and the splat is seamless)."""
    n = int(round(math.sqrt(flux_cube.shape[0] / 6)))
    index, weight = bilinear_weights(directions, n)
    for k in range(4):
        np.add.at(flux_cube, index[k], weight[k][:, None] * flux)


class DomeSampler:
    """Filtered lookups, sun points and importance sampling of a :class:`Dome` (darkness when ``dome`` is None)."""

    def __init__(self, dome: Dome | None) -> None:
        self.dome = dome
        self.black = dome is None or np.asarray(dome.scale, dtype=np.float64).max() <= 0
        self.constant = dome is None or dome.pixels is None
        self.scale = np.zeros(3) if dome is None else np.asarray(dome.scale, dtype=np.float64)
        self.rotation = np.eye(3) if dome is None else np.asarray(dome.rotation, dtype=np.float64)
        self._rot = tuple(tuple(float(x) for x in row) for row in self.rotation)
        self._identity = bool(np.array_equal(self.rotation, np.eye(3)))
        self.has_sun = False
        self._filtered: dict[int, np.ndarray] = {}
        self._sun_points: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        if self.constant:
            return
        assert dome is not None and dome.pixels is not None
        if dome.layout == "equirect":
            self.layout = "equirect"
            self.pixels = np.asarray(dome.pixels, dtype=np.float64)[..., :3]
            h, w = self.pixels.shape[:2]
            omega = equirect_texel_solid_angles(h, w)
        else:
            self.layout = "cube"
            image = EnvironmentImage(np.asarray(dome.pixels, dtype=np.float32)[..., :3], dome.layout, dome.source)
            n = int(min(256, max(32, image.width // 4)))
            self.pixels = resample_to_cube(image, n).astype(np.float64).reshape(6 * n, n, 3)
            omega = cube_texel_solid_angles(n).reshape(6 * n, n)
        self.height, self.width = self.pixels.shape[:2]
        self.omega = omega.reshape(-1)
        self.texels = self.pixels.reshape(-1, 3) * self.scale
        luminance = np.maximum(self.texels @ LUMINANCE_WEIGHTS, 0.0)
        # the sun: brightest texels above SUN_RATIO × mean radiance, within the SUN_SOLID_ANGLE budget
        mean = float(luminance @ self.omega) / (4.0 * np.pi)
        candidates = np.flatnonzero(luminance > SUN_RATIO * mean) if mean > 0 else np.zeros(0, dtype=np.int64)
        candidates = candidates[np.argsort(-luminance[candidates], kind="stable")]
        budget = max(SUN_SOLID_ANGLE, float(self.omega[candidates[0]])) if candidates.size else 0.0
        within = np.cumsum(self.omega[candidates]) <= budget * (1.0 + 1e-12)
        self.sun_index = np.sort(candidates[within])
        self.has_sun = self.sun_index.size > 0
        self.rest = self.texels.copy()
        self.rest[self.sun_index] = 0.0
        weight = luminance * self.omega
        rest_weight = weight.copy()
        rest_weight[self.sun_index] = 0.0
        self.rest_distribution = _Distribution(rest_weight)
        if self.rest_distribution.empty and not self.has_sun:
            self.rest_distribution = _Distribution(self.omega.copy())
        sun_weight = np.zeros_like(weight)
        sun_weight[self.sun_index] = weight[self.sun_index]
        self.sun_distribution = _Distribution(sun_weight)
        # the same distribution over the sun texels alone (a short CDF to search; zero weights add nothing)
        self._sun_compact = _Distribution(weight[self.sun_index]) if self.has_sun else None
        self.sun_flux = (self.texels[self.sun_index] * self.omega[self.sun_index, None]).sum(axis=0)
        # channel-major copies for the (3, M) lookups
        self._rest_t = np.ascontiguousarray(self.rest.T, dtype=np.float32)
        self._texels_t = np.ascontiguousarray(self.texels.T, dtype=np.float32)
        self._sun_t = np.ascontiguousarray((self.texels - self.rest).T, dtype=np.float32)

    # ------------------------------------------------------------------------------------------------------------
    def _local(self, directions: np.ndarray) -> np.ndarray:
        return directions @ self.rotation  # Rᵀω for row vectors

    def _texel_index(self, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat texel index and density dΩ/dA (per unit pixel area) at local directions."""
        if self.layout == "equirect":
            rows, cols = direction_to_equirect(local, self.height, self.width)
            r = np.clip(rows.astype(np.int64), 0, self.height - 1)
            c = np.mod(np.floor(cols).astype(np.int64), self.width)
            return r * self.width + c, equirect_density(rows, self.height, self.width)
        n = self.width
        face, u, v = direction_to_cube_face_uv(local)
        col = np.clip(((u + 1.0) * 0.5 * n).astype(np.int64), 0, n - 1)
        row = np.clip(((v + 1.0) * 0.5 * n).astype(np.int64), 0, n - 1)
        return (face * n + row) * n + col, cube_texel_density(u, v, n)

    def _texel_points(self, k: np.ndarray, fr: np.ndarray, fc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local directions and density dΩ/dA of points (fr, fc) ∈ [0, 1)² inside flat texels k."""
        row, col = k // self.width, k % self.width
        if self.layout == "equirect":
            rows, cols = row + fr, col + fc
            return equirect_directions(rows, cols, self.height, self.width), equirect_density(
                rows, self.height, self.width)
        n = self.width
        face = row // n
        uu = 2.0 * (col + fc) / n - 1.0
        vv = 2.0 * (row - face * n + fr) / n - 1.0
        return cube_face_uv_to_direction(face, uu, vv), cube_texel_density(uu, vv, n)

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """Dome radiance (M, 3) (rest + sun) seen along bake-frame directions (M, 3)."""
        if self.constant:
            return np.broadcast_to(self.scale, directions.shape).copy()
        index, _ = self._texel_index(self._local(directions))
        return self.texels[index]

    def rest_radiance(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (M, 3) of the dome without its sun."""
        if self.constant:
            return np.broadcast_to(self.scale, directions.shape).copy()
        index, _ = self._texel_index(self._local(directions))
        return self.rest[index]

    def sun_radiance(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (M, 3) of the sun texels only (0 elsewhere)."""
        if not self.has_sun:
            return np.zeros((directions.shape[0], 3))
        index, _ = self._texel_index(self._local(directions))
        return self.texels[index] - self.rest[index]

    # ------------------------------------------------------------------------------------------------------------
    def rest_pdf(self, directions: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (M,) of :meth:`sample_rest` at bake-frame directions."""
        if self.constant:
            return np.full(directions.shape[0], 1.0 / (4.0 * np.pi))
        index, density = self._texel_index(self._local(directions))
        return self.rest_distribution.probability[index] / np.maximum(density, 1e-300)

    def sun_pdf(self, directions: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (M,) of :meth:`sample_sun` at bake-frame directions."""
        if not self.has_sun:
            return np.zeros(directions.shape[0])
        index, density = self._texel_index(self._local(directions))
        return self.sun_distribution.probability[index] / np.maximum(density, 1e-300)

    def sample_rest(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directions (M, 3), rest radiance (M, 3) and pdf (M,) from uniform numbers u (M, 3)."""
        if self.constant:
            z = 1.0 - 2.0 * u[:, 0]
            r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
            phi = 2.0 * np.pi * u[:, 1]
            d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
            return d, np.broadcast_to(self.scale, d.shape).copy(), np.full(u.shape[0], 1.0 / (4.0 * np.pi))
        if self.rest_distribution.empty:
            m = u.shape[0]
            return np.tile([0.0, 1.0, 0.0], (m, 1)), np.zeros((m, 3)), np.zeros(m)
        k = self.rest_distribution.sample(u[:, 0])
        local, density = self._texel_points(k, u[:, 1], u[:, 2])
        pdf = self.rest_distribution.probability[k] / np.maximum(density, 1e-300)
        return local @ self.rotation.T, self.rest[k], pdf

    def sample_sun(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directions (M, 3), sun radiance (M, 3) and pdf (M,) from uniform numbers u (M, 3)."""
        k = self.sun_distribution.sample(u[:, 0])
        local, density = self._texel_points(k, u[:, 1], u[:, 2])
        pdf = self.sun_distribution.probability[k] / np.maximum(density, 1e-300)
        return local @ self.rotation.T, self.texels[k], pdf

    # -- (3, M) float32 lookups and samplers of the renderer (bakery.capture.vec) ---------------------------------
    def _local_soa(self, d: np.ndarray) -> np.ndarray:
        if self._identity:
            return d
        r = self._rot
        return np.stack([r[0][i] * d[0] + r[1][i] * d[1] + r[2][i] * d[2] for i in range(3)])  # Rᵀω

    def _world_soa(self, d: np.ndarray) -> np.ndarray:
        if self._identity:
            return d
        r = self._rot
        return np.stack([r[i][0] * d[0] + r[i][1] * d[1] + r[i][2] * d[2] for i in range(3)])  # Rω

    def _texel_index_soa(self, d: np.ndarray, density: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """Flat texel index (and density dΩ/dA if asked) at bake-frame directions (3, M)."""
        local = self._local_soa(d)
        if self.layout != "equirect":
            index, dens = self._texel_index(np.ascontiguousarray(local.T, dtype=np.float64))
            return index, dens.astype(d.dtype) if density else None
        x, y, z = local[0], local[1], local[2]
        norm = np.sqrt(x * x + y * y + z * z)
        latitude = np.arcsin(np.clip(y / np.maximum(norm, 1e-30), -1, 1))
        longitude = np.arctan2(x, z)
        rows = (0.5 - latitude * (1.0 / np.pi)) * self.height
        cols = (0.5 - longitude * (0.5 / np.pi)) * self.width
        r = np.clip(rows.astype(np.int64), 0, self.height - 1)
        c = np.mod(np.floor(cols).astype(np.int64), self.width)
        dens = np.cos(latitude) * ((np.pi / self.height) * (2.0 * np.pi / self.width)) if density else None
        return r * self.width + c, dens

    def _texel_points_soa(self, k: np.ndarray, fr: np.ndarray, fc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bake-frame directions (3, M) and density dΩ/dA (M,) of points (fr, fc) ∈ [0, 1)² inside flat texels k."""
        if self.layout != "equirect":
            local, density = self._texel_points(k, fr.astype(np.float64), fc.astype(np.float64))
            return self._world_soa(np.ascontiguousarray(local.T, dtype=fr.dtype)), density.astype(fr.dtype)
        row, col = k // self.width, k % self.width
        latitude = (0.5 - (row + fr) * (1.0 / self.height)) * np.pi
        longitude = (1.0 - (col + fc) * (2.0 / self.width)) * np.pi
        c = np.cos(latitude)
        local = np.stack([c * np.sin(longitude), np.sin(latitude), c * np.cos(longitude)]).astype(fr.dtype, copy=False)
        density = (c * ((np.pi / self.height) * (2.0 * np.pi / self.width))).astype(fr.dtype, copy=False)
        return self._world_soa(local), density

    def _channels(self, table: np.ndarray, index: np.ndarray, dtype) -> np.ndarray:  # noqa: ANN001
        return np.stack([np.take(table[c], index) for c in range(3)]).astype(dtype, copy=False)

    def rest_radiance_soa(self, d: np.ndarray) -> np.ndarray:
        """:meth:`rest_radiance` of directions (3, M): (3, M)."""
        if self.constant:
            return np.broadcast_to(self.scale.astype(d.dtype)[:, None], d.shape).copy()
        index, _ = self._texel_index_soa(d)
        return self._channels(self._rest_t, index, d.dtype)

    def rest_lookup_soa(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rest radiance (3, M) and :meth:`rest_pdf` (M,) of directions (3, M) with one texel lookup."""
        if self.constant:
            return (np.broadcast_to(self.scale.astype(d.dtype)[:, None], d.shape).copy(),
                    np.full(d.shape[1], 1.0 / (4.0 * np.pi), dtype=d.dtype))
        index, density = self._texel_index_soa(d, density=True)
        pdf = np.take(self.rest_distribution.probability, index) / np.maximum(density, 1e-30)
        return self._channels(self._rest_t, index, d.dtype), pdf.astype(d.dtype, copy=False)

    def sun_lookup_soa(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sun radiance (3, M) and :meth:`sun_pdf` (M,) of directions (3, M)."""
        if not self.has_sun:
            return np.zeros(d.shape, dtype=d.dtype), np.zeros(d.shape[1], dtype=d.dtype)
        index, density = self._texel_index_soa(d, density=True)
        pdf = np.take(self.sun_distribution.probability, index) / np.maximum(density, 1e-30)
        return self._channels(self._sun_t, index, d.dtype), pdf.astype(d.dtype, copy=False)

    def sample_rest_soa(self, u0: np.ndarray, u1: np.ndarray, u2: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`sample_rest` with (3, M) outputs; u0 (the texel choice) should be float64."""
        dtype = u1.dtype
        m = u1.shape[0]
        if self.constant:
            z = 1 - 2 * u0.astype(dtype)
            r = np.sqrt(np.maximum(0, 1 - z * z))
            phi = (2.0 * np.pi) * u1
            d = np.stack([r * np.cos(phi), r * np.sin(phi), z])
            return (d, np.broadcast_to(self.scale.astype(dtype)[:, None], d.shape).copy(),
                    np.full(m, 1.0 / (4.0 * np.pi), dtype=dtype))
        if self.rest_distribution.empty:
            d = np.zeros((3, m), dtype=dtype)
            d[1] = 1
            return d, np.zeros((3, m), dtype=dtype), np.zeros(m, dtype=dtype)
        k = self.rest_distribution.sample(u0)
        d, density = self._texel_points_soa(k, u1, u2)
        pdf = np.take(self.rest_distribution.probability, k) / np.maximum(density, 1e-30)
        return d, self._channels(self._rest_t, k, dtype), pdf.astype(dtype, copy=False)

    def sample_sun_soa(self, u0: np.ndarray, u1: np.ndarray, u2: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`sample_sun` with (3, M) outputs; u0 should be float64."""
        dtype = u1.dtype
        k = self.sun_index[self._sun_compact.sample(u0)]
        d, density = self._texel_points_soa(k, u1, u2)
        pdf = np.take(self.sun_distribution.probability, k) / np.maximum(density, 1e-30)
        return d, self._channels(self._texels_t, k, dtype), pdf.astype(dtype, copy=False)

    # ------------------------------------------------------------------------------------------------------------
    def filtered_cube(self, face_size: int) -> np.ndarray:
        """(6, N, N, 3) mean radiance of the rest of the dome over every bake texel (flux-exact box filter with the
        dome's rotation; module docstring)."""
        if face_size in self._filtered:
            return self._filtered[face_size]
        n = face_size
        if self.constant:
            cube = np.broadcast_to(self.scale, (6, n, n, 3)).astype(np.float64)
            self._filtered[n] = cube
            return cube
        texels = self.height * self.width
        s = int(min(16, max(1, math.ceil(2.0 * math.sqrt(6.0 * n * n / texels)))))
        offsets = (np.arange(s) + 0.5) / s
        flux = np.zeros((6 * n * n, 3))
        weight = np.zeros(6 * n * n)
        band = max(1, int(2_000_000 // max(1, self.width * s * s)))
        rest = self.rest.reshape(self.height, self.width, 3)
        for r0 in range(0, self.height, band):
            r1 = min(self.height, r0 + band)
            k = (np.arange(r0, r1)[:, None] * self.width + np.arange(self.width)[None, :]).reshape(-1)
            kk = np.repeat(k, s * s)
            fr = np.tile(np.repeat(offsets, s), k.size)
            fc = np.tile(np.tile(offsets, s), k.size)
            local, density = self._texel_points(kk, fr, fc)
            w = density / (s * s)
            face, row, col = direction_to_cube_texel(local @ self.rotation.T, n)
            index = (face * n + row) * n + col
            weight += np.bincount(index, weights=w, minlength=weight.size)
            values = rest.reshape(-1, 3)[kk]
            for c in range(3):
                flux[:, c] += np.bincount(index, weights=w * values[:, c], minlength=weight.size)
        cube = np.zeros_like(flux)
        filled = weight > 0
        cube[filled] = flux[filled] / weight[filled, None]
        if not filled.all():  # extreme up-sampling: nearest filled texel
            from bakery.sphere.cubemap import cube_texel_directions

            directions = cube_texel_directions(n).reshape(-1, 3)
            source = directions[filled]
            for i in np.flatnonzero(~filled):
                cube[i] = cube[filled][np.argmax(source @ directions[i])]
        # exact total flux: Σ_j L_j Ω_j (exact cube solid angles) = Σ_k L_k Ω_k (dome texels), per channel
        source_flux = self.omega @ self.rest
        cube_flux = cube_texel_solid_angles(n).reshape(-1) @ cube
        scale = np.where(cube_flux > 0, source_flux / np.where(cube_flux > 0, cube_flux, 1.0), 1.0)
        cube = (cube * scale).reshape(6, n, n, 3)
        self._filtered[n] = cube
        return cube

    def sun_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The sun as sub-texel points: bake-frame directions (K, 3) and the flux (K, 3) each carries (Σ = the sun's
        flux ∫ L dω exactly)."""
        if not self.has_sun:
            return np.zeros((0, 3)), np.zeros((0, 3))
        if 0 in self._sun_points:
            return self._sun_points[0]
        count = self.sun_index.size
        s = int(max(1, min(4, math.floor(math.sqrt(SUN_POINTS / count)))))
        offsets = (np.arange(s) + 0.5) / s
        kk = np.repeat(self.sun_index, s * s)
        fr = np.tile(np.repeat(offsets, s), count)
        fc = np.tile(np.tile(offsets, s), count)
        local, density = self._texel_points(kk, fr, fc)
        # each point's share of its texel's solid angle ∝ density, renormalised to the exact Ω_k
        share = (density / (s * s)).reshape(count, s * s)
        share *= (self.omega[self.sun_index] / share.sum(axis=1))[:, None]
        flux = self.texels[kk] * share.reshape(-1)[:, None]
        self._sun_points[0] = (local @ self.rotation.T, flux)
        return self._sun_points[0]
