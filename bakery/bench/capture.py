"""Capture benchmark (issues 11, 14): rays/s and probes/s of the capture alone (no encoding, no store).

Scenes: the repository's examples (``examples/indoor``: a closed lit room, ``examples/outdoor``: a sphere row under the
sunny StinsonBeach dome) at the default capture settings, plus any scene given. Per scene it records the probes
rendered, rays traced, capture seconds (rendering only; reading and renderer setup — the Embree scene and the
once-per-process caches of :meth:`~bakery.capture.render.ProbeRenderer.prepare` — are reported apart), rays/s,
probes/s and the achieved relative SH noise (median, max). Timing is measured here, never asserted by tests.

Rays are every ray Embree traces (:attr:`bakery.capture.tracer.SceneTracer.rays_cast`): camera rays, bounce
(continuation) rays, shadow rays of next-event estimation, re-traced rays past cut-out hits, and the probe's
visibility rays towards the sun points and small distant lights. Analytic tests against light shapes are not rays.

``processes`` > 1 renders the probes in that many forked worker processes (probe i in worker i mod P, one renderer
each, as the bake runs one worker per core); rays/s is then the total over the wall-clock span from the first
worker's first render to the last worker's last (setup excluded), and ``capture_seconds`` is that span.
"""

from __future__ import annotations

import json
import multiprocessing
import time
from pathlib import Path

import numpy as np

REPOSITORY = Path(__file__).resolve().parents[2]
DEFAULT_SCENES = (REPOSITORY / "examples/indoor/indoor.usda", REPOSITORY / "examples/outdoor/outdoor.usda")


def _render_share(scene, probes: list, face_size: int, samples: int, bounces: int, target_noise: float  # noqa: ANN001
                  ) -> dict:
    """Render ``probes`` with one renderer: rays, seconds, noise and the (monotonic) span of the rendering."""
    from bakery.capture.render import ProbeRenderer

    start = time.perf_counter()
    renderer = ProbeRenderer(scene, samples=samples, bounces=bounces, target_noise=target_noise)
    for size in sorted({p.resolution or face_size for p in probes}):
        renderer.prepare(size)  # once-per-process caches (filtered dome), as a bake worker builds them once
    setup = time.perf_counter() - start
    rays, seconds, noise = 0, 0.0, []
    first = time.monotonic()
    for probe in probes:
        _cube, stats = renderer.render(np.asarray(probe.position), probe.resolution or face_size, probe.name)
        rays += stats.rays
        seconds += stats.seconds
        noise.append(stats.sh_noise)
    return {"rays": rays, "seconds": seconds, "noise": noise, "setup": setup, "first": first,
            "last": time.monotonic()}


_SHARED: dict = {}


def _worker(index: int) -> dict:
    job = _SHARED["job"]
    return _render_share(job["scene"], job["probes"][index :: job["processes"]], *job["settings"])


def bench_scene(path: Path, face_size: int = 32, samples: int = 4, bounces: int | None = None,
                target_noise: float = 0.0, probes: int | None = None, processes: int = 1) -> dict:
    """Capture speed of one scene (the first ``probes`` rendered probes, all by default) in ``processes``
    processes."""
    from bakery.capture.render import DEFAULT_BOUNCES
    from bakery.usd.scene import read_scene

    start = time.perf_counter()
    reading = read_scene(path)
    read_seconds = time.perf_counter() - start
    bounces = DEFAULT_BOUNCES if bounces is None else bounces
    rendered = [p for p in reading.scene.probes if not p.image][: probes or None]
    settings = (face_size, samples, bounces, target_noise)
    if processes <= 1:
        shares = [_render_share(reading.scene, rendered, *settings)]
        seconds = shares[0]["seconds"]
    else:
        _SHARED["job"] = {"scene": reading.scene, "probes": rendered, "processes": processes, "settings": settings}
        try:
            with multiprocessing.get_context("fork").Pool(processes) as pool:
                shares = pool.map(_worker, range(processes))
        finally:
            _SHARED.clear()
        shares = [s for s in shares if s["rays"]]
        seconds = max(s["last"] for s in shares) - min(s["first"] for s in shares) if shares else 0.0
    rays = sum(s["rays"] for s in shares)
    noise = [x for s in shares for x in s["noise"]]
    return {
        "scene": str(path), "probes": len(rendered), "processes": processes, "face_size": face_size,
        "samples": samples, "bounces": bounces, "target_noise": target_noise,
        "triangles": reading.scene.triangle_count(), "lights": len(reading.scene.lights),
        "dome": reading.scene.dome is not None, "read_seconds": round(read_seconds, 3),
        "setup_seconds": round(max((s["setup"] for s in shares), default=0.0), 3),
        "capture_seconds": round(seconds, 3), "rays": rays,
        "rays_per_second": round(rays / seconds, 1) if seconds > 0 else 0.0,
        "probes_per_second": round(len(rendered) / seconds, 3) if seconds > 0 else 0.0,
        "sh_noise_median": float(np.median(noise)) if noise else None,
        "sh_noise_max": float(np.max(noise)) if noise else None,
    }


def run_capture_bench(scenes: tuple[Path, ...] = (), output: Path | None = None, processes: int = 1,
                      **options) -> dict:  # noqa: ANN003
    """Benchmark every scene (the examples by default); write ``capture.json`` into ``output`` if given."""
    results = [bench_scene(Path(s), processes=processes, **options) for s in (scenes or DEFAULT_SCENES)]
    report = {"benchmark": "capture", "processes": processes, "scenes": results}
    if output is not None:
        output = Path(output)
        output.mkdir(parents=True, exist_ok=True)
        (output / "capture.json").write_text(json.dumps(report, indent=2))
    return report
