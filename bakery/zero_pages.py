"""Arrays whose all-zero rows take no memory: a fixed-layout field stores zero where a probe has no value (the
hybrid's levels below its ``first_level``, skipped gap levels: most of a 128² chain for most probes), and a parent
that holds every probe's fields (the merge of a bake, the reading of a store) would otherwise hold those zeros too.

:func:`lazy_zeros` allocates from a private anonymous memory map: the kernel backs a page only once it is written
(reading an unwritten page maps the kernel's zero page, which is not counted in the process's resident memory;
a shared anonymous map, Python's ``mmap`` default, would be: its pages are shmem).
:func:`without_resident_zeros` copies an array into such a map row by row, skipping the rows whose bytes are all
zero; the values, bytes included (−0.0 and NaN payloads are not zero bytes), are unchanged. Arrays below
:data:`MIN_BYTES` are left alone (the map's page rounding and the row test would cost more than they save).

:func:`spilled` and :class:`SparseRows` do the same in a sparse file (a bake's parent, in its work folder): the rows
are written through the file and mapped copy-on-write, so they are page cache the kernel may reclaim under memory
pressure, not anonymous memory, and the zero rows are holes. The parent of a bake holds every probe's fields until
the store is written; there, they no longer have to fit in memory. :func:`discard` removes such a file.
"""

from __future__ import annotations

import mmap
import os
from pathlib import Path

import numpy as np

#: Arrays smaller than this stay ordinary arrays.
MIN_BYTES = 1 << 22


def lazy_zeros(shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
    """np.zeros(shape, dtype) backed by an anonymous memory map (pages resident only once written); writable, C
    order. The map is released with the last array that views it."""
    dtype = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64))
    nbytes = count * dtype.itemsize
    if nbytes == 0 or not hasattr(mmap, "MAP_PRIVATE"):  # Windows: calloc'ed zeros are committed lazily there too
        return np.zeros(shape, dtype)
    # private: a shared anonymous map (Python's default) is shmem, whose pages become resident on reading
    pages = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    return np.frombuffer(pages, dtype=dtype, count=count).reshape(shape)


def nonzero_rows(array: np.ndarray) -> np.ndarray:
    """(P,) bool: rows (axis 0) of ``array`` with any non-zero byte."""
    rows = np.ascontiguousarray(array).reshape(len(array), -1)
    return rows.view(np.uint8).any(axis=1) if rows.shape[1] else np.zeros(len(array), dtype=bool)


def _large(array: np.ndarray) -> bool:
    """A numeric array of rows of at least :data:`MIN_BYTES`."""
    return array.ndim > 0 and array.dtype.kind in "biufc" and array.nbytes >= MIN_BYTES


def without_resident_zeros(array: np.ndarray) -> np.ndarray:
    """``array`` with its all-zero rows not resident (:func:`lazy_zeros`, the other rows copied), when it is a numeric
    array of at least :data:`MIN_BYTES` with such a row; otherwise ``array`` itself."""
    array = np.asarray(array)
    if not _large(array):
        return array
    keep = nonzero_rows(array)
    if keep.all():
        return array
    out = lazy_zeros(array.shape, array.dtype)
    for row in np.flatnonzero(keep).tolist():
        out[row] = array[row]
    return out


class SparseRows:
    """A new sparse file at ``path`` for an array of ``shape`` and ``dtype``, written a row at a time through the
    file (:meth:`write`: a full disk is an ``OSError`` there, never a SIGBUS at a later page fault of a shared map),
    then mapped copy-on-write (:meth:`mapped`): what is read is the file's page cache, which the kernel may reclaim,
    not the process's memory; the rows never written are holes and read as zeros; a write into the map stays in the
    process (private pages). The caller removes the file (:func:`discard`)."""

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype | type, path: Path) -> None:
        self.shape, self.dtype, self.path = tuple(shape), np.dtype(dtype), Path(path)
        self.row_bytes = int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize
        self.nbytes = self.row_bytes * (self.shape[0] if self.shape else 1)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "xb")  # a new file of its own: never another's  # noqa: SIM115
        try:
            self._file.truncate(self.nbytes)
        except BaseException:
            self.close()
            raise

    def write(self, row: int, values: np.ndarray) -> None:
        """Row ``row`` ← ``values`` (of the row's shape; cast to the file's dtype)."""
        data = np.ascontiguousarray(values, dtype=self.dtype)
        self._file.seek(row * self.row_bytes)
        self._file.write(memoryview(data).cast("B"))

    def close(self) -> None:
        self._file.close()

    def mapped(self) -> np.ndarray:
        """The file's values, mapped copy-on-write (``np.memmap`` mode ``c``)."""
        self._file.close()
        if self.nbytes == 0:
            return np.zeros(self.shape, self.dtype)
        return np.memmap(self.path, dtype=self.dtype, mode="c", shape=self.shape)


def spilled(array: np.ndarray, path: Path) -> np.ndarray:
    """``array`` in a sparse file at ``path`` (:class:`SparseRows`: its rows with a non-zero byte written, mapped),
    when it is a numeric array of at least :data:`MIN_BYTES`; otherwise ``array`` itself."""
    array = np.asarray(array)
    if not _large(array):
        return array
    rows = SparseRows(array.shape, array.dtype, path)
    try:
        for row in np.flatnonzero(nonzero_rows(array)).tolist():
            rows.write(row, array[row])
    finally:
        rows.close()
    return rows.mapped()


def discard(array: np.ndarray, folder: Path) -> None:
    """Remove the file of a :class:`SparseRows` array in ``folder`` (its map stays readable until the array is
    dropped, as POSIX keeps an unlinked file's pages); nothing for other arrays, mapped files elsewhere included."""
    if not (isinstance(array, np.memmap) and array.filename):
        return
    if Path(array.filename).parent == Path(os.path.abspath(folder)):  # np.memmap keeps the absolute path
        try:
            os.unlink(array.filename)
        except FileNotFoundError:
            pass
