"""Public Python API: open a store, list its probes and encodings, evaluate any stored encoding.

    >>> store = bakery.open_store("probes.h5")                 # doctest: +SKIP
    >>> store.probe_names, list(store.encodings)               # doctest: +SKIP
    >>> store.evaluate_irradiance("zh3", normals)              # (P, N, 3)  # doctest: +SKIP
    >>> store.evaluate_reflection("sh_exp", v, n, alpha, f0)   # (P, N, 3)  # doctest: +SKIP

Evaluation reconstructs exactly what an engine would, from the stored arrays and the encoding's stored settings.

Errors (every one a :class:`bakery.errors.BakeryError` naming the store and the argument, dataset or attribute)
    :class:`~bakery.errors.ArgumentError`        a bad argument (store path, ``region``, ``probes``); a ValueError
    :class:`~bakery.errors.EvaluationError`      bad evaluation inputs (``normals``, ``view``, ``normal``, ``alpha``,
                                                  ``f0``: :mod:`bakery.reflection.validation`); a ValueError
    :class:`~bakery.errors.UnknownEncodingError`  an encoding the store does not hold, or that this bakery does not
                                                  know (a store of a newer version); a KeyError
    :class:`~bakery.errors.UnknownProbeError`     a probe the encoding does not hold; a KeyError
    :class:`~bakery.errors.EncodingKindError`     irradiance evaluation of a reflection encoding or vice versa
    :class:`~bakery.errors.StoreFormatError`      malformed store metadata or fields (checked on open, and per encoding
                                                  once, on its first evaluation, against its ``field_specs()``)
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from bakery.encodings import ENCODINGS, Encoding, ParamsError
from bakery.errors import (
    ArgumentError,
    EncodingKindError,
    StoreFormatError,
    UnknownEncodingError,
    UnknownProbeError,
)
from bakery.reflection.validation import check_directions, check_reflection_inputs
from bakery.store.format import LazyField, read_store, store_path, version_tuple


@dataclass(frozen=True)
class EncodingInfo:
    name: str
    kind: str
    version: str
    bytes_per_probe: int
    description: str
    settings: dict[str, Any]
    probe_count: int


def _whole_number(value: Any) -> int | None:
    """``value`` as an int ≥ 0 if it is one (also 60.0 or "60"), else None."""
    if value is None or isinstance(value, (bool, np.bool_)):
        return None
    try:
        number = int(value)
        return number if number >= 0 and float(value) == number else None
    except (TypeError, ValueError, OverflowError):
        return None


def _a(word: str) -> str:
    """"an irradiance", "a reflection"."""
    return ("an " if word[:1] in "aeiou" else "a ") + word


def _list_of_objects(*keys: str) -> Callable[[Any], str | None]:
    """Check of a JSON list of objects that each hold every one of ``keys``."""
    shape = "{" + ", ".join(f'"{k}": …' for k in keys) + "}"

    def check(value: Any) -> str | None:
        if not isinstance(value, list):
            return "must be a JSON list"
        for item in value:
            if not (isinstance(item, dict) and all(k in item for k in keys)):
                return f"must list {shape} objects, got {json.dumps(item)[:60]}"
        return None

    return check


def _check_light_sampling(value: Any) -> str | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        return "must be a JSON object or null"
    if value.get("drawn"):
        missing = [k for k in ("lights", "non_distant", "draws_per_vertex", "enumerated_up_to") if k not in value]
        if missing:
            return f"lacks {', '.join(missing)}"
    return None


def _check_conventions(value: Any) -> str | None:
    if not isinstance(value, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        return "must be a JSON object of strings"
    return None


#: Root attributes holding JSON that readers of a store decode (``schemas/store-v1.md``): name → (value when absent,
#: whether "" means absent, check of the decoded value → problem or None).
JSON_ROOT_ATTRIBUTES: dict[str, tuple[Any, bool, Callable[[Any], str | None]]] = {
    "conventions": ({}, False, _check_conventions),
    "warnings": ([], True, lambda v: None if isinstance(v, list) else "must be a JSON list"),
    "skipped": ([], False, _list_of_objects("reason")),  # each also names its "encoding" or "probe"
    "roughness_ranges": ([], False, _list_of_objects("probe", "reason")),
    "capture_light_sampling": (None, True, _check_light_sampling),
}

#: Per-probe diagnostics (P, …) that readers index by probe (``bakery inspect --probes``).
_PER_PROBE_DIAGNOSTICS = ("capture/sh_noise", "capture/backface_fraction")


@dataclass
class _Evaluator:
    """An encoding ready to evaluate: built from its stored settings, its fields checked against its field specs."""

    encoding: Encoding
    entry: dict[str, Any]
    #: fields of the current layout an older stored version lacks (the encoding reads the old layout without them)
    absent: frozenset[str]


class ProbeStore:
    """A probe store opened for reading. Opening verifies the store's checksums (``schemas/store-v1.md``,
    Integrity) and raises :class:`bakery.errors.StoreFormatError` naming the datasets that fail them, and checks
    the metadata readers rely on (encoding attributes, JSON root attributes, the encodings' ``probe_index``) naming
    the attribute or dataset that is malformed.

    Every array is loaded, or with ``lazy`` the large fields (a chain's levels: ≥ 4 MiB a field) are
    :class:`bakery.store.format.LazyField` objects that read the rows they are indexed with from the verified file,
    which stays open until :meth:`close` (or the end of a ``with`` block): a reader that walks the probes in blocks
    holds one block (``bakery export``)."""

    def __init__(self, path: str | os.PathLike[str], lazy: bool = False) -> None:
        self.path = str(store_path(path))
        self._contents = read_store(self.path, lazy_fields=lazy)
        try:
            self._read_metadata()
        except BaseException:  # a lazy store's file is not left open behind a malformed store's error
            self.close()
            raise

    def _read_metadata(self) -> None:
        a = self._contents.attributes
        self.attributes: dict[str, Any] = a
        self.format_version: str = str(a["format_version"])
        self.probe_names: list[str] = list(self._contents.probe_names)
        self.probe_kinds: list[str] = list(self._contents.probe_kinds)
        self.probe_positions: np.ndarray = self._contents.probe_positions
        self.diagnostics: dict[str, np.ndarray] = self._contents.diagnostics
        self.probe_hashes: list[str] = list(self._contents.probe_hashes or [""] * len(self.probe_names))
        self.probe_bake_ids: np.ndarray = np.asarray(self._contents.probe_bake_ids if
                                                     self._contents.probe_bake_ids is not None else
                                                     np.zeros(len(self.probe_names)), dtype=int)
        self.history: list[dict[str, str]] = list(self._contents.history)
        #: checksums were present and verified on open (format ≥ 1.2.0; a store that fails them does not open)
        self.verified: bool = bool(self._contents.integrity and self._contents.integrity.verified)
        for key in JSON_ROOT_ATTRIBUTES:
            self.json_attribute(key)
        self.conventions: dict[str, str] = self.json_attribute("conventions")
        self._check_probes()
        self.encodings: dict[str, EncodingInfo] = {
            name: self._encoding_info(name, entry) for name, entry in self._contents.encodings.items()}
        self._evaluators: dict[str, _Evaluator] = {}

    def close(self) -> None:
        """Close the store's file (a ``lazy`` store's fields cannot be read afterwards; a loaded store has none)."""
        self._contents.close()

    def __enter__(self) -> ProbeStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------------ metadata
    def _malformed(self, where: str, problem: str) -> StoreFormatError:
        return StoreFormatError(f"{self.path}: {where} {problem}; the file was not written by bakery or is corrupt")

    def json_attribute(self, key: str) -> Any:
        """The decoded value of a JSON root attribute of :data:`JSON_ROOT_ATTRIBUTES` (its default when absent);
        :class:`StoreFormatError` naming the attribute when it is not JSON of the documented form."""
        default, empty_is_absent, check = JSON_ROOT_ATTRIBUTES[key]
        raw = self.attributes.get(key)
        if raw is None or (empty_is_absent and raw == ""):
            return default
        if not isinstance(raw, str):
            raise self._malformed(f"root attribute {key}", f"is {raw!r} ({type(raw).__name__}), expected JSON text")
        try:
            value = json.loads(raw)
        except ValueError as error:
            raise self._malformed(f"root attribute {key}", f"is not valid JSON ({error})") from None
        problem = check(value)
        if problem:
            raise self._malformed(f"root attribute {key}", problem)
        return value

    def _check_probes(self) -> None:
        count = len(self.probe_names)
        if self.history and count:
            bad = (self.probe_bake_ids < 0) | (self.probe_bake_ids >= len(self.history))
            if np.any(bad):
                raise self._malformed("dataset /probes/bake_id", f"refers to bake {int(self.probe_bake_ids[bad][0])}, "
                                      f"/history has {len(self.history)} rows")
        for key in _PER_PROBE_DIAGNOSTICS:
            if key in self.diagnostics:
                values = np.asarray(self.diagnostics[key])
                if values.dtype.kind not in "biuf" or values.ndim == 0 or values.shape[0] != count:
                    raise self._malformed(f"dataset /diagnostics/{key}", f"is {values.dtype} of shape "
                                          f"{values.shape}, expected one number per probe ({count})")

    def _encoding_info(self, name: str, entry: dict[str, Any]) -> EncodingInfo:
        at = entry["attributes"]
        where = f"/encodings/{name}"

        def text(key: str) -> str:
            if key not in at:
                raise self._malformed(f"{where}:", f"attribute {key} is missing")
            if not isinstance(at[key], str):
                raise self._malformed(f"{where}: attribute {key}", f"is {at[key]!r}, expected a string")
            return at[key]

        size = _whole_number(at.get("bytes_per_probe"))
        if size is None:
            raise self._malformed(f"{where}: attribute bytes_per_probe", "is missing" if "bytes_per_probe" not in at
                                  else f"is {at['bytes_per_probe']!r}, expected a whole number >= 0")
        settings_text = at.get("settings", "{}")
        try:
            settings = json.loads(settings_text) if isinstance(settings_text, str) else None
        except ValueError as error:
            raise self._malformed(f"{where}: attribute settings", f"is not valid JSON ({error})") from None
        if not isinstance(settings, dict):
            raise self._malformed(f"{where}: attribute settings", "must be a JSON object")
        index = entry["fields"].get("probe_index")
        if index is None:  # read_store checks the layout of every encoding
            raise self._malformed(f"dataset {where}/probe_index", "is missing")
        return EncodingInfo(name=name, kind=text("kind"), version=text("encoding_version"), bytes_per_probe=size,
                            description=str(at.get("description", "")), settings=settings,
                            probe_count=len(index))

    # ------------------------------------------------------------------------------------------------ lookups
    def _info(self, encoding: str) -> EncodingInfo:
        if not isinstance(encoding, str) or encoding not in self.encodings:
            raise UnknownEncodingError(f"{self.path}: no encoding {encoding!r} in this store; stored: "
                                       f"{', '.join(self.encodings) or '(none)'}")
        return self.encodings[encoding]

    def _stored_version(self, encoding: str) -> tuple[int, int, int]:
        version = self._info(encoding).version
        try:
            return version_tuple(version)
        except StoreFormatError:
            raise self._malformed(f"/encodings/{encoding}: attribute encoding_version",
                                  f"is {version!r}, not a version number (MAJOR.MINOR.PATCH)") from None

    def _class_of(self, encoding: str) -> tuple[type[Encoding] | None, str | None]:
        """(the encoding's class, None), or (None or the class, why this bakery cannot evaluate it)."""
        info = self._info(encoding)
        cls = ENCODINGS.get(encoding)
        if cls is None:
            return None, (f"encoding {encoding} is not known to this bakery (written by a newer version?); known: "
                          f"{', '.join(ENCODINGS)}")
        if self._stored_version(encoding)[0] > version_tuple(cls.version)[0]:
            return cls, (f"encoding {encoding} is version {info.version}, newer than this bakery reads "
                         f"({cls.version}); upgrade bakery")
        return cls, None

    def unsupported_reason(self, encoding: str) -> str | None:
        """Why this bakery cannot evaluate the stored ``encoding`` (unknown to it, or a newer major version: a store
        written by a newer bakery), or None if it can. Raises for a name the store does not hold and for a
        malformed ``encoding_version``."""
        return self._class_of(encoding)[1]

    def _evaluator(self, encoding: str, kind: str) -> _Evaluator:
        """The encoding checked for evaluation as ``kind`` (once per encoding: settings, fields vs field specs)."""
        cls, reason = self._class_of(encoding)
        if cls is None:
            raise UnknownEncodingError(f"{self.path}: {reason}")
        if reason:
            raise StoreFormatError(f"{self.path}: {reason}")
        info = self.encodings[encoding]
        if info.kind != cls.kind:
            raise self._malformed(f"/encodings/{encoding}: attribute kind", f"is {info.kind!r}, but {encoding} is "
                                  f"{_a(cls.kind)} encoding")
        if cls.kind != kind:
            use = ("evaluate_reflection(encoding, view, normal, alpha, f0)" if cls.kind == "reflection" else
                   "evaluate_irradiance(encoding, normals)")
            raise EncodingKindError(f"{self.path}: {encoding} is {_a(cls.kind)} encoding, not {kind}: evaluate it "
                                    f"with {use}")
        if encoding not in self._evaluators:
            self._evaluators[encoding] = self._prepare(encoding, cls)
        return self._evaluators[encoding]

    def _prepare(self, name: str, cls: type[Encoding]) -> _Evaluator:
        info = self.encodings[name]
        where = f"/encodings/{name}"
        try:
            enc = cls.from_settings(info.settings)
        except ParamsError as error:
            raise self._malformed(f"{where}: attribute settings", f"is invalid ({error})") from None
        entry = self._contents.encodings[name]
        rows = info.probe_count
        older = self._stored_version(name) < version_tuple(cls.version)
        absent = set()
        for spec in enc.field_specs():
            values = entry["fields"].get(spec.name)
            expected = (rows, *spec.shape)
            if values is None:
                if older:  # the layout of an older version may lack it (the encoding reads the old layout)
                    absent.add(spec.name)
                    continue
                raise self._malformed(f"dataset {where}/{spec.name}", f"is missing ({name} {info.version} stores "
                                      f"{spec.name} {expected} {spec.dtype})")
            array = values if isinstance(values, LazyField) else np.asarray(values)
            if array.shape != expected:
                raise self._malformed(f"dataset {where}/{spec.name}", f"has shape {array.shape}, expected {expected} "
                                      f"({spec.dtype}, from the encoding's settings)")
            if array.dtype.kind != np.dtype(spec.dtype).kind:
                raise self._malformed(f"dataset {where}/{spec.name}", f"has dtype {array.dtype}, expected "
                                      f"{spec.dtype}")
        return _Evaluator(enc, entry, frozenset(absent))

    def select_probes(self, pattern: str | None = None, region: tuple[float, ...] | None = None) -> list[int]:
        """Indices of probes whose name matches the glob ``pattern`` (e.g. ``/World/Volume/*``) and whose position
        lies in the axis-aligned box ``region`` = (xmin, ymin, zmin, xmax, ymax, zmax) (bake frame, metres)."""
        import fnmatch

        if pattern is not None and not isinstance(pattern, str):
            raise ArgumentError(f"pattern must be a glob string (e.g. '/World/*') or None, got {pattern!r}")
        lo = hi = None
        if region is not None:
            try:
                box = np.asarray(region, dtype=np.float64)
            except (TypeError, ValueError):
                box = None
            if box is None or box.shape != (6,) or np.any(np.isnan(box)):
                raise ArgumentError(f"region must be 6 numbers (xmin, ymin, zmin, xmax, ymax, zmax), got {region!r}")
            lo, hi = box[:3], box[3:]
        selected = []
        for i, name in enumerate(self.probe_names):
            if pattern and not fnmatch.fnmatchcase(name, pattern):
                continue
            if lo is not None and not np.all((self.probe_positions[i] >= lo) & (self.probe_positions[i] <= hi)):
                continue
            selected.append(i)
        return selected

    def fields(self, encoding: str) -> dict[str, np.ndarray]:
        """Stored per-probe arrays of an encoding {field: (P_k, ...)}, including ``probe_index``."""
        self._info(encoding)
        return dict(self._contents.encodings[encoding]["fields"])

    def shared(self, encoding: str) -> dict[str, np.ndarray]:
        self._info(encoding)
        return dict(self._contents.encodings[encoding]["shared"])

    def rows(self, encoding: str, probes: str | list[str] | None) -> np.ndarray:
        """Rows (int) of ``encoding`` for the named probes (a name or a list of names; all rows when None)."""
        self._info(encoding)
        index = self._contents.encodings[encoding]["fields"]["probe_index"]
        if probes is None:
            return np.arange(len(index))
        if isinstance(probes, str):
            probes = [probes]
        try:
            probes = list(probes)
        except TypeError:
            raise ArgumentError(f"probes must be a probe name, a list of probe names or None, got {probes!r}") from None
        wrong = [p for p in probes if not isinstance(p, str)]
        if wrong:
            raise ArgumentError(f"probes must be probe names (str), got {wrong[0]!r} ({type(wrong[0]).__name__})")
        lookup = {self.probe_names[i]: row for row, i in enumerate(index)}
        missing = [p for p in probes if p not in lookup]
        if missing:
            raise UnknownProbeError(f"{self.path}: encoding {encoding} has no probe(s) {missing}")
        return np.array([lookup[p] for p in probes], dtype=np.int64)

    def _selected(self, entry, rows):
        return {k: v[rows] for k, v in entry["fields"].items() if k != "probe_index"}

    def _run(self, name: str, evaluator: _Evaluator, method: Callable[..., np.ndarray], *args: Any) -> np.ndarray:
        try:
            return method(*args)
        except KeyError as error:  # a field the older layout lacks and the encoding's reader still needs
            if error.args and error.args[0] in evaluator.absent:
                raise self._malformed(f"dataset /encodings/{name}/{error.args[0]}",
                                      f"is missing ({name} {self.encodings[name].version} needs it)") from None
            raise

    # ------------------------------------------------------------------------------------------------ evaluation
    def evaluate_irradiance(self, encoding: str, normals: np.ndarray, probes: str | list[str] | None = None,
                            ) -> np.ndarray:
        """Irradiance (P, N, 3) of the given probes (a name or a list; default: all of the encoding's) at unit
        normals (N, 3) or one normal (3,) (finite and non-zero, else EvaluationError; normalised: only the direction
        counts)."""
        evaluator = self._evaluator(encoding, "irradiance")
        normals = check_directions(normals, "normals")
        rows = self.rows(encoding, probes)
        if rows.size == 0 or normals.shape[0] == 0:
            return np.zeros((rows.size, normals.shape[0], 3))
        return self._run(encoding, evaluator, evaluator.encoding.evaluate_irradiance,
                         self._selected(evaluator.entry, rows), normals)

    def evaluate_reflection(
        self, encoding: str, view: np.ndarray, normal: np.ndarray, alpha: np.ndarray, f0: np.ndarray,
        probes: str | list[str] | None = None,
    ) -> np.ndarray:
        """Specular radiance (P, N, 3) for batches of view (N, 3), normal (N, 3) (or (3,) each for one row), GGX α
        (N,) or one value, F0 (N,) scalar per row, (N, 3) RGB per row, or one value / (1, 3) for every row; the
        rules and the EvaluationError naming the argument are in :mod:`bakery.reflection.validation`."""
        evaluator = self._evaluator(encoding, "reflection")
        v, n, a, f = check_reflection_inputs(view, normal, alpha, f0)
        rows = self.rows(encoding, probes)
        if rows.size == 0 or v.shape[0] == 0:
            return np.zeros((rows.size, v.shape[0], 3))
        return self._run(encoding, evaluator, evaluator.encoding.evaluate_reflection,
                         self._selected(evaluator.entry, rows), evaluator.entry["shared"], v, n, a, f)


def open_store(path: str | os.PathLike[str], lazy: bool = False) -> ProbeStore:
    """Open a bakery probe store for reading (raises :class:`bakery.errors.StoreFormatError` if it is not one, and
    :class:`bakery.errors.ArgumentError` if ``path`` is not a file path); ``lazy``: :class:`ProbeStore`."""
    return ProbeStore(path, lazy=lazy)
