"""Parent side, between the workers and the writer: merge batches (and reused probes) into store order, skip bands
that carry no energy, and finalize encodings over every probe.

    merged = merge_batches(batches + [extract_probes(previous, reused)], order)
    skipped = apply_band_skips(merged, tolerance)          # seed 003 §5.1, seed 002 §4.4 (bakery.pipeline.skip)
    encodings = finalize_encodings(merged, settings)       # e.g. the hallucination curve fitted over all probes
    inside = inside_geometry_warning(merged)               # probes whose rays see back faces (validity)
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from bakery.conventions import INSIDE_BACKFACE_FRACTION
from bakery.encodings import Encoding, get_encoding
from bakery.errors import ConfigError
from bakery.pipeline.dilate import NEIGHBOURS_KEY
from bakery.pipeline.encode import (
    REFERENCE_IRRADIANCE,
    BakeWarning,
    EncodedBatch,
    aux_key,
    full_length,
    irradiance_diagnostics,
    listed_names,
    relative_rmse_per_probe,
)
from bakery.pipeline.settings import DEFAULT_BAND_TOLERANCE, BakeSettings, build_encodings
from bakery.pipeline.skip import band_skip_decisions
from bakery.probe import Probe
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.zero_pages import MIN_BYTES, SparseRows, discard, lazy_zeros, nonzero_rows


#: Per-probe diagnostics key of the backface fraction (rendered probes; NaN for loaded images and older stores).
BACKFACE_KEY = "capture/backface_fraction"


def inside_geometry(diagnostics: dict[str, np.ndarray], threshold: float = INSIDE_BACKFACE_FRACTION) -> np.ndarray:
    """Indices of the probes whose backface fraction (``diagnostics`` of a merged batch or a store) is ≥
    ``threshold``, in store order (NaN — loaded images, stores from before the diagnostic — never)."""
    fraction = diagnostics.get(BACKFACE_KEY)
    if fraction is None:
        return np.zeros(0, dtype=np.int64)
    with np.errstate(invalid="ignore"):
        return np.flatnonzero(np.asarray(fraction, dtype=np.float64) >= threshold)


def dilated(diagnostics: dict[str, np.ndarray]) -> np.ndarray:
    """(P,) bool: the probes that store a dilation of their volume's valid probes (:mod:`bakery.pipeline.dilate`)."""
    neighbours = diagnostics.get(NEIGHBOURS_KEY)
    if neighbours is None:
        return np.zeros(len(next(iter(diagnostics.values()), ())), dtype=bool)
    with np.errstate(invalid="ignore"):
        return np.asarray(neighbours, dtype=np.float64) > 0


def inside_geometry_warning(merged: EncodedBatch, shown: int = 3) -> BakeWarning | None:
    """One warning naming the probes that are likely inside geometry (:func:`inside_geometry`) and store what they
    captured there (dilated probes store their neighbours'), or None."""
    filled = dilated(merged.diagnostics)
    probes = [merged.probes[i] for i in inside_geometry(merged.diagnostics) if not filled[i]]
    if not probes:
        return None
    names = [probe.name for probe in probes]
    listed = listed_names(names, shown)
    relocated = sum(1 for probe in probes if probe.settings.get("relocate"))
    if relocated == len(probes):  # relocation was on and found no point outside within its search radius
        advice = ("Relocation (bakery:volume:relocate) found no point outside within half the spacing: move them, "
                  "or author")
    else:
        also = f" ({relocated} of them already relocate and found no point outside)" if relocated else ""
        advice = (f"Move them, set bakery:volume:relocate or bakery:volume:dilate on their volume{also}, or "
                  "author")
    return BakeWarning("SceneWarning", (
        f"{len(names)} of {len(merged.probes)} probes are likely inside geometry: ≥ "
        f"{INSIDE_BACKFACE_FRACTION:.0%} of their camera rays see the back of single-sided surfaces ({listed}); "
        f"what they store is the inside. {advice} doubleSided = true on open sheets seen from both sides "
        f"(per probe: /diagnostics/{BACKFACE_KEY})"))


