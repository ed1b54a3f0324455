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
import re
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from bakery.environment.colour import (
    LINEAR_GAMUTS,
    chromaticities_problem,
    decode_to_linear,
    to_rec709_matrix,
    transfer_of,
)
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
        channel_names: the names of ``pixels``' channels in the file (e.g. ``R``, ``G``, ``B``, ``diffuse.R``).
        subimages: the names of the file's subimages (OpenEXR parts; "" when unnamed) when it has more than one; the
            first is the one read.
        chromaticities: the file's primaries and white (OpenEXR ``chromaticities``, a Radiance ``PRIMARIES`` line)
            as (xr, yr, xg, yg, xb, yb, xw, yw), or None when it does not say.
        window_note: with ``display_window``, how the data window differed from the display window ("" when not).
        exposure: a Radiance file's ``EXPOSURE`` (the product of its lines; 1 when absent): the factor its pixels
            were multiplied by after they were radiance. Not applied.
    """

    pixels: np.ndarray
    is_8bit: bool
    texture_format: str = ""
    integer_bits: int = 0
    color_space: str = ""
    gamma: float = 0.0
    alpha_channel: int = -1
    channel_names: tuple[str, ...] = ()
    subimages: tuple[str, ...] = ()
    chromaticities: tuple[float, ...] | None = None
    window_note: str = ""
    exposure: float = 1.0


#: Alpha at or above this counts as opaque (an 8-bit 254/255 = 0.996 does not).
ALPHA_OPAQUE = 0.999

_INTEGER_BITS = {oiio.UINT8: 8, oiio.INT8: 8, oiio.UINT16: 16, oiio.INT16: 16, oiio.UINT32: 32, oiio.INT32: 32}


def _is_8bit(spec: oiio.ImageSpec) -> bool:
    return spec.format.basetype in (oiio.UINT8, oiio.INT8)


def _integer_bits(spec: oiio.ImageSpec) -> int:
    return _INTEGER_BITS.get(spec.format.basetype, 0)


@contextmanager
def _opened(path: Path, unassociated_alpha: bool = False) -> Iterator[tuple[oiio.ImageInput, oiio.ImageSpec]]:
    """An open ImageInput and its spec, after the header checks (empty image, more than :data:`MAX_PIXELS`);
    ``unassociated_alpha``: colours of files that store straight alpha (PNG, TGA, some TIFF) as stored, not
    premultiplied (OpenImageIO's ``oiio:UnassociatedAlpha`` hint)."""
    config = oiio.ImageSpec()
    if unassociated_alpha:
        config.attribute("oiio:UnassociatedAlpha", 1)
    image_input = oiio.ImageInput.open(str(path), config)
    if image_input is None:
        reason = oiio.geterror() or "unknown format"
        header = radiance_header(path)
        if path.stat().st_size == 0:
            reason = "the file is empty (0 bytes)"
        elif header is not None and header.format and header.format != "32-bit_rle_rgbe":
            reason = (f"Radiance pixel format {header.format!r} is not supported (only 32-bit_rle_rgbe; convert XYZE "
                      f"pictures to RGBE, e.g. with Radiance's ra_xyze -r)")
        raise ImageError(f"{path}: OpenImageIO cannot open it: {reason}")
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


def read_image(path: str | os.PathLike[str], channels: int = 4, *, display_window: bool = False,
               orient: bool = False, unassociated_alpha: bool = False) -> ImagePixels:
    """Pixels of any image OpenImageIO reads, the first ``channels`` channels as float32 (see :class:`ImagePixels`).

    Args:
        display_window: return the display window (OpenEXR's frame; its ``full`` window in OpenImageIO) with the data
            window placed in it — texels outside the data window black, data outside the display window dropped —
            instead of the data window alone (which places a shifted or cropped data window wrongly). Files with
            environment-map metadata (OpenEXR ``envmap``, OpenImageIO's ``textureformat`` "… Environment") keep the
            data window: OpenEXR defines its latlong and cube maps on it (ImfEnvmap; a cube's display window is
            commonly one face).
        orient: turn the pixels as the file's orientation says (TIFF/EXIF ``Orientation``; a Radiance file's
            resolution line, e.g. ``+Y 512 +X 1024`` is stored bottom row first), so that row 0 is the top.
        unassociated_alpha: the colour of files that store straight alpha (PNG, TGA) as stored; by default
            OpenImageIO premultiplies it on reading.

    Raises:
        ImageError: the file is missing, unreadable, truncated or its header claims an empty or absurdly large image.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"{path}: image not found")
    with _opened(path, unassociated_alpha) as (image_input, spec):
        count = min(spec.nchannels, channels)
        header = radiance_header(path) if image_input.format_name() == "hdr" else None
        full = (spec.full_x, spec.full_y, spec.full_width, spec.full_height)
        window_note = ""
        environment_map = "environment" in str(spec.getattribute("textureformat") or "").lower()
        data = (spec.x, spec.y, spec.width, spec.height)
        if display_window and not environment_map and full[2] > 0 and full[3] > 0 and full != data:
            if full[2] * full[3] > MAX_PIXELS:
                raise ImageError(f"{path}: header claims a {full[2]}x{full[3]} display window, more than the "
                                 f"{MAX_PIXELS:,} pixels bakery accepts; the file is corrupt")
            window_note = (f"data window {spec.width}x{spec.height} at ({spec.x}, {spec.y}) in the {full[2]}x{full[3]} "
                           f"display window at ({full[0]}, {full[1]})")
        pixels = image_input.read_image(0, 0, 0, count, oiio.FLOAT)
        if pixels is None:
            raise ImageError(f"{path}: reading pixels failed (truncated or corrupt file?): {image_input.geterror()}")
        pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, -1)
        if window_note:
            pixels = _in_display_window(pixels, spec)
        if orient:
            orientation = header.orientation if header is not None else spec.get_int_attribute("Orientation", 1)
            pixels = oriented(pixels, orientation)
        gamma = spec.getattribute("oiio:Gamma")
        subimages = int(spec.get_int_attribute("oiio:subimages", 1))
        chromaticities = spec.getattribute("chromaticities")
        if header is not None and header.primaries is not None:
            chromaticities = header.primaries
        if chromaticities is not None and not any(float(v) for v in chromaticities):
            chromaticities = None  # all zero: "not specified" (Photoshop's PRIMARIES=0 0 0 0 0 0 0 0, Poly Haven's)
        names = tuple(spec.channelnames)[:count]
        return ImagePixels(
            pixels=pixels,
            is_8bit=_is_8bit(spec),
            texture_format=str(spec.getattribute("textureformat") or ""),
            integer_bits=_integer_bits(spec),
            color_space=str(spec.getattribute("oiio:ColorSpace") or ""),
            gamma=float(gamma) if isinstance(gamma, (int, float)) else 0.0,
            alpha_channel=spec.alpha_channel if 0 <= spec.alpha_channel < count else -1,
            channel_names=names,
            subimages=_subimage_names(image_input) if subimages > 1 else (),
            chromaticities=tuple(float(v) for v in chromaticities) if chromaticities is not None else None,
            window_note=window_note,
            exposure=header.exposure if header is not None else 1.0,
        )


def _in_display_window(pixels: np.ndarray, spec: oiio.ImageSpec) -> np.ndarray:
    """The data window ``pixels`` (h, w, C) at (spec.x, spec.y) placed in the display window, black elsewhere."""
    fx, fy, fw, fh = spec.full_x, spec.full_y, spec.full_width, spec.full_height
    out = np.zeros((fh, fw, pixels.shape[2]), dtype=np.float32)
    x0, x1 = max(spec.x, fx), min(spec.x + spec.width, fx + fw)
    y0, y1 = max(spec.y, fy), min(spec.y + spec.height, fy + fh)
    if x0 < x1 and y0 < y1:
        out[y0 - fy:y1 - fy, x0 - fx:x1 - fx] = pixels[y0 - spec.y:y1 - spec.y, x0 - spec.x:x1 - spec.x]
    return out


def _subimage_names(image_input: oiio.ImageInput) -> tuple[str, ...]:
    names = []
    index = 0
    while image_input.seek_subimage(index, 0):
        names.append(str(image_input.spec().getattribute("name") or ""))
        index += 1
    image_input.seek_subimage(0, 0)
    return tuple(names)


def oriented(pixels: np.ndarray, orientation: int) -> np.ndarray:
    """``pixels`` (H, W, ...) as stored, turned upright by a TIFF/EXIF orientation code (1 = as stored; 2–4 mirrored
    or turned 180°; 5–8 transposed: the stored row 0 is the image's left (5, 8) or right (6, 7) column, the stored
    column 0 its top (5, 6) or bottom (7, 8)). Codes outside 1–8 read as 1."""
    if orientation in (5, 6, 7, 8):
        pixels = np.swapaxes(pixels, 0, 1)
    flip_rows = orientation in (3, 4, 7, 8)
    flip_cols = orientation in (2, 3, 6, 7)
    if flip_rows:
        pixels = pixels[::-1]
    if flip_cols:
        pixels = pixels[:, ::-1]
    return np.ascontiguousarray(pixels) if orientation in range(2, 9) else pixels


@dataclass(frozen=True)
class RadianceHeader:
    """What bakery reads from a Radiance picture's header itself (OpenImageIO gives no primaries, and the wrong
    orientation for two of the eight resolution lines).

    Attributes:
        format: the ``FORMAT=`` value ("" when absent), e.g. ``32-bit_rle_rgbe`` or ``32-bit_rle_xyze``.
        orientation: the resolution line as a TIFF/EXIF orientation code of the array of scanlines (1 = ``-Y +X``).
        exposure: the product of the ``EXPOSURE=`` lines (1 when there are none).
        primaries: the ``PRIMARIES=`` line's 8 numbers (red, green, blue, white xy), or None.
    """

    format: str
    orientation: int
    exposure: float
    primaries: tuple[float, ...] | None


#: Radiance resolution lines (scanline axis, pixel axis; resolu.h: origin at the lower left, +Y up) → the TIFF/EXIF
#: orientation of the array whose rows are the scanlines: "+X M +Y N" lists the columns left to right, each from the
#: bottom up, so the array's row 0 is the left column and its column 0 the bottom (code 8). (OpenImageIO's rgbe
#: reader swaps codes 6 and 8.)
_RADIANCE_ORIENTATIONS = {("-Y", "+X"): 1, ("-Y", "-X"): 2, ("+Y", "-X"): 3, ("+Y", "+X"): 4,
                          ("+X", "-Y"): 5, ("-X", "-Y"): 6, ("-X", "+Y"): 7, ("+X", "+Y"): 8}
_RADIANCE_RESOLUTION = re.compile(rb"^([-+][XY])\s+\d+\s+([-+][XY])\s+\d+\s*$")


def radiance_header(path: str | os.PathLike[str]) -> RadianceHeader | None:
    """The header of a Radiance picture (``#?`` magic), or None when ``path`` is not one or its header does not end
    in a resolution line within its first 64 KiB."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(1 << 16)
    except OSError:
        return None
    if not head.startswith(b"#?"):
        return None
    lines = head.split(b"\n")
    fmt, exposure, primaries = "", 1.0, None
    for index, line in enumerate(lines[1:-1], start=1):
        text = line.strip()
        if not text:  # the blank line ends the header; the resolution line follows
            match = _RADIANCE_RESOLUTION.match(lines[index + 1].strip())
            if not match:
                return None
            orientation = _RADIANCE_ORIENTATIONS.get((match[1].decode(), match[2].decode()))
            if orientation is None:
                return None
            return RadianceHeader(fmt, orientation, exposure, primaries)
        key, _, value = text.partition(b"=")
        try:
            if key == b"FORMAT":
                fmt = value.decode("ascii", "replace").strip()
            elif key == b"EXPOSURE":
                exposure *= float(value)
            elif key == b"PRIMARIES":
                numbers = tuple(float(v) for v in value.split())
                primaries = numbers if len(numbers) == 8 else primaries
        except ValueError:
            continue
    return None


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
    if path.exists():  # a pipe, socket or device: reading it could block or never end
        return f"{path}: not a regular file (a pipe, socket or device); give an image file"
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
    image = read_image(path, channels=4, display_window=True, orient=True)
    if image.alpha_channel == 0:
        raise ImageError(f"{path}: its first channel is alpha ({', '.join(image.channel_names)}); an environment "
                         f"image needs RGB or luminance channels")
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
    colour_channels = pixels.shape[2]
    if colour_channels == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    elif colour_channels == 2:
        raise ImageError(f"{path}: two-channel images are not radiance; expected RGB or luminance")
    _warn_about_what_was_read(path, image, colour_channels)
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
    if decode == "auto" and pixels.shape[2] == 3:
        pixels = _to_rec709(path, image, pixels)
    radiance, report = sanitize_radiance(pixels, source=str(path))
    return EnvironmentImage(pixels=radiance, layout=chosen, source=str(path)), report


def _warn_about_what_was_read(path: Path, image: ImagePixels, colour_channels: int) -> None:
    """One-line warnings when the file holds more than, or other than, the radiance that was read: several
    subimages (the first read), colour channels not named R, G, B (or Y), a Radiance EXPOSURE (not applied)."""
    if image.subimages:
        parts = ", ".join(repr(name) for name in image.subimages[:6]) + (" …" if len(image.subimages) > 6 else "")
        warnings.warn(f"{path}: {len(image.subimages)} subimages (parts: {parts}); only the first, "
                      f"{image.subimages[0]!r}, is read", BakeryWarning, stacklevel=3)
    used = image.channel_names[:colour_channels]
    bases = tuple(name.rsplit(".", 1)[-1].upper() for name in used)
    if used and (bases not in (("R", "G", "B"), ("Y",)) or any("." in name for name in used)):
        warnings.warn(f"{path}: no R, G, B (or Y) channels of its own; read {', '.join(used)} as "
                      f"{'RGB' if colour_channels == 3 else 'luminance'} radiance", BakeryWarning, stacklevel=3)
    if image.exposure != 1.0:
        warnings.warn(f"{path}: Radiance EXPOSURE={image.exposure:g} not applied (pixels read as stored, as renderers "
                      f"read them; divide by it for the radiance before that exposure)", BakeryWarning, stacklevel=3)


def _to_rec709(path: Path, image: ImagePixels, pixels: np.ndarray) -> np.ndarray:
    """Linear RGB ``pixels`` of a file whose primaries are not Rec.709 (its chromaticities, else a linear colour-space
    name OpenImageIO reports, e.g. ``lin_ap1_scene`` for an OpenEXR ``colorInteropID`` of ACEScg) converted to linear
    Rec.709, with a one-line warning; other files as they are (float files are linear whatever their tag)."""
    name = image.color_space.strip().lower()
    if image.chromaticities is not None:
        problem = chromaticities_problem(image.chromaticities)
        if problem:
            warnings.warn(f"{path}: {problem}; read as linear Rec.709", BakeryWarning, stacklevel=3)
            return pixels
        chromaticities, what = image.chromaticities, "chromaticities " + " ".join(
            f"{v:g}" for v in image.chromaticities)
    elif name in LINEAR_GAMUTS:
        chromaticities, what = LINEAR_GAMUTS[name], f"colour space {image.color_space!r}"
    else:  # Rec.709, or a name of a transfer function (integer files: decoded before) or unknown: as stored
        return pixels
    matrix = to_rec709_matrix(chromaticities)
    if matrix is None:
        return pixels
    warnings.warn(f"{path}: {what} converted to linear Rec.709 (Bradford-adapted white)", BakeryWarning, stacklevel=3)
    return (pixels @ matrix.T.astype(np.float32)).astype(np.float32)


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
