"""Capture benchmark (issue 11): rays/s and probes/s of the capture alone (no encoding, no store), one process.

Scenes: the repository's examples (``examples/indoor``: a closed lit room, ``examples/outdoor``: a sphere row under the
sunny StinsonBeach dome) at the default capture settings, plus any scene given. Per scene it records the probes
rendered, rays traced, capture seconds (rendering only; reading and snapshotting are reported apart), rays/s,
probes/s and the achieved relative SH noise (median, max). Timing is measured here, never asserted by tests.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

REPOSITORY = Path(__file__).resolve().parents[2]
DEFAULT_SCENES = (REPOSITORY / "examples/indoor/indoor.usda", REPOSITORY / "examples/outdoor/outdoor.usda")


def bench_scene(path: Path, face_size: int = 32, samples: int = 4, bounces: int | None = None,
                target_noise: float = 0.0, probes: int | None = None) -> dict:
    """Capture speed of one scene (the first ``probes`` rendered probes, all by default)."""
    from bakery.capture.render import DEFAULT_BOUNCES, ProbeRenderer
    from bakery.usd.scene import read_scene

    start = time.perf_counter()
    reading = read_scene(path)
    read_seconds = time.perf_counter() - start
    start = time.perf_counter()
    renderer = ProbeRenderer(reading.scene, samples=samples, bounces=DEFAULT_BOUNCES if bounces is None else bounces,
                             target_noise=target_noise)
    setup_seconds = time.perf_counter() - start
    rendered = [p for p in reading.scene.probes if not p.image][: probes or None]
    rays, seconds, noise = 0, 0.0, []
    for probe in rendered:
        _cube, stats = renderer.render(np.asarray(probe.position), probe.resolution or face_size, probe.name)
        rays += stats.rays
        seconds += stats.seconds
        noise.append(stats.sh_noise)
    return {
        "scene": str(path), "probes": len(rendered), "face_size": face_size, "samples": samples,
        "bounces": renderer.bounces, "target_noise": target_noise, "triangles": reading.scene.triangle_count(),
        "lights": len(reading.scene.lights), "dome": reading.scene.dome is not None,
        "read_seconds": round(read_seconds, 3), "setup_seconds": round(setup_seconds, 3),
        "capture_seconds": round(seconds, 3), "rays": rays,
        "rays_per_second": round(rays / seconds, 1) if seconds > 0 else 0.0,
        "probes_per_second": round(len(rendered) / seconds, 3) if seconds > 0 else 0.0,
        "sh_noise_median": float(np.median(noise)) if noise else None,
        "sh_noise_max": float(np.max(noise)) if noise else None,
    }


def run_capture_bench(scenes: tuple[Path, ...] = (), output: Path | None = None, **options) -> dict:  # noqa: ANN003
    """Benchmark every scene (the examples by default); write ``capture.json`` into ``output`` if given."""
    results = [bench_scene(Path(s), **options) for s in (scenes or DEFAULT_SCENES)]
    report = {"benchmark": "capture", "processes": 1, "scenes": results}
    if output is not None:
        output = Path(output)
        output.mkdir(parents=True, exist_ok=True)
        (output / "capture.json").write_text(json.dumps(report, indent=2))
    return report
