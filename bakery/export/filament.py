"""Filament: a KTX1 cube per reflection probe with the ``sh`` key, as Filament's ``cmgen`` writes it.

KTX 1.1 layout written ([KTX1] §2; little-endian, ``endianness`` = 0x04030201)
    identifier «KTX 11»\\r\\n\\x1A\\n, then glType, glTypeSize, glFormat, glInternalFormat, glBaseInternalFormat,
    pixelWidth, pixelHeight, pixelDepth = 0, numberOfArrayElements = 0, numberOfFaces = 6, numberOfMipmapLevels,
    bytesOfKeyValueData (13 × uint32); key/value pairs (keyAndValueByteSize, key NUL value, padding to 4); then per
    mip level: imageSize (bytes of **one face**, cube maps, [KTX1] §2.16), the six faces +X −X +Y −Y +Z −Z (rows
    top-down, bakery's = OpenGL's cube orientation), each padded to 4 bytes (cubePadding).

Formats: ``R11F_G11F_B10F`` (glInternalFormat GL_R11F_G11F_B10F 0x8C3A, glFormat GL_RGB; cmgen's IBL format, what
``Engine.createIblFromKtx1`` expects; clamped to 65024) or ``RGBA16F`` (GL_RGBA16F 0x881A, GL_HALF_FLOAT, GL_RGBA;
saturated at 65504, never inf). The R11F_G11F_B10F file's glType is 0x8C3A, the sized format, as cmgen writes it
(``tools/cmgen/src/cmgen.cpp``, ``.glType = KtxBundle::R11F_G11F_B10F``), not GL's packed type
GL_UNSIGNED_INT_10F_11F_11F_REV 0x8C3B that [KTX1] would have: Filament's ``Ktx1Reader::toPixelDataType``
(``libs/ktxreader/src/Ktx1Reader.cpp``) maps only UNSIGNED_BYTE, UNSIGNED_SHORT, HALF_FLOAT, FLOAT and 0x8C3A, and
``Texture::setImage`` aborts on anything else (bakery wrote 0x8C3B until 2026-12-07: ``createIblFromKtx1`` and
``createSkyFromKtx1`` aborted the WASM engine; :func:`read_ktx1` reads both).

Orientation, checked by rendering with Filament 1.53.4 (WebGL2, ``tests/export/test_export_conventions.py``): Filament
samples the cube with the world direction as GL does (``textureLod(light_iblSpecular, r, lod)``,
``shaders/src/light_indirect.fs``; skybox ``texture(skybox, eyeDirection)``, ``filament/src/materials/skybox.mat``),
and its ``libs/ibl`` ``Cubemap::getDirectionFor`` is bakery's face orientation, so a texel stands for the direction
bakery's conventions give it and a light at world +X shows at +X. cmgen's default mirroring
(``CubemapUtils::mirrorCubemap``, N → (−N.x, N.y, N.z), undone by ``--no-mirror``) compensates its own
equirectangular reader (``equirectangularToCubemap``: column ∝ atan2(x, z), the OpenEXR/USD latlong mirrored), and
its ``sh`` are computed from the mirrored cube; so a cmgen KTX of an OpenEXR-convention panorama and bakery's hold
the same world, cube and SH alike: bakery mirrors nothing.

``sh`` key: 27 floats as text, one "r g b" line per coefficient (what ``Filament._createIblFromKtx1`` parses with
``split(/\\s/, 27)``): Filament's **pre-scaled irradiance** convention (``CubemapSH::computeIrradianceSH3Bands``):
E(n)/π = sh0 + sh1·y + sh2·z + sh3·x + sh4·y·x + sh5·y·z + sh6·(3z² − 1) + sh7·z·x + sh8·(x² − y²), i.e. bakery
radiance SH f_k × A_l/π × the monomial coefficient of Y_k (signs included): sh_k = f_k · (A_l/π) · b_k,
b = (√(1/4π), −√(3/4π), √(3/4π), −√(3/4π), √(15/4π), −√(15/4π), √(5/16π), −√(15/4π), √(15/16π)).
Filament clamps the polynomial at 0 (``max(..., 0.0)``); the store's E/π is not clamped. ``Engine.createIblFromKtx1``
of filament.js 1.53.4 parses the key into ``ibl.shfloats`` but does not give it to the ``IndirectLight``: its
diffuse light is then the roughness-one level sampled at n (``Irradiance_RoughnessOne``, used while ``iblSH[0].x`` is
the 65504 "not set" marker of ``IndirectLight::Builder``), which for the α = 1 level of this kernel is E/π too,
to within that level's resolution (below). Build the light with ``irradianceSh(3, shfloats)`` to use the SH.

Mip levels are re-prefiltered at the ``filament`` profile: Filament's lod is (M − 1)·r(2 − r) with M the texture's
level count (``perceptualRoughnessToLod``, ``iblRoughnessOneLevel = ibl.getLevelCount() − 1``). By default the
chain stops at 16² (:func:`cmgen_levels`, cmgen's ``IBL_DEFAULT_MIN_LOD_SIZE``): N = 256 → 5 levels, 128 → 4,
32 → 2, N < 32 the full chain. The roughness-one level is what Filament reads for r = 1 and, without
``irradianceSh``, for all diffuse light; a 1×1 one (the full chain, bakery's default until 2026-12-07) put that
diffuse light up to 37 % of its maximum off (rendered: 32² sun; 21 % for ``city_512`` at 128²), the 16² one 1.4 %
(1.3 %). ``levels = M`` overrides it.

[KTX1] Khronos, "KTX File Format Specification" version 1.1.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from bakery.encodings.base import EncodingParams
from bakery.export.base import ExportContext, ExportedFile, ExportFormat, register_format, slug
from bakery.export.ktx2 import pack_b10g11r11, to_float16, unpack_b10g11r11
from bakery.export.profiles import full_chain_levels
from bakery.export.source import COSINE_BANDS, profile_chains, radiance_sh
from bakery.sh.basis import sh_bands

KTX1_IDENTIFIER = b"\xabKTX 11\xbb\r\n\x1a\n"
GL_R11F_G11F_B10F, GL_UNSIGNED_INT_10F_11F_11F_REV, GL_RGB = 0x8C3A, 0x8C3B, 0x1907
GL_RGBA16F, GL_HALF_FLOAT, GL_RGBA = 0x881A, 0x140B, 0x1908

#: name → (glType, glTypeSize, glFormat, glInternalFormat, glBaseInternalFormat, bytes per texel); R11F_G11F_B10F's
#: glType is the sized format, as cmgen writes it and Filament's ``Ktx1Reader::toPixelDataType`` requires
GL_FORMATS = {
    "R11F_G11F_B10F": (GL_R11F_G11F_B10F, 4, GL_RGB, GL_R11F_G11F_B10F, GL_RGB, 4),
    "RGBA16F": (GL_HALF_FLOAT, 2, GL_RGBA, GL_RGBA16F, GL_RGBA, 8),
}
#: glTypes :func:`read_ktx1` also accepts: GL's packed type, which bakery wrote before 2026-12-07
LEGACY_GL_TYPES = {"R11F_G11F_B10F": GL_UNSIGNED_INT_10F_11F_11F_REV}
#: Smallest face of the default chain: cmgen's ``IBL_DEFAULT_MIN_LOD_SIZE`` (``tools/cmgen/src/cmgen.cpp``)
CMGEN_MIN_LOD_SIZE = 16

#: Monomial coefficient of bakery's Y_k (signs included) in Filament's order 1, y, z, x, yx, yz, 3z²−1, zx, x²−y².
BASIS_MONOMIAL = np.array([np.sqrt(1 / (4 * np.pi)), -np.sqrt(3 / (4 * np.pi)), np.sqrt(3 / (4 * np.pi)),
                           -np.sqrt(3 / (4 * np.pi)), np.sqrt(15 / (4 * np.pi)), -np.sqrt(15 / (4 * np.pi)),
                           np.sqrt(5 / (16 * np.pi)), -np.sqrt(15 / (4 * np.pi)), np.sqrt(15 / (16 * np.pi))])


def filament_sh(radiance: np.ndarray) -> np.ndarray:
    """bakery radiance SH (9, 3) → Filament's pre-scaled irradiance SH (9, 3) (module docstring)."""
    return np.asarray(radiance, np.float64)[:9] * (COSINE_BANDS[sh_bands(2)] / np.pi * BASIS_MONOMIAL)[:, None]


