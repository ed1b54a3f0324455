"""How good are `bakery plan`'s estimates? ``python -m bakery.farm.estimate_bench OUT [--volume 25,16,25]
[--reflection 1000] [--tasks 4] [--calibrate]``.

On the scale bench's generated hall (:func:`bakery.bench.scale.generate_scene`, recipe ``console``, face 16, default
capture) it plans the bake with N tasks, then measures with real ``bakery`` processes (``--jobs 1``): the whole bake
in one process, each of the plan's N ranges as a shard, and their merge; it checks that the merged store is the
one-process store byte for byte and writes ``OUT/estimate.json`` (estimates, wall and CPU seconds, load averages).
``--calibrate`` first measures a calibration on this machine (``bakery farm calibrate``) and uses it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


def _run(args: list[str], env: dict[str, str]) -> tuple[subprocess.CompletedProcess, float, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "bakery.cli", *args], capture_output=True, text=True, env=env,
                            check=False)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if result.returncode != 0:
        raise RuntimeError(f"bakery {' '.join(args[:2])} failed ({result.returncode}): {result.stderr[-2000:]}")
    return result, wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run_estimate_bench(out: Path, volume=(25, 16, 25), reflection: int = 1000, tasks: int = 4,
                       calibrate_first: bool = False) -> dict[str, Any]:
    from bakery.bench.scale import generate_scene

    out.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000"}
    log: dict[str, Any] = {"load_before": os.getloadavg()}
    calibration: list[str] = []
    if calibrate_first:
        from bakery.farm.calibrate import calibrate

        calibrate(out / "calibration.json")
        calibration = ["--calibration", str(out / "calibration.json")]
    scene = generate_scene(out / "scene", tuple(volume), reflection)
    settings = ["--recipe", "console", "--face-size", "16"]
    one = out / "one.h5"
    result, _, _ = _run(["plan", str(scene), "-o", str(one), "--tasks", str(tasks), "--json", "--no-resume",
                         *settings, *calibration], env)
    plan = json.loads(result.stdout)
    log["plan"] = {"plan_id": plan["plan_id"], "probes": plan["probes"], "batches": len(plan["batches"]),
                   "one_process_seconds": plan["estimate"]["one_process_seconds"], "chunking": plan["chunking"]}
    one.unlink(missing_ok=True)
    _, wall, cpu = _run(["bake", str(scene), "-o", str(one), "-j", "1", "--no-resume", *settings], env)
    log["one_process"] = {"estimated": plan["estimate"]["one_process_seconds"], "wall": wall, "cpu": cpu}
    shards = []
    log["tasks"] = []
    for probes, estimated in zip(plan["chunking"]["ranges"], plan["chunking"]["estimated_seconds"]):
        shard = out / "shards" / f"shard-{probes}.h5"
        shard.unlink(missing_ok=True)
        _, wall, cpu = _run(["bake", str(scene), "--probes", probes, "--plan-id", plan["plan_id"], "-o", str(shard),
                             "-j", "1", *settings], env)
        log["tasks"].append({"range": probes, "estimated": estimated, "wall": wall, "cpu": cpu})
        shards.append(str(shard))
    merged = out / "merged.h5"
    _, wall, cpu = _run(["merge", *shards, "-o", str(merged)], env)
    log["merge"] = {"estimated": plan["chunking"]["merge_seconds"], "wall": wall, "cpu": cpu}
    log["identical"] = merged.read_bytes() == one.read_bytes()
    log["load_after"] = os.getloadavg()
    for entry in [log["one_process"], *log["tasks"], log["merge"]]:
        entry["estimate_over_measured"] = round(entry["estimated"] / entry["wall"], 3)
    (out / "estimate.json").write_text(json.dumps(log, indent=1))
    return log


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--volume", default="25,16,25")
    parser.add_argument("--reflection", type=int, default=1000)
    parser.add_argument("--tasks", type=int, default=4)
    parser.add_argument("--calibrate", action="store_true")
    args = parser.parse_args()
    log = run_estimate_bench(args.out, tuple(int(v) for v in args.volume.split(",")), args.reflection, args.tasks,
                             args.calibrate)
    print(json.dumps(log, indent=1))


if __name__ == "__main__":
    main()
