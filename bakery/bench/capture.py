"""Capture benchmark (issues 11, 14): rays/s and probes/s of the capture alone (no encoding, no store).

Scenes: the repository's examples (``examples/indoor``: a closed lit room, ``examples/outdoor``: a sphere row under the
sunny StinsonBeach dome, ``examples/plaza``: 272 lights, drawn from the light grid) at the default capture settings,
or the scenes given. Per scene it records the probes
rendered, rays traced, capture seconds (rendering only; reading and renderer setup — the Embree scene, the
once-per-process caches of :meth:`~bakery.capture.render.ProbeRenderer.prepare` and one warm-up render of the first
probe under another name, which takes a fresh process's first-touch costs out of a sub-second measurement, as a
bake worker amortises them over its batches — are reported apart), rays/s, probes/s and the achieved relative SH
noise (median, max). Timing is measured here, never asserted by tests.

Rays are every ray Embree traces (each probe's :attr:`bakery.capture.render.CaptureStats.rays`, summed): camera
rays, bounce (continuation) rays, shadow rays of next-event estimation, re-traced rays past cut-out hits, and the
probe's visibility rays towards the sun points and small distant lights. Analytic tests against light shapes are
not rays.

Probes are rendered as a bake worker renders them: in groups traced together (at most
:data:`~bakery.sources.usd_scene.GROUP_PROBES` probes, one :meth:`~bakery.capture.render.ProbeRenderer.render_many`
call each). ``processes`` > 1 renders the probes in that many forked worker processes (probe i in worker i mod P,
one renderer each, as the bake runs one worker per core); the workers wait for each other after their setup (a
barrier), so the measured span is rendering only. ``capture_seconds`` is the wall-clock span from the first
worker's first render to the last worker's last, ``rays_per_second`` the total rays over it, and
``process_rays_per_second`` each worker's rays over its own rendering time.
"""

from __future__ import annotations

import json
import multiprocessing
import queue
import time
from pathlib import Path

import numpy as np

REPOSITORY = Path(__file__).resolve().parents[2]
DEFAULT_SCENES = (REPOSITORY / "examples/indoor/indoor.usda", REPOSITORY / "examples/outdoor/outdoor.usda",
                  REPOSITORY / "examples/plaza/plaza.usda")


def _render_share(scene, probes: list, face_size: int, samples: int, bounces: int, target_noise: float,  # noqa: ANN001
                  barrier=None) -> dict:  # noqa: ANN001 - multiprocessing.Barrier
    """Render ``probes`` with one renderer as a bake worker does (groups of
    :func:`bakery.sources.usd_scene.render_groups`, one :meth:`~bakery.capture.render.ProbeRenderer.render_many`
    call each): rays, noise, setup seconds (renderer, caches, one warm-up render) and the (monotonic) span of the
    rendering. With a ``barrier``, rendering starts when every worker has finished its setup."""
    from bakery.capture.render import ProbeRenderer
    from bakery.sources.usd_scene import render_groups

    start = time.perf_counter()
    renderer = ProbeRenderer(scene, samples=samples, bounces=bounces, target_noise=target_noise)
    sizes: dict[int, list] = {}
    for probe in probes:
        sizes.setdefault(probe.resolution or face_size, []).append(probe)
    for size in sorted(sizes):
        renderer.prepare(size)  # once-per-process caches (filtered dome), as a bake worker builds them once
    if probes:  # first-touch costs of a fresh process (page faults of its first temporaries), not rendering speed
        renderer.render_many([np.asarray(probes[0].position)], next(iter(sizes)), ["warm-up"])
    setup = time.perf_counter() - start
    if barrier is not None:
        barrier.wait(timeout=600)
    rays, noise = 0, []
    first = time.monotonic()
    for size, members in sizes.items():
        for group in render_groups(members, 6 * size * size * samples):
            rendered = renderer.render_many([np.asarray(p.position) for p in group], size, [p.name for p in group])
            rays += sum(stats.rays for _cube, stats in rendered)
            noise.extend(stats.sh_noise for _cube, stats in rendered)
    last = time.monotonic()
    return {"rays": rays, "seconds": last - first, "noise": noise, "setup": setup, "first": first, "last": last}


_SHARED: dict = {}


