"""Pareto benchmark: encode time per probe against error vs the exact reference, for every registered encoding and
its parameters, on a folder of environments. Results are saved as JSON so that versions can be compared.

Protocol
    Environments: every ``.hdr``/``.exr`` under ``env_dir`` (``quick``: the first two). Each is resampled to the
    bake grid at every capture face size N of the grid below; the probes of all environments form one batch.
    Time per probe: wall time of ``encoding.encode(batch)`` on a fresh :class:`~bakery.probe.ProbeBatch` (so the
    SH projection is included) divided by the probe count; ``cold`` is the first call (includes building cached
    operators, e.g. SH-exp's W and A⁺), ``warm`` the best of the following ``repeats`` calls. The Pareto front uses
    ``warm``. Resampling to the bake grid is the capture's cost and is reported separately (``resample_s``).
    Irradiance error: relative RMSE √Σ(E−E_ref)²/√ΣE_ref² over 1024 Fibonacci normals and RGB, E_ref the brute-force
    cosine convolution of the full-resolution image; averaged over environments (also max).
    Reflection error: relative MSE Σ(E−E_ref)²/ΣE_ref² per (α, material) over 64 (v, n) rows (Fibonacci normals,
    views on each normal's hemisphere), α = r², r ∈ {0.5, 0.67, 0.83, 1} (seed 000: α ∈ [0.25, 1]),
    chrome (F0 = 1) and glass (F0 = 0.04); E_ref by brute-force integration of the full-resolution image; averaged
    over α, materials and environments.
    Parameters: capture face size for every encoding; for encodings whose default settings have them, the keys of
    :data:`PARAMETER_GRID` (SH-exp P order ``p_band``, ``fit`` log/weighted; split-sum ``n_levels``). The face size is
    passed as the encoding's ``face_size`` setting when it has one (split-sum chain size).
    Pareto-optimal: no other variant of the same kind is both faster (warm) and more accurate (mean error).
"""

from __future__ import annotations

import itertools
import json
import os
import platform
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

import bakery
from bakery.bench.irradiance import find_environments
from bakery.encodings import ENCODINGS
from bakery.environment.io import read_environment
from bakery.environment.resample import environment_samples, resample_to_cube
from bakery.errors import BakeryWarning
from bakery.irradiance.reference import reference_irradiance
from bakery.probe import ProbeBatch
from bakery.sphere.fibonacci import fibonacci_directions

FACE_SIZES = (8, 16, 32, 64)
QUICK_FACE_SIZES = (8, 32)
REFLECTION_FACE_SIZES = (16, 32, 64)
QUICK_REFLECTION_FACE_SIZES = (16,)
#: Extra settings explored when an encoding's defaults have the key (quick mode: defaults only).
PARAMETER_GRID: dict[str, tuple[Any, ...]] = {"p_band": (2, 3, 4), "fit": ("log", "weighted"), "n_levels": (4, 6)}
ALPHAS = tuple(float(r * r) for r in np.linspace(0.5, 1.0, 4))
MATERIALS = {"chrome": 1.0, "glass": 0.04}
NORMALS = 1024
REFLECTION_ROWS = 64


def _variants(cls: type, quick: bool) -> list[dict[str, Any]]:
    defaults = cls().settings
    keys = [] if quick else [k for k in PARAMETER_GRID if k in defaults]
    combos = itertools.product(*(PARAMETER_GRID[k] for k in keys))
    return [dict(zip(keys, values, strict=True)) for values in combos] or [{}]


def reflection_rows(count: int = REFLECTION_ROWS) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic (v, n): Fibonacci normals; views uniform on each normal's hemisphere with n·v ≥ 0.05."""
    n = fibonacci_directions(count)
    v = np.random.default_rng(0).normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(np.sum(v * n, axis=1, keepdims=True) < 0, -v, v)
    v = v + n * np.maximum(0.05 - np.sum(v * n, axis=1, keepdims=True), 0.0)
    return v / np.linalg.norm(v, axis=1, keepdims=True), n


def _time_encode(encoding: Any, cubes: np.ndarray, repeats: int) -> tuple[dict[str, np.ndarray], float, float]:
    start = time.perf_counter()
    fields = encoding.encode(ProbeBatch(cubes))
    cold = time.perf_counter() - start
    warm = cold
    for _ in range(repeats):
        start = time.perf_counter()
        fields = encoding.encode(ProbeBatch(cubes))
        warm = min(warm, time.perf_counter() - start)
    return fields, cold, warm


def _relative_rmse(values: np.ndarray, reference: np.ndarray) -> np.ndarray:
    num = np.sqrt(np.sum((values - reference) ** 2, axis=(1, 2)))
    den = np.sqrt(np.sum(reference**2, axis=(1, 2)))
    return num / np.where(den > 0, den, 1.0)


