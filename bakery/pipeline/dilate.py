"""Dilation of the irradiance probes inside geometry from their volume's valid probes (parent side, no I/O).

A probe of a volume with ``bakery:volume:dilate`` whose camera rays see back faces (backface fraction ≥
:data:`~bakery.conventions.INSIDE_BACKFACE_FRACTION`: what it captured is the inside of a wall) stores, instead of
its capture, the inverse-square-distance-weighted mean of the radiance SH (bands 0–2) of the valid probes of its
volume within the search radius d:

    L_i = Σ_j w_ij L_j / Σ_j w_ij,   w_ij = 1 / |x_i − x_j|²,   j valid,  0 < |x_i − x_j| ≤ d         (1)

— the weighting of Unity's adaptive probe volumes ("squared distance weighting"; DDGI and Frostbite leave such
probes out at run time instead, which the exports' validity records allow too). Radiance SH is linear in the
radiance, so (1) is the SH of the weighted mean of the neighbours' radiance, and every irradiance encoding — each a
function of the band 0–2 radiance SH alone (:class:`~bakery.probe.RadianceSHBatch`; the conformance suite checks
it) — re-encodes it exactly as it encodes a capture. Pass k draws on the valid probes and on those passes 1 … k − 1
filled (``bakery:volume:dilationIterations``); a probe with no source in reach after the last pass keeps its
capture and is named in a warning.

(1) is exact for radiance linear in position wherever the sources in reach are placed symmetrically about the
probe (the weights are even in x_j − x_i): any interior probe of a grid whose neighbours are valid.

Each dilating probe's captured SH is stored (``dilation/radiance_sh``), so every bake re-dilates over every probe
of the store, baked now or reused: changing the radius or the passes re-bakes nothing, and a re-baked neighbour
changes the probes dilated from it. ``dilation/neighbours`` records how many sources each probe of a dilating
volume was dilated from (0: it stores its capture).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from bakery.conventions import INSIDE_BACKFACE_FRACTION
from bakery.pipeline.encode import (
    CAPTURED_SH_KEY,
    DILATION_SETTING,
    REFERENCE_IRRADIANCE,
    BakeWarning,
    EncodedBatch,
    aux_key,
    irradiance_diagnostics,
)
from bakery.pipeline.settings import BakeSettings, build_encodings
from bakery.pipeline.skip import irradiance_band_energy
from bakery.probe import Probe, RadianceSHBatch
from bakery.sphere.fibonacci import fibonacci_directions

#: Diagnostics key of the number of sources each probe of a dilating volume was dilated from (P,) float32.
NEIGHBOURS_KEY = "dilation/neighbours"
#: Backface-fraction diagnostics key (the same as :data:`bakery.pipeline.merge.BACKFACE_KEY`).
_BACKFACE_KEY = "capture/backface_fraction"


@dataclass(frozen=True)
class DilationSettings:
    """A volume's dilation: its prim path, the search radius d of Eq. 1 (bake-frame metres) and the passes."""

    volume: str
    radius_m: float
    passes: int = 1

    def __post_init__(self) -> None:
        if not (np.isfinite(self.radius_m) and self.radius_m > 0) or self.passes < 1:
            raise ValueError(f"{self.volume}: dilation needs a finite radius > 0 and passes >= 1, got "
                             f"{self.radius_m}, {self.passes}")

    def as_setting(self) -> dict:
        return {"volume": self.volume, "radius_m": float(self.radius_m), "passes": int(self.passes)}

    @classmethod
    def of(cls, probe: Probe) -> DilationSettings | None:
        entry = probe.settings.get(DILATION_SETTING)
        return None if not entry else cls(str(entry["volume"]), float(entry["radius_m"]), int(entry["passes"]))


def hashed_settings(settings: dict) -> dict:
    """A probe's settings as its content hash sees them: the dilation is applied in the parent to stored inputs,
    so only whether it is on matters to the probe's own results (its captured SH is then stored)."""
    if DILATION_SETTING not in settings:
        return settings
    return {**settings, DILATION_SETTING: True}


