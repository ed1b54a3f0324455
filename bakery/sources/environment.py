"""Environment images as distant probes: one probe of every kind per image.

Probe names: ``/environment`` for a single image, ``/environment/<stem>`` for several. The capture is the image
resampled to the bake grid by the flux-exact area-weighted filter (:func:`bakery.environment.resample_to_cube`);
the full-resolution image is the probe's reference quadrature, held binned (:func:`bakery.environment.resample.
environment_reference`). Workers read the image themselves (it is already a
file on disk; nothing is snapshotted) and cache the decoded image per process.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from bakery.environment.io import missing_image_message, read_environment
from bakery.environment.resample import RESAMPLE_MODEL_VERSION, environment_reference, resample_to_cube
from bakery.errors import DegenerateInputWarning, ImageError
from bakery.files import sha256_file
from bakery.probe import PROBE_KINDS, Probe
from bakery.sources.base import Capture, PlannedProbe, Source, SourceHandle, SourcePlan, register_source


@dataclass(frozen=True)
class EnvironmentCapture:
    """Capture spec of one distant probe: the image file, its layout (None: from metadata/aspect ratio) and the
    version of the resampling that turns it into the capture (hashed: a changed resampling re-bakes)."""

    path: str
    layout: str | None = None
    resample_model: int = RESAMPLE_MODEL_VERSION


@lru_cache(maxsize=4)
def _read(path: str, layout: str | None, face_size: int) -> Capture:
    image, report = read_environment(path, layout=layout)
    cube = resample_to_cube(image, face_size)
    reference = environment_reference(image)  # what the diagnostics read: a few MB (an 8K image's samples: 1.9 GB)
    return Capture(cube, reference, report, diagnostics={"input/flux_source": reference.flux().astype(np.float64)})


class EnvironmentSource(Source):
    """Environment images (every layout of :mod:`bakery.environment.layouts`)."""

    kind = "environment"
    default_face_size = 64
    default_batch_size = 16

    def __init__(self, paths: tuple[Path, ...] | list[Path], layout: str | None = None) -> None:
        self.paths = tuple(Path(p) for p in paths)
        self.layout = layout

    def plan(self, settings, previous) -> SourcePlan:  # noqa: ANN001, ARG002
        missing = [p for p in self.paths if not p.is_file()]
        if missing:
            raise ImageError(missing_image_message(missing[0]))
        stems = [p.stem for p in self.paths]
        clashing = sorted(str(p) for p in self.paths if stems.count(p.stem) > 1)
        if clashing:
            raise ImageError(f"{', '.join(clashing[:4])}{' …' if len(clashing) > 4 else ''}: environment images must "
                             f"have distinct file names (probe names are /environment/<stem>)")
        probes = []
        for path in self.paths:
            name = "/environment" if len(self.paths) == 1 else f"/environment/{path.stem}"
            probes.append(PlannedProbe(Probe(name, PROBE_KINDS), EnvironmentCapture(str(path), self.layout),
                                       (sha256_file(path),)))
        attributes: dict[str, Any] = {"sources": json.dumps([str(p) for p in self.paths]), "source_kind": self.kind}
        if len(self.paths) == 1:
            attributes["source"] = str(self.paths[0])
        return SourcePlan(probes, attributes)

    def prepare(self, work_dir: Path) -> SourceHandle:  # noqa: ARG002 - the images are the snapshot
        return SourceHandle(self.kind)

    @classmethod
    def capture(cls, handle: SourceHandle, spec: EnvironmentCapture, face_size: int) -> Capture:  # noqa: ARG003
        capture = _read(spec.path, spec.layout, face_size)
        if not np.any(capture.cube > 0):
            warnings.warn(f"{spec.path}: the environment is entirely black; every encoding is zero",
                          DegenerateInputWarning, stacklevel=2)
        return capture


register_source(EnvironmentSource)
