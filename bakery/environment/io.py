"""Reading environment images through OpenImageIO (the only module here that touches files).

Supported: equirect ``.hdr``/``.exr`` (and any format OpenImageIO reads), OpenEXR cube maps (``envmap=cube``,
OpenImageIO's ``textureformat = "CubeFace Environment"``, six faces stacked vertically), and Debevec angular maps.
The layout comes from the file's metadata, else from its aspect ratio (2:1 equirect, 1:6 cube, 1:1 angular), and can
be forced.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from bakery.environment.layouts import LAYOUTS, EnvironmentImage
from bakery.environment.sanitize import SanitizeReport, sanitize_radiance
from bakery.errors import ImageError

#: Refuse images whose header claims more pixels than this (a corrupt or hostile header), before allocating.
MAX_PIXELS = 1 << 28


def detect_layout(width: int, height: int, texture_format: str = "") -> str:
    """Layout from OpenImageIO's ``textureformat`` metadata or, failing that, the aspect ratio."""
    tf = texture_format.lower()
    if "cube" in tf:
        return "cube"
    if "latlong" in tf:
        return "equirect"
    if width == 2 * height:
        return "equirect"
    if height == 6 * width:
        return "cube"
    if width == height:
        return "angular"
    raise ImageError(
        f"cannot tell the layout of a {width}x{height} image: expected 2:1 equirect, 1:6 stacked cube or 1:1 "
        f"angular map; pass the layout explicitly (--layout {{{','.join(LAYOUTS)}}})"
    )


def read_environment(path: str | os.PathLike[str], layout: str | None = None) -> tuple[EnvironmentImage, SanitizeReport]:
    """Read an environment image as linear RGB radiance, sanitised (see :mod:`bakery.environment.sanitize`).

    Raises:
        ImageError: the file is missing, unreadable, truncated, absurdly large or of an unknown layout.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"{path}: environment image not found")
    image_input = oiio.ImageInput.open(str(path))
    if image_input is None:
        raise ImageError(f"{path}: OpenImageIO cannot open it: {oiio.geterror() or 'unknown format'}")
    try:
        spec = image_input.spec()
        width, height, channels = spec.width, spec.height, spec.nchannels
        if width <= 0 or height <= 0 or channels <= 0:
            raise ImageError(f"{path}: header claims an empty image ({width}x{height}x{channels})")
        if width * height > MAX_PIXELS:
            raise ImageError(
                f"{path}: header claims {width}x{height} = {width * height:,} pixels, more than the {MAX_PIXELS:,} "
                f"bakery accepts; the file is corrupt or not an environment map"
            )
        try:
            chosen = layout or detect_layout(width, height, str(spec.getattribute("textureformat") or ""))
        except ImageError as error:
            raise ImageError(f"{path}: {error}") from None
        if chosen not in LAYOUTS:
            raise ImageError(f"{path}: unknown layout {chosen!r}; expected one of {LAYOUTS}")
        if chosen == "cube" and height != 6 * width:
            raise ImageError(f"{path}: a stacked cube map must be N x 6N, got {width}x{height}")
        pixels = image_input.read_image(0, 0, 0, min(channels, 3), oiio.FLOAT)
        if pixels is None:
            raise ImageError(f"{path}: reading pixels failed (truncated or corrupt file?): {image_input.geterror()}")
    finally:
        image_input.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(height, width, -1)
    if pixels.shape[2] == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    elif pixels.shape[2] == 2:
        raise ImageError(f"{path}: two-channel images are not radiance; expected RGB or luminance")
    radiance, report = sanitize_radiance(pixels, source=str(path))
    return EnvironmentImage(pixels=radiance, layout=chosen, source=str(path)), report


def write_exr(path: str | os.PathLike[str], pixels: np.ndarray, half: bool = True, attributes: dict | None = None) -> None:
    """Write (H, W, C) pixels as an OpenEXR file (float16 by default), atomically (temp file + rename)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}.exr")
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, oiio.HALF if half else oiio.FLOAT)
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(tmp))
    if out is None or not out.open(str(tmp), spec):
        raise ImageError(f"{path}: cannot write EXR: {oiio.geterror()}")
    try:
        if not out.write_image(np.ascontiguousarray(pixels, dtype=np.float32)):
            raise ImageError(f"{path}: writing EXR failed: {out.geterror()}")
    finally:
        out.close()
    os.replace(tmp, path)
