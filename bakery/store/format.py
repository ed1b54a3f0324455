"""Writing and reading bakery probe stores (HDF5), format ``bakery.probe-store`` 1.2.0 (``schemas/store-v1.md``).

Writers write only the newest version; readers accept any 1.x (a newer *minor* may add groups/attributes a reader
ignores) and refuse a newer major with a message that says what to do. Writes are atomic: the file is written
next to the target under a temporary name, flushed, fsync'ed and renamed over the target, so a crash at any point
leaves the previous store intact. Datasets are written without HDF5 timestamps (``track_times=False``) so the same
inputs give the same bytes.

Integrity (1.2.0; ``schemas/store-v1.md``, "Integrity")
    Every fixed-size dataset is chunked with HDF5's fletcher32 filter (bit rot and damaged copies fail on read; the
    variable-length string datasets cannot carry filters, HDF5 refuses them). ``/checksums/probe`` (P, 32) uint8
    holds a SHA-256 per probe over its identity row and its row of every encoding, so a damaged probe is found and
    only it is re-baked; ``/checksums/datasets`` lists the SHA-256, dtype and shape of every other dataset and of
    every group's attributes, so the damaged dataset is named. :func:`read_store` verifies both: ``strict``
    (default: ``inspect``, ``diff``, ``report``, ``migrate``, the API) raises :class:`StoreIntegrityError` naming
    the datasets; ``strict=False`` (the previous store of a bake) returns the findings in
    ``StoreContents.integrity`` instead.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from bakery.errors import ArgumentError, BakeryWarning, StoreFormatError
from bakery.files import (
    atomic_replace,
    os_error_message,
    sha256_array,
    sha256_bytes,
    sha256_running,
    with_filename,
)
from bakery.zero_pages import MIN_BYTES, lazy_zeros, nonzero_rows

FORMAT_NAME = "bakery.probe-store"
FORMAT_VERSION = "1.2.0"
#: Oldest format version with ``/checksums`` and fletcher32 filters.
CHECKSUM_VERSION = "1.2.0"

_STR = h5py.string_dtype("utf-8")
_CHECKSUMS = "checksums"
#: ``/history`` columns every store has (1.1.0); later columns (1.2.0: ``scene_lights``) are written when present.
HISTORY_COLUMNS = ("time_utc", "bakery_version", "settings_hash", "layers")


class StoreIntegrityError(StoreFormatError):
    """A store's contents do not match their checksums (damaged file, or edited outside bakery)."""


class StoreIntegrityWarning(BakeryWarning):
    """The previous store of a bake failed its integrity check; the affected probes are re-baked."""


@dataclass
class StoreIntegrity:
    """What :func:`read_store` found when it verified a store.

    Attributes:
        verified: the store carries checksums (format ≥ 1.2.0) and they were checked.
        problems: one line per finding, each naming the dataset (or attributes) concerned.
        bad_probes: probes whose stored values do not match their per-probe checksum.
        whole_store: a finding that cannot be attributed to probes (shared tables, diagnostics, history,
            attributes, missing checksums): nothing of the store can be trusted.
    """

    verified: bool = False
    problems: list[str] = field(default_factory=list)
    bad_probes: set[str] = field(default_factory=set)
    whole_store: bool = False

    @property
    def ok(self) -> bool:
        return not self.problems


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
    #: bakes that produced the probes: {"time_utc", "bakery_version", "settings_hash", "layers"} (1.1.0), plus
    #: ``scene_lights`` (1.2.0: the light table a scene bake used; "" when unknown).
    history: list[dict[str, str]] = field(default_factory=list)
    #: what reading found when it verified the checksums (1.2.0; set by :func:`read_store`).
    integrity: StoreIntegrity | None = None
    #: the open file the :class:`LazyField` fields read from (``lazy_fields``), else None; :meth:`close` closes it.
    file: Any = None

    def close(self) -> None:
        """Close the file lazy fields read from (they cannot be read afterwards)."""
        if self.file is not None:
            self.file.close()
            self.file = None


class LazyField:
    """A large field of a store read with ``lazy_fields`` (:func:`read_store`): (P_k, ...) rows read from the open
    file when indexed, so a consumer that walks the probes in blocks (an export) holds one block, not the store.

    Indexing takes a row, a slice, a 1-D array of rows or a boolean mask, optionally followed by indices into the
    row (``field[rows, 0]``); values are little-endian numpy arrays, as the eager reader returns them. ``np.asarray``
    reads it whole. The file handle is the one :func:`read_store` verified (a store renamed over the path meanwhile
    is not read)."""

    def __init__(self, dataset: h5py.Dataset) -> None:
        self._dataset = dataset
        self.name: str = dataset.name
        self.shape: tuple[int, ...] = tuple(dataset.shape)
        self.dtype: np.dtype = dataset.dtype.newbyteorder("<") if dataset.dtype.byteorder == ">" else dataset.dtype
        self.ndim = len(self.shape)
        self.size = int(np.prod(self.shape, dtype=np.int64))
        self.nbytes = self.size * self.dtype.itemsize

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"LazyField({self.name}, {self.dtype.str} {self.shape})"

    def _rows(self, key: Any) -> np.ndarray:
        """Rows ``key`` (an array of row numbers or a boolean mask) in the given order, repeats allowed: the
        distinct rows read by runs of consecutive rows (HDF5 reads a slice at a time; h5py's point selections are
        slow), then put in order."""
        index = np.asarray(key)
        if index.dtype == bool:
            if index.shape != (self.shape[0],):
                raise IndexError(f"{self.name}: boolean index of shape {index.shape} for {self.shape[0]} rows")
            index = np.flatnonzero(index)
        if index.ndim != 1 or (index.size and index.dtype.kind not in "iu"):
            raise IndexError(f"{self.name}: rows must be a 1-D array of integers, got {index.dtype} {index.shape}")
        index = index.astype(np.int64)
        count = self.shape[0]
        if np.any((index < -count) | (index >= count)):
            raise IndexError(f"{self.name}: row out of range for {count} rows")
        index = np.where(index < 0, index + count, index)
        distinct, inverse = np.unique(index, return_inverse=True)
        out = np.empty((distinct.size, *self.shape[1:]), dtype=self.dtype)
        starts = np.flatnonzero(np.r_[True, np.diff(distinct) != 1]) if distinct.size else np.zeros(0, np.int64)
        for a, b in zip(starts.tolist(), np.r_[starts[1:], distinct.size].tolist()):
            out[a:b] = self._dataset[int(distinct[a]) : int(distinct[b - 1]) + 1]
        return out[inverse]

    def _open(self) -> h5py.Dataset:
        if not self._dataset.id.valid:
            raise StoreFormatError(f"{self.name}: the store it was read from is closed; open it again to read it")
        return self._dataset

    def __getitem__(self, key: Any) -> np.ndarray:
        return self._reading(self._index, key)

    def _reading(self, read: Any, *args: Any) -> np.ndarray:
        dataset = self._open()
        try:
            return read(*args)
        except (OSError, RuntimeError) as error:  # a chunk that fails its fletcher32 check, a damaged file
            raise StoreIntegrityError(f"{dataset.file.filename}: dataset {self.name} cannot be read: "
                                      f"{os_error_message(error)}; the file is damaged — re-bake it or restore a "
                                      "copy") from None

    def _index(self, key: Any) -> np.ndarray:
        rest: tuple = ()
        if isinstance(key, tuple):
            key, rest = (key[0], key[1:]) if key else (slice(None), ())
        if isinstance(key, (int, np.integer)):
            row = int(key) + (self.shape[0] if int(key) < 0 else 0)
            if not 0 <= row < self.shape[0]:
                raise IndexError(f"{self.name}: row {int(key)} out of range for {self.shape[0]} rows")
            values = _le(self._dataset[row]).reshape(self.shape[1:])  # a 1-D field's row: a scalar, as numpy's
            return values[rest] if rest else values[()]
        values = _le(self._dataset[key] if isinstance(key, slice) else self._rows(key))
        return values[(slice(None), *rest)] if rest else values

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        values = _le(self._reading(_read_rows_lazily, self._dataset))
        return values if dtype is None else values.astype(dtype, copy=False)


