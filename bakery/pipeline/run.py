"""The one bake path: plan → check outputs → execute → merge → finalize → write. The CLI, :func:`bakery.bake`, the
benchmarks and the conformance suite all call :func:`bake`.

    source = source_for(request.sources)                    # environment images, a USD scene, in-memory cubes
    plan   = plan_bake(request, source)                     # content hashes, reuse, batches (no writes)
    outcomes = executor.run(batches)                        # workers: Source.capture → encode_batch
    merged = merge_batches(outcomes + reused probes)        # store order; band skips; finalize over all probes
    write_store(...); source.after_write(...)               # the single writer; then e.g. the USD layer

Reliability (``docs/reliability.md``)
    * Output policy (:func:`check_output_paths`), before any work: a bake writes its store only to a new path or
      over a bakery store of a format this bakery writes, and its layer only to a new path or over a bakery layer;
      anything else (a scene, an image, a text file, a foreign HDF5 file, a newer-format or unreadable store) is
      refused with :class:`~bakery.files.OutputError` (exit 2) naming the file and the reason, unless
      ``request.force`` — which never overwrites an input of the bake.
    * One writer per store: :class:`~bakery.files.FileLock` on ``STORE.h5.lock`` for the whole bake.
    * Repair on entry (holding the lock): a store/layer commit a crash interrupted is completed, temporary files of
      killed runs are removed.
    * The previous store is read with its checksums verified; probes that fail them are re-baked, never reused.
    * Non-finite encoded values (finite but huge inputs overflowing float32) are refused per probe (reported as
      failed probes), never stored.
    * The store and the layer are written to temporary names and committed together
      (:func:`bakery.files.commit_staged`): store first, then layer, through a commit record.
    * Every ``OSError`` (permissions, read-only or full file system) becomes an ``OutputError`` naming the file;
      temporary files are removed on every exit path (also SIGTERM).

Finished batches are checkpointed in ``<store>.partial/`` (:mod:`bakery.pipeline.journal`), beside the snapshot
workers read; the folder is removed once the store is written.
"""

from __future__ import annotations

import json
import os
import shutil
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

import bakery.errors
from bakery.errors import BakeryWarning, InputError, StoreFormatError
from bakery.files import (
    FileLock,
    OutputError,
    check_output_file,
    commit_staged,
    os_error_message,
    recover_staged,
    remove_stale_temporaries,
    remove_temporaries_under,
    same_file,
    staged_path,
    terminate_as_exit as _terminate_as_exit,
    with_filename,
)
from bakery.pipeline.background import BackgroundCall
from bakery.pipeline.dilate import dilate_volumes
from bakery.pipeline.encode import EncodedBatch
from bakery.pipeline.executors import Executor, SerialExecutor
from bakery.pipeline.journal import Journal
from bakery.pipeline.merge import (
    BACKFACE_KEY,
    DEFAULT_BAND_TOLERANCE,
    INSIDE_BACKFACE_FRACTION,
    apply_band_skips,
    extract_probes,
    finalize_encodings,
    inside_geometry_warning,
    merge_batches,
    remap_history,
)
from bakery.pipeline.plan import BatchTask, Plan, make_batches, plan_tasks
from bakery.pipeline.settings import BakeRequest
from bakery.pipeline.worker import BatchOutcome
from bakery.pipeline.write import store_contents
from bakery.sources import Source, source_for
from bakery.store.format import (
    StoreContents,
    StoreIntegrityWarning,
    overwrite_refusal,
    read_store,
    write_store_file,
)
from bakery.zero_pages import spilled, without_resident_zeros

STORE_SUFFIXES = (".h5", ".hdf5")
LAYER_SUFFIXES = (".usda", ".usdc", ".usd")
#: The comment every baked-results layer carries (``bakery.usd.layer.write_bake_layer``); an existing file at the
#: layer path is a previous bakery layer iff it holds this text (``.usda`` header or ``.usdc`` string table).
BAKE_LAYER_MARKER = b"Baked light probes written by bakery"
#: Warning categories (class names) re-emitted to the user but not recorded in the store's ``warnings``.
MACHINE_WARNINGS = frozenset({"OperatorCacheWarning"})


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


