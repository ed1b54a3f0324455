"""Transfer functions of integer image files: which one a file's colour-space name means, and decoding to linear
(pure numpy; :mod:`bakery.environment.io` applies them to environment images).

The sRGB EOTF is the one definition in bakery (IEC 61966-2-1); texture readers should import it from here.
"""

from __future__ import annotations

import re

import numpy as np

#: Colour-space names (lower case) of sRGB-encoded Rec.709: OpenImageIO's ``oiio:ColorSpace`` for PNG, JPEG, BMP
#: (``srgb_rec709_scene``), the OCIO built-in configs' names and aliases, and USD's ``sRGB``.
SRGB_NAMES = frozenset({"srgb", "srgb_rec709_scene", "srgb_rec709_display", "srgb_texture", "srgb - texture",
                        "srgb encoded rec.709 (srgb)", "srgb_tx"})
#: Colour-space names (lower case) of linear Rec.709: OpenImageIO's ``lin_rec709_scene`` (e.g. ``.hdr``) and aliases.
LINEAR_NAMES = frozenset({"linear", "lin_rec709", "lin_rec709_scene", "lin_srgb", "scene_linear", "raw",
                          "linear rec.709 (srgb)", "lin_rec709_srgb"})
_GAMMA_NAME = re.compile(
    r"^g(\d)(\d)_rec709(_scene|_display)?$|^gamma ?(?:corrected ?)?(\d+(?:\.\d+)?)(?: encoded rec\.709)?$")


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """The sRGB EOTF (IEC 61966-2-1) of encoded values (...) in [0, 1]: c/12.92 for c ≤ 0.04045, else
    ((c + 0.055)/1.055)^2.4. Same shape; float64 for float64 input, else float32."""
    values = np.asarray(values)
    dtype = np.float64 if values.dtype == np.float64 else np.float32
    c = values.astype(dtype, copy=False)
    return np.where(c <= 0.04045, c / 12.92, ((np.maximum(c, 0.0) + 0.055) / 1.055) ** 2.4).astype(dtype)


def transfer_of(color_space: str, gamma: float | None = None) -> tuple[str, float] | None:
    """What a file's colour-space name says about its encoding: ``("srgb", 0)``, ``("linear", 0)``,
    ``("gamma", γ)`` (OpenImageIO's ``g22_rec709``/``Gamma2.2``, γ from its ``oiio:Gamma`` attribute when given),
    or None (no name, or a name bakery does not interpret)."""
    name = color_space.strip().lower()
    if not name:
        return None
    if name in SRGB_NAMES:
        return "srgb", 0.0
    if name in LINEAR_NAMES:
        return "linear", 0.0
    match = _GAMMA_NAME.match(name)
    if match:
        parsed = float(f"{match[1]}.{match[2]}") if match[1] else float(match[4])
        value = float(gamma) if gamma and gamma > 0 else parsed
        if not value > 0.0:  # "g00_rec709", "gamma 0": no transfer function (c⁰ = 1 would make every texel white)
            return None
        return ("linear", 0.0) if value == 1.0 else ("gamma", value)
    return None


def decode_to_linear(values: np.ndarray, transfer: str, gamma: float = 0.0) -> np.ndarray:
    """``values`` (...) in [0, 1] decoded by ``transfer`` (``srgb``, ``gamma`` with exponent ``gamma``, ``linear``)."""
    if transfer == "srgb":
        return srgb_to_linear(values)
    if transfer == "gamma":
        return (np.maximum(np.asarray(values, dtype=np.float32), 0.0) ** np.float32(gamma)).astype(np.float32)
    return np.asarray(values, dtype=np.float32)


