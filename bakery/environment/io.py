"""Reading images through OpenImageIO: environment maps and textures (the only module of bakery that imports
OpenImageIO, and the only one here that touches files).

Supported: equirect ``.hdr``/``.exr`` (and any format OpenImageIO reads), OpenEXR cube maps (``envmap=cube``,
OpenImageIO's ``textureformat = "CubeFace Environment"``, six faces stacked vertically), Debevec angular maps,
mirrored-ball photographs and vertical-cross cube maps (:mod:`bakery.environment.layouts`). The layout comes from
the file's metadata, else from its aspect ratio (2:1 equirect, 1:6 cube, 1:1 angular, 3:4 vertical cross), and can
be forced (a mirrored ball is 1:1 like an angular map, so it is always named). Disc maps must be square and at
least :data:`~bakery.environment.layouts.MIN_DISC_SIZE` texels a side.

Colour of environment images (:func:`read_environment`)
    Float files (EXR, HDR, float TIFF) are linear radiance as stored. Integer files (8/16-bit PNG, JPEG, TIFF, …)
    are decoded to linear by the transfer function OpenImageIO reports in ``oiio:ColorSpace`` (PNG, JPEG and BMP:
    ``srgb_rec709_scene``, 8- and 16-bit alike; a PNG ``gAMA`` chunk: ``g22_rec709``…; a linear tag: none), and
    without such metadata (TIFF, TGA) by bit depth: 8-bit files are sRGB-encoded by convention — as DomeLight
    textures are read (``sourceColorSpace`` "auto", Hydra's rule) — and deeper ones linear. Every integer file's
    decode is a one-line :class:`~bakery.errors.BakeryWarning` ("FILE: 8-bit image decoded as sRGB to linear
    radiance"), recorded in the store's ``warnings`` like the sanitised-texel counts.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from bakery.environment.colour import decode_to_linear, transfer_of
from bakery.environment.layouts import LAYOUTS, EnvironmentImage, layout_size_problem
from bakery.environment.sanitize import SanitizeReport, sanitize_radiance
from bakery.errors import ArgumentError, BakeryWarning, ImageError
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
        integer_bits: bits per channel of an integer file (8, 16, 32), 0 for float files.
        color_space: OpenImageIO's ``oiio:ColorSpace`` metadata ("" when absent), e.g. ``srgb_rec709_scene``.
        gamma: OpenImageIO's ``oiio:Gamma`` metadata (0 when absent).
        alpha_channel: index of the alpha channel among ``pixels``' channels (OpenImageIO's ``alpha_channel``), −1
            when there is none or it was not read. OpenImageIO returns colour associated with alpha (premultiplied).
    """

    pixels: np.ndarray
    is_8bit: bool
    texture_format: str = ""
    integer_bits: int = 0
    color_space: str = ""
    gamma: float = 0.0
    alpha_channel: int = -1


#: Alpha at or above this counts as opaque (an 8-bit 254/255 = 0.996 does not).
ALPHA_OPAQUE = 0.999

_INTEGER_BITS = {oiio.UINT8: 8, oiio.INT8: 8, oiio.UINT16: 16, oiio.INT16: 16, oiio.UINT32: 32, oiio.INT32: 32}


def _is_8bit(spec: oiio.ImageSpec) -> bool:
    return spec.format.basetype in (oiio.UINT8, oiio.INT8)


def _integer_bits(spec: oiio.ImageSpec) -> int:
    return _INTEGER_BITS.get(spec.format.basetype, 0)


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
        count = min(spec.nchannels, channels)
        pixels = image_input.read_image(0, 0, 0, count, oiio.FLOAT)
        if pixels is None:
            raise ImageError(f"{path}: reading pixels failed (truncated or corrupt file?): {image_input.geterror()}")
        gamma = spec.getattribute("oiio:Gamma")
        return ImagePixels(
            pixels=np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, -1),
            is_8bit=_is_8bit(spec),
            texture_format=str(spec.getattribute("textureformat") or ""),
            integer_bits=_integer_bits(spec),
            color_space=str(spec.getattribute("oiio:ColorSpace") or ""),
            gamma=float(gamma) if isinstance(gamma, (int, float)) else 0.0,
            alpha_channel=spec.alpha_channel if 0 <= spec.alpha_channel < count else -1,
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


