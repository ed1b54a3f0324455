"""SH-exponential fit speed, fused vs step-by-step (issue 14): ``bakery bench shexp-fit``.

Protocol
    Captures: every ``.hdr``/``.exr`` under ``env_dir`` resampled to ``face_size`` (default 128), repeated to a batch
    of ``batch_size`` (default 64 — a bake's batch); without ``env_dir``, deterministic sky-and-sun cubes.
    Settings: the default :class:`~bakery.reflection.shexp.SHExpSettings` (weighted) and ``fit = "log"``.
    For each: wall-clock median (and minimum) over ``repeats`` (≥ 5) runs of :func:`fit_shexp` (fused, current) and
    :func:`fit_shexp_stepwise` (the previous formulation, same least squares), interleaved in one process so that
    both see the same machine load; ms per probe = seconds / batch_size, and the CPU time of the process per probe
    (all BLAS threads; ``time.process_time``). The fused path's pieces are timed alone: the splat, W·F over the
    normal-cluster tiles and the low-rank slabs (what the fit multiplies) and W·F as the dense blocks (before
    either). Agreement: the largest coefficient difference and the relative RMS of E0 over the design rows between
    the two paths — the error against the plain fit is unchanged when they agree to float32 rounding.

    Bake configuration (``processes`` ≥ 2): a bake runs one single-threaded worker per core, each fitting its own
    batches. That many spawned processes (one BLAS thread each, as :mod:`bakery.pipeline.executors` starts them)
    fit their own copy of the batch ``repeats`` times, starting each round together at a barrier; ms per probe =
    the median round's wall-clock span (first start to last finish) / (processes · batch_size): the machine's fit
    throughput as a bake sees it; and each worker's CPU time per probe (median over workers and rounds): its work
    per probe without the time it waited for a core.
    The operators are built (or loaded from the operator cache, memory-mapped as in a bake, so the workers share
    one copy of W) before timing and reported separately; the workers tune the allocator as a bake's do
    (:mod:`bakery.allocator`).
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from bakery import operator_cache
from bakery.allocator import tune_allocator
from bakery.reflection.shexp import (
    SHExpSettings,
    build_operators,
    evaluate_e0,
    fit_design,
    fit_shexp,
    fit_shexp_stepwise,
    splat_flux,
)
from bakery.sphere.cubemap import cube_texel_directions


def synthetic_captures(face_size: int, count: int = 4) -> np.ndarray:
    """Sky gradient + ground + a one-texel sun per capture, the sun moving between captures (P, 6, N, N, 3)."""
    d = cube_texel_directions(face_size)
    sky = np.where(d[..., 1:2] > 0, (0.4 + 0.6 * d[..., 1:2]) * np.array([0.3, 0.5, 1.0]), [0.2, 0.15, 0.1])
    out = []
    for i in range(count):
        cube = sky.copy()
        angle = 2.0 * np.pi * i / count
        sun = np.array([np.cos(angle) * 0.6, 0.7, np.sin(angle) * 0.6])
        cube[np.unravel_index(np.argmax(d @ sun), d.shape[:3])] = 5e4 * np.array([1.0, 0.9, 0.8])
        out.append(cube)
    return np.stack(out).astype(np.float32)


def environment_captures(env_dir: Path, face_size: int) -> tuple[np.ndarray, list[str]]:
    from bakery.environment import resample_to_cube
    from bakery.environment.io import read_environment

    paths = sorted(p for p in Path(env_dir).rglob("*") if p.suffix.lower() in (".hdr", ".exr"))
    if not paths:
        raise FileNotFoundError(f"no .hdr/.exr environments under {env_dir}")
    return np.stack([resample_to_cube(read_environment(p)[0], face_size) for p in paths]), [p.stem for p in paths]


def _timings(fns: dict[str, Callable[[], object]], repeats: int,
             clock: Callable[[], float] = time.perf_counter) -> dict[str, list[float]]:
    """Interleaved runs of every function (one warm-up each), timed by ``clock``."""
    for fn in fns.values():
        fn()
    out: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for key, fn in fns.items():
            start = clock()
            fn()
            out[key].append(clock() - start)
    return out


def _bake_worker(args: tuple[np.ndarray, SHExpSettings, int, object]) -> list[tuple[float, float, float]]:
    """One bake-like worker: build the operators, then ``repeats`` rounds of fitting its batch, each started at the
    shared barrier; (start, end) monotonic seconds and the process's CPU seconds per round."""
    batch, settings, repeats, barrier = args
    operator_cache.install()  # as in a bake (bakery.encodings installs it): W from the shared on-disk cache
    tune_allocator()  # as every bake worker does (bakery.pipeline.worker)
    fit_shexp(batch, settings)  # operators and allocator warm
    rounds = []
    for _ in range(repeats):
        barrier.wait()
        start, cpu = time.monotonic(), time.process_time()
        fit_shexp(batch, settings)
        rounds.append((start, time.monotonic(), time.process_time() - cpu))
    return rounds


def bake_configuration_ms_per_probe(batch: np.ndarray, settings: SHExpSettings, processes: int,
                                    repeats: int) -> dict:
    """Fit throughput of ``processes`` single-threaded workers (module doc "Bake configuration")."""
    from bakery.pipeline.executors import _single_threaded_children

    context = multiprocessing.get_context("spawn")
    with _single_threaded_children(), context.Manager() as manager, context.Pool(processes) as pool:
        barrier = manager.Barrier(processes)
        rounds = pool.map(_bake_worker, [(batch, settings, repeats, barrier)] * processes)
    spans = [max(r[i][1] for r in rounds) - min(r[i][0] for r in rounds) for i in range(repeats)]
    per_probe = 1e3 / (processes * batch.shape[0])
    cpu = [r[i][2] for r in rounds for i in range(repeats)]  # one thread per worker: its CPU time is its work
    return {"processes": processes, "ms_per_probe": per_probe * float(np.median(spans)),
            "min_ms_per_probe": per_probe * float(np.min(spans)),
            "cpu_ms_per_probe_per_worker": 1e3 * float(np.median(cpu)) / batch.shape[0]}


def run_shexp_fit_bench(env_dir: Path | None = None, batch_size: int = 64, face_size: int = 128, repeats: int = 7,
                        echo: Callable[[str], object] | None = None, processes: int = 2) -> dict:
    """Fused vs step-by-step SH-exp fit (module doc); ``echo`` (e.g. ``print``) receives the table; ``processes``
    < 2 skips the bake configuration.

    Returns {"batch_size", "face_size", "repeats", "environments", "operator_build_s", "variants": {name:
    {"fused_ms_per_probe", "fused_min_ms_per_probe", "fused_cpu_ms_per_probe", "stepwise_ms_per_probe",
    "stepwise_min_ms_per_probe", "stepwise_cpu_ms_per_probe", "speedup", "max_abs_coefficient_difference",
    "rel_rms_e0_difference"}}, "fused_breakdown_ms_per_probe": {"splat", "W_times_F_tiles", "W_times_F_dense",
    "rest"}, "bake_configuration": {"processes", "ms_per_probe", "min_ms_per_probe",
    "cpu_ms_per_probe_per_worker"} or None}."""
    if repeats < 5:
        raise ValueError(f"repeats must be >= 5, got {repeats}")
    operator_cache.install()  # the operators a bake uses: built once, then memory-mapped from the on-disk cache
    if env_dir is not None:
        cubes, names = environment_captures(env_dir, face_size)
    else:
        cubes, names = synthetic_captures(face_size), ["synthetic sky + sun"]
    batch = np.ascontiguousarray(cubes[np.arange(batch_size) % len(cubes)], dtype=np.float32)
    default = SHExpSettings()
    variants = {"weighted (default)": default, "log (unweighted)": replace(default, fit="log")}
    start = time.perf_counter()
    for settings in variants.values():
        build_operators(settings, face_size)
    result: dict = {"batch_size": batch_size, "face_size": face_size, "repeats": repeats, "environments": names,
                    "operator_build_s": time.perf_counter() - start, "variants": {}}
    v, n, a = fit_design(default)
    per_probe = 1e3 / batch_size
    for key, settings in variants.items():
        fns = {"fused": lambda s=settings: fit_shexp(batch, s),
               "stepwise": lambda s=settings: fit_shexp_stepwise(batch, s)}
        runs = _timings(fns, repeats)
        cpu = _timings(fns, repeats, clock=time.process_time)
        fused, stepwise = fit_shexp(batch, settings), fit_shexp_stepwise(batch, settings)
        e_new = evaluate_e0(fused[: len(cubes)], v, n, a, settings)
        e_old = evaluate_e0(stepwise[: len(cubes)], v, n, a, settings)
        result["variants"][key] = {
            "fused_ms_per_probe": per_probe * float(np.median(runs["fused"])),
            "fused_min_ms_per_probe": per_probe * float(np.min(runs["fused"])),
            "fused_cpu_ms_per_probe": per_probe * float(np.median(cpu["fused"])),
            "stepwise_ms_per_probe": per_probe * float(np.median(runs["stepwise"])),
            "stepwise_cpu_ms_per_probe": per_probe * float(np.median(cpu["stepwise"])),
            "stepwise_min_ms_per_probe": per_probe * float(np.min(runs["stepwise"])),
            "speedup": float(np.median(runs["stepwise"]) / np.median(runs["fused"])),
            "max_abs_coefficient_difference": float(np.abs(fused - stepwise).max()),
            "rel_rms_e0_difference": float(np.sqrt(np.mean((e_new - e_old) ** 2)) / np.sqrt(np.mean(e_old**2))),
        }
    ops = build_operators(default, face_size)
    grids = tuple(b.face_size for b in ops.blocks)
    flux = splat_flux(batch, grids)
    pieces = _timings({"splat": lambda: splat_flux(batch, grids),
                       "W_times_F_tiles": lambda: ([t.weights @ np.take(flux[t.face_size], t.nodes, axis=0)
                                                    for t in ops.tiles],
                                                   [np.matmul(s.left, (s.right @ flux[s.face_size]).reshape(
                                                       s.left.shape[0], s.rank, -1)) for s in ops.low_rank]),
                       "W_times_F_dense": lambda: [b.weights @ flux[b.face_size] for b in ops.blocks]}, repeats)
    breakdown = {k: per_probe * float(np.median(v)) for k, v in pieces.items()}
    total = result["variants"]["weighted (default)"]["fused_ms_per_probe"]
    breakdown["rest"] = total - breakdown["splat"] - breakdown["W_times_F_tiles"]
    result["fused_breakdown_ms_per_probe"] = breakdown
    result["bake_configuration"] = (bake_configuration_ms_per_probe(batch, default, processes, repeats)
                                    if processes >= 2 else None)
    if echo is not None:
        echo(format_shexp_fit_table(result))
    return result


