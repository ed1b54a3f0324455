"""Planning a bake: probes, their capture specs, content hashes, and batches (plain picklable data).

Content hash (incremental bakes)
    A probe's hash covers everything its result depends on: the probe's identity, kinds, position and per-probe
    settings; its capture spec (capture kind, inputs' content hashes — e.g. the image bytes, or the hashes of the
    scene parts that can affect it — and capture parameters); the bake settings and the encodings selected for it;
    and bakery's version (the code). Equal hash ⇒ the stored result is reused without re-baking.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

from bakery.probe import Probe


def stable_hash(*parts: Any) -> str:
    """sha256 hex of the canonical JSON of ``parts``."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


@dataclass(frozen=True)
class CaptureSpec:
    """How to obtain one probe's radiance cube. ``kind`` selects a registered capture function
    (:mod:`bakery.pipeline.capture`); ``inputs`` are content hashes of what it reads; ``params`` its parameters."""

    kind: str
    source: str
    inputs: tuple[str, ...] = ()
    params: tuple[tuple[str, Any], ...] = ()

    def param(self, key: str, default: Any = None) -> Any:
        return dict(self.params).get(key, default)


@dataclass(frozen=True)
class ProbeTask:
    probe: Probe
    capture: CaptureSpec
    encodings: tuple[str, ...]
    content_hash: str


@dataclass(frozen=True)
class BatchTask:
    """A unit of work for a worker; ``key`` identifies it for checkpoints (hash of its probes' hashes)."""

    key: str
    probes: tuple[ProbeTask, ...]
    settings_json: str


@dataclass
class Plan:
    """What a bake will do: every planned probe in store order, which are reused, and the batches to run."""

    tasks: list[ProbeTask]
    batches: list[BatchTask]
    reused: list[str] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)
    attributes: dict[str, Any] = field(default_factory=dict)

    @property
    def order(self) -> list[str]:
        return [t.probe.name for t in self.tasks]


def probe_content_hash(probe: Probe, capture: CaptureSpec, encodings: tuple[str, ...], settings_hash: str) -> str:
    """The content hash of the module docstring."""
    return stable_hash(
        probe.name, probe.kinds, probe.position, probe.settings, capture.kind, capture.inputs, capture.params,
        sorted(encodings), settings_hash,
    )


def make_batches(tasks: list[ProbeTask], batch_size: int, settings_json: str) -> list[BatchTask]:
    """Split tasks into batches of ≤ batch_size with one encoding set and one set of per-probe encoding-setting
    overrides (``probe.settings["encoding_settings"]``) each, in plan order (deterministic: batch composition
    depends only on the plan, never on the number of workers)."""
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