# ---------------------------------------------------------------------------------------------------------------
# Primaries: linear RGB of other gamuts → linear Rec.709 (the bake's colour, :mod:`bakery.conventions`)
#: CIE xy chromaticities (red, green, blue, white) as OpenEXR's ``chromaticities`` attribute orders them.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
#: Linear colour spaces by name (lower case; OpenImageIO's ``oiio:ColorSpace``, OpenColorIO's built-in names and
#: aliases) → their chromaticities (ACES: SMPTE ST 2065-1 and S-2014-004; Rec.2020: ITU-R BT.2020; P3-D65: SMPTE
#: EG 432-1 with the D65 white).
LINEAR_GAMUTS = {
    **{name: REC709_CHROMATICITIES for name in LINEAR_NAMES},
    **{name: (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.077, 0.32168, 0.33767)
       for name in ("aces2065-1", "aces2065_1", "aces", "lin_ap0", "lin_ap0_scene", "aces - aces2065-1")},
    **{name: (0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767)
       for name in ("acescg", "lin_ap1", "lin_ap1_scene", "aces - acescg")},
    **{name: (0.708, 0.292, 0.170, 0.797, 0.131, 0.046, 0.3127, 0.3290)
       for name in ("linear rec.2020", "lin_rec2020", "lin_rec2020_scene", "utility - linear - rec.2020")},
    **{name: (0.680, 0.320, 0.265, 0.690, 0.150, 0.060, 0.3127, 0.3290)
       for name in ("linear p3-d65", "lin_p3d65", "lin_p3d65_scene", "lin_displayp3", "linear display p3",
                    "utility - linear - p3-d65")},
}
#: Bradford cone response matrix (Lam 1985; as ACES and OpenColorIO's built-in configs adapt white points).
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])


def _xy_to_xyz(x: float, y: float) -> np.ndarray:
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


def rgb_to_xyz_matrix(chromaticities) -> np.ndarray:  # noqa: ANN001
    """(3, 3) linear RGB → CIE XYZ of primaries and white ``(xr, yr, xg, yg, xb, yb, xw, yw)`` (white → Y = 1)."""
    c = [float(v) for v in chromaticities]
    primaries = np.stack([_xy_to_xyz(c[0], c[1]), _xy_to_xyz(c[2], c[3]), _xy_to_xyz(c[4], c[5])], axis=1)
    return primaries * np.linalg.solve(primaries, _xy_to_xyz(c[6], c[7]))[None, :]


def chromaticities_problem(chromaticities) -> str | None:  # noqa: ANN001
    """Why ``chromaticities`` (8 numbers) cannot be primaries and a white (one line), or None if they can."""
    try:
        c = [float(v) for v in chromaticities]
    except (TypeError, ValueError):
        return f"chromaticities {chromaticities!r} are not numbers"
    if len(c) != 8 or not all(np.isfinite(c)):
        return f"chromaticities {tuple(c)} are not 8 finite numbers"
    if min(c[1], c[3], c[7]) <= 0.0 or abs(c[5]) < 1e-9:
        return f"chromaticities {tuple(c)} have a zero luminance primary or white (y = 0)"
    primaries = np.stack([_xy_to_xyz(c[0], c[1]), _xy_to_xyz(c[2], c[3]), _xy_to_xyz(c[4], c[5])], axis=1)
    if abs(np.linalg.det(primaries)) < 1e-9:
        return f"chromaticities {tuple(c)} have collinear primaries"
    return None


def to_rec709_matrix(chromaticities) -> np.ndarray | None:  # noqa: ANN001
    """(3, 3) M with rec709 = M @ rgb for linear RGB of ``chromaticities``, the white adapted to D65 by Bradford;
    None when they are Rec.709's (within 5·10⁻⁴ in x and y: files round them)."""
    c = np.asarray([float(v) for v in chromaticities])
    if np.max(np.abs(c - np.asarray(REC709_CHROMATICITIES))) <= 5e-4:
        return None
    source_white = rgb_to_xyz_matrix(c) @ np.ones(3)
    target = rgb_to_xyz_matrix(REC709_CHROMATICITIES)
    target_white = target @ np.ones(3)
    cone_ratio = (_BRADFORD @ target_white) / (_BRADFORD @ source_white)
    adapt = np.linalg.solve(_BRADFORD, cone_ratio[:, None] * _BRADFORD)
    return np.linalg.solve(target, adapt @ rgb_to_xyz_matrix(c))
