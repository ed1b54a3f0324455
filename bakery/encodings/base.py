"""The encoding plug-in contract: :class:`FieldSpec`, typed parameters (:class:`EncodingParams`) and :class:`Encoding`.

An encoding is one module of ``bakery/encodings/`` defining :class:`Encoding` subclasses, each with a frozen
dataclass ``Params`` (a subclass of :class:`EncodingParams`), registered at the bottom of the module with
:func:`bakery.encodings.registry.register`. Everything else (store writer and reader, ``bakery inspect``, the public
API, the pipeline, the memory report and ``tests/test_encoding_conformance.py``) works from the declaration.

Declaration (class variables)
    name                    store group ``/encodings/<name>``
    kind                    ``"irradiance"`` or ``"reflection"``
    version                 semantic version of the stored layout (bump it when the layout or meaning changes and
                            keep a reader for the old one)
    description             stored with the group
    Params                  the typed parameters (recipe ``[encoding_settings.<name>]``, stored ``settings``)

Capabilities (read by the pipeline instead of lists of names)
    max_band                irradiance: highest SH band whose information is stored (1 or 2); reflection: None
    radiance_sh_field       stored float field holding radiance SH with the DC first (light bounds of incremental
                            bakes), or None
    accepts_alpha_range     Params has ``alpha_min``/``alpha_max`` that the pipeline may override per probe
                            (:meth:`Encoding.probe_alpha_overrides` says with what, from the probe's materials)
    follows_bake_face_size  Params has ``face_size: int | None = None``; None = the bake's face size, resolved by
                            the pipeline with ``params.replace(face_size=N)`` before constructing
    worse_than              (diagnostic, other encoding class): the pipeline stores the per-probe diagnostic
                            ``diagnostic = reference_error[this] > reference_error[other]`` when both are baked

Instance
    ``field_specs()``       per-probe arrays it stores (shape after the probe axis, dtype, meaning), written as
                            datasets (P, *shape) in ``/encodings/<name>/``
    ``shared_tables()``     arrays stored once per store in ``/encodings/<name>/shared/``
    ``encode(batch)``       {field: (P, *shape)}: every stored field plus the ``aux_specs()`` fields
    ``finalize(fields, aux)`` once in the parent over every probe of the store → the Params stored in ``settings``
                            and used for evaluation (default: ``self.params``)
    ``settings``            ``params.as_dict()`` + ``derived_settings()`` (JSON-able), the group attribute
                            ``settings``; ``from_settings`` rebuilds the encoding from it
    ``evaluate_irradiance`` / ``evaluate_reflection``: what an engine reconstructs, from stored fields only. Every
                            subclass's ``evaluate_reflection`` is wrapped (:meth:`Encoding.__init_subclass__`) so that
                            it receives its arguments checked and in row form: view, normal (M, 3), α (M,), F0 (M,) or
                            (M, 3) float64 (:func:`bakery.reflection.validation.check_reflection_inputs`; bad input
                            raises :class:`~bakery.errors.EvaluationError`, a ValueError naming the argument).
                            Evaluating an encoding as the other kind raises
                            :class:`~bakery.errors.EncodingKindError` (also a NotImplementedError).

Parameters (:class:`EncodingParams`)
    Frozen dataclasses whose field annotations are the schema: ``bool``, ``int``, ``float`` (an int is accepted),
    ``str``, ``Literal[...]``, ``tuple[T, ...]`` / ``tuple[T1, T2]`` (a list is accepted), ``X | None`` and unions
    of these. Construction type-checks every field (a bool is not a number, a string is never a bool), applies
    ``normalize()`` and calls ``validate()`` for ranges (which raises ValueError); failures raise
    :class:`ParamsError`, a :class:`~bakery.errors.ConfigError` (CLI exit 3) that is also a ValueError.
    Fields made with :func:`finalize_field` are results of ``finalize()``: not settable in recipes, omitted from
    ``as_dict()`` while None.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import types
from abc import ABC, abstractmethod
from collections.abc import Hashable, Mapping
from functools import cache
from typing import TYPE_CHECKING, Any, ClassVar, Literal, Union, get_args, get_origin, get_type_hints

import numpy as np

from bakery.errors import ConfigError, EncodingKindError

if TYPE_CHECKING:
    from bakery.probe import ProbeBatch

#: Field metadata key of :func:`finalize_field` fields.
FINALIZE_METADATA = "bakery_set_by_finalize"


@dataclasses.dataclass(frozen=True)
class FieldSpec:
    """One stored per-probe array: ``shape`` excludes the leading probe axis."""

    name: str
    shape: tuple[int, ...]
    dtype: str
    description: str

    @property
    def nbytes(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) * np.dtype(self.dtype).itemsize


class ParamsError(ConfigError, ValueError):
    """Invalid encoding parameters: ``"<where>: <detail>"``. ``key`` is the offending key when there is one.

    A :class:`~bakery.errors.ConfigError` (exit code 3) for recipes and user settings, and a ValueError for code
    that constructs encodings directly."""

    def __init__(self, message: str, key: str | None = None, detail: str | None = None) -> None:
        super().__init__(message)
        self.key = key
        self.detail = message if detail is None else detail


def finalize_field(default: Any = None) -> Any:
    """A Params field set by :meth:`Encoding.finalize` (e.g. the number of samples a fit used): not a recipe key,
    omitted from :meth:`EncodingParams.as_dict` while None, read back by :meth:`EncodingParams.from_stored`."""
    return dataclasses.field(default=default, metadata={FINALIZE_METADATA: True})


# ------------------------------------------------------------------------------------------------ type checking
def _describe(hint: Any) -> str:
    """Human-readable expected type of an annotation (error messages)."""
    origin = get_origin(hint)
    if origin in (Union, types.UnionType):
        return " or ".join(_describe(arm) for arm in get_args(hint))
    if origin is Literal:
        return "one of " + ", ".join(repr(option) for option in get_args(hint))
    if origin is tuple:
        args = get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_describe(args[0])}"
        return f"a list [{', '.join(_describe(arg) for arg in args)}]"
    return {type(None): "None", bool: "bool", int: "int", float: "float", str: "str"}.get(
        hint, getattr(hint, "__name__", repr(hint)))


def _coerce(value: Any, hint: Any) -> tuple[bool, Any]:
    """(True, value converted to the annotation's Python type) if ``value`` matches ``hint``, else (False, None).

    Strict: a bool is not an int or a float, a string is never a bool or a number, floats are finite; an int is
    accepted for a float (converted), a list for a tuple; numpy scalars count as their Python types."""
    if hint is Any:
        return True, value
    origin = get_origin(hint)
    if origin in (Union, types.UnionType):
        for arm in get_args(hint):
            ok, converted = _coerce(value, arm)
            if ok:
                return True, converted
        return False, None
    if origin is Literal:
        for option in get_args(hint):
            if type(value) is type(option) and value == option:
                return True, value
        return False, None
    if origin is tuple:
        if isinstance(value, np.ndarray):
            value = value.tolist()
        if not isinstance(value, (tuple, list)):
            return False, None
        args = get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            element_hints = (args[0],) * len(value)
        elif len(args) != len(value):
            return False, None
        else:
            element_hints = args
        items = []
        for item, element_hint in zip(value, element_hints, strict=True):
            ok, converted = _coerce(item, element_hint)
            if not ok:
                return False, None
            items.append(converted)
        return True, tuple(items)
    if hint is type(None) or hint is None:
        return value is None, None
    is_bool = isinstance(value, (bool, np.bool_))
    if hint is bool:
        return (True, bool(value)) if is_bool else (False, None)
    if hint is int:
        return (True, int(value)) if isinstance(value, (int, np.integer)) and not is_bool else (False, None)
    if hint is float:
        if isinstance(value, (int, float, np.integer, np.floating)) and not is_bool and math.isfinite(value):
            return True, float(value)
        return False, None
    if hint is str:
        return (True, str(value)) if isinstance(value, str) else (False, None)
    if isinstance(hint, type):
        return (True, value) if isinstance(value, hint) else (False, None)
    raise TypeError(f"unsupported EncodingParams annotation {hint!r}")


@cache
def _field_hints(cls: type) -> dict[str, Any]:
    hints = get_type_hints(cls)
    return {f.name: hints.get(f.name, Any) for f in dataclasses.fields(cls)}


def _jsonable(value: Any) -> Any:
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    return value


def _plural(keys: list[str]) -> str:
    return ("unknown key " if len(keys) == 1 else "unknown keys ") + ", ".join(repr(k) for k in keys)


# ------------------------------------------------------------------------------------------------ parameters
@dataclasses.dataclass(frozen=True)
class EncodingParams:
    """Base of the typed parameters of an encoding (see the module docstring). Subclasses are
    ``@dataclass(frozen=True)`` with annotated, defaulted fields, and optionally override :meth:`validate`
    (ranges; raise ValueError naming the key), :meth:`normalize` and :attr:`LEGACY_VALUES`."""

    #: Stored values of older versions, mapped by :meth:`from_stored`: {key: {old value: current value}}.
    LEGACY_VALUES: ClassVar[Mapping[str, Mapping[Any, Any]]] = {}

    def __post_init__(self) -> None:
        hints = _field_hints(type(self))
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            ok, converted = _coerce(value, hints[f.name])
            if not ok:
                detail = (f"{f.name} must be {_describe(hints[f.name])}, got {value!r} "
                          f"({type(value).__name__})")
                raise ParamsError(f"{self._label()}: {detail}", key=f.name, detail=detail)
            object.__setattr__(self, f.name, converted)
        for key, value in self.normalize().items():
            object.__setattr__(self, key, value)
        try:
            self.validate()
        except ParamsError:
            raise
        except ValueError as error:
            detail = str(error)
            key = next((f.name for f in dataclasses.fields(self) if detail.startswith(f.name + " ")), None)
            raise ParamsError(f"{self._label()}: {detail}", key=key, detail=detail) from None

    @classmethod
    def _label(cls) -> str:
        return cls.__qualname__

    def validate(self) -> None:
        """Check ranges after type checking; raise ValueError("<key> must be …, got …")."""

    def normalize(self) -> Mapping[str, Any]:
        """Field values to replace after type checking and before :meth:`validate` (e.g. clamp a dependent
        default); default: none."""
        return {}

    # --------------------------------------------------------------------------------------------- builders
    @classmethod
    def recipe_keys(cls) -> tuple[str, ...]:
        """Keys a recipe may set: every field except :func:`finalize_field` ones."""
        return tuple(f.name for f in dataclasses.fields(cls) if not f.metadata.get(FINALIZE_METADATA))

    @classmethod
    def _build(cls, values: Mapping[str, Any], where: str) -> EncodingParams:
        """Construct from known keys, errors prefixed with ``where``."""
        try:
            return cls(**values)
        except ParamsError as error:
            raise ParamsError(f"{where}: {error.detail}", key=error.key, detail=error.detail) from None

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], where: str) -> EncodingParams:
        """STRICT: recipe or user settings → Params. Unknown keys, wrong types and out-of-range values raise
        :class:`ParamsError` (a ConfigError) ``"<where>: …"`` naming the key."""
        if not isinstance(values, Mapping):
            raise ParamsError(f"{where}: expected a table of settings, got {values!r}")
        known = cls.recipe_keys()
        unknown = [str(k) for k in values if k not in known]
        if unknown:
            detail = f"{_plural(unknown)}; known: {', '.join(known) or '(none)'}"
            raise ParamsError(f"{where}: {detail}", key=unknown[0], detail=detail)
        return cls._build(values, where)

    @classmethod
    def from_stored(cls, values: Mapping[str, Any]) -> EncodingParams:
        """LENIENT: a store's ``settings`` → Params. Ignores keys that are not fields (derived settings), maps
        :attr:`LEGACY_VALUES`, accepts lists for tuples; the values are still type- and range-checked."""
        names = {f.name for f in dataclasses.fields(cls)}
        kept: dict[str, Any] = {}
        for key, value in values.items():
            if key not in names:
                continue
            legacy = cls.LEGACY_VALUES.get(key)
            if legacy and isinstance(value, Hashable) and value in legacy:
                value = legacy[value]
            kept[key] = value
        return cls._build(kept, f"stored {cls._label()} settings")

    def replace(self, **changes: Any) -> EncodingParams:
        """A copy with ``changes`` (any field, including :func:`finalize_field` ones), validated."""
        names = [f.name for f in dataclasses.fields(self)]
        unknown = [k for k in changes if k not in names]
        if unknown:
            detail = f"{_plural(unknown)}; known: {', '.join(names) or '(none)'}"
            raise ParamsError(f"{self._label()}: {detail}", key=unknown[0], detail=detail)
        return self._build({**self._values(), **changes}, self._label())

    def _values(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def as_dict(self) -> dict[str, Any]:
        """JSON-able {key: value} (tuples as lists); :func:`finalize_field` fields only once set."""
        return {f.name: _jsonable(getattr(self, f.name)) for f in dataclasses.fields(self)
                if not (f.metadata.get(FINALIZE_METADATA) and getattr(self, f.name) is None)}


@dataclasses.dataclass(frozen=True)
class NoParams(EncodingParams):
    """Parameters of an encoding that has none."""


# ------------------------------------------------------------------------------------------------ encodings
def _checked_reflection(method: Any) -> Any:
    """``method`` (an ``evaluate_reflection``) called with its arguments checked and in row form (module doc)."""

    @functools.wraps(method)
    def evaluate_reflection(self: Encoding, fields: dict[str, np.ndarray], shared: dict[str, np.ndarray],
                            view: np.ndarray, normal: np.ndarray, alpha: np.ndarray, f0: np.ndarray) -> np.ndarray:
        from bakery.reflection.validation import check_reflection_inputs

        return method(self, fields, shared, *check_reflection_inputs(view, normal, alpha, f0))

    evaluate_reflection.checks_inputs = True  # type: ignore[attr-defined]
    return evaluate_reflection


class Encoding(ABC):
    """Base class of every encoding; see the module docstring for the contract."""

    name: ClassVar[str]
    kind: ClassVar[str]
    version: ClassVar[str] = "1.0.0"
    description: ClassVar[str] = ""
    Params: ClassVar[type[EncodingParams]]

    max_band: ClassVar[int | None] = None
    radiance_sh_field: ClassVar[str | None] = None
    accepts_alpha_range: ClassVar[bool] = False
    follows_bake_face_size: ClassVar[bool] = False
    worse_than: ClassVar[tuple[str, type[Encoding]] | None] = None

    #: Non-default settings whose layout adds fields the USD schema declares as well (label → Params overrides), e.g.
    #: a setting a recipe preset turns on: :func:`bakery.usd.plugin.baked_field_attributes`.
    schema_layouts: ClassVar[Mapping[str, Mapping[str, Any]]] = {}

    @classmethod
    def probe_alpha_overrides(cls, params: EncodingParams, alpha_range: tuple[float, float],
                              alpha_min_nonzero: float | None) -> dict[str, Any]:
        """The per-probe overrides (``accepts_alpha_range``) from the materials in a probe's influence volume: their
        bucketed α range, and the smallest of their α above 0 (None: none); ``params``: the bake's resolved Params.
        Default: ``alpha_min``/``alpha_max`` only."""
        return {"alpha_min": alpha_range[0], "alpha_max": alpha_range[1]}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Wrap the subclass's own ``evaluate_reflection`` so that every reflection encoding checks its arguments in
        one place (module doc); the checks are idempotent, so a wrapped method calling a wrapped super() is fine."""
        super().__init_subclass__(**kwargs)
        method = cls.__dict__.get("evaluate_reflection")
        if callable(method) and not getattr(method, "checks_inputs", False):
            cls.evaluate_reflection = _checked_reflection(method)  # type: ignore[method-assign]

    def __init__(self, params: EncodingParams | None = None, **overrides: Any) -> None:
        """``params`` (default ``Params()``) with ``overrides`` applied. Keys of :meth:`derived_settings` are
        accepted and ignored among the overrides, so ``cls(**encoding.settings)`` rebuilds an encoding."""
        if params is None:
            params = self.Params()
        elif type(params) is not self.Params:
            raise TypeError(f"{self.name}: params must be {type(self).__name__}.Params, got {type(params).__name__}")
        names = {f.name for f in dataclasses.fields(self.Params)}
        extra = [k for k in overrides if k not in names]
        if overrides:
            params = self.Params._build(
                {**params._values(), **{k: v for k, v in overrides.items() if k in names}}, self.name)
        self.params = self._resolve(params)
        if extra:
            unknown = [k for k in extra if k not in self.derived_settings()]
            if unknown:
                detail = f"{_plural(unknown)}; known: {', '.join(self.Params.recipe_keys()) or '(none)'}"
                raise ParamsError(f"{self.name}: {detail}", key=unknown[0], detail=detail)

    def _resolve(self, params: EncodingParams) -> EncodingParams:
        """The Params this instance uses (hook, e.g. to fill a None meaning "the bake's" with a default)."""
        return params

    @classmethod
    def from_settings(cls, stored: Mapping[str, Any]) -> Encoding:
        """The encoding a store's ``settings`` describe (lenient: :meth:`EncodingParams.from_stored`)."""
        return cls(cls.Params.from_stored(stored))

    @property
    def settings(self) -> dict[str, Any]:
        """JSON-able settings stored with the encoding: the Params and the derived settings."""
        return {**self.params.as_dict(), **self.derived_settings()}

    def settings_json(self) -> str:
        return json.dumps(self.settings, sort_keys=True)

    def derived_settings(self) -> dict[str, Any]:
        """Informative settings computed from the Params (stored, ignored when read back)."""
        return {}

    @abstractmethod
    def field_specs(self) -> tuple[FieldSpec, ...]:
        """The stored per-probe arrays."""

    def aux_specs(self) -> tuple[FieldSpec, ...]:
        """Per-probe arrays :meth:`encode` returns besides the stored fields, for :meth:`finalize`."""
        return ()

    def shared_tables(self) -> dict[str, np.ndarray]:
        return {}

    def bytes_per_probe(self) -> int:
        """Bytes an engine stores per probe: the sum of the per-probe fields (shared tables excluded)."""
        return sum(spec.nbytes for spec in self.field_specs())

    def upload_bytes(self, fields: dict[str, np.ndarray]) -> np.ndarray:
        """(P,) bytes an engine uploads for each of the P probes of stored ``fields``: :meth:`bytes_per_probe` each;
        an encoding whose probes use only part of a fixed layout overrides it (``shexp_hybrid``: not the chain levels
        below a probe's ``first_level``)."""
        rows = int(np.asarray(fields[self.field_specs()[0].name]).shape[0])
        return np.full(rows, self.bytes_per_probe(), dtype=np.int64)

    @classmethod
    def layer_fields(cls, fields: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The fields {name: (R, *shape)} of one prim's R probes to write into the baked USD layer: every stored field
        by default; an encoding may leave out fields that no probe of the prim uses (the layer is what an engine
        uploads; the store keeps its fixed layout)."""
        return fields

    @classmethod
    def captures_kept(cls, fields: dict[str, np.ndarray], settings: dict[str, Any]) -> np.ndarray:
        """(P,) bool: which stored probes hold their capture in an α = 0 ``level0`` field (what cube-map exports
        re-prefilter), given the stored ``fields`` and ``settings``; every probe by default (encodings without such
        a level are never asked)."""
        return np.ones(len(next(iter(fields.values()))), dtype=bool)

    @abstractmethod
    def encode(self, batch: ProbeBatch) -> dict[str, np.ndarray]:
        """{field: (P, *shape)} for every field of :meth:`field_specs` and :meth:`aux_specs`."""

    def finalize(self, fields: dict[str, np.ndarray], aux: dict[str, np.ndarray]) -> EncodingParams:
        """Called once in the parent over every probe of the store, with the stored fields and the aux arrays
        (each (P, *shape)); returns the Params to store and evaluate with."""
        return self.params

    def evaluate_irradiance(self, fields: dict[str, np.ndarray], normals: np.ndarray) -> np.ndarray:
        """Irradiance (P, N, 3) at unit normals (N, 3) from stored fields {name: (P, *shape)}."""
        raise EncodingKindError(f"{self.name} is a {self.kind} encoding, not an irradiance encoding: evaluate it with "
                                "evaluate_reflection(fields, shared, view, normal, alpha, f0)")

    def evaluate_reflection(
        self,
        fields: dict[str, np.ndarray],
        shared: dict[str, np.ndarray],
        view: np.ndarray,
        normal: np.ndarray,
        alpha: np.ndarray,
        f0: np.ndarray,
    ) -> np.ndarray:
        """Specular radiance E (P, N, 3) for (N,) batches of view v (N, 3) (towards the viewer), normal n (N, 3),
        GGX α (N,) and F0 (N,) or (N, 3), from stored fields and shared tables."""
        raise EncodingKindError(f"{self.name} is an {self.kind} encoding, not a reflection encoding: evaluate it with "
                                "evaluate_irradiance(fields, normals)")
