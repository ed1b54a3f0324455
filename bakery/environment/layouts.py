"""Image layouts of environment maps: continuous pixel position ↔ direction, and solid-angle density.

Pure numpy. Pixel positions are continuous (row, column) with pixel (i, j) covering [i, i+1) × [j, j+1).
Orientations are the ones in :mod:`bakery.conventions`.

Layouts
    ``equirect``   H × W latlong, row 0 = zenith (+Y), column 0 = longitude +π, centre = +Z (OpenEXR, USD).
    ``cube``       six N × N faces stacked vertically in the order +X,-X,+Y,-Y,+Z,-Z, each face in OpenEXR's
                   ``envmap=cube`` orientation (ImfEnvmap.cpp, ``CubeMap::direction``); converted to bakery's
                   OpenGL-style faces on resampling.
    ``angular``    Debevec's angular map: disc centre = +Z, rim = -Z, the radius linear in the angle from +Z;
                   pixels outside the disc are invalid.
    ``mirrored_ball`` a mirrored sphere photographed orthographically from +Z (UsdLux ``mirroredBall``): the disc
                   point (u, v) reflects the view ray (0, 0, -1) about the ball's normal (u, v, √(1−u²−v²)), so
                   centre = +Z (towards the camera), rim = -Z, the radius r = sin(θ/2); u right, v up as in
                   ``angular``; pixels outside the disc are invalid.
    ``vertical_cross`` a 3N × 4N unfolded cube (UsdLux ``cubeMapVerticalCross``, HDRShop's layout) seen from inside:
                   the middle row is +X | +Z | −X with +Y above and −Y, −Z below the centre; −Z is upside down.
                   The centre face continues the latlong's centre (+Z, +Y up, −X to the right), every shared
                   edge of the image is continuous, and the six empty cells are invalid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bakery.sphere.cubemap import cube_texel_density

LAYOUTS = ("equirect", "cube", "angular", "mirrored_ball", "vertical_cross")
#: Layouts whose image holds invalid pixels (outside the disc, the cross's empty cells).
PARTIAL_LAYOUTS = ("angular", "mirrored_ball", "vertical_cross")
DISC_LAYOUTS = ("angular", "mirrored_ball")
#: Smallest side of a disc map (N × N) that is read: below it the disc is a handful of texels, each spanning a
#: steradian or more (a 4 × 4 mirrored ball: 1 sr per texel, its rim texels the whole −Z hemisphere). The
#: equirect, cube and cross layouts have exact texel solid angles at every size (down to 2 × 1, 1 × 6, 3 × 4).
MIN_DISC_SIZE = 8


def layout_size_problem(layout: str, height: int, width: int) -> str | None:
    """Why an H × W image cannot be read in ``layout`` (one line, without the file name), or None if it can.

    A stacked cube is N × 6N, a vertical cross 3N × 4N, a disc map square and at least :data:`MIN_DISC_SIZE` a side.
    """
    if layout == "cube" and height != 6 * width:
        return f"a stacked cube map must be N x 6N, got {width}x{height}"
    if layout == "vertical_cross" and (4 * width != 3 * height or width % 3):
        return f"a vertical cross must be 3N x 4N, got {width}x{height}"
    if layout in DISC_LAYOUTS:
        name = "an angular map" if layout == "angular" else "a mirrored ball"
        if width != height:
            return f"{name} ({layout}) must be square (N x N), got {width}x{height}"
        if width < MIN_DISC_SIZE:
            return (f"{name} ({layout}) must be at least {MIN_DISC_SIZE}x{MIN_DISC_SIZE} texels, got {width}x{height}: "
                    f"too small to resolve the sphere")
    return None


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
def _equirect_directions_and_cos(rows: np.ndarray, cols: np.ndarray, height: int, width: int
                                 ) -> tuple[np.ndarray, np.ndarray]:
    """Directions (..., 3) at continuous pixel positions of an H × W equirect map, and cos(latitude) (...)."""
    latitude = np.pi * (0.5 - rows / height)
    longitude = np.pi * (1.0 - 2.0 * cols / width)
    c = np.cos(latitude)
    return np.stack([c * np.sin(longitude), np.sin(latitude), c * np.cos(longitude)], axis=-1), c


def equirect_directions(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """Directions (..., 3) at continuous pixel positions of an H × W equirect map."""
    return _equirect_directions_and_cos(rows, cols, height, width)[0]


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
# Disc maps: angular and mirrored ball
def _disc_uv(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    return 2.0 * cols / width - 1.0, 1.0 - 2.0 * rows / height


def _disc_polar_angle(layout: str, r: np.ndarray) -> np.ndarray:
    """Angle θ from +Z at disc radius r ∈ [0, 1]: θ = π·r (angular), θ = 2·asin r (mirrored ball)."""
    r = np.minimum(r, 1.0)
    return np.pi * r if layout == "angular" else 2.0 * np.arcsin(r)


def disc_directions(layout: str, rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """Directions (..., 3) at continuous pixel positions of a disc map (undefined outside the disc)."""
    u, v = _disc_uv(rows, cols, height, width)
    r = np.sqrt(u * u + v * v)
    theta = _disc_polar_angle(layout, r)
    # sin θ / r → dθ/dr at r = 0 (π, resp. 2); (u·s, v·s, cos θ) is unit length by construction.
    s = np.where(r > 1e-12, np.sin(theta) / np.maximum(r, 1e-12), np.pi if layout == "angular" else 2.0)
    return np.stack([u * s, v * s, np.cos(theta)], axis=-1)


def disc_density(layout: str, rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """Solid angle per unit pixel area, 0 outside the disc; du dv = (2/W)(2/H) per pixel.

    dΩ = sin θ · dθ/dr / r du dv: π·sin(πr)/r for the angular map; for the mirrored ball sin θ = 2r√(1−r²) and
    dθ/dr = 2/√(1−r²), so dΩ = 4 du dv, uniform (the disc's area π holds 4π steradians).
    """
    u, v = _disc_uv(rows, cols, height, width)
    r = np.sqrt(u * u + v * v)
    if layout == "angular":
        rc = np.minimum(r, 1.0)
        jac = np.where(r > 1e-12, np.pi * np.sin(np.pi * rc) / np.maximum(r, 1e-12), np.pi * np.pi)
    else:
        jac = np.full_like(r, 4.0)
    return np.where(r <= 1.0, jac, 0.0) * (4.0 / (width * height))


def disc_texel_solid_angles(layout: str, height: int, width: int, sub: int | None = None) -> np.ndarray:
    """Solid angle (H, W) of every texel of a disc map: :func:`disc_density` integrated over the texel's part inside
    the unit disc, then scaled so that the texels sum to 4π exactly (0 for texels off the disc).

    Texels wholly inside the disc take the 2 × 2-point Gauss–Legendre rule (the density is smooth there:
    π·sin(πr)/r, or 4 for the mirrored ball, exact); texels the rim crosses take sub × sub midpoints, each counted
    only inside the disc (``sub`` from 16 at ≥ 32 texels a side up to 64 for small maps). The rule alone sums to
    within 6·10⁻⁵ of 4π from 8 × 8 up (the angular map's density at the texel centres, read before: 0.56 % high at
    8 × 8, 3.14 × 4π at 1 × 1); the final scale removes the rest, so a constant image holds exactly 4π·L of flux.
    """
    omega = disc_texel_integrals(layout, height, width, sub)
    total = omega.sum()
    return omega * (4.0 * np.pi / total) if total > 0 else omega


def disc_texel_integrals(layout: str, height: int, width: int, sub: int | None = None) -> np.ndarray:
    """:func:`disc_density` integrated (H, W) over each texel's part inside the unit disc, before the scale to 4π
    (the quadrature of :func:`disc_texel_solid_angles`)."""
    if sub is None:
        sub = int(min(64, max(16, 512 // max(1, height, width))))
    omega = np.zeros((height, width))
    u_edges = 2.0 * np.arange(width + 1) / width - 1.0
    v_edges = 1.0 - 2.0 * np.arange(height + 1) / height
    # squared distance from the disc centre to the texel's nearest point and its farthest corner
    near_u = np.minimum(np.abs(u_edges[:-1]), np.abs(u_edges[1:])) * ((u_edges[:-1] > 0) | (u_edges[1:] < 0))
    near_v = np.minimum(np.abs(v_edges[:-1]), np.abs(v_edges[1:])) * ((v_edges[:-1] < 0) | (v_edges[1:] > 0))
    far_u = np.maximum(np.abs(u_edges[:-1]), np.abs(u_edges[1:]))
    far_v = np.maximum(np.abs(v_edges[:-1]), np.abs(v_edges[1:]))
    touches = near_v[:, None] ** 2 + near_u[None, :] ** 2 <= 1.0
    inside = far_v[:, None] ** 2 + far_u[None, :] ** 2 <= 1.0
    rim = touches & ~inside

    gauss = 0.5 + np.array([-0.5, 0.5]) / np.sqrt(3.0)
    band = max(1, 1_000_000 // max(1, 4 * width))  # rows per band: O(1M) points at a time
    for r0 in range(0, height, band):
        rows = np.arange(r0, min(height, r0 + band), dtype=np.float64)
        rr = rows[:, None, None, None] + gauss[None, None, :, None]
        cc = np.arange(width, dtype=np.float64)[None, :, None, None] + gauss[None, None, None, :]
        rr, cc = np.broadcast_arrays(rr, cc)
        density = disc_density(layout, rr, cc, height, width).mean(axis=(2, 3))
        omega[r0:r0 + rows.size] = np.where(inside[r0:r0 + rows.size], density, 0.0)

    r, c = np.nonzero(rim)
    offsets = (np.arange(sub) + 0.5) / sub
    chunk = max(1, 1_000_000 // (sub * sub))
    for start in range(0, r.size, chunk):
        part = slice(start, start + chunk)
        rr = r[part, None, None] + offsets[None, :, None] + 0.0 * offsets[None, None, :]
        cc = c[part, None, None] + 0.0 * offsets[None, :, None] + offsets[None, None, :]
        omega[r[part], c[part]] = disc_density(layout, rr, cc, height, width).mean(axis=(1, 2))
    return omega


def direction_to_disc(layout: str, directions: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (row, column) of directions (..., 3) in a disc map (−Z maps to the rim at +u)."""
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    theta = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
    r = theta / np.pi if layout == "angular" else np.sin(0.5 * theta)
    planar = np.hypot(d[..., 0], d[..., 1])
    cos_phi = np.where(planar > 1e-12, d[..., 0] / np.maximum(planar, 1e-12), 1.0)
    sin_phi = np.where(planar > 1e-12, d[..., 1] / np.maximum(planar, 1e-12), 0.0)
    u, v = r * cos_phi, r * sin_phi
    return (1.0 - v) * 0.5 * height, (u + 1.0) * 0.5 * width


def disc_inside(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    u, v = _disc_uv(rows, cols, height, width)
    return u * u + v * v <= 1.0


# ---------------------------------------------------------------------------------------------------------------
# Vertical cross (3N × 4N): cell (row, column) of each face, and its direction at face coordinates a (rightwards)
# and b (downwards) in [-1, 1]. Derived by unfolding: each image-adjacent pair of faces agrees on its shared edge
# (+Y|+Z, +X|+Z, +Z|−X, +Z|−Y, −Y|−Z), and the folded edges pair up likewise (tests check all twelve).
VERTICAL_CROSS_CELLS = {"+Y": (0, 1), "+X": (1, 0), "+Z": (1, 1), "-X": (1, 2), "-Y": (2, 1), "-Z": (3, 1)}


def _cross_face_direction(face: str, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    one = np.ones_like(a)
    return {
        "+Y": lambda: np.stack([-a, one, b], -1),
        "+X": lambda: np.stack([one, -b, a], -1),
        "+Z": lambda: np.stack([-a, -b, one], -1),
        "-X": lambda: np.stack([-one, -b, -a], -1),
        "-Y": lambda: np.stack([-a, -one, -b], -1),
        "-Z": lambda: np.stack([-a, b, -one], -1),
    }[face]()


def _cross_cell(rows: np.ndarray, cols: np.ndarray, face_size: int):
    cell_row = np.clip(np.floor(np.asarray(rows) / face_size).astype(np.int64), 0, 3)
    cell_col = np.clip(np.floor(np.asarray(cols) / face_size).astype(np.int64), 0, 2)
    a = 2.0 * (cols - cell_col * face_size) / face_size - 1.0
    b = 2.0 * (rows - cell_row * face_size) / face_size - 1.0
    return cell_row, cell_col, a, b


def vertical_cross_directions(rows: np.ndarray, cols: np.ndarray, face_size: int) -> np.ndarray:
    """Unit directions (..., 3) at continuous pixel positions of a vertical cross (zero in the empty cells)."""
    cell_row, cell_col, a, b = _cross_cell(rows, cols, face_size)
    out = np.zeros((*np.shape(a), 3))
    for face, (r, c) in VERTICAL_CROSS_CELLS.items():
        mask = (cell_row == r) & (cell_col == c)
        out[mask] = _cross_face_direction(face, a[mask], b[mask])
    norm = np.linalg.norm(out, axis=-1, keepdims=True)
    return out / np.where(norm > 0, norm, 1.0)


def vertical_cross_inside(rows: np.ndarray, cols: np.ndarray, face_size: int) -> np.ndarray:
    cell_row, cell_col, _, _ = _cross_cell(rows, cols, face_size)
    inside = np.zeros(np.shape(cell_row), dtype=bool)
    for r, c in VERTICAL_CROSS_CELLS.values():
        inside |= (cell_row == r) & (cell_col == c)
    return inside


def vertical_cross_density(rows: np.ndarray, cols: np.ndarray, face_size: int) -> np.ndarray:
    """Solid angle per unit pixel area: a cube face's (1 + a² + b²)^(-3/2) · (2/N)², 0 in the empty cells."""
    _, _, a, b = _cross_cell(rows, cols, face_size)
    return np.where(vertical_cross_inside(rows, cols, face_size), cube_texel_density(a, b, face_size), 0.0)


def vertical_cross_face_size(height: int, width: int) -> int:
    if 4 * width != 3 * height or width % 3:
        raise ValueError(f"a vertical cross is 3N x 4N, got {width}x{height}")
    return width // 3


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
    if layout == "equirect":  # cos(latitude) evaluated once (the reflection reference's hot path)
        directions, c = _equirect_directions_and_cos(rows, cols, height, width)
        return directions, c * (np.pi / height) * (2.0 * np.pi / width)  # equirect_density's arithmetic
    if layout in ("angular", "mirrored_ball"):
        return (disc_directions(layout, rows, cols, height, width),
                disc_density(layout, rows, cols, height, width))
    if layout == "cube":
        return exr_cube_directions(rows, cols, width), exr_cube_density(rows, cols, width)
    if layout == "vertical_cross":
        n = vertical_cross_face_size(height, width)
        return vertical_cross_directions(rows, cols, n), vertical_cross_density(rows, cols, n)
    raise ValueError(f"unknown layout {layout!r}")


def layout_inside(layout: str, rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """Whether continuous pixel positions hold radiance (the disc, the cross's six faces; everywhere otherwise)."""
    if layout in ("angular", "mirrored_ball"):
        return disc_inside(rows, cols, height, width)
    if layout == "vertical_cross":
        return vertical_cross_inside(rows, cols, vertical_cross_face_size(height, width))
    return np.ones(np.shape(rows), dtype=bool)
