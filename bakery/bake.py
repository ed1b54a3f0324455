"""Baking: encode a batch of probes with every requested encoding and write the store.

Library entry points (no printing): ``encode_batch`` encodes captured probes (what pipeline workers run),
``merge_batches`` and ``store_contents`` assemble what the single writer stores; ``bake_probes`` does all three for
an in-memory batch and ``bake_environment`` for one environment image (the CLI goes through
:mod:`bakery.pipeline`, which adds planning, workers, checkpoints and incremental reuse).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import bakery
from bakery.conventions import convention_attributes
from bakery.encodings import ENCODINGS, Encoding, get_encoding
from bakery.environment.io import read_environment
from bakery.environment.resample import environment_samples, resample_to_cube
from bakery.environment.sanitize import SanitizeReport
from bakery.errors import BakeryWarning, ConfigError, DegenerateInputWarning, EncodingError
from bakery.irradiance.reference import reference_irradiance
from bakery.pipeline.skip import irradiance_band_energy
from bakery.probe import PROBE_KINDS, Probe, ProbeBatch
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.store.format import StoreContents, write_store


@dataclass(frozen=True)
class BakeSettings:
    """Everything a bake's result depends on besides its inputs (hashed into ``settings_hash``).

    Attributes:
        face_size: bake-grid cube face size N (texels).
        encodings: encoding names to bake; empty = every registered encoding of the probes' kinds.
        encoding_settings: per-encoding parameters {name: {...}} passed to the encoding's constructor.
        quality_directions: size of the Fibonacci direction set for negative-share and error diagnostics.
        reference_errors: compute each irradiance encoding's error against the exact reference irradiance.
    """

    face_size: int = 64
    encodings: tuple[str, ...] = ()
    encoding_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    quality_directions: int = 1024
    reference_errors: bool = True

    def __post_init__(self) -> None:
        if not 4 <= self.face_size <= 4096:
            raise ConfigError(f"face_size must be in [4, 4096], got {self.face_size}")
        for name in self.encodings:
            try:
                get_encoding(name)
            except KeyError as error:
                raise ConfigError(str(error.args[0])) from None

    def as_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    def hash(self) -> str:
        """sha256 of the canonical settings JSON and bakery's version (code version is a result input)."""
        return hashlib.sha256(f"{self.as_json()}|{bakery.__version__}".encode()).hexdigest()


@dataclass
class BakeResult:
    """What a bake produced. ``encoded``: {encoding: {field: (P_k, ...)}}; ``probe_index``: rows → probes."""

    store_path: Path
    settings_hash: str
    probes: list[Probe]
    encoded: dict[str, dict[str, np.ndarray]]
    probe_index: dict[str, np.ndarray]
    encodings: dict[str, Encoding]
    diagnostics: dict[str, np.ndarray]
    timings: dict[str, float]
    warnings: list[str]


