"""Arrays whose all-zero rows take no memory: a fixed-layout field stores zero where a probe has no value (the
hybrid's levels below its ``first_level``, skipped gap levels: most of a 128² chain for most probes), and a parent
that holds every probe's fields (the merge of a bake, the reading of a store) would otherwise hold those zeros too.

:func:`lazy_zeros` allocates from a private anonymous memory map: the kernel backs a page only once it is written
(reading an unwritten page maps the kernel's zero page, which is not counted in the process's resident memory;
a shared anonymous map, Python's ``mmap`` default, would be: its pages are shmem).
:func:`without_resident_zeros` copies an array into such a map row by row, skipping the rows whose bytes are all
zero; the values, bytes included (−0.0 and NaN payloads are not zero bytes), are unchanged. Arrays below
:data:`MIN_BYTES` are left alone (the map's page rounding and the row test would cost more than they save).
"""

from __future__ import annotations

import mmap

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


def without_resident_zeros(array: np.ndarray) -> np.ndarray:
    """``array`` with its all-zero rows not resident (:func:`lazy_zeros`, the other rows copied), when it is a numeric
    array of at least :data:`MIN_BYTES` with such a row; otherwise ``array`` itself."""
    array = np.asarray(array)
    if array.ndim == 0 or array.dtype.kind not in "biufc" or array.nbytes < MIN_BYTES:
        return array
    keep = nonzero_rows(array)
    if keep.all():
        return array
    out = lazy_zeros(array.shape, array.dtype)
    for row in np.flatnonzero(keep).tolist():
        out[row] = array[row]
    return out