def cmgen_levels(face_size: int) -> int:
    """Mip levels cmgen writes for N² faces (``iblRoughnessPrefilter``: ``numLevels = baseExp + 1 − minLod``,
    ``minLod`` = log2 16 unless that is ≥ log2 N, then 0): the levels down to the last face ≥ 16², or the full chain
    when fewer than two would be (N < 32)."""
    count = sum(1 for i in range(full_chain_levels(face_size)) if face_size >> i >= CMGEN_MIN_LOD_SIZE)
    return count if count >= 2 else full_chain_levels(face_size)


def sh_text(sh: np.ndarray) -> str:
    return "".join(f"{r:.9g} {g:.9g} {b:.9g}\n" for r, g, b in np.asarray(sh, np.float64))


@dataclass
class Ktx1Cube:
    gl_format: str
    size: int
    levels: list[np.ndarray] = field(default_factory=list)  # (6, N_i, N_i, 3) float32 per level
    key_values: dict[str, bytes] = field(default_factory=dict)


def _face_bytes(face: np.ndarray, gl_format: str) -> bytes:
    if gl_format == "R11F_G11F_B10F":
        return pack_b10g11r11(face[..., :3]).astype("<u4").tobytes()
    rgba = np.concatenate([face[..., :3], np.ones_like(face[..., :1])], axis=-1)
    return np.ascontiguousarray(to_float16(rgba)).tobytes()  # saturated at 65504: no inf texels


