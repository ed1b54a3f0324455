"""File helpers with one home: atomic replacement and content hashes.

Atomic replacement
    ``with atomic_replace(path) as tmp:`` yields a temporary path beside ``path`` (same folder, so the rename is
    atomic on POSIX file systems). The caller writes ``tmp``; on a normal exit the file is fsync'ed and renamed over
    ``path``; on an exception the temporary file is removed and ``path`` is untouched. A crash (SIGKILL) at any
    moment leaves either the old or the new file, never a partial one.

Hashes
    ``sha256_file`` (streamed), ``sha256_bytes`` and ``stable_hash`` (sha256 of the canonical JSON of plain data,
    numpy arrays by their bytes, shape and dtype) are the only hashers; content hashes of probes, batches, scenes
    and cached operators are built from them.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


@contextmanager
def atomic_replace(path: str | os.PathLike[str], suffix: str = "") -> Iterator[Path]:
    """Temporary path beside ``path``, renamed over it on success (fsync'ed first); removed on failure.

    ``suffix`` is appended to the temporary name (writers that choose a format by extension, e.g. USD's
    ``.usda``, need it)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}{suffix}")
    try:
        yield tmp
        if tmp.exists():
            with open(tmp, "rb+") as handle:
                os.fsync(handle.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_replace`)."""
    path = Path(path)
    with atomic_replace(path) as tmp:
        tmp.write_bytes(data)
    return path


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike[str]) -> str:
    """sha256 hex of a file's bytes, streamed in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _canonical(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        return {"__ndarray__": sha256_bytes(array.tobytes()), "shape": list(array.shape), "dtype": array.dtype.str}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if hasattr(value, "__dataclass_fields__"):
        return {"__dataclass__": type(value).__name__,
                **{name: _canonical(getattr(value, name)) for name in value.__dataclass_fields__}}
    return value


def stable_hash(*parts: Any) -> str:
    """sha256 hex of the canonical JSON of ``parts`` (dicts sorted by key; arrays by content, shape and dtype;
    dataclasses by their fields)."""
    return sha256_bytes(json.dumps(_canonical(parts), sort_keys=True, default=str).encode())
