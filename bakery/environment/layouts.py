"""Image layouts of environment maps: continuous pixel position ↔ direction, and solid-angle density.

Pure numpy. Pixel positions are continuous (row, column) with pixel (i, j) covering [i, i+1) × [j, j+1).
Orientations are the ones in :mod:`bakery.conventions`.

Layouts
    ``equirect``   H × W latlong, row 0 = zenith (+Y), column 0 = longitude +π, centre = +Z (OpenEXR, USD).
    ``cube``       six N × N faces stacked vertically in the order +X,-X,+Y,-Y,+Z,-Z, each face in OpenEXR's
                   ``envmap=cube`` orientation (ImfEnvmap.cpp, ``CubeMap::direction``); converted to bakery's
                   OpenGL-style faces on resampling.
    ``angular``    Debevec's angular map: disc centre = +Z, rim = -Z; pixels outside the disc are invalid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bakery.sphere.cubemap import cube_texel_density

LAYOUTS = ("equirect", "cube", "angular")


@dataclass(frozen=True)
class EnvironmentImage:
    """Radiance pixels of one environment in a known layout.

    Attributes:
        pixels: (H, W, 3) float32 linear RGB radiance.
        layout: one of :data:`LAYOUTS`.
        source: file name or description, for messages.
    """

    pixels: np.ndarray
    layout: str
    source: str = "<array>"

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise ValueError(f"unknown layout {self.layout!r}; expected one of {LAYOUTS}")
        if self.pixels.ndim != 3 or self.pixels.shape[2] != 3:
            raise ValueError(f"pixels must be (H, W, 3), got {self.pixels.shape}")

    @property
    def height(self) -> int:
        return int(self.pixels.shape[0])

    @property
    def width(self) -> int:
        return int(self.pixels.shape[1])


# ---------------------------------------------------------------------------------------------------------------
# Equirect
def equirect_directions(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """Directions (..., 3) at continuous pixel positions of an H × W equirect map."""
    latitude = np.pi * (0.5 - rows / height)
    longitude = np.pi * (1.0 - 2.0 * cols / width)
    c = np.cos(latitude)
    return np.stack([c * np.sin(longitude), np.sin(latitude), c * np.cos(longitude)], axis=-1)


def equirect_density(rows: np.ndarray, height: int, width: int) -> np.ndarray:
    """Solid angle per unit pixel area at continuous rows: dΩ = cos(lat) dlat dlon = cos(lat)·(π/H)·(2π/W)."""
    latitude = np.pi * (0.5 - rows / height)
    return np.cos(latitude) * (np.pi / height) * (2.0 * np.pi / width)


def equirect_texel_solid_angles(height: int, width: int) -> np.ndarray:
    """Exact solid angle (H, W) of each texel: (2π/W)·(sin lat_top − sin lat_bottom). Sums to 4π."""
    lat_edges = np.pi * (0.5 - np.arange(height + 1) / height)
    band = np.sin(lat_edges[:-1]) - np.sin(lat_edges[1:])
    return np.broadcast_to((2.0 * np.pi / width) * band[:, None], (height, width)).copy()


def direction_to_equirect(directions: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (row, column) of directions (..., 3) in an H × W equirect map."""
    d = np.asarray(directions, dtype=np.float64)
    latitude = np.arcsin(np.clip(d[..., 1] / np.linalg.norm(d, axis=-1), -1.0, 1.0))
    longitude = np.arctan2(d[..., 0], d[..., 2])
    return (0.5 - latitude / np.pi) * height, (0.5 - longitude / (2.0 * np.pi)) * width


