"""Farm bakes without a Dask cluster: a plan split into shards baked by independent processes, then merged.

    bakery plan SCENE --json                        the plan, its id, batches, estimated costs, a chunking
    bakery bake SCENE --probes A-B -o s0.h5         one shard: exactly the probes A..B of the plan's work order
    bakery bake SCENE --shard i/n  -o si.h5         the same with the plan's i-th of n suggested ranges (1-based)
    bakery merge s*.h5 -o STORE.h5 [--layer L]      coverage check, then the parent-side tail of a bake

Work order
    The probes a plan bakes (not the reused ones), batch after batch (``Plan.batches``, which list probes in plan
    order within each group of equal encodings). Index ``i`` of ``--probes`` is a position in this list; for a clean
    bake of a scene whose probes all get the same encodings it is plan (store) order.

Bit-identity
    Per-probe results depend on the batch a probe was encoded in (some fits solve a batch at once), so a shard runs
    the plan's own batches unchanged: a range that cuts a batch computes that batch whole and keeps only its own
    probes (reported as ``recomputed_outside_range``; ``bakery plan`` suggests ranges on batch boundaries, which
    never do). A shard store holds its probes' *pre-finalize* results: encoded fields, every diagnostic including
    the ``finalize/<enc>/<field>`` inputs and ``band_energy``, the transient reference irradiance (under
    ``/diagnostics/shard/transient/``), worker warnings and timings. Band skipping and ``finalize`` run only in
    :func:`merge_shards`, through :func:`bakery.pipeline.run.finalize_and_write` — the same code as a one-process
    bake — so the merged store and layer are the same bytes as ``bakery bake`` (``SOURCE_DATE_EPOCH`` pinned).

Plan id
    sha256 of what the plan computes: source kind, settings hash (includes bakery's version), band tolerance, every
    planned probe's name and content hash, the reused probes and the batches' keys. Shards carry it (root attribute
    ``shard_of``) with their range (``shard_range``); the merge refuses shards of different plans and re-plans the
    bake itself, refusing if the scene, settings or base store changed since the shards were baked.

Base store
    A shard plans against ``--base STORE`` (the farm's final store, for incremental bakes: its unchanged probes are
    reused by the merge instead of baked by a shard) or against nothing (a clean bake). Its own ``-o`` is never a
    reuse base: a finished shard of the same plan and range is kept as is (the task is done), anything else there is
    re-baked. Batches are checkpointed in ``<shard>.partial/`` like any bake, so a killed task resumes.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bakery.errors import ConfigError, InputError, StoreFormatError
from bakery.files import stable_hash
from bakery.pipeline.encode import BakeWarning, EncodedBatch
from bakery.pipeline.journal import Journal
from bakery.pipeline.plan import Plan
from bakery.pipeline.settings import (
    BakeRequest,
    BakeSettings,
    CaptureSettings,
    build_encodings,
)
from bakery.store.format import StoreContents, overwrite_refusal, read_store, write_store

#: /diagnostics prefix of per-probe arrays a shard keeps for the merge that a final store does not hold.
TRANSIENT_PREFIX = "shard/transient/"
SHARD_FORMAT = 1


class ShardError(InputError):
    """Shards that cannot be merged (different plans, gaps, overlaps) or a shard request that does not fit the plan."""


# --- ranges --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ShardSpec:
    """Which part of a plan one task bakes: ``probes`` (first, last) inclusive, or ``shard`` (i, n) 1-based.

    Attributes:
        probes: an explicit inclusive range of work-order indices.
        shard: the i-th of n ranges of :func:`suggest_chunking` (empty when the plan has fewer than i batches).
        base: the store the plan reuses unchanged probes from (None: a clean bake).
        plan_id: refuse to bake if the plan's id differs (job templates pin the plan they were written for).
    """

    probes: tuple[int, int] | None = None
    shard: tuple[int, int] | None = None
    base: Path | None = None
    plan_id: str | None = None

    def __post_init__(self) -> None:
        if (self.probes is None) == (self.shard is None):
            raise ConfigError("a shard takes exactly one of --probes A-B and --shard i/n")


def parse_probe_range(text: str) -> tuple[int, int]:
    """``"A-B"`` or ``"A"`` (inclusive work-order indices) → (A, B)."""
    match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", str(text))
    if not match:
        raise ConfigError(f"--probes takes a range A-B of plan indices (e.g. 0-63), got {text!r}")
    first = int(match.group(1))
    last = int(match.group(2)) if match.group(2) is not None else first
    if last < first:
        raise ConfigError(f"--probes {text}: the range ends before it starts")
    return first, last


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` (1 ≤ i ≤ n) → (i, n)."""
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not match:
        raise ConfigError(f"--shard takes i/n (the i-th of n shards, 1-based), got {text!r}")
    index, count = int(match.group(1)), int(match.group(2))
    if not 1 <= index <= count:
        raise ConfigError(f"--shard {text}: i must be in 1..n")
    return index, count


