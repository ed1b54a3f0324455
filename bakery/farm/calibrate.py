"""Calibrating the cost model (:mod:`bakery.farm.cost`) on this machine: ``bakery farm calibrate -o FILE``.

Eight real ``bakery bake`` processes (``--jobs 1``, fresh, so each pays its start-up and encoder set-ups) of the
scale benchmark's generated hall (:func:`bakery.bench.scale.generate_scene`: pillars, three sphere lights, a dome)
at two sizes and three face sizes (:data:`FACE_SIZES`; one bounce, every encoding), then the larger hall at the
largest face size with reference errors and at the smallest at the default bounces; and the merges of two shards
of a 2,000-probe volume, alone and with 200 and 400 reflection probes. From their ``--json`` timings and wall
times, non-negative least squares gives each constant of the model: per encoding a set-up and a per-probe cost,
each ``f0 + f2·N²``; capture seconds per probe and per modelled ray, and per ray the bakes really traced (with the
pilot capture's own seconds per ray on the hall: the yardstick of `bakery plan`'s pilot); the effective bounces of
the default (paths that escape or end by Russian roulette); the irradiance diagnostics and reference errors; the
process overhead; the merge's seconds per probe.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import nnls

from bakery.encodings import ENCODINGS
from bakery.farm.cost import CALIBRATION_VERSION
from bakery.pipeline.settings import CaptureSettings

#: (volume counts, reflection probes) of the two sizes; (face sizes) of the two grids.
SIZES = (((3, 2, 3), 2), ((6, 3, 6), 24))
FACE_SIZES = (8, 16, 32)
SAMPLES, BOUNCES = 2, 1


def _bake(scene: Path, store: Path, face_size: int, reference: bool, bounces: int | None = BOUNCES) -> dict[str, Any]:
    command = [sys.executable, "-m", "bakery.cli", "bake", str(scene), "-o", str(store), "--face-size",
               str(face_size), "--samples", str(SAMPLES), "--jobs", "1", "--json", "--no-resume"] \
        + ([] if reference else ["--no-reference"]) + ([] if bounces is None else ["--bounces", str(bounces)])
    for name in ENCODINGS:
        command += ["-e", name]
    start = time.perf_counter()
    result = subprocess.run(command, check=False, capture_output=True, text=True, env={**os.environ, "SOURCE_DATE_EPOCH": "0"})
    wall = time.perf_counter() - start
    if result.returncode not in (0, 6):
        raise RuntimeError(f"calibration bake failed ({result.returncode}): {result.stderr[-2000:]}")
    return {"wall": wall, "summary": json.loads(result.stdout)}


def _features(scene: Path, face_size: int) -> dict[str, float]:
    """What the cost model counts for a bake of ``scene``: probes per kind and modelled capture rays."""
    from bakery.farm.cost import CostModel
    from bakery.pipeline.run import plan_bake
    from bakery.pipeline.settings import request_from

    request = request_from(scene, scene.with_suffix(".h5"), encodings=tuple(ENCODINGS), face_size=face_size,
                           samples=SAMPLES, bounces=BOUNCES)
    source, plan = plan_bake(request)
    model = CostModel(request, source, plan, {})
    kinds = [k for t in plan.tasks for k in t.probe.kinds]
    return {"irradiance": kinds.count("irradiance"), "reflection": kinds.count("reflection"),
            "probes": len(plan.tasks), "rays": sum(model.capture_rays(t) for t in plan.tasks)}


#: The merge runs: cheap bakes (recipe ``console``, capture face 4, one sample, no bounce) in two shards, then
#: their merge: the volume alone, then with reflection probes (each a prim of its own in the layer).
MERGE_VOLUME, MERGE_REFLECTION = (20, 5, 20), (0, 200, 400)


def _merge_fit(seconds: list[float]) -> dict[str, Any]:
    """Per-probe merge seconds by kind and the layer's per-prim² term, from the merges of the volume with 0, 200 and
    400 reflection probes (each reflection probe is a prim of the layer; the volume is one)."""
    volume = MERGE_VOLUME[0] * MERGE_VOLUME[1] * MERGE_VOLUME[2]
    rows = [[count, (count + 1) ** 2 - 1] for count in MERGE_REFLECTION[1:]]
    reflection, per_prim2 = _fit(rows, [t - seconds[0] for t in seconds[1:]])
    return {"merge_probe_seconds": {"irradiance": seconds[0] / volume, "reflection": reflection},
            "merge_prim_squared_seconds": per_prim2}


def _merge_run(folder: Path, generate_scene: Any, reflection: int) -> float:
    """Seconds of merging two shards of a bake of the merge volume and ``reflection`` probes, measured in this process
    after a first merge (imports and caches warm: the process start-up is ``process_seconds``)."""
    from bakery.pipeline.shards import merge_shards

    scene = generate_scene(folder / f"hall-merge-{reflection}", MERGE_VOLUME, reflection)
    common = ["--recipe", "console", "--face-size", "4", "--samples", "1", "--bounces", "0", "--no-reference",
              "--jobs", "1"]
    shards = []
    for i in (1, 2):
        shards.append(folder / f"merge-{reflection}-{i}.h5")
        result = subprocess.run([sys.executable, "-m", "bakery.cli", "bake", str(scene), "--shard", f"{i}/2", "-o",
                                 str(shards[-1]), *common], check=False, capture_output=True, text=True)
        if result.returncode != 0:
            raise RuntimeError(f"calibration shard failed ({result.returncode}): {result.stderr[-2000:]}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        merge_shards(shards, folder / f"warm-{reflection}.h5")
        start = time.perf_counter()
        merge_shards(shards, folder / f"merged-{reflection}.h5")
        return time.perf_counter() - start


def _pilot_seconds_per_ray(scene: Path, repeats: int = 3) -> float:
    """The pilot capture's seconds per traced ray on the calibration hall (default bounces; median of ``repeats``):
    the yardstick of :attr:`bakery.farm.cost.CostModel.ray_cost_ratio`."""
    from bakery.farm.cost import pilot_capture
    from bakery.pipeline.run import plan_bake
    from bakery.pipeline.settings import request_from

    request = request_from([scene], scene.with_suffix(".h5"), face_size=FACE_SIZES[0], samples=SAMPLES)
    source, plan = plan_bake(request)
    return float(np.median([pilot_capture(request, source, plan).seconds_per_ray for _ in range(repeats)]))


def _fit(rows: list[list[float]], values: list[float]) -> list[float]:
    solution, _ = nnls(np.asarray(rows, dtype=np.float64), np.asarray(values, dtype=np.float64))
    return [float(v) for v in solution]


def calibration_refusal(path: Path) -> str | None:
    """Why an existing file must not be replaced by a calibration (None: a calibration bakery wrote)."""
    from bakery.files import json_output_refusal

    return json_output_refusal(path, ("version", "process_seconds", "encodings"),
                               "a calibration written by bakery farm calibrate")


def calibrate(output: Path, work: Path | None = None, force: bool = False) -> dict[str, Any]:
    """Measure and write the calibration JSON to ``output`` (atomically; the output policy is checked before any
    measurement and before anything is created: its folder must exist; a new path or a calibration bakery wrote,
    ``force``: any file); returns it.

    SIGTERM unwinds like Ctrl-C for the whole run (``SystemExit(143)``, as during a bake): the running bake process
    is killed and the temporary folder of the bakes (MBs) removed — its default action left it behind."""
    from bakery.files import check_output_file, terminate_as_exit

    output = Path(output)
    check_output_file(output, "calibration", refusal=calibration_refusal, force=force)
    with terminate_as_exit():  # the in-process merges' own (a bake's) then leave this one in place
        return _calibrate(output, work)


def _calibrate(output: Path, work: Path | None) -> dict[str, Any]:
    from bakery.bench.scale import generate_scene
    from bakery.files import write_bytes_atomic

    runs = []
    load = os.getloadavg()  # other jobs on the machine slow every measurement; recorded with the result
    with tempfile.TemporaryDirectory(dir=work) as folder:
        for counts, reflection in SIZES:
            scene = generate_scene(Path(folder) / f"hall-{counts[0]}", counts, reflection)
            for face_size in FACE_SIZES:
                run = _bake(scene, Path(folder) / f"hall-{counts[0]}-{face_size}.h5", face_size, reference=False)
                run.update(n=face_size, **_features(scene, face_size))
                runs.append(run)
        # The same largest bake with reference errors: their cost, on top of the diagnostics without them.
        with_reference = _bake(scene, Path(folder) / "hall-reference.h5", FACE_SIZES[-1], reference=True)
        # And at the default bounces (paths end early: escaping rays, Russian roulette): the effective bounces.
        default_bounces = _bake(scene, Path(folder) / "hall-bounces.h5", FACE_SIZES[0], reference=False, bounces=None)
        merges = [_merge_run(Path(folder), generate_scene, count) for count in MERGE_REFLECTION]
        pilot_seconds = _pilot_seconds_per_ray(scene)
    irradiance_encodings = sum(1 for cls in ENCODINGS.values() if cls.kind == "irradiance")
    encodings: dict[str, dict[str, list[float]]] = {}
    for name, cls in ENCODINGS.items():
        rows, values = [], []
        for run in runs:
            count = run[cls.kind]
            n2 = run["n"] ** 2
            rows.append([1.0, n2, count, count * n2])
            values.append(run["summary"]["timings"].get(f"encode/{name}", 0.0))
        s0, s2, c0, c2 = _fit(rows, values)
        encodings[name] = {"setup": [s0, s2], "probe": [c0, c2]}
    capture_rows, capture_values, diag_rows, diag_values, rest_rows, rest_values = [], [], [], [], [], []
    for run in runs:
        timings = run["summary"]["timings"]
        capture_rows.append([run["probes"], run["rays"]])
        capture_values.append(timings.get("capture_seconds", 0.0))
        diag_rows.append([run["irradiance"], run["irradiance"] * run["n"] ** 2])
        diag_values.append(timings.get("diagnostics/irradiance", 0.0) / irradiance_encodings)
        measured = sum(v for k, v in timings.items() if k.startswith("encode/")) + timings.get("capture_seconds", 0.0) \
            + timings.get("diagnostics/irradiance", 0.0)
        rest_rows.append([1.0, run["probes"]])
        rest_values.append(run["wall"] - measured)
    capture_probe, per_ray = _fit(capture_rows, capture_values)
    # The same against the rays the bakes really traced (the pilot-based estimates of `bakery plan`), with the
    # default-bounces bake as a seventh row: its paths are longer, its rays as cheap.
    traced = [(r["probes"], r["summary"]["timings"].get("capture_rays", 0.0), r["summary"]["timings"].get(
        "capture_seconds", 0.0)) for r in runs + [dict(default_bounces, probes=runs[len(FACE_SIZES)]["probes"])]]
    _traced_probe, per_traced_ray = _fit([[p, rays] for p, rays, _ in traced], [t for _, _, t in traced])
    process, per_probe = _fit(rest_rows, rest_values)
    largest = runs[-1]
    extra = with_reference["summary"]["timings"].get("diagnostics/irradiance", 0.0) \
        - largest["summary"]["timings"].get("diagnostics/irradiance", 0.0)
    reference = max(extra, 0.0) / (largest["irradiance"] * largest["n"] ** 2)
    # capture ∝ 1 + b_eff: b_eff(default) from the capture time at the default bounces against BOUNCES (the larger
    # hall's first run: the same scene and face size).
    one_bounce = runs[len(FACE_SIZES)]["summary"]["timings"].get("capture_seconds", 0.0)
    ratio = default_bounces["summary"]["timings"].get("capture_seconds", 0.0) / max(one_bounce, 1e-9)
    effective = max(ratio * (1 + BOUNCES) - 1, float(BOUNCES))
    data = {
        "version": CALIBRATION_VERSION,
        "measured": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
                    "load_average_1_5_15_min": [round(v, 2) for v in load]},
        "bench": {"scene": "bakery.bench.scale.generate_scene", "sizes": [list(c) + [r] for c, r in SIZES],
                  "face_sizes": list(FACE_SIZES), "samples": SAMPLES, "bounces": BOUNCES,
                  "runs": [{"n": r["n"], "irradiance": r["irradiance"], "reflection": r["reflection"],
                            "wall_seconds": round(r["wall"], 3)} for r in runs]
                  + [{"n": largest["n"], "reference_errors": True, "wall_seconds": round(with_reference["wall"], 3)},
                     {"n": FACE_SIZES[0], "bounces": CaptureSettings().bounces,
                      "wall_seconds": round(default_bounces["wall"], 3)}]},
        "process_seconds": process, "per_probe_seconds": per_probe,
        **_merge_fit(merges),
        "capture_probe_seconds": capture_probe, "seconds_per_ray": per_ray,
        "seconds_per_traced_ray": per_traced_ray,
        "pilot_seconds_per_ray": pilot_seconds,
        "loaded_probe_seconds": 0.002, "unknown_encoding_seconds": 0.01,
        "irradiance_diagnostics": _fit(diag_rows, diag_values),
        "reference_seconds_per_texel": reference,
        "effective_bounces": {"default": CaptureSettings().bounces, "measured": effective},
        "encodings": encodings,
    }
    write_bytes_atomic(output, (json.dumps(data, indent=1, sort_keys=True) + "\n").encode())
    return data