def pareto_front(points: list[tuple[float, float]]) -> list[bool]:
    """Flags of the points (time, error) not dominated by another (≤ in both and < in one)."""
    flags = []
    for i, (t, e) in enumerate(points):
        dominated = any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for j, (t2, e2) in enumerate(points) if j != i)
        flags.append(not dominated)
    return flags


def run_pareto_bench(env_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str], quick: bool = False,
                     repeats: int = 2, force: bool = False) -> dict[str, Any]:
    """Run the benchmark (module doc) and write ``pareto.json``, ``pareto.md`` and one SVG plot per kind into
    ``out_dir`` (refused before the run if one of them is a file bench did not write, unless ``force``). Returns
    the result dictionary (what ``pareto.json`` holds)."""
    from bakery.bench.output import check_bench_outputs

    env_dir, out = Path(env_dir), Path(out_dir)
    check_bench_outputs(out, PARETO_FILES, force)
    paths = find_environments(env_dir)[: 2 if quick else None]
    if not paths:
        from bakery.errors import InputError

        raise InputError(f"{env_dir}: no .hdr/.exr environments found")
    started = time.perf_counter()
    images, samples = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BakeryWarning)
        for path in paths:
            image, _ = read_environment(path)
            images.append(image)
            samples.append(environment_samples(image))
    normals = fibonacci_directions(NORMALS)
    irr_reference = np.stack([reference_irradiance(s, normals, dtype=np.float32) for s in samples])
    kinds = {cls.kind for cls in ENCODINGS.values()}
    refl_reference = None
    view, normal = reflection_rows()
    if "reflection" in kinds:
        from bakery.reflection.reference import integrate_reflection, reflected_radiance

        refl_reference = np.zeros((len(samples), len(ALPHAS), len(MATERIALS), len(view), 3))
        for e, s in enumerate(samples):
            for a, alpha in enumerate(ALPHAS):
                e0, e1 = integrate_reflection(s, view, normal, np.full(len(view), alpha))
                for m, f0 in enumerate(MATERIALS.values()):
                    refl_reference[e, a, m] = reflected_radiance(e0, e1, np.full(len(view), f0))
    reference_s = time.perf_counter() - started

    cube_cache: dict[int, tuple[np.ndarray, float]] = {}

    def cubes_at(n: int) -> tuple[np.ndarray, float]:
        if n not in cube_cache:
            start = time.perf_counter()
            cube_cache[n] = (np.stack([resample_to_cube(im, n) for im in images]),
                             (time.perf_counter() - start) / len(images))
        return cube_cache[n]

    rows: list[dict[str, Any]] = []
    for name, cls in ENCODINGS.items():
        sizes = (QUICK_FACE_SIZES if quick else FACE_SIZES) if cls.kind == "irradiance" else \
            (QUICK_REFLECTION_FACE_SIZES if quick else REFLECTION_FACE_SIZES)
        defaults = cls().settings
        for params in _variants(cls, quick):
            for n in sizes:
                settings = {**defaults, **params}
                if "face_size" in defaults:
                    settings["face_size"] = n
                try:
                    encoding = cls(**settings)
                    cubes, resample_s = cubes_at(n)
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", BakeryWarning)
                        fields, cold, warm = _time_encode(encoding, cubes, repeats)
                    if cls.kind == "irradiance":
                        per_env = _relative_rmse(encoding.evaluate_irradiance(fields, normals), irr_reference)
                    else:
                        per_env = _reflection_errors(encoding, fields, view, normal, refl_reference)
                except (MemoryError, ValueError, RuntimeError) as error:  # a variant that cannot run is recorded
                    rows.append({"encoding": name, "kind": cls.kind, "face_size": n, "params": params,
                                 "error_message": f"{type(error).__name__}: {error}"})
                    continue
                rows.append({
                    "encoding": name, "kind": cls.kind, "face_size": n, "params": params,
                    "bytes_per_probe": encoding.bytes_per_probe(),
                    "time_per_probe_s": {"cold": cold / len(paths), "warm": warm / len(paths)},
                    "resample_s": resample_s,
                    "error": {"mean": float(np.mean(per_env)), "max": float(np.max(per_env)),
                              "per_environment": {p.name: float(x) for p, x in zip(paths, per_env, strict=True)}},
                })
    for kind in ("irradiance", "reflection"):
        ok = [r for r in rows if r["kind"] == kind and "error" in r]
        for r, flag in zip(ok, pareto_front([(r["time_per_probe_s"]["warm"], r["error"]["mean"]) for r in ok]),
                           strict=True):
            r["pareto"] = flag
    result = {
        "bakery_version": bakery.__version__, "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": {"platform": platform.platform(), "processor": platform.processor(), "cpus": os.cpu_count(),
                    "python": platform.python_version(), "numpy": np.__version__},
        "quick": quick, "environments": [str(p.relative_to(env_dir)) for p in paths],
        "metrics": {"irradiance": "relative RMSE vs exact irradiance (1024 Fibonacci normals, RGB)",
                    "reflection": "relative MSE vs brute-force reflection (64 (v,n) rows, α = r², r ∈ [0.5, 1], "
                                  "chrome + glass)"},
        "alphas": list(ALPHAS), "reference_s": reference_s, "rows": rows,
    }
    write_pareto(result, out, force)
    return result