def format_shexp_fit_table(result: dict) -> str:
    """The bench result as a small Markdown table."""
    title = (f"SH-exp fit, batch {result['batch_size']} × 6×{result['face_size']}², median of {result['repeats']} "
             f"(min in brackets), ms/probe; operators {result['operator_build_s']:.2f} s")
    lines = [title,
             "", "| settings | fused (new) | CPU | step-by-step (old) | CPU | speed-up | max |Δ coeff| | rel. RMS ΔE0 |",
             "|---|---|---|---|---|---|---|---|"]
    for key, r in result["variants"].items():
        lines.append(f"| {key} | {r['fused_ms_per_probe']:.3f} ({r['fused_min_ms_per_probe']:.3f}) | "
                     f"{r['fused_cpu_ms_per_probe']:.3f} | "
                     f"{r['stepwise_ms_per_probe']:.3f} ({r['stepwise_min_ms_per_probe']:.3f}) | "
                     f"{r['stepwise_cpu_ms_per_probe']:.3f} | "
                     f"{r['speedup']:.2f}× | {r['max_abs_coefficient_difference']:.1e} | "
                     f"{r['rel_rms_e0_difference']:.1e} |")
    b = result["fused_breakdown_ms_per_probe"]
    # the rest is a difference of medians: below the pieces' own noise it is not a measurement
    rest = f"rest {b['rest']:.3f}" if b["rest"] > 0 else "rest below the timing noise (pieces timed alone)"
    lines += ["", f"fused, by piece: splat {b['splat']:.3f}, W·F {b['W_times_F_tiles']:.3f} (tiles and low-rank "
                  f"slabs; dense blocks "
                  f"{b['W_times_F_dense']:.3f}), {rest} ms/probe"]
    bake = result.get("bake_configuration")
    if bake:
        lines += [f"bake configuration, {bake['processes']} single-threaded processes: {bake['ms_per_probe']:.3f} "
                  f"({bake['min_ms_per_probe']:.3f}) ms/probe; CPU {bake['cpu_ms_per_probe_per_worker']:.3f} ms per "
                  f"probe in each worker"]
    return "\n".join(lines)
