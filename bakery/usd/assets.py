"""Asset files for readers outside USD (OpenImageIO): plain files, or members of a .usdz package.

A texture inside a package resolves to ``pkg.usdz[member.png]``, which only USD's asset resolver (Ar) can open.
:func:`local_asset_path` copies such a member once to a content-addressed file in the system temporary directory
(``bakery-usd-assets/<sha256[:16]><suffix>``) and returns that path; ordinary files are returned as they are.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from pxr import Ar, Sdf

from bakery.files import sha256_bytes, write_bytes_atomic


def local_asset_path(asset: Sdf.AssetPath) -> str | None:
    """A readable file for a resolved asset path, or None if it does not resolve to anything readable."""
    resolved = asset.resolvedPath
    if not resolved:
        return None
    if Path(resolved).is_file():
        return resolved
    if not (resolved.endswith("]") and "[" in resolved):
        return None
    handle = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved))
    if not handle:
        return None
    data = bytes(handle.GetBuffer())
    suffix = Path(resolved[resolved.rindex("[") + 1 : -1]).suffix
    cache = Path(tempfile.gettempdir()) / "bakery-usd-assets"
    cache.mkdir(parents=True, exist_ok=True)
    target = cache / f"{sha256_bytes(data)[:16]}{suffix}"
    if not target.is_file():
        write_bytes_atomic(target, data)
    return str(target)
