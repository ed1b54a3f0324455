"""Where ``bakery bench`` writes: the output policy of its result files.

A bench writes its results (JSON, Markdown, SVG, a generated scene) into a folder it may share with other benches
and with the user's own files (the default ``bench-results``, or any ``-o``). It replaces a file only if a bench
wrote it and nobody changed it since: every write is recorded with its sha256 in the folder's
:data:`MANIFEST`; any other existing file is refused (:class:`~bakery.files.OutputError` naming it) unless
``force``. :func:`check_bench_outputs` applies the policy to the files a bench will write before it runs (a long
run is not wasted on a refusal), :func:`write_bench_file` again at each write (atomically; the manifest's update
holds a lock on the folder, so benches writing into one folder at once keep each other's records).
"""

from __future__ import annotations

import fcntl
import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from bakery.files import OutputError, check_output_file, sha256_bytes, write_bytes_atomic

#: The record of the files benches wrote in a folder: {"files": {name: sha256}}.
MANIFEST = ".bakery-bench.json"


def _recorded(folder: Path) -> dict[str, str]:
    try:
        data = json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return {}
    files = data.get("files") if isinstance(data, dict) else None
    return {k: v for k, v in files.items() if isinstance(v, str)} if isinstance(files, dict) else {}


def _refusal(folder: Path):  # noqa: ANN202
    recorded = _recorded(folder)

    def refusal(path: Path) -> str | None:
        try:
            same = recorded.get(path.name) == sha256_bytes(path.read_bytes())
        except OSError:
            same = False
        return None if same else "exists and is not a result bakery bench wrote (or it changed since)"

    return refusal


def check_bench_outputs(folder: str | os.PathLike[str], names: list[str] | tuple[str, ...], force: bool = False,
                        inputs: tuple = ()) -> Path:
    """Create ``folder`` if needed and apply the policy (module doc) to each of ``names`` in it; returns the folder."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: is not a folder; give a folder for the bench results")
    folder.mkdir(parents=True, exist_ok=True)
    refusal = _refusal(folder)
    for name in names:
        check_output_file(folder / name, "bench result", inputs=inputs, refusal=refusal, force=force)
    return folder


def write_bench_file(folder: str | os.PathLike[str], name: str, data: str | bytes, force: bool = False) -> Path:
    """Write ``folder/name`` atomically under the policy (module doc) and record it in the manifest."""
    folder = check_bench_outputs(folder, [name], force)
    payload = data.encode() if isinstance(data, str) else bytes(data)
    path = write_bytes_atomic(folder / name, payload)
    with _folder_locked(folder):  # two benches writing into one folder: neither loses the other's record
        recorded = _recorded(folder)
        recorded[name] = sha256_bytes(payload)
        write_bytes_atomic(folder / MANIFEST, json.dumps({"files": dict(sorted(recorded.items()))}, indent=1).encode())
    return path


@contextmanager
def _folder_locked(folder: Path) -> Iterator[None]:
    """An exclusive ``flock`` on the folder itself for the manifest's read-modify-write (held for milliseconds, so
    waited for; no lock file is left in the user's folder)."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock
