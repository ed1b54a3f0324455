"""Worker side: capture and encode one batch. Runs in a worker process (or in-process for ``--jobs 1``)."""

from __future__ import annotations

import json
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from bakery.allocator import tune_allocator
from bakery.bake import BakeSettings, EncodedBatch, encode_batch, sanitize_diagnostics, select_encodings
from bakery.environment.sanitize import SanitizeReport
from bakery.errors import BakeryError
from bakery.pipeline.capture import capture_function
from bakery.pipeline.plan import BatchTask
from bakery.probe import ProbeBatch


@dataclass
class BatchOutcome:
    """What a worker returns: the encoded probes that succeeded and an error message per failed probe."""

    key: str
    result: EncodedBatch | None
    failures: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0


def _settings(task: BatchTask) -> BakeSettings:
    data = json.loads(task.settings_json)
    data["encodings"] = tuple(data.get("encodings", ()))
    return BakeSettings(**data)


def run_batch(task: BatchTask) -> BatchOutcome:
    """Capture every probe of ``task`` and encode them together. A probe whose capture raises is reported in
    ``failures`` and left out; the others are encoded."""
    start = time.perf_counter()
    tune_allocator()
    settings = _settings(task)
    cubes, references, reports, probes, failures = [], [], [], [], {}
    capture_stats: dict[str, float] = {}
    for probe_task in task.probes:
        try:
            capture = capture_function(probe_task.capture.kind)
            captured = capture(probe_task.capture, settings.face_size, probe_task.probe)
            cube, reference, report = captured[:3]
            for key, value in (captured[3] if len(captured) > 3 else {}).items():
                capture_stats[key] = capture_stats.get(key, 0.0) + value
            if not np.all(np.isfinite(cube)):
                raise BakeryError(f"{probe_task.probe.name}: capture produced non-finite radiance")
        except Exception as error:  # noqa: BLE001 - one failing probe must not lose the batch
            detail = str(error) if isinstance(error, BakeryError) else traceback.format_exc(limit=3)
            failures[probe_task.probe.name] = detail
            continue
        cubes.append(cube)
        references.append(reference)
        reports.append(report or SanitizeReport(0, 0, 0, 0, 0, 0.0, 0.0))
        probes.append(probe_task.probe)
    if not probes:
        return BatchOutcome(task.key, None, failures, time.perf_counter() - start)
    reference = references if all(r is not None for r in references) else None
    batch = ProbeBatch(np.stack(cubes), reference)
    # Per-probe encoding-setting overrides (one set per batch, see make_batches), e.g. a reflection probe's fit α range.
    overrides = task.probes[0].probe.settings.get("encoding_settings", {})
    base = json.loads(task.settings_json)
    merged_settings = {name: {**base.get("encoding_settings", {}).get(name, {}), **values}
                       for name, values in {**base.get("encoding_settings", {}), **overrides}.items()}
    encodings = select_encodings(
        BakeSettings(**{**base, "encodings": task.probes[0].encodings, "encoding_settings": merged_settings}),
        {k for p in probes for k in p.kinds},
    )
    diagnostics = sanitize_diagnostics(reports)
    if "shexp" in overrides:
        alpha = overrides["shexp"]
        diagnostics["fit_alpha_range"] = np.tile(
            np.array([alpha["alpha_min"], alpha["alpha_max"]], dtype=np.float32), (len(probes), 1))
    result = encode_batch(probes, batch, settings, encodings, diagnostics)
    result.timings.update(capture_stats)
    return BatchOutcome(task.key, result, failures, time.perf_counter() - start)
