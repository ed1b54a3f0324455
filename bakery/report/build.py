"""Assemble the report of a probe store: compute memory and quality figures (public API only), render the page
and the JSON, and write both atomically.

``write_report(store, out_dir)`` is what ``bakery report STORE -o DIR`` calls. It computes everything before it
touches ``out_dir``; files are written under temporary names and renamed into place, so a failure (unreadable
store, unwritable directory) leaves an existing report untouched.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

import bakery
from bakery.api import open_store
from bakery.files import (
    OutputError,
    atomic_replace,
    check_output_file,
    folder_problem,
    json_output_refusal,
    jsonable,
    os_error_message,
)
from bakery.report import quality, render, svg
from bakery.report.memory import memory_summary
from bakery.report.page import render_page
from bakery.store.format import failed_probes

#: Preview material roughness (GGX α) of the chrome and glass spheres.
PREVIEW_ALPHAS = (0.25, 0.6)


def build_report(store_path: str | os.PathLike[str], environment: str | os.PathLike[str] | None = None,
                 previews: bool = True, sphere_size: int = 48) -> tuple[dict[str, Any], str]:
    """(report data, HTML page) of the store at ``store_path``; ``environment`` overrides the capture source."""
    start = time.perf_counter()
    store = open_store(store_path)
    references = quality.load_reference_samples(store, environment)
    memory = memory_summary(store)
    directions = quality.quality_directions(store)
    errors = quality.irradiance_errors(store, references)
    for name in quality.encodings_of_kind(store, "reflection"):
        stored = quality._per_probe(store, f"reference_error/{name}", name)
        if stored is not None:
            errors[name] = quality._measurable(store, stored, quality.probe_rows(store, name))
    negatives = quality.negative_shares(store)
    quantization = quality.quantization_errors(store)
    curves = quality.reflection_alpha_curves(store, references)
    # (P_k,) per probe: the plain mean of its relative MSE over the len(CURVE_ALPHAS) α of the grid (not an integral
    # over α: the grid is denser below 0.25) and both materials; NaN (not measured) if any cell is (black reference)
    reflection_errors = {name: np.mean([np.asarray(c[m]) for m in quality.MATERIALS], axis=(0, 2))
                         for name, c in curves.get("encodings", {}).items()}
    for name, v in reflection_errors.items():  # measured here: replaces a stored diagnostic (the label is this one)
        errors[name] = v
    data: dict[str, Any] = {
        "store": str(store_path), "format_version": store.format_version,
        "bakery_version": bakery.__version__, "store_bakery_version": store.attributes.get("bakery_version"),
        "settings_hash": store.attributes.get("settings_hash"),
        "probes": len(store.probe_names), "reference_available": references is not None,
        # the capture the quality figures were measured against (re-read image), and whether it is the one baked
        "reference": ({"path": references[0].path, "flux_matches_store": references[0].flux_matches_store}
                      if references and isinstance(references[0], quality.CaptureReference) else None),
        "quality_directions": directions,
        "memory": memory,
        "errors": {n: {"kind": store.encodings[n].kind, "metric": _metric(store, n, reflection_errors, directions),
                       "probes": int(np.asarray(v).size), "summary": quality.summarise(v), "per_probe": v}
                   for n, v in errors.items()},
        "worst_probes": quality.worst_probes(store, errors),
        "negative_share": {n: {"summary": quality.summarise(v), "per_probe": v} for n, v in negatives.items()},
        "deringing": _deringing(store, negatives),
        "quantization": {n: {"source": q["source"], "summary": quality.summarise(q["relative_rmse"]),
                             "per_probe": q["relative_rmse"]} for n, q in quantization.items()},
        "reflection_alpha_curves": curves,
        "sanitized_texels": (np.asarray(store.diagnostics["input/sanitized_texels"]).sum(axis=0).tolist()
                             if "input/sanitized_texels" in store.diagnostics else None),
        # issue 11: the relative SH noise each rendered probe's capture achieved (NaN: loaded from an image)
        "capture_sh_noise": _capture_noise(store),
        "capture_validity": _capture_validity(store),
        "warnings": store.json_attribute("warnings"),
        # probes the bake could not store (root attribute failed_probes: probe → reason; absent from the store)
        "failed_probes": failed_probes(store.attributes),
        # encodings of a newer bakery: in the memory table, not in the quality figures (quality.evaluable)
        "not_evaluated": {n: reason for n in store.encodings for reason in [store.unsupported_reason(n)] if reason},
    }
    plots: dict[str, str] = {}
    for kind, suffix, ylabel in (("irradiance", "", "relative RMSE vs exact irradiance"),
                                 ("reflection", "-reflection",
                                  "relative MSE vs reference (mean over α grid, materials)")):
        points = []
        chosen = {n: v for n, v in errors.items() if store.encodings[n].kind == kind}
        for name, v in chosen.items():
            s = quality.summarise(v)
            if s["count"]:
                points.append({"label": name, "x": float(store.encodings[name].bytes_per_probe), "y": s["median"],
                               "y_lo": s["min"], "y_hi": s["max"]})
        if points:
            plots[f"error-vs-memory{suffix}"] = svg.scatter_plot(
                f"error-vs-memory{suffix}", f"{kind.capitalize()}: error vs memory (median, whiskers min–max over "
                "probes)", points, "bytes per probe", ylabel)
            plots[f"error-distribution{suffix}"] = svg.strip_plot(
                f"error-distribution{suffix}", f"{kind.capitalize()}: per-probe error distribution",
                {n: list(map(float, v)) for n, v in chosen.items()}, ylabel)
    plots["memory"] = svg.bar_plot(
        "memory", "Bytes per probe (log scale)",
        [(n, float(e["bytes_per_probe"])) for n, e in memory["encodings"].items()]
        + [(k, float(c["bytes_per_probe"])) for k, c in memory["comparisons"].items()], "bytes per probe")
    if negatives:
        plots["negative-share"] = svg.bar_plot(  # the table's mean (summarise: over the measured probes)
            "negative-share", "Mean share of normals with negative irradiance",
            [(n, float(quality.summarise(v).get("mean", math.nan))) for n, v in negatives.items()],
            "share of directions", log=False)
    if curves:
        for material in quality.MATERIALS:  # the per-α table's means (over the measured probes)
            series = {n: list(zip(curves["alphas"], quality._measured_mean(c[material]), strict=True))
                      for n, c in curves["encodings"].items()}
            plots[f"alpha-{material}"] = svg.line_plot(
                f"alpha-{material}", f"Reflection error per α ({material}, F0 = {quality.MATERIALS[material]})",
                series, "GGX α", "relative MSE vs reference")
    previews_out: dict[str, Any] = {}
    if previews:
        previews_out = _previews(store, errors, references, sphere_size)
    data["previews"] = {kind: {role: {"probe": p["probe"]} for role, p in v.items()} for kind, v in previews_out.items()}
    data["seconds"] = time.perf_counter() - start
    data = jsonable(data)
    return data, render_page(data, plots, previews_out)


def _deringing(store: Any, negatives: dict[str, np.ndarray]) -> dict[str, dict[str, Any]]:
    """Negative share before (``<base>``) and after (``<base>_deringed``) deringing, over the probes both encodings
    hold and measured (each probe of a scene may list its own encodings: rows are matched by probe, not position)."""
    out = {}
    for name, after in negatives.items():
        base = name.removesuffix("_deringed")
        if not name.endswith("_deringed") or base not in negatives:
            continue
        before = dict(zip(quality.probe_rows(store, base).tolist(), np.asarray(negatives[base]).tolist(), strict=True))
        pairs = np.array([(before[i], a) for i, a in zip(quality.probe_rows(store, name).tolist(),
                                                           np.asarray(after).tolist(), strict=True)
                          if i in before and math.isfinite(before[i]) and math.isfinite(a)], dtype=np.float64)
        if len(pairs) == 0:
            continue
        out[name] = {"before": base, "probes": len(pairs), "mean_before": float(pairs[:, 0].mean()),
                     "mean_after": float(pairs[:, 1].mean()), "max_before": float(pairs[:, 0].max()),
                     "max_after": float(pairs[:, 1].max())}
    return out


def _metric(store: Any, name: str, reflection_errors: dict[str, Any], directions: int) -> str:
    """What an encoding's error figure is (quality module doc)."""
    if store.encodings[name].kind == "irradiance":
        return f"relative RMSE vs exact irradiance ({directions} directions, RGB)"
    if name in reflection_errors:
        return (f"relative MSE vs reference reflection, mean over the {len(quality.CURVE_ALPHAS)} α of the grid "
                "and chrome/glass")
    return "stored reference_error diagnostic"


