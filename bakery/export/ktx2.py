"""KTX 2.0 container: a small writer and a strict reader, and the ``ktx2`` export format (cube maps, cube arrays).

No maintained Python KTX2 writer exists (``pyktx`` is source-only and needs a system libktx that Debian 12 lacks), so
this module implements the parts of the Khronos KTX 2.0 specification [KTX2] that bakery writes: uncompressed
images (``supercompressionScheme`` 0), 2-D, cube, cube-array and 3-D textures, a full or partial mip chain, one basic
data format descriptor (DFD) and key/value data (KVD).

File layout written ([KTX2] §3, "File Structure"; all integers little-endian)
    identifier        12 bytes «KTX 20»\\r\\n\\x1A\\n                                              [KTX2] §3.1
    header            vkFormat, typeSize, pixelWidth, pixelHeight, pixelDepth, layerCount, faceCount, levelCount,
                      supercompressionScheme (9 × uint32)                                      [KTX2] §3.2-3.10
    index             dfdByteOffset, dfdByteLength, kvdByteOffset, kvdByteLength (uint32), sgdByteOffset,
                      sgdByteLength (uint64; 0: no supercompression global data)              [KTX2] §3.11
    level index       levelCount × (byteOffset, byteLength, uncompressedByteLength) uint64, level 0 (the largest)
                      first                                                                   [KTX2] §3.12
    DFD               dfdTotalSize uint32 + one basic descriptor block ([KDFS] §5; see :func:`basic_dfd`)
    KVD               entries sorted by key (byte order), each keyAndValueByteLength uint32, key NUL value,
                      padded with zeros to a multiple of 4                                     [KTX2] §3.15
    mip level data    **smallest level first**; each level starts at a multiple of lcm(texel block size, 4)
                      (mipPadding zeros before it); within a level: layers, then faces, then z slices, then rows
                      top-down (KTXorientation ``rd``), texels left to right                  [KTX2] §3.16

Cube maps: ``faceCount`` 6, faces +X, −X, +Y, −Y, +Z, −Z, rows top-down (``KTXorientation`` ``rd``, the only value
[KTX2] §3.9 allows for cube maps), each face in the orientation of the Vulkan/OpenGL face selection table applied to
the bake frame's direction as it is (``bakery.conventions``; what Filament and bakery's shaders sample). [KTX2]
("Cubemap orientation") calls the cube's coordinate system left-handed (+Y up, +Z forward, +X right) and has a
right-handed application negate x or z before sampling: such a consumer (three.js negates x) sees these cubes
mirrored — the ``three`` export writes its cubes mirrored in x for that reason (:mod:`bakery.export.three`). A cube
array has ``layerCount`` = the number of cubes (> 0); a plain texture has ``layerCount`` 0. ``pixelDepth`` 0 for
2-D/cube, > 0 for 3-D.

Formats written (``vkFormat`` values of the Vulkan specification, DFDs per [KDFS] and libktx's ``vk2dfd``)
    R16G16B16A16_SFLOAT      97   typeSize 2, alpha = 1; saturated at ±65504 (the largest finite float16, never inf)
    R32G32B32A32_SFLOAT     109   typeSize 4
    B10G11R11_UFLOAT_PACK32 122   typeSize 4: R bits 0–10, G 11–21 (6-bit mantissa, 5-bit exponent), B 22–31 (5/5);
                                  unsigned, rounded to nearest, clamped to the largest finite value 65024
    E5B9G9R9_UFLOAT_PACK32  123   typeSize 4: shared exponent (bias 15) in bits 27–31, 9-bit mantissas R 0–8,
                                  G 9–17, B 18–26 (Vulkan §"Shared exponent", round to nearest)

References
    [KTX2] Khronos, "KTX File Format Specification, version 2.0" (https://registry.khronos.org/KTX/specs/2.0/).
    [KDFS] Khronos, "Data Format Specification", version 1.3, §5 (basic descriptor block), §10 (float formats),
           §3.4 of the Vulkan mapping.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

IDENTIFIER = b"\xabKTX 20\xbb\r\n\x1a\n"

VK_FORMAT_R16G16B16A16_SFLOAT = 97
VK_FORMAT_R32G32B32A32_SFLOAT = 109
VK_FORMAT_B10G11R11_UFLOAT_PACK32 = 122
VK_FORMAT_E5B9G9R9_UFLOAT_PACK32 = 123

#: name → (vkFormat, typeSize, bytes per texel)
VK_FORMATS: dict[str, tuple[int, int, int]] = {
    "R16G16B16A16_SFLOAT": (VK_FORMAT_R16G16B16A16_SFLOAT, 2, 8),
    "R32G32B32A32_SFLOAT": (VK_FORMAT_R32G32B32A32_SFLOAT, 4, 16),
    "B10G11R11_UFLOAT_PACK32": (VK_FORMAT_B10G11R11_UFLOAT_PACK32, 4, 4),
    "E5B9G9R9_UFLOAT_PACK32": (VK_FORMAT_E5B9G9R9_UFLOAT_PACK32, 4, 4),
}
FORMAT_NAMES = {code: name for name, (code, _, _) in VK_FORMATS.items()}

# [KDFS] constants
_MODEL_RGBSDA, _PRIMARIES_BT709, _TRANSFER_LINEAR = 1, 1, 1
_FLOAT, _SIGNED, _EXPONENT = 0x80, 0x40, 0x20
_ALPHA = 15
_ONE_F, _MINUS_ONE_F = 0x3F800000, 0xBF800000

#: Largest finite value of the unsigned 11-bit float (5-bit exponent, 6-bit mantissa): (2 − 2⁻⁶)·2¹⁵.
UFLOAT11_MAX = 65024.0
#: Largest value of E5B9G9R9: (511/512)·2¹⁶.
E5B9G9R9_MAX = 65408.0
#: Largest finite float16 (binary16): (2 − 2⁻¹⁰)·2¹⁵. Casting anything from 65520 up gives +inf (round to nearest).
FLOAT16_MAX = 65504.0


class Ktx2Error(ValueError):
    """A KTX2 file that violates the specification (reader) or parameters that cannot be written (writer)."""


# ------------------------------------------------------------------------------------------------ pixel packing
def _pack_ufloat(values: np.ndarray, mantissa_bits: int) -> np.ndarray:
    """Unsigned small floats (5-bit exponent, bias 15, ``mantissa_bits``; no sign, no infinities written) from
    float32, rounded to nearest even via float16 → uint codes."""
    v = np.clip(np.nan_to_num(np.asarray(values, np.float32), nan=0.0), 0.0, None)
    half = np.minimum(v, 65504.0).astype(np.float16)  # round to nearest even at 10 mantissa bits
    bits = half.view(np.uint16).astype(np.uint32) & 0x7FFF
    shift = 10 - mantissa_bits
    rounded = (bits + (1 << (shift - 1)) - 1 + ((bits >> shift) & 1)) >> shift  # round half to even
    top = (0x1E << mantissa_bits) | ((1 << mantissa_bits) - 1)  # largest finite: exponent 30, mantissa all ones
    return np.minimum(rounded, top)


def _unpack_ufloat(codes: np.ndarray, mantissa_bits: int) -> np.ndarray:
    half_bits = (np.asarray(codes, np.uint32) << (10 - mantissa_bits)).astype(np.uint16)
    return half_bits.view(np.float16).astype(np.float32)


def pack_b10g11r11(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) float → (...,) uint32 B10G11R11_UFLOAT_PACK32."""
    r = _pack_ufloat(rgb[..., 0], 6)
    g = _pack_ufloat(rgb[..., 1], 6)
    b = _pack_ufloat(rgb[..., 2], 5)
    return (r | (g << 11) | (b << 22)).astype(np.uint32)


