"""Encoding a batch of captured probes with every selected encoding, plus per-probe diagnostics (worker side, no
I/O).

Diagnostics (arrays (P, ...) aligned with the batch's probes; NaN where an entry does not apply)
    ``negative_fraction/<enc>``  share of the quality directions where the irradiance is negative (any channel)
    ``reference_error/<enc>``    relative RMSE against the exact irradiance of the probe's reference quadrature
    ``<flag>``                   an encoding's ``worse_than = (flag, Baseline)``: its error exceeds the baseline's
    ``band_energy``              per-band irradiance energy (skip decisions, :mod:`bakery.pipeline.skip`)
    ``finalize/<enc>/<field>``   inputs of an encoding's parent-side ``finalize`` (its ``aux_specs``), kept in the
                                 store so that an incremental bake finalizes over every probe again
    ``dilation/radiance_sh``     radiance SH bands 0–2 (P, 9, 3) of the probes of dilating volumes, kept so that
                                 every bake dilates over every probe again (:mod:`bakery.pipeline.dilate`)
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from bakery.encodings import Encoding
from bakery.environment.sanitize import SanitizeReport
from bakery.errors import BakeryWarning, EncodingError
from bakery.irradiance.reference import (
    reference_irradiance_binned,
    reference_irradiance_cubes,
)
from bakery.pipeline.settings import BakeSettings, build_encodings, default_encodings
from bakery.pipeline.skip import irradiance_band_energy
from bakery.probe import PROBE_KINDS, Probe, ProbeBatch
from bakery.sphere.fibonacci import fibonacci_directions


@dataclass(frozen=True)
class BakeWarning:
    """A warning raised while capturing or encoding, carried across process borders (category: a class name in
    :mod:`bakery.errors`)."""

    category: str
    message: str


@dataclass
class EncodedBatch:
    """Encoded results of a set of probes (the unit workers return and the writer merges).

    Attributes:
        probes: the probes, in row order.
        encoded: {encoding: {field: (P_k, ...)}} for the probes having that encoding's kind.
        rows: {encoding: (P_k,) indices into ``probes``}.
        diagnostics: {path: (P, ...)} aligned with ``probes``; float arrays hold NaN where not applicable.
        timings: seconds (and counts) per step, summed over batches.
        warnings: BakeryWarnings raised while capturing or encoding.
        transient: per-probe arrays for the parent that are not stored.
    """

    probes: list[Probe]
    encoded: dict[str, dict[str, np.ndarray]]
    rows: dict[str, np.ndarray]
    diagnostics: dict[str, np.ndarray]
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[BakeWarning] = field(default_factory=list)
    #: per-probe arrays the parent needs but the store does not keep (e.g. ``reference_irradiance`` (P, N, 3))
    transient: dict[str, np.ndarray] = field(default_factory=dict)


#: ``EncodedBatch.transient`` key of the exact irradiance (P, N, 3) at the quality directions.
REFERENCE_IRRADIANCE = "reference_irradiance"
#: ``Probe.settings`` key of a dilating volume's probes: {"volume": prim path, "radius_m": d, "passes": k}
#: (:mod:`bakery.pipeline.dilate`).
DILATION_SETTING = "dilation"
#: Diagnostics key of each dilating probe's captured radiance SH (P, 9, 3) float32, NaN for the other probes.
CAPTURED_SH_KEY = "dilation/radiance_sh"


def listed_names(names: list[str], shown: int = 3) -> str:
    """``/A, /B, /C and 4 more``: the first ``shown`` of ``names`` and how many others, for one-line messages."""
    return ", ".join(names[:shown]) + (f" and {len(names) - shown} more" if len(names) > shown else "")


def aux_key(encoding: str, field_name: str) -> str:
    """Diagnostics path of a finalize input."""
    return f"finalize/{encoding}/{field_name}"


def full_length(values: np.ndarray, rows: np.ndarray, count: int) -> np.ndarray:
    """(count, ...) float32 array with ``values`` at ``rows`` and NaN elsewhere."""
    out = np.full((count, *values.shape[1:]), np.nan, dtype=np.float32)
    out[rows] = values
    return out


def reference_irradiance_values(batch: ProbeBatch, normals: np.ndarray) -> np.ndarray:
    """Reference irradiance (P, N, 3) float32 of every probe's reference quadrature at ``normals`` (N, 3): the
    capture's brute force as one GEMM with a cached operator when the capture is the reference, else the binned
    full-resolution quadrature (exact but for the terminator texels; bound and measured error in
    :mod:`bakery.irradiance.reference`)."""
    if batch.reference_samples is None:
        return reference_irradiance_cubes(batch.cubes, normals)
    return reference_irradiance_binned(batch.reference_samples, normals)


def irradiance_diagnostics(
    encoded: dict[str, dict[str, np.ndarray]], encodings: dict[str, Encoding], normals: np.ndarray,
    reference: np.ndarray | None,
) -> dict[str, np.ndarray]:
    """Negative-direction share and (with a ``reference`` (P, N, 3)) the relative RMSE against the exact irradiance
    for every irradiance encoding in ``encodings``, and each one's ``worse_than`` flag. Arrays are (P,)."""
    out: dict[str, np.ndarray] = {}
    errors: dict[str, np.ndarray] = {}
    for name, encoding in encodings.items():
        if encoding.kind != "irradiance":
            continue
        values = encoding.evaluate_irradiance(encoded[name], normals)  # (P, N, 3)
        out[f"negative_fraction/{name}"] = np.mean(np.any(values < 0, axis=-1), axis=1).astype(np.float32)
        if reference is not None:
            errors[name] = relative_rmse_per_probe(values, reference)
            out[f"reference_error/{name}"] = errors[name]
    for name, encoding in encodings.items():
        if encoding.worse_than is not None:
            flag, baseline = encoding.worse_than
            if name in errors and baseline.name in errors:
                out[flag] = (errors[name] > errors[baseline.name]).astype(np.float32)
    return out


