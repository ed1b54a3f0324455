"""three.js r187: ``LightProbe`` JSON for irradiance probes, ``LightProbeGrid`` atlases for probe volumes, KTX2 cubes
for reflection probes.

``lightprobes.json``  ObjectLoader JSON (``metadata.type = "Object"``): a ``Group`` whose children are one
                      ``LightProbe`` per irradiance probe outside a volume (``name`` = probe, ``matrix`` = its
                      translation, ``sh`` = 27 floats, coefficient-major). three's ``SphericalHarmonics3`` basis is
                      bakery's without the Condon–Shortley signs (three: Y1,−1 = +c·y, Y1,1 = +c·x, Y2,−1 = +c·yz,
                      Y2,1 = +c·xz), so coefficients 1, 3, 5 and 7 change sign; three stores **radiance** SH and
                      ``getIrradianceAt`` applies π, 2π/3, π/4 — bakery's irradiance (not divided by π). A
                      ``LightProbe`` is not spatial: ``WebGLLights.setup`` adds the SH of every LightProbe in the scene
                      (position ignored), so a scene takes one of them (the nearest, or a blend), not the Group.
``<volume>.ktx2``     a 3-D KTX2 (``VK_FORMAT_R32G32B32A32_SFLOAT``, which three's KTX2Loader returns as a
                      ``Data3DTexture``) in ``LightProbeGrid``'s atlas layout: width nx, height ny, depth 7·(nz + 2);
                      sub-volume t ∈ 0..6 holds floats 4t..4t+3 of the 27 (three basis, coefficient-major; the last
                      texel's 4th channel is 0) at slices t·(nz+2) + 1 + iz, with slice t·(nz+2) a copy of iz = 0 and
                      t·(nz+2) + nz + 1 a copy of iz = nz − 1 (three's padding). Texel (ix, iy) of a slice is the
                      probe at grid index (ix, iy, iz) along +x, +y, +z of the bake frame (rows in upload order;
                      ``KTXorientation`` ``ruo``: rows up, slices out of the screen, as the grid lies in a right-handed
                      y-up view — ``rdi``, which says the opposite, until 2026-12-07). KTX2Loader gives it
                      ``NearestFilter``; the grid shader (``lightprobes_pars_fragment``) needs the trilinear filtering
                      LightProbeGridWebGL's own atlas has: set ``LinearFilter`` before use.
``lightprobegrids.json``  per volume: ``texture``, ``position`` (box centre), ``width``/``height``/``depth`` and
                      ``resolution`` for ``new LightProbeGridWebGL(width, height, depth, nx, ny, nz)`` (WebGLRenderer;
                      ``LightProbeGrid`` for WebGPURenderer) at ``position`` (three puts probes at cell centres: box =
                      probe extent + one spacing), its ``texture`` set to the atlas. Only volumes whose probes form an
                      axis-aligned lattice in the bake frame become grids; others export as LightProbes.
``<probe>.ktx2``      reflection probes (when the store keeps their capture): KTX2 cubes (RGBA16F) **in three's cube
                      frame** (below), at the ``three`` profile, levels down to the last face ≥ 8²
                      (:func:`pmrem_levels`).

Cube frame. three samples every ``CubeTexture`` that is not a render target at (−x, y, z): the material's
``envMapRotation`` is premultiplied by diag(−1, 1, 1) (``WebGLMaterials.refreshUniformsCommon``), so is the
skybox's ``backgroundRotation`` (``WebGLBackground.addToRenderList``), and ``PMREMGenerator._textureToCubemap``
reads the cube with ``flipEnvMap = −1`` — [KTX2]'s cube coordinates, left-handed, reached from a right-handed world
by negating x (KTX 2.0 §"Cubemap orientation"). So the three cubes hold the environment mirrored in x
(:func:`three_cube_faces`: faces ±X swapped, every face flipped left↔right): texel direction d of the GL face table
shows the bake frame's (−d.x, d.y, d.z), and three renders a light at +X at +X. Written in bakery's frame (as the
``ktx2`` export is; bakery until 2026-12-07), three showed every cube mirrored in x — skybox, mirror spheres and
the PMREM's diffuse light alike (rendered, ``tests/export/test_export_three_render.py``), while the LightProbes,
evaluated at the world normal, were right. Exported cube bytes changed.

Mip chain. three's KTX2Loader returns an uncompressed cube as a ``DataTexture`` whose mipmaps hold the six faces in
a row; docs/exports.md gives the few lines that make it a ``CompressedCubeTexture``. As ``scene.environment`` /
``envMap`` three then builds its own PMREM from level 0 (``WebGLEnvironments.getPMREM`` → ``PMREMGenerator``:
faces ≥ 256², levels down to 8², roughness of level i = 1 − √(1 − i/maxLod)) and ignores the rest of the chain —
unless the cube is marked ``isPMREMTexture``, then three uses the chain as is: lod = maxLod·r(2 − r) with maxLod =
the file's levels − 1 (``roughnessToMip``, ``envmap_common_pars_fragment``; ``WebGLPrograms``: ``envMapMaxLod``), and
its last level, × π, is the diffuse light (``getIBLIrradiance``: ``textureLod(envMap, n, ENVMAP_MAX_LOD)``). The
``three`` profile prefilters level i at exactly three's roughness, and the default chain stops where three's PMREM
does, at 8² (``LOD_MIN = 3``): with the full chain down to 1×1 (bakery's default until 2026-12-07) that diffuse
light was 35 % of its maximum off and rough reflections read 2², 1² faces (rendered: 32² disc environment).
``levels = M`` overrides it.

[KTX2] Khronos, "KTX File Format Specification, version 2.0".
"""