def load_previous(output: str | Path, *, warn: bool = True) -> StoreContents | None:
    """The existing store at ``output`` for reuse, or None (a full bake) if there is none or it is not a readable
    store. Its checksums are verified: probes that fail them lose their content hash (so they are re-baked, never
    reused) and a finding that cannot be attributed to probes discards the whole store; both are warned about."""
    output = Path(output)
    try:
        previous = read_store(output, strict=False) if output.is_file() else None
    except StoreFormatError as error:
        if warn and overwrite_refusal(output) is None:  # our own store, damaged beyond reading
            warnings.warn(f"{error}; re-baking every probe", StoreIntegrityWarning, stacklevel=2)
        return None
    if previous is None or previous.integrity is None or previous.integrity.ok:
        return previous
    integrity = previous.integrity
    findings = "; ".join(integrity.problems[:3]) + (" …" if len(integrity.problems) > 3 else "")
    if integrity.whole_store or previous.probe_hashes is None:
        if warn:
            warnings.warn(f"{output}: the previous store failed its integrity check ({findings}); nothing is reused, "
                          "every probe is re-baked", StoreIntegrityWarning, stacklevel=2)
        return None
    previous.probe_hashes = ["" if n in integrity.bad_probes else h
                             for n, h in zip(previous.probe_names, previous.probe_hashes)]
    if warn:
        warnings.warn(f"{output}: {len(integrity.bad_probes)} probe(s) of the previous store failed their checksum "
                      f"({findings}); they are re-baked, not reused", StoreIntegrityWarning, stacklevel=2)
    return previous


def source_inputs(source: Source) -> list[Path]:
    """Files the bake reads that no output may replace (images, the scene and, once planned, its layers)."""
    paths = [Path(p) for p in getattr(source, "paths", ())]
    if getattr(source, "path", None) is not None:
        paths.append(Path(source.path))
    paths += [Path(p) for p in getattr(source, "_protected", ())]
    return paths


def layer_overwrite_refusal(path: Path) -> str | None:
    """Why an existing file must not be replaced by a baked-results layer (None: it is one)."""
    try:
        with open(path, "rb") as handle:
            found = _contains(handle, BAKE_LAYER_MARKER, limit=256 << 20)
    except OSError as error:
        return f"exists and cannot be read ({os_error_message(error)})"
    return None if found else "exists and is not a bakery baked-results layer"


def _contains(handle, marker: bytes, limit: int, chunk: int = 1 << 20) -> bool:  # noqa: ANN001
    """Whether ``marker`` occurs in the first ``limit`` bytes of ``handle``, read in ``chunk``-sized pieces (one
    256 MB read allocated 256 MB on every bake, whatever the layer's size)."""
    tail, read = b"", 0
    while read < limit:
        data = handle.read(min(chunk, limit - read))
        if not data:
            return False
        window = tail + data
        if marker in window:
            return True
        tail, read = window[max(0, len(window) - len(marker) + 1):], read + len(data)
    return False


def layer_path_of(request: BakeRequest, source: Source) -> Path | None:
    """The USD layer a bake writes: ``--layer``, else the source's default (scenes), else None."""
    if request.layer is not None:
        return Path(request.layer)
    path_of = getattr(source, "layer_path", None)
    return Path(path_of(request)) if callable(path_of) else None


def check_store_output(output: Path, inputs: list[Path] = (), force: bool = False) -> None:  # type: ignore[assignment]
    """The output policy for a store path (also ``bakery migrate -o``): an ``.h5``/``.hdf5`` file in a writable
    folder, not an input, and either new or a bakery store of a format this bakery writes (``force``: anything
    but an input)."""
    output = Path(output)
    if output.suffix.lower() not in STORE_SUFFIXES:
        raise OutputError(f"{output}: the store must be an HDF5 file ({' or '.join(STORE_SUFFIXES)}); refusing to "
                          "write a store there")
    check_output_file(output, "store", inputs=inputs, refusal=overwrite_refusal, force=force)


def check_output_paths(request: BakeRequest, source: Source) -> None:
    """Before any work: the output policy (module docstring) for the store and the layer."""
    output = request.output
    inputs = source_inputs(source)
    check_store_output(output, inputs, request.force)
    layer = layer_path_of(request, source)
    if layer is not None:
        if layer.suffix.lower() not in LAYER_SUFFIXES:
            raise LayerOutputError(f"{layer}: the layer must be a USD file ({', '.join(LAYER_SUFFIXES)})")
        if layer.resolve() == output.resolve():
            raise LayerOutputError(f"{layer}: the layer and the store must be different files")
        try:
            check_output_file(layer, "layer", inputs=[*inputs, output],
                              refusal=lambda path: layer_overwrite_refusal(path) or _other_store_layer(path, output),
                              force=request.force)
        except OutputError as error:
            raise LayerOutputError(str(error)) from None


