"""glTF 2.0 + ``EXT_lights_image_based`` (Babylon.js is its runtime): one ``.gltf`` per reflection probe.

Per reflection probe ``<slug>.gltf`` with a node at the probe's position (name = probe, ``extras.bakery``), one scene
referencing the light, and the light [EXT]:

``irradianceCoefficients``  9 × 3 **irradiance** SH: bakery radiance SH × (π, 2π/3, π/4) per band, in Babylon's
                            basis (real, orthonormal, Condon–Shortley signs, order l00, l1−1, l10, l11, l2−2 …:
                            babylon.js ``SH3ylmBasisConstants``; its loader divides by π itself,
                            ``convertIrradianceToLambertianRadiance``) and in Babylon's left-handed world (below):
                            coefficients 3, 4 and 7 (odd in x) negated (:func:`irradiance_coefficients`). The radiance
                            SH come from the probe's irradiance encoding when it has one (:mod:`bakery.export.source`),
                            else from the kept capture.
``specularImageSize``       face size of mip 0: a power of two (Babylon loads no other), by default the largest
                            ≤ the kept capture's (an N = 12 bake exports 8², resampled preserving flux)
``specularImages``          M × 6 image indices, mips of halving sizes, faces +X −X +Y −Y +Z −Z, each a 4-channel PNG
                            in Babylon's RGBD packing (below), re-prefiltered at the profile's α per mip (default
                            profile ``babylon``: the loader sets lodGenerationScale = (M − 1)/log2 N)
``intensity``, ``rotation`` 1, identity (always written: Babylon's loader multiplies the SH by ``light.intensity``
                            unguarded, so an absent one — 1 by [EXT] — would make them NaN)

Orientation: [EXT] names no coordinate system for the cube or the SH and says "each saved image must be flipped about
its vertical axis to correspond with the way glTF references texture space". What Babylon.js 9.28 (the extension's
runtime) does, measured by rendering (``tests/export/test_export_conventions.py``): its glTF loader puts the asset
under ``__root__``, which in its default left-handed scene maps glTF (x, y, z) to world (−x, y, z); the loader leaves
the IBL alone, and the PBR and skybox shaders look the cube and the SH up with that world direction
(``RawCubeTexture`` uploads each PNG with its top row at t = 1, Babylon's ``invertY``). So a glTF asset sees the
store's environment only if the file holds it in Babylon's world, mirrored in x: every face image is the face, in
the standard (OpenGL) orientation, of the mirrored environment — bakery's faces with ±X swapped, each left↔right (the
flip [EXT] asks for) — saved upside down (glTF's texture space runs top-down), i.e. ±X swapped and every face rotated
180° (:data:`FACE_TRANSFORM`); the SH are mirrored likewise. Written as the text alone reads (left↔right only in
glTF's frame, bakery before 2026-12-07), Babylon turned each face's content 180° about the face's axis in its world —
a light at glTF (x, a, b) on +X appeared at (−x, −a, −b), one on +Y at (x, y, −z), one on +Z at (x, −y, z), seams
broken — and mirrored the diffuse light in x. In a right-handed Babylon scene (``useRightHandedSystem``) Babylon
negates z of the lookup instead, so the same file shows the environment turned 180° about +Y: Babylon's two modes
disagree for any EXT_lights_image_based file.

RGBD (Babylon's ``toRGBD``/``fromRGBD``, 8-bit PNG): D = ⌊max(255 / max(r, g, b), 1)⌋ / 255 (clamped to [1/255, 1]),
RGB = round(255 · (c·D)^(1/2.2)), A = round(255 · D); decoded c = (RGB/255)^2.2 / (A/255). Range: up to 255 (values
above clamp); relative quantisation ≈ 2.2 · ½ / 255 / (c·D)^(1/2.2) per channel (≤ 0.6 % for the largest channel).

[EXT] https://github.com/KhronosGroup/glTF/tree/main/extensions/2.0/Vendor/EXT_lights_image_based
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from bakery.encodings.base import EncodingParams
from bakery.errors import ClampWarning
from bakery.export.base import (
    ExportContext,
    ExportedFile,
    ExportFormat,
    register_format,
    slug,
)
from bakery.export.source import COSINE_BANDS, profile_chains, radiance_sh
from bakery.png import encode_png
from bakery.sh.basis import sh_bands

RGBD_MAX_RANGE = 255.0
GAMMA = 2.2


def encode_rgbd(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) linear radiance → (..., 4) uint8 RGBD (module docstring)."""
    c = np.clip(np.nan_to_num(np.asarray(rgb, np.float64), nan=0.0), 0.0, None)
    max_rgb = np.maximum(c.max(axis=-1), 1e-6)
    d = np.clip(np.floor(np.maximum(RGBD_MAX_RANGE / max_rgb, 1.0)) / 255.0, 1.0 / 255.0, 1.0)
    rgb = np.clip(c * d[..., None], 0.0, 1.0) ** (1.0 / GAMMA)
    out = np.concatenate([np.round(rgb * 255.0), np.round(d * 255.0)[..., None]], axis=-1)
    return out.astype(np.uint8)


def decode_rgbd(rgbd: np.ndarray) -> np.ndarray:
    q = np.asarray(rgbd, np.float64) / 255.0
    return (q[..., :3] ** GAMMA) / np.maximum(q[..., 3:4], 1.0 / 255.0)


#: Babylon's left-handed world is glTF's mirrored in x: the face order after mirroring (+X ↔ −X).
MIRROR_X_FACES = [1, 0, 2, 3, 4, 5]
#: Sign of each SH coefficient under x → −x (Y1,1 ∝ x, Y2,−2 ∝ xy, Y2,1 ∝ xz change sign).
MIRROR_X_SIGNS = np.array([1, 1, 1, -1, -1, 1, 1, -1, 1], dtype=np.float64)


