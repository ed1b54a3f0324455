"""Glossy-reflection quality bench over the full roughness range (seed 000 Fig. 4–7 protocol, extended by issue 12):
``bakery bench reflection DIR``.

Protocol
    Environments: every ``.hdr``/``.exr`` under ``env_dir``, resampled to the bake cube grid (``face_size``) and encoded
    by every reflection encoding through its registered class (what a store holds, float16 levels included):
    ``splitsum`` (the baseline), ``shexp``, ``shexp_lights``, ``shexp_hybrid`` (probe range α ∈ [0, 1]: every chain
    level). Also scored: the *idealised split-sum* (``splitsum_ideal``: the GGX v = n kernel applied exactly at the
    row's α to the full-resolution capture, × the same DFG factor — the best any split-sum chain can do), and with
    ``plain_splitsum`` the paper's plain 1024-sample chain (``splitsum_plain``; omitted, never printed, otherwise).
    Spheres: orthographic, ``sphere_resolution``² pixels, seen from :data:`ELEVATIONS` (view elevation −30° … 85°,
    azimuth +Z); chrome (F0 = 1) and glass (F0 = 0.04); α ∈ :data:`ALPHAS` (0 … 1, including α between chain levels).
    Reference: Eq. 1 integrated over the full-resolution image's texels, each constant over its exact footprint (the
    converged reference of :mod:`bakery.environment.reflection_reference`, also the report's: texel centres plus
    adaptive sub-texels where the lobe is narrow on a texel's scale); at α = 0 the mirror E = F(n·v)·L(r) with L(r)
    the texel containing r (the α → 0 limit of the integral). Cached per reference-method version, image and row set
    in ``cache_dir`` (default ``out_dir/reference-cache``).
    One case = (environment, material, elevation, α); MSE over the sphere's pixels and RGB.
    Per α and per α band, for every scored encoding: win share (MSE < split-sum's), geometric-mean MSE ratio vs
    split-sum (and vs the idealised split-sum), geometric-mean relative MSE vs the reference, signed brightness bias
    (mean over cases of Σ E / Σ E_ref − 1). Memory: bytes per probe of each encoding's stored fields; for the hybrid
    also the upload per probe by the probe's smallest material α.

Speed (``speed=True``): the SH-exp speed protocol of docs/reflection.md (fits, grids, split-sum fast vs plain) and
the encode time of every reflection encoding.
"""

from __future__ import annotations

import json
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bakery.brdf.ggx import reflect
from bakery.encodings.hybrid import SHExpHybrid
from bakery.encodings.shexp import SHExp, SHExpLights
from bakery.encodings.splitsum import SplitSum
from bakery.environment import resample_to_cube
from bakery.environment.io import read_environment
from bakery.environment.layouts import EnvironmentImage
from bakery.environment.reflection_reference import CubeTexels, cube_prefiltered, environment_reflection
from bakery.files import atomic_replace, sha256_array, sha256_bytes, sha256_file
from bakery.probe import ProbeBatch
from bakery.reflection import splitsum as ss
from bakery.reflection.hybrid import first_chain_level
from bakery.reflection.reference import REFERENCE_METHOD_VERSION
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
from bakery.reflection.tables import compute_dfg_tables, lookup_table
from bakery.sphere.cubemap import sample_cube_bilinear
from bakery.sphere.fibonacci import fibonacci_directions

IMAGE_SUFFIXES = (".hdr", ".exr")
#: Result keys: the registered encodings (store group names), then the idealised and the plain split-sum.
SPLITSUM, SHEXP, SHEXP_LIGHTS, HYBRID = SplitSum.name, SHExp.name, SHExpLights.name, SHExpHybrid.name
IDEAL, PLAIN = "splitsum_ideal", "splitsum_plain"
#: GGX α of the cases: the issue's grid {0, 0.04, 0.0625, 0.1, 0.16, 0.25, …, 1} plus α between chain levels.
ALPHAS = (0.0, 0.02, 0.04, 0.0625, 0.1, 0.13, 0.16, 0.2, 0.25, 0.3, 0.36, 0.49, 0.64, 0.81, 1.0)
#: View elevations in degrees (v = (0, sin e, cos e), towards the viewer).
ELEVATIONS = (-30.0, 0.0, 30.0, 60.0, 85.0)
MATERIALS = {"chrome": 1.0, "glass": 0.04}
#: α bands of the summary tables: (label, lo, hi) with lo ≤ α < hi.
BANDS = (("α < 0.1", 0.0, 0.1), ("0.1 ≤ α < 0.25", 0.1, 0.25), ("α ≥ 0.25", 0.25, 1.01), ("all α", 0.0, 1.01))


