"""On-disk cache of environment-independent operators (the SH-exponential fit's W blocks, 4096 × 1536 and
12288 × 384 float32 = 44 MB at default settings, ≈ 1–2 s to build; the DFG/Fresnel-tail quadrature, ≈ 4 s),
memory-mapped so that every worker process of a bake — and every later bake on the machine — shares one physical
copy instead of rebuilding it per process.

Location: ``$BAKERY_CACHE_DIR`` or ``~/.cache/bakery/operators``. Files are named
``<key digest>.<content sha256>.npy``: the sha256 of the operator's key (which encodes every setting it depends
on and its formulation version) and bakery's version, then the SHA-256 of the array (dtype, shape, bytes). They
are written atomically (temp file + rename) so concurrent workers never read a partial file.

Sparse operators (the split-sum prefilter's kernel operators, :mod:`bakery.reflection.prefilter_operator`, 2–60 MB
each) are stored as four such arrays — ``<key>#shape`` (rows, cols, nnz), ``#indptr``, ``#indices`` (int32) and
``#data`` (float32) — by :func:`save_sparse`; :func:`load_sparse` returns None (rebuild) unless all four are present,
verified and consistent, and then a CSR matrix over the memory-mapped arrays (no copy).

Integrity: :func:`load` re-hashes the memory-mapped array and compares it with its name. A file that does not
match (a damaged disk, a poisoned cache: valid header, altered values) is removed with a
:class:`OperatorCacheWarning` and the operator is rebuilt — a cached operator is never used unverified. Temporary
files of killed writers are removed on the next save. Delete the folder to clear it; set ``BAKERY_CACHE_DIR=off``
to keep operators in memory only.

Size: the folder is kept under ``$BAKERY_CACHE_MAX_MB`` (default 4096; ``0`` = no limit). Every save that takes
it over removes the least recently used cache files (a verified load marks its file used) until it fits, never
the file just written, and only files this module names (``<32 hex>.<64 hex>.npy``, and the ``<32 hex>.npy`` of
earlier versions, which are never read) — a folder shared with other files loses none of them. Settings,
formulation versions and bakery versions that are no longer used would otherwise accumulate forever. A worker
that has a removed file mapped keeps reading it (POSIX unlink semantics); the next process rebuilds it.
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np

import bakery
from bakery.errors import BakeryWarning
from bakery.files import atomic_replace, pid_alive, sha256_array, sha256_bytes


class OperatorCacheWarning(BakeryWarning):
    """A cached operator failed its checksum and was rebuilt."""


def cache_directory() -> Path | None:
    configured = os.environ.get("BAKERY_CACHE_DIR")
    if configured and configured.lower() == "off":
        return None
    return Path(configured) if configured else Path.home() / ".cache" / "bakery" / "operators"


#: Default size limit of the cache folder in MB (``BAKERY_CACHE_MAX_MB``; module doc "Size").
DEFAULT_MAX_MB = 4096
#: The files this module writes (and those of earlier versions, named without the content hash).
_CACHE_FILE = re.compile(r"^[0-9a-f]{32}(\.[0-9a-f]{64})?\.npy$")


def cache_limit_bytes() -> int | None:
    """The folder's size limit in bytes, or None for no limit (``BAKERY_CACHE_MAX_MB=0``)."""
    configured = os.environ.get("BAKERY_CACHE_MAX_MB", "").strip()
    try:
        megabytes = float(configured) if configured else float(DEFAULT_MAX_MB)
    except ValueError:
        megabytes = float(DEFAULT_MAX_MB)  # a malformed limit must not break a bake: the default applies
    return None if megabytes <= 0 else int(megabytes * 2**20)


