"""``bakery plan``: what a bake would do, without baking — probes by kind, reuse, batches, estimated costs, and the
suggested chunking of the work into N farm tasks (:mod:`bakery.pipeline.shards`)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from bakery.farm.cost import (
    PILOT_FACES,
    PILOT_PROBES,
    CostModel,
    load_calibration,
    pilot_capture,
)
from bakery.pipeline.run import source_inputs
from bakery.pipeline.settings import BakeRequest
from bakery.pipeline.shards import (
    batch_ranges,
    chunk_ranges,
    format_range,
    plan_against,
    suggest_chunking,
)


def _pilot(request: BakeRequest, source: Any, plan: Any) -> Any:
    """:func:`bakery.farm.cost.pilot_capture`, or None (with a warning) if the scene cannot be rendered: the plan
    then estimates with the modelled rays, and the bake reports the error."""
    try:
        return pilot_capture(request, source, plan)
    except (ValueError, RuntimeError, MemoryError, FloatingPointError) as error:
        warnings.warn(f"the pilot capture failed ({error}); the estimates use the modelled rays", stacklevel=2)
        return None


def plan_info(request: BakeRequest, tasks: int = 4, base: Path | None = None,
              calibration: str | Path | None = None) -> dict[str, Any]:
    """The plan of ``request`` as JSON-able data (``bakery plan --json``)."""
    source, plan, identity, _ = plan_against(request, base)
    cal = load_calibration(calibration)
    pilot = _pilot(request, source, plan) if plan.batches else None
    model = CostModel(request, source, plan, cal, pilot)  # the estimates: this scene's traced rays
    chunk_model = CostModel(request, source, plan, cal)  # the chunking: modelled rays, the same on every host
    kinds: dict[str, int] = {}
    for task in plan.tasks:
        for kind in task.probe.kinds:
            kinds[kind] = kinds.get(kind, 0) + 1
    pending = [t for b in plan.batches for t in b.probes]
    costs = [model.probe(t) for t in pending]
    capture = sum(c.capture for c in costs)
    encode: dict[str, float] = {}
    for cost in costs:
        for name, value in cost.encode.items():
            encode[name] = encode.get(name, 0.0) + value
    by_kind: dict[str, list[float]] = {}
    for task, cost in zip(pending, costs):
        by_kind.setdefault(",".join(task.probe.kinds), []).append(cost.total + cal["per_probe_seconds"])
    batch_cost = [model.batch(b) for b in plan.batches]
    groups = suggest_chunking([chunk_model.batch(b) for b in plan.batches], tasks)
    ranges = chunk_ranges(plan, groups)
    task_seconds = [model.process(plan.batches[a: b + 1]) for a, b in groups]
    merge_seconds = model.merge(plan)
    one_process = model.process(plan.batches) if plan.batches else cal["process_seconds"]
    note = None
    if len(plan.batches) < tasks:
        note = (f"the plan has {len(plan.batches)} batches: at most {len(plan.batches)} tasks do useful work "
                f"(a shard runs whole batches); a smaller [pipeline] batch_size gives more, but is a different bake")
    return {
        "plan_id": identity,
        "store": str(request.output),
        "base": str(base) if base else None,
        "sources": [str(s) for s in request.sources],
        "inputs": [str(p) for p in source_inputs(source)],  # every file the bake reads (the scene's layers too)
        "source_kind": source.kind,
        "settings_hash": request.settings.hash(),
        "probes": {"total": len(plan.tasks), "by_kind": kinds},
        "reused": len(plan.reused),
        "to_bake": plan.to_bake,
        "skipped": plan.skipped,
        "issues": plan.issues,
        "encodings": sorted({e for t in plan.tasks for e in t.encodings}),
        "batches": [{"index": k, "range": format_range(r), "probes": len(b.probes), "encodings": list(b.probes[0].encodings),
                     "estimated_seconds": round(batch_cost[k], 4)}
                    for k, (b, r) in enumerate(zip(plan.batches, batch_ranges(plan)))],
        "estimate": {
            "seconds_per_probe": {kind: round(sum(v) / len(v), 6) for kind, v in sorted(by_kind.items())},
            "capture_seconds": round(capture, 3),
            "encode_seconds": {k: round(v, 3) for k, v in sorted(encode.items())},
            "setup_seconds": round(model.setup({e for t in pending for e in t.encodings}), 3),
            "one_process_seconds": round(one_process, 2),
            "capture": {"face_size": request.settings.face_size, "samples": request.capture.samples,
                        "bounces": request.capture.bounces, "lights": model.lights,
                        "next_event_lights": model.next_event_lights,
                        "pilot": None if model.pilot is None else {
                            "probes_per_kind": PILOT_PROBES, "face_sizes": list(PILOT_FACES),
                            "rays_per_camera_ray": {k: round(v, 4) for k, v in
                                                    sorted(model.pilot.rays_per_camera_ray.items())},
                            "seconds_per_ray": model.pilot.seconds_per_ray,
                            "seconds_per_probe": model.pilot.seconds_per_probe}},
            "calibration": {"path": cal["path"], "measured": cal.get("measured"), "machine": cal.get("machine")},
        },
        "chunking": {
            "tasks": tasks, "useful_tasks": len(groups),
            "ranges": [format_range(r) for r in ranges],
            "estimated_seconds": [round(s, 2) for s in task_seconds],
            "merge_seconds": round(merge_seconds, 2),
            "makespan_seconds": round((max(task_seconds) if task_seconds else 0.0) + merge_seconds, 2),
            "note": note,
        },
    }
