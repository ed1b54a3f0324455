"""Scale benchmark (issue 5): a generated scene with a large irradiance probe volume and many reflection probes.

The scene is a 40 m × 12 m × 40 m hall (floor, walls, pillars) under a constant dome with three sphere lights; an
irradiance volume of ``volume_counts`` probes fills it and ``reflection`` reflection probes stand on a grid. Each
run is a bake through the one bake path (:func:`bakery.bake` with worker processes); the benchmark records wall
time, per-stage timings, peak resident memory of the parent, of the largest worker and of all workers together
(the kernel's high-water marks, looked at four times a second: :class:`_MemorySampler`), the store size and the
speed-up from 1 to 2 workers. ``--production`` (:data:`PRODUCTION`) is issue 14's production-size scene, exports
included.
"""

from __future__ import annotations

import json
import os
import platform
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

import numpy as np
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


def generate_scene(folder: Path, volume_counts=(25, 16, 25), reflection: int = 1000,
                   reflection_resolution: int = 0, force: bool = False) -> Path:
    """Write the benchmark scene (Y-up, metres) and return its path. ``reflection_resolution``: the reflection
    probes' ``bakery:capture:resolution`` (0: the bake's face size); ``hall.usda`` replaces only a file a bench
    wrote (:mod:`bakery.bench.output`) unless ``force``."""
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
    resolution = (f"\n            int bakery:capture:resolution = {int(reflection_resolution)}"
                  if reflection_resolution else "")
    reflection_probes = []
    for k in range(reflection):
        i, j, l = k % side, (k // side) % side, k // (side * side)
        x, y, z = -18 + 36 * (i + 0.5) / side, 1 + 10 * (l + 0.5) / max(1, (reflection + side * side - 1) // (side * side)), -18 + 36 * (j + 0.5) / side
        reflection_probes.append(f"""
        def BakeryReflectionProbe "R{k}"
        {{
            float bakery:influence:radius = 3{resolution}
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
    from bakery.bench.output import write_bench_file

    return write_bench_file(folder, "hall.usda", text, force)


#: Seconds between the memory sampler's looks at the process table while the workers run (module doc of
#: :class:`_MemorySampler`); while the store's writer runs (the workers are idle then) it looks every
#: :data:`WRITER_SAMPLE_SECONDS`.
SAMPLE_SECONDS = 0.25
WRITER_SAMPLE_SECONDS = 0.05


def _status_kib(pid: int | str, *keys: str) -> tuple[int, ...] | None:
    """Fields of ``/proc/<pid>/status`` in KiB (e.g. ``VmHWM``, the peak resident size the kernel keeps; ``VmRSS``),
    or None where there is no such file (not Linux, the process has exited)."""
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return None
    found = {}
    for line in lines:
        name, _, value = line.partition(":")
        if name in keys:
            found[name] = value.split()[0]
    if len(found) != len(keys):
        return None
    return tuple(int(found[k]) for k in keys)


class _MemorySampler:
    """Peak resident memory of this process and of each of its child processes (the bake's workers) during a bake.

    Peaks are the kernel's high-water marks (``VmHWM``, exact whatever happens between two looks): this process's
    is reset when sampling starts (``/proc/self/clear_refs`` 5), each worker's is read while it lives. A background
    thread looks every :data:`SAMPLE_SECONDS` — few enough looks that the sampler costs the bake nothing measurable:
    at 20 Hz its process-table scans took about 0.9 s of the parent's CPU in a 2-worker scale bake, time the busy
    workers lost, which lengthened the 2-worker bake by about 2 s (and so lowered the measured speed-up). The peak
    of all workers *together* is the largest sum of their current sizes at one look (a lower bound between looks).
    Without ``/proc`` (not Linux) the peaks are the sizes seen at the looks.

    ``VmHWM`` counts every resident page, those of the files a process maps included: a bake's parent maps the
    fields it spills to its work folder (:data:`bakery.pipeline.run.SPILL_FOLDER`), page cache the kernel may
    reclaim. Its anonymous memory (``RssAnon``: heap and private pages, what must stay in memory) has no kernel
    high-water mark: ``peak_parent_anon_mb`` is the largest seen at the looks (a lower bound between looks).

    The store's forked writer (:mod:`bakery.pipeline.background`) is not a worker: its resident size counts the
    parent's pages it shares, so its own pages (USS) are reported apart, looked at every
    :data:`WRITER_SAMPLE_SECONDS` while it runs. Children already running when sampling starts (an earlier trial's
    workers still exiting) are not this bake's."""

    def __init__(self) -> None:
        self.parent = psutil.Process()
        self.peak_parent = self.peak_worker = self.peak_workers_total = self.peak_writer = 0
        self.peak_parent_anon = 0
        self._parent_mark = False
        self._before: set[int] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    @staticmethod
    def _peak_and_current(process: psutil.Process) -> tuple[int, int]:
        """(peak, current) resident bytes of ``process``: VmHWM and VmRSS where the kernel has them, else RSS twice."""
        marks = _status_kib(process.pid, "VmHWM", "VmRSS")
        if marks is not None:
            return marks[0] * 1024, marks[1] * 1024
        rss = process.memory_info().rss
        return rss, rss

    def _look(self) -> bool:
        """One look at this process and its children; whether the store's writer is running."""
        from bakery.pipeline.background import children_known

        self._parent_peak()
        with children_known() as writers:
            children = self.parent.children(recursive=True)
        current, writing = [], False
        for child in children:
            try:
                if child.pid in writers:
                    writing = True
                    self.peak_writer = max(self.peak_writer, child.memory_full_info().uss)
                elif child.pid not in self._before:
                    peak, now = self._peak_and_current(child)
                    self.peak_worker = max(self.peak_worker, peak)
                    current.append(now)
            except psutil.Error:  # exited between the listing and the look
                pass
        if current:
            self.peak_workers_total = max(self.peak_workers_total, sum(current))
        return writing

    def _sample(self) -> None:
        while not self._stop.is_set():
            try:
                writing = self._look()
            except psutil.Error:
                writing = False
            self._stop.wait(WRITER_SAMPLE_SECONDS if writing else SAMPLE_SECONDS)

    def __enter__(self) -> _MemorySampler:
        self._before = {child.pid for child in self.parent.children(recursive=True)}
        try:  # reset this process's high-water mark to its current size (Linux ≥ 4.0)
            Path("/proc/self/clear_refs").write_text("5")
            self._parent_mark = _status_kib("self", "VmHWM") is not None
        except OSError:
            self._parent_mark = False
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self._parent_peak()

    def _parent_peak(self) -> None:
        marks = _status_kib("self", "VmHWM") if self._parent_mark else None
        self.peak_parent = max(self.peak_parent, marks[0] * 1024 if marks else self.parent.memory_info().rss)
        anon = _status_kib("self", "RssAnon")
        if anon is not None:
            self.peak_parent_anon = max(self.peak_parent_anon, anon[0] * 1024)

    def as_dict(self) -> dict[str, float]:
        anon = {"peak_parent_anon_mb": self.peak_parent_anon / 2**20} if self.peak_parent_anon else {}
        return {"peak_parent_mb": self.peak_parent / 2**20, **anon, "peak_worker_mb": self.peak_worker / 2**20,
                "peak_workers_total_mb": self.peak_workers_total / 2**20,
                "peak_store_writer_uss_mb": self.peak_writer / 2**20}


#: A progress display: a context manager yielding the bake's ``progress(done, total)`` callback (the CLI's bar).
ProgressBar = Callable[[], AbstractContextManager[Callable[[int, int], None] | None]]


def _measured_bake(scene: Path, store: Path, recipe: str, face_size: int, jobs: int,
                   encoding_settings: dict[str, dict] | None, progress_bar: ProgressBar | None) -> dict[str, Any]:
    """One bake through the one bake path (:func:`bakery.bake`, ``jobs`` worker processes) with wall time, per-stage
    timings and peak memory."""
    import bakery

    for stale in (store, store.with_name(store.stem + ".bake.usda")):
        stale.unlink(missing_ok=True)
    with _MemorySampler() as memory, (progress_bar or nullcontext)() as progress:
        start = time.perf_counter()
        summary = bakery.bake(scene, store, recipe=recipe, face_size=face_size, jobs=jobs, resume=False,
                              encoding_settings=encoding_settings, progress=progress)
        wall = time.perf_counter() - start
    timings = summary.timings
    return {"wall_seconds": wall, **memory.as_dict(), "store_mb": store.stat().st_size / 2**20,
            "probes_per_second": summary.probes_per_second, "rays_per_second": timings.get("rays_per_second", 0.0),
            "stages": _stages(timings), "worker_seconds": {k: v for k, v in sorted(timings.items())
                                                           if k.endswith("_seconds") or k.startswith(("encode/", "diagnostics/"))}}


def _stages(timings: dict[str, float]) -> dict[str, float]:
    """Wall seconds of the parent's stages: read + plan, the workers (capture, encode, diagnostics of every batch),
    merge + finalize + write of store and layer."""
    return {"read_plan": timings.get("parent/read_plan", 0.0), "workers": timings.get("parent/workers", 0.0),
            "merge_finalize_write": timings.get("parent/merge_finalize_write", 0.0)}


def _median_run(trials: list[dict[str, Any]]) -> dict[str, Any]:
    """The trial of median wall time (the lower middle of an even count), with every trial's wall seconds."""
    ordered = sorted(trials, key=lambda t: t["wall_seconds"])
    return {**ordered[(len(ordered) - 1) // 2], "wall_seconds_runs": [t["wall_seconds"] for t in trials]}


def run_scale_bench(out_dir: Path, volume_counts=(25, 16, 25), reflection: int = 1000, recipe: str = "console",
                    face_size: int = 16, jobs: tuple[int, ...] = (1, 2), reflection_resolution: int = 0,
                    encoding_settings: dict[str, dict] | None = None, exports: tuple[str, ...] = (),
                    progress_bar: ProgressBar | None = None, repeats: int = 1, force: bool = False) -> dict:
    """Bake the generated scene with each worker count (then export the last store in each of ``exports``);
    returns and writes ``scale.json``.

    Per run: wall seconds, peak memory of the parent (and its anonymous memory, sampled: ``peak_parent_anon_mb``),
    of the largest worker and of all workers together (and the own pages of the store's forked writer,
    ``peak_store_writer_uss_mb``), store size, probes/s, capture rays/s, the parent's stages and the summed worker seconds per step (``capture_seconds``,
    ``encode/<encoding>``, ``diagnostics/…``; summed over workers, so they exceed the wall time with 2 workers).

    With ``repeats`` > 1 the worker counts alternate (1, 2, 1, 2, …: the shared machine's drift falls on both) and each
    count reports its median-wall trial, with every trial's wall time in ``wall_seconds_runs``; ``speedup_1_to_2``
    is then the ratio of the median walls, ``speedup_1_to_2_runs`` the ratio within each repetition and
    ``speedup_1_to_2_median_of_runs`` their median (the side-by-side statistic: it scatters less with the neighbours'
    load only when the machine's speed holds within a repetition)."""
    from bakery.bench.output import check_bench_outputs, write_bench_file

    check_bench_outputs(out_dir, ("scale.json",), force)
    check_bench_outputs(out_dir / "scene", ("hall.usda",), force)
    scene = generate_scene(out_dir / "scene", volume_counts, reflection, reflection_resolution, force)
    if encoding_settings is None and reflection_resolution:
        encoding_settings = reflection_at_capture_size(recipe, reflection_resolution)
    trials: dict[int, list[dict[str, Any]]] = {n: [] for n in jobs}
    store = out_dir / "hall.h5"
    for _ in range(max(1, repeats)):
        for n in jobs:
            store = out_dir / f"hall-j{n}.h5"
            trials[n].append(_measured_bake(scene, store, recipe, face_size, n, encoding_settings, progress_bar))
    runs = {n: _median_run(t) for n, t in trials.items()}
    exported = {}
    if exports:
        from bakery.export import export_store

        for fmt in exports:
            with _MemorySampler() as memory:
                start = time.perf_counter()
                result = export_store(store, out_dir / "exports" / fmt, fmt)
                seconds = time.perf_counter() - start
            exported[fmt] = {"seconds": seconds, "files": len(result.files), "peak_mb": memory.peak_parent / 2**20}
    probes = volume_counts[0] * volume_counts[1] * volume_counts[2] + reflection
    result = {"probes": probes, "irradiance_probes": probes - reflection, "reflection_probes": reflection,
              "recipe": recipe, "face_size": face_size, "reflection_resolution": reflection_resolution or face_size,
              "encoding_settings": encoding_settings or {}, "cpus": os.cpu_count(), "machine": platform.platform(),
              "date": time.strftime("%Y-%m-%d"), "runs": {str(n): r for n, r in runs.items()}}
    if exported:
        result["exports"] = exported
        result["total_seconds"] = runs[jobs[-1]]["wall_seconds"] + sum(e["seconds"] for e in exported.values())
    if 1 in runs and 2 in runs:
        result["speedup_1_to_2"] = runs[1]["wall_seconds"] / runs[2]["wall_seconds"]
        result["speedup_1_to_2_runs"] = [a["wall_seconds"] / b["wall_seconds"] for a, b in zip(trials[1], trials[2])]
        result["speedup_1_to_2_median_of_runs"] = float(np.median(result["speedup_1_to_2_runs"]))
    write_bench_file(out_dir, "scale.json", json.dumps(result, indent=2), force)
    return result


def reflection_at_capture_size(recipe: str, face_size: int) -> dict[str, dict[str, Any]]:
    """Encoding settings that put ``recipe``'s reflection encodings which follow the bake's face size (their chains)
    at the reflection probes' capture size ``face_size`` instead, and make those that can drop the capture keep it
    (``keep_capture``), so that the store can be exported."""
    import dataclasses

    from bakery.encodings import ENCODINGS
    from bakery.pipeline.recipe import load_recipe

    settings: dict[str, dict[str, Any]] = {}
    for name in load_recipe(recipe).targets.get("reflection", ()):
        keys = {f.name for f in dataclasses.fields(ENCODINGS[name].Params)}
        entry = {"face_size": face_size} if ENCODINGS[name].follows_bake_face_size else {}
        entry |= {"keep_capture": True} if "keep_capture" in keys else {}
        if entry:
            settings[name] = entry
    return settings


#: ``bakery bench scale --production``: the production-size scene of issue 14 — 10,000 irradiance probes at face 32
#: and 1,000 reflection probes captured at 128² with the ``console`` recipe's reflection encoding (its chain at the
#: capture's 128², keeping the capture for the export: :func:`reflection_at_capture_size`), 2 workers, then exported
#: as KTX2 (the engine-neutral container).
PRODUCTION = {"volume_counts": (25, 16, 25), "reflection": 1000, "recipe": "console", "face_size": 32,
              "reflection_resolution": 128, "jobs": (2,), "exports": ("ktx2",)}