def unpack_b10g11r11(packed: np.ndarray) -> np.ndarray:
    p = np.asarray(packed, np.uint32)
    return np.stack([_unpack_ufloat(p & 0x7FF, 6), _unpack_ufloat((p >> 11) & 0x7FF, 6),
                     _unpack_ufloat((p >> 22) & 0x3FF, 5)], axis=-1)


def pack_e5b9g9r9(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) float → (...,) uint32 E5B9G9R9_UFLOAT_PACK32 (Vulkan specification, "Shared Exponent" encoding)."""
    n, bias = 9, 15
    c = np.clip(np.nan_to_num(np.asarray(rgb, np.float64), nan=0.0), 0.0, E5B9G9R9_MAX)
    cmax = c.max(axis=-1)
    with np.errstate(divide="ignore"):
        exp_p = np.maximum(-bias - 1, np.floor(np.log2(np.maximum(cmax, 1e-300)))) + 1 + bias
    exp_p = exp_p.astype(np.int64)
    m_max = np.floor(cmax / np.exp2(exp_p - bias - n) + 0.5)
    exp_s = np.where(m_max == (1 << n), exp_p + 1, exp_p)
    mant = np.floor(c / np.exp2(exp_s - bias - n)[..., None] + 0.5).astype(np.uint32)
    mant = np.minimum(mant, (1 << n) - 1)
    return (mant[..., 0] | (mant[..., 1] << 9) | (mant[..., 2] << 18)
            | (exp_s.astype(np.uint32) << 27)).astype(np.uint32)


def unpack_e5b9g9r9(packed: np.ndarray) -> np.ndarray:
    p = np.asarray(packed, np.uint32)
    scale = np.exp2(((p >> 27) & 0x1F).astype(np.float64) - 15 - 9)
    return (np.stack([p & 0x1FF, (p >> 9) & 0x1FF, (p >> 18) & 0x1FF], axis=-1) * scale[..., None]).astype(np.float32)


def to_float16(values: np.ndarray) -> np.ndarray:
    """float16 of ``values`` saturated to ±:data:`FLOAT16_MAX` (never ±inf; NaN → 0), as the packed formats clamp to
    their largest finite value. A re-prefiltered level of a capture at the float16 ceiling (a bake clamps radiance to
    65504) can exceed it by rounding or ringing, and a plain cast would write +inf texels that poison every filtered
    fetch and mip blend around them."""
    v = np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0, posinf=FLOAT16_MAX, neginf=-FLOAT16_MAX)
    return np.clip(v, -FLOAT16_MAX, FLOAT16_MAX).astype("<f2")


def encode_texels(rgb: np.ndarray, vk_format: int) -> bytes:
    """Texel bytes of (..., 3) or (..., 4) float data in ``vk_format`` (alpha = 1 where the format has alpha and the
    input has none; ``R16G16B16A16_SFLOAT`` saturates at ±65504, :func:`to_float16`)."""
    rgb = np.asarray(rgb, dtype=np.float32)
    if vk_format in (VK_FORMAT_R16G16B16A16_SFLOAT, VK_FORMAT_R32G32B32A32_SFLOAT):
        if rgb.shape[-1] == 3:
            rgb = np.concatenate([rgb, np.ones_like(rgb[..., :1])], axis=-1)
        if vk_format == VK_FORMAT_R16G16B16A16_SFLOAT:
            return np.ascontiguousarray(to_float16(rgb)).tobytes()
        return np.ascontiguousarray(rgb, dtype="<f4").tobytes()
    if vk_format == VK_FORMAT_B10G11R11_UFLOAT_PACK32:
        return pack_b10g11r11(rgb[..., :3]).astype("<u4").tobytes()
    if vk_format == VK_FORMAT_E5B9G9R9_UFLOAT_PACK32:
        return pack_e5b9g9r9(rgb[..., :3]).astype("<u4").tobytes()
    raise Ktx2Error(f"vkFormat {vk_format} is not written by bakery; formats: {', '.join(VK_FORMATS)}")


def decode_texels(data: bytes, vk_format: int, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`encode_texels`: (*shape, 4) float32 for RGBA formats, (*shape, 3) for packed RGB."""
    if vk_format == VK_FORMAT_R16G16B16A16_SFLOAT:
        return np.frombuffer(data, "<f2").astype(np.float32).reshape(*shape, 4)
    if vk_format == VK_FORMAT_R32G32B32A32_SFLOAT:
        return np.frombuffer(data, "<f4").astype(np.float32).reshape(*shape, 4)
    if vk_format == VK_FORMAT_B10G11R11_UFLOAT_PACK32:
        return unpack_b10g11r11(np.frombuffer(data, "<u4").reshape(shape))
    if vk_format == VK_FORMAT_E5B9G9R9_UFLOAT_PACK32:
        return unpack_e5b9g9r9(np.frombuffer(data, "<u4").reshape(shape))
    raise Ktx2Error(f"vkFormat {vk_format} is not read by bakery; formats: {', '.join(VK_FORMATS)}")