def babylon_faces(cube: np.ndarray) -> np.ndarray:
    """(6, N, N, C) bakery faces (OpenGL orientation) → the face images Babylon renders as the same environment in
    its default left-handed scene (module docstring "Orientation"): the faces of the environment mirrored in x (±X
    swapped, each left↔right), each saved upside down — together, ±X swapped and every face rotated 180°."""
    return np.ascontiguousarray(np.asarray(cube)[MIRROR_X_FACES][:, ::-1, ::-1])


#: The face transform applied to every exported mip level (module docstring "Orientation").
FACE_TRANSFORM = babylon_faces


def irradiance_coefficients(radiance: np.ndarray) -> np.ndarray:
    """Irradiance SH (9, 3) = radiance SH × A_l, mirrored in x for Babylon's left-handed world (module docstring)."""
    return np.asarray(radiance, np.float64)[:9] * (COSINE_BANDS[sh_bands(2)] * MIRROR_X_SIGNS)[:, None]


@register_format
class GltfExport(ExportFormat):
    """glTF 2.0 with EXT_lights_image_based, one file per reflection probe."""

    name = "gltf"
    description = "glTF 2.0 + EXT_lights_image_based per reflection probe (RGBD PNG faces per mip, irradiance SH)"
    default_profile = "babylon"

    @dataclass(frozen=True)
    class Params(EncodingParams):
        levels: int | None = None
        face_size: int | None = None

        def validate(self) -> None:
            if self.levels is not None and self.levels < 1:
                raise ValueError(f"levels must be >= 1 (or unset: full chain), got {self.levels}")
            if self.face_size is not None and self.face_size < 1:
                raise ValueError(f"face_size must be >= 1 (or unset: the kept capture's), got {self.face_size}")

    def build(self, context: ExportContext) -> Iterator[ExportedFile]:
        """Per probe (streamed): its specular PNGs, then its .gltf."""
        p = context.params
        # Babylon.js refuses cube faces that are not a power of two ("Texture size must be a power of two"): an
        # N = 12, 24 or 100 bake exports 8², 16² or 64² faces (flux-preserving resample of the kept capture)
        chains = profile_chains(context.store, context.probes, context.profile, p.levels, p.face_size,
                                power_of_two=True)
        record = chains.record
        clipped: dict[str, tuple[int, float]] = {}  # probe → (texels above RGBD's range, their largest value)
        for name, chain, capture in chains:
            base = slug(name)
            radiance, sh_source = radiance_sh(context.store, name, capture)
            images, grid = [], []
            for i, level in enumerate(chain):
                brightest = np.max(level[..., :3], axis=-1)
                if np.any(brightest > RGBD_MAX_RANGE):
                    count, peak = clipped.get(name, (0, 0.0))
                    clipped[name] = (count + int(np.count_nonzero(brightest > RGBD_MAX_RANGE)),
                                     max(peak, float(brightest.max())))
                row = []
                for f, face in enumerate(FACE_TRANSFORM(level)):
                    path = f"{base}/specular_{i}_{f}.png"
                    yield ExportedFile(path, encode_png(encode_rgbd(face)), (), "image")
                    row.append(len(images))
                    images.append({"uri": path, "mimeType": "image/png"})
                grid.append(row)
            position = context.store.probe_positions[context.store.probe_names.index(name)]
            extras = {"bakery": {**context.provenance(), "probe": name, "profile": record,
                                 "irradiance_source": sh_source, "encoding": "RGBD (Babylon), 8-bit PNG",
                                 "faces": "Babylon's left-handed world (glTF mirrored in x): +X/-X swapped, each "
                                          "image rotated 180 degrees (left-right and upside down)",
                                 **({"validity": v} if (v := context.validity([name]).get(name)) else {})}}
            light = {"name": name, "intensity": 1.0, "rotation": [0.0, 0.0, 0.0, 1.0],
                     "irradianceCoefficients": [[float(v) for v in row] for row in
                                                irradiance_coefficients(radiance)],
                     "specularImageSize": int(chain[0].shape[1]), "specularImages": grid}
            document = {
                "asset": {"version": "2.0", "generator": "bakery export"},
                "extensionsUsed": ["EXT_lights_image_based"],
                "extensions": {"EXT_lights_image_based": {"lights": [light]}},
                "images": images,
                "nodes": [{"name": name, "translation": [float(v) for v in position]}],
                "scenes": [{"name": name, "nodes": [0], "extensions": {"EXT_lights_image_based": {"light": 0}}}],
                "scene": 0,
                "extras": extras,
            }
            text = json.dumps(document, indent=1, sort_keys=True) + "\n"
            yield ExportedFile(f"{base}.gltf", text.encode(), (name,), "")
        if clipped:  # RGBD holds at most 255: a sun's highlight in the sharp mips loses its energy there
            names = sorted(clipped)
            texels = sum(count for count, _ in clipped.values())
            peak = max(p for _, p in clipped.values())
            warnings.warn(f"gltf export: {texels:,} specular texels of {len(names)} probe(s) ({', '.join(names[:3])}"
                          f"{' …' if len(names) > 3 else ''}) exceed Babylon's RGBD range {RGBD_MAX_RANGE:g} (up to "
                          f"{peak:.3g}) and were clamped to it; export ktx2 or filament (float formats) to keep HDR "
                          f"highlights such as a sun", ClampWarning, stacklevel=2)

