"""The dome (environment) seen by escaping rays: lookup, importance sampling and its pdf.

Orientation
    A UsdLux DomeLight's latlong texture follows the OpenEXR latlong convention in the dome's local frame
    (pole = local +Y, longitude 0 = local +Z, longitude +π/2 = local +X): exactly bakery's equirect convention
    (:mod:`bakery.conventions`). :class:`bakery.capture.scene.Dome` carries the dome-local → bake rotation R, so a
    bake direction ω looks up the texture at Rᵀω.

Sampling (pbrt-v4 style triple: sample, pdf, lookup)
    Texels are chosen with probability p_k ∝ luminance_k · Ω_k (Ω_k exact texel solid angle), then a point
    uniform in the texel's pixel area; the solid-angle pdf at that point is p_k / (dΩ/dA) with dΩ/dA the layout's
    density (:func:`bakery.environment.layouts.layout_directions_and_density`). Lookup is nearest-texel, which
    makes L/pdf exactly consistent with the sampled texel. Layouts other than equirect are first resampled to a
    bake-grid cube (:func:`bakery.environment.resample.resample_to_cube`) and sampled as cube texels.
"""

from __future__ import annotations

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
)


class DomeSampler:
    """Radiance lookup and importance sampling of a :class:`Dome` (or of darkness when ``dome`` is None)."""

    def __init__(self, dome: Dome | None) -> None:
        self.dome = dome
        self.black = dome is None
        self.constant = dome is None or dome.pixels is None
        self.scale = np.zeros(3) if dome is None else np.asarray(dome.scale, dtype=np.float64)
        self.rotation = np.eye(3) if dome is None else np.asarray(dome.rotation, dtype=np.float64)
        if self.constant:
            return
        assert dome is not None and dome.pixels is not None
        if dome.layout == "equirect":
            self.layout = "equirect"
            self.pixels = np.asarray(dome.pixels, dtype=np.float64)
            h, w = self.pixels.shape[:2]
            omega = equirect_texel_solid_angles(h, w)
        else:
            self.layout = "cube"
            image = EnvironmentImage(np.asarray(dome.pixels, dtype=np.float32), dome.layout, dome.source)
            n = int(min(256, max(32, image.width // 4)))
            self.pixels = resample_to_cube(image, n).astype(np.float64).reshape(6 * n, n, 3)
            omega = cube_texel_solid_angles(n).reshape(6 * n, n)
        self.height, self.width = self.pixels.shape[:2]
        self.texels = self.pixels.reshape(-1, 3) * self.scale
        weight = np.maximum(self.texels @ LUMINANCE_WEIGHTS, 0.0) * omega.reshape(-1)
        total = weight.sum()
        if not np.isfinite(total) or total <= 0:
            weight = omega.reshape(-1).copy()
            total = weight.sum()
        self.probability = weight / total
        self.cdf = np.cumsum(self.probability)
        self.cdf[-1] = 1.0

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

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """Dome radiance (M, 3) seen along bake-frame directions (M, 3)."""
        if self.constant:
            return np.broadcast_to(self.scale, directions.shape).copy()
        index, _ = self._texel_index(self._local(directions))
        return self.texels[index]

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (M,) of :meth:`sample` at bake-frame directions."""
        if self.constant:
            return np.full(directions.shape[0], 1.0 / (4.0 * np.pi))
        index, density = self._texel_index(self._local(directions))
        return self.probability[index] / np.maximum(density, 1e-300)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Directions (M, 3) and their pdf (M,) from uniform numbers u (M, 3)."""
        if self.constant:
            z = 1.0 - 2.0 * u[:, 0]
            r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
            phi = 2.0 * np.pi * u[:, 1]
            d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
            return d, np.full(u.shape[0], 1.0 / (4.0 * np.pi))
        k = np.minimum(np.searchsorted(self.cdf, u[:, 0], side="right"), self.cdf.size - 1)
        row = k // self.width
        col = k % self.width
        if self.layout == "equirect":
            rows = row + u[:, 1]
            cols = col + u[:, 2]
            local = equirect_directions(rows, cols, self.height, self.width)
            density = equirect_density(rows, self.height, self.width)
        else:
            n = self.width
            face = row // n
            uu = 2.0 * (col + u[:, 2]) / n - 1.0
            vv = 2.0 * (row - face * n + u[:, 1]) / n - 1.0
            local = cube_face_uv_to_direction(face, uu, vv)
            density = cube_texel_density(uu, vv, n)
        directions = local @ self.rotation.T
        return directions, self.probability[k] / np.maximum(density, 1e-300)