# ------------------------------------------------------------------------------------------------ DFD
@dataclass(frozen=True)
class DfdSample:
    bit_offset: int
    bit_length: int  # actual bit count (stored as count − 1)
    channel_type: int  # channel id | qualifier flags
    lower: int
    upper: int


def _samples(vk_format: int) -> tuple[int, list[DfdSample]]:
    """(bytesPlane0, samples) of the basic descriptor block for ``vk_format`` ([KDFS] §5.6, libktx vk2dfd)."""
    if vk_format in (VK_FORMAT_R16G16B16A16_SFLOAT, VK_FORMAT_R32G32B32A32_SFLOAT):
        bits = 16 if vk_format == VK_FORMAT_R16G16B16A16_SFLOAT else 32
        channels = (0, 1, 2, _ALPHA)
        return bits // 2, [DfdSample(i * bits, bits, ch | _FLOAT | _SIGNED, _MINUS_ONE_F, _ONE_F)
                           for i, ch in enumerate(channels)]
    if vk_format == VK_FORMAT_B10G11R11_UFLOAT_PACK32:
        return 4, [DfdSample(0, 11, 0 | _FLOAT, 0, _ONE_F), DfdSample(11, 11, 1 | _FLOAT, 0, _ONE_F),
                   DfdSample(22, 10, 2 | _FLOAT, 0, _ONE_F)]
    if vk_format == VK_FORMAT_E5B9G9R9_UFLOAT_PACK32:
        # [KDFS] §5.18 shared-exponent formats: per channel a 9-bit mantissa sample (upper 8448 = 1.0 · 2⁸ + 2⁸·32,
        # as libktx writes it) and a 5-bit exponent sample (lower = bias 15, upper 31) at bit 27.
        out = []
        for ch in range(3):
            out.append(DfdSample(9 * ch, 9, ch, 0, 8448))
            out.append(DfdSample(27, 5, ch | _EXPONENT, 15, 31))
        return 4, out
    raise Ktx2Error(f"no DFD for vkFormat {vk_format}")


