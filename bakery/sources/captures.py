"""Captures already in memory: cube maps an engine or another renderer produced, baked through the same path.

    source = CubeSource([Probe("/a"), Probe("/b")], cubes)        # cubes (P, 6, N, N, 3) float32 radiance
    bakery.bake(source, "probes.h5", encodings=("zh3", "shexp"))

The parent writes the cubes once into the bake's work folder (``<store>.partial/``) as a ``.npy`` that workers
memory-map; optional full-resolution reference quadratures go beside it. The bake face size defaults to the cubes'
own (other sizes are resampled flux-exactly).
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from bakery.errors import ConfigError, EncodingError
from bakery.files import atomic_replace, stable_hash
from bakery.probe import Probe
from bakery.sphere.cubemap import resample_cube
from bakery.sphere.grid import SphericalSamples
from bakery.sources.base import Capture, PlannedProbe, Source, SourceHandle, SourcePlan, register_source


@dataclass(frozen=True)
class CubeCapture:
    """Capture spec of one in-memory probe: its row in the snapshot."""

    index: int


@lru_cache(maxsize=2)
def _snapshot(location: str, digest: str) -> tuple[np.ndarray, list[SphericalSamples] | None]:  # noqa: ARG001
    cubes = np.load(Path(location) / "cubes.npy", mmap_mode="r")
    references = None
    path = Path(location) / "references.pkl"
    if path.is_file():
        with open(path, "rb") as handle:
            references = pickle.load(handle)
    return cubes, references


class CubeSource(Source):
    """Probes with captured radiance cubes (P, 6, N, N, 3); ``references`` optional per-probe quadratures."""

    kind = "cubes"
    default_batch_size = 64

    def __init__(self, probes: list[Probe], cubes: np.ndarray,
                 references: list[SphericalSamples] | None = None) -> None:
        cubes = np.asarray(cubes, dtype=np.float32)
        if cubes.ndim != 5 or cubes.shape[1] != 6 or cubes.shape[2] != cubes.shape[3] or cubes.shape[4] != 3:
            raise ConfigError(f"cubes must be (P, 6, N, N, 3), got {cubes.shape}")
        if len(probes) != cubes.shape[0]:
            raise ConfigError(f"{len(probes)} probes but {cubes.shape[0]} captures")
        names = [p.name for p in probes]
        if len(set(names)) != len(names):
            raise ConfigError("probe names must be unique")
        if references is not None and len(references) != len(probes):
            raise ConfigError(f"{len(probes)} probes but {len(references)} reference quadratures")
        finite = np.isfinite(cubes).reshape(len(probes), -1).all(axis=1)
        if not finite.all():
            bad = [names[i] for i in np.flatnonzero(~finite)]
            raise EncodingError(f"non-finite captured radiance in probe(s) {', '.join(bad[:5])}"
                                f"{' …' if len(bad) > 5 else ''}; sanitise captures before encoding")
        self.probes = list(probes)
        self.cubes = cubes
        self.references = references
        self.default_face_size = int(cubes.shape[2])
        self._digest = stable_hash(cubes, None if references is None else
                                   [(r.directions, r.solid_angles, r.radiance) for r in references])

    def plan(self, settings, previous) -> SourcePlan:  # noqa: ANN001, ARG002
        planned = []
        for i, probe in enumerate(self.probes):
            reference = None if self.references is None else self.references[i]
            inputs = (stable_hash(self.cubes[i], None if reference is None else
                                  (reference.directions, reference.solid_angles, reference.radiance)),)
            planned.append(PlannedProbe(probe, CubeCapture(i), inputs))
        return SourcePlan(planned, {"source_kind": self.kind})

    def prepare(self, work_dir: Path) -> SourceHandle:
        folder = Path(work_dir) / f"cubes-{self._digest[:16]}"
        if not (folder / "cubes.npy").is_file():
            folder.mkdir(parents=True, exist_ok=True)
            if self.references is not None:
                with atomic_replace(folder / "references.pkl") as tmp, open(tmp, "wb") as handle:
                    pickle.dump(self.references, handle, protocol=pickle.HIGHEST_PROTOCOL)
            with atomic_replace(folder / "cubes.npy") as tmp, open(tmp, "wb") as handle:
                np.save(handle, self.cubes)
        return SourceHandle(self.kind, str(folder), self._digest)

    @classmethod
    def capture(cls, handle: SourceHandle, spec: CubeCapture, face_size: int) -> Capture:
        cubes, references = _snapshot(handle.location, handle.digest)
        cube = np.array(cubes[spec.index], dtype=np.float32)
        if cube.shape[1] != face_size:
            cube = resample_cube(cube, face_size)
        return Capture(cube, None if references is None else references[spec.index])


register_source(CubeSource)
