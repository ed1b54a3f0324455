"""The source protocol: what every kind of bake input (environment images, USD scenes, in-memory captures)
provides to the one bake path (:func:`bakery.pipeline.run.bake`).

    parent   plan(settings, previous)      → SourcePlan: probes, each with a typed capture spec and input hashes
             validate_outputs(request)     → raise before any work if an output would damage an input
             rebake(previous, reused)      → reused probes that must be baked again anyway (e.g. a light changed)
             prepare(work_dir)             → SourceHandle: a small picklable handle to a snapshot workers read
    worker   capture(handle, spec, N)      → Capture (runs in worker processes; never imports ``pxr``)
             capture_many(handle, specs, N) → a Capture or the exception per probe (default: ``capture`` each;
                                              sources that render probes faster together override it)
    parent   after_write(merged, request)  → extra outputs after the store (e.g. the USD layer), summary entries

A new source is one module that subclasses :class:`Source`, declares ``kind`` and is listed in
:mod:`bakery.sources` (explicit import, so a broken source fails loudly).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from bakery.environment.sanitize import SanitizeReport
from bakery.probe import Probe
from bakery.sphere.grid import SphericalSamples

if TYPE_CHECKING:  # pragma: no cover
    from bakery.pipeline.encode import EncodedBatch
    from bakery.pipeline.settings import BakeRequest, BakeSettings
    from bakery.store.format import StoreContents


@dataclass(frozen=True)
class Capture:
    """What a worker captured for one probe.

    Attributes:
        cube: (6, N, N, 3) float32 radiance on the bake grid.
        reference: full-resolution quadrature of what the probe sees (a distant probe's source image; a
            :class:`~bakery.irradiance.reference.BinnedQuadrature` of it), or None when the cube is the reference.
        sanitize: counts of input texels replaced by sanitising, or None when nothing was read from a file.
        stats: numbers summed into the bake's timings (``capture_rays``, ``capture_seconds``, …).
        diagnostics: per-probe arrays (no probe axis) stored under ``/diagnostics`` (e.g. ``input/flux_source``).
    """

    cube: np.ndarray
    reference: SphericalSamples | None = None
    sanitize: SanitizeReport | None = None
    stats: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class PlannedProbe:
    """One probe as its source plans it.

    Attributes:
        probe: identity, kinds, position and per-probe settings.
        capture: the source's frozen capture spec for this probe (hashed; handed back to :meth:`Source.capture`).
        inputs: content hashes of everything the capture reads (image bytes, the scene parts it can see).
    """

    probe: Probe
    capture: Any
    inputs: tuple[str, ...] = ()


@dataclass
class SourcePlan:
    """A source's plan: its probes in store order and the root attributes its stores carry."""

    probes: list[PlannedProbe]
    attributes: dict[str, Any] = field(default_factory=dict)
    #: identifiers of the source's own files, recorded in the store's bake history
    layers: str = ""
    #: human-readable notes (scene issues that were worked around), reported in the summary
    issues: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class SourceHandle:
    """What a worker needs to capture any probe of a source: the source kind, where its snapshot is, its digest."""

    kind: str
    location: str = ""
    digest: str = ""


class Source(ABC):
    """Base of every bake input (see the module docstring for the protocol)."""

    kind: ClassVar[str]
    #: bake-grid face size when neither the recipe nor the command line gives one
    default_face_size: ClassVar[int] = 64
    #: probes per worker batch when the recipe does not say
    default_batch_size: ClassVar[int] = 16

    @abstractmethod
    def plan(self, settings: BakeSettings, previous: StoreContents | None) -> SourcePlan: ...

    def validate_outputs(self, request: BakeRequest) -> None:  # noqa: B027 - optional hook
        """Raise :class:`bakery.errors.BakeryError` if an output path would overwrite one of this source's inputs."""

    def rebake(self, previous: StoreContents, reused: list[str]) -> tuple[set[str], dict[str, Any]]:
        """Reused probes (unchanged content hash) that must be baked again anyway, and attributes that say why."""
        return set(), {}

    @abstractmethod
    def prepare(self, work_dir: Path) -> SourceHandle:
        """Parent, before workers start: write what workers need into ``work_dir`` (once) and return its handle."""

    @classmethod
    @abstractmethod
    def capture(cls, handle: SourceHandle, spec: Any, face_size: int) -> Capture:
        """Worker: the capture of one probe (``spec`` from its :class:`PlannedProbe`) on the bake grid."""

    @classmethod
    def capture_many(cls, handle: SourceHandle, specs: Sequence[Any], face_size: int) -> list[Capture | Exception]:
        """Worker: the captures of several probes, in ``specs`` order, each the :class:`Capture` :meth:`capture`
        gives or the exception its capture raised (one failing probe does not lose the others). The default
        captures them one by one (:func:`capture_each`); a source may capture several together, with the same
        results."""
        return capture_each(cls, handle, specs, face_size)

    def after_write(self, merged: EncodedBatch, contents: StoreContents, request: BakeRequest) -> dict[str, Any]:
        """Parent, after the store is written: further outputs; returns entries for the bake summary."""
        return {}


def capture_each(source: type[Source], handle: SourceHandle, specs: Sequence[Any], face_size: int
                 ) -> list[Capture | Exception]:
    """:meth:`Source.capture` of every spec, one by one: its capture, or the exception it raised."""
    results: list[Capture | Exception] = []
    for spec in specs:
        try:
            results.append(source.capture(handle, spec, face_size))
        except Exception as error:  # noqa: BLE001 - reported for this probe by the caller
            results.append(error)
    return results


#: kind → Source class; filled by :func:`register_source` from the modules :mod:`bakery.sources` imports.
SOURCES: dict[str, type[Source]] = {}


def register_source(*classes: type[Source]) -> None:
    for cls in classes:
        if cls.kind in SOURCES and SOURCES[cls.kind] is not cls:
            raise ValueError(f"source kind {cls.kind!r} registered twice")
        SOURCES[cls.kind] = cls


def source_class(kind: str) -> type[Source]:
    import bakery.sources  # noqa: F401 - importing the package registers every source

    try:
        return SOURCES[kind]
    except KeyError:
        raise KeyError(f"unknown source kind {kind!r}; known: {', '.join(SOURCES)}") from None