def basic_dfd(vk_format: int) -> bytes:
    """dfdTotalSize + one basic descriptor block: vendor Khronos (0), type 0, version 2 (KDFS 1.3), colour model
    RGBSDA, primaries BT.709, transfer linear, straight alpha, 1×1×1×1 texel block ([KDFS] §5)."""
    bytes_plane0, samples = _samples(vk_format)
    block_size = 24 + 16 * len(samples)
    out = bytearray(struct.pack("<I", 4 + block_size))
    out += struct.pack("<HHHH", 0, 0, 2, block_size)
    out += struct.pack("<BBBB", _MODEL_RGBSDA, _PRIMARIES_BT709, _TRANSFER_LINEAR, 0)
    out += bytes(4)  # texelBlockDimension0..3 (dimension − 1)
    out += bytes([bytes_plane0, 0, 0, 0, 0, 0, 0, 0])
    for s in samples:
        out += struct.pack("<HBB", s.bit_offset, s.bit_length - 1, s.channel_type)
        out += bytes(4)  # samplePosition0..3
        out += struct.pack("<II", s.lower & 0xFFFFFFFF, s.upper & 0xFFFFFFFF)
    return bytes(out)


# ------------------------------------------------------------------------------------------------ container
@dataclass
class Ktx2Texture:
    """An uncompressed KTX2 texture. ``levels[i]`` is the level's bytes (all layers, faces and slices)."""

    vk_format: int
    width: int
    height: int
    depth: int = 0
    layers: int = 0
    faces: int = 1
    levels: list[bytes] = field(default_factory=list)
    key_values: dict[str, bytes] = field(default_factory=dict)
    level_count_field: int | None = None  # levelCount as stored (0 = "generate mips"); None: len(levels)

    @property
    def type_size(self) -> int:
        return {VK_FORMAT_R16G16B16A16_SFLOAT: 2}.get(self.vk_format, 4)

    def level_extent(self, level: int) -> tuple[int, int, int]:
        """(width, height, depth) of mip ``level``: max(1, size >> level) ([KTX2] §4.1)."""
        return (max(1, self.width >> level), max(1, self.height >> level),
                max(1, self.depth >> level) if self.depth else 0)

    def expected_level_bytes(self, level: int) -> int:
        w, h, d = self.level_extent(level)
        texel = VK_FORMATS[FORMAT_NAMES[self.vk_format]][2]
        return w * h * max(d, 1) * max(self.layers, 1) * self.faces * texel


