"""The converged reflection reference of an environment image or a cube map: the image side of
:func:`bakery.reflection.reference.converged_reflection` (module doc there, "Converged reference").

An image is texels of constant radiance over their exact footprints. :class:`ImageTexels` gives the math package
what it reads of one (:class:`bakery.reflection.reference.TexelRadiance`): the texel-centre quadrature
(:func:`bakery.environment.resample.environment_samples`), the direction and solid-angle density at any point inside
a texel (the layout's own mapping, :func:`bakery.environment.layouts.layout_directions_and_density`, 0 off a disc
or outside the cross), each texel's longest chord, and the radiance of the texel *containing* a direction — for an
equirect image the texel :func:`bakery.environment.layouts.direction_to_equirect` falls in (exact, and cheaper
than a nearest-centre search), for the other layouts the texel of the nearest centre (a KD-tree). :class:`CubeTexels`
is the same for a bake-grid cube map (the idealised split-sum's capture).

The report (:mod:`bakery.report.quality`) and the reflection bench (:mod:`bakery.bench.reflection`) both call
:func:`environment_reflection`; the irradiance side's analogue is
:func:`bakery.environment.resample.environment_reference`.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cached_property

import numpy as np

from bakery.environment.layouts import (
    EnvironmentImage,
    direction_to_equirect,
    layout_directions_and_density,
    layout_inside,
)
from bakery.environment.resample import cube_samples, environment_samples, source_texel_solid_angles
from bakery.reflection.reference import converged_prefiltered, converged_reflection
from bakery.sphere.cubemap import cube_face_uv_to_direction, cube_texel_density, direction_to_cube_texel
from bakery.sphere.grid import SphericalSamples


def _diagonals(points: Callable[[np.ndarray, np.ndarray], np.ndarray], count: int) -> np.ndarray:
    """(T,) the larger diagonal chord of each texel, from its corner directions ``points(a, b)`` (T, 3)."""
    zero, one = np.zeros(count), np.ones(count)
    c00, c11, c01, c10 = points(zero, zero), points(one, one), points(zero, one), points(one, zero)
    return np.maximum(np.linalg.norm(c00 - c11, axis=1), np.linalg.norm(c01 - c10, axis=1))


class ImageTexels:
    """An environment image as a :class:`bakery.reflection.reference.TexelRadiance` (module doc). ``samples``: its
    texel-centre quadrature if already built (:func:`environment_samples`; sample k is the k-th valid texel in
    row-major order)."""

    def __init__(self, image: EnvironmentImage, samples: SphericalSamples | None = None) -> None:
        self.image = image
        if samples is not None:
            self.samples = samples

    @cached_property
    def samples(self) -> SphericalSamples:
        return environment_samples(self.image)

    @cached_property
    def _pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) (T,) of every texel (sample)."""
        valid = source_texel_solid_angles(self.image) > 0
        return np.nonzero(valid)

    def texel_points(self, texels: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h, w = self.image.height, self.image.width
        rows, cols = self._pixels[0][texels] + a, self._pixels[1][texels] + b
        directions, density = layout_directions_and_density(self.image.layout, rows, cols, h, w)
        return directions, np.where(layout_inside(self.image.layout, rows, cols, h, w), density, 0.0)

    @cached_property
    def texel_extents(self) -> np.ndarray:
        everything = np.arange(self.samples.count)
        return _diagonals(lambda a, b: self.texel_points(everything, a, b)[0], everything.size)

    @cached_property
    def _tree(self):  # noqa: ANN202 - scipy.spatial.cKDTree
        from scipy.spatial import cKDTree

        return cKDTree(np.asarray(self.samples.directions, dtype=np.float64))

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        if self.image.layout == "equirect":
            h, w = self.image.height, self.image.width
            rows, cols = direction_to_equirect(d, h, w)
            i = np.clip(np.floor(rows).astype(np.int64), 0, h - 1)
            j = np.floor(cols).astype(np.int64) % w
            return self.image.pixels[i, j].astype(np.float64)
        _, index = self._tree.query(d)
        return np.asarray(self.samples.radiance, dtype=np.float64)[index]


class CubeTexels:
    """A cube map (6, N, N, C) as a :class:`bakery.reflection.reference.TexelRadiance`: texel (face, row, column)
    spans face coordinates u = 2(column + b)/N − 1, v = 2(row + a)/N − 1, (a, b) ∈ [0, 1]²; the texel containing a
    direction by :func:`bakery.sphere.cubemap.direction_to_cube_texel`."""

    def __init__(self, cube: np.ndarray) -> None:
        self.cube = np.asarray(cube)

    @cached_property
    def samples(self) -> SphericalSamples:
        return cube_samples(self.cube)

    def texel_points(self, texels: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        size = self.cube.shape[1]
        face, rest = np.divmod(np.asarray(texels), size * size)
        row, col = np.divmod(rest, size)
        u, v = 2.0 * (col + b) / size - 1.0, 2.0 * (row + a) / size - 1.0
        return cube_face_uv_to_direction(face, u, v), cube_texel_density(u, v, size)

    @cached_property
    def texel_extents(self) -> np.ndarray:
        everything = np.arange(self.samples.count)
        return _diagonals(lambda a, b: self.texel_points(everything, a, b)[0], everything.size)

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        face, row, col = direction_to_cube_texel(np.asarray(directions, dtype=np.float64).reshape(-1, 3),
                                                 self.cube.shape[1])
        return self.cube[face, row, col].astype(np.float64)


def environment_reflection(image: EnvironmentImage | ImageTexels, view: np.ndarray, normal: np.ndarray,
                           alpha: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """(E0, E1) (M, C) of the image's piecewise-constant radiance at rows (v, n, α), α a scalar or (M,): the
    converged reference (:func:`bakery.reflection.reference.converged_reflection`)."""
    texels = image if isinstance(image, ImageTexels) else ImageTexels(image)
    return converged_reflection(texels, view, normal, alpha)


def cube_prefiltered(cube: np.ndarray | CubeTexels, directions: np.ndarray, alpha: float) -> np.ndarray:
    """The normalised split-sum kernel K_α applied to the cube map's piecewise-constant radiance at directions (M, 3),
    α > 0, converged (:func:`bakery.reflection.reference.converged_prefiltered`)."""
    texels = cube if isinstance(cube, CubeTexels) else CubeTexels(cube)
    return converged_prefiltered(texels, directions, alpha)