def merge_batches(batches: list[EncodedBatch], order: list[str] | None = None, *,
                  release_inputs: bool = False, scratch: Path | None = None) -> EncodedBatch:
    """Concatenate batches and reorder their probes to ``order`` (names; default: concatenation order).

    ``release_inputs``: each batch's encoded fields are dropped from it as soon as they are merged, so the peak is
    the merged fields plus the one being merged instead of the merged fields plus every batch (the parent of a
    production bake: 1.4 GB of hybrid chains each); the batches' fields are gone afterwards, and those spilled to
    files (:func:`bakery.zero_pages.spilled`) removed. ``scratch``: a folder where the large merged fields are
    sparse files (:class:`bakery.zero_pages.SparseRows`), not memory."""
    probes = [p for b in batches for p in b.probes]
    offsets = np.cumsum([0] + [len(b.probes) for b in batches])
    names = [p.name for p in probes]
    if len(set(names)) != len(names):
        raise ConfigError("probe names must be unique")
    position = {n: i for i, n in enumerate(order if order is not None else names)}
    if set(position) != set(names):
        raise ConfigError("merge order does not name the same probes as the batches")
    permutation = np.array([position[n] for n in names], dtype=np.int64)  # concatenated row -> final row
    final_probes: list[Probe] = [None] * len(probes)  # type: ignore[list-item]
    for i, p in enumerate(probes):
        final_probes[permutation[i]] = p
    encoded: dict[str, dict[str, np.ndarray]] = {}
    rows: dict[str, np.ndarray] = {}
    for name in sorted({n for b in batches for n in b.encoded}):
        parts = [(b, off) for b, off in zip(batches, offsets[:-1]) if name in b.encoded]
        final_rows = np.concatenate([permutation[b.rows[name] + off] for b, off in parts])
        sort = np.argsort(final_rows, kind="stable")
        rows[name] = final_rows[sort]
        destination = np.empty_like(sort)
        destination[sort] = np.arange(sort.size)  # concatenated row -> merged row
        encoded[name] = {}
        for f in list(parts[0][0].encoded[name]):
            encoded[name][f] = _scatter([b.encoded[name][f] for b, _ in parts], destination,
                                        None if scratch is None else scratch / f"merged.{name}.{f}")
            if release_inputs:
                for b, _ in parts:
                    released = b.encoded[name].pop(f)
                    if scratch is not None:  # the batches' spilled files are there too
                        discard(released, scratch)
    diagnostics = _merge_per_probe([b.diagnostics for b in batches], [len(b.probes) for b in batches], permutation)
    transient = _merge_per_probe([b.transient for b in batches], [len(b.probes) for b in batches], permutation)
    timings: dict[str, float] = {}
    for b in batches:
        for k, v in b.timings.items():
            timings[k] = timings.get(k, 0.0) + v
    # Warnings sorted and de-duplicated: their arrival order depends on scheduling, the store must not.
    merged_warnings = sorted({w for b in batches for w in b.warnings}, key=lambda w: (w.message, w.category))
    return EncodedBatch(final_probes, encoded, rows, diagnostics, timings, merged_warnings, transient)


def _merge_per_probe(parts_of: list[dict[str, np.ndarray]], counts: list[int],
                     permutation: np.ndarray) -> dict[str, np.ndarray]:
    """Concatenate per-probe arrays {key: (P_b, ...)} of batches (NaN where a batch lacks a key) into final order."""
    merged: dict[str, np.ndarray] = {}
    for key in sorted({k for part in parts_of for k in part}):
        template = next(part[key] for part in parts_of if key in part)
        parts = [np.asarray(part[key]) if key in part
                 else np.full((count, *np.shape(template)[1:]), np.nan, dtype=np.float32)
                 for part, count in zip(parts_of, counts)]
        merged[key] = _scatter(parts, permutation)
    return merged