def _other_store_layer(layer: Path, store: Path) -> str | None:
    """Why a bakery layer must not be replaced by this store's: it records another store that still exists
    (``--layer`` naming another bake's layer, or ``x.h5`` and ``x.hdf5`` sharing ``x.bake.usda``)."""
    from bakery.usd.layer import recorded_store

    recorded = recorded_store(layer)
    if recorded is None or not recorded.exists() or same_file(recorded, Path(store)):
        return None
    return (f"is the baked-results layer of the store {recorded.name}, not of {Path(store).name} (another bake's "
            f"results; choose another --layer)")


class LayerOutputError(OutputError, bakery.errors.SceneError):
    """The USD layer path is refused by the output policy (also a :class:`~bakery.errors.SceneError`, what a
    refused layer raised before the policy existed)."""


def plan_bake(request: BakeRequest, source: Source | None = None,
              previous: StoreContents | None = None) -> tuple[Source, Plan]:
    """The source and plan of a request: reuse decisions against ``previous``, batches; nothing is written."""
    source = source or source_for(request.sources, request.layout, request.capture)
    source_plan = source.plan(request.settings, previous)
    source.validate_outputs(request)
    check_output_paths(request, source)  # again: planning knows more inputs (a scene's layers)
    batch_size = request.batch_size or source.default_batch_size
    plan = plan_tasks(source.kind, source_plan, request.settings, previous, batch_size)
    if previous is not None and plan.reused:
        again, attributes = rebake_per_bake(source, previous, plan.reused)
        if again:
            plan.reused = [n for n in plan.reused if n not in again]
            plan.batches = make_batches(plan.pending_tasks(), batch_size, request.settings.as_json())
            plan.attributes.update(attributes)
    return source, plan


#: Source attributes recorded per bake in ``/history`` so that later bakes compare reused probes with what they were
#: baked from (:func:`rebake_per_bake`).
PER_BAKE_ATTRIBUTES = ("scene_lights",)


def rebake_per_bake(source: Source, previous: StoreContents, reused: list[str]) -> tuple[set[str], dict[str, Any]]:
    """``Source.rebake`` for each group of reused probes produced by the same earlier bake, each against that
    bake's own record of :data:`PER_BAKE_ATTRIBUTES` (``/history``) where the store has one: a probe is compared
    with the lights it was baked with, not with the last bake's, so repeated small edits cannot accumulate."""
    ids = dict(zip(previous.probe_names, (int(i) for i in previous.probe_bake_ids)))
    groups: dict[tuple[str, ...], list[str]] = {}
    for name in reused:
        bake = previous.history[ids[name]] if 0 <= ids.get(name, -1) < len(previous.history) else {}
        groups.setdefault(tuple(str(bake.get(k, "")) for k in PER_BAKE_ATTRIBUTES), []).append(name)
    again: set[str] = set()
    attributes: dict[str, Any] = {}
    for recorded, names in groups.items():
        own = {k: v for k, v in zip(PER_BAKE_ATTRIBUTES, recorded) if v}
        view = replace(previous, attributes={**previous.attributes, **own}) if own else previous
        affected, notes = source.rebake(view, names)
        again |= set(affected)
        for key, value in notes.items():
            try:
                merged = sorted(set(json.loads(attributes[key])) | set(json.loads(value)))
                attributes[key] = json.dumps(merged)
            except (KeyError, TypeError, ValueError):
                attributes[key] = value
    return again, attributes


def _reemit(batch: EncodedBatch) -> None:
    for record in batch.warnings:
        category = getattr(bakery.errors, record.category, BakeryWarning)
        if not (isinstance(category, type) and issubclass(category, BakeryWarning)):
            category = BakeryWarning
        warnings.warn(record.message, category, stacklevel=3)


