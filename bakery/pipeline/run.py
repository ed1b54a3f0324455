"""Planning environment bakes and executing any plan: journal, incremental reuse, single writer."""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bakery.bake import BakeSettings, EncodedBatch, instantiate_encoding, merge_batches, store_contents
from bakery.encodings import ENCODINGS, get_encoding
from bakery.errors import InputError, StoreFormatError
from bakery.pipeline.journal import Journal
from bakery.pipeline.plan import CaptureSpec, Plan, ProbeTask, make_batches, probe_content_hash
from bakery.pipeline.skip import band_skip_decisions

#: Default ε of band skipping: a band is dropped only where the bands above carry < 1e-6 of the irradiance energy
#: (≈ 0.1% RMS irradiance), i.e. where they carry no visible energy.
DEFAULT_BAND_TOLERANCE = 1e-6
from bakery.probe import PROBE_KINDS, Probe
from bakery.store.format import StoreContents, read_store, write_store


def file_hash(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def load_previous(output: str | Path) -> StoreContents | None:
    """The existing store at ``output``, if it is a readable store (else None: a full bake)."""
    try:
        return read_store(output) if Path(output).is_file() else None
    except StoreFormatError:
        return None


def encodings_for(probe: Probe, settings: BakeSettings) -> tuple[str, ...]:
    """Encodings a probe gets: the per-probe override, else the settings' list, else every registered one of its
    kinds; always restricted to the probe's kinds (skip what the probe kind does not need)."""
    requested = tuple(probe.settings.get("encodings", ())) or settings.encodings or tuple(ENCODINGS)
    return tuple(n for n in requested if get_encoding(n).kind in probe.kinds)


def plan_tasks(
    probes_and_captures: list[tuple[Probe, CaptureSpec]], settings: BakeSettings, previous: StoreContents | None,
    batch_size: int = 64,
) -> Plan:
    """Content hashes, reuse decisions against ``previous`` and batches for the given probes."""
    tasks: list[ProbeTask] = []
    skipped: list[dict[str, str]] = []
    for probe, capture in probes_and_captures:
        encodings = encodings_for(probe, settings)
        if not encodings:
            skipped.append({"probe": probe.name, "reason": f"no requested encoding applies to kinds {probe.kinds}"})
            continue
        tasks.append(ProbeTask(probe, capture, encodings, probe_content_hash(probe, capture, encodings,
                                                                             settings.hash())))
    reused: list[str] = []
    if previous is not None and previous.probe_hashes is not None:
        old = dict(zip(previous.probe_names, previous.probe_hashes))
        reused = [t.probe.name for t in tasks if t.content_hash and old.get(t.probe.name) == t.content_hash]
    reused_set = set(reused)
    batches = make_batches([t for t in tasks if t.probe.name not in reused_set], batch_size, settings.as_json())
    return Plan(tasks, batches, reused, skipped)


def plan_environment_bake(
    sources: list[Path], settings: BakeSettings, previous: StoreContents | None, layout: str | None = None,
    batch_size: int = 16,
) -> Plan:
    """One distant probe of every kind per image: ``/environment`` (one image) or ``/environment/<stem>``."""
    entries = []
    for path in sources:
        name = "/environment" if len(sources) == 1 else f"/environment/{path.stem}"
        inputs = (file_hash(path),) if path.is_file() else ()
        capture = CaptureSpec("environment", str(path), inputs, (("layout", layout),))
        entries.append((Probe(name, PROBE_KINDS), capture))
    return plan_tasks(entries, settings, previous, batch_size)


def extract_probes(contents: StoreContents, names: list[str]) -> EncodedBatch:
    """The stored results of ``names`` as an :class:`EncodedBatch` (for incremental reuse)."""
    index = {n: i for i, n in enumerate(contents.probe_names)}
    picked = np.array([index[n] for n in names], dtype=np.int64)
    probes = [Probe(contents.probe_names[i], tuple(contents.probe_kinds[i].split(",")),
                    tuple(map(float, contents.probe_positions[i]))) for i in picked]
    position = {int(i): r for r, i in enumerate(picked)}
    encoded, rows = {}, {}
    for name, entry in contents.encodings.items():
        probe_index = entry["fields"]["probe_index"]
        keep = np.array([r for r, i in enumerate(probe_index) if int(i) in position], dtype=np.int64)
        if keep.size == 0:
            continue
        rows[name] = np.array([position[int(probe_index[r])] for r in keep], dtype=np.int64)
        encoded[name] = {k: v[keep] for k, v in entry["fields"].items() if k != "probe_index"}
    diagnostics = {k: v[picked] for k, v in contents.diagnostics.items()
                   if np.ndim(v) >= 1 and len(v) == len(contents.probe_names)}
    return EncodedBatch(probes, encoded, rows, diagnostics)


@dataclass
class BakeSummary:
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
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    #: mean over probes of the relative RMSE against the exact irradiance, per irradiance encoding
    reference_error: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def execute_plan(
    plan: Plan, settings: BakeSettings, output: str | Path, executor, previous: StoreContents | None = None,
    resume: bool = True, progress: Callable[[int, int], None] | None = None, attributes: dict | None = None,
    layers: str = "", on_written: Callable[[EncodedBatch, dict[str, Any]], None] | None = None,
    band_energy_tolerance: float | None = DEFAULT_BAND_TOLERANCE,
) -> BakeSummary:
    """Run ``plan`` on ``executor``, checkpointing each finished batch, and write the store atomically.

    Probes whose capture failed are left out of the store and reported in ``failed`` (the caller's exit code says
    so); everything else is written. If no probe could be baked, nothing is written and :class:`InputError` is
    raised. ``band_energy_tolerance=None`` disables band skipping (explicitly requested encodings). ``on_written`` is called with the merged results after the store is written
    (the USD layer writer).
    """
    start = time.perf_counter()
    output = Path(output)
    directory = output.parent if str(output.parent) else Path(".")
    if not directory.is_dir():
        raise StoreFormatError(f"{output}: output directory {directory} does not exist")
    if output.is_dir():
        raise StoreFormatError(f"{output}: is a directory; give a file name for the store")
    journal = Journal(output)
    keys = {b.key for b in plan.batches}
    done = journal.load(keys) if resume else {}
    outcomes = list(done.values())
    total = sum(len(b.probes) for b in plan.batches)
    finished = sum(len(b.probes) for b in plan.batches if b.key in done)
    if progress:
        progress(finished, total)
    todo = [b for b in plan.batches if b.key not in done]
    size_of = {b.key: len(b.probes) for b in plan.batches}
    if todo:
        for outcome in executor.run(todo):
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
    if failures and not batches and not plan.reused:
        journal.remove()
        first = next(iter(failures.values()))
        raise InputError(f"no probe could be baked; nothing was written. First failure: {first}"
                         if len(failures) > 1 else first)
    order = [n for n in plan.order if n not in failures]
    merged = merge_batches(batches, order) if batches else EncodedBatch([], {}, {}, {})
    skipped = list(plan.skipped)
    if "band_energy" in merged.diagnostics:
        energy = np.asarray(merged.diagnostics["band_energy"], dtype=np.float64)
        has = np.all(np.isfinite(energy), axis=1)
        positions = np.array([p.position for p in merged.probes], dtype=np.float64).reshape(-1, 3)
        required, skips = band_skip_decisions(energy[has], positions[has],
                                              band_energy_tolerance or DEFAULT_BAND_TOLERANCE, list(merged.encoded))
        if band_energy_tolerance is None:  # encodings were asked for explicitly: report, do not skip
            skips = []
        required_all = np.full(len(merged.probes), np.nan, dtype=np.float32)
        required_all[has] = required
        merged.diagnostics["required_band"] = required_all
        for skip in skips:
            merged.encoded.pop(skip["encoding"], None)
            merged.rows.pop(skip["encoding"], None)
            for key in [k for k in merged.diagnostics if k.endswith("/" + skip["encoding"])]:
                del merged.diagnostics[key]
        skipped += skips
    instances = {name: instantiate_encoding(name, settings) for name in merged.encoded}
    hash_of = {t.probe.name: t.content_hash for t in plan.tasks}
    history: list[dict[str, str]] = []
    bake_ids = None
    if plan.reused and previous is not None:
        # Keep the history entries of reused probes; this bake is appended last by store_contents.
        old_ids = dict(zip(previous.probe_names, previous.probe_bake_ids))
        used = sorted({int(old_ids[n]) for n in plan.reused})
        remap = {old: new for new, old in enumerate(used)}
        history = [previous.history[i] for i in used] if previous.history else []
        reused = set(plan.reused)
        bake_ids = np.array([remap[int(old_ids[p.name])] if p.name in reused else len(history)
                             for p in merged.probes], dtype=np.int32)
    contents = store_contents(
        merged, settings, instances,
        {**(attributes or {}), "failed_probes": json.dumps(failures, sort_keys=True),
         "skipped": json.dumps(skipped, sort_keys=True),
         "band_energy_tolerance": band_energy_tolerance or DEFAULT_BAND_TOLERANCE,
         "band_skipping": band_energy_tolerance is not None},
        probe_hashes=[hash_of[p.name] for p in merged.probes], history=history, bake_ids=bake_ids, layers=layers,
    )
    write_store(output, contents)
    if on_written is not None:
        on_written(merged, contents.attributes)
    journal.remove()
    seconds = time.perf_counter() - start
    baked = total - len(failures)
    return BakeSummary(
        store=str(output), planned=len(plan.tasks), baked=baked, reused=len(plan.reused),
        resumed_batches=len(done), failed=failures, skipped=skipped, batches=len(plan.batches),
        workers=getattr(executor, "workers", 1), executor=getattr(executor, "name", "?"), seconds=seconds,
        probes_per_second=baked / seconds if seconds > 0 else 0.0, store_bytes=output.stat().st_size,
        bytes_per_probe={n: e.bytes_per_probe() for n, e in instances.items()}, timings=merged.timings,
        warnings=merged.warnings,
        reference_error={k.split("/", 1)[1]: float(np.nanmean(v)) for k, v in merged.diagnostics.items()
                         if k.startswith("reference_error/") and np.any(np.isfinite(v))},
    )
