"""Comparing two stores probe by probe (``bakery diff``)."""

from __future__ import annotations

import os

import numpy as np

from bakery.store.format import read_store


def diff_stores(a: str | os.PathLike[str], b: str | os.PathLike[str], tolerance: float = 0.0) -> dict:
    """Probes added/removed/changed from A to B, and encodings added/removed. A probe changed if any stored field
    of an encoding both stores have differs, or if it has that encoding in one store only; the size of the change
    is ‖b − a‖ / max(‖a‖, tiny) per encoding (float64 of the stored values; 1.0 when the shapes differ or the probe
    has the encoding in one store only). Fields one store's encoding version lacks are not compared.
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
    unchanged = 0
    for name in sorted(names_a & names_b):
        change: dict[str, float] = {}
        for enc in sorted(set(sa.encodings) & set(sb.encodings)):
            ra = rows_a[enc].get(index_a[name])
            rb = rows_b[enc].get(index_b[name])
            if ra is None and rb is None:
                continue
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
                num += float(np.sum((vb - va) ** 2))
                den += float(np.sum(va**2))
            relative = np.sqrt(num) / max(np.sqrt(den), 1e-300) if num > 0 else 0.0
            if relative > tolerance:
                change[enc] = float(relative)
        if change:
            changed[name] = change
        else:
            unchanged += 1
    return {"added": sorted(names_b - names_a), "removed": sorted(names_a - names_b), "changed": changed,
            "unchanged": unchanged, "encodings_added": sorted(set(sb.encodings) - set(sa.encodings)),
            "encodings_removed": sorted(set(sa.encodings) - set(sb.encodings))}
