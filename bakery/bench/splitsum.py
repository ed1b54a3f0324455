"""Split-sum prefilter speed and accuracy bench (issue 14): the sparse kernel operator vs filtered importance sampling
(``formulation="fis"``), side by side in one run: ``bakery bench splitsum``.

Protocol
    Chains: the split-sum encoding's (:class:`bakery.reflection.splitsum.SplitSumSettings` at ``face_size``; default
    6 levels 128 … 32, one sharp level α = 0.04 at 64²) and the hybrid encoding's bandwidth chain
    (:class:`bakery.reflection.splitsum.BandwidthChainSettings` of ``shexp_hybrid`` at ``face_size``; sharp levels
    α = 0.019 / 0.038 / 0.075 at 128² / 64² / 32²), every level computed (first level 0).
    Environments: ``env_paths`` (default: ``examples/data/StinsonBeach_512.hdr`` and, when ``../shared/data`` is
    present, Poly Haven ``park`` (sun) and ``city``), resampled to the cube grid with
    :func:`bakery.environment.resample_to_cube`.
    Speed: wall time per probe, median of ``repeats`` runs (``fis_repeats`` for FIS: 2.5 s / 55 s per probe), for
    each batch size in ``batch_sizes`` (batches cycle through the environments); FIS runs probe by probe, so its
    per-probe time does not depend on the batch (``fis_batch_sizes`` defaults to (1,)). Operators: build time cold
    (empty cache folder: build + checksummed save) and load time warm (from that folder, new process state), rows,
    nnz, nnz per row and MB (float32 data + int32 indices + indptr) of each sharp level.
    Accuracy: relative MSE Σ (x − x_exact)² / Σ x_exact² of each sharp level against the dense quadrature of the
    normalised kernel (:func:`bakery.reflection.splitsum._exact_prefilter_level`) at ``error_texels`` random texels
    of the level (seeded), per environment, for both formulations.
    cmft: timed only if a ``cmft`` executable is on PATH (it is not installed by bakery).

Returns a dict (``chains`` → name → {levels, speed, operators, errors}); prints a short table through ``echo``.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bakery.environment import resample_to_cube
from bakery.environment.io import read_environment
from bakery.reflection import prefilter_operator as po
from bakery.reflection import splitsum as ss

REPOSITORY = Path(__file__).resolve().parents[2]
DEFAULT_ENVIRONMENTS = (
    REPOSITORY / "examples" / "data" / "StinsonBeach_512.hdr",
    REPOSITORY.parent / "shared" / "data" / "hdri" / "polyhaven_1k" / "park.hdr",
    REPOSITORY.parent / "shared" / "data" / "hdri" / "polyhaven_1k" / "city.hdr",
)


def _median_seconds(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def _exact_at(cube: np.ndarray, alpha: float, size: int, texels: np.ndarray) -> np.ndarray:
    """:func:`bakery.reflection.splitsum._exact_prefilter_level` at selected texels (T, C) float64."""
    from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles

    n = cube.shape[1]
    src = cube_texel_directions(n).reshape(-1, 3)
    omega = cube_texel_solid_angles(n).reshape(-1)
    radiance = cube.reshape(-1, cube.shape[-1]).astype(np.float64)
    out_dirs = cube_texel_directions(size).reshape(-1, 3)[texels]
    out = np.empty((texels.size, radiance.shape[1]))
    for s in range(0, texels.size, 100):
        k = ss._kernel_profile(out_dirs[s : s + 100] @ src.T, alpha) * omega
        out[s : s + 100] = (k @ radiance) / k.sum(axis=1)[:, None]
    return out


def _chains(face_size: int) -> dict[str, object]:
    from bakery.encodings.hybrid import SHExpHybrid

    return {"split_sum_chain": ss.SplitSumSettings(face_size=face_size),
            "bandwidth_chain": SHExpHybrid(SHExpHybrid.Params(face_size=face_size)).chain}


def _sharp_levels(settings) -> list[tuple[int, float, int]]:
    """(k, α, N_k) of the levels the sharp formulation (operator / FIS) computes."""
    out = []
    for k, (a, size) in enumerate(zip(settings.level_alphas(), settings.level_sizes(), strict=True)):
        if a > 0 and ss.sh_band_limit(float(a), settings.sh_tolerance) > settings.max_sh_band:
            out.append((k, float(a), int(size)))
    return out


def _run(settings, cubes: np.ndarray) -> list:
    if isinstance(settings, ss.BandwidthChainSettings):
        return ss.prefilter_bandwidth_batch(cubes, settings)
    return ss.prefilter_batch(cubes, settings)


def _sharp_level(settings, cube: np.ndarray, alpha: float, size: int) -> np.ndarray:
    """One sharp level of one capture in the chain's formulation (what the chain computes for it)."""
    if isinstance(settings, ss.BandwidthChainSettings):
        return ss.prefilter_level(cube, alpha, size, settings)
    if settings.formulation == "fis":
        return ss._prefilter_fis(ss.build_mips(cube), alpha, size, settings.fis_samples).astype(np.float32)
    return ss._prefilter_sharp_batch(cube[None], [alpha], [size], settings)[0][0]