def _reflection_errors(encoding: Any, fields: dict[str, np.ndarray], view: np.ndarray, normal: np.ndarray,
                       reference: np.ndarray) -> np.ndarray:
    shared = encoding.shared_tables()
    errors = np.zeros(reference.shape[0])
    for a, alpha in enumerate(ALPHAS):
        for m, f0 in enumerate(MATERIALS.values()):
            est = encoding.evaluate_reflection(fields, shared, view, normal, np.full(len(view), alpha),
                                               np.full(len(view), f0))
            ref = reference[:, a, m]
            den = np.sum(ref**2, axis=(1, 2))
            errors += np.sum((est - ref) ** 2, axis=(1, 2)) / np.where(den > 0, den, 1.0)
    return errors / (len(ALPHAS) * len(MATERIALS))


def _label(row: dict[str, Any]) -> str:
    params = ",".join(f"{k}={v}" for k, v in row["params"].items())
    return f"{row['encoding']} N={row['face_size']}" + (f" {params}" if params else "")


def format_pareto_table(result: dict[str, Any]) -> str:
    """Markdown tables (one per kind), Pareto-optimal rows in bold, sorted by warm time per probe."""
    out = []
    for kind in ("irradiance", "reflection"):
        rows = [r for r in result["rows"] if r["kind"] == kind]
        if not rows:
            continue
        out.append(f"### {kind} — {result['metrics'][kind]}\n")
        out.append("| variant | bytes/probe | ms/probe (warm) | ms/probe (cold) | mean error | max error | Pareto |")
        out.append("|---|---:|---:|---:|---:|---:|:---:|")
        for r in sorted((r for r in rows if "error" in r), key=lambda r: r["time_per_probe_s"]["warm"]):
            b = "**" if r.get("pareto") else ""
            out.append(f"| {b}{_label(r)}{b} | {r['bytes_per_probe']:,} | {1e3 * r['time_per_probe_s']['warm']:.3f} | "
                       f"{1e3 * r['time_per_probe_s']['cold']:.3f} | {r['error']['mean']:.4g} | {r['error']['max']:.4g} | "
                       f"{'✔' if r.get('pareto') else ''} |")
        for r in rows:
            if "error_message" in r:
                out.append(f"| {_label(r)} | – | – | – | – | – | failed: {r['error_message'][:80]} |")
        out.append("")
    return "\n".join(out)


#: The files :func:`write_pareto` may write (checked before the run: :mod:`bakery.bench.output`).
PARETO_FILES = ("pareto.json", "pareto.md", "pareto_irradiance.svg", "pareto_reflection.svg")


def write_pareto(result: dict[str, Any], out_dir: Path, force: bool = False) -> dict[str, Path]:
    from bakery.bench.output import write_bench_file
    from bakery.report.svg import scatter_plot

    paths = {"json": write_bench_file(out_dir, "pareto.json", json.dumps(result, indent=1), force),
             "md": write_bench_file(out_dir, "pareto.md", format_pareto_table(result), force)}
    for kind in ("irradiance", "reflection"):
        ok = [r for r in result["rows"] if r["kind"] == kind and "error" in r]
        if not ok:
            continue
        points = [{"label": r["encoding"] + ("" if not r["params"] else " " + ",".join(map(str, r["params"].values()))),
                   "x": 1e3 * r["time_per_probe_s"]["warm"], "y": r["error"]["mean"]} for r in ok]
        svg = scatter_plot(f"pareto-{kind}", f"{kind}: time vs error (all face sizes)", points,
                           "ms per probe (warm)", "mean " + ("relative RMSE" if kind == "irradiance" else "relative MSE"))
        paths[f"svg_{kind}"] = write_bench_file(out_dir, f"pareto_{kind}.svg", svg, force)
    return paths


def compare_pareto(old: dict[str, Any], new: dict[str, Any]) -> list[dict[str, Any]]:
    """Rows present in both results (same encoding, face size, params): warm-time ratio and error change."""
    def key(r: dict[str, Any]) -> str:
        return json.dumps([r["encoding"], r["face_size"], r["params"]], sort_keys=True)

    before = {key(r): r for r in old["rows"] if "error" in r}
    out = []
    for r in new["rows"]:
        if "error" in r and key(r) in before:
            o = before[key(r)]
            out.append({"variant": _label(r),
                        "time_ratio": r["time_per_probe_s"]["warm"] / max(o["time_per_probe_s"]["warm"], 1e-12),
                        "error_old": o["error"]["mean"], "error_new": r["error"]["mean"]})
    return out