def _is_lazy(values: Any) -> bool:
    return isinstance(values, LazyField)


class _DigestedInPassing:
    """A :class:`LazyField` as :func:`probe_checksums` reads it, block after block of rows from the first: its
    dataset digest (:func:`bakery.files.sha256_array`'s: dtype, shape, then the C-order bytes) is fed by those
    blocks as they pass, so verifying a lazily read store reads each large field once."""

    def __init__(self, lazy: LazyField) -> None:
        self.lazy = lazy
        self.dtype, self.shape = lazy.dtype, lazy.shape
        self._digest = sha256_running()
        self._digest.update(json.dumps([lazy.dtype.str, list(lazy.shape)]).encode())
        self._next = 0

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
        values = self.lazy[key]
        if isinstance(key, slice) and key.step in (None, 1) and (key.start or 0) == self._next and len(values):
            self._digest.update(memoryview(np.ascontiguousarray(values)).cast("B"))
            self._next += len(values)
        return values

    def hexdigest(self) -> str:
        """The field's digest; the rest of it read now if the blocks that passed did not cover it."""
        while self._next < self.shape[0]:
            self[self._next : self._next + max(1, _LAZY_READ_BYTES // max(1, self.lazy.nbytes // self.shape[0]))]
        return self._digest.hexdigest()


def version_tuple(version: str) -> tuple[int, int, int]:
    """``"1.2.0"`` → (1, 2, 0); raises :class:`StoreFormatError` for anything else."""
    try:
        parts = [int(p) for p in str(version).split(".")]
    except ValueError:
        raise StoreFormatError(f"unreadable format version {version!r}") from None
    if not 1 <= len(parts) <= 3 or any(p < 0 for p in parts):
        raise StoreFormatError(f"unreadable format version {version!r}")
    return tuple(parts + [0] * (3 - len(parts)))  # type: ignore[return-value]


# ------------------------------------------------------------------------------------------------ checksums
def _le(array: np.ndarray) -> np.ndarray:
    array = np.asarray(array)
    if array.dtype.kind in "fiuc" and array.dtype.byteorder == ">":
        array = array.astype(array.dtype.newbyteorder("<"))
    return np.ascontiguousarray(array)


def _field_prefix(key: str, array: np.ndarray) -> bytes:
    """What precedes a row of field ``key`` in its probe's checksum: name, NUL, the row's dtype and shape."""
    return key.encode() + b"\0" + array.dtype.str.encode() + repr(tuple(array.shape[1:])).encode()


#: Bytes of the row matrix :func:`_update_by_rows` builds at once (a bound on the checksum's temporary memory).
_CHECKSUM_BLOCK_BYTES = 1 << 25


def _update_by_rows(digests: list[Any], index: np.ndarray, header: bytes, keys: list[str],
                    arrays: dict[str, np.ndarray]) -> None:
    """Feed each row of an encoding whose fields all have every row to its probe's digest as one message: the same
    bytes :func:`probe_checksums` feeds field by field, built for a block of rows as one (rows, bytes) uint8 matrix
    of constant prefixes and the rows' little-endian bytes."""
    rows = len(index)
    if rows == 0:
        return
    prefixes = {key: np.frombuffer(_field_prefix(key, arrays[key]), dtype=np.uint8) for key in keys}
    row_bytes = len(header) + sum(prefixes[key].size + arrays[key].dtype.itemsize
                                  * int(np.prod(arrays[key].shape[1:], dtype=np.int64)) for key in keys)
    block = max(1, _CHECKSUM_BLOCK_BYTES // row_bytes)
    header_bytes = np.frombuffer(header, dtype=np.uint8)
    probes = index.tolist()
    for start in range(0, rows, block):
        stop = min(rows, start + block)
        columns = [np.broadcast_to(header_bytes, (stop - start, header_bytes.size))]
        for key in keys:
            columns.append(np.broadcast_to(prefixes[key], (stop - start, prefixes[key].size)))
            columns.append(arrays[key][start:stop].reshape(stop - start, -1).view(np.uint8))
        matrix = np.concatenate(columns, axis=1)
        for row in range(start, stop):
            probe = probes[row]
            if 0 <= probe < len(digests):
                digests[probe].update(matrix[row - start].data)


def probe_checksums(names: list[str], kinds: list[str], positions: np.ndarray, hashes: list[str],
                    bake_ids: np.ndarray, encodings: dict[str, dict[str, Any]]) -> np.ndarray:
    """(P, 32) uint8: per probe, SHA-256 over its identity row (name, kinds, position, content hash, bake id) and,
    for every encoding (by name) that has a row for it, the encoding name and each field's name, dtype, row shape
    and row bytes (fields by name, ``probe_index`` excluded: the row's attribution is the probe it hashes into)."""
    count = len(names)
    positions = _le(np.asarray(positions, dtype=np.float64).reshape(-1, 3))
    bake_ids = _le(np.asarray(bake_ids, dtype=np.int32).reshape(-1))
    # one running digest per probe, fed in the order below (no copy of the rows' bytes is kept: the store's size)
    digests = []
    for i in range(count):
        digest = sha256_running()
        for part in (b"probe\0", names[i].encode(), b"\0", kinds[i].encode(), b"\0", positions[i].tobytes(),
                     hashes[i].encode(), b"\0", bake_ids[i].tobytes()):
            digest.update(part)
        digests.append(digest)
    for name in sorted(encodings):
        fields = encodings[name]["fields"]
        index = np.asarray(fields.get("probe_index", np.zeros(0, dtype=np.int32))).reshape(-1)
        keys = sorted(k for k in fields if k != "probe_index")
        arrays = {k: fields[k] if isinstance(fields[k], (LazyField, _DigestedInPassing)) else _le(fields[k])
                  for k in keys if fields[k] is not None}
        header = b"encoding\0" + name.encode() + b"\0"
        if all(k in arrays and len(arrays[k]) >= len(index) and arrays[k].dtype.kind in "biuf" for k in keys):
            _update_by_rows(digests, index, header, keys, arrays)
            continue
        for row, probe in enumerate(index.tolist()):
            if not 0 <= probe < count:
                continue
            digest = digests[probe]
            digest.update(header)
            for key in keys:
                array = arrays.get(key)
                if array is None or row >= len(array):
                    digest.update(key.encode())
                    digest.update(b"\0<missing>")
                    continue
                value = array[row]
                digest.update(_field_prefix(key, array))
                digest.update(np.ascontiguousarray(value).data)  # the row's bytes, not copied
    out = np.zeros((count, 32), dtype=np.uint8)
    for i, digest in enumerate(digests):
        out[i] = np.frombuffer(digest.digest(), dtype=np.uint8)
    return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return {"__ndarray__": value.tolist(), "dtype": value.dtype.str}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return value


def _attributes_digest(node: h5py.HLObject) -> str:
    values = {k: _jsonable(v) for k, v in node.attrs.items()}
    return sha256_bytes(json.dumps(values, sort_keys=True, default=repr).encode())


def _describe(dataset: h5py.Dataset) -> str:
    return f"{dataset.dtype.str if dataset.dtype.kind != 'O' else 'str'} {tuple(dataset.shape)}"


def _dataset_digest(dataset: h5py.Dataset, values: Any) -> str:
    if dataset.dtype.kind == "O" or h5py.check_string_dtype(dataset.dtype) is not None:
        strings = [v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)
                   for v in np.asarray(values, dtype=object).reshape(-1).tolist()]
        return sha256_bytes(json.dumps([list(dataset.shape), strings]).encode())
    return sha256_array(_le(values))


def _checksum_table(f: h5py.File, written: dict[str, Any] | None = None) -> list[list[str]]:
    """[path, sha256, "dtype shape"] of every dataset and group-attribute set outside ``/checksums``. A dataset in
    ``written`` ({path: values given to HDF5}) is hashed from those values, the others from the file: the reader
    hashes what it reads, so a value HDF5 stored wrongly fails the check instead of being hashed as written."""
    rows: list[list[str]] = [["@/", _attributes_digest(f), "attributes"]]
    written = written or {}

    def visit(name: str, item: Any) -> None:
        if name == _CHECKSUMS or name.startswith(_CHECKSUMS + "/"):
            return
        if isinstance(item, h5py.Dataset):
            values = written.get(item.name)
            rows.append([f"/{name}", _dataset_digest(item, item[()] if values is None else values), _describe(item)])
        elif isinstance(item, h5py.Group) and len(item.attrs):
            rows.append([f"@/{name}", _attributes_digest(item), "attributes"])

    f.visititems(visit)
    return rows


def _write_attributes(node: h5py.HLObject, attributes: dict[str, Any]) -> None:
    for key, value in sorted(attributes.items()):
        if isinstance(value, (dict, list, tuple)) and not isinstance(value, np.ndarray):
            value = json.dumps(value, sort_keys=True)
        node.attrs[key] = value


#: Target bytes of a dataset's chunk. Chunks hold whole rows along axis 0 (the probe axis): reading a probe touches
#: one chunk, and the filters run over contiguous memory (h5py's automatic shapes cut rows across faces and colour
#: channels, which made writing and reading about 1.5× slower and the file about 1.6× larger).
CHUNK_BYTES = 1 << 18


#: gzip level of the larger datasets. After the byte shuffle, level 1 compresses probe data as well as 4 (scale hall:
#: 8.57 vs 8.63 MB) in two thirds of the time (0.33 vs 0.50 s); 6 gains 5 % for twice the time.
GZIP_LEVEL = 1


def _chunk_shape(data: np.ndarray) -> tuple[int, ...] | bool:
    """Chunks of whole rows (axis 0) of about :data:`CHUNK_BYTES` (at least one row); h5py's choice when empty."""
    if data.shape[0] == 0:
        return True
    row_bytes = max(1, data.itemsize * int(np.prod(data.shape[1:], dtype=np.int64)))
    return (max(1, min(data.shape[0], CHUNK_BYTES // row_bytes)), *data.shape[1:])


def _dataset(group: h5py.Group, name: str, data: np.ndarray, written: dict[str, Any] | None = None,
             **kwargs: Any) -> h5py.Dataset:
    """A dataset of fixed-size values: chunked by whole rows (:func:`_chunk_shape`) with the fletcher32 filter
    (gzip + shuffle from 4096 values). ``written`` records {dataset path: the values given} for the checksum
    table."""
    data = np.asarray(data)
    options: dict[str, Any] = {"track_times": False}
    if data.ndim > 0 and data.dtype.kind in "fiubS":
        options.update(chunks=_chunk_shape(data), fletcher32=True)
        if data.dtype.kind in "fiub" and data.size >= 4096:
            options.update(compression="gzip", compression_opts=GZIP_LEVEL, shuffle=True)
    dataset = group.create_dataset(name, data=data, **options, **kwargs)
    if written is not None:
        written[dataset.name] = data
    return dataset


def _strings(group: h5py.Group, name: str, values: list[str], written: dict[str, Any] | None = None,
             ) -> h5py.Dataset:
    """Variable-length UTF-8 strings (HDF5 cannot filter these; covered by ``/checksums``)."""
    data = np.array(values, dtype=object)
    dataset = group.create_dataset(name, data=data, dtype=_STR, track_times=False)
    if written is not None:
        written[dataset.name] = data
    return dataset


def write_store(path: str | os.PathLike[str], contents: StoreContents) -> Path:
    """Write ``contents`` to ``path`` atomically (temp file + fsync + rename). Returns the path."""
    path = Path(path)
    if path.exists() and path.is_dir():
        raise StoreFormatError(f"{path}: is a directory; give a file name for the store")
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise StoreFormatError(f"{path}: output directory {directory} does not exist")
    try:
        with atomic_replace(path) as tmp:
            write_store_file(tmp, contents)
    except OSError as error:
        raise StoreFormatError(f"{path}: cannot write the store: {os_error_message(error)}") from error
    return path


def write_store_file(path: str | os.PathLike[str], contents: StoreContents) -> Path:
    """Write ``contents`` to exactly ``path`` (no rename; fsync'ed): the staged half of a commit that writes the
    store together with other files (:func:`bakery.files.commit_staged`). Raises ``OSError`` on I/O failure.

    The HDF5 file is built in memory and then written with plain file I/O: HDF5 does not survive a write error
    (a full disk leaves its metadata cache inconsistent and the process crashes on close), plain writes fail with
    a clean ``OSError``."""
    path = Path(path)
    image = _file_image(contents)
    try:
        with open(path, "wb") as handle:
            handle.write(image)
            handle.flush()
            os.fsync(handle.fileno())
    except OSError as error:
        path.unlink(missing_ok=True)
        raise with_filename(error, path) from None
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    return path


def _file_image(contents: StoreContents) -> bytes:
    """The bytes of the store file for ``contents``."""
    buffer = io.BytesIO()
    _write_file(buffer, contents)
    return buffer.getvalue()


def _write_file(target: Any, contents: StoreContents) -> None:
    given: dict[str, Any] = {}  # dataset path → the values given to HDF5 (for the checksum table)
    with h5py.File(target, "w", track_order=True, libver=("v110", "v110")) as f:
        _write_attributes(f, {**contents.attributes, "format": FORMAT_NAME, "format_version": FORMAT_VERSION})
        probes = f.create_group("probes")
        probes.attrs["count"] = len(contents.probe_names)
        _strings(probes, "name", list(contents.probe_names), given)
        _strings(probes, "kinds", list(contents.probe_kinds), given)
        positions = np.asarray(contents.probe_positions, dtype=np.float64).reshape(-1, 3)
        _dataset(probes, "position", positions, given)
        count = len(contents.probe_names)
        hashes = list(contents.probe_hashes) if contents.probe_hashes is not None else [""] * count
        _strings(probes, "content_hash", hashes, given)
        bake_ids = np.asarray(contents.probe_bake_ids if contents.probe_bake_ids is not None else np.zeros(count),
                              dtype=np.int32)
        _dataset(probes, "bake_id", bake_ids, given)
        history = f.create_group("history")
        extra = sorted({k for h in contents.history for k in h} - set(HISTORY_COLUMNS))
        for key in (*HISTORY_COLUMNS, *extra):
            _strings(history, key, [str(h.get(key, "")) for h in contents.history], given)
        encodings = f.create_group("encodings")
        for name in sorted(contents.encodings):
            entry = contents.encodings[name]
            group = encodings.create_group(name)
            _write_attributes(group, entry["attributes"])
            # fields by name: the bytes must not depend on whether a fresh batch or a reused store came first
            for field_name, array in sorted(entry["fields"].items()):
                ds = _dataset(group, field_name, array, given)
                description = entry.get("descriptions", {}).get(field_name)
                if description:
                    ds.attrs["description"] = description
            if entry.get("shared"):
                shared = group.create_group("shared")
                for table, array in sorted(entry["shared"].items()):
                    _dataset(shared, table, array, given)
        diagnostics = f.create_group("diagnostics")
        for key in sorted(contents.diagnostics):
            parent, _, leaf = key.rpartition("/")
            target = diagnostics.require_group(parent) if parent else diagnostics
            _dataset(target, leaf, contents.diagnostics[key], given)
        # Integrity: per-probe checksums and the dataset table from the values given (the reader recomputes both
        # the same way from what it reads).
        checksums = f.create_group(_CHECKSUMS)
        written = {name: {"fields": {k: np.asarray(v) for k, v in entry["fields"].items()}}
                   for name, entry in contents.encodings.items()}
        _dataset(checksums, "probe", probe_checksums(list(contents.probe_names), list(contents.probe_kinds),
                                                     positions, hashes, bake_ids, written))
        table = _checksum_table(f, given)
        checksums.create_dataset("datasets", data=np.array(table, dtype=object).reshape(-1, 3), dtype=_STR,
                                 track_times=False)
        f.flush()


def _read_attributes(node: h5py.HLObject) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in node.attrs.items():
        if isinstance(value, bytes):
            value = value.decode()
        elif isinstance(value, np.generic):
            value = value.item()
        out[key] = value
    return out


#: What h5py raises for a damaged file: OSError for most damage, but KeyError ("Unable to synchronously open object")
#: or RuntimeError ("Error iterating over attributes") when a metadata checksum fails (a flipped byte in an object
#: header, a zeroed tail)
_DAMAGED = (OSError, RuntimeError, KeyError)


def overwrite_refusal(path: str | os.PathLike[str]) -> str | None:
    """Why an existing file at ``path`` must not be replaced by a new store (None: it is a bakery store of a
    format version this bakery reads and writes, i.e. a previous output). Used by the output policy."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            signature = handle.read(8)
    except OSError as error:
        return f"exists and cannot be read ({os_error_message(error)})"
    if signature != b"\x89HDF\r\n\x1a\n":
        return "exists and is not an HDF5 file (not a bakery store)"
    try:
        with h5py.File(path, "r") as f:
            attributes = _read_attributes(f)
    except _DAMAGED:
        return "exists and is not a readable HDF5 file (truncated or corrupt?)"
    if attributes.get("format") != FORMAT_NAME:
        return "exists and is an HDF5 file but not a bakery probe store"
    version = str(attributes.get("format_version", ""))
    try:
        newer = version_tuple(version) > version_tuple(FORMAT_VERSION)
    except StoreFormatError:
        return f"is a bakery store with an unreadable format version {version!r}"
    if newer:
        return (f"is a bakery store of format {version}, newer than this bakery writes ({FORMAT_VERSION}); "
                "replacing it would lose data (upgrade bakery)")
    return None


def _integrity_error(path: Path, integrity: StoreIntegrity) -> StoreIntegrityError:
    shown = "; ".join(integrity.problems[:4]) + (f"; … ({len(integrity.problems)} findings)"
                                                 if len(integrity.problems) > 4 else "")
    return StoreIntegrityError(f"{path}: failed its integrity check: {shown}. The file is damaged or was edited "
                               "outside bakery; re-bake it (bakery bake re-computes the affected probes) or restore "
                               "a copy")


def read_store(path: str | os.PathLike[str], load_fields: bool = True, *, strict: bool = True,
               lazy_fields: bool = False) -> StoreContents:
    """Read a store and verify its checksums (module docstring).

    ``lazy_fields``: the large numeric fields (≥ :data:`~bakery.zero_pages.MIN_BYTES`) are :class:`LazyField` objects
    that read their rows from the file when indexed, the file kept open (``StoreContents.file``; close it with
    :meth:`StoreContents.close`). They are verified as the eager reader verifies them — the per-probe and
    per-dataset checksums, by one pass over each field in blocks of rows — so what is read later is what was
    verified (the open handle keeps reading the verified file even if another is renamed over its path).

    Raises :class:`StoreFormatError` for a missing, corrupt, foreign or newer-major file, and (``strict``)
    :class:`StoreIntegrityError` naming the datasets that fail their checksums. With ``strict=False`` the findings
    are returned in ``integrity`` (a dataset that cannot be read at all is then treated as damaged, not raised).

    The structure the reader relies on is checked first (``/probes`` and ``/encodings`` are groups holding datasets,
    …: :class:`StoreFormatError` naming the node otherwise); ``strict`` also checks the layout of every encoding
    (:func:`check_encoding_layout`)."""
    path = store_path(path)
    if path.is_dir():
        raise StoreFormatError(f"{path}: is a directory, not a store file")
    if not path.is_file():
        raise StoreFormatError(f"{path}: store not found" if not path.exists() else
                               f"{path}: is not a regular file (not a store)")
    try:
        f = h5py.File(path, "r")
    except _DAMAGED as error:
        raise StoreFormatError(f"{path}: not a readable HDF5 file (truncated or corrupt?): "
                               f"{os_error_message(error)}") from error
    integrity = StoreIntegrity()
    unreadable: dict[str, str] = {}

    def value(item: h5py.Dataset, rows_lazily: bool = False) -> Any:
        """The dataset's values; a read failure (fletcher32 mismatch, damaged chunk) is recorded, not raised.
        ``rows_lazily``: a large numeric dataset is read by blocks of rows, its all-zero rows left unwritten in a
        :func:`~bakery.zero_pages.lazy_zeros` array (the same values; those rows take no memory), or with
        ``lazy_fields`` not read (a :class:`LazyField`)."""
        try:
            if rows_lazily and lazy_fields and _large_numeric(item):
                return LazyField(item)
            if rows_lazily:
                return _read_rows_lazily(item)
            return item[()]
        except (OSError, RuntimeError, ValueError) as error:
            unreadable[item.name] = os_error_message(error)
            if strict:
                raise StoreIntegrityError(f"{path}: dataset {item.name} cannot be read: {unreadable[item.name]}; "
                                          "the file is damaged — re-bake it or restore a copy") from None
            return None

    keep_open = False
    try:
        try:
            attributes = _read_attributes(f)
        except _DAMAGED as error:
            raise StoreFormatError(f"{path}: store is corrupt (its root attributes cannot be read: "
                                   f"{os_error_message(error)}); restore a copy or re-bake it") from None
        if attributes.get("format") != FORMAT_NAME:
            raise StoreFormatError(f"{path}: not a bakery probe store (format attribute {attributes.get('format')!r})")
        version = str(attributes.get("format_version", ""))
        try:
            parsed = version_tuple(version)
        except StoreFormatError as error:
            raise StoreFormatError(f"{path}: {error}") from None
        if parsed[0] > version_tuple(FORMAT_VERSION)[0]:
            raise StoreFormatError(
                f"{path}: store format {version} is newer than this bakery reads ({FORMAT_VERSION}); "
                f"upgrade bakery to read it"
            )

        def strings(item: h5py.Dataset) -> list[str]:
            values = value(item)
            return [] if values is None else [v.decode() if isinstance(v, bytes) else str(v)
                                              for v in np.asarray(values, dtype=object).reshape(-1).tolist()]

        try:
            _check_structure(path, f)
            names = strings(f["probes/name"])
            kinds = strings(f["probes/kinds"])
            positions = value(f["probes/position"])
            count = len(names)
            if positions is None:
                positions = np.full((count, 3), np.nan)
            encodings: dict[str, dict[str, Any]] = {}
            for name, group in f["encodings"].items():
                entry: dict[str, Any] = {"attributes": _read_attributes(group), "fields": {}, "shared": {},
                                         "descriptions": {}}
                for key, item in group.items():
                    if isinstance(item, h5py.Dataset):
                        entry["fields"][key] = value(item, rows_lazily=True) if load_fields else None
                        if "description" in item.attrs:
                            entry["descriptions"][key] = str(item.attrs["description"])
                if "shared" in group:
                    entry["shared"] = {k: value(v) for k, v in group["shared"].items()}
                encodings[name] = entry
            if "content_hash" in f["probes"]:
                hashes = strings(f["probes/content_hash"])
                bake_ids = value(f["probes/bake_id"])
                if bake_ids is None:
                    bake_ids = np.zeros(count, dtype=np.int32)
            else:
                hashes, bake_ids = [""] * count, np.zeros(count, dtype=np.int32)
            history: list[dict[str, str]] = []
            if "history" in f:
                columns = {k: strings(f["history"][k]) for k in f["history"]}
                history = [{k: columns[k][i] if i < len(columns[k]) else "" for k in columns}
                           for i in range(max((len(c) for c in columns.values()), default=0))]
            elif "bake_time_utc" in attributes:
                history = [{"time_utc": str(attributes["bake_time_utc"]),
                            "bakery_version": str(attributes.get("bakery_version", "")),
                            "settings_hash": str(attributes.get("settings_hash", "")), "layers": ""}]
            diagnostics: dict[str, np.ndarray] = {}
            if "diagnostics" in f:
                def visit(name: str, item: Any) -> None:
                    if isinstance(item, h5py.Dataset):
                        values = value(item)
                        if values is not None:
                            diagnostics[name] = values

                f["diagnostics"].visititems(visit)
            if parsed >= version_tuple(CHECKSUM_VERSION):
                _verify(f, integrity, unreadable, names, kinds, positions, hashes, bake_ids, encodings, load_fields)
            elif unreadable:
                integrity.problems += [f"dataset {k} cannot be read: {v}" for k, v in sorted(unreadable.items())]
                integrity.whole_store = True
        except KeyError as error:
            raise StoreFormatError(f"{path}: store is missing required data or is corrupt: {error}") from error
        except (OSError, RuntimeError) as error:
            raise StoreFormatError(f"{path}: store is corrupt: {os_error_message(error)}") from error
        except (AttributeError, TypeError, ValueError) as error:  # a node of an unexpected type or shape
            raise StoreFormatError(f"{path}: store is malformed ({type(error).__name__}: {error}); the file was not "
                                   "written by bakery or is corrupt") from None
        keep_open = lazy_fields and any(_is_lazy(v) for e in encodings.values() for v in e["fields"].values())
    finally:
        if not keep_open:
            f.close()
    try:
        return _checked_contents(path, strict, load_fields, attributes, names, kinds, positions, encodings,
                                 diagnostics, hashes, bake_ids, history, integrity, f if keep_open else None)
    except BaseException:
        if keep_open:
            f.close()
        raise


def _checked_contents(path: Path, strict: bool, load_fields: bool, attributes: dict[str, Any], names: list[str],
                      kinds: list[str], positions: Any, encodings: dict[str, dict[str, Any]],
                      diagnostics: dict[str, np.ndarray], hashes: list[str], bake_ids: Any,
                      history: list[dict[str, str]], integrity: StoreIntegrity, file: Any) -> StoreContents:
    """:func:`read_store`'s last checks, once the file is read: the /probes datasets' lengths, the integrity
    findings (``strict``: raised) and the encodings' layout."""
    count = len(names)
    if len(hashes) != count or len(kinds) != count or np.shape(positions) != (count, 3) \
            or np.shape(bake_ids) != (count,):
        if strict or not integrity.problems:
            raise StoreFormatError(f"{path}: store is corrupt: /probes datasets disagree on the number of probes")
        integrity.whole_store = True
        hashes = (list(hashes) + [""] * count)[:count]
        bake_ids = np.zeros(count, dtype=np.int32)
        positions = np.zeros((count, 3))
        kinds = (list(kinds) + [""] * count)[:count]
    if strict and integrity.problems:
        raise _integrity_error(path, integrity)
    if strict and load_fields:
        check_encoding_layout(path, encodings, count)
    return StoreContents(attributes, names, kinds, np.asarray(positions), encodings, diagnostics, hashes,
                         np.asarray(bake_ids, dtype=np.int32), history, integrity, file)


#: Rows read at once by :func:`_read_rows_lazily` (bytes, rounded to whole chunks).
_LAZY_READ_BYTES = 1 << 25


def _large_numeric(dataset: h5py.Dataset) -> bool:
    """A numeric dataset of rows of at least :data:`~bakery.zero_pages.MIN_BYTES` (read by rows, or lazily)."""
    return (dataset.ndim > 0 and dataset.dtype.kind in "biufc" and dataset.shape[0] > 0
            and dataset.size * dataset.dtype.itemsize >= MIN_BYTES)


def _read_rows_lazily(dataset: h5py.Dataset) -> np.ndarray:
    """``dataset[()]``, read in blocks of whole chunks of rows into a :func:`~bakery.zero_pages.lazy_zeros` array
    where only the rows with a non-zero byte are written (a numeric dataset of at least
    :data:`~bakery.zero_pages.MIN_BYTES`; others are read whole)."""
    if not _large_numeric(dataset):
        return dataset[()]
    count = dataset.shape[0]
    row_bytes = max(1, dataset.size // count * dataset.dtype.itemsize)
    chunk_rows = dataset.chunks[0] if dataset.chunks else 1
    block = max(chunk_rows, _LAZY_READ_BYTES // row_bytes // chunk_rows * chunk_rows)
    out = lazy_zeros(dataset.shape, dataset.dtype)
    for start in range(0, count, block):
        values = dataset[start : start + block]
        keep = nonzero_rows(values)
        if keep.all():
            out[start : start + len(values)] = values
        elif keep.any():
            out[start : start + len(values)][keep] = values[keep]
    return out


def failed_probes(attributes: dict[str, Any]) -> dict[str, str]:
    """{probe: reason} of the root attribute ``failed_probes`` (JSON object; probes a bake could not store, absent
    from the store); {} when absent or empty. A value that is not a JSON object is returned as one entry rather than
    dropped: the store says probes failed, even if it cannot say which."""
    raw = attributes.get("failed_probes")
    if raw is None or raw == "":
        return {}
    try:
        value = json.loads(raw) if isinstance(raw, str) else None
    except ValueError:
        value = None
    if not isinstance(value, dict):
        return {"(unreadable failed_probes attribute)": str(raw)[:200]}
    return {str(k): str(v) for k, v in value.items()}


def store_path(path: Any) -> Path:
    """``path`` as a Path, or :class:`~bakery.errors.ArgumentError` naming the argument when it is not a file path
    (None, a number, …)."""
    try:
        text = os.fspath(path)
    except TypeError:
        text = None
    if not isinstance(text, str) or not text:
        raise ArgumentError(f"store path must be a file name (str or os.PathLike), got {path!r} "
                            f"({type(path).__name__})")
    return Path(text)


#: Datasets of ``/probes`` every version has.
_PROBE_DATASETS = ("name", "kinds", "position")


def _check_structure(path: Path, f: h5py.File) -> None:
    """The node types :func:`read_store` relies on (a crafted or damaged file may have a dataset where a group
    belongs, …): :class:`StoreFormatError` naming the node otherwise."""

    def need(node: Any, where: str, kind: type, required: bool = True) -> None:
        if node is None:
            if required:
                raise StoreFormatError(f"{path}: {where} is missing (a bakery store always has it)")
            return
        if not isinstance(node, kind):
            found = "a group" if isinstance(node, h5py.Group) else "a dataset" if isinstance(node, h5py.Dataset) \
                else type(node).__name__
            expected = "a group" if kind is h5py.Group else "a dataset"
            raise StoreFormatError(f"{path}: {where} is {found}, expected {expected}; the file was not written by "
                                   "bakery or is corrupt")

    def child(group: h5py.Group, name: str) -> Any:
        return group.get(name) if name in group else None

    need(child(f, "probes"), "/probes", h5py.Group)
    probes = f["probes"]
    for name in _PROBE_DATASETS:
        need(child(probes, name), f"/probes/{name}", h5py.Dataset)
    if "content_hash" in probes:
        need(child(probes, "content_hash"), "/probes/content_hash", h5py.Dataset)
        need(child(probes, "bake_id"), "/probes/bake_id", h5py.Dataset)
    need(child(f, "encodings"), "/encodings", h5py.Group)
    for name, group in f["encodings"].items():
        need(group, f"/encodings/{name}", h5py.Group)
        if "shared" in group:
            need(child(group, "shared"), f"/encodings/{name}/shared", h5py.Group)
            for table, item in group["shared"].items():
                need(item, f"/encodings/{name}/shared/{table}", h5py.Dataset)
    for name in ("history", "diagnostics"):
        need(child(f, name), f"/{name}", h5py.Group, required=False)
    if "history" in f:
        for column, item in f["history"].items():
            need(item, f"/history/{column}", h5py.Dataset)


def check_encoding_layout(path: str | os.PathLike[str], encodings: dict[str, dict[str, Any]], count: int) -> None:
    """Every encoding has ``probe_index`` (P_k,) of distinct integers in [0, P) and every other field has P_k rows
    (``schemas/store-v1.md``, ``/encodings/<name>``); :class:`StoreFormatError` naming the dataset otherwise. Read
    with ``strict`` (the stores a user reads: ``inspect``, ``diff``, ``report``, the API)."""
    for name, entry in encodings.items():
        where = f"/encodings/{name}"
        fields = entry["fields"]
        if fields.get("probe_index") is None:
            raise StoreFormatError(f"{path}: dataset {where}/probe_index is missing (every encoding has one)")
        index = np.asarray(fields["probe_index"])
        if index.ndim != 1 or index.dtype.kind not in "iu":
            raise StoreFormatError(f"{path}: dataset {where}/probe_index is {_array_description(index)}, expected "
                                   "(P_k,) integers")
        outside = (index < 0) | (index >= count)
        if np.any(outside):
            raise StoreFormatError(f"{path}: dataset {where}/probe_index refers to probe {int(index[outside][0])}, "
                                   f"the store has {count} probes (0 … {count - 1})")
        unique, counts = np.unique(index, return_counts=True)
        if np.any(counts > 1):
            raise StoreFormatError(f"{path}: dataset {where}/probe_index lists probe {int(unique[counts > 1][0])} "
                                   f"{int(counts[counts > 1][0])} times")
        for key, values in fields.items():
            if key == "probe_index" or values is None:
                continue
            array = values if _is_lazy(values) else np.asarray(values)
            if array.ndim == 0 or array.shape[0] != index.size:
                raise StoreFormatError(f"{path}: dataset {where}/{key} is {_array_description(array)}, expected "
                                       f"{index.size} rows (one per entry of {where}/probe_index)")


def _array_description(array: np.ndarray) -> str:
    kind = "str" if array.dtype.kind in "OSU" else str(array.dtype)
    return f"{kind} of shape {tuple(array.shape)}"


def _verify(f: h5py.File, integrity: StoreIntegrity, unreadable: dict[str, str], names: list[str], kinds: list[str],
            positions: np.ndarray, hashes: list[str], bake_ids: np.ndarray, encodings: dict[str, dict[str, Any]],
            load_fields: bool) -> None:
    """Check ``/checksums`` against what was read (module docstring); findings go into ``integrity``. A
    :class:`LazyField` is hashed as the per-probe checksums read it (:class:`_DigestedInPassing`)."""
    integrity.verified = True
    problems = integrity.problems
    field_paths = {f"/encodings/{e}/{k}": e for e, entry in encodings.items() for k in entry["fields"]}
    if _CHECKSUMS not in f or "probe" not in f[_CHECKSUMS] or "datasets" not in f[_CHECKSUMS]:
        problems.append("/checksums is missing (a 1.2 store always has it)")
        integrity.whole_store = True
        return
    mismatched: dict[str, str] = {}  # field dataset path → encoding (localized by the per-probe checksums)
    for path, reason in sorted(unreadable.items()):
        problems.append(f"dataset {path} cannot be read: {reason}")
        if path not in field_paths:
            integrity.whole_store = True
    try:
        table = np.asarray(f[_CHECKSUMS]["datasets"][()], dtype=object).reshape(-1, 3)
        stored = np.asarray(f[_CHECKSUMS]["probe"][()])
    except (OSError, ValueError) as error:
        problems.append(f"/checksums cannot be read: {os_error_message(error)}")
        integrity.whole_store = True
        return

    def mismatch(item: h5py.Dataset, path: str, description: str, values: Any) -> None:
        actual = _describe(item)
        detail = f"is {actual}, written as {description}" if actual != description else "holds other values"
        if values is not None and item.dtype.kind == "f" and not np.all(np.isfinite(values)):
            detail += f", {int(np.sum(~np.isfinite(values)))} of them non-finite"
        problems.append(f"dataset {path} does not match its checksum ({detail})")
        if path.startswith("/encodings/") and path.count("/") == 3:
            mismatched[path] = path.split("/")[2]
        else:
            integrity.whole_store = True

    # lazy fields: {path: (the digest written, its description, the field as the per-probe pass reads it)}
    passing: dict[str, tuple[str, str, _DigestedInPassing]] = {}
    listed = set()
    for row in table.tolist():
        path, digest, description = (v.decode() if isinstance(v, bytes) else str(v) for v in row)
        listed.add(path)
        if path in unreadable:
            continue
        if path.startswith("@"):
            node_path = path[1:]
            if node_path not in f:
                problems.append(f"group {node_path} is missing")
                integrity.whole_store = True
            elif _attributes_digest(f[node_path]) != digest:
                problems.append(f"the attributes of {node_path} do not match their checksum")
                integrity.whole_store = True
            continue
        is_field = path.startswith("/encodings/") and path.count("/") == 3
        if path not in f or not isinstance(f[path], h5py.Dataset):
            problems.append(f"dataset {path} ({description}) is missing")
            if is_field:
                mismatched[path] = path.split("/")[2]
            else:
                integrity.whole_store = True
            continue
        if is_field and not load_fields:
            continue
        item = f[path]
        # a field's values as read_store read them (not a second read of the largest datasets: the store's size
        # again in time and, for one dataset at a time, in memory)
        values = None
        if is_field:
            _, _, encoding, key = path.split("/")
            values = encodings[encoding]["fields"].get(key)
            if _is_lazy(values):
                passing[path] = (digest, description, _DigestedInPassing(values))
                continue
        if values is None:
            values = item[()]
        if _dataset_digest(item, values) != digest:
            mismatch(item, path, description, values)
    for path, encoding in field_paths.items():
        if path not in listed:
            problems.append(f"dataset {path} was not written by bakery")
            mismatched[path] = encoding
    if not load_fields:
        if mismatched:
            integrity.whole_store = True
        return
    count = len(names)
    hashed = {name: {**entry, "fields": {k: passing[f"/encodings/{name}/{k}"][2] if f"/encodings/{name}/{k}" in
                                         passing else v for k, v in entry["fields"].items()}}
              for name, entry in encodings.items()}
    try:
        computed = probe_checksums(names, kinds, positions, hashes, bake_ids, hashed)
    except (ValueError, TypeError) as error:
        problems.append(f"per-probe checksums cannot be computed: {error}")
        integrity.whole_store = True
        return
    for path, (digest, description, field_) in passing.items():
        if field_.hexdigest() != digest:
            mismatch(f[path], path, description, None)
    if stored.shape != (count, 32):
        problems.append(f"dataset /checksums/probe has shape {stored.shape}, expected ({count}, 32)")
        integrity.whole_store = True
        return
    bad = np.flatnonzero(np.any(computed != stored, axis=1))
    integrity.bad_probes = {names[i] for i in bad.tolist()}
    if integrity.bad_probes:
        shown = ", ".join(sorted(integrity.bad_probes)[:5]) + (" …" if len(bad) > 5 else "")
        problems.append(f"{len(bad)} probe(s) do not match /checksums/probe: {shown}")
    elif mismatched:
        integrity.whole_store = True  # a field changed where no probe's checksum can see it (unattributed rows)


#: What each upgrade adds (:func:`migrate_store`).
MIGRATION_STEPS = {
    "1.0.0": "add /probes/content_hash, /probes/bake_id, /history",
    "1.1.0": "add fletcher32 filters and /checksums (per-probe and per-dataset SHA-256)",
}


def migrate_store(source: str | os.PathLike[str], target: str | os.PathLike[str] | None = None,
                  dry_run: bool = False) -> list[str]:
    """Upgrade a store to :data:`FORMAT_VERSION` (atomically, in place unless ``target``). Returns the steps taken.

    1.0.0 → 1.1.0: adds ``/probes/content_hash`` (empty: the probes will be re-baked on the next incremental bake),
    ``/probes/bake_id`` (0) and ``/history`` with one entry from the root attributes.
    1.1.0 → 1.2.0: rewrites every dataset with the fletcher32 filter and adds ``/checksums`` (of the values as they
    are: a 1.1 store has nothing to verify them against).

    A store that fails its integrity check, or of a newer format, is refused (:class:`StoreFormatError`). The
    caller applies the output policy to ``target`` (``bakery migrate -o``).
    """
    contents = read_store(source)
    version = str(contents.attributes.get("format_version"))
    if version_tuple(version) > version_tuple(FORMAT_VERSION):
        raise StoreFormatError(f"{source}: store format {version} is newer than this bakery writes "
                               f"({FORMAT_VERSION}); nothing to migrate")
    if version_tuple(version) == version_tuple(FORMAT_VERSION):
        if target is not None and Path(target).resolve() != Path(source).resolve() and not dry_run:
            write_store(target, contents)
        return []
    steps = []
    for step_from, what in MIGRATION_STEPS.items():
        if version_tuple(version) <= version_tuple(step_from):
            steps.append(what)
    steps = [f"{version} -> {FORMAT_VERSION}: " + "; ".join(steps)]
    if not dry_run:
        write_store(target or source, contents)
    return steps