def _scatter(parts: list[np.ndarray], destination: np.ndarray, scratch: Path | None = None) -> np.ndarray:
    """``out[destination] = np.concatenate(parts)`` without the concatenated copy: each part is written straight to
    its rows (the parent's peak memory at merge is the batches plus one merged copy, not two). A large numeric
    result is allocated by :func:`bakery.zero_pages.lazy_zeros` — or is the sparse file ``scratch``
    (:class:`bakery.zero_pages.SparseRows`) — and only the parts' rows with a non-zero byte are written, so its
    all-zero rows (levels a probe does not upload) take no memory."""
    shape = (destination.size, *np.shape(parts[0])[1:])
    dtype = np.result_type(*parts)
    lazy = dtype.kind in "biufc" and int(np.prod(shape, dtype=np.int64)) * dtype.itemsize >= MIN_BYTES
    if lazy and scratch is not None:
        rows = SparseRows(shape, dtype, scratch)
        try:
            start = 0
            for part in parts:
                part = np.asarray(part)
                for row in np.flatnonzero(nonzero_rows(part)).tolist():
                    rows.write(int(destination[start + row]), part[row])
                start += len(part)
        finally:
            rows.close()
        return rows.mapped()
    out = lazy_zeros(shape, dtype) if lazy else np.empty(shape, dtype=dtype)
    start = 0
    for part in parts:
        rows = destination[start : start + len(part)]
        start += len(part)
        if not lazy:
            out[rows] = part
            continue
        part = np.asarray(part)
        keep = nonzero_rows(part)
        if keep.all():
            out[rows] = part
        elif keep.any():
            out[rows[keep]] = part[keep]
    return out


def extract_probes(contents, names: list[str], *, encodings: bool = True) -> EncodedBatch:  # noqa: ANN001
    """The stored results of ``names`` (``contents``: a StoreContents) as an :class:`EncodedBatch` (incremental
    reuse); ``encodings`` False: their probes and diagnostics only."""
    index = {n: i for i, n in enumerate(contents.probe_names)}
    picked = np.array([index[n] for n in names], dtype=np.int64)
    probes = [Probe(contents.probe_names[i], tuple(contents.probe_kinds[i].split(",")),
                    tuple(map(float, contents.probe_positions[i]))) for i in picked]
    position = {int(i): r for r, i in enumerate(picked)}
    encoded, rows = {}, {}
    for name, entry in (contents.encodings.items() if encodings else ()):
        probe_index = entry["fields"]["probe_index"]
        keep = np.array([r for r, i in enumerate(probe_index) if int(i) in position], dtype=np.int64)
        if keep.size == 0:
            continue
        rows[name] = np.array([position[int(probe_index[r])] for r in keep], dtype=np.int64)
        encoded[name] = {k: v[keep] for k, v in entry["fields"].items() if k != "probe_index"}
    diagnostics = {k: v[picked] for k, v in contents.diagnostics.items()
                   if np.ndim(v) >= 1 and len(v) == len(contents.probe_names)}
    return EncodedBatch(probes, encoded, rows, diagnostics)


def apply_band_skips(merged: EncodedBatch, tolerance: float | None,
                     candidates: Iterable[str] = ()) -> list[dict[str, str]]:
    """Record each probe's required band (``diagnostics/required_band``) and, unless ``tolerance`` is None
    (encodings asked for explicitly: report, do not skip), drop the encodings no probe needs. ``candidates``: more
    encodings the decision is reported for although no probe of ``merged`` holds them (the planned encodings of
    reused probes whose previous bake skipped them). Returns the skips."""
    if "band_energy" not in merged.diagnostics:
        return []
    energy = np.asarray(merged.diagnostics["band_energy"], dtype=np.float64)
    has = np.all(np.isfinite(energy), axis=1)
    positions = np.array([p.position for p in merged.probes], dtype=np.float64).reshape(-1, 3)
    required, skips = band_skip_decisions(energy[has], positions[has], tolerance or DEFAULT_BAND_TOLERANCE,
                                          sorted(set(merged.encoded) | set(candidates)))
    if tolerance is None:
        skips = []
    required_all = np.full(len(merged.probes), np.nan, dtype=np.float32)
    required_all[has] = required
    merged.diagnostics["required_band"] = required_all
    for skip in skips:
        name = skip["encoding"]
        merged.encoded.pop(name, None)
        merged.rows.pop(name, None)
        for key in [k for k in merged.diagnostics if k.endswith("/" + name) or k.startswith(f"finalize/{name}/")]:
            del merged.diagnostics[key]
    return skips