def prune(directory: Path, keep: Path | None = None) -> list[Path]:
    """Remove the least recently used cache files of ``directory`` (not ``keep``) until the cache files fit the
    limit (module doc "Size"); returns the removed paths. Files removed meanwhile by another process are skipped."""
    limit = cache_limit_bytes()
    if limit is None:
        return []
    entries = []
    for path in directory.iterdir():
        if _CACHE_FILE.match(path.name):
            try:
                stat = path.stat()
            except OSError:
                continue
            entries.append((stat.st_mtime_ns, path.name, stat.st_size, path))
    total = sum(size for _, _, size, _ in entries)
    removed = []
    for _, _, size, path in sorted(entries):  # oldest use first (name breaks ties: deterministic)
        if total <= limit:
            break
        if keep is not None and path == keep:
            continue
        try:
            path.unlink()
        except FileNotFoundError:
            pass
        except OSError:
            continue
        total -= size
        removed.append(path)
    return removed


def _key_digest(key: str) -> str:
    return sha256_bytes(f"{key}|{bakery.__version__}".encode())[:32]


def _candidates(key: str) -> list[Path]:
    directory = cache_directory()
    if directory is None or not directory.is_dir():
        return []
    return sorted(directory.glob(f"{_key_digest(key)}.*.npy"))


def _verified(path: Path) -> np.ndarray | None:
    """The memory-mapped array at ``path`` if its content matches the SHA-256 in its name, else None."""
    expected = path.name.split(".")[1] if path.name.count(".") >= 2 else ""
    try:
        array = np.load(path, mmap_mode="r")
        actual = sha256_array(array)
    except FileNotFoundError:
        return None  # pruned by another process since it was listed: not damage, just absent
    except (OSError, ValueError, EOFError):
        actual = None
    if actual == expected:
        try:
            os.utime(path)  # used now: the last to be pruned (module doc "Size")
        except OSError:
            pass  # a read-only cache is still a cache
        return array
    warnings.warn(f"operator cache file {path} does not match its SHA-256 checksum (damaged or altered); "
                  "rebuilding the operator", OperatorCacheWarning, stacklevel=3)
    try:
        path.unlink()
    except OSError:
        pass
    return None


def load(key: str) -> np.ndarray | None:
    for path in _candidates(key):
        array = _verified(path)
        if array is not None:
            return array
    return None


def _remove_stale_temporaries(directory: Path) -> None:
    for tmp in directory.glob(".*.npy.tmp-*"):
        pid = tmp.name.rsplit(".tmp-", 1)[1]
        if pid.isdigit() and not pid_alive(int(pid)):
            try:
                tmp.unlink()
            except OSError:
                pass


def save(key: str, array: np.ndarray) -> np.ndarray:
    directory = cache_directory()
    if directory is None:
        return array
    array = np.ascontiguousarray(array)
    path = directory / f"{_key_digest(key)}.{sha256_array(array)}.npy"
    try:
        directory.mkdir(parents=True, exist_ok=True)
        _remove_stale_temporaries(directory)
        with atomic_replace(path) as tmp, open(tmp, "wb") as handle:
            np.save(handle, array)
        prune(directory, keep=path)
        return np.load(path, mmap_mode="r")
    except OSError:
        return array  # a read-only home or full disk only costs the rebuild next time


def load_sparse(key: str):
    """The ``scipy.sparse`` CSR matrix stored under ``key`` by :func:`save_sparse`, or None (module doc)."""
    from bakery.reflection.prefilter_operator import load_sparse as _load_sparse

    return _load_sparse(key, load)


def save_sparse(key: str, matrix):
    """Store a CSR matrix as four checksummed arrays (module doc); returns it backed by the memory-mapped files."""
    from bakery.reflection.prefilter_operator import save_sparse as _save_sparse

    return _save_sparse(key, matrix, save)


def install() -> None:
    """Back the reflection operator cache (:class:`bakery.reflection.tables.OperatorCache`) with this module."""
    from bakery.reflection.tables import OperatorCache

    OperatorCache.load = staticmethod(load)
    OperatorCache.save = staticmethod(save)