from __future__ import annotations

import json
import re
import uuid
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from bakery.encodings.base import EncodingParams
from bakery.errors import BakeryWarning, InputError
from bakery.export.base import ExportContext, ExportedFile, ExportFormat, register_format, slug
from bakery.export.ktx2 import (
    VK_FORMAT_R16G16B16A16_SFLOAT,
    VK_FORMAT_R32G32B32A32_SFLOAT,
    Ktx2Texture,
    bakery_key_values,
    cube_texture,
    encode_texels,
    text_value,
    write_ktx2,
)
from bakery.export.profiles import full_chain_levels
from bakery.export.source import (
    irradiance_encoding,
    radiance_sh_from_irradiance,
    stored_capture_encoding,
)

#: Coefficients whose sign differs between bakery's basis and three's (1, 3, 5, 7).
THREE_SIGNS = np.array([1, -1, 1, -1, 1, -1, 1, -1, 1], dtype=np.float64)

_VOLUME_NAME = re.compile(r"^(?P<prim>.*)\[(?P<i>\d+),(?P<j>\d+),(?P<k>\d+)\]$")


def to_three_sh(radiance: np.ndarray) -> np.ndarray:
    """bakery radiance SH (9, 3) → three.js ``SphericalHarmonics3`` coefficients (9, 3)."""
    return np.asarray(radiance, np.float64)[:9] * THREE_SIGNS[:, None]


#: KVD ``bakery:cube_frame`` of the three cubes (module doc "Cube frame").
CUBE_FRAME = text_value("three.js CubeTexture: the bake frame mirrored in x (texel direction d of the GL face table "
                        "holds the radiance bakery's frame has at (-d.x, d.y, d.z)); three samples at (-x, y, z)")

#: three's PMREM stops at 8² faces (``PMREMGenerator``: ``LOD_MIN = 3``, ``_allocateTarget``: maxLod = log2 N − 3).
PMREM_MIN_FACE_SIZE = 8


def pmrem_levels(face_size: int) -> int:
    """Mip levels of a three cube with N² faces: down to the last face ≥ 8², like three's own PMREM
    (``PMREMGenerator._allocateTarget``), or the full chain when that would be fewer than two levels (N < 16)."""
    count = sum(1 for i in range(full_chain_levels(face_size)) if face_size >> i >= PMREM_MIN_FACE_SIZE)
    return count if count >= 2 else full_chain_levels(face_size)


def three_cube_faces(level: np.ndarray) -> np.ndarray:
    """A cube level (6, N, N, C) in bakery's frame → three's cube frame, the environment mirrored in x (module doc
    "Cube frame"): three looks a ``CubeTexture`` up at (−x, y, z) (``WebGLMaterials``, ``WebGLBackground``:
    ``_m`` = diag(−1, 1, 1); ``PMREMGenerator``: ``flipEnvMap = −1``), and the GL face table maps (−x, y, z) of +X's
    texel (i, j) to −X's texel (i, N − 1 − j), of ±Y's and ±Z's to the same face's (i, N − 1 − j)."""
    return np.ascontiguousarray(np.asarray(level)[[1, 0, 2, 3, 4, 5]][:, :, ::-1])


