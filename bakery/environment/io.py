"""Reading images through OpenImageIO: environment maps and textures (the only module of bakery that imports
OpenImageIO, and the only one here that touches files).

Supported: equirect ``.hdr``/``.exr`` (and any format OpenImageIO reads), OpenEXR cube maps (``envmap=cube``,
OpenImageIO's ``textureformat = "CubeFace Environment"``, six faces stacked vertically), Debevec angular maps,
mirrored-ball photographs and vertical-cross cube maps (:mod:`bakery.environment.layouts`). The layout comes from
the file's metadata, else from its aspect ratio (2:1 equirect, 1:6 cube, 1:1 angular, 3:4 vertical cross), and can
be forced (a mirrored ball is 1:1 like an angular map, so it is always named).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from bakery.environment.layouts import LAYOUTS, EnvironmentImage
from bakery.environment.sanitize import SanitizeReport, sanitize_radiance
from bakery.errors import ImageError
from bakery.files import atomic_replace

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
    if 4 * width == 3 * height and width % 3 == 0:
        return "vertical_cross"
    raise ImageError(
        f"cannot tell the layout of a {width}x{height} image: expected 2:1 equirect, 1:6 stacked cube, 1:1 "
        f"angular map or 3:4 vertical cross; pass the layout explicitly (--layout {{{','.join(LAYOUTS)}}})"
    )


@dataclass(frozen=True)
class ImagePixels:
    """The pixels of one image file as OpenImageIO decodes them.

    Attributes:
        pixels: (H, W, C) float32, C = min(the file's channels, the channels asked for); integer formats are
            normalised to [0, 1] (no colour decoding).
        is_8bit: the file stores 8-bit integer channels (by convention sRGB-encoded, as Hydra assumes).
        texture_format: OpenImageIO's ``textureformat`` metadata ("" when absent), e.g. ``CubeFace Environment``.
    """

    pixels: np.ndarray
    is_8bit: bool
    texture_format: str = ""


def _is_8bit(spec: oiio.ImageSpec) -> bool:
    return spec.format.basetype in (oiio.UINT8, oiio.INT8)


@contextmanager
def _opened(path: Path) -> Iterator[tuple[oiio.ImageInput, oiio.ImageSpec]]:
    """An open ImageInput and its spec, after the header checks (empty image, more than :data:`MAX_PIXELS`)."""
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
                f"bakery accepts; the file is corrupt"
            )
        yield image_input, spec
    finally:
        image_input.close()


def read_image(path: str | os.PathLike[str], channels: int = 4) -> ImagePixels:
    """Pixels of any image OpenImageIO reads, the first ``channels`` channels as float32 (see :class:`ImagePixels`).

    Raises:
        ImageError: the file is missing, unreadable, truncated or its header claims an empty or absurdly large image.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"{path}: image not found")
    with _opened(path) as (image_input, spec):
        pixels = image_input.read_image(0, 0, 0, min(spec.nchannels, channels), oiio.FLOAT)
        if pixels is None:
            raise ImageError(f"{path}: reading pixels failed (truncated or corrupt file?): {image_input.geterror()}")
        return ImagePixels(
            pixels=np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, -1),
            is_8bit=_is_8bit(spec),
            texture_format=str(spec.getattribute("textureformat") or ""),
        )


def is_8bit_image(path: str | os.PathLike[str]) -> bool:
    """Whether an image file stores 8-bit integer channels (header only; False when it cannot be opened)."""
    try:
        with _opened(Path(path)) as (_, spec):
            return _is_8bit(spec)
    except ImageError:
        return False


def missing_image_message(path: Path) -> str:
    """Why ``path`` cannot be read as an environment image: a folder (or a USD scene's suffix missing), or absent."""
    if path.is_dir():
        return (f"{path}: is a directory, not an environment image (give the image files, or a USD scene file, "
                f"e.g. {path}/*.hdr)")
    return f"{path}: environment image not found"


def read_environment(path: str | os.PathLike[str], layout: str | None = None) -> tuple[EnvironmentImage, SanitizeReport]:
    """Read an environment image as linear RGB radiance, sanitised (see :mod:`bakery.environment.sanitize`).

    Raises:
        ImageError: the file is missing, unreadable, truncated, absurdly large or of an unknown layout.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageError(missing_image_message(path))
    if layout is not None and layout not in LAYOUTS:
        raise ImageError(f"{path}: unknown layout {layout!r}; expected one of {LAYOUTS}")
    image = read_image(path, channels=3)
    pixels = image.pixels
    height, width = pixels.shape[:2]
    try:
        chosen = layout or detect_layout(width, height, image.texture_format)
    except ImageError as error:
        raise ImageError(f"{path}: {error}") from None
    if chosen == "cube" and height != 6 * width:
        raise ImageError(f"{path}: a stacked cube map must be N x 6N, got {width}x{height}")
    if chosen == "vertical_cross" and (4 * width != 3 * height or width % 3):
        raise ImageError(f"{path}: a vertical cross must be 3N x 4N, got {width}x{height}")
    if pixels.shape[2] == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    elif pixels.shape[2] == 2:
        raise ImageError(f"{path}: two-channel images are not radiance; expected RGB or luminance")
    radiance, report = sanitize_radiance(pixels, source=str(path))
    return EnvironmentImage(pixels=radiance, layout=chosen, source=str(path)), report


def write_exr(path: str | os.PathLike[str], pixels: np.ndarray, half: bool = True, attributes: dict | None = None) -> None:
    """Write (H, W, C) pixels as an OpenEXR file (float16 by default), atomically (temp file + rename)."""
    path = Path(path)
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, oiio.HALF if half else oiio.FLOAT)
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    with atomic_replace(path, suffix=".exr") as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise ImageError(f"{path}: cannot write EXR: {oiio.geterror()}")
        try:
            if not out.write_image(np.ascontiguousarray(pixels, dtype=np.float32)):
                raise ImageError(f"{path}: writing EXR failed: {out.geterror()}")
        finally:
            out.close()