def _kvd(key_values: dict[str, bytes]) -> bytes:
    out = bytearray()
    for key in sorted(key_values, key=lambda k: k.encode()):
        value = key_values[key]
        entry = key.encode() + b"\x00" + value
        out += struct.pack("<I", len(entry)) + entry + bytes(-len(entry) % 4)
    return bytes(out)


def text_value(value: str) -> bytes:
    """A KVD string value: UTF-8 with its terminating NUL ([KTX2] §3.15: values of the KTX* keys are NUL-terminated
    UTF-8 strings)."""
    return value.encode() + b"\x00"


def write_ktx2(texture: Ktx2Texture) -> bytes:
    """Serialise ``texture`` ([KTX2] §3). Validates sizes and the header rules of [KTX2] §3.4-3.9."""
    t = texture
    if t.vk_format not in FORMAT_NAMES:
        raise Ktx2Error(f"vkFormat {t.vk_format} is not written by bakery")
    if t.width < 1 or t.height < 1 or t.depth < 0 or t.layers < 0:
        raise Ktx2Error(f"bad extent {t.width}x{t.height}x{t.depth}, {t.layers} layers")
    if t.faces not in (1, 6):
        raise Ktx2Error(f"faceCount must be 1 or 6, got {t.faces}")
    if t.faces == 6 and (t.width != t.height or t.depth):
        raise Ktx2Error("cube map faces must be square and 2-D ([KTX2] §3.9)")
    max_levels = int(math.floor(math.log2(max(t.width, t.height, t.depth or 1)))) + 1
    if not 1 <= len(t.levels) <= max_levels:
        raise Ktx2Error(f"{len(t.levels)} levels; a {t.width}x{t.height} texture has 1..{max_levels}")
    for i, data in enumerate(t.levels):
        if len(data) != t.expected_level_bytes(i):
            raise Ktx2Error(f"level {i} has {len(data)} bytes, expected {t.expected_level_bytes(i)}")
    count = len(t.levels)
    dfd = basic_dfd(t.vk_format)
    kvd = _kvd(t.key_values)
    dfd_offset = len(IDENTIFIER) + 68 + 24 * count
    kvd_offset = dfd_offset + len(dfd)
    texel = VK_FORMATS[FORMAT_NAMES[t.vk_format]][2]
    align = texel * 4 // math.gcd(texel, 4)
    offsets = [0] * count
    body = bytearray()
    cursor = kvd_offset + len(kvd)
    for i in range(count - 1, -1, -1):  # smallest level first ([KTX2] §3.16)
        pad = -cursor % align
        body += bytes(pad)
        cursor += pad
        offsets[i] = cursor
        body += t.levels[i]
        cursor += len(t.levels[i])
    level_count = count if t.level_count_field is None else t.level_count_field
    header = struct.pack("<9I", t.vk_format, t.type_size, t.width, t.height, t.depth, t.layers, t.faces,
                         level_count, 0)
    index = struct.pack("<IIIIQQ", dfd_offset, len(dfd), kvd_offset if kvd else 0, len(kvd), 0, 0)
    level_index = b"".join(struct.pack("<QQQ", offsets[i], len(t.levels[i]), len(t.levels[i])) for i in range(count))
    return IDENTIFIER + header + index + level_index + dfd + kvd + bytes(body)