@dataclass(frozen=True)
class DilatedProbes:
    """Result of :func:`dilate_radiance_sh` for P probes: ``radiance_sh`` (P, 9, 3) float64 (the input where not
    dilated) and ``neighbours`` (P,) int64, the number of sources each was dilated from (0: not dilated)."""

    radiance_sh: np.ndarray
    neighbours: np.ndarray


def dilate_radiance_sh(radiance_sh: np.ndarray, positions: np.ndarray, valid: np.ndarray, radius: float,
                       passes: int = 1) -> DilatedProbes:
    """Eq. 1 over ``passes`` passes. radiance_sh (P, 9, 3), positions (P, 3) metres, valid (P,) bool (the sources
    of the first pass; a non-finite SH is never a source). Each pass is one sparse row-normalised product, its
    rows summed in source order (deterministic)."""
    sh = np.array(radiance_sh, dtype=np.float64).reshape(len(positions), -1)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    filled = np.asarray(valid, dtype=bool) & np.all(np.isfinite(sh), axis=1)
    neighbours = np.zeros(len(positions), dtype=np.int64)
    tree = cKDTree(positions) if len(positions) else None
    for _ in range(passes):
        targets = np.flatnonzero(~filled)
        if targets.size == 0 or not filled.any() or tree is None:
            break
        reach = tree.query_ball_point(positions[targets], r=radius)
        counts = np.array([len(r) for r in reach], dtype=np.int64)
        target_of = np.repeat(np.arange(targets.size), counts)
        source = np.concatenate([np.sort(np.asarray(r, dtype=np.int64)) for r in reach]) if counts.sum() else \
            np.zeros(0, dtype=np.int64)
        distance2 = np.sum((positions[source] - positions[targets[target_of]]) ** 2, axis=1)
        keep = filled[source] & (distance2 > 0.0)
        target_of, source, weight = target_of[keep], source[keep], 1.0 / distance2[keep]  # Eq. 1: w = 1/|x_i − x_j|²
        used = np.bincount(target_of, minlength=targets.size)
        total = np.zeros((targets.size, sh.shape[1]))
        np.add.at(total, target_of, weight[:, None] * sh[source])  # unbuffered, in source order per target
        norm = np.bincount(target_of, weights=weight, minlength=targets.size)
        done = used > 0
        if not done.any():
            break
        sh[targets[done]] = total[done] / norm[done, None]
        neighbours[targets[done]] = used[done]
        filled[targets[done]] = True
    return DilatedProbes(sh.reshape(np.shape(radiance_sh)), neighbours)


def dilate_volumes(merged: EncodedBatch, settings: BakeSettings) -> list[BakeWarning]:
    """Dilate every dilating volume of ``merged`` in place (module docstring) and record ``dilation/neighbours``.
    Every probe inside geometry of such a volume — baked now or reused, dilated or left with its capture — is
    re-encoded from its stored inputs (Eq. 1, or its own captured SH), so that an incremental bake stores what a
    full one does: its irradiance encodings' fields, finalize inputs, band energy and negative share follow; its
    reference errors and ``worse_than`` flags are NaN (the error of encoding the inside of a wall means nothing).
    Returns the warnings about probes left undilated."""
    volumes: dict[DilationSettings, list[int]] = {}
    for row, probe in enumerate(merged.probes):
        dilation = DilationSettings.of(probe)
        if dilation is not None and "irradiance" in probe.kinds:
            volumes.setdefault(dilation, []).append(row)
    if not volumes:
        return []
    count = len(merged.probes)
    captured = merged.diagnostics.get(CAPTURED_SH_KEY)
    captured = np.full((count, 9, 3), np.nan) if captured is None else np.asarray(captured, dtype=np.float64)
    fraction = np.asarray(merged.diagnostics.get(_BACKFACE_KEY, np.full(count, np.nan)), dtype=np.float64)
    with np.errstate(invalid="ignore"):
        inside = fraction >= INSIDE_BACKFACE_FRACTION
    recorded = np.asarray(merged.diagnostics.get(NEIGHBOURS_KEY, np.full(count, np.nan)), dtype=np.float32).copy()
    messages: list[BakeWarning] = []
    changed_rows, changed_sh = [], []
    for dilation in sorted(volumes, key=lambda d: d.volume):
        rows = np.asarray(volumes[dilation], dtype=np.int64)
        positions = np.array([merged.probes[r].position for r in rows], dtype=np.float64)
        result = dilate_radiance_sh(captured[rows], positions, ~inside[rows], dilation.radius_m, dilation.passes)
        recorded[rows] = result.neighbours
        done = result.neighbours > 0
        # every probe inside is re-encoded, dilated or not: one not dilated now may store an earlier bake's dilation
        again = inside[rows] & np.all(np.isfinite(result.radiance_sh), axis=(1, 2))
        changed_rows.append(rows[again])
        changed_sh.append(result.radiance_sh[again])
        left = rows[inside[rows] & ~done]
        if left.size:
            names = [merged.probes[r].name for r in left[:3]]
            messages.append(BakeWarning("SceneWarning", (
                f"{dilation.volume}: {left.size} probe(s) inside geometry have no valid probe within "
                f"{dilation.radius_m:.3g} m after {dilation.passes} dilation pass(es) and keep what they captured "
                f"({', '.join(names)}{' …' if left.size > 3 else ''}); raise bakery:volume:dilationDistance or "
                "bakery:volume:dilationIterations")))
    merged.diagnostics[NEIGHBOURS_KEY] = recorded
    rows = np.concatenate(changed_rows)
    if rows.size:
        _reencode(merged, rows, np.concatenate(changed_sh), settings)
    return messages


