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


#: Hydra's tolerance on a PNG's gAMA value (Hio's stb reader: |γ − 0.45455| < 0.1 is sRGB, |γ − 1| < 0.1 linear)
_GAMMA_TOLERANCE = 0.1


def png_transfer_tag(path: str) -> str:
    """What a PNG file's own colour chunks say about its encoding, read before its image data: ``"srgb"`` for an
    ``sRGB`` chunk or a ``gAMA`` of 1/2.2 (0.45455), ``"linear"`` for a ``gAMA`` of 1, else ``""`` (not a PNG, no
    chunk, another gamma). UsdPreviewSurface's ``sourceColorSpace`` "auto" checks the file's gamma / colour-space
    metadata before it guesses from the bit depth and channel count (Hydra's stb reader reads ``gAMA`` the same
    way); OpenImageIO reports a PNG without these chunks as sRGB too, so its ``oiio:ColorSpace`` cannot tell."""
    try:
        with open(path, "rb") as handle:
            if handle.read(8) != b"\x89PNG\r\n\x1a\n":
                return ""
            tag = ""
            for _ in range(64):  # the colour chunks precede IDAT (PNG specification, chunk ordering)
                head = handle.read(8)
                if len(head) < 8:
                    return tag
                length, kind = int.from_bytes(head[:4], "big"), head[4:]
                if kind in (b"IDAT", b"IEND"):
                    return tag
                if kind not in (b"gAMA", b"sRGB"):
                    handle.seek(length + 4, 1)  # the chunk's data and CRC
                    continue
                data = handle.read(length)
                handle.seek(4, 1)  # CRC
                if kind == b"sRGB":
                    return "srgb"
                if kind == b"gAMA" and len(data) == 4:
                    gamma = int.from_bytes(data, "big") / 100000.0
                    if abs(gamma - 0.45455) < _GAMMA_TOLERANCE:
                        tag = "srgb"
                    elif abs(gamma - 1.0) < _GAMMA_TOLERANCE:
                        tag = "linear"
            return tag
    except OSError:
        return ""


def auto_decodes_srgb(path: str, is_8bit: bool, channels: int) -> tuple[bool, str]:
    """UsdUVTexture ``sourceColorSpace = "auto"`` (UsdPreviewSurface specification 2.5): "Check for gamma/color
    space metadata in the texture file itself; if metadata is indicative of sRGB, mark texture as sRGB. If no
    relevant metadata is found, mark texture as sRGB if it is either 8-bit and has 3 channels or if it is 8-bit and
    has 4 channels. Otherwise, do not mark texture as sRGB". Returns (decode as sRGB, why) for the file at ``path``
    with ``channels`` channels (its integer depth ``is_8bit``)."""
    tag = png_transfer_tag(path)
    if tag:
        return tag == "srgb", f"its PNG colour chunk says {tag}"
    if is_8bit and channels in (3, 4):
        return True, f"8-bit, {channels} channels"
    return False, ("8-bit, " if is_8bit else "not 8-bit, ") + f"{channels} channel{'s' if channels != 1 else ''}"