def find_environments(folder: Path) -> list[Path]:
    return sorted(p for p in Path(folder).rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())


def sphere_normals(view: np.ndarray, resolution: int) -> np.ndarray:
    """Normals (K, 3) of the visible pixels of an orthographic unit sphere seen from ``view`` (towards the viewer),
    pixel centres of a resolution² image over [-1, 1]² (image up = +Y projected, or −Z for a view along ±Y)."""
    up = np.array([0.0, 1.0, 0.0]) if abs(view[1]) < 0.99 else np.array([0.0, 0.0, -1.0])
    right = np.cross(up, view)
    right /= np.linalg.norm(right)
    up = np.cross(view, right)
    c = (np.arange(resolution) + 0.5) / resolution * 2.0 - 1.0
    y, x = np.meshgrid(-c, c, indexing="ij")
    inside = x * x + y * y < 1.0
    z = np.sqrt(1.0 - x[inside] ** 2 - y[inside] ** 2)
    return x[inside, None] * right + y[inside, None] * up + z[:, None] * view


def view_direction(elevation_deg: float) -> np.ndarray:
    e = np.radians(elevation_deg)
    return np.array([0.0, np.sin(e), np.cos(e)])


def bench_rows(resolution: int, alphas=ALPHAS, elevations=ELEVATIONS):
    """Rows v (M, 3), n (M, 3), α (M,) and the cases [(elevation, α, slice)] (elevation slowest)."""
    views, normals, alpha, cases = [], [], [], []
    start = 0
    for elevation in elevations:
        v = view_direction(elevation)
        n = sphere_normals(v, resolution)
        for a in alphas:
            views.append(np.broadcast_to(v, n.shape))
            normals.append(n)
            alpha.append(np.full(len(n), float(a)))
            cases.append((float(elevation), float(a), slice(start, start + len(n))))
            start += len(n)
    return np.concatenate(views), np.concatenate(normals), np.concatenate(alpha), cases


def reference_e0_e1(path: Path, image: EnvironmentImage, view: np.ndarray, normal: np.ndarray, alpha: np.ndarray,
                    cache_dir: Path | None) -> tuple[np.ndarray, np.ndarray]:
    """(E0, E1) (M, 3) of the full-resolution image's texels ([SHExp] Eq. 6–7): the converged reference
    (:func:`bakery.environment.reflection_reference.environment_reflection`; α = 0: the mirror, the texel containing
    r). Cached in ``cache_dir`` by the reference method's version
    (:data:`bakery.reflection.reference.REFERENCE_METHOD_VERSION`), the image's sha256 and the rows; a cache file
    holds the sha256 of (E0, E1) and is used only if they match it (else recomputed and replaced, atomically)."""
    rows = np.concatenate([view, normal, alpha[:, None]], 1).tobytes()
    key = (f"v{REFERENCE_METHOD_VERSION}-" + sha256_file(path)[:16] + sha256_bytes(rows)[:16])
    cached = Path(cache_dir) / f"{Path(path).stem}-{key}.npz" if cache_dir is not None else None
    if cached is not None and cached.is_file():
        verified = _verified_reference(cached, len(view))
        if verified is not None:
            return verified
    e0, e1 = environment_reflection(image, view, normal, alpha)
    if cached is not None:
        cached.parent.mkdir(parents=True, exist_ok=True)
        with atomic_replace(cached, ".npz") as tmp:
            np.savez(tmp, e0=e0, e1=e1, sha256=np.array(_reference_digest(e0, e1)))
    return e0, e1