def _operator_stats(settings, face_size: int) -> list[dict]:
    """Cold build (empty cache folder) and warm load of each sharp level's operator (module doc)."""
    stats = []
    previous = os.environ.get("BAKERY_CACHE_DIR")
    with tempfile.TemporaryDirectory(prefix="bakery-bench-ops-") as folder:
        os.environ["BAKERY_CACHE_DIR"] = folder
        try:
            for k, alpha, size in _sharp_levels(settings):
                po.cached_prefilter_operator.cache_clear()
                start = time.perf_counter()
                op = ss._sharp_operator(alpha, size, face_size, settings.operator_tolerance, settings.operator_core)
                build = time.perf_counter() - start
                po.cached_prefilter_operator.cache_clear()
                start = time.perf_counter()
                op = ss._sharp_operator(alpha, size, face_size, settings.operator_tolerance, settings.operator_core)
                load = time.perf_counter() - start
                stats.append({"level": k, "alpha": alpha, "size": size, "rows": int(op.shape[0]),
                              "rows_all_faces": 6 * int(op.shape[0]), "cols": int(op.shape[1]), "nnz": int(op.nnz),
                              "nnz_per_row": op.nnz / op.shape[0],
                              "mb": (op.data.nbytes + op.indices.nbytes + op.indptr.nbytes) / 1e6,
                              "build_cold_s": build, "load_warm_s": load})
        finally:
            po.cached_prefilter_operator.cache_clear()
            if previous is None:
                os.environ.pop("BAKERY_CACHE_DIR", None)
            else:
                os.environ["BAKERY_CACHE_DIR"] = previous
    return stats


