"""The report's HTML page: one file, inline CSS, inline SVG, PNG data URIs, no scripts and no external requests."""

from __future__ import annotations

import math
from html import escape
from typing import Any

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px auto;max-width:1340px;color:#222;
background:#fafafa;padding:0 16px}
h1{font-size:22px}h2{font-size:18px;border-bottom:1px solid #ccc;padding-bottom:4px;margin-top:32px}
h3{font-size:15px}
table{border-collapse:collapse;margin:8px 0;font-size:13px;background:#fff}
th,td{border:1px solid #ccc;padding:3px 8px;text-align:right}th{background:#eee}
td.l,th.l{text-align:left}
.plots{display:flex;flex-wrap:wrap;gap:12px}.plots svg{border:1px solid #ddd;background:#fff}
.row{display:flex;flex-wrap:wrap;gap:8px;align-items:flex-start;margin:4px 0 12px}
figure{margin:0;text-align:center;font-size:11px}figure img{image-rendering:pixelated;width:128px;height:128px;
display:block;border:1px solid #ccc}
.note{color:#666;font-size:13px}
code{background:#eee;padding:0 3px}
"""


#: What a cell of a measured figure says when nothing was measured (null in the JSON; never a made-up 0).
NOT_MEASURED = "not measured"


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None or isinstance(v, float) and not math.isfinite(v):  # unmeasured or not applicable (null in the JSON)
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    if isinstance(v, int):
        return f"{v:,}"
    return escape(str(v))


def _table(header: list[str], rows: list[list[Any]], left: int = 1) -> str:
    th = "".join(f'<th class="{"l" if i < left else ""}">{escape(h)}</th>' for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(f'<td class="{"l" if i < left else ""}">{_fmt(c)}</td>' for i, c in enumerate(r))
                   + "</tr>" for r in rows)
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def _memory_section(m: dict[str, Any]) -> str:
    chains = [k for k in m["comparisons"] if k.startswith("split_sum_")]
    rows = [[n, e["kind"], e["bytes_per_probe"], _upload(e), e["probes"], e["total_bytes"],
             m["ratios"][n]["vs_sh3_float"], *[m["ratios"][n][f"vs_{k}"] for k in chains]]
            for n, e in m["encodings"].items()]
    out = [_table(["encoding", "kind", "bytes/probe", "uploaded bytes/probe", "probes", "total bytes", "× SH3 float",
                   *[f"× {k.removeprefix('split_sum_')}" for k in chains]], rows, left=2)]
    out.append(_table(["probe kind", "probes", "total bytes (stored encodings)"],
                      [[k, m["probes_of_kind"].get(k, 0), m["total_bytes_per_kind"].get(k, 0)]
                       for k in ("irradiance", "reflection")]
                      + [["shared tables (once)", None, m.get("shared_bytes", 0)],
                         ["all", m["probes"], m.get("total_bytes_with_shared", m["total_bytes"])]]))
    if m.get("shared_tables"):
        out.append(_table(["shared table (identical contents counted once)", "dtype", "shape", "bytes"],
                          [[", ".join(t["tables"]), t["dtype"], " × ".join(map(str, t["shape"])), t["bytes"]]
                           for t in m["shared_tables"]]))
    c = m["split_sum_chain"]
    out.append(_table(["alternative", "bytes/probe", "total for the same probes"],
                      [[k, v["bytes_per_probe"], v.get("total_bytes_irradiance_probes",
                                                       v.get("total_bytes_reflection_probes"))]
                       for k, v in m["comparisons"].items()]))
    out.append(f'<p class="note">Split-sum chains: {c["n_levels"]} levels, cube faces {c["cube_sizes"]}, octahedral '
               f'sides {c["octahedral_sizes"]}; RGBA16F = 8 B/texel, BC6H = 1 B/texel (computed). SH3 float = 108 B. '
               f'Totals for split-sum count the store\'s reflection probes, SH3 its irradiance probes. Ratios are of '
               f'the stored bytes/probe. Uploaded bytes/probe: what an engine uploads (mean over the probes; '
               f'<code>shexp_hybrid</code> probes do not upload the chain levels below their '
               f'<code>first_level</code>, nor a gap level they skip; none for a probe that needs no chain). '
               f'Bytes/probe exclude shared '
               f'tables (e.g. the DFG table of the reflection encodings), which are counted once per distinct '
               f'content in "shared tables"; the octahedral chain\'s floor is the paper\'s {c["min_face_size"]}² '
               f'octahedral map, not twice the cube floor.</p>')
    return "\n".join(out)


def _measured(v: Any) -> Any:
    """A measured figure's cell value: the number, or NOT_MEASURED where nothing was measured (null)."""
    return NOT_MEASURED if v is None or isinstance(v, float) and not math.isfinite(v) else v


def _upload(e: dict[str, Any]) -> Any:
    """Uploaded bytes per probe of a memory-table entry: the value when every probe uploads the same, else the mean
    with the range."""
    u = e.get("upload_bytes_per_probe")
    if not u:
        return None
    if u["min"] == u["max"]:
        return u["min"]
    return f'{u["mean"]:,.0f} ({u["min"]:,}–{u["max"]:,})'


def _percent(b: float) -> str:
    """A signed percentage with enough digits that a small bias does not print as "+0%" / "-0%"."""
    if b == 0:
        return "±0%"
    return f"{100 * b:+.0f}%" if abs(b) >= 0.0995 else f"{100 * b:+.2g}%"


def _alpha_cell(mse: float | None, bias: float | None) -> str:
    """"0.12 (+3%)"; NOT_MEASURED for an unmeasured or unbounded value (a NaN/inf cell is null in the JSON)."""
    if mse is None or not math.isfinite(mse):
        return NOT_MEASURED
    if bias is None or not math.isfinite(bias):
        return f"{mse:.3g}"
    return f"{mse:.3g} ({_percent(bias)})"


def _alpha_table(curves: dict[str, Any]) -> str:
    """Per encoding and material, per α: relative MSE vs the reference and the signed brightness bias (mean over
    probes) — the reflection bench's per-α table for this store."""
    from bakery.report.quality import alpha_table

    alphas = curves.get("alphas", [])
    rows = []
    for row in alpha_table(curves):
        bias = row["bias"] or [None] * len(alphas)
        rows.append([row["encoding"], row["material"],
                     *[_alpha_cell(m, b) for m, b in zip(row["relative_mse"], bias, strict=True)]])
    table = _table(["encoding", "material", *[f"α={a:g}" for a in alphas]], rows, left=2)
    methods = curves.get("reference") or []
    if methods:
        table += _table(["reference integration", *[f"α={m['alpha']:g}" for m in methods]],
                        [["method", *[m["method"] for m in methods]],
                         ["finest sub-texels per texel side (view along n)",
                          *[m["subdivision"] if m["method"] != "mirror" else None for m in methods]],
                         ["texel centres (per row)", *[m["samples"] for m in methods]]])
    return (table + '<p class="note">Cells: relative MSE ΣΔE²/ΣE<sub>ref</sub>² over '
            f'{curves.get("rows_per_alpha", 0)} (v, n) rows and RGB (signed brightness bias ΣE/ΣE<sub>ref</sub> − 1), '
            "mean over the measured probes. Reference: the integral over the full-resolution capture, every texel's "
            "radiance constant over its footprint — every texel at its centre, and the texels where the GGX lobe "
            "is narrow on their scale split adaptively into sub-texels (at most 1/16 of the lobe's local width), "
            "the texel containing the mirror direction for α = 0 (the mirror). "
            f"{NOT_MEASURED}: the reference is black over every row (a relative error is not measurable).</p>")


def _preview_section(title: str, previews: dict[str, Any]) -> str:
    out = [f"<h3>{escape(title)}</h3>"]
    for role, p in previews.items():
        out.append(f'<p><b>{escape(role)} probe</b>: <code>{escape(p["probe"])}</code></p>')
        for row_label, images in p["rows"].items():
            figs = "".join(f'<figure><img alt="{escape(label)}" src="{uri}"><figcaption>{escape(label)}'
                           f'</figcaption></figure>' for label, uri in images.items())
            out.append(f'<div class="row" data-preview="{escape(row_label)}"><div style="width:110px;font-size:12px">'
                       f'{escape(row_label)}</div>{figs}</div>')
    return "\n".join(out)


def _reference_note(reference: dict[str, Any] | None) -> str:
    """Which image the quality figures were measured against, and whether it is the one the store was baked from."""
    if not reference:
        return ""
    match = {True: "its flux matches the store's input", False: "<b>not the image this store was baked from</b> "
             "(its flux differs from the store's input)", None: "the store records no input flux to check it"}
    return f' (<code>{escape(str(reference["path"]))}</code>; {match[reference["flux_matches_store"]]})'


def render_page(data: dict[str, Any], plots: dict[str, str], previews: dict[str, Any]) -> str:
    """The HTML page for report ``data`` with ready SVG ``plots`` and preview image rows."""
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             '<link rel="icon" href="data:,">',
             f"<title>bakery report: {escape(str(data['store']))}</title><style>{_CSS}</style></head><body>",
             f"<h1>bakery report — <code>{escape(str(data['store']))}</code></h1>",
             f'<p class="note">{data["probes"]} probe{"" if data["probes"] == 1 else "s"}; '
             f'store format {escape(str(data["format_version"]))}, '
             f'baked by bakery {escape(str(data["store_bakery_version"]))}; report by bakery '
             f'{escape(str(data["bakery_version"]))}; settings hash <code>{escape(str(data["settings_hash"])[:16])}'
             f'</code>. Reference capture available: {"yes" if data["reference_available"] else "no"}'
             f'{_reference_note(data.get("reference"))}.</p>']
    if data.get("failed_probes"):
        failed = data["failed_probes"]
        parts.append(f"<h2>Failed probes</h2><p class=\"note\">{len(failed)} probe(s) failed in the bake and are "
                     "<b>not in this store</b> (nor in the figures below); re-bake after fixing their input.</p>")
        parts.append(_table(["probe (prim path)", "reason"], [[n, r.removeprefix(f"{n}: ")] for n, r in failed.items()]))
    parts.append("<h2>Memory</h2>")
    parts.append(_memory_section(data["memory"]))
    parts.append('<div class="plots">' + plots.get("memory", "") + "</div>")
    parts.append("<h2>Quality</h2>")
    directions = data.get("quality_directions", 1024)
    curves = data.get("reflection_alpha_curves") or {}
    grid = ", ".join(f"{a:g}" for a in curves.get("alphas", []))
    if data["errors"]:
        rows = [[n, e["metric"], data["memory"]["encodings"][n]["bytes_per_probe"],
                 e.get("probes", e["summary"].get("count", 0)), e["summary"].get("count", 0),
                 *[_measured(e["summary"].get(k)) for k in ("mean", "median", "p90", "max")]]
                for n, e in data["errors"].items()]
        parts.append(_table(["encoding", "metric", "bytes/probe", "probes", "measured", "mean", "median", "p90",
                             "max"], rows, left=2))
        parts.append(f'<p class="note">Irradiance: relative RMSE √Σ(E−E<sub>ref</sub>)²/√ΣE<sub>ref</sub>² over '
                     f'{directions} Fibonacci normals and RGB against the brute-force irradiance of the '
                     'full-resolution capture (the store\'s <code>reference_error</code> diagnostics where it has '
                     'them). Reflection: relative MSE ΣΔE²/ΣE<sub>ref</sub>² over '
                     f'{curves.get("rows_per_alpha", 128)} (v, n) rows and RGB per α, the plain mean over the α '
                     f'grid ({grid}) and chrome/glass (seed 000 Fig. 4–7 protocol, extended to α &lt; 0.25). '
                     'Statistics are over the measured probes: a probe whose reference is black has no relative '
                     'error ("not measurable", not 0).</p>')
        parts.append('<div class="plots">' + "".join(plots.get(k, "") for k in (
            "error-vs-memory", "error-distribution", "error-vs-memory-reflection", "error-distribution-reflection"))
            + "</div>")
        parts.append("<h3>Worst probes</h3>")
        short = {"irradiance": "relative RMSE", "reflection": "relative MSE"}
        worst = [[n, w["probe"], short.get(data["errors"][n]["kind"], "error"), w["error"],
                  ", ".join(f"{x:.3g}" for x in w["position"])]
                 for n, ws in data["worst_probes"].items() for w in ws[:3]]
        parts.append(_table(["encoding", "probe (prim path)", "metric", "error", "position"], worst, left=3))
    else:
        parts.append('<p class="note">No reference errors: the store has no <code>reference_error/*</code> '
                     "diagnostics and no capture to compute them from.</p>")
    if data["negative_share"]:
        parts.append("<h3>Negative irradiance</h3>")
        rows = [[n, _measured(s["summary"].get("mean")), _measured(s["summary"].get("max"))]
                for n, s in data["negative_share"].items()]
        parts.append(_table(["encoding", "mean share", "max share"], rows))
        parts.append(f'<p class="note">Share of {directions} Fibonacci normals where any channel of the '
                     "reconstructed irradiance is negative (compare an encoding with its <code>_deringed</code> "
                     "variant: before and after deringing).</p>")
        if data.get("deringing"):
            rows = [[d["before"], n, d["mean_before"], d["mean_after"], d["max_before"], d["max_after"]]
                    for n, d in data["deringing"].items()]
            parts.append(_table(["before", "after deringing", "mean share before", "mean share after",
                                 "max before", "max after"], rows, left=2))
        parts.append('<div class="plots">' + plots.get("negative-share", "") + "</div>")
    if data.get("capture_sh_noise") and data["capture_sh_noise"]["summary"].get("count"):
        noise = data["capture_sh_noise"]
        parts.append("<h3>Capture noise</h3>")
        summary = noise["summary"]
        parts.append(_table(["rendered probes", "mean", "median", "p90", "max", "target"],
                            [[summary["count"], summary["mean"], summary["median"], summary["p90"], summary["max"],
                              noise["target"] if noise["target"] else "none (fixed samples)"]], left=0))
        parts.append(_table(["noisiest probe (prim path)", "relative SH noise"],
                            [[w["probe"], w["noise"]] for w in noise["noisiest"]]))
        parts.append('<p class="note">Relative Monte Carlo standard error of each rendered capture\'s radiance SH '
                     "(bands 0–2, luminance), estimated from independent sample passes; with a target the capture "
                     "adds passes until it is reached or <code>max_samples</code> is spent.</p>")
    validity = data.get("capture_validity")
    if validity and validity["summary"].get("count"):
        parts.append("<h3>Probe validity</h3>")
        parts.append(_table(["rendered probes", f"likely inside geometry (≥ {validity['threshold']:.0%})",
                             "mean backface fraction", "max", "relocated", "largest offset (m)", "dilated"],
                            [[validity["summary"]["count"], validity["inside_count"], validity["summary"]["mean"],
                              validity["summary"]["max"], validity["relocated_count"],
                              validity["largest_offset_m"], validity.get("dilated_count", 0)]], left=0))
        if validity["inside"]:
            parts.append(_table(["probe inside geometry (prim path)", "backface fraction", "dilated from"],
                                [[w["probe"], w["backface_fraction"], w.get("dilated_from", 0) or "—"]
                                 for w in validity["inside"]]))
        parts.append('<p class="note">Share of each probe\'s camera rays whose first hit is the back of a '
                     "single-sided surface (inside closed geometry, or a surface wound away from the probe); such a "
                     "probe stores what the inside looks like unless its volume dilates it (it then stores the "
                     "inverse-square-distance-weighted mean of the valid probes within reach; "
                     "<code>bakery:volume:dilate</code>). Move it, relocate or dilate its volume, or author "
                     "<code>doubleSided</code> on open sheets seen from both sides.</p>")
    if data["quantization"]:
        parts.append("<h3>Quantization error</h3>")
        rows = [[n, q["source"], _measured(q["summary"].get("mean")), _measured(q["summary"].get("max"))]
                for n, q in data["quantization"].items()]
        parts.append(_table(["quantized", "float source", "mean rel. RMSE", "max rel. RMSE"], rows, left=2))
        parts.append(f'<p class="note">Relative RMSE of the quantized encoding\'s irradiance against its float '
                     f"source's over {directions} Fibonacci normals and RGB (the quantization alone, not the error "
                     "against the capture), over the probes both hold.</p>")
    if data["reflection_alpha_curves"]:
        parts.append("<h3>Reflection error per roughness</h3>")
        parts.append(_alpha_table(data["reflection_alpha_curves"]))
        parts.append('<div class="plots">' + "".join(v for k, v in plots.items() if k.startswith("alpha-"))
                     + "</div>")
    elif any(e["kind"] == "reflection" for e in data["memory"]["encodings"].values()):
        parts.append('<p class="note">Per-α reflection curves need the probe capture, which this store does not '
                     "reference.</p>")
    else:
        parts.append('<p class="note">No reflection encodings in this store: reflection sections skipped.</p>')
    if previews:
        parts.append("<h2>Previews</h2>")
        parts.append('<p class="note">Orthographic spheres, shared exposure per row, tone map 1−e<sup>−kx</sup> + '
                     "sRGB; magenta = negative radiance (ringing).</p>")
        if "irradiance" in previews:
            parts.append(_preview_section("Diffuse sphere (irradiance / π)", previews["irradiance"]))
        if "reflection" in previews:
            parts.append(_preview_section("Chrome (F0 = 1) and glass (F0 = 0.04) spheres", previews["reflection"]))
    if data.get("not_evaluated"):
        parts.append("<h2>Encodings not evaluated</h2><p class=\"note\">In the memory table only: this bakery cannot "
                     "evaluate them (upgrade bakery to see their quality).</p><ul>"
                     + "".join(f"<li>{escape(n)}: {escape(str(r))}</li>" for n, r in data["not_evaluated"].items())
                     + "</ul>")
    if data.get("warnings"):
        parts.append("<h2>Bake warnings</h2><ul>" + "".join(f"<li>{escape(str(w))}</li>" for w in data["warnings"])
                     + "</ul>")
    if data.get("sanitized_texels"):
        s = data["sanitized_texels"]
        parts.append(f'<p class="note">Input texels replaced: NaN {s[0]}, +Inf {s[1]}, −Inf {s[2]}, negative {s[3]}.</p>')
    parts.append("</body></html>")
    return "\n".join(parts)