def _reference_digest(e0: np.ndarray, e1: np.ndarray) -> str:
    return sha256_bytes((sha256_array(e0) + sha256_array(e1)).encode())


def _verified_reference(path: Path, rows: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(E0, E1) of a reference cache file if it is readable, holds (rows, 3) float64 arrays and their recorded
    sha256; otherwise None (damaged, truncated, or written before the checksum was recorded)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            e0, e1, digest = z["e0"], z["e1"], str(z["sha256"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    if e0.shape != (rows, 3) or e1.shape != (rows, 3) or e0.dtype != np.float64 or e1.dtype != np.float64:
        return None
    return (e0, e1) if digest == _reference_digest(e0, e1) else None


def ideal_split_sum(cube: np.ndarray, directions: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """The idealised split-sum's prefiltered radiance (M, 3): the normalised v = n kernel K_α applied exactly to the
    capture's piecewise-constant texels at each row's own α and direction, converged as the reference is
    (:func:`bakery.environment.reflection_reference.cube_prefiltered`); α = 0: bilinear in the capture (what every
    chain's level 0 gives)."""
    texels = CubeTexels(np.asarray(cube, dtype=np.float32))
    out = np.empty((len(directions), 3))
    for a in np.unique(alpha):
        rows = np.flatnonzero(alpha == a)
        out[rows] = (sample_cube_bilinear(texels.cube, directions[rows]) if a <= 0
                     else cube_prefiltered(texels, directions[rows], float(a)))
    return out


def _encoders(face_size: int, hybrid_gap_levels: int = 0) -> dict[str, object]:
    """The scored encoders; ``hybrid_gap_levels`` > 0: the hybrid with ``gap_level`` and that many gap levels."""
    gaps = {"gap_level": True, "gap_levels": hybrid_gap_levels} if hybrid_gap_levels else {}
    return {SPLITSUM: SplitSum(face_size=face_size), SHEXP: SHExp(), SHEXP_LIGHTS: SHExpLights(),
            HYBRID: SHExpHybrid(face_size=face_size, **gaps)}


def run_reflection_bench(
    env_dir: Path, out_dir: Path, speed: bool = False, face_size: int = 128, sphere_resolution: int = 12,
    plain_splitsum: bool = True, cache_dir: Path | None = None, echo: Callable[[str], None] | None = print,
    force: bool = False, hybrid_gap_levels: int = 0,
) -> dict:
    """Run the protocol (module doc), write ``reflection.json`` and ``reflection.md`` to ``out_dir`` (refused before
    the run if one is a file bench did not write, unless ``force``: :mod:`bakery.bench.output`), print the headline
    table through ``echo`` (stdout by default; None: silent) and return the result dict."""
    from bakery.bench.output import check_bench_outputs

    check_bench_outputs(out_dir, ("reflection.json", "reflection.md"), force)
    paths = find_environments(Path(env_dir))
    if not paths:
        raise FileNotFoundError(f"no .hdr/.exr environment images under {env_dir}")
    cache_dir = Path(out_dir) / "reference-cache" if cache_dir is None else Path(cache_dir)
    encoders = _encoders(face_size, hybrid_gap_levels)
    view, normal, alpha, cases = bench_rows(sphere_resolution)
    r = reflect(view, normal)
    nv = np.clip(np.sum(view * normal, axis=1), 0.0, 1.0)
    ab = lookup_table(compute_dfg_tables(64, 64).dfg, nv, alpha)  # the encodings' DFG table
    rows: list[dict] = []
    encode_seconds = {k: 0.0 for k in [*encoders, IDEAL] + ([PLAIN] if plain_splitsum else [])}
    upload = []
    for path in paths:
        image = read_environment(path)[0]
        cube = resample_to_cube(image, face_size)
        batch = ProbeBatch(cube[None])
        e0, e1 = reference_e0_e1(path, image, view, normal, alpha, cache_dir)
        fields = {}
        for key, encoding in encoders.items():
            start = time.perf_counter()
            fields[key] = encoding.encode(batch)
            encode_seconds[key] += time.perf_counter() - start
        upload.append(int(encoders[HYBRID].upload_bytes(fields[HYBRID])[0]))
        start = time.perf_counter()
        ideal = ideal_split_sum(cube, r, alpha)
        encode_seconds[IDEAL] += time.perf_counter() - start
        plain = None
        if plain_splitsum:
            start = time.perf_counter()
            chain = ss._reference_prefilter_chain(cube, encoders[SPLITSUM].chain, 1024)
            plain = {f"level{k}": level[None].astype(np.float16) for k, level in enumerate(chain)}
            encode_seconds[PLAIN] += time.perf_counter() - start
        for material, f0 in MATERIALS.items():
            f0s = np.full(len(alpha), f0)
            reference = f0 * e0 + (1.0 - f0) * e1  # [SHExp] Eq. 5
            est = {k: enc.evaluate_reflection(fields[k], enc.shared_tables(), view, normal, alpha, f0s)[0]
                   for k, enc in encoders.items()}
            est[IDEAL] = ideal * (f0 * ab[:, 0:1] + ab[:, 1:2])
            if plain is not None:
                split = encoders[SPLITSUM]
                est[PLAIN] = split.evaluate_reflection(plain, split.shared_tables(), view, normal, alpha, f0s)[0]
            for elevation, a, sl in cases:
                ref = reference[sl]
                row = {"environment": path.stem, "material": material, "elevation": elevation, "alpha": a,
                       "reference_power": float(np.mean(ref**2)), "reference_sum": float(np.sum(ref)),
                       "reference_max": float(np.max(ref))}
                for k, x in est.items():
                    row[f"mse_{k}"] = float(np.mean((x[sl] - ref) ** 2))
                    row[f"bias_{k}"] = float(np.sum(x[sl]) / row["reference_sum"] - 1.0) if row["reference_sum"] > 0 \
                        else 0.0
                    row[f"peak_{k}"] = float(np.max(x[sl]) / row["reference_max"]) if row["reference_max"] > 0 else 0.0
                rows.append(row)
    keys = [*encoders, IDEAL] + ([PLAIN] if plain_splitsum else [])
    hybrid = encoders[HYBRID]
    chain_bytes = [6 * s * s * 3 * 2 for s in hybrid.chain.level_sizes()]
    fixed = hybrid.bytes_per_probe() - sum(chain_bytes)
    by_alpha_min = {}
    for a in ALPHAS:
        k0 = first_chain_level(hybrid.chain.level_alphas(), float(a), hybrid.blends[1][1])
        by_alpha_min[str(a)] = fixed + sum(chain_bytes[k0:])
    result = {
        "protocol": {
            "face_size": face_size, "sphere_resolution": sphere_resolution, "alphas": list(ALPHAS),
            "elevations_deg": list(ELEVATIONS), "materials": MATERIALS, "environments": [p.stem for p in paths],
            "normals_per_view": [int(sl.stop - sl.start) for e, a, sl in cases if a == ALPHAS[0]],
            "settings": {k: e.settings for k, e in encoders.items()},
            "reference": "Eq. 1 over the full-resolution image's piecewise-constant texels, converged (texel "
                         "centres plus adaptive sub-texels where the lobe is narrow on a texel's scale); α = 0: the "
                         "mirror F(n·v)·L(r), L(r) the texel containing r",
            "reference_method_version": REFERENCE_METHOD_VERSION,
            "idealised_split_sum": "K_α (v = n) applied exactly at the row's α to the full-resolution capture's "
                                   "piecewise-constant texels (converged as the reference), × DFG; α = 0: bilinear",
            "scored": keys,
        },
        "rows": rows,
        "summary": summarise(rows, keys),
        "bytes_per_probe": {k: e.bytes_per_probe() for k, e in encoders.items()},
        "hybrid_upload_bytes": {"per_environment_probe": upload, "by_smallest_material_alpha": by_alpha_min,
                                "level_alphas": [float(a) for a in hybrid.chain.level_alphas()],
                                "level_sizes": list(hybrid.chain.level_sizes())},
        "encode_s_per_probe": {k: v / len(paths) for k, v in encode_seconds.items()},
    }
    if speed:
        cubes = np.stack([resample_to_cube(read_environment(p)[0], face_size) for p in paths])
        result["speed"] = run_speed(cubes, [p.stem for p in paths])
    write_results(result, Path(out_dir), force=force)
    if echo is not None:
        echo(format_headline(result))
    return result


def _geomean(values: list[float]) -> float:
    return float(np.exp(np.mean(np.log(np.maximum(values, 1e-300))))) if values else float("nan")


def summarise(rows: list[dict], keys: list[str]) -> dict:
    """Per α (``by_alpha``) and per band (``by_band``), for every scored key: cases, wins (MSE < split-sum's),
    win share, geometric-mean MSE ratio vs split-sum and vs the idealised split-sum, geometric-mean relative MSE vs
    the reference, mean signed brightness bias, median peak ratio."""
    def stats(subset: list[dict]) -> dict:
        out = {}
        for k in keys:
            ratio = [r[f"mse_{k}"] / r[f"mse_{SPLITSUM}"] for r in subset if r[f"mse_{SPLITSUM}"] > 0]
            out[k] = {
                "cases": len(subset),
                "wins": int(sum(r[f"mse_{k}"] < r[f"mse_{SPLITSUM}"] for r in subset)),
                "win_share": float(np.mean([r[f"mse_{k}"] < r[f"mse_{SPLITSUM}"] for r in subset])),
                "geomean_ratio_vs_splitsum": _geomean(ratio),
                "geomean_ratio_vs_ideal": _geomean([r[f"mse_{k}"] / r[f"mse_{IDEAL}"] for r in subset
                                                    if r[f"mse_{IDEAL}"] > 0]),
                "geomean_relative_mse": _geomean([r[f"mse_{k}"] / r["reference_power"] for r in subset
                                                  if r["reference_power"] > 0]),
                "bias": float(np.mean([r[f"bias_{k}"] for r in subset])),
                "median_peak_ratio": float(np.median([r[f"peak_{k}"] for r in subset])),
            }
        return out

    alphas = sorted({r["alpha"] for r in rows})
    return {
        "cases": len(rows),
        "by_alpha": {str(a): stats([r for r in rows if r["alpha"] == a]) for a in alphas},
        "by_band": {label: stats([r for r in rows if lo <= r["alpha"] < hi]) for label, lo, hi in BANDS},
        "by_material": {m: stats([r for r in rows if r["material"] == m]) for m in MATERIALS},
    }


def _cell(s: dict) -> str:
    return (f"{100 * s['win_share']:.0f}% · {s['geomean_ratio_vs_splitsum']:.3g}× · "
            f"{100 * s['bias']:+.0f}%")


def format_headline(result: dict) -> str:
    """The headline table (stdout and the top of reflection.md): per α band and per α, every scored encoding's win
    share vs split-sum · geometric-mean MSE ratio vs split-sum · mean signed brightness bias; bytes per probe."""
    summary, protocol = result["summary"], result["protocol"]
    keys = protocol["scored"]
    lines = [f"Reflection bench: {summary['cases']} cases = {len(protocol['environments'])} environments × "
             f"{len(MATERIALS)} materials × {len(protocol['elevations_deg'])} view elevations × "
             f"{len(protocol['alphas'])} α (face {protocol['face_size']}, "
             f"{sum(protocol['normals_per_view'])} normals per α and material)", "",
             "Cells: win share vs splitsum · geometric-mean MSE ratio vs splitsum · mean brightness bias vs the "
             "reference.", "",
             "| α band | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
    for label, _, _ in BANDS:
        s = summary["by_band"][label]
        lines.append(f"| {label} | " + " | ".join(_cell(s[k]) for k in keys) + " |")
    lines += ["", "| α | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
    for a, s in summary["by_alpha"].items():
        lines.append(f"| {float(a):.4g} | " + " | ".join(_cell(s[k]) for k in keys) + " |")
    chains = [k for k in (SPLITSUM, HYBRID, PLAIN) if k in keys]
    lines += ["", "Geometric-mean MSE ratio vs the idealised split-sum (exact α, full resolution):", "",
              "| α | " + " | ".join(chains) + " |", "|---|" + "---|" * len(chains)]
    for a, s in summary["by_alpha"].items():
        lines.append(f"| {float(a):.4g} | " + " | ".join(f"{s[k]['geomean_ratio_vs_ideal']:.3g}" for k in chains)
                     + " |")
    up = result["hybrid_upload_bytes"]
    lines += ["", "Bytes per probe: " + ", ".join(f"{k} {v:,}" for k, v in result["bytes_per_probe"].items())
              + f". {HYBRID} upload by the probe's smallest material α: "
              + ", ".join(f"α ≥ {float(a):g}: {b:,}" for a, b in up["by_smallest_material_alpha"].items()) + "."]
    return "\n".join(lines) + "\n"


def format_table(result: dict) -> str:
    """reflection.md: the headline, per-environment tables of the hybrid, by material, and speed if measured."""
    lines = ["# Reflection bench", "", format_headline(result)]
    summary = result["summary"]
    keys = result["protocol"]["scored"]
    lines += ["## By material", "", "| material | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
    for m, s in summary["by_material"].items():
        lines.append(f"| {m} | " + " | ".join(_cell(s[k]) for k in keys) + " |")
    envs = result["protocol"]["environments"]
    for key in (HYBRID, SHEXP_LIGHTS):
        lines += ["", f"## {key} / {SPLITSUM}: geometric-mean MSE ratio per environment and α (wins/cases)", "",
                  "| environment | " + " | ".join(f"α={a:g}" for a in ALPHAS) + " |", "|---|" + "---|" * len(ALPHAS)]
        for env in envs:
            cells = []
            for a in ALPHAS:
                rr = [r for r in result["rows"] if r["environment"] == env and r["alpha"] == a]
                ratio = [r[f"mse_{key}"] / r[f"mse_{SPLITSUM}"] for r in rr if r[f"mse_{SPLITSUM}"] > 0]
                cells.append(f"{_geomean(ratio):.3g} ({sum(x < 1 for x in ratio)}/{len(rr)})")
            lines.append(f"| {env} | " + " | ".join(cells) + " |")
    lines += ["", "Encode seconds per probe: " + ", ".join(f"{k} {v:.2f}" for k, v in
                                                          result["encode_s_per_probe"].items()), ""]
    if "speed" in result:
        sp = result["speed"]
        lines += [
            "## Speed (single process)", "",
            *[f"- SH-exp fit, {k} (grids {sp['shexp_grids'][k]}): {v:.3f} ms/probe "
              f"({sp['shexp_probes_per_s'][k]:.0f} probes/s); rel. RMS of E0 vs the plain fit: max "
              f"{max(sp['shexp_vs_plain_rel_rms'][k].values()):.3g}, median "
              f"{np.median(list(sp['shexp_vs_plain_rel_rms'][k].values())):.3g}"
              for k, v in sp["shexp_ms_per_probe"].items()],
            f"- split-sum chain: fast {sp['splitsum_fast_ms_per_probe']:.0f} ms/probe, plain 1024-sample IS "
            f"{sp['splitsum_plain_ms_per_probe']:.0f} ms/probe", "",
        ]
    return "\n".join(lines) + "\n"


def write_results(result: dict, out_dir: Path, stem: str = "reflection", force: bool = False) -> tuple[Path, Path]:
    """``stem``.json and ``stem``.md in ``out_dir`` (:mod:`bakery.bench.output` policy)."""
    from bakery.bench.output import write_bench_file

    return (write_bench_file(out_dir, f"{stem}.json", json.dumps(result, indent=1), force),
            write_bench_file(out_dir, f"{stem}.md", format_table(result), force))


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