def run_splitsum_bench(
    face_size: int = 128, env_paths: list[Path] | None = None, batch_sizes: tuple[int, ...] = (1, 16),
    repeats: int = 5, fis_repeats: int = 1, fis_batch_sizes: tuple[int, ...] = (1,), error_texels: int = 1000,
    chains: tuple[str, ...] = ("split_sum_chain", "bandwidth_chain"), echo: Callable[[str], None] | None = print,
) -> dict:
    """Run the protocol (module doc) and return the result dict; prints the table through ``echo`` (None: silent)."""
    import bakery.encodings  # noqa: F401 - installs the on-disk operator cache

    paths = [Path(p) for p in (env_paths if env_paths is not None else DEFAULT_ENVIRONMENTS) if Path(p).is_file()]
    if not paths:
        raise FileNotFoundError("no environment images found for the split-sum bench (the defaults are "
                                "examples/data and ../shared/data of a bakery checkout): name the images to use")
    names = [p.stem for p in paths]
    cubes = np.stack([resample_to_cube(read_environment(p)[0], face_size) for p in paths]).astype(np.float32)
    rng = np.random.default_rng(14)
    result: dict = {"face_size": face_size, "environments": names, "batch_sizes": list(batch_sizes),
                    "repeats": repeats, "fis_repeats": fis_repeats, "chains": {}}
    for chain_name, settings in _chains(face_size).items():
        if chain_name not in chains:
            continue
        fis = dataclasses.replace(settings, formulation="fis")
        entry: dict = {"levels": [[float(a), int(s)] for a, s in zip(settings.level_alphas(), settings.level_sizes(),
                                                                      strict=True)],
                       "operators": _operator_stats(settings, face_size), "speed": {}, "errors": {}}
        _run(settings, cubes[:1])  # operators (warm, this process) and lookup tables
        for formulation, st, sizes, reps in (("operator", settings, batch_sizes, repeats),
                                             ("fis", fis, fis_batch_sizes, fis_repeats)):
            speed = {}
            for p in sizes:
                batch = np.ascontiguousarray(cubes[np.arange(p) % len(cubes)])
                speed[str(p)] = 1e3 * _median_seconds(lambda st=st, batch=batch: _run(st, batch), reps) / p
            entry["speed"][formulation] = speed  # ms per probe by batch size
        for k, alpha, size in _sharp_levels(settings):
            texels = rng.choice(6 * size * size, min(error_texels, 6 * size * size), replace=False)
            for name, cube in zip(names, cubes, strict=True):
                exact = _exact_at(cube, alpha, size, texels)
                for formulation, st in (("operator", settings), ("fis", fis))[: 2 if fis_batch_sizes else 1]:
                    got = _sharp_level(st, cube, alpha, size).reshape(-1, cube.shape[-1])[texels]
                    rel = float(np.sum((got - exact) ** 2) / np.sum(exact**2))
                    entry["errors"].setdefault(formulation, {}).setdefault(f"level{k}", {})[name] = rel
        result["chains"][chain_name] = entry
    cmft = shutil.which("cmft") or shutil.which("cmftRelease64")
    result["cmft"] = {"path": cmft, "note": "found on PATH, not timed by this version" if cmft else "not installed"}
    if echo is not None:
        echo(format_table(result))
    return result


def format_table(result: dict) -> str:
    """Short text table of :func:`run_splitsum_bench`'s result."""
    environments = ", ".join(result["environments"])
    lines = [f"split-sum prefilter bench, {result['face_size']}² captures, environments: {environments}"]
    for name, entry in result["chains"].items():
        lines.append(f"\n[{name}] levels (alpha, face): " + ", ".join(f"({a:.3g}, {s})" for a, s in entry["levels"]))
        lines.append("  ms/probe      " + "  ".join(f"batch {p:>3}" for p in entry["speed"]["operator"]))
        for formulation, speed in entry["speed"].items():
            if not speed:  # not measured (e.g. --no-fis): no row
                continue
            lines.append(f"  {formulation:<12}" + "  ".join(f"{v:9.1f}" for v in speed.values()))
        for op in entry["operators"]:
            lines.append(f"  operator level {op['level']} (alpha {op['alpha']:.3g}, {op['size']}²): "
                         f"{op['nnz_per_row']:.0f} nnz/row, {op['mb']:.0f} MB (face 0; ×6 rows by symmetry), "
                         f"build {op['build_cold_s']:.2f} s cold, load {1e3 * op['load_warm_s']:.0f} ms warm")
        for level in next(iter(entry["errors"].values()), {}):
            for formulation, errors in entry["errors"].items():
                cells = ", ".join(f"{env} {v:.2e}" for env, v in errors[level].items())
                lines.append(f"  rel. MSE vs exact {level} {formulation:<9}: {cells}")
    lines.append(f"\ncmft: {result['cmft']['note']}")
    return "\n".join(lines)