# --- parent-side tail, shared by bake() and bakery.pipeline.shards.merge_shards (issue 16) -------------------------
def finalize_and_write(request: BakeRequest, source: Source, plan: Plan, batches: list[EncodedBatch],
                       failures: dict[str, str], previous: StoreContents | None, spill: Path | None = None,
                       ) -> tuple[EncodedBatch, StoreContents, dict[str, Any], list[dict[str, str]], dict[str, Any]]:
    """The parent-side steps that need every probe: merge ``batches`` (worker results and reused probes) into plan
    order, re-emit worker warnings, band skipping refined over neighbours, each encoding's ``finalize`` over every
    probe, then write the store and the source's other outputs (e.g. the USD layer) together
    (:func:`commit_outputs`). Probes with non-finite encoded values are moved to ``failures`` first
    (:func:`refuse_non_finite`). The caller holds the store's lock (:func:`locked_outputs`).

    Returns (merged, contents, encodings, skipped, extra outputs). :func:`bake` calls it after its executor;
    ``bakery merge`` calls it on the results of shard stores, so a merged farm bake is the same bytes as one
    process's. ``batches`` is emptied once merged, and each batch's fields are released as they are merged: from
    there on the merged copy is all the parent holds of them (its peak memory is the merged fields plus the one
    being merged, not the merge plus the batches). ``spill``: the folder where the large merged fields are sparse
    files (:func:`bakery.pipeline.merge.merge_batches`)."""
    settings = request.settings
    given, batches = batches, refuse_non_finite(batches, failures)
    if failures and not batches:
        first = next(iter(failures.values()))
        raise InputError(f"no probe could be baked; nothing was written. First failure: {first}"
                         if len(failures) > 1 else first)
    # No probe at all (a scene without probes, or none with an applicable encoding): an empty, valid store.
    merged = (merge_batches(batches, [n for n in plan.order if n not in failures], release_inputs=True,
                            scratch=spill) if batches else EncodedBatch([], {}, {}, {}))
    given.clear()
    batches.clear()
    planned = {task.probe.name: task.probe for task in plan.tasks}  # reused probes come back without their settings
    merged.probes = [planned.get(probe.name, probe) for probe in merged.probes]
    _reemit(merged)
    # Warnings about this machine rather than the results (a rebuilt operator cache) are shown, not stored: the
    # store must not depend on the state of the machine that baked it.
    merged.warnings = [w for w in merged.warnings if w.category not in MACHINE_WARNINGS]
    for record in dilate_volumes(merged, settings):  # probes inside geometry, from their volume's valid probes
        merged.warnings.append(record)
        warnings.warn(record.message, bakery.errors.SceneWarning, stacklevel=2)
    inside = inside_geometry_warning(merged)  # probe validity: recorded in the store's warnings, shown
    if inside is not None:
        merged.warnings.append(inside)
        warnings.warn(inside.message, bakery.errors.SceneWarning, stacklevel=2)
    reused = set(plan.reused)  # what a reused probe's previous bake skipped is reported skipped again
    skipped = list(plan.skipped) + apply_band_skips(
        merged, request.band_energy_tolerance, {e for t in plan.tasks if t.probe.name in reused for e in t.encodings})
    encodings = finalize_encodings(merged, settings)
    hash_of = {t.probe.name: t.content_hash for t in plan.tasks}
    history, bake_ids = remap_history(previous, plan.reused, merged.probes)
    attributes = {
        **plan.attributes, "failed_probes": json.dumps(failures, sort_keys=True),
        "skipped": json.dumps(skipped, sort_keys=True),
        "band_energy_tolerance": request.band_energy_tolerance or DEFAULT_BAND_TOLERANCE,
        "band_skipping": request.band_energy_tolerance is not None,
    }
    if BACKFACE_KEY in merged.diagnostics:  # the validity threshold the warning and inspect apply
        attributes["inside_geometry_backface_fraction"] = INSIDE_BACKFACE_FRACTION
    contents = store_contents(merged, settings, encodings, attributes,
                              probe_hashes=[hash_of[p.name] for p in merged.probes], history=history,
                              bake_ids=bake_ids, layers=plan.layers)
    if len(contents.history) > len(history):  # this bake produced probes and was appended (write.store_contents)
        this_bake = dict(contents.history[-1])
        for key in PER_BAKE_ATTRIBUTES:
            if key in plan.attributes:
                this_bake[key] = str(plan.attributes[key])
        contents.history[-1] = this_bake
    extra = commit_outputs(request, source, merged, contents)
    return merged, contents, encodings, skipped, extra
# --- end of the shared parent-side tail ------------------------------------------------------------------------


def commit_record_path(output: Path) -> Path:
    """The commit record of a store's staged commit (:func:`bakery.files.commit_staged`)."""
    output = Path(output)
    return output.with_name(f".{output.name}.commit")


def recover_outputs(request: BakeRequest, source: Source) -> list[str]:
    """With the store's lock held: finish a store/layer commit a crash interrupted and remove the temporary files
    killed runs left (beside the store and the layer, and in the journal folder). Returns notes for warnings."""
    notes = []
    finished = recover_staged(commit_record_path(request.output))
    if finished:
        notes.append(f"completed the interrupted commit of {', '.join(str(p) for p in finished)} (a previous bake "
                     "was killed between writing the store and the layer)")
    removed = remove_stale_temporaries(request.output, keep_live=False)  # we hold the lock: all are stale
    layer = layer_path_of(request, source)
    if layer is not None:
        removed += remove_stale_temporaries(layer)
    removed += remove_temporaries_under(Journal(request.output).directory)
    if removed:
        notes.append(f"removed {len(removed)} temporary file(s) of an interrupted run "
                     f"({', '.join(p.name for p in removed[:3])}{' …' if len(removed) > 3 else ''})")
    return notes