def _worker(index: int, results) -> None:  # noqa: ANN001 - multiprocessing.Queue
    job = _SHARED["job"]
    share = job["probes"][index :: job["processes"]]
    try:
        results.put((index, _render_share(job["scene"], share, *job["settings"], barrier=job["barrier"])))
    except BaseException as error:  # noqa: BLE001 - reported by the parent; the other workers stop waiting
        job["barrier"].abort()
        results.put((index, {"error": f"{type(error).__name__}: {error}"}))


def _run_workers(scene, probes: list, processes: int, settings: tuple) -> list[dict]:  # noqa: ANN001
    """:func:`_render_share` of probe i in forked worker i mod ``processes``, the workers released together by a
    barrier after their setup; their results in worker order."""
    context = multiprocessing.get_context("fork")
    results = context.Queue()
    _SHARED["job"] = {"scene": scene, "probes": probes, "processes": processes, "settings": settings,
                      "barrier": context.Barrier(processes)}
    workers = [context.Process(target=_worker, args=(i, results), daemon=True) for i in range(processes)]
    shares: dict[int, dict] = {}
    try:
        for worker in workers:
            worker.start()
        while len(shares) < processes:
            try:
                index, share = results.get(timeout=1.0)
                shares[index] = share
            except queue.Empty:
                dead = [i for i, w in enumerate(workers) if i not in shares and w.exitcode not in (None, 0)]
                if dead:
                    raise RuntimeError(f"capture bench worker {dead[0]} died (exit code {workers[dead[0]].exitcode})"
                                       ) from None
        for worker in workers:
            worker.join()
    finally:
        _SHARED.clear()
        for worker in workers:
            if worker.is_alive():
                worker.terminate()
    errors = [share["error"] for share in shares.values() if "error" in share]
    if errors:
        raise RuntimeError(f"capture bench worker failed: {errors[0]}")
    return [shares[i] for i in range(processes)]


def _scene_name(path: Path) -> str:
    """The scene as the report names it: relative to the repository for its examples (the JSON is compared across
    machines), otherwise as given."""
    resolved = Path(path).resolve()
    return resolved.relative_to(REPOSITORY).as_posix() if resolved.is_relative_to(REPOSITORY) else str(path)


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
    else:
        shares = _run_workers(reading.scene, rendered, processes, settings)
    active = [s for s in shares if s["rays"]]
    seconds = max(s["last"] for s in active) - min(s["first"] for s in active) if active else 0.0
    rays = sum(s["rays"] for s in shares)
    noise = [x for s in shares for x in s["noise"]]
    return {
        "scene": _scene_name(path), "probes": len(rendered), "processes": processes, "face_size": face_size,
        "samples": samples, "bounces": bounces, "target_noise": target_noise,
        "triangles": reading.scene.triangle_count(), "lights": len(reading.scene.lights),
        "dome": reading.scene.dome is not None, "read_seconds": round(read_seconds, 3),
        "setup_seconds": round(max((s["setup"] for s in shares), default=0.0), 3),
        "capture_seconds": round(seconds, 3), "rays": rays,
        "rays_per_second": round(rays / seconds, 1) if seconds > 0 else 0.0,
        "process_rays_per_second": [round(s["rays"] / s["seconds"], 1) if s["seconds"] > 0 else 0.0
                                    for s in shares],
        "probes_per_second": round(len(rendered) / seconds, 3) if seconds > 0 else 0.0,
        "sh_noise_median": float(np.median(noise)) if noise else None,
        "sh_noise_max": float(np.max(noise)) if noise else None,
    }


def run_capture_bench(scenes: tuple[Path, ...] = (), output: Path | None = None, processes: int = 1,
                      force: bool = False, **options) -> dict:  # noqa: ANN003
    """Benchmark every scene (the examples by default); write ``capture.json`` into ``output`` if given
    (:mod:`bakery.bench.output` policy, checked before the run)."""
    from bakery.bench.output import check_bench_outputs, write_bench_file

    if output is not None:
        check_bench_outputs(output, ("capture.json",), force)
    if not scenes and not all(s.is_file() for s in DEFAULT_SCENES):
        raise FileNotFoundError("no scenes given, and the default scenes (examples/ of a bakery checkout) are not "
                                "installed with this bakery: name the USD scenes to benchmark")
    results = [bench_scene(Path(s), processes=processes, **options) for s in (scenes or DEFAULT_SCENES)]
    report = {"benchmark": "capture", "processes": processes, "scenes": results}
    if output is not None:
        write_bench_file(output, "capture.json", json.dumps(report, indent=2), force)
    return report
