"""Scale benchmark (issue 5): a generated scene with a large irradiance probe volume and many reflection probes.

The scene is a 40 m × 12 m × 40 m hall (floor, walls, pillars) under a constant dome with three sphere lights; an
irradiance volume of ``volume_counts`` probes fills it and ``reflection`` reflection probes stand on a grid. Each
run is a real ``bakery bake`` subprocess; the benchmark records wall time, peak resident memory of the parent and
of all workers together (sampled with psutil at 20 Hz), the store size and the speed-up from 1 to 2 workers.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import psutil


def _box(name: str, lo, hi, material: str) -> str:  # noqa: ANN001
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    pts = [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    points = ", ".join(f"({x}, {y}, {z})" for x, y, z in pts)
    return f"""
    def Mesh "{name}" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
        int[] faceVertexIndices = [0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3]
        point3f[] points = [{points}]
        rel material:binding = <{material}>
    }}"""


def generate_scene(folder: Path, volume_counts=(25, 16, 25), reflection: int = 1000) -> Path:
    """Write the benchmark scene (Y-up, metres) and return its path."""
    folder.mkdir(parents=True, exist_ok=True)
    meshes = [_box("Floor", (-20, -0.5, -20), (20, 0, 20), "/Hall/Grey")]
    for i, x in enumerate((-10, 0, 10)):
        for j, z in enumerate((-10, 0, 10)):
            meshes.append(_box(f"Pillar_{i}_{j}", (x - 0.5, 0, z - 0.5), (x + 0.5, 12, z + 0.5), "/Hall/Grey"))
    lights = "".join(f"""
    def SphereLight "Lamp{i}"
    {{
        float inputs:intensity = 200
        float inputs:radius = 0.25
        double3 xformOp:translate = ({x}, 10, {z})
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}""" for i, (x, z) in enumerate([(-15, -15), (5, 12), (15, -5)]))
    side = max(1, round(reflection ** (1 / 3)))
    reflection_probes = []
    for k in range(reflection):
        i, j, l = k % side, (k // side) % side, k // (side * side)
        x, y, z = -18 + 36 * (i + 0.5) / side, 1 + 10 * (l + 0.5) / max(1, (reflection + side * side - 1) // (side * side)), -18 + 36 * (j + 0.5) / side
        reflection_probes.append(f"""
        def BakeryReflectionProbe "R{k}"
        {{
            float bakery:influence:radius = 3
            double3 xformOp:translate = ({x:.3f}, {y:.3f}, {z:.3f})
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }}""")
    nx, ny, nz = volume_counts
    text = f"""#usda 1.0
(
    upAxis = "Y"
    metersPerUnit = 1
)

def Xform "Hall"
{{
    def Material "Grey"
    {{
        token outputs:surface.connect = </Hall/Grey/Surface.outputs:surface>
        def Shader "Surface"
        {{
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0.5, 0.5, 0.5)
            float inputs:roughness = 0.4
            token outputs:surface
        }}
    }}
    def DomeLight "Sky"
    {{
        float inputs:intensity = 1
    }}
    {"".join(meshes)}
    {lights}
    def Scope "Probes"
    {{
        def BakeryIrradianceProbeVolume "Volume"
        {{
            float3 bakery:volume:extent = (38, 11, 38)
            int3 bakery:volume:counts = ({nx}, {ny}, {nz})
            double3 xformOp:translate = (0, 6, 0)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }}
        {"".join(reflection_probes)}
    }}
}}
"""
    path = folder / "hall.usda"
    path.write_text(text)
    return path


def _run(command: list[str]) -> dict:
    start = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, "SOURCE_DATE_EPOCH": "1700000000"})
    parent = psutil.Process(process.pid)
    peak_parent = peak_workers = 0
    while process.poll() is None:
        try:
            peak_parent = max(peak_parent, parent.memory_info().rss)
            workers = sum(c.memory_info().rss for c in parent.children(recursive=True))
            peak_workers = max(peak_workers, workers)
        except psutil.Error:
            pass
        time.sleep(0.05)
    stdout, stderr = process.communicate()
    if process.returncode not in (0, 6):
        raise RuntimeError(f"bake failed ({process.returncode}): {stderr[-2000:]}")
    return {"wall_seconds": time.perf_counter() - start, "peak_parent_mb": peak_parent / 2**20,
            "peak_workers_mb": peak_workers / 2**20, "summary": json.loads(stdout)}


def run_scale_bench(out_dir: Path, volume_counts=(25, 16, 25), reflection: int = 1000, recipe: str = "console",
                    face_size: int = 16, jobs: tuple[int, ...] = (1, 2)) -> dict:
    """Bake the generated scene with each worker count; returns and writes ``scale.json``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = generate_scene(out_dir / "scene", volume_counts, reflection)
    runs = {}
    for n in jobs:
        store = out_dir / f"hall-j{n}.h5"
        for stale in (store, store.with_name(store.stem + ".bake.usda")):
            stale.unlink(missing_ok=True)
        command = [sys.executable, "-m", "bakery.cli", "bake", str(scene), "-o", str(store), "--recipe", recipe,
                   "--face-size", str(face_size), "--jobs", str(n), "--json", "--no-resume"]
        run = _run(command)
        run["store_mb"] = store.stat().st_size / 2**20
        runs[n] = run
    probes = volume_counts[0] * volume_counts[1] * volume_counts[2] + reflection
    result = {"probes": probes, "irradiance_probes": probes - reflection, "reflection_probes": reflection,
              "recipe": recipe, "face_size": face_size, "cpus": os.cpu_count(),
              "runs": {str(n): {k: v for k, v in r.items() if k != "summary"} | {
                  "probes_per_second": r["summary"]["probes_per_second"],
                  "rays_per_second": r["summary"]["timings"].get("rays_per_second", 0.0)} for n, r in runs.items()}}
    if 1 in runs and 2 in runs:
        result["speedup_1_to_2"] = runs[1]["wall_seconds"] / runs[2]["wall_seconds"]
    (out_dir / "scale.json").write_text(json.dumps(result, indent=2))
    return result