def _reencode(merged: EncodedBatch, rows: np.ndarray, radiance_sh: np.ndarray, settings: BakeSettings) -> None:
    """Every irradiance encoding of the probes at store ``rows`` from ``radiance_sh`` (R, 9, 3): Eq. 1, or their
    own captured SH where nothing was in reach."""
    normals = fibonacci_directions(settings.quality_directions)
    energy = merged.diagnostics.get("band_energy")
    if energy is not None:
        energy[rows] = irradiance_band_energy(radiance_sh)
    for key in [k for k in merged.diagnostics if k.startswith("reference_error/")]:
        merged.diagnostics[key][rows] = np.nan  # the error of a capture the probe no longer stores
    if REFERENCE_IRRADIANCE in merged.transient:
        merged.transient[REFERENCE_IRRADIANCE][rows] = np.nan
    groups: dict[str, list[int]] = {}  # one encoding set per per-probe overrides, as the workers build them
    for k, row in enumerate(rows):
        groups.setdefault(json.dumps(merged.probes[row].settings.get("encoding_settings", {}), sort_keys=True),
                          []).append(k)
    for overrides, members in sorted(groups.items()):
        group_rows, group_sh = rows[members], radiance_sh[members]
        for name in sorted(merged.encoded):
            encoding = build_encodings([name], settings, json.loads(overrides))[name]
            if encoding.kind != "irradiance":
                continue
            position = {int(r): k for k, r in enumerate(merged.rows[name])}
            has = [k for k, r in enumerate(group_rows) if int(r) in position]
            if not has:
                continue
            fields = encoding.encode(RadianceSHBatch(group_sh[has]))
            at = np.array([position[int(group_rows[k])] for k in has], dtype=np.int64)
            for spec in encoding.field_specs():
                merged.encoded[name][spec.name][at] = fields[spec.name]
            stored_rows = group_rows[has]
            for spec in encoding.aux_specs():
                merged.diagnostics[aux_key(name, spec.name)][stored_rows] = fields[spec.name]
            if not encoding.aux_specs():  # finalized encodings get theirs in the parent's finalize
                values = irradiance_diagnostics({name: {s.name: fields[s.name] for s in encoding.field_specs()}},
                                                {name: encoding}, normals, None)
                key = f"negative_fraction/{name}"
                if key in merged.diagnostics:
                    merged.diagnostics[key][stored_rows] = values[key]
            if encoding.worse_than is not None and encoding.worse_than[0] in merged.diagnostics:
                merged.diagnostics[encoding.worse_than[0]][stored_rows] = np.nan
