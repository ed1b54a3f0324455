"""The one bake path: plan → check outputs → execute → merge → finalize → write. The CLI, :func:`bakery.bake`, the
benchmarks and the conformance suite all call :func:`bake`.

    source = source_for(request.sources)                    # environment images, a USD scene, in-memory cubes
    plan   = plan_bake(request, source)                     # content hashes, reuse, batches (no writes)
    outcomes = executor.run(batches)                        # workers: Source.capture → encode_batch
    merged = merge_batches(outcomes + reused probes)        # store order; band skips; finalize over all probes
    write_store(...); source.after_write(...)               # the single writer; then e.g. the USD layer

Outputs are checked before any work (:func:`check_output_paths` and ``Source.validate_outputs``), so a refused
bake touches no file. Finished batches are checkpointed in ``<store>.partial/`` (:mod:`bakery.pipeline.journal`),
beside the snapshot workers read; the folder is removed once the store is written.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

import bakery.errors
from bakery.errors import BakeryWarning, InputError, StoreFormatError
from bakery.pipeline.encode import EncodedBatch
from bakery.pipeline.executors import Executor, SerialExecutor
from bakery.pipeline.journal import Journal
from bakery.pipeline.merge import (
    DEFAULT_BAND_TOLERANCE,
    apply_band_skips,
    extract_probes,
    finalize_encodings,
    merge_batches,
    remap_history,
)
from bakery.pipeline.plan import Plan, make_batches, plan_tasks
from bakery.pipeline.settings import BakeRequest
from bakery.pipeline.write import store_contents
from bakery.sources import Source, source_for
from bakery.store.format import StoreContents, read_store, write_store

STORE_SUFFIXES = (".h5", ".hdf5")
LAYER_SUFFIXES = (".usda", ".usdc", ".usd")
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


@dataclass
class BakeSummary:
    """What a bake did (printed by ``bakery bake --json``)."""

    store: str
    planned: int
    baked: int
    reused: int
    resumed_batches: int
    failed: dict[str, str]
    skipped: list[dict[str, str]]
    batches: int
    workers: int
    executor: str
    seconds: float
    probes_per_second: float
    store_bytes: int
    bytes_per_probe: dict[str, int]
    source_kind: str = ""
    settings_hash: str = ""
    layer: str | None = None
    issues: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    #: mean over probes of the relative RMSE against the exact irradiance, per irradiance encoding
    reference_error: dict[str, float] = field(default_factory=dict)

    @property
    def encodings(self) -> list[str]:
        return sorted(self.bytes_per_probe)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def load_previous(output: str | Path) -> StoreContents | None:
    """The existing store at ``output``, if it is a readable store (else None: a full bake)."""
    try:
        return read_store(output) if Path(output).is_file() else None
    except StoreFormatError:
        return None


def _writable_folder(path: Path, what: str) -> None:
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise StoreFormatError(f"{path}: {what} folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise StoreFormatError(f"{path}: {what} folder {folder} is not writable")
    if path.is_dir():
        raise StoreFormatError(f"{path}: is a directory; give a file name for the {what}")


def check_output_paths(request: BakeRequest, source: Source) -> None:
    """Before any work: the store and layer paths are writable files of the right kind and are not inputs."""
    output = request.output
    if output.suffix.lower() not in STORE_SUFFIXES:
        raise StoreFormatError(f"{output}: the store must be an HDF5 file ({' or '.join(STORE_SUFFIXES)})")
    _writable_folder(output, "store")
    if output.is_file():
        with open(output, "rb") as handle:
            if handle.read(8) != _HDF5_SIGNATURE:
                raise StoreFormatError(f"{output}: exists and is not an HDF5 file; refusing to overwrite it")
    inputs = {str(Path(p).resolve()) for p in getattr(source, "paths", ())}
    if str(output.resolve()) in inputs:
        raise StoreFormatError(f"{output}: is an input of this bake; choose another -o")
    if request.layer is not None:
        layer = request.layer
        if layer.suffix.lower() not in LAYER_SUFFIXES:
            raise StoreFormatError(f"{layer}: the layer must be a USD file ({', '.join(LAYER_SUFFIXES)})")
        _writable_folder(layer, "layer")
        if layer.resolve() == output.resolve():
            raise StoreFormatError(f"{layer}: the layer and the store must be different files")
        if str(layer.resolve()) in inputs:
            raise StoreFormatError(f"{layer}: is an input of this bake; choose another --layer")


def plan_bake(request: BakeRequest, source: Source | None = None,
              previous: StoreContents | None = None) -> tuple[Source, Plan]:
    """The source and plan of a request: reuse decisions against ``previous``, batches; nothing is written."""
    source = source or source_for(request.sources, request.layout, request.capture)
    source_plan = source.plan(request.settings, previous)
    source.validate_outputs(request)
    batch_size = request.batch_size or source.default_batch_size
    plan = plan_tasks(source.kind, source_plan, request.settings, previous, batch_size)
    if previous is not None and plan.reused:
        again, attributes = source.rebake(previous, plan.reused)
        if again:
            plan.reused = [n for n in plan.reused if n not in again]
            plan.batches = make_batches(plan.pending_tasks(), batch_size, request.settings.as_json())
            plan.attributes.update(attributes)
    return source, plan


def _reemit(batch: EncodedBatch) -> None:
    for record in batch.warnings:
        category = getattr(bakery.errors, record.category, BakeryWarning)
        if not (isinstance(category, type) and issubclass(category, BakeryWarning)):
            category = BakeryWarning
        warnings.warn(record.message, category, stacklevel=3)


def bake(request: BakeRequest, executor: Executor | None = None,
         progress: Callable[[int, int], None] | None = None) -> BakeSummary:
    """Bake ``request`` on ``executor`` (default: in-process serial) and write the store (and the source's other
    outputs, e.g. the USD layer) atomically.

    Probes whose capture failed are left out of the store and reported in ``failed``; everything else is written.
    If no probe could be baked, nothing is written and :class:`InputError` is raised. Warnings raised in workers are
    re-emitted here (and recorded in the store's ``warnings``).
    """
    start = time.perf_counter()
    executor = executor or SerialExecutor()
    source = source_for(request.sources, request.layout, request.capture)
    check_output_paths(request, source)
    previous = load_previous(request.output) if request.resume else None
    source, plan = plan_bake(request, source, previous)
    settings = request.settings

    journal = Journal(request.output)
    done = journal.load({b.key for b in plan.batches}) if request.resume else {}
    outcomes = list(done.values())
    total = plan.to_bake
    finished = sum(len(b.probes) for b in plan.batches if b.key in done)
    if progress:
        progress(finished, total)
    todo = [b for b in plan.batches if b.key not in done]
    if todo:
        handle = source.prepare(journal.directory)
        size_of = {b.key: len(b.probes) for b in plan.batches}
        for outcome in executor.run([replace(b, source=handle) for b in todo]):
            journal.save(outcome)
            outcomes.append(outcome)
            finished += size_of[outcome.key]
            if progress:
                progress(finished, total)

    failures: dict[str, str] = {}
    batches = []
    for outcome in outcomes:
        failures.update(outcome.failures)
        if outcome.result is not None:
            batches.append(outcome.result)
    if plan.reused and previous is not None:
        batches.append(extract_probes(previous, plan.reused))
    if failures and not batches:
        journal.remove()
        first = next(iter(failures.values()))
        raise InputError(f"no probe could be baked; nothing was written. First failure: {first}"
                         if len(failures) > 1 else first)
    # No probe at all (a scene without probes, or none with an applicable encoding): an empty, valid store.
    merged = (merge_batches(batches, [n for n in plan.order if n not in failures]) if batches
              else EncodedBatch([], {}, {}, {}))
    _reemit(merged)
    skipped = list(plan.skipped) + apply_band_skips(merged, request.band_energy_tolerance)
    encodings = finalize_encodings(merged, settings)
    hash_of = {t.probe.name: t.content_hash for t in plan.tasks}
    history, bake_ids = remap_history(previous, plan.reused, merged.probes)
    attributes = {
        **plan.attributes, "failed_probes": json.dumps(failures, sort_keys=True),
        "skipped": json.dumps(skipped, sort_keys=True),
        "band_energy_tolerance": request.band_energy_tolerance or DEFAULT_BAND_TOLERANCE,
        "band_skipping": request.band_energy_tolerance is not None,
    }
    contents = store_contents(merged, settings, encodings, attributes,
                              probe_hashes=[hash_of[p.name] for p in merged.probes], history=history,
                              bake_ids=bake_ids, layers=plan.layers)
    write_store(request.output, contents)
    extra = source.after_write(merged, contents, request)
    journal.remove()

    seconds = time.perf_counter() - start
    baked = total - len(failures)
    timings = dict(merged.timings)
    rays, capture_seconds = timings.get("capture_rays", 0.0), timings.get("capture_seconds", 0.0)
    if rays:
        timings["rays_per_second"] = rays / capture_seconds if capture_seconds > 0 else 0.0
    return BakeSummary(
        store=str(request.output), planned=len(plan.tasks), baked=baked, reused=len(plan.reused),
        resumed_batches=len(done), failed=failures, skipped=skipped, batches=len(plan.batches),
        workers=getattr(executor, "workers", 1), executor=getattr(executor, "name", "?"), seconds=seconds,
        probes_per_second=baked / seconds if seconds > 0 else 0.0, store_bytes=request.output.stat().st_size,
        bytes_per_probe={n: e.bytes_per_probe() for n, e in encodings.items()}, source_kind=source.kind,
        settings_hash=settings.hash(), layer=extra.get("layer"), issues=list(plan.issues), timings=timings,
        warnings=[w.message for w in merged.warnings],
        reference_error={k.split("/", 1)[1]: float(np.nanmean(v)) for k, v in merged.diagnostics.items()
                         if k.startswith("reference_error/") and np.any(np.isfinite(v))},
    )
