"""The encoding registry: one class per encoding, declared once, picked up by store, API and conformance tests.

An encoding module defines a subclass of :class:`Encoding` and decorates it with :func:`register`. Everything else
(the store writer and reader, ``bakery inspect``, the public API, the memory report and the conformance test suite
in ``tests/test_encoding_conformance.py``) works from the declaration:

- ``name``: the store group ``/encodings/<name>``; ``version``: semantic version of its stored layout (bump it when
  the layout or meaning changes and keep a reader for the old one); ``kind``: ``"irradiance"`` or ``"reflection"``.
- ``field_specs()``: the per-probe arrays it stores (shape after the probe axis, dtype, meaning); the store writes
  each as a dataset (P, *shape) in ``/encodings/<name>/``.
- ``shared_tables()``: arrays stored once per store (e.g. the DFG table) in ``/encodings/<name>/shared/``.
- ``settings``: JSON-able parameters, stored as the group attribute ``settings``; ``from_settings`` rebuilds the
  encoding from them so that a store can be evaluated without the bake's settings.
- ``encode(batch)`` → {field: (P, *shape) array}; ``evaluate_irradiance`` / ``evaluate_reflection`` reconstruct
  what an engine would, from stored fields only.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bakery.probe import ProbeBatch


@dataclass(frozen=True)
class FieldSpec:
    """One stored per-probe array: ``shape`` excludes the leading probe axis."""

    name: str
    shape: tuple[int, ...]
    dtype: str
    description: str

    @property
    def nbytes(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) * np.dtype(self.dtype).itemsize


class Encoding:
    """Base class of every encoding; see the module docstring for the contract."""

    name: ClassVar[str]
    version: ClassVar[str] = "1.0.0"
    kind: ClassVar[str]
    description: ClassVar[str] = ""

    def __init__(self, **settings: Any) -> None:
        self.settings: dict[str, Any] = dict(settings)

    @classmethod
    def from_settings(cls, settings: dict[str, Any]) -> Encoding:
        return cls(**settings)

    def field_specs(self) -> tuple[FieldSpec, ...]:
        raise NotImplementedError

    def shared_tables(self) -> dict[str, np.ndarray]:
        return {}

    def bytes_per_probe(self) -> int:
        """Bytes an engine stores per probe: the sum of the per-probe fields (shared tables excluded)."""
        return sum(spec.nbytes for spec in self.field_specs())

    def encode(self, batch: ProbeBatch) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def evaluate_irradiance(self, fields: dict[str, np.ndarray], normals: np.ndarray) -> np.ndarray:
        """Irradiance (P, N, 3) at unit normals (N, 3) from stored fields {name: (P, *shape)}."""
        raise NotImplementedError(f"{self.name} is not an irradiance encoding")

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
        raise NotImplementedError(f"{self.name} is not a reflection encoding")

    def settings_json(self) -> str:
        return json.dumps(self.settings, sort_keys=True)


#: name → encoding class, in registration order.
ENCODINGS: dict[str, type[Encoding]] = {}


def register(cls: type[Encoding]) -> type[Encoding]:
    """Class decorator adding an encoding to :data:`ENCODINGS`."""
    if cls.name in ENCODINGS and ENCODINGS[cls.name] is not cls:
        raise ValueError(f"encoding name {cls.name!r} registered twice")
    if cls.kind not in ("irradiance", "reflection"):
        raise ValueError(f"encoding {cls.name!r} has unknown kind {cls.kind!r}")
    ENCODINGS[cls.name] = cls
    return cls


def get_encoding(name: str) -> type[Encoding]:
    from bakery import encodings  # noqa: F401 - importing the package registers every encoding

    try:
        return ENCODINGS[name]
    except KeyError:
        raise KeyError(f"unknown encoding {name!r}; known: {', '.join(ENCODINGS)}") from None