def environment_transfer(image: ImagePixels) -> tuple[str, float, str]:
    """How :func:`read_environment` decodes ``image`` (module docstring): (transfer, gamma, why).

    transfer is ``linear`` (float files; integer files tagged linear, or deeper than 8 bits and untagged), ``srgb``
    (tagged sRGB, or 8-bit and untagged) or ``gamma`` (tagged ``g22_rec709`` or with an ``oiio:Gamma``); why is
    "" when the bit depth's convention decided for an 8-bit file, else the metadata (or its absence) in words.
    """
    if image.integer_bits == 0:
        return "linear", 0.0, ""
    by_depth = "srgb" if image.integer_bits == 8 else "linear"
    tagged = transfer_of(image.color_space, image.gamma)
    if tagged is not None:
        transfer, gamma = tagged
        why = "" if transfer == by_depth == "srgb" else f" (file colour space {image.color_space!r})"
        return transfer, gamma, why
    if image.color_space:
        return by_depth, 0.0, f" (file colour space {image.color_space!r} not interpreted: by bit depth)"
    return by_depth, 0.0, "" if by_depth == "srgb" else " (no colour-space metadata)"


def read_environment(
    path: str | os.PathLike[str], layout: str | None = None, *, decode: str = "auto"
) -> tuple[EnvironmentImage, SanitizeReport]:
    """Read an environment image as linear RGB radiance, sanitised (see :mod:`bakery.environment.sanitize`).

    Args:
        path: the image file.
        layout: one of :data:`~bakery.environment.layouts.LAYOUTS`, or None to detect it.
        decode: ``auto`` decodes integer files to linear radiance by their transfer function (module docstring)
            and emits a one-line :class:`~bakery.errors.BakeryWarning` saying how; ``raw`` returns integer files
            normalised to [0, 1] undecoded, for a caller that applies its own colour management.

    Raises:
        ImageError: the file is missing, unreadable, truncated, absurdly large, of an unknown layout, or of a size
            its layout cannot have (:func:`bakery.environment.layouts.layout_size_problem`: a disc map that is not
            square or smaller than :data:`~bakery.environment.layouts.MIN_DISC_SIZE` a side, …).
    """
    path = Path(path)
    if not path.is_file():
        raise ImageError(missing_image_message(path))
    if layout is not None and layout not in LAYOUTS:
        raise ImageError(f"{path}: unknown layout {layout!r}; expected one of {LAYOUTS}")
    if decode not in ("auto", "raw"):
        raise ArgumentError(f"decode must be 'auto' or 'raw', got {decode!r}")
    image = read_image(path, channels=4)
    pixels, alpha = image.pixels[..., :3], None
    if image.alpha_channel > 0:  # RGBA → RGB, YA → Y; the colour is premultiplied (OpenImageIO associates alpha)
        pixels, alpha = image.pixels[..., :image.alpha_channel], image.pixels[..., image.alpha_channel]
    height, width = pixels.shape[:2]
    try:
        chosen = layout or detect_layout(width, height, image.texture_format)
    except ImageError as error:
        raise ImageError(f"{path}: {error}") from None
    problem = layout_size_problem(chosen, height, width)
    if problem:
        raise ImageError(f"{path}: {problem}")
    if pixels.shape[2] == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    elif pixels.shape[2] == 2:
        raise ImageError(f"{path}: two-channel images are not radiance; expected RGB or luminance")
    transparent = 0 if alpha is None else int(np.count_nonzero(alpha < ALPHA_OPAQUE))
    if transparent:
        warnings.warn(f"{path}: {transparent:,} of {alpha.size:,} texels are not opaque (alpha < 1); an environment "
                      f"has nothing behind it, so alpha is ignored and the colour used as stored (associated alpha: "
                      f"as if over black)", BakeryWarning, stacklevel=2)
    if decode == "auto" and image.integer_bits:
        transfer, gamma, why = environment_transfer(image)
        pixels = decode_to_linear(pixels, transfer, gamma)
        how = {"srgb": "decoded as sRGB to", "gamma": f"decoded as gamma {gamma:g} to", "linear": "read as"}[transfer]
        warnings.warn(f"{path}: {image.integer_bits}-bit image {how} linear radiance{why}", BakeryWarning,
                      stacklevel=2)
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