def read_ktx2(data: bytes) -> Ktx2Texture:
    """Parse and validate a KTX2 file written in the subset above; raises :class:`Ktx2Error` naming the rule broken
    (truncated file, offsets outside the file, level sizes inconsistent with the header, unsorted keys …)."""
    data = bytes(data)
    if len(data) < 80 or data[:12] != IDENTIFIER:
        raise Ktx2Error("not a KTX 2.0 file (identifier)")
    (vk_format, type_size, width, height, depth, layers, faces, level_count, scheme) = struct.unpack_from("<9I", data, 12)
    dfd_offset, dfd_length, kvd_offset, kvd_length, sgd_offset, sgd_length = struct.unpack_from("<IIIIQQ", data, 48)
    if scheme != 0:
        raise Ktx2Error(f"supercompressionScheme {scheme} is not read by bakery")
    if vk_format not in FORMAT_NAMES:
        raise Ktx2Error(f"vkFormat {vk_format} is not read by bakery")
    count = max(level_count, 1)
    if len(data) < 80 + 24 * count:
        raise Ktx2Error("truncated level index")
    texture = Ktx2Texture(vk_format, width, height, depth, layers, faces, level_count_field=level_count)
    if type_size != texture.type_size:
        raise Ktx2Error(f"typeSize {type_size} does not match vkFormat {FORMAT_NAMES[vk_format]}")
    if faces == 6 and width != height:
        raise Ktx2Error("cube map with non-square faces")
    for name, offset, length in (("DFD", dfd_offset, dfd_length), ("KVD", kvd_offset, kvd_length),
                                 ("SGD", sgd_offset, sgd_length)):
        if length and offset + length > len(data):
            raise Ktx2Error(f"{name} extends past the end of the file (truncated?)")
    if dfd_length < 4 or struct.unpack_from("<I", data, dfd_offset)[0] != dfd_length:
        raise Ktx2Error("dfdTotalSize does not match dfdByteLength")
    if data[dfd_offset:dfd_offset + dfd_length] != basic_dfd(vk_format):
        raise Ktx2Error(f"DFD is not the basic descriptor of {FORMAT_NAMES[vk_format]}")
    pos, end, keys = kvd_offset, kvd_offset + kvd_length, []
    while pos < end:
        (length,) = struct.unpack_from("<I", data, pos)
        entry = data[pos + 4:pos + 4 + length]
        if len(entry) != length or b"\x00" not in entry:
            raise Ktx2Error("malformed key/value entry")
        key, value = entry.split(b"\x00", 1)
        keys.append(key)
        texture.key_values[key.decode()] = value
        pos += 4 + length + (-length % 4)
    if keys != sorted(keys):
        raise Ktx2Error("key/value entries are not sorted by key ([KTX2] §3.15)")
    for i in range(count):
        offset, length, uncompressed = struct.unpack_from("<QQQ", data, 80 + 24 * i)
        if length != uncompressed or length != texture.expected_level_bytes(i):
            raise Ktx2Error(f"level {i}: {length} bytes, the header implies {texture.expected_level_bytes(i)}")
        if offset + length > len(data):
            raise Ktx2Error(f"level {i} extends past the end of the file (truncated?)")
        texture.levels.append(data[offset:offset + length])
    return texture


def level_array(texture: Ktx2Texture, level: int) -> np.ndarray:
    """Level ``level`` as float32 (layers?, faces?, depth?, height, width, channels), leading unit axes dropped for
    absent dimensions (cube → (6, N, N, C), cube array → (L, 6, N, N, C), 3-D → (D, H, W, C))."""
    w, h, d = texture.level_extent(level)
    shape = [n for n, present in ((texture.layers, texture.layers > 0), (texture.faces, texture.faces > 1),
                                  (d, d > 0)) if present] + [h, w]
    return decode_texels(texture.levels[level], texture.vk_format, tuple(shape))


# ------------------------------------------------------------------------------------------------ export format
from typing import Literal  # noqa: E402

from bakery.encodings.base import EncodingParams  # noqa: E402
from bakery.export.base import ExportContext, ExportedFile, ExportFormat, register_format, slug  # noqa: E402