def _is_usd_error(error: BaseException) -> bool:
    return type(error).__module__.startswith("pxr")


def _usd_reason(error: BaseException, path: Path) -> str:
    """The end of a USD (Tf) error message, and the cause USD does not report: a full or read-only folder."""
    lines = [line.strip() for line in str(error).strip().splitlines() if line.strip()]
    reason = lines[-1].rsplit(" : ", 1)[-1].strip("'") if lines else type(error).__name__
    folder = path.parent if str(path.parent) else Path(".")
    try:
        stats = os.statvfs(folder)
        if stats.f_flag & os.ST_RDONLY:
            reason += " (Read-only file system)"
        elif stats.f_bavail * stats.f_frsize < (1 << 20):
            reason += f" (No space left on device: {stats.f_bavail * stats.f_frsize // 1024} KiB free)"
    except OSError:
        pass
    return reason


def _non_finite_probes(batch: EncodedBatch) -> dict[str, str]:
    """Probes of ``batch`` with a non-finite value in any float field of any encoding → the reason."""
    bad: dict[str, str] = {}
    for name in sorted(batch.encoded):
        rows = np.asarray(batch.rows[name])
        for key in sorted(batch.encoded[name]):
            values = np.asarray(batch.encoded[name][key])
            if values.dtype.kind not in "fc" or values.size == 0:
                continue
            finite = np.isfinite(values).reshape(len(values), -1).all(axis=1)
            for r in np.flatnonzero(~finite).tolist():
                probe = batch.probes[int(rows[r])].name
                count = int(np.sum(~np.isfinite(values[r])))
                bad.setdefault(probe, f"{probe}: encoding {name} produced {count} non-finite value(s) in {key} "
                                      "(the input radiance overflows float32, max 3.4e38); the probe was not stored")
    return bad


def refuse_non_finite(batches: list[EncodedBatch], failures: dict[str, str]) -> list[EncodedBatch]:
    """``batches`` without the probes whose encoded values are not finite; those are added to ``failures`` (the
    store never holds inf/NaN: a finite but huge input overflows float32 in the projection)."""
    out = []
    for batch in batches:
        refused = _non_finite_probes(batch)
        failures.update(refused)
        kept = _without_probes(batch, set(refused)) if refused else batch
        if kept is not None:
            out.append(kept)
    return out