def finalize_encodings(merged: EncodedBatch, settings: BakeSettings) -> dict[str, Encoding]:
    """The encodings whose parameters are stored: built from the bake's settings, then each one's ``finalize`` over
    every probe of the store (its fields and its ``aux_specs`` inputs) — e.g. the hallucination curve fit.

    The diagnostics of a finalized encoding are computed here, from the finalized parameters: the negative share
    for every probe, the reference error where the workers returned the reference irradiance (probes baked now;
    reused probes keep their stored error)."""
    encodings = build_encodings(sorted(merged.encoded), settings)
    out: dict[str, Encoding] = {}
    deferred: list[str] = []
    for name, encoding in encodings.items():
        rows = merged.rows[name]
        aux = {}
        for spec in encoding.aux_specs():
            values = merged.diagnostics.get(aux_key(name, spec.name))
            if values is None:
                raise ConfigError(f"{name}: finalize input {spec.name} is missing from the merged results")
            aux[spec.name] = np.asarray(values)[rows].astype(spec.dtype)
        params = encoding.finalize(merged.encoded[name], aux)
        out[name] = encoding if params == encoding.params else get_encoding(name)(params)
        if encoding.aux_specs() and encoding.kind == "irradiance":
            deferred.append(name)
    if deferred:
        _finalized_diagnostics(merged, out, deferred, settings)
    return out


def _finalized_diagnostics(merged: EncodedBatch, encodings: dict[str, Encoding], names: list[str],
                           settings: BakeSettings) -> None:
    normals = fibonacci_directions(settings.quality_directions)
    reference_all = merged.transient.get(REFERENCE_IRRADIANCE)
    count = len(merged.probes)
    for name in names:
        rows = merged.rows[name]
        reference = None
        if reference_all is not None:
            reference = np.asarray(reference_all)[rows]
        values = irradiance_diagnostics({name: merged.encoded[name]}, {name: encodings[name]}, normals, None)
        merged.diagnostics[f"negative_fraction/{name}"] = full_length(values[f"negative_fraction/{name}"], rows, count)
        if reference is None:
            continue
        fresh = np.all(np.isfinite(reference), axis=(1, 2))
        if not fresh.any():
            continue
        evaluated = encodings[name].evaluate_irradiance({k: v[fresh] for k, v in merged.encoded[name].items()},
                                                        normals)
        key = f"reference_error/{name}"
        errors = merged.diagnostics.get(key, np.full(count, np.nan, dtype=np.float32)).astype(np.float32)
        errors[rows[fresh]] = relative_rmse_per_probe(evaluated, reference[fresh])
        merged.diagnostics[key] = errors
        if encodings[name].worse_than is not None:
            flag, baseline = encodings[name].worse_than
            base = merged.diagnostics.get(f"reference_error/{baseline.name}")
            if base is not None:
                hurts = np.where(np.isfinite(errors) & np.isfinite(base), (errors > base).astype(np.float32), np.nan)
                merged.diagnostics[flag] = hurts.astype(np.float32)


def remap_history(previous, reused: list[str], probes: list[Probe]) -> tuple[list[dict[str, str]], np.ndarray | None]:  # noqa: ANN001
    """History entries of the earlier bakes that reused probes come from, and each probe's index into it (this
    bake, appended last by the writer, gets index ``len(history)``)."""
    if not reused or previous is None:
        return [], None
    old_ids = dict(zip(previous.probe_names, previous.probe_bake_ids))
    used = sorted({int(old_ids[n]) for n in reused})
    remap = {old: new for new, old in enumerate(used)}
    history = [previous.history[i] for i in used] if previous.history else []
    reused_set = set(reused)
    bake_ids = np.array([remap[int(old_ids[p.name])] if p.name in reused_set else len(history) for p in probes],
                        dtype=np.int32)
    return history, bake_ids
