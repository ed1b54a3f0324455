"""Glossy-reflection quality and speed bench (seed 000, Fig. 4–7 protocol): ``bakery bench reflection DIR``.

Protocol
    For every environment image in ``env_dir``: resample to the bake cube grid (``face_size``), encode with SH
    exponentials (``shexp``) and split-sum (``splitsum``) through the registered encodings (what a store holds,
    float16 chain included), and render orthographic spheres — chrome (F0 = 1) and glass (F0 = 0.04) — at
    α = r², r ∈ linspace(0.5, 1, 6) (α ∈ [0.25, 1], perceptually spaced [Bur12]) from two views (front, +Z;
    elevated, looking down 40°). The reference is the brute-force integral of Eq. 1 over the full-resolution image
    (:func:`bakery.reflection.reference.integrate_reflection`, exact texel solid angles). One case = (environment,
    material, view, α); MSE over the sphere's pixels and RGB; ratio = MSE(shexp) / MSE(splitsum) (< 1: SH-exp
    wins). Memory: bytes per probe of each encoding's stored fields (shared tables excluded).

    SH-exp is scored three ways: the default (albedo-normalised, luminance-weighted solve), the unweighted
    log-space solve (``fit="log"``, to measure the weighting against the plain fit) and the paper's formulation
    (unweighted, not albedo-normalised); and ``shexp_lights`` (SH-exp of the capture without its brightest texel
    clusters + those clusters as analytic lights) is scored against the same split-sum.

Speed (``speed=True``): single process, captures 6×N² (N = ``face_size``), batches of 64 probes (a bake's batch size).
    SH-exp fit: ms/probe and probes/s of the default (splatted multi-resolution grid, weighted solve), of the
    unweighted solve and of a finer grid, with a breakdown by step; each one's error against the plain fit (E0 at
    the design rows by brute force over every capture texel, same solve) on every environment.
    Split-sum chain: fast formulation (SH per-band scaling for rough levels, filtered importance sampling for
    sharp ones) vs the plain 1024-sample GGX importance sampling, ms/probe, and each one's error per level vs an
    exact dense quadrature of the same kernel at 512 texel directions.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from bakery.encodings.shexp import SHExp, SHExpLights
from bakery.encodings.splitsum import SplitSum
from bakery.environment import environment_samples, resample_to_cube
from bakery.environment.io import read_environment
from bakery.probe import ProbeBatch
from bakery.reflection import splitsum as ss
from bakery.reflection.reference import integrate_reflection, reflected_radiance
from bakery.reflection.shexp import (
    WEIGHT_MIN,
    SHExpSettings,
    _luminance_operator,
    build_operators,
    design_e0_samples,
    evaluate_e0,
    fit_shexp,
    log_e0,
    plain_e0_samples,
    row_weights,
    slab_face_sizes,
    solve_coefficients,
    solve_from_samples,
    splat_flux,
)
from bakery.sphere.fibonacci import fibonacci_directions

IMAGE_SUFFIXES = (".hdr", ".exr")
#: Result keys of the encodings (their registered names; the JSON keys stay the store's group names).
SHEXP, SPLITSUM, SHEXP_LIGHTS = SHExp.name, SplitSum.name, SHExpLights.name
PERCEPTUAL = np.linspace(0.5, 1.0, 6)
ALPHAS = PERCEPTUAL**2
MATERIALS = {"chrome": 1.0, "glass": 0.04}
VIEWS = {"front": np.array([0.0, 0.0, 1.0]), "elevated": np.array([0.0, np.sin(np.radians(40)), np.cos(np.radians(40))])}


def find_environments(folder: Path) -> list[Path]:
    return sorted(p for p in Path(folder).rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())


def sphere_normals(view: np.ndarray, resolution: int) -> np.ndarray:
    """Normals (K, 3) of the visible pixels of an orthographic unit sphere seen from ``view`` (towards the viewer),
    pixel centres of a resolution² image over [-1, 1]²."""
    up = np.array([0.0, 1.0, 0.0])
    right = np.cross(up, view)
    right /= np.linalg.norm(right)
    up = np.cross(view, right)
    c = (np.arange(resolution) + 0.5) / resolution * 2.0 - 1.0
    y, x = np.meshgrid(-c, c, indexing="ij")
    inside = x * x + y * y < 1.0
    z = np.sqrt(1.0 - x[inside] ** 2 - y[inside] ** 2)
    return x[inside, None] * right + y[inside, None] * up + z[:, None] * view


def _rows(resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[str, float, slice]]]:
    views, normals, alphas, cases = [], [], [], []
    start = 0
    for view_name, view in VIEWS.items():
        n = sphere_normals(view, resolution)
        for alpha in ALPHAS:
            views.append(np.broadcast_to(view, n.shape))
            normals.append(n)
            alphas.append(np.full(len(n), alpha))
            cases.append((view_name, float(alpha), slice(start, start + len(n))))
            start += len(n)
    return np.concatenate(views), np.concatenate(normals), np.concatenate(alphas), cases


def run_reflection_bench(
    env_dir: Path, out_dir: Path, speed: bool = False, face_size: int = 128, sphere_resolution: int = 20,
    plain_splitsum: bool = True,
) -> dict:
    """Run the quality protocol (and with ``speed`` the speed protocol); write ``reflection.json`` and
    ``reflection.md`` to ``out_dir``; return the result dict. ``plain_splitsum`` also scores the paper's split-sum
    setting (plain 1024-sample GGX importance sampling per texel; ~20 s per 128² probe)."""
    paths = find_environments(Path(env_dir))
    if not paths:
        raise FileNotFoundError(f"no .hdr/.exr environment images under {env_dir}")
    images = [read_environment(p)[0] for p in paths]
    names = [p.stem for p in paths]
    cubes = np.stack([resample_to_cube(img, face_size) for img in images])
    batch = ProbeBatch(cubes)
    shexp, split = SHExp(), SplitSum(face_size=face_size)
    paper = SHExp(fit="log", albedo_normalized=False)
    unweighted = SHExp(fit="log")
    lights = SHExpLights()
    t0 = time.perf_counter()
    fields_shexp = shexp.encode(batch)
    t1 = time.perf_counter()
    fields_split = split.encode(batch)
    t2 = time.perf_counter()
    fields_paper = paper.encode(batch)
    fields_log = unweighted.encode(batch)
    t3 = time.perf_counter()
    fields_lights = lights.encode(batch)
    t4 = time.perf_counter()
    plain_levels = None
    if plain_splitsum:  # the paper's split-sum: 1024-sample plain IS chain, stored as float16 like the encoding
        chains = [ss._reference_prefilter_chain(c, split.chain, 1024) for c in cubes]
        plain_levels = [np.stack([ch[i] for ch in chains]).astype(np.float16) for i in range(split.chain.n_levels)]
    view, normal, alpha, cases = _rows(sphere_resolution)
    rows = []
    for i, (name, image) in enumerate(zip(names, images, strict=True)):
        e0, e1 = integrate_reflection(environment_samples(image), view, normal, alpha)
        one = lambda fields: {k: v[i : i + 1] for k, v in fields.items()}  # noqa: E731
        for material, f0 in MATERIALS.items():
            f0s = np.full(len(alpha), f0)
            reference = reflected_radiance(e0, e1, f0s)
            est_shexp = shexp.evaluate_reflection(one(fields_shexp), shexp.shared_tables(), view, normal, alpha, f0s)[0]
            est_split = split.evaluate_reflection(one(fields_split), split.shared_tables(), view, normal, alpha, f0s)[0]
            est_paper = paper.evaluate_reflection(one(fields_paper), paper.shared_tables(), view, normal, alpha, f0s)[0]
            est_log = unweighted.evaluate_reflection(one(fields_log), unweighted.shared_tables(), view, normal, alpha,
                                                     f0s)[0]
            est_lights = lights.evaluate_reflection(one(fields_lights), lights.shared_tables(), view, normal, alpha,
                                                    f0s)[0]
            est_plain = None
            if plain_levels is not None:
                est_plain = split.evaluate_reflection({f"level{k}": lv[i : i + 1] for k, lv in enumerate(plain_levels)},
                                                      split.shared_tables(), view, normal, alpha, f0s)[0]
            for view_name, a, sl in cases:
                ref = reference[sl]
                mse_shexp = float(np.mean((est_shexp[sl] - ref) ** 2))
                mse_split = float(np.mean((est_split[sl] - ref) ** 2))
                mse_paper = float(np.mean((est_paper[sl] - ref) ** 2))
                mse_log = float(np.mean((est_log[sl] - ref) ** 2))
                mse_lights = float(np.mean((est_lights[sl] - ref) ** 2))
                mse_plain = float(np.mean((est_plain[sl] - ref) ** 2)) if est_plain is not None else float("nan")
                power = float(np.mean(ref**2))
                rows.append({
                    "environment": name, "material": material, "view": view_name, "alpha": a,
                    "mse_shexp": mse_shexp, "mse_splitsum": mse_split, "mse_shexp_paper": mse_paper,
                    "rel_mse_shexp": mse_shexp / power if power > 0 else 0.0,
                    "rel_mse_splitsum": mse_split / power if power > 0 else 0.0,
                    "ratio": mse_shexp / mse_split if mse_split > 0 else float("inf"),
                    "ratio_paper": mse_paper / mse_split if mse_split > 0 else float("inf"),
                    "mse_shexp_unweighted": mse_log,
                    "mse_shexp_lights": mse_lights,
                    "ratio_lights": mse_lights / mse_split if mse_split > 0 else float("inf"),
                    "ratio_lights_vs_plain": mse_lights / mse_plain if mse_plain > 0 else float("nan"),
                    "ratio_unweighted": mse_log / mse_split if mse_split > 0 else float("inf"),
                    "mse_splitsum_plain": mse_plain,
                    "ratio_vs_plain": mse_shexp / mse_plain if mse_plain > 0 else float("nan"),
                })
    ratios = np.array([r["ratio"] for r in rows])
    losses = [r for r in rows if r["ratio"] >= 1.0]
    result = {
        "protocol": {
            "face_size": face_size, "sphere_resolution": sphere_resolution, "alphas": [float(a) for a in ALPHAS],
            "materials": MATERIALS, "views": {k: v.tolist() for k, v in VIEWS.items()},
            "shexp_settings": shexp.settings, "splitsum_settings": split.settings,
            "shexp_lights_settings": lights.settings,
            "reference": "brute-force Eq. 1 over the full-resolution image (exact texel solid angles)",
        },
        "rows": rows,
        "summary": {
            "cases": len(rows),
            "shexp_wins": int(np.sum(ratios < 1.0)),
            "shexp_win_share": float(np.mean(ratios < 1.0)),
            "median_ratio": float(np.median(ratios)),
            "paper_formulation_wins": int(sum(r["ratio_paper"] < 1.0 for r in rows)),
            "paper_formulation_win_share": float(np.mean([r["ratio_paper"] < 1.0 for r in rows])),
            "unweighted_wins": int(sum(r["ratio_unweighted"] < 1.0 for r in rows)),
            "unweighted_geometric_mean_ratio": float(np.exp(np.mean(np.log(np.maximum(
                [r["ratio_unweighted"] for r in rows], 1e-30))))),
            "weighted_beats_unweighted": float(np.mean([r["mse_shexp"] < r["mse_shexp_unweighted"] for r in rows])),
            "lights_wins": int(sum(r["ratio_lights"] < 1.0 for r in rows)),
            "lights_win_share": float(np.mean([r["ratio_lights"] < 1.0 for r in rows])),
            "lights_win_share_vs_plain_splitsum": float(np.mean([r["ratio_lights_vs_plain"] < 1.0 for r in rows])),
            "lights_geometric_mean_ratio": float(np.exp(np.mean(np.log(np.maximum(
                [r["ratio_lights"] for r in rows], 1e-30))))),
            "lights_memory_ratio": split.bytes_per_probe() / lights.bytes_per_probe(),
            "wins_at_alpha_ge_0.36": float(np.mean([r["ratio"] < 1.0 for r in rows if r["alpha"] > 0.3])),
            "wins_at_alpha_ge_0.49": float(np.mean([r["ratio"] < 1.0 for r in rows if r["alpha"] > 0.4])),
            "win_share_vs_plain_splitsum": float(np.mean([r["ratio_vs_plain"] < 1.0 for r in rows])),
            "paper_formulation_win_share_vs_plain": float(np.mean([
                r["mse_shexp_paper"] < r["mse_splitsum_plain"] for r in rows])),
            "geometric_mean_ratio": float(np.exp(np.mean(np.log(np.maximum(ratios, 1e-30))))),
            "bytes_per_probe": {SHEXP: shexp.bytes_per_probe(), SPLITSUM: split.bytes_per_probe(),
                                SHEXP_LIGHTS: lights.bytes_per_probe()},
            "memory_ratio": split.bytes_per_probe() / shexp.bytes_per_probe(),
            "losses_by_environment": _count(losses, "environment"),
            "losses_by_alpha": _count(losses, "alpha"),
            "losses_by_material": _count(losses, "material"),
            "encode_ms_per_probe": {SHEXP: 1e3 * (t1 - t0) / len(names),
                                    f"{SPLITSUM}_fast": 1e3 * (t2 - t1) / len(names),
                                    SHEXP_LIGHTS: 1e3 * (t4 - t3) / len(names)},
        },
    }
    if speed:
        result["speed"] = run_speed(cubes, names)
    write_results(result, Path(out_dir))
    return result


def _count(rows: list[dict], key: str) -> dict:
    out: dict[str, int] = {}
    for r in rows:
        k = str(round(r[key], 4)) if isinstance(r[key], float) else r[key]
        out[k] = out.get(k, 0) + 1
    return out


def _time(fn, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def run_speed(cubes: np.ndarray, names: list[str], batch_size: int = 64, plain_probes: int = 2) -> dict:
    """Speed protocol of the module doc on captures ``cubes`` (P, 6, N, N, 3)."""
    from dataclasses import replace

    default = SHExpSettings()
    variants = {"default": default, "unweighted": replace(default, fit="log"),
                "grid32": replace(default, fit_face_size=32)}
    n = int(cubes.shape[2])
    start = time.perf_counter()
    build_operators(default, n)
    build_seconds = time.perf_counter() - start
    big = np.ascontiguousarray(cubes[np.arange(batch_size) % len(cubes)], dtype=np.float32)
    ms = {k: 1e3 * _time(lambda st=st: fit_shexp(big, st), repeat=5) / batch_size for k, st in variants.items()}
    lights_encoding, lights_batch = SHExpLights(), ProbeBatch(big)
    lights_ms = 1e3 * _time(lambda: lights_encoding.encode(lights_batch), repeat=5) / batch_size
    ops = build_operators(default, n)
    grids = tuple(b.face_size for b in ops.blocks)
    flux = splat_flux(big, grids)
    e0 = design_e0_samples(big, default)
    logs, _ = log_e0(e0, batch_size)
    weights, mean = row_weights(e0, batch_size)

    def gram_and_solve() -> np.ndarray:
        lum = _luminance_operator(batch_size)
        gram = sum(g @ (flux[b.face_size] @ lum) for g, b in zip(ops.gram_operators, ops.blocks, strict=True))
        upper = (gram / mean[None, :]).T.astype(np.float64) + WEIGHT_MIN * ops.design_gram_upper[None, :]
        return solve_coefficients(logs, ops, batch_size, weights, upper)

    breakdown = {
        "splat": _time(lambda: splat_flux(big, grids), 5),
        "W_times_F": _time(lambda: [b.weights @ flux[b.face_size] for b in ops.blocks], 5),
        "log_and_weights": _time(lambda: (log_e0(e0, batch_size), row_weights(e0, batch_size)), 5),
        "gram_and_solve": _time(gram_and_solve, 5),
    }
    breakdown = {k: 1e3 * v / batch_size for k, v in breakdown.items()}
    # every formulation vs the plain fit (brute-force E0 at the design rows, same solve), on every environment:
    # relative RMS of E0 on a Fibonacci set of (v = n) and grazing rows at α = 0.25, 0.5, 1.
    normals = fibonacci_directions(512)
    views = np.roll(normals, 7, axis=0) + normals
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    rows_v = np.concatenate([normals, views] * 3)
    rows_n = np.concatenate([normals, normals] * 3)
    rows_a = np.repeat([0.25, 0.5, 1.0], 1024)
    start = time.perf_counter()
    plain_samples = plain_e0_samples(cubes, default).astype(np.float32)  # (M, 3P)
    plain_ms = 1e3 * (time.perf_counter() - start) / len(cubes)
    vs_plain = {}
    for key, st in variants.items():
        plain_fit = solve_from_samples(plain_samples, st, build_operators(st, n))
        truth = evaluate_e0(plain_fit, rows_v, rows_n, rows_a, st)
        fast = evaluate_e0(fit_shexp(cubes, st), rows_v, rows_n, rows_a, st)
        vs_plain[key] = {name: float(np.sqrt(np.mean((fast[i] - truth[i]) ** 2)) / max(float(np.mean(truth[i])), 1e-30))
                         for i, name in enumerate(names)}
    shexp_speed = {
        "shexp_operator_build_s": build_seconds,
        "shexp_grids": {k: list(slab_face_sizes(st, n)) for k, st in variants.items()},
        "shexp_ms_per_probe": ms, "shexp_probes_per_s": {k: 1e3 / v for k, v in ms.items()},
        "shexp_breakdown_ms_per_probe": breakdown,
        "shexp_lights_ms_per_probe": lights_ms,
        "shexp_plain_ms_per_probe": plain_ms,
        "shexp_vs_plain_rel_rms": vs_plain,
    }
    chain = ss.SplitSumSettings(face_size=cubes.shape[2])
    chain_fast_s = _time(lambda: ss.prefilter_chain(cubes[0], chain), repeat=2)
    pick = [names.index(n) for n in ("park", "city") if n in names][:plain_probes] or list(range(min(plain_probes, len(names))))
    level_errors = []
    plain_s = []
    rng = np.random.default_rng(0)
    for i in pick:
        start = time.perf_counter()
        plain = ss._reference_prefilter_chain(cubes[i], chain, 1024)
        plain_s.append(time.perf_counter() - start)
        fast_chain = ss.prefilter_chain(cubes[i], chain)
        for level, (a, size) in enumerate(zip(chain.level_alphas(), chain.level_sizes(), strict=True)):
            if a == 0:
                continue
            texels = rng.choice(6 * size * size, 512, replace=False)
            exact = _exact_at(cubes[i], float(a), size, texels)
            err = lambda x: float(np.sqrt(np.mean((x.reshape(-1, 3)[texels] - exact) ** 2)) / max(float(exact.mean()), 1e-30))  # noqa: E731
            level_errors.append({
                "environment": names[i], "level": level, "alpha": float(a), "size": size,
                "formulation": ss.level_formulation(chain, float(a)),
                "rel_rms_fast_vs_exact": err(fast_chain[level]), "rel_rms_plain_vs_exact": err(plain[level]),
                "rel_rms_fast_vs_plain": float(np.sqrt(np.mean((fast_chain[level] - plain[level]) ** 2))
                                               / max(float(plain[level].mean()), 1e-30)),
            })
    return {
        "batch_size": batch_size, "face_size": int(cubes.shape[2]), **shexp_speed,
        "splitsum_fast_ms_per_probe": 1e3 * chain_fast_s, "splitsum_plain_ms_per_probe": 1e3 * float(np.mean(plain_s)),
        "splitsum_level_errors": level_errors,
    }


def _exact_at(cube: np.ndarray, alpha: float, size: int, texels: np.ndarray) -> np.ndarray:
    """Exact kernel quadrature (:func:`bakery.reflection.splitsum._exact_prefilter_level`) at selected texels."""
    from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles

    n = cube.shape[1]
    src = cube_texel_directions(n).reshape(-1, 3)
    omega = cube_texel_solid_angles(n).reshape(-1)
    out_dirs = cube_texel_directions(size).reshape(-1, 3)[texels]
    k = ss._kernel_profile(out_dirs @ src.T, alpha) * omega
    return (k @ cube.reshape(-1, 3).astype(np.float64)) / k.sum(axis=1)[:, None]


def format_table(result: dict) -> str:
    """Markdown summary: per (environment, α) mean ratio, then totals (and speed)."""
    s = result["summary"]
    lines = [
        f"# Reflection bench ({s['cases']} cases)", "",
        f"SH-exp lower MSE in {s['shexp_wins']}/{s['cases']} cases ({100 * s['shexp_win_share']:.1f}%); "
        f"median ratio {s['median_ratio']:.3g}, geometric mean {s['geometric_mean_ratio']:.3g}. "
        f"Unweighted log-space solve: {s['unweighted_wins']}/{s['cases']} (geometric mean "
        f"{s['unweighted_geometric_mean_ratio']:.3g}); the weighted solve has the lower MSE in "
        f"{100 * s['weighted_beats_unweighted']:.1f}% of cases. "
        f"Paper formulation (unweighted, no albedo normalisation): {s['paper_formulation_wins']}/{s['cases']} "
        f"({100 * s['paper_formulation_win_share']:.1f}%). Against the paper's split-sum setting (plain 1024-sample "
        f"IS chain): {100 * s['win_share_vs_plain_splitsum']:.1f}% (paper formulation "
        f"{100 * s['paper_formulation_win_share_vs_plain']:.1f}%).",
        f"Bytes per probe: {SHEXP} {s['bytes_per_probe'][SHEXP]}, {SPLITSUM} {s['bytes_per_probe'][SPLITSUM]} "
        f"(ratio {s['memory_ratio']:.0f}×).",
        f"{SHEXP_LIGHTS} ({s['bytes_per_probe'][SHEXP_LIGHTS]} bytes, {s['lights_memory_ratio']:.0f}× less than "
        f"split-sum): lower MSE in {s['lights_wins']}/{s['cases']} ({100 * s['lights_win_share']:.1f}%), geometric "
        f"mean ratio {s['lights_geometric_mean_ratio']:.3g}; vs the plain 1024-sample chain "
        f"{100 * s['lights_win_share_vs_plain_splitsum']:.1f}%.", "",
        "| environment | " + " | ".join(f"α={a:.3g}" for a in ALPHAS) + " |",
        "|---|" + "---|" * len(ALPHAS),
    ]
    envs = sorted({r["environment"] for r in result["rows"]})
    for key, label in (("ratio", SHEXP), ("ratio_lights", SHEXP_LIGHTS)):
        if key != "ratio":
            lines += ["", "| environment | " + " | ".join(f"α={a:.3g}" for a in ALPHAS) + " |",
                      "|---|" + "---|" * len(ALPHAS)]
        for env in envs:
            cells = []
            for a in ALPHAS:
                rr = [r[key] for r in result["rows"] if r["environment"] == env and abs(r["alpha"] - a) < 1e-9]
                wins = sum(x < 1 for x in rr)
                cells.append(f"{np.exp(np.mean(np.log(np.maximum(rr, 1e-30)))):.3g} ({wins}/{len(rr)})")
            lines.append(f"| {env} | " + " | ".join(cells) + " |")
        lines += ["", f"Cells: geometric-mean MSE ratio {label}/{SPLITSUM} over materials × views (wins/cases)."]
    lines += [""]
    if "speed" in result:
        sp = result["speed"]
        lines += [
            "## Speed (single process)", "",
            *[f"- SH-exp fit, {k} (grids {sp['shexp_grids'][k]}): {v:.3f} ms/probe "
              f"({sp['shexp_probes_per_s'][k]:.0f} probes/s); rel. RMS of E0 vs the plain fit: max "
              f"{max(sp['shexp_vs_plain_rel_rms'][k].values()):.3g}, median "
              f"{np.median(list(sp['shexp_vs_plain_rel_rms'][k].values())):.3g}"
              for k, v in sp["shexp_ms_per_probe"].items()],
            "- default breakdown (ms/probe): " + ", ".join(
                f"{k} {v:.3f}" for k, v in sp["shexp_breakdown_ms_per_probe"].items()),
            f"- shexp_lights (light extraction + fit): {sp['shexp_lights_ms_per_probe']:.3f} ms/probe",
            f"- plain fit (brute-force design samples): {sp['shexp_plain_ms_per_probe']:.0f} ms/probe",
            f"- split-sum chain: fast {sp['splitsum_fast_ms_per_probe']:.0f} ms/probe, plain 1024-sample IS "
            f"{sp['splitsum_plain_ms_per_probe']:.0f} ms/probe", "",
            "| env | level | α | formulation | fast vs exact | plain vs exact |", "|---|---|---|---|---|---|",
        ]
        for e in sp["splitsum_level_errors"]:
            lines.append(f"| {e['environment']} | {e['level']} | {e['alpha']:.3g} | {e['formulation']} | "
                         f"{e['rel_rms_fast_vs_exact']:.3g} | {e['rel_rms_plain_vs_exact']:.3g} |")
    return "\n".join(lines) + "\n"


def write_results(result: dict, out_dir: Path, stem: str = "reflection") -> tuple[Path, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, text_path = out_dir / f"{stem}.json", out_dir / f"{stem}.md"
    json_path.write_text(json.dumps(result, indent=2))
    text_path.write_text(format_table(result))
    return json_path, text_path
