"""Public Python API: open a store, list its probes and encodings, evaluate any stored encoding.

    >>> store = bakery.open_store("probes.h5")                 # doctest: +SKIP
    >>> store.probe_names, list(store.encodings)               # doctest: +SKIP
    >>> store.evaluate_irradiance("zh3", normals)              # (P, N, 3)  # doctest: +SKIP
    >>> store.evaluate_reflection("sh_exp", v, n, alpha, f0)   # (P, N, 3)  # doctest: +SKIP

Evaluation reconstructs exactly what an engine would, from the stored arrays and the encoding's stored settings.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from bakery.encodings import get_encoding
from bakery.errors import StoreFormatError
from bakery.store.format import read_store


@dataclass(frozen=True)
class EncodingInfo:
    name: str
    kind: str
    version: str
    bytes_per_probe: int
    description: str
    settings: dict[str, Any]
    probe_count: int


class ProbeStore:
    """A probe store opened for reading (all arrays are loaded; stores are small). Opening verifies the store's
    checksums (``schemas/store-v1.md``, Integrity) and raises :class:`bakery.errors.StoreFormatError` naming the
    datasets that fail them."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = str(path)
        self._contents = read_store(path)
        a = self._contents.attributes
        self.attributes: dict[str, Any] = a
        self.format_version: str = str(a["format_version"])
        self.conventions: dict[str, str] = {}
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
        self.encodings: dict[str, EncodingInfo] = {}
        try:
            self.conventions = json.loads(a.get("conventions", "{}"))
            for name, entry in self._contents.encodings.items():
                at = entry["attributes"]
                self.encodings[name] = EncodingInfo(
                    name=name, kind=str(at["kind"]), version=str(at["encoding_version"]),
                    bytes_per_probe=int(at["bytes_per_probe"]), description=str(at.get("description", "")),
                    settings=json.loads(at.get("settings", "{}")), probe_count=len(entry["fields"]["probe_index"]),
                )
        except (KeyError, ValueError, TypeError) as error:  # JSONDecodeError is a ValueError
            raise StoreFormatError(f"{self.path}: malformed store metadata ({type(error).__name__}: {error}); the "
                                   f"file was not written by bakery or is corrupt") from None

    def _encoding(self, name: str):
        if name not in self.encodings:
            raise KeyError(f"{self.path}: no encoding {name!r}; stored: {', '.join(self.encodings)}")
        entry = self._contents.encodings[name]
        stored_version = str(entry["attributes"]["encoding_version"])
        cls = get_encoding(name)
        if int(stored_version.split(".")[0]) > int(cls.version.split(".")[0]):
            raise StoreFormatError(
                f"{self.path}: encoding {name} is version {stored_version}, newer than this bakery reads "
                f"({cls.version}); upgrade bakery"
            )
        return cls.from_settings(self.encodings[name].settings), entry

    def select_probes(self, pattern: str | None = None, region: tuple[float, ...] | None = None) -> list[int]:
        """Indices of probes whose name matches the glob ``pattern`` (e.g. ``/World/Volume/*``) and whose position
        lies in the axis-aligned box ``region`` = (xmin, ymin, zmin, xmax, ymax, zmax) (bake frame, metres)."""
        import fnmatch

        selected = []
        for i, name in enumerate(self.probe_names):
            if pattern and not fnmatch.fnmatchcase(name, pattern):
                continue
            if region is not None:
                lo, hi = np.asarray(region[:3]), np.asarray(region[3:])
                if not np.all((self.probe_positions[i] >= lo) & (self.probe_positions[i] <= hi)):
                    continue
            selected.append(i)
        return selected

    def fields(self, encoding: str) -> dict[str, np.ndarray]:
        """Stored per-probe arrays of an encoding {field: (P_k, ...)}, including ``probe_index``."""
        return dict(self._contents.encodings[encoding]["fields"])

    def shared(self, encoding: str) -> dict[str, np.ndarray]:
        return dict(self._contents.encodings[encoding]["shared"])

    def rows(self, encoding: str, probes: list[str] | None) -> np.ndarray:
        """Rows of ``encoding`` for the named probes (all rows when None)."""
        index = self._contents.encodings[encoding]["fields"]["probe_index"]
        if probes is None:
            return np.arange(len(index))
        lookup = {self.probe_names[i]: row for row, i in enumerate(index)}
        missing = [p for p in probes if p not in lookup]
        if missing:
            raise KeyError(f"{self.path}: encoding {encoding} has no probe(s) {missing}")
        return np.array([lookup[p] for p in probes])

    def _selected(self, entry, rows):
        return {k: v[rows] for k, v in entry["fields"].items() if k != "probe_index"}

    def evaluate_irradiance(self, encoding: str, normals: np.ndarray, probes: list[str] | None = None) -> np.ndarray:
        """Irradiance (P, N, 3) of the given probes (default: all of the encoding's) at unit normals (N, 3)."""
        enc, entry = self._encoding(encoding)
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        return enc.evaluate_irradiance(self._selected(entry, self.rows(encoding, probes)), normals)

    def evaluate_reflection(
        self, encoding: str, view: np.ndarray, normal: np.ndarray, alpha: np.ndarray, f0: np.ndarray,
        probes: list[str] | None = None,
    ) -> np.ndarray:
        """Specular radiance (P, N, 3) for batches of view (N, 3), normal (N, 3), GGX α (N,), F0 (N,) or (N, 3)."""
        enc, entry = self._encoding(encoding)
        return enc.evaluate_reflection(
            self._selected(entry, self.rows(encoding, probes)), entry["shared"], np.asarray(view, float),
            np.asarray(normal, float), np.asarray(alpha, float), np.asarray(f0, float),
        )


def open_store(path: str | os.PathLike[str]) -> ProbeStore:
    """Open a bakery probe store for reading (raises :class:`bakery.errors.StoreFormatError` if it is not one)."""
    return ProbeStore(path)
