"""Colour management of texture and colour inputs into the bake's working space, linear Rec.709, with OpenColorIO.

The bake works in linear Rec.709 (``lin_rec709``; recorded in the store as ``capture_working_space``). Sources in
other spaces are converted with OpenColorIO's built-in studio config (``studio-config-latest``), which knows the
usual names and aliases (``ACEScg``/``lin_ap1``/``acescg``, ``srgb_texture``/``sRGB``, ``lin_displayp3``,
``ACES2065-1``/``lin_ap0``, ``g22_rec709`` …). ``raw`` (data) is never converted. sRGB decoding of 8-bit textures
("auto") uses the same config's ``srgb_texture``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

WORKING_SPACE = "lin_rec709"
#: UsdShade/MaterialX spellings mapped to OpenColorIO names (the config resolves further aliases itself).
_ALIASES = {"sRGB": "srgb_texture", "srgb": "srgb_texture", "linear": "lin_rec709", "lin_srgb": "lin_rec709",
            "": "lin_rec709"}
_RAW = {"raw", "Raw", "data", "none"}


class ColorSpaceError(ValueError):
    """An unknown colour-space name."""


@lru_cache(maxsize=1)
def _config():  # noqa: ANN202
    import PyOpenColorIO as ocio

    return ocio.Config.CreateFromBuiltinConfig("studio-config-latest")


def canonical_name(name: str) -> str | None:
    """The OpenColorIO colour space ``name`` denotes (None for raw/data). Raises ColorSpaceError if unknown."""
    if name in _RAW:
        return None
    name = _ALIASES.get(name, name)
    space = _config().getColorSpace(name)
    if space is None:
        raise ColorSpaceError(f"unknown colour space {name!r}")
    return space.getName()


@lru_cache(maxsize=32)
def _processor(source: str):  # noqa: ANN202
    config = _config()
    target = config.getColorSpace(WORKING_SPACE).getName()
    return config.getProcessor(source, target).getDefaultCPUProcessor()


def is_working_space(name: str) -> bool:
    canonical = canonical_name(name)
    return canonical is None or canonical == _config().getColorSpace(WORKING_SPACE).getName()


def to_working_space(rgb: np.ndarray, name: str) -> np.ndarray:
    """RGB values (..., 3) in colour space ``name`` converted to linear Rec.709 (float32)."""
    values = np.ascontiguousarray(np.asarray(rgb, dtype=np.float32))
    if is_working_space(name):
        return values
    flat = np.ascontiguousarray(values.reshape(-1, 3))
    _processor(canonical_name(name)).applyRGB(flat)
    return flat.reshape(values.shape)