def _bake_time() -> str:
    """UTC bake time; ``SOURCE_DATE_EPOCH`` (reproducible-builds convention) pins it for bit-identical stores."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    seconds = int(epoch) if epoch and epoch.isdigit() else int(time.time())
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(seconds))


def select_encodings(settings: BakeSettings, kinds: set[str]) -> dict[str, Encoding]:
    """Instantiate the requested encodings (default: every registered one whose kind some probe has)."""
    names = settings.encodings or tuple(name for name, cls in ENCODINGS.items() if cls.kind in kinds)
    return {name: instantiate_encoding(name, settings) for name in names}


def instantiate_encoding(name: str, settings: BakeSettings) -> Encoding:
    """An encoding with the bake's parameters: the recipe's ``encoding_settings`` for it, and the bake face size for
    encodings that resample the capture (``face_size`` setting, e.g. the split-sum chain) unless set explicitly."""
    cls = get_encoding(name)
    options = dict(settings.encoding_settings.get(name, {}))
    if getattr(cls, "follows_bake_face_size", False):
        options.setdefault("face_size", settings.face_size)
    return cls(**options)


def irradiance_diagnostics(
    batch: ProbeBatch, encoded: dict[str, dict[str, np.ndarray]], encodings: dict[str, Encoding],
    settings: BakeSettings,
) -> dict[str, np.ndarray]:
    """Per-probe share of directions with negative irradiance (any channel) and, with ``reference_errors``, the
    relative RMSE against the exact irradiance, for every irradiance encoding; plus ``hallucination_hurts``.
    Arrays are (P,) over the probes of ``batch``."""
    normals = fibonacci_directions(settings.quality_directions)
    out: dict[str, np.ndarray] = {}
    reference = None
    if settings.reference_errors:
        reference = np.stack(
            [reference_irradiance(batch.samples(j), normals, dtype=np.float32) for j in range(batch.count)]
        )
    errors: dict[str, np.ndarray] = {}
    for name, encoding in encodings.items():
        if encoding.kind != "irradiance":
            continue
        values = encoding.evaluate_irradiance(encoded[name], normals)  # (P, N, 3)
        out[f"negative_fraction/{name}"] = np.mean(np.any(values < 0, axis=-1), axis=1).astype(np.float32)
        if reference is not None:
            num = np.sqrt(np.sum((values - reference) ** 2, axis=(1, 2)))
            den = np.sqrt(np.sum(reference**2, axis=(1, 2)))
            errors[name] = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0).astype(np.float32)
            out[f"reference_error/{name}"] = errors[name]
    if "zh3_hallucinated" in errors and "sh2" in errors:
        out["hallucination_hurts"] = (errors["zh3_hallucinated"] > errors["sh2"]).astype(np.float32)
    return out


@dataclass
class EncodedBatch:
    """Encoded results of a set of probes (the unit workers return and the writer merges).

    Attributes:
        probes: the probes, in row order.
        encoded: {encoding: {field: (P_k, ...)}} for the probes having that encoding's kind.
        rows: {encoding: (P_k,) indices into ``probes``}.
        diagnostics: {path: (P, ...)} aligned with ``probes``; float arrays hold NaN where not applicable.
        timings: seconds per step; warnings: messages of BakeryWarnings raised while encoding.
    """

    probes: list[Probe]
    encoded: dict[str, dict[str, np.ndarray]]
    rows: dict[str, np.ndarray]
    diagnostics: dict[str, np.ndarray]
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _full_length(values: np.ndarray, rows: np.ndarray, count: int) -> np.ndarray:
    out = np.full((count, *values.shape[1:]), np.nan, dtype=np.float32)
    out[rows] = values
    return out


def encode_batch(
    probes: list[Probe], batch: ProbeBatch, settings: BakeSettings, encodings: dict[str, Encoding] | None = None,
    diagnostics: dict[str, np.ndarray] | None = None,
) -> EncodedBatch:
    """Encode ``batch`` (one capture per probe, same order) with every selected encoding. No I/O."""
    if len(probes) != batch.count:
        raise ConfigError(f"{len(probes)} probes but {batch.count} captures")
    finite = np.isfinite(batch.cubes).reshape(batch.count, -1).all(axis=1)
    if not finite.all():
        bad = [probes[i].name for i in np.flatnonzero(~finite)]
        raise EncodingError(f"non-finite captured radiance in probe(s) {', '.join(bad[:5])}"
                            f"{' …' if len(bad) > 5 else ''}; sanitise captures before encoding")
    timings: dict[str, float] = {}
    if encodings is None:
        encodings = select_encodings(settings, {k for p in probes for k in p.kinds})
    encoded: dict[str, dict[str, np.ndarray]] = {}
    rows_of: dict[str, np.ndarray] = {}
    all_diagnostics = dict(diagnostics or {})
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
                start = time.perf_counter()
                fields = encoding.encode(sub)
                timings[f"encode/{name}"] = time.perf_counter() - start
                for spec in encoding.field_specs():
                    array = fields[spec.name]
                    if array.shape != (rows.size, *spec.shape) or array.dtype != np.dtype(spec.dtype):
                        raise AssertionError(f"{name}.{spec.name}: got {array.shape} {array.dtype}, declared "
                                             f"{(rows.size, *spec.shape)} {spec.dtype}")
                encoded[name] = {spec.name: fields[spec.name] for spec in encoding.field_specs()}
                rows_of[name] = rows
            if kind == "irradiance":
                start = time.perf_counter()
                for key, values in irradiance_diagnostics(sub, encoded, chosen, settings).items():
                    all_diagnostics[key] = _full_length(values, rows, len(probes))
                all_diagnostics["band_energy"] = _full_length(irradiance_band_energy(sub.radiance_sh(2)), rows,
                                                              len(probes))
                timings["diagnostics/irradiance"] = time.perf_counter() - start
    caught = [str(w.message) for w in recorded if issubclass(w.category, BakeryWarning)]
    return EncodedBatch(list(probes), encoded, rows_of, all_diagnostics, timings, caught)


def merge_batches(batches: list[EncodedBatch], order: list[str] | None = None) -> EncodedBatch:
    """Concatenate batches and reorder their probes to ``order`` (names; default: concatenation order)."""
    probes = [p for b in batches for p in b.probes]
    offsets = np.cumsum([0] + [len(b.probes) for b in batches])
    names = [p.name for p in probes]
    if len(set(names)) != len(names):
        raise ConfigError("probe names must be unique")
    position = {n: i for i, n in enumerate(order if order is not None else names)}
    if set(position) != set(names):
        raise ConfigError("merge order does not name the same probes as the batches")
    permutation = np.array([position[n] for n in names])  # concatenated row -> final row
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
        encoded[name] = {f: np.concatenate([b.encoded[name][f] for b, _ in parts])[sort]
                         for f in parts[0][0].encoded[name]}
    diagnostics: dict[str, np.ndarray] = {}
    for key in sorted({k for b in batches for k in b.diagnostics}):
        parts = []
        for b in batches:
            if key in b.diagnostics:
                parts.append(np.asarray(b.diagnostics[key]))
            else:
                template = next(bb.diagnostics[key] for bb in batches if key in bb.diagnostics)
                parts.append(np.full((len(b.probes), *np.shape(template)[1:]), np.nan, dtype=np.float32))
        values = np.concatenate([np.asarray(p, dtype=np.result_type(*parts)) for p in parts])
        out = np.empty_like(values)
        out[permutation] = values
        diagnostics[key] = out
    timings: dict[str, float] = {}
    for b in batches:
        for k, v in b.timings.items():
            timings[k] = timings.get(k, 0.0) + v
    # Warnings sorted and de-duplicated: their arrival order depends on scheduling, the store must not.
    return EncodedBatch(final_probes, encoded, rows, diagnostics, timings, sorted({w for b in batches for w in b.warnings}))


def store_contents(
    merged: EncodedBatch, settings: BakeSettings, encodings: dict[str, Encoding],
    attributes: dict[str, Any] | None = None, probe_hashes: list[str] | None = None,
    history: list[dict[str, str]] | None = None, bake_ids: np.ndarray | None = None, layers: str = "",
) -> StoreContents:
    """The store for merged results (probes in ``merged.probes`` order).

    ``history`` lists earlier bakes still referenced by ``bake_ids``; this bake is appended as the last entry and
    probes without a bake id (default: all) are attributed to it.
    """
    this_bake = {"time_utc": _bake_time(), "bakery_version": bakery.__version__, "settings_hash": settings.hash(),
                 "layers": layers}
    history = list(history or []) + [this_bake]
    if bake_ids is None:
        bake_ids = np.full(len(merged.probes), len(history) - 1, dtype=np.int32)
    return StoreContents(
        attributes={
            **convention_attributes(),
            "bakery_version": bakery.__version__,
            "settings": settings.as_json(),
            "settings_hash": settings.hash(),
            "bake_time_utc": _bake_time(),
            "bake_face_size": settings.face_size,
            "warnings": json.dumps(merged.warnings),
            **(attributes or {}),
        },
        probe_names=[p.name for p in merged.probes],
        probe_kinds=[",".join(p.kinds) for p in merged.probes],
        probe_positions=np.array([p.position for p in merged.probes], dtype=np.float64).reshape(-1, 3),
        encodings={
            name: {
                "attributes": {
                    "encoding_type": name,
                    "encoding_version": encodings[name].version,
                    "kind": encodings[name].kind,
                    "description": encodings[name].description,
                    "settings": encodings[name].settings_json(),
                    "bytes_per_probe": encodings[name].bytes_per_probe(),
                },
                "fields": {"probe_index": merged.rows[name].astype(np.int32), **merged.encoded[name]},
                "descriptions": {"probe_index": "row -> index into /probes",
                                 **{s.name: s.description for s in encodings[name].field_specs()}},
                "shared": encodings[name].shared_tables(),
            }
            for name in merged.encoded
        },
        diagnostics=merged.diagnostics,
        probe_hashes=probe_hashes,
        probe_bake_ids=np.asarray(bake_ids, dtype=np.int32),
        history=history,
    )


def bake_probes(
    probes: list[Probe],
    batch: ProbeBatch,
    settings: BakeSettings,
    output: str | os.PathLike[str],
    attributes: dict[str, Any] | None = None,
    diagnostics: dict[str, np.ndarray] | None = None,
) -> BakeResult:
    """Encode ``batch`` (one capture per probe, same order) and write the store atomically to ``output``."""
    if len({p.name for p in probes}) != len(probes):
        raise ConfigError("probe names must be unique")
    encodings = select_encodings(settings, {k for p in probes for k in p.kinds})
    result = encode_batch(probes, batch, settings, encodings, diagnostics)
    for message in result.warnings:
        warnings.warn(message, BakeryWarning, stacklevel=2)
    start = time.perf_counter()
    path = write_store(output, store_contents(result, settings, encodings, attributes))
    result.timings["write"] = time.perf_counter() - start
    return BakeResult(path, settings.hash(), list(probes), result.encoded, result.rows, encodings,
                      result.diagnostics, result.timings, result.warnings)


def sanitize_diagnostics(reports: list[SanitizeReport]) -> dict[str, np.ndarray]:
    """Per-probe input sanitisation counts (P, 4): NaN, +Inf, −Inf, negative texels."""
    return {
        "input/sanitized_texels": np.array(
            [[r.nan, r.positive_inf, r.negative_inf, r.negative] for r in reports], dtype=np.int64
        ).reshape(-1, 4)
    }


def bake_environment(
    image_path: str | os.PathLike[str],
    output: str | os.PathLike[str],
    settings: BakeSettings | None = None,
    layout: str | None = None,
) -> BakeResult:
    """Bake one environment image as one distant probe (``/environment``) of every kind."""
    settings = settings or BakeSettings()
    start = time.perf_counter()
    image, report = read_environment(image_path, layout=layout)
    cube = resample_to_cube(image, settings.face_size)
    samples = environment_samples(image)
    load_time = time.perf_counter() - start
    if not np.any(cube > 0):
        warnings.warn(
            f"{image_path}: the environment is entirely black; every encoding is zero", DegenerateInputWarning,
            stacklevel=2,
        )
    batch = ProbeBatch(cube[None], [samples])
    probe = Probe(name="/environment", kinds=PROBE_KINDS)
    result = bake_probes(
        [probe], batch, settings, output,
        attributes={"source": str(image_path), "source_layout": image.layout,
                    "source_size": [image.width, image.height]},
        diagnostics={**sanitize_diagnostics([report]),
                     "input/flux_source": samples.flux().astype(np.float64)[None, :]},
    )
    result.timings["load_and_resample"] = load_time
    return result