def relative_rmse_per_probe(values: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """√Σ(E − E_ref)² / √ΣE_ref² per probe over directions and RGB: (P, N, 3) × 2 → (P,) float32. Against a black
    reference (E_ref = 0 everywhere): 0 when the encoding is black too (exact), +inf when it is not (unbounded;
    before: 0, which hid an encoding that lit a black probe)."""
    num = np.sqrt(np.sum((values - reference) ** 2, axis=(1, 2)))
    den = np.sqrt(np.sum(reference**2, axis=(1, 2)))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.where(num > 0, np.inf, 0.0)).astype(np.float32)


def sanitize_diagnostics(reports: list[SanitizeReport | None]) -> dict[str, np.ndarray]:
    """Per-probe input sanitisation counts (P, 4): NaN, +Inf, −Inf, negative texels (zeros when nothing was read)."""
    rows = [[r.nan, r.positive_inf, r.negative_inf, r.negative] if r is not None else [0, 0, 0, 0] for r in reports]
    return {"input/sanitized_texels": np.array(rows, dtype=np.int64).reshape(-1, 4)}


def encode_batch(
    probes: list[Probe], batch: ProbeBatch, settings: BakeSettings, encodings: dict[str, Encoding] | None = None,
    diagnostics: dict[str, np.ndarray] | None = None,
) -> EncodedBatch:
    """Encode ``batch`` (one capture per probe, same order) with ``encodings`` (default: the settings' list, else
    every encoding of the probes' kinds), each applied to the probes of its kind. Warnings raised by encodings are
    recorded, not emitted.

    Diagnostics of an encoding that needs the parent's ``finalize`` (non-empty ``aux_specs``) cannot be computed
    here; the reference irradiance is then returned in ``transient`` for the parent
    (:func:`bakery.pipeline.merge.finalize_encodings`)."""
    if len(probes) != batch.count:
        raise EncodingError(f"{len(probes)} probes but {batch.count} captures")
    finite = np.isfinite(batch.cubes).reshape(batch.count, -1).all(axis=1)
    if not finite.all():
        bad = [probes[i].name for i in np.flatnonzero(~finite)]
        raise EncodingError(f"non-finite captured radiance in probe(s) {', '.join(bad[:5])}"
                            f"{' …' if len(bad) > 5 else ''}; sanitise captures before encoding")
    if encodings is None:
        encodings = build_encodings(settings.encodings or default_encodings({k for p in probes for k in p.kinds}),
                                    settings)
    timings: dict[str, float] = {}
    encoded: dict[str, dict[str, np.ndarray]] = {}
    rows_of: dict[str, np.ndarray] = {}
    all_diagnostics = dict(diagnostics or {})
    transient: dict[str, np.ndarray] = {}
    with warnings.catch_warnings(record=True) as recorded:
        warnings.simplefilter("always", BakeryWarning)
        for kind in PROBE_KINDS:
            rows = np.array([i for i, p in enumerate(probes) if kind in p.kinds], dtype=np.int64)
            chosen = {n: e for n, e in encodings.items() if e.kind == kind}
            if rows.size == 0 or not chosen:
                continue
            sub = batch if rows.size == batch.count else ProbeBatch(
                batch.cubes[rows], None if batch.reference_samples is None else [batch.reference_samples[i] for i in rows]
            )
            for name, encoding in chosen.items():
                start, before = time.perf_counter(), len(recorded)
                fields = encoding.encode(sub)
                timings[f"encode/{name}"] = time.perf_counter() - start
                for record in recorded[before:]:  # bakery.errors.warn_about_probes: name the probes it is about
                    if getattr(record.message, "probe_rows", None):
                        named = [probes[rows[row]].name for row in record.message.probe_rows]
                        record.message = f"{record.message} ({listed_names(named)})"
                for spec in (*encoding.field_specs(), *encoding.aux_specs()):
                    array = fields[spec.name]
                    if array.shape != (rows.size, *spec.shape) or array.dtype != np.dtype(spec.dtype):
                        raise AssertionError(f"{name}.{spec.name}: got {array.shape} {array.dtype}, declared "
                                             f"{(rows.size, *spec.shape)} {spec.dtype}")
                encoded[name] = {spec.name: fields[spec.name] for spec in encoding.field_specs()}
                for spec in encoding.aux_specs():
                    all_diagnostics[aux_key(name, spec.name)] = full_length(fields[spec.name], rows, len(probes))
                rows_of[name] = rows
            if kind == "irradiance":
                start = time.perf_counter()
                normals = fibonacci_directions(settings.quality_directions)
                reference = reference_irradiance_values(sub, normals) if settings.reference_errors else None
                ready = {n: e for n, e in chosen.items() if not e.aux_specs()}
                for key, values in irradiance_diagnostics(encoded, ready, normals, reference).items():
                    all_diagnostics[key] = full_length(values, rows, len(probes))
                if reference is not None and len(ready) < len(chosen):
                    transient[REFERENCE_IRRADIANCE] = full_length(reference, rows, len(probes))
                all_diagnostics["band_energy"] = full_length(irradiance_band_energy(sub.radiance_sh(2)), rows,
                                                             len(probes))
                dilating = np.array([DILATION_SETTING in probes[r].settings for r in rows], dtype=bool)
                if dilating.any():  # the dilation's input (bakery.pipeline.dilate), kept for every later bake
                    all_diagnostics[CAPTURED_SH_KEY] = full_length(
                        sub.radiance_sh(2)[dilating].astype(np.float32), rows[dilating], len(probes))
                timings["diagnostics/irradiance"] = time.perf_counter() - start
    caught = [BakeWarning(w.category.__name__, str(w.message)) for w in recorded
              if issubclass(w.category, BakeryWarning)]
    return EncodedBatch(list(probes), encoded, rows_of, all_diagnostics, timings, caught, transient)
