"""Comparing two stores probe by probe (``bakery diff``)."""

from __future__ import annotations

import os

import numpy as np

from bakery.store.format import read_store


def diff_stores(a: str | os.PathLike[str], b: str | os.PathLike[str], tolerance: float = 0.0) -> dict:
    """Probes added/removed/changed from A to B, and encodings added/removed. A probe changed if any stored field
    of an encoding both stores have differs, or if it has that encoding in one store only; the size of the change
    is ‖b − a‖ / max(‖a‖, tiny) per encoding (float64 of the stored values; 1.0 when the shapes differ, when the
    probe has the encoding in one store only, or when non-finite values differ; equal non-finite values are no
    change). Fields one store's encoding version lacks are not compared.

    Returns {"added", "removed": probe names; "changed": {probe: {encoding: relative change}}; "unchanged": count;
    "moved": {probe: distance in metres between its positions in A and B} (a probe's position is not part of its
    encodings: a moved probe may be unchanged);
    "not_compared": probes in both stores that share no encoding with a row in either (nothing to compare, so
    neither changed nor unchanged); "encodings": the encodings both stores have; "encodings_added",
    "encodings_removed"; "identical": same probes, same encodings, no change, none moved, nothing left
    uncompared}.
    """
    sa, sb = read_store(a), read_store(b)
    names_a, names_b = set(sa.probe_names), set(sb.probe_names)

    def rows(contents, name):
        out = {}
        for enc, entry in contents.encodings.items():
            index = entry["fields"]["probe_index"]
            out[enc] = {int(i): r for r, i in enumerate(index)}
        return out

    rows_a, rows_b = rows(sa, None), rows(sb, None)
    index_a = {n: i for i, n in enumerate(sa.probe_names)}
    index_b = {n: i for i, n in enumerate(sb.probe_names)}
    changed: dict[str, dict[str, float]] = {}
    not_compared: list[str] = []
    unchanged = 0
    common = sorted(set(sa.encodings) & set(sb.encodings))
    for name in sorted(names_a & names_b):
        change: dict[str, float] = {}
        compared = False
        for enc in common:
            ra = rows_a[enc].get(index_a[name])
            rb = rows_b[enc].get(index_b[name])
            if ra is None and rb is None:
                continue
            compared = True
            if ra is None or rb is None:  # the probe has this encoding in one store only
                change[enc] = 1.0
                continue
            fa = sa.encodings[enc]["fields"]
            fb = sb.encodings[enc]["fields"]
            num = den = 0.0
            for key in fa:
                if key == "probe_index" or key not in fb:
                    continue
                va = np.asarray(fa[key][ra], dtype=np.float64)
                vb = np.asarray(fb[key][rb], dtype=np.float64)
                if va.shape != vb.shape:
                    num, den = 1.0, 1.0
                    break
                finite = np.isfinite(va) & np.isfinite(vb)
                same = (va == vb) | (np.isnan(va) & np.isnan(vb))
                if np.any(~finite & ~same):  # inf vs a number, NaN vs a number, +inf vs -inf
                    num, den = 1.0, 1.0
                    break
                num += float(np.sum((vb[finite] - va[finite]) ** 2))
                den += float(np.sum(va[finite] ** 2))
            relative = np.sqrt(num) / max(np.sqrt(den), 1e-300) if num > 0 else 0.0
            if relative > tolerance:
                change[enc] = float(relative)
        if change:
            changed[name] = change
        elif compared:
            unchanged += 1
        else:
            not_compared.append(name)
    moved = {}
    for name in sorted(names_a & names_b):
        pa = np.asarray(sa.probe_positions[index_a[name]], dtype=np.float64)
        pb = np.asarray(sb.probe_positions[index_b[name]], dtype=np.float64)
        if not np.array_equal(pa, pb, equal_nan=True):
            distance = float(np.linalg.norm(pb - pa))
            moved[name] = distance if np.isfinite(distance) else None
    report = {"added": sorted(names_b - names_a), "removed": sorted(names_a - names_b), "changed": changed,
              "unchanged": unchanged, "moved": moved, "not_compared": not_compared, "encodings": common,
              "encodings_added": sorted(set(sb.encodings) - set(sa.encodings)),
              "encodings_removed": sorted(set(sa.encodings) - set(sb.encodings))}
    report["identical"] = not (report["added"] or report["removed"] or changed or moved or not_compared
                               or report["encodings_added"] or report["encodings_removed"])
    return report