def _uuid(name: str) -> str:
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "bakery:" + name)).upper()


def axis_aligned_grid(positions: np.ndarray, tolerance: float = 1e-6):
    """(resolution (3,), index (P, 3), minimum (3,), spacing (3,)) if ``positions`` form a full regular lattice aligned
    with the bake axes, else None."""
    positions = np.asarray(positions, np.float64)
    scale = max(float(np.ptp(positions, axis=0).max()), 1.0)
    res, index, lo, spacing = [], [], [], []
    for axis in range(3):
        values = positions[:, axis]
        unique = [values.min()]
        for v in np.sort(values):
            if v - unique[-1] > tolerance * scale:
                unique.append(v)
        unique = np.asarray(unique)
        idx = np.argmin(np.abs(values[:, None] - unique[None, :]), axis=1)
        if len(unique) > 1:
            steps = np.diff(unique)
            if np.ptp(steps) > 1e-4 * steps.mean():
                return None
            spacing.append(float(steps.mean()))
        else:
            spacing.append(0.0)
        res.append(len(unique))
        index.append(idx)
        lo.append(float(unique[0]))
    index = np.stack(index, axis=-1)
    if int(np.prod(res)) != len(positions) or len({tuple(i) for i in index.tolist()}) != len(positions):
        return None
    return np.asarray(res), index, np.asarray(lo), np.asarray(spacing)


def grid_atlas(sh_three: np.ndarray, res: np.ndarray, index: np.ndarray) -> np.ndarray:
    """(7·(nz+2), ny, nx, 4) float32 atlas of LightProbeGrid from per-probe three SH (P, 9, 3)."""
    nx, ny, nz = (int(v) for v in res)
    floats = np.zeros((len(sh_three), 28), dtype=np.float32)
    floats[:, :27] = sh_three.reshape(len(sh_three), 27)
    data = np.zeros((nz, ny, nx, 7, 4), dtype=np.float32)
    data[index[:, 2], index[:, 1], index[:, 0]] = floats.reshape(-1, 7, 4)
    atlas = np.zeros((7 * (nz + 2), ny, nx, 4), dtype=np.float32)
    for t in range(7):
        base = t * (nz + 2)
        atlas[base + 1:base + 1 + nz] = data[..., t, :]
        atlas[base] = data[0, ..., t, :]
        atlas[base + nz + 1] = data[nz - 1, ..., t, :]
    return atlas


