"""File helpers with one home: atomic replacement, staged multi-file commits, store locks, OS-error messages and
content hashes.

Atomic replacement
    ``with atomic_replace(path) as tmp:`` yields a temporary path beside ``path`` (same folder, so the rename is
    atomic on POSIX file systems). The caller writes ``tmp``; on a normal exit the file is fsync'ed and renamed over
    ``path``; on an exception the temporary file is removed and ``path`` is untouched. A crash (SIGKILL) at any
    moment leaves either the old or the new file, never a partial one; the temporary file a SIGKILL leaves
    (``.<name>.tmp-<pid>[suffix]``) is removed by :func:`remove_stale_temporaries` on the next run.

Staged commits (several files that must change together, e.g. a store and its USD layer)
    Each file is written to its :func:`staged_path` (fsync'ed, not renamed). :func:`commit_staged` then writes a
    commit record (atomically) listing the (staged, final) pairs, renames them in the listed order, fsyncs the
    folders and removes the record. :func:`recover_staged` — run by the next writer while it holds the lock —
    finishes the renames of a record a crash left behind, so a pair is never left half-committed: before the
    record exists nothing has changed (the staged files are stale and removed); once it exists the commit is
    completed.

Signals
    ``with terminate_as_exit():`` turns SIGTERM into ``SystemExit(143)`` for the writers (``bakery bake``,
    ``bakery export``), so the cleanup above runs on the way out instead of being skipped by the default action.

Locks
    :class:`FileLock` is an ``fcntl`` advisory lock on ``<path>.lock`` holding the owner's pid, host and start time.
    A second writer fails at once with a message naming the holder; a lock file left by a process that died is
    taken over (the kernel released its lock) and reported.

Hashes
    ``sha256_file`` (streamed), ``sha256_bytes`` and ``stable_hash`` (sha256 of the canonical JSON of plain data,
    numpy arrays by their bytes, shape and dtype) are the only hashers; content hashes of probes, batches, scenes
    and cached operators are built from them.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import math
import os
import re
import shutil
import signal
import socket
import stat
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from bakery.errors import InputError


class OutputError(InputError):
    """An output cannot be written where it was asked for: refused by the output policy (it would replace a file
    that is not a previous output of the same kind, or an input), locked by another writer, or the file system
    failed (permissions, read-only, full). Nothing was changed (exit 2)."""


@contextmanager
def atomic_replace(path: str | os.PathLike[str], suffix: str = "") -> Iterator[Path]:
    """Temporary path beside ``path``, renamed over it on success (fsync'ed first); removed on failure.

    ``suffix`` is appended to the temporary name (writers that choose a format by extension, e.g. USD's
    ``.usda``, need it)."""
    path = Path(path)
    tmp = staged_path(path, suffix)
    try:
        yield tmp
        fsync_file(tmp)
        os.replace(tmp, path)
        fsync_directory(path.parent)
    except OSError as error:
        raise with_filename(error, tmp) from None
    finally:
        if tmp.exists():
            tmp.unlink()


@contextmanager
def terminate_as_exit() -> Iterator[None]:
    """SIGTERM raises ``SystemExit(143)`` in the main thread while a writer runs (a bake, an export), so that every
    temporary file is removed on the way out (the default action would kill the process without running any
    cleanup). Nested uses, other threads and a handler someone else installed are left alone."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def with_filename(error: OSError, path: str | os.PathLike[str]) -> OSError:
    """``error`` naming ``path`` if it names no file (a failed ``write`` does not say which file it was)."""
    if getattr(error, "filename", None) or not isinstance(getattr(error, "errno", None), int):
        return error
    return type(error)(error.errno, error.strerror or os.strerror(error.errno), str(path))


def staged_path(path: str | os.PathLike[str], suffix: str = "") -> Path:
    """The temporary name beside ``path`` that :func:`atomic_replace` and staged commits write first."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp-{os.getpid()}{suffix}")


def fsync_file(path: str | os.PathLike[str]) -> None:
    if Path(path).exists():
        with open(path, "rb+") as handle:
            os.fsync(handle.fileno())


def fsync_directory(path: str | os.PathLike[str]) -> None:
    """fsync a folder (makes a rename in it durable); a no-op where folders cannot be opened."""
    try:
        fd = os.open(str(path) or ".", os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def pid_alive(pid: int) -> bool:
    """Whether a process with this pid exists on this machine."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


_TMP_PID = re.compile(r"\.tmp-(\d+)")


def remove_stale_temporaries(path: str | os.PathLike[str], *, keep_live: bool = True) -> list[Path]:
    """Remove the temporary siblings of ``path`` that killed writers left (``.<name>.tmp-<pid>…`` and the nested
    ``..<name>.tmp-<pid>…`` of a writer that itself writes through :func:`atomic_replace`). With ``keep_live``
    (default) files of a process that is still running are kept; the caller's own are always kept. Returns what
    was removed."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    removed: list[Path] = []
    if not folder.is_dir():
        return removed
    for pattern in (f".{path.name}.tmp-*", f"..{path.name}.tmp-*"):
        for candidate in folder.glob(pattern):
            match = _TMP_PID.search(candidate.name[len(path.name):])
            pid = int(match.group(1)) if match else -1
            if pid == os.getpid() or (keep_live and pid_alive(pid)):
                continue
            if _remove_path(candidate):
                removed.append(candidate)
    return removed


def remove_temporaries_under(folder: str | os.PathLike[str]) -> list[Path]:
    """Remove every ``.*.tmp-*`` file or folder under ``folder`` (a work folder the caller holds the lock of)."""
    folder = Path(folder)
    removed: list[Path] = []
    if not folder.is_dir():
        return removed
    for candidate in sorted(folder.rglob(".*.tmp-*"), key=lambda p: -len(p.parts)):
        if ".tmp-" not in candidate.name:
            continue
        match = _TMP_PID.search(candidate.name)
        if match and int(match.group(1)) == os.getpid():
            continue
        if _remove_path(candidate):
            removed.append(candidate)
    return removed


def _remove_path(path: Path) -> bool:
    """Remove a file, symlink or folder tree; False if it was already gone (another cleaner won the race)."""
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
    except FileNotFoundError:
        return False
    return True


#: Test hook of the fault-injection suite (``tests/faults``): ``BAKERY_FAULT=commit:N`` kills the process with
#: SIGKILL right after the N-th rename of a staged commit. Unset in normal use.
FAULT_ENVIRONMENT = "BAKERY_FAULT"


def _fault_point(name: str, count: int) -> None:
    spec = os.environ.get(FAULT_ENVIRONMENT, "")
    if spec and spec == f"{name}:{count}":
        os.kill(os.getpid(), signal.SIGKILL)


def commit_staged(pairs: list[tuple[Path, Path]], record: str | os.PathLike[str]) -> None:
    """Rename every staged file over its final path, in order, through a commit record (module docstring)."""
    record = Path(record)
    pairs = [(Path(a), Path(b)) for a, b in pairs]
    for staged, _ in pairs:
        fsync_file(staged)
    if len(pairs) > 1:
        body = json.dumps({"pairs": [[str(a.resolve()), str(b.resolve())] for a, b in pairs],
                           "pid": os.getpid(), "host": socket.gethostname()}, sort_keys=True)
        write_bytes_atomic(record, body.encode())
    for count, (staged, final) in enumerate(pairs, start=1):
        os.replace(staged, final)
        fsync_directory(final.parent)
        _fault_point("commit", count)
    if len(pairs) > 1:
        record.unlink(missing_ok=True)
        fsync_directory(record.parent)


def recover_staged(record: str | os.PathLike[str]) -> list[Path]:
    """Finish a commit a crash interrupted (see the module docstring); returns the files renamed into place."""
    record = Path(record)
    if not record.is_file():
        return []
    try:
        pairs = [(Path(a), Path(b)) for a, b in json.loads(record.read_text(encoding="utf-8"))["pairs"]]
    except (OSError, ValueError, KeyError, TypeError):
        record.unlink(missing_ok=True)  # an unreadable record was never completely written: nothing was renamed
        return []
    finished = []
    for staged, final in pairs:
        if staged.exists():
            os.replace(staged, final)
            fsync_directory(final.parent)
            finished.append(final)
    record.unlink(missing_ok=True)
    fsync_directory(record.parent)
    return finished


def os_error_message(error: BaseException) -> str:
    """One line for an OS-level failure: ``<file>: <reason>``, also for HDF5's errors, which carry the errno in
    their text (``errno = 28, error message = 'No space left on device'``), and of h5py's KeyError and RuntimeError
    for a failed metadata checksum."""
    text = str(error.args[0]) if isinstance(error, KeyError) and error.args else str(error)
    code = getattr(error, "errno", None)
    reason = getattr(error, "strerror", None)
    match = re.search(r"errno = (\d+), error message = '([^']*)'", text)
    if match:
        code, reason = int(match.group(1)), match.group(2)
    if not reason and isinstance(code, int) and code in errno.errorcode:
        reason = os.strerror(code)
    if not reason:
        if "fletcher32" in text.lower() or "filter returned failure" in text.lower():
            reason = "HDF5 checksum (fletcher32) failure: the file is corrupt"
        else:
            reason = text.splitlines()[0] if text else type(error).__name__
    filename = getattr(error, "filename", None)
    match = re.search(r"name = '([^']*)'", text)
    if not filename and match:
        filename = match.group(1)
    return f"{filename}: {reason}" if filename else reason


def is_space_error(error: BaseException) -> bool:
    return getattr(error, "errno", None) in (errno.ENOSPC, errno.EDQUOT) or "errno = 28" in str(error)


# ---------------------------------------------------------------------------------------------------- output policy
def folder_problem(folder: Path) -> str | None:
    """Why files cannot be created in ``folder`` (None: they can, as far as permissions and mounts tell)."""
    if not folder.is_dir():
        return "does not exist" if not folder.exists() else "is not a folder"
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            return "is on a read-only file system"
    except OSError:
        pass
    if not os.access(folder, os.W_OK | os.X_OK):
        return "is not writable (permissions or an immutable folder)"
    return None


def same_file(a: Path, b: Path) -> bool:
    try:
        if a.resolve() == b.resolve():
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def json_output_refusal(path: str | os.PathLike[str], keys: Any, what: str) -> str | None:
    """A ``refusal`` for :func:`check_output_file` of a JSON output bakery writes: None when the existing file is a
    previous one (a JSON object holding every one of ``keys``), else why it must not be replaced."""
    try:
        data = json.loads(Path(path).read_bytes())
    except OSError as error:
        return f"exists and cannot be read ({os_error_message(error)})"
    except ValueError:  # not JSON, not UTF-8
        data = None
    if isinstance(data, dict) and set(keys) <= set(data):
        return None
    return f"exists and is not {what}"


#: Bytes bakery adds to an output's file name for the files beside it (``..<name>.tmp-<pid>.tmp-<pid>.usda``,
#: ``<name>.partial``, ``<name>.lock``): an output name must leave this much room below the file system's limit.
NAME_MARGIN = 32


def check_output_file(path: str | os.PathLike[str], what: str, *, inputs: Any = (), refusal: Any = None,
                      force: bool = False) -> None:
    """The output policy for one file a command is about to write (:class:`OutputError` if refused):

    * its folder exists and is writable (not read-only, not immutable) and the path is not a folder;
    * it is none of ``inputs`` (also through links) — never overridden, not even by ``force``;
    * if it exists, ``refusal(path)`` (a function returning why that file must not be replaced, or None when it is
      a previous output of the same kind) must return None, unless ``force``. Without ``refusal`` any existing
      file is refused.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; give a file name for the {what}")
    problem = folder_problem(folder)
    if problem:
        raise OutputError(f"{path}: the {what} folder {folder} {problem}")
    try:
        longest = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        longest = 255
    if len(os.fsencode(path.name)) + NAME_MARGIN > longest:  # found before the work, not when it is written
        raise OutputError(f"{path}: the {what}'s file name is too long ({len(os.fsencode(path.name))} bytes): the "
                          f"temporary and lock files bakery writes beside it add up to {NAME_MARGIN} bytes to names "
                          f"of at most {longest}")
    for item in inputs:
        if same_file(path, Path(item)):
            raise OutputError(f"{path}: is an input of this command; refusing to overwrite it (also with --force); "
                              f"write the {what} elsewhere")
    if path.exists() or path.is_symlink():
        if not path.is_file():
            raise OutputError(f"{path}: exists and is not a regular file; refusing to replace it with the {what}")
        reason = refusal(path) if refusal is not None else "exists"
        if reason and not force:
            raise OutputError(f"{path}: {reason}; refusing to overwrite it with the {what} "
                              "(use --force to replace it anyway)")


# ---------------------------------------------------------------------------------------------------------- locks
_HELD: set[str] = set()
_HELD_GUARD = threading.Lock()


def lock_path(path: str | os.PathLike[str]) -> Path:
    path = Path(path)
    return path.with_name(path.name + ".lock")


class FileLock:
    """An exclusive ``fcntl`` lock on ``<path>.lock`` for the lifetime of a writer (module docstring).

    ``acquire`` raises :class:`OutputError` if another process (or another bake in this process) holds it; a lock
    file left by a dead process is taken over and described in :attr:`stale` (the caller warns)."""

    def __init__(self, path: str | os.PathLike[str], what: str = "store", writer: str = "bake") -> None:
        self.path = Path(path)
        self.what = what
        self.writer = writer  # who holds such a lock, for the message: "another <writer> is writing this <what>"
        self.file = lock_path(self.path)
        self._key = str(self.path.resolve())
        self._fd: int | None = None
        self.stale: dict[str, Any] | None = None

    def __enter__(self) -> FileLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    @staticmethod
    def _read(fd: int) -> dict[str, Any]:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            data = os.read(fd, 4096)
            return json.loads(data.decode("utf-8")) if data.strip() else {}
        except (OSError, ValueError, UnicodeDecodeError):
            return {}

    @staticmethod
    def describe(info: dict[str, Any]) -> str:
        if not info:
            return "another process"
        since = info.get("since", "")
        return (f"pid {info.get('pid', '?')} on host {info.get('host', '?')}"
                + (f" since {since}" if since else "") + (f" ({info['command']})" if info.get("command") else ""))

    def acquire(self) -> None:
        with _HELD_GUARD:
            if self._key in _HELD:
                raise OutputError(f"{self.path}: this process is already writing this {self.what}")
            _HELD.add(self._key)
        try:
            self._acquire()
        except BaseException:
            with _HELD_GUARD:
                _HELD.discard(self._key)
            raise

    def _acquire(self) -> None:
        for _attempt in range(20):
            try:  # never through a symbolic link: the lock's JSON would overwrite whatever it points to
                fd = os.open(self.file, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
            except OSError as error:
                if error.errno == errno.ELOOP:
                    raise OutputError(f"{self.path}: the lock file {self.file.name} is a symbolic link; bakery "
                                      f"writes its locks only as regular files: remove the link") from None
                raise OutputError(f"{self.path}: cannot create the lock file {self.file.name}: "
                                  f"{os_error_message(error)}") from None
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                os.close(fd)
                raise OutputError(f"{self.path}: the lock file {self.file.name} is not a regular file; remove it")
            try:
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as error:
                info = self._read(fd)
                os.close(fd)
                if error.errno in (errno.EACCES, errno.EAGAIN):
                    raise OutputError(
                        f"{self.path}: another {self.writer} is writing this {self.what} ({self.describe(info)}); wait "
                        f"for it "
                        f"to finish or write to another path") from None
                raise OutputError(f"{self.path}: cannot lock {self.file.name}: {os_error_message(error)}") from None
            try:
                same = os.stat(self.file)
                mine = os.fstat(fd)
            except FileNotFoundError:
                os.close(fd)  # the previous holder removed it between our open and lock: try again
                continue
            if (same.st_ino, same.st_dev) != (mine.st_ino, mine.st_dev):
                os.close(fd)
                continue
            previous = self._read(fd)
            if previous:
                self.stale = previous
            info = {"pid": os.getpid(), "host": socket.gethostname(),
                    "since": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                    "command": " ".join(os.path.basename(a) if i == 0 else a
                                        for i, a in enumerate(sys.argv[:6]))}
            try:
                os.ftruncate(fd, 0)
                os.lseek(fd, 0, os.SEEK_SET)
                os.write(fd, json.dumps(info, sort_keys=True).encode())
                os.fsync(fd)
            except OSError as error:
                try:
                    self.file.unlink()  # ours (we hold the lock): leave nothing behind
                except OSError:
                    pass
                os.close(fd)
                raise OutputError(f"{self.path}: cannot write the lock file {self.file.name}: "
                                  f"{os_error_message(error)}") from None
            self._fd = fd
            return
        raise OutputError(f"{self.path}: could not lock {self.file.name} (it keeps being replaced)")

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            self.file.unlink(missing_ok=True)  # while still holding it: a waiter re-checks the inode
        except OSError:
            pass
        try:
            os.close(self._fd)  # releases the fcntl lock
        finally:
            self._fd = None
            with _HELD_GUARD:
                _HELD.discard(self._key)


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_replace`)."""
    path = Path(path)
    with atomic_replace(path) as tmp:
        tmp.write_bytes(data)
    return path


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_array(array: np.ndarray) -> str:
    """sha256 hex of an array's dtype, shape and C-order bytes (memory-mapped arrays are hashed without a copy)."""
    array = np.ascontiguousarray(array)
    digest = hashlib.sha256(json.dumps([array.dtype.str, list(array.shape)]).encode())
    digest.update(memoryview(array).cast("B") if array.size else b"")
    return digest.hexdigest()


def sha256_running() -> Any:
    """A running SHA-256 (``update(bytes-like)`` as data comes, ``digest()`` at the end): digests of data too large
    to concatenate first."""
    return hashlib.sha256()


def sha256_digest(*chunks: bytes) -> bytes:
    """Raw 32-byte sha256 of the concatenated chunks."""
    digest = hashlib.sha256()
    for chunk in chunks:
        digest.update(chunk)
    return digest.digest()


def sha256_file(path: str | os.PathLike[str]) -> str:
    """sha256 hex of a file's bytes, streamed in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


_JSON_SCALARS = frozenset({str, int, float, bool, type(None)})


def _canonical(value: Any) -> Any:
    kind = type(value)  # exact built-in types first (a plan hashes thousands of probes): same result, fewer checks
    if kind in _JSON_SCALARS:
        return value
    if kind is tuple or kind is list:
        return [_canonical(v) for v in value]
    if kind is dict:
        return {str(k): _canonical(v) for k, v in value.items()}
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
                **{name: _canonical(getattr(value, name)) for name, spec in value.__dataclass_fields__.items()
                   if spec.metadata.get("content_hash", True)
                   and not (spec.metadata.get("hashed_at_default", True) is False
                            and getattr(value, name) == spec.default)}}
    return value


def stable_hash(*parts: Any) -> str:
    """sha256 hex of the canonical JSON of ``parts`` (dicts sorted by key; arrays by content, shape and dtype;
    dataclasses by their fields, except those declared with ``metadata={"content_hash": False}``, and those declared
    with ``metadata={"hashed_at_default": False}`` while at their default: a parameter added to an encoding whose
    default reproduces the former output leaves the hashes of earlier bakes, and so their probes' reuse, intact)."""
    return sha256_bytes(json.dumps(_canonical(parts), sort_keys=True, default=str).encode())


def jsonable(x: Any) -> Any:
    """``x`` with numpy values as Python ones and non-finite floats as None: what ``json.dumps(..., allow_nan=False)``
    accepts (strict JSON, which ``jq`` and browsers parse; an unmeasured value is null, never ``NaN``/``Infinity``)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, np.integer):
        return int(x)
    return x
