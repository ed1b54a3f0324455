"""Worker side: capture and encode one batch (in a worker process, or in-process for ``--jobs 1``).

    run_batch(BatchTask) → BatchOutcome:   Source.capture_many (a capture or an error per probe)  →  ProbeBatch
                                           →  encode_batch

A probe whose capture fails is reported in ``failures`` and left out; the others are encoded. Warnings raised
while capturing and encoding travel back in the outcome (the parent re-emits them). Nothing here imports ``pxr``.

Worker processes die with the bake's parent (:func:`watch_parent`): the parent-death signal where the parent is the
process that spawned us, and a watchdog thread that exits when the parent's pid is gone.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import sys
import threading
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from bakery.allocator import tune_allocator
from bakery.errors import BakeryError, BakeryWarning
from bakery.files import pid_alive
from bakery.pipeline.encode import (
    BakeWarning,
    EncodedBatch,
    encode_batch,
    sanitize_diagnostics,
)
from bakery.pipeline.plan import BatchTask
from bakery.pipeline.settings import BakeSettings, build_encodings
from bakery.probe import ProbeBatch
from bakery.sources.base import capture_each, source_class

#: Environment variable ``host:pid`` naming the process a worker must die with (set for LocalCluster workers).
PARENT_ENVIRONMENT = "BAKERY_PARENT"
_WATCHED: list[int] = []


def _set_death_signal() -> bool:
    """Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)``: the kernel kills us when the thread that spawned us exits."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(1, int(signal.SIGKILL), 0, 0, 0) == 0  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return False


def watch_parent(pid: int | None = None, *, death_signal: bool = False, interval: float = 0.25) -> None:
    """Make this process exit when the bake's parent ``pid`` exits (default: from :data:`PARENT_ENVIRONMENT`,
    if it names this host). Idempotent per process."""
    if pid is None:
        token = os.environ.get(PARENT_ENVIRONMENT, "")
        host, _, text = token.rpartition(":")
        if not text.isdigit() or host != socket.gethostname():
            return
        pid = int(text)
    if _WATCHED or pid <= 0 or pid == os.getpid():
        return
    _WATCHED.append(pid)
    direct = os.getppid() == pid
    if death_signal and direct:
        _set_death_signal()
    if direct and os.getppid() != pid:  # the parent died before the signal was armed
        os._exit(70)

    def watch() -> None:
        while True:
            time.sleep(interval)
            if (direct and os.getppid() != pid) or not pid_alive(pid):
                os._exit(70)

    threading.Thread(target=watch, name="bakery-parent-watch", daemon=True).start()


@dataclass
class BatchOutcome:
    """What a worker returns: the encoded probes that succeeded and an error message per failed probe."""

    key: str
    result: EncodedBatch | None
    failures: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0


def run_batch(task: BatchTask) -> BatchOutcome:
    """Capture every probe of ``task`` and encode them together (module docstring), with one BLAS/OpenMP thread
    whatever the executor: a BLAS kernel may round differently with another thread count (measured: the SH-exp
    fit's tile GEMMs, 1e-6), so the in-process executor must compute exactly what a worker process does."""
    with threadpool_limits(limits=1):
        return _run_batch(task)


def failure_message(error: BaseException) -> str:
    """One line for a probe that failed: a :class:`BakeryError`'s message as is; anything else as its type and
    message and where it was raised (``MemoryError: Unable to allocate 74.5 GiB … (render.py:212 in capture)``),
    not a traceback: the store's ``failed`` record and the CLI print it."""
    if isinstance(error, BakeryError):
        return str(error)
    frames = traceback.extract_tb(error.__traceback__)
    where = f" ({Path(frames[-1].filename).name}:{frames[-1].lineno} in {frames[-1].name})" if frames else ""
    text = " ".join(str(error).split()) or "no message"
    return f"{type(error).__name__}: {text}{where}"


def _run_batch(task: BatchTask) -> BatchOutcome:
    start = time.perf_counter()
    watch_parent()  # LocalCluster workers: die with the bake (pool workers are set up by their initializer)
    tune_allocator()
    settings = BakeSettings.from_json(task.settings_json)
    source = source_class(task.source.kind)
    captures, probes, failures = [], [], {}
    stats: dict[str, float] = {}
    with warnings.catch_warnings(record=True) as recorded:
        warnings.simplefilter("always", BakeryWarning)
        specs = [probe_task.capture for probe_task in task.probes]
        try:
            results = source.capture_many(task.source, specs, settings.face_size)
        except Exception:  # noqa: BLE001 - a source's grouping failed: capture the probes one by one
            results = capture_each(source, task.source, specs, settings.face_size)
        for probe_task, capture in zip(task.probes, results, strict=True):
            try:
                if isinstance(capture, Exception):
                    raise capture
                if not np.all(np.isfinite(capture.cube)):
                    raise BakeryError(f"{probe_task.probe.name}: capture produced non-finite radiance")
            except Exception as error:  # noqa: BLE001 - one failing probe must not lose the batch
                failures[probe_task.probe.name] = failure_message(error)
                continue
            for key, value in capture.stats.items():
                stats[key] = stats.get(key, 0.0) + value
            captures.append(capture)
            probes.append(probe_task.probe)
    capture_warnings = [BakeWarning(w.category.__name__, str(w.message)) for w in recorded
                        if issubclass(w.category, BakeryWarning)]
    if not probes:
        return BatchOutcome(task.key, None, failures, time.perf_counter() - start)
    references = [c.reference for c in captures]
    cubes = np.stack([c.cube for c in captures])
    # from here on the batch holds the only copy of each cube (a worker's peak memory is in the encoding)
    captures = [dataclasses.replace(c, cube=cubes[i]) for i, c in enumerate(captures)]
    del results
    batch = ProbeBatch(cubes, references if all(r is not None for r in references) else None)
    # One encoding set and one set of per-probe overrides per batch (plan.make_batches).
    overrides = task.probes[0].probe.settings.get("encoding_settings", {})
    encodings = build_encodings(task.probes[0].encodings, settings, overrides)
    diagnostics = sanitize_diagnostics([c.sanitize for c in captures])
    for key in sorted({k for c in captures for k in c.diagnostics}):
        template = next(c.diagnostics[key] for c in captures if key in c.diagnostics)
        diagnostics[key] = np.stack([np.asarray(c.diagnostics.get(key, np.full_like(template, np.nan)))
                                     for c in captures])
    ranged = [e for e in encodings.values() if e.accepts_alpha_range and e.name in overrides]
    if ranged:
        alpha = ranged[0].params
        diagnostics["fit_alpha_range"] = np.tile(np.array([alpha.alpha_min, alpha.alpha_max], dtype=np.float32),
                                                 (len(probes), 1))
    result = encode_batch(probes, batch, settings, encodings, diagnostics)
    result.timings.update(stats)
    result.warnings = capture_warnings + result.warnings
    return BatchOutcome(task.key, result, failures, time.perf_counter() - start)