def _without_probes(batch: EncodedBatch, names: set[str]) -> EncodedBatch | None:
    """``batch`` without the named probes (None if none is left)."""
    keep = np.array([i for i, p in enumerate(batch.probes) if p.name not in names], dtype=np.int64)
    if keep.size == 0:
        return None
    new_index = np.full(len(batch.probes), -1, dtype=np.int64)
    new_index[keep] = np.arange(keep.size)
    encoded, rows = {}, {}
    for name, fields in batch.encoded.items():
        old_rows = np.asarray(batch.rows[name])
        mask = new_index[old_rows] >= 0
        if not mask.any():
            continue
        rows[name] = new_index[old_rows[mask]]
        encoded[name] = {k: np.asarray(v)[mask] for k, v in fields.items()}

    def per_probe(values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {k: np.asarray(v)[keep] for k, v in values.items()}

    return EncodedBatch([batch.probes[i] for i in keep.tolist()], encoded, rows, per_probe(batch.diagnostics),
                        dict(batch.timings), list(batch.warnings), per_probe(batch.transient))


def bake(request: BakeRequest, executor: Executor | None = None,
         progress: Callable[[int, int], None] | None = None) -> BakeSummary:
    """Bake ``request`` on ``executor`` (default: in-process serial) and write the store (and the source's other
    outputs, e.g. the USD layer) atomically and together.

    Probes whose capture failed, or whose encoded values are not finite, are left out of the store and reported in
    ``failed``; everything else is written. If no probe could be baked, nothing is written and :class:`InputError`
    is raised. Warnings raised in workers are re-emitted here (and recorded in the store's ``warnings``). Output
    problems (policy, lock, file-system errors) raise :class:`~bakery.files.OutputError` and change nothing.
    """
    start = time.perf_counter()
    executor = executor or SerialExecutor()
    source = source_for(request.sources, request.layout, request.capture)
    check_output_paths(request, source)
    with locked_outputs(request, source):
        try:
            return _bake_locked(request, executor, progress, source, start)
        finally:  # the spilled fields are no checkpoints: a resumed bake spills again from those
            _remove_spilled(request)


def _remove_spilled(request: BakeRequest) -> None:
    """Remove the spill folder of ``request``'s work folder, if the work folder is one bakery may use (a real folder
    of this user: :class:`Journal`; never through a symbolic link)."""
    if SPILL_FOLDER is None:
        return
    try:
        journal = Journal(request.output)
    except OutputError:
        return
    shutil.rmtree(journal.directory / SPILL_FOLDER, ignore_errors=True)


@contextmanager
def locked_outputs(request: BakeRequest, source: Source) -> Iterator[FileLock]:
    """Hold the store's lock for a writer of ``request``'s outputs (a bake, ``bakery merge``): warn about a stale
    lock taken over, repair what a killed run left (:func:`recover_outputs`), turn SIGTERM into a clean exit and
    every ``OSError`` into an :class:`~bakery.files.OutputError` naming the file."""
    try:
        with FileLock(request.output) as lock, _terminate_as_exit():
            if lock.stale:
                warnings.warn(f"{request.output}: took over the lock of a bake that is no longer running "
                              f"({FileLock.describe(lock.stale)})", BakeryWarning, stacklevel=3)
            for note in recover_outputs(request, source):
                warnings.warn(f"{request.output}: {note}", BakeryWarning, stacklevel=3)
            yield lock
    except OSError as error:
        raise OutputError(f"{request.output}: the bake failed and the previous store and layer are unchanged: "
                          f"{os_error_message(error)}") from None


def _longest_first(batches: list[BatchTask], request: BakeRequest, source: Source, plan: Plan) -> list[BatchTask]:
    """``batches`` in decreasing estimated cost (:mod:`bakery.farm.cost`, the shipped calibration): the classic
    longest-processing-time order, so that no expensive batch starts last and leaves the other workers idle. The
    store does not depend on it (outcomes are merged in batch-key order)."""
    if len(batches) < 2:
        return batches
    from bakery.farm.cost import DEFAULT_CALIBRATION, CostModel, load_calibration

    model = CostModel(request, source, plan, load_calibration(DEFAULT_CALIBRATION))
    cost = {b.key: model.batch(b) for b in batches}
    return sorted(batches, key=lambda b: (-cost[b.key], b.key))


#: The folder of a bake's work folder (:class:`Journal`) where the parent keeps the large fields of the batches and
#: of their merge as sparse files (:func:`bakery.zero_pages.spilled`); None on Windows, which cannot remove a
#: mapped file (the fields then stay in memory, their zero rows not resident).
SPILL_FOLDER = None if os.name == "nt" else "fields"


def spill_folder(journal: Journal) -> Path | None:
    """Where this bake's parent spills its large fields (:data:`SPILL_FOLDER`), emptied of what a killed bake left
    there; None: kept in memory."""
    if SPILL_FOLDER is None:
        return None
    folder = journal.directory / SPILL_FOLDER
    shutil.rmtree(folder, ignore_errors=True)
    return folder


def _zero_rows_not_resident(outcome: BatchOutcome, spill: Path | None = None) -> BatchOutcome:
    """``outcome`` with its large encoded fields' all-zero rows not resident (:mod:`bakery.zero_pages`): the parent
    holds every batch until the merge, and a fixed-layout chain is mostly zero rows (a 128² hybrid probe stores
    2.6 MB with 2 gap levels, a hall's probe uploads ~0.6 MB of them). With ``spill`` (a folder), those fields are
    sparse files there instead (:func:`bakery.zero_pages.spilled`): page cache, not the parent's memory."""
    if outcome.result is not None:
        for encoding, fields in outcome.result.encoded.items():
            for key in list(fields):
                fields[key] = (without_resident_zeros(fields[key]) if spill is None else
                               spilled(fields[key], spill / f"{outcome.key}.{encoding}.{key}"))
    return outcome


def execute_batches(batches: list[BatchTask], request: BakeRequest, source: Source, plan: Plan, executor: Executor,
                    journal: Journal, progress: Callable[[int, int], None] | None, spill: Path | None = None,
                    ) -> tuple[list[BatchOutcome], int]:
    """Run ``batches`` on ``executor`` (longest first), checkpointing every outcome in ``journal``; with
    ``request.resume``, batches the journal already holds are not run again. Returns (every outcome, the number of
    resumed batches). Progress is reported in probes of ``batches``. ``spill``: :func:`_zero_rows_not_resident`."""
    done = journal.load({b.key for b in batches}) if request.resume else {}
    outcomes = [_zero_rows_not_resident(outcome, spill) for outcome in done.values()]
    total = sum(len(b.probes) for b in batches)
    finished = sum(len(b.probes) for b in batches if b.key in done)
    if progress:
        progress(finished, total)
    todo = _longest_first([b for b in batches if b.key not in done], request, source, plan)
    if todo:
        try:
            handle = source.prepare(journal.directory)  # the workers' snapshot (e.g. the scene), in the journal
        except OSError as error:
            raise with_filename(error, journal.directory) from None
        size_of = {b.key: len(b.probes) for b in todo}
        for outcome in executor.run([replace(b, source=handle) for b in todo]):
            journal.save(outcome)
            outcomes.append(_zero_rows_not_resident(outcome, spill))
            finished += size_of[outcome.key]
            if progress:
                progress(finished, total)
    return outcomes, len(done)


def reused_lacking_kept_encodings(request: BakeRequest, plan: Plan, previous: StoreContents | None,
                                  fresh: list[EncodedBatch]) -> set[str]:
    """Reused probes whose stored results lack one of their encodings that this bake keeps.

    Band skipping drops the band-2 encodings from a store when no probe needs band 2 (:mod:`bakery.pipeline.skip`).
    A later bake reuses those probes (their hashes are unchanged) and may keep the encodings — a probe moved next to
    a light now needs band 2, or ``band_energy_tolerance`` was lowered — and the reused probes have nothing to give
    them: until 2026-12-07 the store then held them for the probes baked now only (or for none, while reporting
    nothing skipped), where a clean bake holds them for every probe. The decision is the one
    :func:`finalize_and_write` takes, on the band energies of every probe (``fresh``: the batches baked now, and the
    reused probes' stored ones), after the volumes' dilation; the probes it leaves lacking are baked again."""
    if previous is None or not plan.reused:
        return set()
    index = {n: i for i, n in enumerate(previous.probe_names)}
    stored = {name: {int(i) for i in entry["fields"]["probe_index"]} for name, entry in previous.encodings.items()}
    wanted = {t.probe.name: t.encodings for t in plan.tasks}
    lacking = {n: {e for e in wanted[n] if index[n] not in stored.get(e, ())} for n in plan.reused}
    lacking = {n: missing for n, missing in lacking.items() if missing}
    if not lacking:
        return set()
    skipped: set[str] = set()
    if request.band_energy_tolerance is not None:
        # the probes and diagnostics alone (band energy, captured SH, backface fraction): what the decision reads
        light = [EncodedBatch(b.probes, {}, {}, b.diagnostics) for b in fresh]
        light.append(extract_probes(previous, plan.reused, encodings=False))
        names = {p.name for b in light for p in b.probes}
        trial = merge_batches(light, [n for n in plan.order if n in names])
        planned = {t.probe.name: t.probe for t in plan.tasks}
        trial.probes = [planned.get(p.name, p) for p in trial.probes]  # their settings (dilation)
        dilate_volumes(trial, request.settings)
        candidates = {e for missing in lacking.values() for e in missing}
        skipped = {s["encoding"] for s in apply_band_skips(trial, request.band_energy_tolerance, candidates)}
    return {n for n, missing in lacking.items() if missing - skipped}


def with_rates(timings: dict[str, float]) -> dict[str, float]:
    """``timings`` (summed over batches) with ``rays_per_second`` = capture rays / capture seconds (per worker)."""
    timings = dict(timings)
    rays, capture_seconds = timings.get("capture_rays", 0.0), timings.get("capture_seconds", 0.0)
    if rays:
        timings["rays_per_second"] = rays / capture_seconds if capture_seconds > 0 else 0.0
    return timings


def _bake_locked(request: BakeRequest, executor: Executor, progress: Callable[[int, int], None] | None,
                 source: Source, start: float) -> BakeSummary:
    start_workers = getattr(executor, "start", None)
    if start_workers is not None:  # the workers start (spawn, imports) while the parent reads and plans
        start_workers((type(source).__module__,))
    previous = load_previous(request.output) if request.resume else None
    source, plan = plan_bake(request, source, previous)
    settings = request.settings
    stage = {"parent/read_plan": time.perf_counter() - start}  # per-stage wall times of the parent (summary only)
    stage_start = time.perf_counter()

    journal = Journal(request.output)
    spill = spill_folder(journal)
    outcomes, resumed = execute_batches(plan.batches, request, source, plan, executor, journal, progress, spill)
    stage["parent/workers"] = time.perf_counter() - stage_start
    stage_start = time.perf_counter()
    failures: dict[str, str] = {}
    batches = []
    for outcome in sorted(outcomes, key=lambda o: o.key):
        failures.update(outcome.failures)
        if outcome.result is not None:
            batches.append(outcome.result)
    del outcomes  # the batches are all that is kept of them (finalize_and_write drops them once merged)
    batches = refuse_non_finite(batches, failures)
    while True:  # reused probes whose stored results lack an encoding this bake keeps are baked after all
        again = reused_lacking_kept_encodings(request, plan, previous, batches)
        if not again:
            break
        plan.reused = [n for n in plan.reused if n not in again]
        extra = make_batches([t for t in plan.tasks if t.probe.name in again],
                             request.batch_size or source.default_batch_size, settings.as_json())
        plan.batches = plan.batches + extra
        more, more_resumed = execute_batches(extra, request, source, plan, executor, journal, progress, spill)
        resumed += more_resumed
        fresh = []
        for outcome in sorted(more, key=lambda o: o.key):
            failures.update(outcome.failures)
            if outcome.result is not None:
                fresh.append(outcome.result)
        batches += refuse_non_finite(fresh, failures)
    if plan.reused and previous is not None:
        batches.append(extract_probes(previous, plan.reused))
    if failures and not batches:
        journal.remove()
        first = next(iter(failures.values()))
        raise InputError(f"no probe could be baked; nothing was written. First failure: {first}"
                         if len(failures) > 1 else first)
    merged, _contents, encodings, skipped, extra = finalize_and_write(request, source, plan, batches, failures,
                                                                      previous, spill)
    journal.remove()
    stage["parent/merge_finalize_write"] = time.perf_counter() - stage_start

    seconds = time.perf_counter() - start
    baked = plan.to_bake - len(failures)
    timings = with_rates(merged.timings) | stage
    return BakeSummary(
        store=str(request.output), planned=len(plan.tasks), baked=baked, reused=len(plan.reused),
        resumed_batches=resumed, failed=failures, skipped=skipped, batches=len(plan.batches),
        workers=getattr(executor, "workers", 1), executor=getattr(executor, "name", "?"), seconds=seconds,
        probes_per_second=baked / seconds if seconds > 0 else 0.0, store_bytes=request.output.stat().st_size,
        bytes_per_probe={n: e.bytes_per_probe() for n, e in encodings.items()}, source_kind=source.kind,
        settings_hash=settings.hash(), layer=extra.get("layer"), issues=list(plan.issues), timings=timings,
        warnings=[w.message for w in merged.warnings],
        reference_error={k.split("/", 1)[1]: float(np.nanmean(v)) for k, v in merged.diagnostics.items()
                         if k.startswith("reference_error/") and np.any(np.isfinite(v))},
    )


def commit_outputs(request: BakeRequest, source: Source, merged: EncodedBatch,
                   contents: StoreContents) -> dict[str, Any]:
    """Write the store and the layer to temporary names, then rename both into place through a commit record
    (:func:`bakery.files.commit_staged`: store first, then layer). Nothing is renamed unless both were written."""
    output = request.output
    layer = layer_path_of(request, source) if callable(getattr(source, "layer_path", None)) else None
    staged_store = staged_path(output)
    staged_layer = staged_path(layer, layer.suffix) if layer is not None else None
    try:
        pairs = [(staged_store, output)]
        if layer is not None:
            # The store (HDF5) and the layer (USD) are written side by side, the store in a forked child: h5py and
            # Sdf's export both hold the GIL, so two threads would write one after the other.
            store_writer = BackgroundCall(write_store_file, staged_store, contents)
            try:
                extra = source.after_write(merged, contents, replace(request, layer=staged_layer))
            except Exception as error:
                store_writer.exception()  # the store's writer is done before its file is removed
                if _is_usd_error(error) or isinstance(error, bakery.errors.SceneError):
                    raise OutputError(f"{layer}: USD could not write the layer: {_usd_reason(error, layer)}") \
                        from None
                raise
            else:
                store_writer.result()
            finally:
                store_writer.stop()  # SIGTERM, an error: no writer is left behind the staged files' removal
            extra["layer"] = str(layer)
            pairs.append((staged_layer, layer))
        else:
            write_store_file(staged_store, contents)
            extra = source.after_write(merged, contents, request)
        commit_staged(pairs, commit_record_path(output))
        return extra
    finally:
        for staged in (staged_store, staged_layer):
            if staged is not None and staged.exists():
                staged.unlink()