def format_range(probe_range: tuple[int, int] | None) -> str:
    return "none" if probe_range is None else f"{probe_range[0]}-{probe_range[1]}"


def _parse_stored_range(text: str) -> tuple[int, int] | None:
    return None if text == "none" else parse_probe_range(text)


def format_ranges(ranges: list[tuple[int, int]]) -> str:
    """Compact listing: ``0-6, 14-20``."""
    return ", ".join(f"{a}-{b}" if a != b else f"{a}" for a, b in ranges)


# --- the plan ------------------------------------------------------------------------------------------------------
def work_order(plan: Plan) -> list[str]:
    """Names of the probes a plan bakes, batch after batch (module docstring)."""
    return [t.probe.name for b in plan.batches for t in b.probes]


def batch_ranges(plan: Plan) -> list[tuple[int, int]]:
    """(first, last) work-order indices of every batch."""
    ranges, start = [], 0
    for batch in plan.batches:
        ranges.append((start, start + len(batch.probes) - 1))
        start += len(batch.probes)
    return ranges


def plan_id(request: BakeRequest, source_kind: str, plan: Plan) -> str:
    """The plan's identity (module docstring); 16 hex digits."""
    return stable_hash(
        "bakery-plan", SHARD_FORMAT, source_kind, request.settings.hash(), request.band_energy_tolerance,
        [(t.probe.name, t.content_hash) for t in plan.tasks], sorted(plan.reused), [b.key for b in plan.batches],
    )[:16]


def suggest_chunking(costs: list[float], tasks: int) -> list[tuple[int, int]]:
    """Contiguous groups of whole batches (batch indices, inclusive), at most ``tasks`` of them, balancing the summed
    cost: group j ends at the batch boundary nearest to j/tasks of the total cost. Fewer batches than tasks: one
    batch per group (more tasks than batches would only recompute batches)."""
    if tasks < 1:
        raise ConfigError(f"the number of tasks must be >= 1, got {tasks}")
    count = len(costs)
    if count == 0:
        return []
    if count <= tasks:
        return [(k, k) for k in range(count)]
    weights = np.maximum(np.asarray(costs, dtype=np.float64), 1e-12)
    prefix = np.concatenate([[0.0], np.cumsum(weights)])
    total = prefix[-1]
    groups, start = [], 0
    for j in range(1, tasks):
        left = tasks - j  # groups still to come after this one, each needs at least one batch
        lowest, highest = start + 1, count - left
        target = total * j / tasks
        ends = np.arange(lowest, highest + 1)
        end = int(ends[np.argmin(np.abs(prefix[ends] - target))])
        groups.append((start, end - 1))
        start = end
    groups.append((start, count - 1))
    return groups


