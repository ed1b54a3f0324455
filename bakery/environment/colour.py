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
