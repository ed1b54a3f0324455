"""On-disk cache of environment-independent operators (the SH-exponential fit's W blocks, 4096 × 1536 and
12288 × 384 float32 = 44 MB at default settings, ≈ 1–2 s to build; the DFG/Fresnel-tail quadrature, ≈ 4 s),
memory-mapped so that every worker process of a bake — and every later bake on the machine — shares one physical
copy instead of rebuilding it per process.

Location: ``$BAKERY_CACHE_DIR`` or ``~/.cache/bakery/operators``. Files are named by the sha256 of the operator's
key (which encodes every setting it depends on and its formulation version) and bakery's version, written
atomically (temp file + rename) so concurrent workers never read a partial file. Delete the folder to clear it;
set ``BAKERY_CACHE_DIR=off`` to keep operators in memory only.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import bakery
from bakery.files import atomic_replace, sha256_bytes


def cache_directory() -> Path | None:
    configured = os.environ.get("BAKERY_CACHE_DIR")
    if configured and configured.lower() == "off":
        return None
    return Path(configured) if configured else Path.home() / ".cache" / "bakery" / "operators"


def _path(key: str) -> Path | None:
    directory = cache_directory()
    if directory is None:
        return None
    digest = sha256_bytes(f"{key}|{bakery.__version__}".encode())[:32]
    return directory / f"{digest}.npy"


def load(key: str) -> np.ndarray | None:
    path = _path(key)
    if path is None or not path.is_file():
        return None
    try:
        return np.load(path, mmap_mode="r")
    except (OSError, ValueError):
        return None  # unreadable or partial (should not happen: writes are atomic): rebuild


def save(key: str, array: np.ndarray) -> np.ndarray:
    path = _path(key)
    if path is None:
        return array
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_replace(path) as tmp, open(tmp, "wb") as handle:
            np.save(handle, np.ascontiguousarray(array))
        return np.load(path, mmap_mode="r")
    except OSError:
        return array  # a read-only home or full disk only costs the rebuild next time


def install() -> None:
    """Back the reflection operator cache (:class:`bakery.reflection.tables.OperatorCache`) with this module."""
    from bakery.reflection.tables import OperatorCache

    OperatorCache.load = staticmethod(load)
    OperatorCache.save = staticmethod(save)