def write_ktx1(cube: Ktx1Cube) -> bytes:
    gl_type, type_size, gl_fmt, internal, base, _ = GL_FORMATS[cube.gl_format]
    kvd = bytearray()
    for key, value in cube.key_values.items():
        entry = key.encode() + b"\x00" + value
        kvd += struct.pack("<I", len(entry)) + entry + bytes(-len(entry) % 4)
    out = bytearray(KTX1_IDENTIFIER)
    out += struct.pack("<13I", 0x04030201, gl_type, type_size, gl_fmt, internal, base, cube.size, cube.size, 0, 0, 6,
                       len(cube.levels), len(kvd))
    out += kvd
    for level in cube.levels:
        faces = [_face_bytes(face, cube.gl_format) for face in level]
        out += struct.pack("<I", len(faces[0]))
        for data in faces:
            out += data + bytes(-len(data) % 4)
    return bytes(out)


def read_ktx1(data: bytes) -> Ktx1Cube:
    """Parse a KTX1 cube written by :func:`write_ktx1` (strict: sizes must match the header)."""
    if data[:12] != KTX1_IDENTIFIER or len(data) < 64:
        raise ValueError("not a KTX 1 file")
    values = struct.unpack_from("<13I", data, 12)
    if values[0] != 0x04030201:
        raise ValueError("big-endian KTX1 is not read by bakery")
    gl_type, _, _, internal, _, width, height, _, _, faces, levels, kvd_len = values[1:]
    name = next((n for n, f in GL_FORMATS.items()
                 if f[3] == internal and gl_type in (f[0], LEGACY_GL_TYPES.get(n))), None)
    if name is None or faces != 6 or width != height:
        raise ValueError("not a bakery KTX1 cube")
    cube = Ktx1Cube(name, width)
    pos, end = 64, 64 + kvd_len
    while pos < end:
        (length,) = struct.unpack_from("<I", data, pos)
        key, value = data[pos + 4:pos + 4 + length].split(b"\x00", 1)
        cube.key_values[key.decode()] = value
        pos += 4 + length + (-length % 4)
    texel = GL_FORMATS[name][5]
    for i in range(max(levels, 1)):
        n = max(1, width >> i)
        (image_size,) = struct.unpack_from("<I", data, pos)
        if image_size != n * n * texel:
            raise ValueError(f"level {i}: imageSize {image_size}, expected {n * n * texel}")
        pos += 4
        faces_out = []
        for _ in range(6):
            raw = data[pos:pos + image_size]
            if len(raw) != image_size:
                raise ValueError("truncated KTX1")
            if name == "R11F_G11F_B10F":
                faces_out.append(unpack_b10g11r11(np.frombuffer(raw, "<u4").reshape(n, n)))
            else:
                faces_out.append(np.frombuffer(raw, "<f2").astype(np.float32).reshape(n, n, 4)[..., :3])
            pos += image_size + (-image_size % 4)
        cube.levels.append(np.stack(faces_out))
    return cube


@register_format
class FilamentExport(ExportFormat):
    """Filament KTX1 IBL cube with the ``sh`` key, per reflection probe."""

    name = "filament"
    description = "Filament KTX1 cube (R11F_G11F_B10F or RGBA16F) with the pre-scaled irradiance 'sh' key, as cmgen"
    default_profile = "filament"

    @dataclass(frozen=True)
    class Params(EncodingParams):
        gl_format: Literal["R11F_G11F_B10F", "RGBA16F"] = "R11F_G11F_B10F"
        levels: int | None = None
        face_size: int | None = None

        def validate(self) -> None:
            if self.levels is not None and self.levels < 1:
                raise ValueError(f"levels must be >= 1 (or unset: cmgen's chain, down to 16²), got {self.levels}")
            if self.face_size is not None and self.face_size < 1:
                raise ValueError(f"face_size must be >= 1 (or unset: the kept capture's), got {self.face_size}")

    def build(self, context: ExportContext) -> Iterator[ExportedFile]:
        """One .ktx per probe, streamed."""
        import json

        p = context.params
        chains = profile_chains(context.store, context.probes, context.profile, p.levels, p.face_size)
        if p.levels is None:  # cmgen's chain (down to 16²) for the face size the options resolve to (lazy: nothing
            chains = profile_chains(context.store, context.probes, context.profile,  # is prefiltered yet)
                                    cmgen_levels(chains.face_size), p.face_size)
        for name, chain, capture in chains:
            radiance, source = radiance_sh(context.store, name, capture)
            meta = {**context.provenance(), "probe": name, "profile": chains.record, "irradiance_source": source,
                    **({"validity": v} if (v := context.validity([name]).get(name)) else {})}
            cube = Ktx1Cube(p.gl_format, chain[0].shape[1], chain,
                            {"sh": sh_text(filament_sh(radiance)).encode() + b"\x00",
                             "bakery": json.dumps(meta, sort_keys=True).encode() + b"\x00"})
            yield ExportedFile(f"{slug(name)}.ktx", write_ktx1(cube), (name,), "")