def _roles(picked: dict[str, int]) -> dict[str, int]:
    """Merge roles that name the same probe ("worst = median" for a one-probe store)."""
    merged: dict[int, list[str]] = {}
    for role, i in picked.items():
        merged.setdefault(i, []).append(role)
    return {" = ".join(roles): i for i, roles in merged.items()}


def _previews(store: Any, errors: dict[str, np.ndarray], references: list[Any] | None, size: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    irr = quality.encodings_of_kind(store, "irradiance")
    if irr:
        out["irradiance"] = {}
        for role, i in _roles(quality.pick_probes(store, errors, "irradiance")).items():
            probe = store.probe_names[i]
            usable = [n for n in irr if i in set(quality.probe_rows(store, n).tolist())]
            ref = references[i] if references is not None else None
            out["irradiance"][role] = {"probe": probe, "rows": {
                "diffuse": render.irradiance_previews(store, probe, usable, ref, size)}}
    refl = quality.encodings_of_kind(store, "reflection")
    if refl:
        out["reflection"] = {}
        for role, i in _roles(quality.pick_probes(store, errors, "reflection")).items():
            probe = store.probe_names[i]
            usable = [n for n in refl if i in set(quality.probe_rows(store, n).tolist())]
            ref = references[i] if references is not None else None
            rows = {}
            for material, f0 in quality.MATERIALS.items():
                for alpha in PREVIEW_ALPHAS:
                    rows[f"{material} α={alpha}"] = render.reflection_previews(
                        store, probe, usable, ref, alpha, f0, size=max(32, size * 3 // 4))
            out["reflection"][role] = {"probe": probe, "rows": rows}
    return out


def _report_refusal(path: Path) -> str | None:
    """Why an existing file must not be replaced by a report file (None: a previous bakery report)."""
    if path.suffix != ".html":
        return json_output_refusal(path, ("store", "bakery_version", "memory"), "a bakery report")
    try:
        with open(path, "rb") as handle:
            head = handle.read(1 << 20)
    except OSError as error:
        return f"exists and cannot be read ({os_error_message(error)})"
    return None if b"<title>bakery report:" in head else "exists and is not a bakery report page"


def check_report_output(out: Path, inputs: list[Path], force: bool = False) -> None:
    """The output policy for ``bakery report -o DIR``: DIR is new or a folder; report.html/report.json in it are
    new or previous bakery reports (``force``: anything but an input)."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: report output exists and is not a directory; refusing to replace it")
    if not out.exists():
        parent = out.parent if str(out.parent) else Path(".")
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        problem = folder_problem(parent)
        if problem:
            raise OutputError(f"{out}: cannot create the report folder: {parent} {problem}")
        return
    for name in ("report.html", "report.json"):
        check_output_file(out / name, "report", inputs=inputs, refusal=_report_refusal, force=force)


def write_report(store: str | os.PathLike[str], out_dir: str | os.PathLike[str],
                 environment: str | os.PathLike[str] | None = None, previews: bool = True,
                 force: bool = False) -> dict[str, Any]:
    """Write ``report.html`` and ``report.json`` for ``store`` into ``out_dir`` (created if missing).

    Returns {"html": path, "json": path, "data": report data}. Raises :class:`bakery.errors.StoreFormatError` for
    an unreadable store (or one that fails its checksums) and :class:`bakery.files.OutputError` when ``out_dir``
    cannot be written or holds files that are not previous bakery reports (unless ``force``); in every case
    nothing in ``out_dir`` is changed.
    """
    out = Path(out_dir)
    inputs = [Path(store)] + ([Path(environment)] if environment is not None else [])
    check_report_output(out, inputs, force)
    data, page = build_report(store, environment=environment, previews=previews)
    html_path, json_path = out / "report.html", out / "report.json"
    created = _missing_folders(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        # Both written before either replaces an existing file (the inner one, report.json, is renamed first).
        with atomic_replace(html_path) as html_tmp, atomic_replace(json_path) as json_tmp:
            json_tmp.write_text(json.dumps(data, indent=1, allow_nan=False), encoding="utf-8")
            html_tmp.write_text(page, encoding="utf-8")
    except OSError as error:
        _remove_empty_folders(created)
        raise OutputError(f"{out}: cannot write the report: {os_error_message(error)}") from None
    except BaseException:  # Ctrl-C, SIGTERM: the temporaries are gone (atomic_replace); so are the new folders
        _remove_empty_folders(created)
        raise
    return {"html": html_path, "json": json_path, "data": data}


def _missing_folders(out: Path) -> list[Path]:
    """The folders ``out.mkdir(parents=True)`` would create, deepest first."""
    missing = []
    folder = out
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


def _remove_empty_folders(folders: list[Path]) -> None:
    """Remove the folders a failed report created (deepest first; only if empty: nothing of anyone else's)."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            return


def _capture_validity(store: Any, listed: int = 20) -> dict[str, Any] | None:
    """The threshold, count and (up to ``listed``) names of the probes likely inside geometry, with the summary of
    every rendered probe's backface fraction (``capture/backface_fraction``), or None when the store has none."""
    from bakery.conventions import INSIDE_BACKFACE_FRACTION
    from bakery.pipeline.dilate import NEIGHBOURS_KEY
    from bakery.pipeline.merge import BACKFACE_KEY, inside_geometry

    if BACKFACE_KEY not in store.diagnostics:
        return None
    fraction = np.asarray(store.diagnostics[BACKFACE_KEY], dtype=np.float64)
    threshold = float(store.attributes.get("inside_geometry_backface_fraction", INSIDE_BACKFACE_FRACTION))
    inside = inside_geometry(store.diagnostics, threshold)
    offset = np.linalg.norm(np.asarray(store.diagnostics.get("capture/offset", np.zeros((len(fraction), 3))),
                                       dtype=np.float64), axis=-1)
    moved = np.flatnonzero(offset > 0)
    sources = np.nan_to_num(np.asarray(store.diagnostics.get(NEIGHBOURS_KEY, np.zeros(len(fraction))),
                                       dtype=np.float64))
    return {"threshold": threshold, "summary": quality.summarise(fraction), "inside_count": int(inside.size),
            "inside": [{"probe": store.probe_names[i], "backface_fraction": float(fraction[i]),
                        "dilated_from": int(sources[i])} for i in inside[:listed]],
            "relocated_count": int(moved.size), "largest_offset_m": float(offset[moved].max()) if moved.size else 0.0,
            "dilated_count": int(np.count_nonzero(sources > 0))}


def _capture_noise(store: Any) -> dict[str, Any] | None:
    """Summary, target and the noisiest probes of the relative SH noise each rendered probe's capture achieved
    (``capture/sh_noise``; NaN: loaded from an image), or None when the store has none (issue 11)."""
    if "capture/sh_noise" not in store.diagnostics:
        return None
    noise = np.asarray(store.diagnostics["capture/sh_noise"], dtype=np.float64)
    order = [int(i) for i in np.argsort(-np.where(np.isfinite(noise), noise, -np.inf), kind="stable")
             if np.isfinite(noise[i])][:5]
    target = store.attributes.get("capture_target_noise")
    return {"summary": quality.summarise(noise), "target": float(target) if target is not None else None,
            "noisiest": [{"probe": store.probe_names[i], "noise": float(noise[i])} for i in order]}
