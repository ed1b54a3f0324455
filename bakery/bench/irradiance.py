"""Irradiance quality table: every irradiance encoding against the exact irradiance, per environment.

For each environment image in a folder (recursively: .hdr, .exr): bake it as one distant probe on the bake grid,
evaluate every irradiance encoding at a Fibonacci set of normals, and compare with the brute-force cosine
convolution of the *full-resolution* image (:mod:`bakery.irradiance.reference`). Error = relative RMSE over
directions and RGB, √Σ(E−E_ref)² / √ΣE_ref². Also: share of negative directions, bytes per probe, and the
reductions the ZH3 paper reports (ZH3 vs SH2: −44% average; hallucinated vs SH2: −23%).
"""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import numpy as np

from bakery.encodings import ENCODINGS
from bakery.environment.io import read_environment
from bakery.environment.resample import environment_samples, resample_to_cube
from bakery.errors import BakeryWarning
from bakery.irradiance.reference import reference_irradiance, relative_rmse
from bakery.irradiance.zh3 import evaluate_zh3_irradiance, fit_hallucination_curve, hallucinate_zonal_l2
from bakery.probe import ProbeBatch
from bakery.sphere.fibonacci import fibonacci_directions

IMAGE_SUFFIXES = (".hdr", ".exr")


def find_environments(folder: Path) -> list[Path]:
    return sorted(p for p in Path(folder).rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())


def irradiance_encodings() -> dict:
    return {name: cls() for name, cls in ENCODINGS.items() if cls.kind == "irradiance"}


def run_irradiance_bench(folder: Path, face_size: int = 64, directions: int = 2048) -> dict:
    """Rows {environment, per-encoding error/negative share} plus summary; see module docstring."""
    normals = fibonacci_directions(directions)
    encodings = irradiance_encodings()
    rows = []
    cache = []  # (radiance SH3, reference) per environment, for the leave-one-out hallucination fit
    for path in find_environments(folder):
        start = time.perf_counter()
        with warnings.catch_warnings(record=True) as recorded:
            warnings.simplefilter("always", BakeryWarning)
            image, report = read_environment(path)
        cube = resample_to_cube(image, face_size)
        samples = environment_samples(image)
        reference = reference_irradiance(samples, normals)
        batch = ProbeBatch(cube[None], [samples])
        row = {"environment": str(path.relative_to(folder)), "layout": image.layout,
               "sanitized_texels": report.replaced, "errors": {}, "negative_fraction": {}}
        for name, encoding in encodings.items():
            values = encoding.evaluate_irradiance(encoding.encode(batch), normals)[0]
            row["errors"][name] = relative_rmse(values, reference)
            row["negative_fraction"][name] = float(np.mean(np.any(values < 0, axis=-1)))
        row["seconds"] = time.perf_counter() - start
        row["warnings"] = [str(w.message) for w in recorded]
        rows.append(row)
        cache.append((batch.radiance_sh(2), reference))
    if len(rows) >= 3:
        # Hallucination with a curve fitted to the *other* environments (leave-one-out): what a bake that fits the
        # curve to a scene's probes (method notes §2) gains over the paper's production-map curve (Eq. 21).
        for i, row in enumerate(rows):
            others = np.concatenate([sh for j, (sh, _) in enumerate(cache) if j != i])
            curve, _, _ = fit_hallucination_curve(others, minimum_samples=6)
            sh, reference = cache[i]
            values = evaluate_zh3_irradiance(sh[:, :4], hallucinate_zonal_l2(sh[:, :4], curve), normals)[0]
            row["errors"]["zh3_hallucinated_fit_loo"] = relative_rmse(values, reference)
            row["negative_fraction"]["zh3_hallucinated_fit_loo"] = float(np.mean(np.any(values < 0, axis=-1)))
            row["hallucination_curve_loo"] = list(curve)
    summary = {"bytes_per_probe": {n: e.bytes_per_probe() for n, e in encodings.items()}}
    if rows and "zh3_hallucinated_fit_loo" in rows[0]["errors"]:
        summary["bytes_per_probe"]["zh3_hallucinated_fit_loo"] = encodings["zh3_hallucinated"].bytes_per_probe()
    columns = list(summary["bytes_per_probe"])
    if rows:
        mean = {n: float(np.mean([r["errors"][n] for r in rows])) for n in columns}
        summary["mean_error"] = mean
        summary["mean_reduction_vs_sh2"] = {
            n: float(np.mean([1.0 - r["errors"][n] / r["errors"]["sh2"] for r in rows if r["errors"]["sh2"] > 0]))
            for n in columns
        }
    return {"face_size": face_size, "directions": directions, "metric": "relative RMSE vs exact irradiance",
            "rows": rows, "summary": summary}


def format_table(result: dict) -> str:
    """Markdown table of a :func:`run_irradiance_bench` result."""
    names = list(result["summary"]["bytes_per_probe"])
    lines = ["| environment | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for row in result["rows"]:
        lines.append(f"| {row['environment']} | " + " | ".join(f"{row['errors'][n]:.4f}" for n in names) + " |")
    summary = result["summary"]
    if "mean_error" in summary:
        lines.append("| **mean** | " + " | ".join(f"{summary['mean_error'][n]:.4f}" for n in names) + " |")
        lines.append("| **mean reduction vs SH2** | "
                     + " | ".join(f"{100 * summary['mean_reduction_vs_sh2'][n]:+.0f}%" for n in names) + " |")
    lines.append("| **bytes per probe** | " + " | ".join(str(summary["bytes_per_probe"][n]) for n in names) + " |")
    return "\n".join(lines)


def write_results(result: dict, out_dir: Path, stem: str = "irradiance") -> tuple[Path, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, text_path = out_dir / f"{stem}.json", out_dir / f"{stem}.md"
    json_path.write_text(json.dumps(result, indent=2))
    text_path.write_text(format_table(result) + "\n")
    return json_path, text_path
