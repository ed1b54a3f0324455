"""Test harness: bakes through the one bake path (``bakery.bake``) and read-back helpers.

    baked = bake_cubes(tmp_path / "s.h5", probes, cubes, encodings=("zh3",))      # in-memory captures
    baked = bake_image(image_path, tmp_path / "s.h5", encodings=("sh2",))        # an environment image
    baked.fields("zh3"), baked.encoding("zh3"), baked.diagnostics, baked.summary, baked.store
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

import bakery
from bakery.encodings import Encoding, get_encoding
from bakery.sources import CubeSource


@dataclass
class Baked:
    path: Path
    summary: object
    store: object

    def fields(self, name: str) -> dict[str, np.ndarray]:
        """Stored per-probe arrays of an encoding, without ``probe_index``."""
        return {k: v for k, v in self.store.fields(name).items() if k != "probe_index"}

    @property
    def encoded(self) -> dict[str, dict[str, np.ndarray]]:
        return {name: self.fields(name) for name in self.store.encodings}

    def encoding(self, name: str) -> Encoding:
        """The encoding as the store records it (its stored, finalized parameters)."""
        return get_encoding(name).from_settings(self.store.encodings[name].settings)

    @property
    def diagnostics(self) -> dict[str, np.ndarray]:
        return self.store.diagnostics

    @property
    def warnings(self) -> list[str]:
        return list(self.summary.warnings)


def bake_cubes(path, probes, cubes, *, references=None, **options) -> Baked:  # noqa: ANN001
    """Bake captured cubes (P, 6, N, N, 3) for ``probes`` into ``path`` (options as for ``bakery.bake``)."""
    summary = bakery.bake(CubeSource(probes, np.asarray(cubes), references), path, **options)
    return Baked(Path(path), summary, bakery.open_store(path))


def bake_image(image, path, **options) -> Baked:  # noqa: ANN001
    """Bake an environment image (one distant probe) into ``path``."""
    summary = bakery.bake(image, path, **options)
    return Baked(Path(path), summary, bakery.open_store(path))


def single_scattering(scene):  # noqa: ANN001, ANN201 - bakery.capture.scene.CaptureScene
    """``scene`` with its MaterialX materials combining their lobes as UsdPreviewSurface does (``layering =
    "preview"``: no layering throughput, no multiple-scattering compensation; bakery.capture.bsdf "MaterialX
    layering"), for tests of what the reader maps a MaterialX surface onto (F0, F90, tints, normal maps) against a
    UsdPreviewSurface twin or a model linear in F0."""
    from dataclasses import replace

    return replace(scene, meshes=tuple(replace(mesh, material=replace(mesh.material, layering="preview",
                                                                      specular_layer=None))
                                       for mesh in scene.meshes))
