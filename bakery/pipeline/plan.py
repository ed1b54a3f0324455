"""Planning a bake: the probes of a source, their content hashes, reuse decisions, and batches (plain picklable
data; nothing here reads or writes files).

Content hash (incremental bakes)
    A probe's hash covers everything its result depends on: the probe's identity, kinds, position and per-probe
    settings; its source kind, its typed capture spec and the content hashes of what the capture reads (e.g. the
    image bytes, or the hash of the scene parts that can affect it); the bake settings and the encodings selected for
    it with their versions and resolved parameters (defaults included); bakery's version (the code). Equal hash ⇒
    the stored result is reused without re-baking, provided the stored fields of each of its encodings are the
    fields this bake writes (:func:`changed_layouts`; otherwise the hash missed a layout change and it re-bakes).

Batches
    Probes with the same encodings and the same per-probe encoding overrides are batched together in plan order, at
    most ``batch_size`` per batch: composition depends only on the plan, never on the number of workers, so stores
    are bit-identical for any executor.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bakery.encodings import get_encoding
from bakery.files import stable_hash
from bakery.pipeline.dilate import hashed_settings
from bakery.pipeline.settings import BakeSettings, default_encodings, encoding_params
from bakery.probe import Probe
from bakery.sources.base import PlannedProbe, SourceHandle, SourcePlan


@dataclass(frozen=True)
class ProbeTask:
    """One probe to bake: identity, the source's capture spec, the encodings it gets, its content hash."""

    probe: Probe
    capture: Any
    encodings: tuple[str, ...]
    content_hash: str


@dataclass(frozen=True)
class BatchTask:
    """A unit of work for a worker; ``key`` identifies it for checkpoints (hash of its probes' hashes)."""

    key: str
    probes: tuple[ProbeTask, ...]
    settings_json: str
    source: SourceHandle | None = None


@dataclass
class Plan:
    """What a bake will do: every planned probe in store order, which are reused, and the batches to run."""

    tasks: list[ProbeTask]
    batches: list[BatchTask]
    reused: list[str] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)
    attributes: dict[str, Any] = field(default_factory=dict)
    layers: str = ""
    issues: list[str] = field(default_factory=list)

    @property
    def order(self) -> list[str]:
        return [t.probe.name for t in self.tasks]

    def pending_tasks(self) -> list[ProbeTask]:
        """Tasks of the probes that are not reused, in plan order."""
        reused = set(self.reused)
        return [t for t in self.tasks if t.probe.name not in reused]

    @property
    def to_bake(self) -> int:
        return sum(len(b.probes) for b in self.batches)


def encodings_for(probe: Probe, settings: BakeSettings) -> tuple[str, ...]:
    """Encodings a probe gets: the per-probe override, else the settings' list, else every registered one of its
    kinds; always restricted to the probe's kinds (skip what the probe kind does not need)."""
    requested = tuple(probe.settings.get("encodings", ())) or settings.encodings or default_encodings(probe.kinds)
    return tuple(n for n in requested if get_encoding(n).kind in probe.kinds)


def probe_content_hash(source_kind: str, planned: PlannedProbe, encodings: tuple[str, ...], settings_hash: str,
                       params: Mapping[str, Any] | None = None) -> str:
    """The content hash of the module docstring; ``params``: the bake's resolved ``Params`` (or their hash) per
    encoding name — defaults included, so that a changed default re-bakes the probes of its encoding even at the
    same version."""
    probe = planned.probe
    versions = sorted((name, get_encoding(name).version, (params or {}).get(name)) for name in encodings)
    return stable_hash(probe.name, probe.kinds, probe.position, hashed_settings(probe.settings), source_kind,
                       planned.capture, planned.inputs, versions, settings_hash)