def chunk_ranges(plan: Plan, groups: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Work-order ranges of batch groups."""
    ranges = batch_ranges(plan)
    return [(ranges[a][0], ranges[b][1]) for a, b in groups]


def shard_ranges(request: BakeRequest, source: Any, plan: Plan, tasks: int,
                 calibration: Any = None) -> list[tuple[int, int]]:
    """The suggested work-order range of each of at most ``tasks`` tasks (balanced by estimated cost). Without a
    ``calibration``, bakery's shipped one — never a host's own — so that every host of a farm computes the same
    ranges for ``--shard i/n``."""
    from bakery.farm.cost import DEFAULT_CALIBRATION, batch_costs, load_calibration

    costs = batch_costs(request, source, plan, calibration or load_calibration(DEFAULT_CALIBRATION))
    return chunk_ranges(plan, suggest_chunking(costs, tasks))


def resolve_range(request: BakeRequest, source: Any, plan: Plan, spec: ShardSpec) -> tuple[int, int] | None:
    """The inclusive work-order range of ``spec`` for ``plan`` (None: an empty shard)."""
    total = plan.to_bake
    if spec.probes is not None:
        first, last = spec.probes
        if last >= total:
            raise ShardError(f"--probes {first}-{last}: the plan bakes {total} probes (indices 0-{total - 1})"
                             if total else f"--probes {first}-{last}: the plan bakes no probe")
        return first, last
    index, count = spec.shard
    ranges = shard_ranges(request, source, plan, count)
    return ranges[index - 1] if index <= len(ranges) else None


# --- requests as data (the merge re-plans the bake the shards were cut from) ---------------------------------------
def request_to_json(request: BakeRequest) -> str:
    if not isinstance(request.sources, tuple):
        raise ConfigError("shards need file sources (images or a USD scene): an in-memory source cannot be re-planned "
                          "by the merge")
    return json.dumps({
        "sources": [str(p) for p in request.sources], "settings": json.loads(request.settings.as_json()),
        "capture": asdict(request.capture), "layout": request.layout,
        "band_energy_tolerance": request.band_energy_tolerance, "batch_size": request.batch_size,
    }, sort_keys=True)


def request_from_json(text: str, output: Path, layer: Path | None, sources: tuple[Path, ...] | None = None,
                      ) -> BakeRequest:
    data = json.loads(text)
    settings = BakeSettings.from_json(json.dumps(data["settings"]))
    return BakeRequest(sources=sources or tuple(Path(p) for p in data["sources"]), output=Path(output),
                       settings=settings, capture=CaptureSettings(**data["capture"]), layer=layer,
                       layout=data["layout"], resume=True, band_energy_tolerance=data["band_energy_tolerance"],
                       batch_size=data["batch_size"])


# --- baking a shard ------------------------------------------------------------------------------------------------
@dataclass
class ShardSummary:
    """What one shard task did (``bakery bake --probes/--shard --json``; one line per task in farm logs)."""

    store: str
    plan_id: str
    range: str
    shard: str | None
    work_probes: int
    probes: int
    baked: int
    failed: dict[str, str]
    batches: int
    resumed_batches: int
    recomputed_outside_range: int
    already_complete: bool
    workers: int
    executor: str
    seconds: float
    probes_per_second: float
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def log_line(self) -> str:
        rays = self.timings.get("rays_per_second", 0.0)
        where = f"shard {self.shard} " if self.shard else ""
        return (f"{where}probes {self.range} of {self.work_probes} (plan {self.plan_id}): {self.baked} baked, "
                f"{len(self.failed)} failed in {self.seconds:.1f} s ({self.probes_per_second:.3g} probes/s"
                + (f", {rays / 1e6:.2f} M rays/s" if rays else "") + ")"
                + ("; already complete" if self.already_complete else "")
                + (f"; {self.recomputed_outside_range} probes of cut batches recomputed"
                   if self.recomputed_outside_range else ""))


def plan_against(request: BakeRequest, base: Path | None):
    """The plan of ``request`` against the store ``base`` (None or a missing file: a clean bake) and its id;
    nothing is written."""
    from bakery.pipeline.run import check_output_paths, load_previous, plan_bake
    from bakery.sources import source_for

    request_to_json(request)  # file sources only
    source = source_for(request.sources, request.layout, request.capture)
    check_output_paths(request, source)
    if base is not None and (Path(base).exists() or Path(base).is_symlink()):  # missing: the farm's first bake
        reason = overwrite_refusal(base)
        if reason is not None:  # a text file, a foreign HDF5 file, …: planning against nothing would be silent
            raise InputError(f"{base}: the base store {reason.removeprefix('exists and ')}; give the farm's final "
                             "store (or the path it will be merged to)")
    previous = load_previous(base) if base is not None else None
    source, plan = plan_bake(request, source, previous)
    return source, plan, plan_id(request, source.kind, plan), previous


def plan_shard(request: BakeRequest, spec: ShardSpec):
    """Plan the bake a shard belongs to (against ``spec.base``) and resolve its range; nothing is written."""
    if spec.base is not None and Path(spec.base).resolve() == request.output.resolve():
        raise ConfigError(f"{spec.base}: the base store cannot be the shard's own -o")
    source, plan, identity, base = plan_against(request, spec.base)
    if spec.plan_id is not None and spec.plan_id != identity:
        raise ShardError(f"this shard's plan is {identity}, not {spec.plan_id}: the scene, settings, base store or "
                         f"bakery changed since the job was planned; write the job again (bakery farm openjd)")
    return source, plan, identity, resolve_range(request, source, plan, spec), base


def _existing_shard(path: Path, force: bool = False) -> dict[str, Any] | None:
    """The root attributes of the shard store at ``path`` (None: no readable shard there). A finished store that
    is not a shard is refused (a shard task must not replace a farm's final store) unless ``force``."""
    try:
        contents = read_store(path, load_fields=False) if path.is_file() else None
    except StoreFormatError:
        return None
    if contents is not None and "shard_of" not in contents.attributes:
        if force:
            return None
        raise ShardError(f"{path}: is a finished store, not a shard; give the shard its own -o (or --force)")
    return None if contents is None else contents.attributes


def subset(batch: EncodedBatch, names: set[str]) -> EncodedBatch:
    """The probes of ``batch`` named in ``names`` (row order kept)."""
    keep = np.array([i for i, p in enumerate(batch.probes) if p.name in names], dtype=np.int64)
    if keep.size == len(batch.probes):
        return batch
    new_row = np.full(len(batch.probes), -1, dtype=np.int64)
    new_row[keep] = np.arange(keep.size)
    encoded, rows = {}, {}
    for name, fields in batch.encoded.items():
        mask = new_row[batch.rows[name]] >= 0
        if mask.any():
            rows[name] = new_row[batch.rows[name][mask]]
            encoded[name] = {k: v[mask] for k, v in fields.items()}
    return EncodedBatch([batch.probes[i] for i in keep], encoded, rows,
                        {k: v[keep] for k, v in batch.diagnostics.items()}, dict(batch.timings),
                        list(batch.warnings), {k: v[keep] for k, v in batch.transient.items()})


def bake_shard(request: BakeRequest, spec: ShardSpec, executor: Any = None,
               progress: Any = None) -> ShardSummary:
    """Bake the probes of ``spec`` and write them, before finalizing, to the shard store ``request.output``."""
    from bakery.pipeline.executors import SerialExecutor
    from bakery.pipeline.merge import merge_batches
    from bakery.pipeline.run import execute_batches, locked_outputs, with_rates

    start = time.perf_counter()
    executor = executor or SerialExecutor()
    folder = request.output.parent
    if str(folder) and not folder.exists():
        folder.mkdir(parents=True, exist_ok=True)  # a farm job's shard folder
    source, plan, identity, probe_range, _ = plan_shard(request, spec)
    work = work_order(plan)
    wanted = work[probe_range[0]: probe_range[1] + 1] if probe_range else []
    wanted_set = set(wanted)
    batches = [b for b in plan.batches if any(t.probe.name in wanted_set for t in b.probes)]
    extra = sum(1 for b in batches for t in b.probes if t.probe.name not in wanted_set)
    shard_label = f"{spec.shard[0]}/{spec.shard[1]}" if spec.shard else None

    def summary(**values: Any) -> ShardSummary:
        seconds = time.perf_counter() - start
        baked = values.pop("baked")
        recomputed = 0 if values["already_complete"] else extra  # a finished shard recomputes nothing
        return ShardSummary(store=str(request.output), plan_id=identity, range=format_range(probe_range),
                            shard=shard_label, work_probes=len(work), probes=len(wanted), baked=baked,
                            batches=len(batches), recomputed_outside_range=recomputed,
                            workers=getattr(executor, "workers", 1), executor=getattr(executor, "name", "?"),
                            seconds=seconds, probes_per_second=baked / seconds if seconds > 0 else 0.0, **values)

    with locked_outputs(request, source):
        existing = _existing_shard(request.output, bool(getattr(request, "force", False)))
        if existing is not None and existing.get("shard_of") == identity and \
                existing.get("shard_range") == format_range(probe_range):
            failed = json.loads(existing.get("failed_probes", "{}"))
            return summary(baked=0, failed=failed, resumed_batches=0, already_complete=True,
                           timings=json.loads(existing.get("shard_timings", "{}")))

        journal = Journal(request.output)
        outcomes, resumed = execute_batches(batches, request, source, plan, executor, journal, progress)

        failures: dict[str, str] = {}
        parts: list[EncodedBatch] = []
        for outcome in sorted(outcomes, key=lambda o: o.key):
            failures.update({n: m for n, m in outcome.failures.items() if n in wanted_set})
            if outcome.result is not None:
                part = subset(outcome.result, wanted_set)
                if part.probes:
                    parts.append(part)
        order = [n for n in wanted if n not in failures]
        merged = merge_batches(parts, order, release_inputs=True) if parts else EncodedBatch([], {}, {}, {})
        write_shard(request, source.kind, plan, identity, probe_range, len(work), merged, failures, spec)
        journal.remove()
        timings = with_rates(merged.timings)
        return summary(baked=len(order), failed=failures, resumed_batches=resumed, already_complete=False,
                       timings=timings, warnings=[w.message for w in merged.warnings])


def write_shard(request: BakeRequest, source_kind: str, plan: Plan, identity: str,
                probe_range: tuple[int, int] | None, work_probes: int, merged: EncodedBatch,
                failures: dict[str, str], spec: ShardSpec) -> None:
    """The shard store: a readable store (``bakery inspect``, ``bakery.open_store``) of un-finalized results."""
    from bakery.pipeline.write import store_contents

    settings = request.settings
    encodings = build_encodings(sorted(merged.encoded), settings)
    hash_of = {t.probe.name: t.content_hash for t in plan.tasks}
    attributes = {
        **plan.attributes, "failed_probes": json.dumps(failures, sort_keys=True),
        "shard_of": identity, "shard_range": format_range(probe_range), "shard_work_probes": work_probes,
        "shard_format": SHARD_FORMAT, "shard_source_kind": source_kind, "shard_request": request_to_json(request),
        "shard_base": "" if spec.base is None else str(Path(spec.base).resolve()),
        "shard_timings": json.dumps(merged.timings, sort_keys=True),
        "shard_warnings": json.dumps([[w.category, w.message] for w in merged.warnings]),
        "shard_note": "a shard of a farm bake: un-finalized results; `bakery merge` the shards of this plan",
    }
    if spec.shard is not None:
        attributes["shard"] = f"{spec.shard[0]}/{spec.shard[1]}"
    diagnostics = dict(merged.diagnostics)
    diagnostics.update({TRANSIENT_PREFIX + k: v for k, v in merged.transient.items()})
    contents = store_contents(replace(merged, diagnostics=diagnostics), settings, encodings, attributes,
                              probe_hashes=[hash_of[p.name] for p in merged.probes], layers=plan.layers)
    write_store(request.output, contents)


# --- merging -------------------------------------------------------------------------------------------------------
@dataclass
class Shard:
    path: Path
    plan_id: str
    range: tuple[int, int] | None
    work_probes: int
    request_json: str
    base: str
    batch: EncodedBatch
    failures: dict[str, str]


def read_shard(path: str | Path) -> Shard:
    """A shard store's results as an :class:`EncodedBatch` (probes in stored order) plus its plan and range."""
    from bakery.probe import Probe

    path = Path(path)
    contents = read_store(path)
    a = contents.attributes
    if "shard_of" not in a:
        raise ShardError(f"{path}: not a shard store (no shard_of attribute); merge takes the shards of one plan")
    if int(a.get("shard_format", 0)) != SHARD_FORMAT:
        raise ShardError(f"{path}: shard format {a.get('shard_format')} (this bakery merges {SHARD_FORMAT})")
    settings = BakeSettings.from_json(json.dumps(json.loads(str(a["shard_request"]))["settings"]))
    return Shard(path, str(a["shard_of"]), _parse_stored_range(str(a["shard_range"])), int(a["shard_work_probes"]),
                 str(a["shard_request"]), str(a.get("shard_base", "")),
                 _batch_of(contents, Probe, settings), json.loads(str(a.get("failed_probes", "{}"))))


def _batch_of(contents: StoreContents, probe_class: Any, settings: BakeSettings) -> EncodedBatch:
    count = len(contents.probe_names)
    probes = [probe_class(n, tuple(k.split(",")), tuple(map(float, p)))
              for n, k, p in zip(contents.probe_names, contents.probe_kinds, contents.probe_positions)]
    encoded, rows = {}, {}
    for name, entry in contents.encodings.items():
        fields = dict(entry["fields"])
        rows[name] = np.asarray(fields.pop("probe_index"), dtype=np.int64)
        # The encoder's field order (a store reads them back sorted): the merged store writes them in this order.
        order = [spec.name for spec in build_encodings([name], settings)[name].field_specs()]
        encoded[name] = {**{k: fields.pop(k) for k in order if k in fields}, **fields}
    diagnostics = {k: v for k, v in contents.diagnostics.items() if not k.startswith(TRANSIENT_PREFIX)}
    transient = {k[len(TRANSIENT_PREFIX):]: v for k, v in contents.diagnostics.items() if k.startswith(TRANSIENT_PREFIX)}
    for key, value in {**diagnostics, **transient}.items():
        if np.ndim(value) < 1 or len(value) != count:
            raise ShardError(f"diagnostic {key} is not per-probe")
    a = contents.attributes
    warnings = [BakeWarning(c, m) for c, m in json.loads(str(a.get("shard_warnings", "[]")))]
    timings = {k: float(v) for k, v in json.loads(str(a.get("shard_timings", "{}"))).items()}
    return EncodedBatch(probes, encoded, rows, diagnostics, timings, warnings, transient)


def check_coverage(shards: list[Shard], work_probes: int) -> None:
    """The shards' ranges cover 0..work_probes-1 exactly once; else a :class:`ShardError` naming the missing and the
    duplicated ranges (and the shards that duplicate them)."""
    owners = np.zeros(work_probes, dtype=np.int64)
    for shard in shards:
        if shard.range is not None:
            first, last = shard.range
            if last >= work_probes:
                raise ShardError(f"{shard.path}: range {first}-{last} is outside the plan (0-{work_probes - 1})")
            owners[first: last + 1] += 1
    problems = []
    missing = _runs(owners == 0)
    if missing:
        problems.append(f"missing probes {format_ranges(missing)} (in no shard)")
    for first, last in _runs(owners > 1):
        holders = [str(s.path) for s in shards if s.range and s.range[0] <= last and s.range[1] >= first]
        problems.append(f"probes {first}-{last} are in more than one shard ({', '.join(holders)})")
    if problems:
        raise ShardError(f"the shards do not cover the plan's {work_probes} probes exactly once: "
                         + "; ".join(problems))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    runs, start = [], None
    for i, value in enumerate(mask.tolist() + [False]):
        if value and start is None:
            start = i
        elif not value and start is not None:
            runs.append((start, i - 1))
            start = None
    return runs


def shard_paths(items: list[str | Path], output: str | Path | None = None) -> list[Path]:
    """Shard files from arguments: files as given, folders expanded to their ``*.h5`` files (sorted) except
    ``output`` (a merged store written into the shards' folder is not a shard of the next merge)."""
    paths: list[Path] = []
    merged = Path(output).resolve() if output is not None else None
    for item in map(Path, items):
        if item.is_dir():
            paths.extend(sorted(p for p in item.iterdir() if p.suffix.lower() in (".h5", ".hdf5")
                                and p.resolve() != merged))
        else:
            paths.append(item)
    if not paths:
        raise ShardError("no shard stores given")
    return paths


@dataclass
class MergeSummary:
    store: str
    plan_id: str
    shards: int
    planned: int
    baked: int
    reused: int
    failed: dict[str, str]
    skipped: list[dict[str, str]]
    seconds: float
    store_bytes: int
    bytes_per_probe: dict[str, int]
    layer: str | None = None
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def merge_shards(items: list[str | Path], output: str | Path, layer: str | Path | None = None,
                 sources: tuple[Path, ...] | None = None) -> MergeSummary:
    """Merge the shards of one plan into ``output`` (and the source's layer) exactly as :func:`bakery.pipeline.run.
    bake` would have written it: coverage check, re-plan (must give the shards' plan id), then
    :func:`bakery.pipeline.run.finalize_and_write`. ``sources`` overrides the scene/image paths the shards recorded
    (a farm whose merge node mounts the scene elsewhere)."""
    from bakery.pipeline.run import check_output_paths, locked_outputs
    from bakery.sources import source_for

    start = time.perf_counter()
    paths = shard_paths(list(items), output)
    output = Path(output)
    if any(p.resolve() == output.resolve() for p in paths):
        raise ShardError(f"{output}: is one of the shards; choose another -o")
    shards = [read_shard(p) for p in paths]
    plans: dict[str, list[str]] = {}
    for shard in shards:
        plans.setdefault(shard.plan_id, []).append(str(shard.path))
    if len(plans) > 1:
        raise ShardError("the shards belong to different plans: "
                         + "; ".join(f"plan {k}: {', '.join(v)}" for k, v in sorted(plans.items()))
                         + ". Merge the shards of one plan (bake them with the same scene, settings and base)")
    first = shards[0]
    bases = {s.base for s in shards}
    if len(bases) > 1 or len({s.request_json for s in shards}) > 1 or len({s.work_probes for s in shards}) > 1:
        raise ShardError("the shards carry the same plan id but different requests or bases; bake them again")
    check_coverage(shards, first.work_probes)

    request = request_from_json(first.request_json, output, Path(layer) if layer else None, sources)
    source = source_for(request.sources, request.layout, request.capture)
    check_output_paths(request, source)
    with locked_outputs(request, source):
        return _merge_locked(request, source, shards, first, start)


def _merge_locked(request: BakeRequest, source: Any, shards: list[Shard], first: Shard, start: float,
                  ) -> MergeSummary:
    from bakery.pipeline.merge import extract_probes
    from bakery.pipeline.run import (
        finalize_and_write,
        load_previous,
        plan_bake,
        reused_lacking_kept_encodings,
        with_rates,
    )

    output = request.output
    previous = load_previous(first.base) if first.base else None
    source, plan = plan_bake(request, source, previous)
    identity = plan_id(request, source.kind, plan)
    if identity != first.plan_id:
        raise ShardError(f"the shards are of plan {first.plan_id} but the bake now plans {identity}: the scene, "
                         f"settings or base store changed since the shards were baked; bake the shards again")
    probe_of = {t.probe.name: t.probe for t in plan.tasks}
    failures: dict[str, str] = {}
    batches: list[EncodedBatch] = []
    for shard in shards:
        failures.update(shard.failures)
        if shard.batch.probes:
            batch = shard.batch
            batch.probes = [probe_of[p.name] for p in batch.probes]
            batches.append(batch)
    lacking = sorted(reused_lacking_kept_encodings(request, plan, previous, batches))
    if lacking:  # the merge cannot bake them (bakery.pipeline.run.reused_lacking_kept_encodings): refused, not stale
        raise ShardError(f"{len(lacking)} probe(s) the plan reuses from the base store ({', '.join(lacking[:3])}"
                         f"{' …' if len(lacking) > 3 else ''}) lack an encoding this bake keeps (the base's bake "
                         f"skipped it, band skipping); bake without --base, or in one process (bakery bake), which "
                         f"bakes them again")
    if plan.reused and previous is not None:
        batches.append(extract_probes(previous, plan.reused))
    if failures and not batches:
        first_failure = next(iter(failures.values()))
        raise InputError(f"no probe could be baked; nothing was written. First failure: {first_failure}")
    merged, _, encodings, skipped, extra = finalize_and_write(request, source, plan, batches, failures, previous)
    timings: dict[str, float] = {}
    for shard in shards:
        for key, value in shard.batch.timings.items():
            timings[key] = timings.get(key, 0.0) + value
    timings = with_rates(timings)
    return MergeSummary(
        store=str(output), plan_id=identity, shards=len(shards), planned=len(plan.tasks),
        baked=plan.to_bake - len(failures), reused=len(plan.reused), failed=failures, skipped=skipped,
        seconds=time.perf_counter() - start, store_bytes=output.stat().st_size,
        bytes_per_probe={n: e.bytes_per_probe() for n, e in encodings.items()}, layer=extra.get("layer"),
        timings=timings, warnings=[w.message for w in merged.warnings])