# ---------------------------------------------------------------------------------------------------------------
# Angular map
def _angular_uv(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    return 2.0 * cols / width - 1.0, 1.0 - 2.0 * rows / height


def angular_directions(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """Directions (..., 3) at continuous pixel positions of an angular map (undefined outside the disc)."""
    u, v = _angular_uv(rows, cols, height, width)
    r = np.sqrt(u * u + v * v)
    # sin(πr)/r → π as r → 0; (u·s, v·s, cos πr) is unit length by construction.
    s = np.where(r > 1e-12, np.sin(np.pi * np.minimum(r, 1.0)) / np.maximum(r, 1e-12), np.pi)
    return np.stack([u * s, v * s, np.cos(np.pi * np.minimum(r, 1.0))], axis=-1)


def angular_density(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """Solid angle per unit pixel area: dΩ = π·sin(πr)/r du dv, du dv = (2/W)(2/H) per pixel; 0 outside the disc."""
    u, v = _angular_uv(rows, cols, height, width)
    r = np.sqrt(u * u + v * v)
    jac = np.where(r > 1e-12, np.pi * np.sin(np.pi * np.minimum(r, 1.0)) / np.maximum(r, 1e-12), np.pi * np.pi)
    return np.where(r <= 1.0, jac, 0.0) * (4.0 / (width * height))


def angular_inside(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    u, v = _angular_uv(rows, cols, height, width)
    return u * u + v * v <= 1.0


# ---------------------------------------------------------------------------------------------------------------
# OpenEXR vertical cross: six faces stacked +X,-X,+Y,-Y,+Z,-Z
def exr_cube_directions(rows: np.ndarray, cols: np.ndarray, face_size: int) -> np.ndarray:
    """Directions (..., 3) at continuous pixel positions of an OpenEXR stacked cube (height = 6·N).

    OpenEXR's ``CubeMap::pixelPosition``/``direction`` (ImfEnvmap.cpp) rewritten for image coordinates
    a = 2·column/N − 1 (rightwards) and b = 2·row/N − 1 (downwards, within the face):
    +X:(1,-b,a)  -X:(-1,-b,-a)  +Y:(a,1,-b)  -Y:(a,-1,b)  +Z:(-a,-b,1)  -Z:(a,-b,-1).
    """
    face = np.clip((np.asarray(rows) // face_size).astype(np.int64), 0, 5)
    a = 2.0 * cols / face_size - 1.0
    b = 2.0 * (rows - face * face_size) / face_size - 1.0
    one = np.ones_like(a)
    table = np.stack(
        [
            np.stack([one, -b, a], -1),  # +X
            np.stack([-one, -b, -a], -1),  # -X
            np.stack([a, one, -b], -1),  # +Y
            np.stack([a, -one, b], -1),  # -Y
            np.stack([-a, -b, one], -1),  # +Z
            np.stack([a, -b, -one], -1),  # -Z
        ],
        axis=0,
    )
    d = np.take_along_axis(table, np.broadcast_to(face[None, ..., None], (1, *face.shape, 3)), axis=0)[0]
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def exr_cube_density(rows: np.ndarray, cols: np.ndarray, face_size: int) -> np.ndarray:
    """Solid angle per unit pixel area of a cube face: (1 + a² + b²)^(-3/2) · (2/N)²."""
    face = np.clip((rows // face_size).astype(np.int64), 0, 5)
    a = 2.0 * cols / face_size - 1.0
    b = 2.0 * (rows - face * face_size) / face_size - 1.0
    return cube_texel_density(a, b, face_size)


# ---------------------------------------------------------------------------------------------------------------
def layout_directions_and_density(
    layout: str, rows: np.ndarray, cols: np.ndarray, height: int, width: int
) -> tuple[np.ndarray, np.ndarray]:
    """Directions (..., 3) and solid angle per unit pixel area (...) at continuous positions of any layout."""
    if layout == "equirect":
        return equirect_directions(rows, cols, height, width), equirect_density(rows, height, width)
    if layout == "angular":
        return angular_directions(rows, cols, height, width), angular_density(rows, cols, height, width)
    if layout == "cube":
        return exr_cube_directions(rows, cols, width), exr_cube_density(rows, cols, width)
    raise ValueError(f"unknown layout {layout!r}")