def bakery_key_values(context: ExportContext, record: dict, probes: list[str], orientation: str = "rd") -> dict:
    """The KVD of an exported texture: ``KTXorientation``, ``KTXwriter`` and bakery's profile, conventions and probe
    names (user keys, NUL-terminated UTF-8 JSON)."""
    import json

    from bakery import __version__

    provenance = context.provenance()
    validity = context.validity(probes)
    return ({"bakery:validity": text_value(json.dumps(validity, sort_keys=True))} if validity else {}) | {
        "KTXorientation": text_value(orientation),
        "KTXwriter": text_value(f"bakery {__version__}"),
        "bakery:conventions": text_value(json.dumps(provenance["conventions"], sort_keys=True)),
        "bakery:probes": text_value(json.dumps(probes)),
        "bakery:profile": text_value(json.dumps(record, sort_keys=True)),
        "bakery:store": text_value(json.dumps({"store": provenance["store"],
                                                "settings_hash": provenance["settings_hash"],
                                                "radiance_units": "as baked (scene-linear)"}, sort_keys=True)),
    }


def cube_texture(chains: list[list[np.ndarray]], vk_format: int, key_values: dict,
                 array: bool | None = None) -> Ktx2Texture:
    """A cube map or a cube array from chains of (6, N_i, N_i, 3) levels. ``array``: a cube array (``layerCount`` =
    len(chains), also for one chain: an engine that binds the file as a cube array needs ``layerCount`` ≥ 1, [KTX2]
    §4.3) or a single cube (``layerCount`` 0, one chain); None: an array exactly when there are several chains."""
    array = len(chains) > 1 if array is None else bool(array)
    if not array and len(chains) != 1:
        raise Ktx2Error(f"a cube map holds one chain, got {len(chains)}: write a cube array")
    levels = []
    for i in range(len(chains[0])):
        stacked = np.stack([chain[i] for chain in chains]) if array else chains[0][i]
        levels.append(encode_texels(stacked, vk_format))
    n = chains[0][0].shape[1]
    return Ktx2Texture(vk_format, n, n, 0, len(chains) if array else 0, 6, levels, key_values)


@register_format
class Ktx2Export(ExportFormat):
    """KTX 2.0 cube maps of the reflection probes, re-prefiltered at the profile's α per mip level."""

    name = "ktx2"
    description = "KTX 2.0 cube map per reflection probe (or one cube array), full or partial mip chain"
    default_profile = "gltf"

    @dataclass(frozen=True)
    class Params(EncodingParams):
        vk_format: Literal["R16G16B16A16_SFLOAT", "R32G32B32A32_SFLOAT", "B10G11R11_UFLOAT_PACK32",
                           "E5B9G9R9_UFLOAT_PACK32"] = \
            "R16G16B16A16_SFLOAT"
        levels: int | None = None  # None: full chain down to 1×1
        face_size: int | None = None  # None: the kept capture's
        layout: Literal["cube", "array"] = "cube"

        def validate(self) -> None:
            if self.levels is not None and self.levels < 1:
                raise ValueError(f"levels must be >= 1 (or unset: full chain), got {self.levels}")
            if self.face_size is not None and self.face_size < 1:
                raise ValueError(f"face_size must be >= 1, got {self.face_size}")

    def build(self, context: ExportContext) -> Iterator[ExportedFile]:
        """One file per probe, streamed (``layout = "cube"``), or one cube array holding every chain at once."""
        from bakery.export.source import profile_chains

        p = context.params
        chains = profile_chains(context.store, context.probes, context.profile, p.levels, p.face_size)
        vk = VK_FORMATS[p.vk_format][0]
        if p.layout == "array":
            texture = cube_texture([chain for _, chain, _ in chains], vk,
                                   bakery_key_values(context, chains.record, chains.probes), array=True)
            yield ExportedFile("reflection_probes.ktx2", write_ktx2(texture), tuple(chains.probes), "")
            return
        for name, chain, _ in chains:
            texture = cube_texture([chain], vk, bakery_key_values(context, chains.record, [name]))
            yield ExportedFile(f"{slug(name)}.ktx2", write_ktx2(texture), (name,), "")