@register_format
class ThreeExport(ExportFormat):
    """three.js r187: LightProbe JSON, LightProbeGrid 3-D KTX2 atlases, KTX2 cubes for reflection probes."""

    name = "three"
    description = "three.js r187 LightProbe JSON, LightProbeGrid atlas (3-D KTX2) per volume, KTX2 reflection cubes"
    default_profile = "three"

    @dataclass(frozen=True)
    class Params(EncodingParams):
        grids: bool = True  # probe volumes as LightProbeGrid atlases (else as individual LightProbes)
        reflection: bool = True  # KTX2 cubes for reflection probes with a kept capture
        levels: int | None = None

        def validate(self) -> None:
            if self.levels is not None and self.levels < 1:
                raise ValueError(f"levels must be >= 1 (or unset: full chain), got {self.levels}")

    def build(self, context: ExportContext) -> Iterator[ExportedFile]:
        """The irradiance files (grid atlases, light probes), then one KTX2 per reflection probe, streamed."""
        store, files = context.store, []
        irradiance = [p for p in context.probes if irradiance_encoding(store, p) is not None]
        volumes: dict[str, list[str]] = {}
        singles = []
        for p in irradiance:
            match = _VOLUME_NAME.match(p)
            (volumes.setdefault(match["prim"], []) if match and context.params.grids else singles).append(p)
        grids = []
        for prim, members in volumes.items():
            positions = store.probe_positions[[store.probe_names.index(p) for p in members]]
            lattice = axis_aligned_grid(positions)
            if lattice is None:
                warnings.warn(f"three export: volume {prim} is not an axis-aligned lattice in the bake frame; its "
                              f"probes are exported as LightProbes", BakeryWarning, stacklevel=2)
                singles.extend(members)
                continue
            res, index, lo, spacing = lattice
            sh = np.stack([to_three_sh(s) for s in self._radiance(store, members)])
            atlas = grid_atlas(sh, res, index)
            size = np.where(res > 1, spacing * res, 1.0)
            centre = lo + np.where(res > 1, spacing * (res - 1) / 2.0, 0.0)
            record = {"layout": "three.js LightProbeGrid atlas (7 sub-volumes of nz + 2 slices)",
                      "resolution": [int(v) for v in res]}
            texture = Ktx2Texture(VK_FORMAT_R32G32B32A32_SFLOAT, int(res[0]), int(res[1]), int(atlas.shape[0]), 0, 1,
                                  [encode_texels(atlas, VK_FORMAT_R32G32B32A32_SFLOAT)],
                                  bakery_key_values(context, record, members, orientation="ruo"))
            path = f"{slug(prim)}.ktx2"
            files.append(ExportedFile(path, write_ktx2(texture), (prim,), "grid"))
            grids.append({"name": prim, "texture": path, "position": [float(v) for v in centre],
                          "width": float(size[0]), "height": float(size[1]), "depth": float(size[2]),
                          "resolution": [int(v) for v in res],
                          "probes": {p: [int(v) for v in ix] for p, ix in zip(members, index.tolist(), strict=True)},
                          **({"validity": v} if (v := context.validity(members)) else {})})
        if singles:
            children = []
            for p, radiance in zip(singles, self._radiance(store, singles), strict=True):
                x, y, z = (float(v) for v in store.probe_positions[store.probe_names.index(p)])
                children.append({"uuid": _uuid(p), "type": "LightProbe", "name": p, "intensity": 1,
                                 "sh": [float(v) for v in to_three_sh(radiance).reshape(-1)],
                                 "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, x, y, z, 1],
                                 "userData": {"bakery": {"probe": p, "source": irradiance_encoding(store, p),
                                                         **({"validity": v} if (v := context.validity([p]).get(p))
                                                            else {})}}})
            document = {"metadata": {"version": 4.6, "type": "Object", "generator": "bakery export"},
                        "object": {"uuid": _uuid("light probes"), "type": "Group", "name": "bakery light probes",
                                   "userData": {"bakery": context.provenance()}, "children": children}}
            files.append(ExportedFile("lightprobes.json", (json.dumps(document, indent=1) + "\n").encode(),
                                      tuple(singles), "lightprobes"))
        if grids:
            document = {"generator": "bakery export", "bakery": context.provenance(), "grids": grids}
            files.append(ExportedFile("lightprobegrids.json", (json.dumps(document, indent=1) + "\n").encode(), (),
                                      "grids"))
        chains = None
        if context.params.reflection and stored_capture_encoding(store) is not None:
            from bakery.export.source import profile_chains, reflection_probes

            if reflection_probes(store, context.probes, stored_capture_encoding(store)):
                chains = profile_chains(store, context.probes, context.profile, context.params.levels, None)
                if context.params.levels is None:  # three's PMREM layout (down to 8²) for the capture's face size
                    chains = profile_chains(store, context.probes, context.profile, pmrem_levels(chains.face_size),
                                            None)
        if not files and chains is None:
            raise InputError(f"{store.path}: no selected probe has an irradiance encoding with bands <= 2 or a kept "
                             f"reflection capture; nothing to export for three.js")
        yield from files
        for name, chain, _ in chains or ():
            key_values = bakery_key_values(context, chains.record, [name]) | {"bakery:cube_frame": CUBE_FRAME}
            texture = cube_texture([[three_cube_faces(level) for level in chain]], VK_FORMAT_R16G16B16A16_SFLOAT,
                                   key_values)
            yield ExportedFile(f"{slug(name)}.ktx2", write_ktx2(texture), (name,), "cube")

    @staticmethod
    def _radiance(store, probes: list[str]) -> list[np.ndarray]:  # noqa: ANN001
        by_encoding: dict[str, list[str]] = {}
        for p in probes:
            by_encoding.setdefault(irradiance_encoding(store, p), []).append(p)
        result = {}
        for encoding, members in by_encoding.items():
            for p, sh in zip(members, radiance_sh_from_irradiance(store, encoding, members), strict=True):
                result[p] = sh
        return [result[p] for p in probes]
