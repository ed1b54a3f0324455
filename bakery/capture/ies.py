"""IES photometric profiles (ANSI/IES LM-63) on UsdLux lights: ``inputs:shaping:ies:*`` of UsdLuxShapingAPI.

Reading (LM-63-1986 … LM-63-2019; the keyword header up to ``TILT=`` is skipped, values may be separated by
spaces, line breaks or commas)
    After ``TILT=`` (NONE, INCLUDE with its tilt table skipped, or a tilt file name, ignored: tilt only matters
    for lamps mounted at other angles than measured): lamp count, lumens per lamp, candela multiplier, the numbers
    of vertical and horizontal angles, the photometric type, units, width, length, height, ballast factor,
    ballast–lamp photometric factor (1 = "future use" since LM-63-1995), input watts, then the vertical angles,
    the horizontal angles and the candela values, one run of vertical angles per horizontal angle.

Intensity units (as OpenUSD's reference renderer HdEmbree, ``pxrIES``, reads them)
    value = candela × multiplier × ballast factor × ballast–lamp factor × 4π/177.83 (Cycles' candela → W/sr·4π
    factor for a D65 white, :data:`CANDELA_TO_EMBREE`), and the light's radiance is multiplied by the sampled
    value. With ``shaping:ies:normalize`` the value is divided by the profile's power (:attr:`IesProfile.power`:
    the mean of the intensity over the sphere, or the hemisphere when the vertical angles span at most
    90° + 0.1 rad, by the midpoint rule on the angle grid — pxrIES's ``pxr_extra_process``), so the profile
    shapes the light without changing its mean output.

Angles (photometric type C; types A and B are transposed onto it as Cycles and pxrIES do)
    The vertical angle θ is measured from the light's emission axis −Z (θ = 0 straight along −Z, the nadir of a
    down light), the horizontal angle φ counter-clockwise from +X towards +Y seen from +Z (LM-63's convention:
    seen from above the luminaire). For an emission direction e in light-local coordinates: θ = acos(−e_z),
    φ = atan2(e_y, e_x). (HdEmbree evaluates φ of −e, i.e. φ + 180°: the same result for profiles symmetric
    under a half turn, which most are.) The horizontal angles are expanded to a full turn by the symmetry the
    file declares: a single angle (rotational symmetry), 0–90° (quadrants), 0–180° (the 0–180° plane),
    90–270° (the 90–270° plane: mirrored as φ → 180° − φ). Values are bilinear in (θ, φ) on the grid and 0
    outside the vertical range the file covers.

``shaping:ies:angleScale`` s (UsdLuxShapingAPI, OpenUSD ≥ 25.05 documentation)
    θ_ies = θ / s (s > 0: scaled about θ = 0, for profiles aimed down), θ (s = 0), (θ − π) / (−s) + π (s < 0:
    about θ = π, for profiles aimed up); θ_ies outside the profile is dark.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

#: Cycles' candela → radiometric factor, 4π / 177.83 (the luminous efficacy of D65 in lm/W), which OpenUSD's
#: HdEmbree (pxrIES, from Cycles' ``util/ies.cpp``) applies to every value: the unnormalised profile's scale.
CANDELA_TO_EMBREE = 4.0 * math.pi / 177.83
#: Vertical spans above 90° + this (radians) make the profile a sphere's, not a hemisphere's (pxrIES).
_HEMISPHERE_FUDGE = 0.1
_PHOTOMETRIC_TYPES = {1: "C", 2: "B", 3: "A"}


class IesError(ValueError):
    """A profile that cannot be read; the message is one line naming what is wrong."""


@dataclass(frozen=True)
class IesProfile:
    """A photometric profile on the type-C grid, horizontal angles expanded to a full turn.

    Attributes:
        source: the file it was read from (for messages).
        vertical: (V,) ascending vertical angles θ in radians (0 = the emission axis −Z).
        horizontal: (H,) ascending horizontal angles φ in radians: 0 to 2π for type C (H ≥ 2); types A and B
            keep the span they cover (dark outside it).
        intensity: (H, V) values in HdEmbree's units (module docstring), row h at ``horizontal[h]``.
        power: the mean value over the sphere or hemisphere the profile covers (``shaping:ies:normalize``).
    """

    source: str
    vertical: tuple[float, ...]
    horizontal: tuple[float, ...]
    intensity: tuple[tuple[float, ...], ...]
    power: float

    @property
    def peak(self) -> float:
        """The largest value of the profile (what a light's radiance bound multiplies)."""
        return float(max(max(row) for row in self.intensity))


@dataclass(frozen=True)
class IesShaping:
    """A light's IES shaping: the profile, ``shaping:ies:angleScale`` and ``shaping:ies:normalize``."""

    profile: IesProfile
    angle_scale: float = 0.0
    normalize: bool = False

    @property
    def peak(self) -> float:
        """The largest factor the shaping applies to the light's radiance."""
        peak = self.profile.peak
        return peak / self.profile.power if self.normalize and self.profile.power > 0 else peak


def _numbers(text: str, source: str) -> tuple[str, list[str]]:
    """The TILT mode and the whitespace/comma separated tokens after the TILT line."""
    match = re.search(r"^\s*TILT\s*=\s*(.*?)\s*$", text, flags=re.MULTILINE)
    if match is None:
        raise IesError(f"{source}: not an IES (LM-63) profile: no TILT= line")
    tokens = text[match.end():].replace(",", " ").split()
    return match.group(1).upper(), tokens


def parse_ies(text: str, source: str = "<ies>") -> IesProfile:
    """An :class:`IesProfile` from the text of an LM-63 file (module docstring); :class:`IesError` if malformed."""
    tilt, tokens = _numbers(text, source)
    position = 0

    def take(count: int, what: str) -> np.ndarray:
        nonlocal position
        if position + count > len(tokens):
            raise IesError(f"{source}: the file ends before its {what}")
        try:
            values = np.array([float(t) for t in tokens[position:position + count]], dtype=np.float64)
        except ValueError as error:
            raise IesError(f"{source}: {what}: {error}") from None
        position += count
        if not np.all(np.isfinite(values)):
            raise IesError(f"{source}: {what} are not finite")
        return values

    if tilt == "INCLUDE":  # lamp-to-luminaire geometry, the tilt angles and their factors: not used
        take(1, "tilt geometry")
        count = int(take(1, "tilt angle count")[0])
        take(2 * count, "tilt table")
    header = take(13, "photometric header")
    multiplier = header[2] * header[10] * header[11]  # candela multiplier × ballast × ballast-lamp factor
    v_count, h_count, kind = int(header[3]), int(header[4]), int(header[5])
    if kind not in _PHOTOMETRIC_TYPES:
        raise IesError(f"{source}: photometric type {kind} is not 1 (C), 2 (B) or 3 (A)")
    if v_count < 1 or h_count < 1:
        raise IesError(f"{source}: {v_count} vertical and {h_count} horizontal angles")
    vertical = take(v_count, "vertical angles")
    horizontal = take(h_count, "horizontal angles")
    candela = take(v_count * h_count, "candela values").reshape(h_count, v_count) * multiplier
    if np.any(np.diff(vertical) <= 0) or np.any(np.diff(horizontal) <= 0):
        raise IesError(f"{source}: the angles are not strictly increasing")
    if np.any(candela < 0):
        raise IesError(f"{source}: negative candela values")
    vertical, horizontal, candela = _to_type_c(_PHOTOMETRIC_TYPES[kind], vertical, horizontal, candela)
    if vertical[0] < -1e-4 or vertical[-1] > 180 + 1e-4:
        raise IesError(f"{source}: vertical angles {vertical[0]:g}…{vertical[-1]:g}° are outside 0…180°")
    if kind == 1:  # type C: a full turn by the declared symmetry; A and B keep their span (dark outside it)
        horizontal, candela = _full_turn(horizontal, candela, source)
    v, h = np.radians(vertical), np.radians(horizontal)
    intensity = candela * CANDELA_TO_EMBREE
    return IesProfile(source=source, vertical=tuple(v.tolist()), horizontal=tuple(h.tolist()),
                      intensity=tuple(tuple(row) for row in intensity.tolist()), power=_power(v, h, intensity))


def _close(a: float, b: float) -> bool:
    return abs(a - b) < 1e-4


def _to_type_c(kind: str, vertical: np.ndarray, horizontal: np.ndarray, candela: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Types A and B on the type-C grid as pxrIES (Cycles) does: vertical angles offset by 90°, horizontal ones
    mirrored from a half range; type B's polar axis is horizontal, so its grid is transposed first."""
    if kind == "C":
        return vertical, horizontal, candela
    if kind == "B":  # transpose: the polar axis becomes vertical
        candela = candela.T
        vertical, horizontal = horizontal, vertical
        if _close(horizontal[0], 0.0):  # 0…90° → mirrored to −90…90°, shifted to 0…180°
            horizontal = np.concatenate([90.0 - horizontal[:0:-1], 90.0 + horizontal])
            candela = np.concatenate([candela[:0:-1], candela])
        else:
            horizontal = horizontal + 90.0
        if _close(vertical[0], 0.0):
            vertical = np.concatenate([90.0 - vertical[:0:-1], 90.0 + vertical])
            candela = np.concatenate([candela[:, :0:-1], candela], axis=1)
        else:
            vertical = vertical + 90.0
        return vertical, horizontal, candela
    # type A: vertical −90…90° → 0…180°; horizontal −90…90° maps to 270…90° (reversed), 0…90° mirrored
    vertical = vertical + 90.0
    new_h = 180.0 - horizontal[::-1]
    new_c = candela[::-1]
    if _close(horizontal[0], 0.0):
        new_h = np.concatenate([new_h, 180.0 + horizontal[1:]])
        new_c = np.concatenate([new_c, candela[1:]])
    return vertical, new_h, new_c


def _full_turn(horizontal: np.ndarray, candela: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal angles expanded to 0…360° by the symmetry the file declares (module docstring)."""
    if horizontal.size == 1:  # rotationally symmetric
        return np.array([0.0, 360.0]), np.concatenate([candela, candela])
    if _close(horizontal[0], 90.0) and _close(horizontal[-1], 270.0):  # symmetric about the 90–270° plane
        # φ → 180° − φ: the mirror images of the inner angles cover −90…90°
        mirrored = 180.0 - horizontal[-2:0:-1]
        angles = np.mod(np.concatenate([mirrored, horizontal]), 360.0)
        values = np.concatenate([candela[-2:0:-1], candela])
        order = np.argsort(angles, kind="stable")
        return _close_turn(angles[order], values[order])
    if not _close(horizontal[0], 0.0):
        raise IesError(f"{source}: horizontal angles start at {horizontal[0]:g}° (expected 0° or 90…270°)")
    if _close(horizontal[-1], 90.0):  # one quadrant: mirror to 0…180°, then below
        horizontal = np.concatenate([horizontal, 180.0 - horizontal[-2::-1]])
        candela = np.concatenate([candela, candela[-2::-1]])
    if _close(horizontal[-1], 180.0):  # bilateral about the 0–180° plane
        horizontal = np.concatenate([horizontal, 360.0 - horizontal[-2::-1]])
        candela = np.concatenate([candela, candela[-2::-1]])
    if _close(horizontal[-1], 360.0):
        return horizontal, candela
    if horizontal[-1] < 360.0:  # a full turn without its closing 360° entry (some files)
        return _close_turn(horizontal, candela)
    raise IesError(f"{source}: horizontal angles end at {horizontal[-1]:g}° (beyond a full turn)")


def _close_turn(angles: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ascending angles in [0°, 360°) (H,) and their rows (H, V) → a grid from exactly 0° to 360°: the rows at 0°
    and 360° interpolated linearly across the wrap between the last and the first angle."""
    if not _close(angles[0], 0.0):
        gap = angles[0] + 360.0 - angles[-1]
        weight = (360.0 - angles[-1]) / gap
        at_zero = values[-1] * (1 - weight) + values[0] * weight
        angles = np.concatenate([[0.0], angles])
        values = np.concatenate([at_zero[None], values])
    return np.concatenate([angles, [360.0]]), np.concatenate([values, values[:1]])


def _power(vertical: np.ndarray, horizontal: np.ndarray, intensity: np.ndarray) -> float:
    """Mean intensity over the sphere (or hemisphere) the profile covers: the midpoint rule of pxrIES on the
    grid, Σ Δφ Δθ sin(θ_mid) · I(cell centre, bilinear) / (4π or 2π)."""
    if vertical.size < 2:
        return 0.0
    d_h = np.diff(horizontal)[:, None]
    d_v = np.diff(vertical)[None, :]
    centre = 0.25 * (intensity[:-1, :-1] + intensity[:-1, 1:] + intensity[1:, :-1] + intensity[1:, 1:])
    total = float(np.sum(d_h * d_v * np.sin(vertical[:-1] + 0.5 * d_v) * centre))
    sphere = vertical[-1] - vertical[0] > math.pi / 2 + _HEMISPHERE_FUDGE
    return total / (math.pi * (4.0 if sphere else 2.0))


def scaled_vertical_angle(theta: np.ndarray, angle_scale: float) -> np.ndarray:
    """θ_ies of ``shaping:ies:angleScale`` (module docstring) for vertical angles θ (M,) in radians."""
    if angle_scale > 0:
        return theta / angle_scale
    if angle_scale < 0:
        return (theta - math.pi) / -angle_scale + math.pi
    return theta


def _bilinear_cells(grid: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For samples x (M,) on an ascending grid (N,): the cell index (M,), the weight of its upper node and
    whether x lies on the grid's span."""
    inside = (x >= grid[0]) & (x <= grid[-1])
    index = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
    lo, hi = grid[index], grid[index + 1]
    weight = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return index, weight, inside


def evaluate_ies(shaping: IesShaping, emission: np.ndarray) -> np.ndarray:
    """The factor (M,) the shaping applies to the radiance emitted along light-local unit directions
    ``emission`` (3, M) (module docstring: θ = acos(−e_z), φ = atan2(e_y, e_x))."""
    profile = shaping.profile
    dtype = emission.dtype if emission.dtype.kind == "f" else np.float64
    e = np.asarray(emission, dtype=np.float64)
    theta = scaled_vertical_angle(np.arccos(np.clip(-e[2], -1.0, 1.0)), shaping.angle_scale)
    phi = np.mod(np.arctan2(e[1], e[0]), 2.0 * math.pi)
    vertical = np.asarray(profile.vertical)
    intensity = np.asarray(profile.intensity)
    horizontal = np.asarray(profile.horizontal)
    if vertical.size == 1:  # a single vertical angle: its value on that cone only (measure zero) → dark
        return np.zeros(e.shape[1], dtype=dtype)
    vi, vw, inside = _bilinear_cells(vertical, theta)
    hi, hw, inside_h = _bilinear_cells(horizontal, phi)
    inside &= inside_h
    low = intensity[hi, vi] * (1 - vw) + intensity[hi, vi + 1] * vw
    high = intensity[hi + 1, vi] * (1 - vw) + intensity[hi + 1, vi + 1] * vw
    value = np.where(inside, low * (1 - hw) + high * hw, 0.0)
    if shaping.normalize:
        value = value / profile.power if profile.power > 0 else np.zeros_like(value)
    return value.astype(dtype, copy=False)
