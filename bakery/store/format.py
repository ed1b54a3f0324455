"""Writing and reading bakery probe stores (HDF5), format ``bakery.probe-store`` 1.0.0 (``schemas/store-v1.md``).

Writers write only the newest version; readers accept any 1.x (a newer *minor* may add groups/attributes a reader
ignores) and refuse a newer major with a message that says what to do. Writes are atomic: the file is written
next to the target under a temporary name, flushed, fsync'ed and renamed over the target, so a crash at any point
leaves the previous store intact. Datasets are written without HDF5 timestamps (``track_times=False``) so the same
inputs give the same bytes.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from bakery.errors import StoreFormatError
from bakery.files import atomic_replace

FORMAT_NAME = "bakery.probe-store"
FORMAT_VERSION = "1.1.0"

_STR = h5py.string_dtype("utf-8")


@dataclass
class StoreContents:
    """Everything a store holds, as plain data.

    Attributes (the first five are in every version; the last three from 1.1.0):
        attributes: root attributes (format, versions, conventions, settings, settings hash, …).
        probe_names: (P,) unique probe identities (prim paths, or ``/environment``).
        probe_kinds: (P,) comma-separated kinds (``irradiance``, ``reflection``).
        probe_positions: (P, 3) float64 bake-frame positions in metres.
        encodings: {name: {"attributes": {...}, "fields": {field: (P, ...)}, "shared": {table: array}}}.
        diagnostics: {path: array} under ``/diagnostics`` (e.g. ``negative_fraction/zh3``).
    """

    attributes: dict[str, Any]
    probe_names: list[str]
    probe_kinds: list[str]
    probe_positions: np.ndarray
    encodings: dict[str, dict[str, Any]] = field(default_factory=dict)
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)
    #: (P,) content hash per probe (1.1.0; "" when unknown, e.g. migrated from 1.0.0).
    probe_hashes: list[str] | None = None
    #: (P,) index into ``history`` of the bake that produced each probe (1.1.0).
    probe_bake_ids: np.ndarray | None = None
    #: bakes that produced the probes: {"time_utc", "bakery_version", "settings_hash", "layers"} (1.1.0).
    history: list[dict[str, str]] = field(default_factory=list)


def _write_attributes(node: h5py.HLObject, attributes: dict[str, Any]) -> None:
    for key, value in sorted(attributes.items()):
        if isinstance(value, (dict, list, tuple)) and not isinstance(value, np.ndarray):
            value = json.dumps(value, sort_keys=True)
        node.attrs[key] = value


def _dataset(group: h5py.Group, name: str, data: np.ndarray, **kwargs: Any) -> h5py.Dataset:
    data = np.asarray(data)
    options: dict[str, Any] = {"track_times": False}
    if data.dtype.kind in "fiub" and data.size >= 4096:
        options.update(compression="gzip", compression_opts=4, shuffle=True, chunks=True)
    return group.create_dataset(name, data=data, **options, **kwargs)


def write_store(path: str | os.PathLike[str], contents: StoreContents) -> Path:
    """Write ``contents`` to ``path`` atomically (temp file + fsync + rename). Returns the path."""
    path = Path(path)
    if path.exists() and path.is_dir():
        raise StoreFormatError(f"{path}: is a directory; give a file name for the store")
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise StoreFormatError(f"{path}: output directory {directory} does not exist")
    try:
        with atomic_replace(path) as tmp, h5py.File(tmp, "w", track_order=True, libver=("earliest", "v110")) as f:
            _write_attributes(f, {**contents.attributes, "format": FORMAT_NAME, "format_version": FORMAT_VERSION})
            probes = f.create_group("probes")
            probes.attrs["count"] = len(contents.probe_names)
            probes.create_dataset("name", data=np.array(contents.probe_names, dtype=object), dtype=_STR,
                                  track_times=False)
            probes.create_dataset("kinds", data=np.array(contents.probe_kinds, dtype=object), dtype=_STR,
                                  track_times=False)
            _dataset(probes, "position", np.asarray(contents.probe_positions, dtype=np.float64).reshape(-1, 3))
            count = len(contents.probe_names)
            hashes = contents.probe_hashes if contents.probe_hashes is not None else [""] * count
            probes.create_dataset("content_hash", data=np.array(hashes, dtype=object), dtype=_STR, track_times=False)
            bake_ids = contents.probe_bake_ids if contents.probe_bake_ids is not None else np.zeros(count)
            _dataset(probes, "bake_id", np.asarray(bake_ids, dtype=np.int32))
            history = f.create_group("history")
            for key in ("time_utc", "bakery_version", "settings_hash", "layers"):
                history.create_dataset(key, data=np.array([str(h.get(key, "")) for h in contents.history],
                                                          dtype=object), dtype=_STR, track_times=False)
            encodings = f.create_group("encodings")
            for name in sorted(contents.encodings):
                entry = contents.encodings[name]
                group = encodings.create_group(name)
                _write_attributes(group, entry["attributes"])
                for field_name, array in entry["fields"].items():
                    ds = _dataset(group, field_name, array)
                    description = entry.get("descriptions", {}).get(field_name)
                    if description:
                        ds.attrs["description"] = description
                if entry.get("shared"):
                    shared = group.create_group("shared")
                    for table, array in sorted(entry["shared"].items()):
                        _dataset(shared, table, array)
            diagnostics = f.create_group("diagnostics")
            for key in sorted(contents.diagnostics):
                parent, _, leaf = key.rpartition("/")
                target = diagnostics.require_group(parent) if parent else diagnostics
                _dataset(target, leaf, contents.diagnostics[key])
            f.flush()
    except OSError as error:
        raise StoreFormatError(f"{path}: cannot write the store: {error.strerror or error}") from error
    return path


def _major(version: str) -> int:
    try:
        return int(str(version).split(".")[0])
    except ValueError:
        raise StoreFormatError(f"unreadable format version {version!r}") from None


def _read_attributes(node: h5py.HLObject) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in node.attrs.items():
        if isinstance(value, bytes):
            value = value.decode()
        elif isinstance(value, np.generic):
            value = value.item()
        out[key] = value
    return out


def read_store(path: str | os.PathLike[str], load_fields: bool = True) -> StoreContents:
    """Read a store. Raises :class:`StoreFormatError` for a missing, corrupt, foreign or newer-major file."""
    path = Path(path)
    if not path.is_file():
        raise StoreFormatError(f"{path}: store not found")
    try:
        f = h5py.File(path, "r")
    except OSError as error:
        raise StoreFormatError(f"{path}: not a readable HDF5 file (truncated or corrupt?): {error}") from error
    with f:
        attributes = _read_attributes(f)
        if attributes.get("format") != FORMAT_NAME:
            raise StoreFormatError(f"{path}: not a bakery probe store (format attribute {attributes.get('format')!r})")
        version = str(attributes.get("format_version", ""))
        try:
            major = _major(version)
        except StoreFormatError as error:
            raise StoreFormatError(f"{path}: {error}") from None
        if major > _major(FORMAT_VERSION):
            raise StoreFormatError(
                f"{path}: store format {version} is newer than this bakery reads ({FORMAT_VERSION}); "
                f"upgrade bakery to read it"
            )
        try:
            names = [n.decode() if isinstance(n, bytes) else str(n) for n in f["probes/name"][()]]
            kinds = [k.decode() if isinstance(k, bytes) else str(k) for k in f["probes/kinds"][()]]
            positions = f["probes/position"][()]
            encodings: dict[str, dict[str, Any]] = {}
            for name, group in f["encodings"].items():
                entry: dict[str, Any] = {"attributes": _read_attributes(group), "fields": {}, "shared": {},
                                         "descriptions": {}}
                for key, item in group.items():
                    if isinstance(item, h5py.Dataset):
                        entry["fields"][key] = item[()] if load_fields else None
                        if "description" in item.attrs:
                            entry["descriptions"][key] = str(item.attrs["description"])
                if "shared" in group:
                    entry["shared"] = {k: v[()] for k, v in group["shared"].items()}
                encodings[name] = entry
            count = len(names)
            if "content_hash" in f["probes"]:
                hashes = [h.decode() if isinstance(h, bytes) else str(h) for h in f["probes/content_hash"][()]]
                bake_ids = f["probes/bake_id"][()]
            else:
                hashes, bake_ids = [""] * count, np.zeros(count, dtype=np.int32)
            history: list[dict[str, str]] = []
            if "history" in f:
                columns = {k: [v.decode() if isinstance(v, bytes) else str(v) for v in f["history"][k][()]]
                           for k in f["history"]}
                history = [{k: columns[k][i] for k in columns} for i in range(len(next(iter(columns.values()), [])))]
            elif "bake_time_utc" in attributes:
                history = [{"time_utc": str(attributes["bake_time_utc"]),
                            "bakery_version": str(attributes.get("bakery_version", "")),
                            "settings_hash": str(attributes.get("settings_hash", "")), "layers": ""}]
            diagnostics: dict[str, np.ndarray] = {}
            if "diagnostics" in f:
                def visit(name: str, item: Any) -> None:
                    if isinstance(item, h5py.Dataset):
                        diagnostics[name] = item[()]

                f["diagnostics"].visititems(visit)
        except (KeyError, OSError) as error:
            raise StoreFormatError(f"{path}: store is missing required data or is corrupt: {error}") from error
    return StoreContents(attributes, names, kinds, np.asarray(positions), encodings, diagnostics, hashes,
                         np.asarray(bake_ids, dtype=np.int32), history)


def migrate_store(source: str | os.PathLike[str], target: str | os.PathLike[str] | None = None,
                  dry_run: bool = False) -> list[str]:
    """Upgrade a store to :data:`FORMAT_VERSION` (atomically, in place unless ``target``). Returns the steps taken.

    1.0.0 → 1.1.0: adds ``/probes/content_hash`` (empty: the probes will be re-baked on the next incremental bake),
    ``/probes/bake_id`` (0) and ``/history`` with one entry from the root attributes.
    """
    contents = read_store(source)
    version = str(contents.attributes.get("format_version"))
    if version == FORMAT_VERSION:
        return []
    steps = [f"{version} -> {FORMAT_VERSION}: add /probes/content_hash, /probes/bake_id, /history"]
    if not dry_run:
        write_store(target or source, contents)
    return steps
