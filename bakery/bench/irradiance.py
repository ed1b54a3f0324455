"""Irradiance quality table: every irradiance encoding against the exact irradiance, per environment.

For each environment image in a folder (recursively: .hdr, .exr): bake it through the one bake path
(:func:`bakery.bake`, every registered irradiance encoding, into a temporary store), evaluate every encoding from
the store through the public API (:meth:`bakery.api.ProbeStore.evaluate_irradiance`, what an engine reconstructs
from the stored arrays) at a Fibonacci set of normals, and compare with the brute-force cosine convolution of the
*full-resolution* image (:mod:`bakery.irradiance.reference`, independent of the bake). Error = relative RMSE over
directions and RGB, √Σ(E−E_ref)² / √ΣE_ref². Also: share of negative directions, bytes per probe, and the
reductions the ZH3 paper reports (ZH3 vs SH2: −44% average; hallucinated vs SH2: −23%).

With three or more environments, hallucinated ZH3 is also scored with the Eq. 21 curve refitted on the *other*
environments (leave-one-out), from each store's stored radiance SH3.
"""

from __future__ import annotations

import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import bakery
from bakery.encodings import ENCODINGS, Encoding
from bakery.encodings.sh import SH2, SH3
from bakery.encodings.zh3 import ZH3Hallucinated
from bakery.environment.io import read_environment
from bakery.environment.resample import environment_samples
from bakery.errors import BakeryWarning
from bakery.irradiance.reference import reference_irradiance, relative_rmse
from bakery.irradiance.zh3 import evaluate_zh3_irradiance, fit_hallucination_curve, hallucinate_zonal_l2
from bakery.sphere.fibonacci import fibonacci_directions

IMAGE_SUFFIXES = (".hdr", ".exr")
#: Column of hallucinated ZH3 with the curve fitted on the other environments (leave-one-out).
LOO_COLUMN = f"{ZH3Hallucinated.name}_fit_loo"


def find_environments(folder: Path) -> list[Path]:
    return sorted(p for p in Path(folder).rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())


def irradiance_encodings() -> dict[str, Encoding]:
    """Every registered irradiance encoding with its default parameters (what the bench's bakes build)."""
    return {name: cls() for name, cls in ENCODINGS.items() if cls.kind == "irradiance"}


def _bake_one(path: Path, store_path: Path, names: tuple[str, ...], face_size: int) -> bakery.api.ProbeStore:
    """One environment baked through the one bake path into ``store_path``, opened for reading."""
    bakery.bake(path, store_path, encodings=names, face_size=face_size, jobs=1, reference_errors=False)
    return bakery.open_store(store_path)


def run_irradiance_bench(folder: Path, face_size: int = 64, directions: int = 2048) -> dict:
    """Rows {environment, per-encoding error/negative share} plus summary; see module docstring."""
    folder = Path(folder)
    normals = fibonacci_directions(directions)
    encodings = irradiance_encodings()
    names = tuple(encodings)
    bytes_per_probe = {n: e.bytes_per_probe() for n, e in encodings.items()}
    rows = []
    cache = []  # (stored radiance SH3, reference) per environment, for the leave-one-out hallucination fit
    with tempfile.TemporaryDirectory(prefix="bakery-bench-irradiance-") as tmp:
        for index, path in enumerate(find_environments(folder)):
            start = time.perf_counter()
            with warnings.catch_warnings(record=True) as recorded:
                warnings.simplefilter("always", BakeryWarning)
                # the reference: the full-resolution image, read and integrated independently of the bake
                image, report = read_environment(path)
                store = _bake_one(path, Path(tmp) / f"{index}.h5", names, face_size)
            reference = reference_irradiance(environment_samples(image), normals)
            row = {"environment": str(path.relative_to(folder)), "layout": image.layout,
                   "sanitized_texels": report.replaced, "errors": {}, "negative_fraction": {}}
            for name in names:
                values = store.evaluate_irradiance(name, normals)[0]
                row["errors"][name] = relative_rmse(values, reference)
                row["negative_fraction"][name] = float(np.mean(np.any(values < 0, axis=-1)))
                bytes_per_probe[name] = store.encodings[name].bytes_per_probe
            row["seconds"] = time.perf_counter() - start
            row["warnings"] = list(dict.fromkeys(str(w.message) for w in recorded))  # the read's and the bake's, once
            rows.append(row)
            radiance_sh3 = np.asarray(store.fields(SH3.name)[SH3.radiance_sh_field], dtype=np.float64)
            cache.append((radiance_sh3, reference))
    if len(rows) >= 3:
        # Hallucination with a curve fitted to the *other* environments (leave-one-out): what a bake that fits the
        # curve to a scene's probes (method notes §2) gains over the paper's production-map curve (Eq. 21).
        for i, row in enumerate(rows):
            others = np.concatenate([sh for j, (sh, _) in enumerate(cache) if j != i])
            curve, _, _ = fit_hallucination_curve(others, minimum_samples=6)
            sh, reference = cache[i]
            values = evaluate_zh3_irradiance(sh[:, :4], hallucinate_zonal_l2(sh[:, :4], curve), normals)[0]
            row["errors"][LOO_COLUMN] = relative_rmse(values, reference)
            row["negative_fraction"][LOO_COLUMN] = float(np.mean(np.any(values < 0, axis=-1)))
            row["hallucination_curve_loo"] = list(curve)
    summary = {"bytes_per_probe": bytes_per_probe}
    if rows and LOO_COLUMN in rows[0]["errors"]:
        summary["bytes_per_probe"][LOO_COLUMN] = bytes_per_probe[ZH3Hallucinated.name]
    columns = list(summary["bytes_per_probe"])
    if rows:
        mean = {n: float(np.mean([r["errors"][n] for r in rows])) for n in columns}
        summary["mean_error"] = mean
        summary["mean_reduction_vs_sh2"] = {
            n: float(np.mean([1.0 - r["errors"][n] / r["errors"][SH2.name] for r in rows
                              if r["errors"][SH2.name] > 0]))
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