def changed_layouts(previous: Any, names: set[str], settings: BakeSettings) -> set[str]:
    """Encodings whose fields in the ``previous`` store are not the fields this bake writes: their probes are
    re-baked even where the content hash matches (verify before reuse: a reused row must fit the new rows' layout;
    e.g. a store baked with ``gap_level`` before ``gap_skipped`` existed)."""
    changed = set()
    for name in sorted(names):
        stored = previous.encodings.get(name)
        if stored is None:
            continue
        fields = {spec.name for spec in get_encoding(name)(encoding_params(name, settings)).field_specs()}
        if set(stored["fields"]) - {"probe_index"} != fields:
            changed.add(name)
    return changed


def make_batches(tasks: list[ProbeTask], batch_size: int, settings_json: str) -> list[BatchTask]:
    """Batches of ≤ batch_size probes with one encoding set and one set of per-probe encoding overrides each
    (module docstring)."""
    groups: dict[tuple, list[ProbeTask]] = {}
    for task in tasks:
        overrides = json.dumps(task.probe.settings.get("encoding_settings", {}), sort_keys=True)
        groups.setdefault((task.encodings, overrides), []).append(task)
    batches = []
    for group in groups.values():
        for start in range(0, len(group), batch_size):
            members = tuple(group[start : start + batch_size])
            key = stable_hash([t.content_hash for t in members])[:32]
            batches.append(BatchTask(key, members, settings_json))
    return batches


def plan_tasks(source_kind: str, source_plan: SourcePlan, settings: BakeSettings, previous: Any,
               batch_size: int) -> Plan:
    """Content hashes, reuse decisions against ``previous`` (a StoreContents or None) and batches."""
    tasks: list[ProbeTask] = []
    skipped: list[dict[str, str]] = []
    names = [p.probe.name for p in source_plan.probes]
    if len(set(names)) != len(names):
        from bakery.errors import ConfigError

        duplicated = sorted({n for n in names if names.count(n) > 1})
        raise ConfigError(f"probe names must be unique; repeated: {', '.join(duplicated[:5])}")
    settings_hash = settings.hash()
    params: dict[str, Any] = {}  # resolved once per encoding (per-probe overrides are in the probe's settings)
    for planned in source_plan.probes:
        encodings = encodings_for(planned.probe, settings)
        if not encodings:
            skipped.append({"probe": planned.probe.name,
                            "reason": f"no requested encoding applies to kinds {planned.probe.kinds}"})
            continue
        for name in encodings:
            if name not in params:  # hashed once: thousands of probes share it
                params[name] = stable_hash(encoding_params(name, settings))
        tasks.append(ProbeTask(planned.probe, planned.capture, encodings,
                               probe_content_hash(source_kind, planned, encodings, settings_hash, params)))
    if skipped and not tasks:  # a store of no encoding at all: bad settings, not a bake that succeeded
        from bakery.errors import ConfigError

        kinds = sorted({k for p in source_plan.probes for k in p.probe.kinds})
        asked = ", ".join(f"{n} ({get_encoding(n).kind})" for n in settings.encodings) or "the probes' own encodings"
        where = f"{source_plan.attributes['source']}: " if source_plan.attributes.get("source") else ""
        raise ConfigError(f"{where}no probe takes any requested encoding: asked for {asked}; the probes are "
                          f"{' and '.join(kinds)} probes ({skipped[0]['probe']}: {skipped[0]['reason']})")
    reused: list[str] = []
    if previous is not None and previous.probe_hashes is not None:
        old = dict(zip(previous.probe_names, previous.probe_hashes))
        relaid = changed_layouts(previous, {n for t in tasks for n in t.encodings}, settings)
        reused = [t.probe.name for t in tasks if old.get(t.probe.name) == t.content_hash
                  and not relaid.intersection(t.encodings)]
    plan = Plan(tasks, [], reused, skipped, dict(source_plan.attributes), source_plan.layers,
                list(source_plan.issues))
    plan.batches = make_batches(plan.pending_tasks(), batch_size, settings.as_json())
    return plan
