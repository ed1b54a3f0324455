"""The export plug-in contract and the one export path: formats declared once, files written all-or-nothing.

An export format is one module of ``bakery/export/`` with an :class:`ExportFormat` subclass (``name``,
``description``, ``default_profile``, a frozen dataclass ``Params`` of typed options — the same
:class:`~bakery.encodings.base.EncodingParams` machinery as the encodings: wrong types, unknown keys and
out-of-range values are exit 3 — and ``build(context)``, a generator of :class:`ExportedFile`), registered with
:func:`register_format` at the bottom of the module and imported in ``bakery/export/__init__.py``. The CLI
(``bakery export``), the recipe key ``exports`` and ``tests/export/test_export.py``'s conformance suite pick formats
up from :data:`EXPORT_FORMATS`.

:func:`export_store` is the only writer (:func:`write_files` its steps 2–6), with SIGTERM turned into
``SystemExit(143)`` throughout (:func:`bakery.files.terminate_as_exit`, as in a bake) so that every failure path below
also runs on SIGTERM:

1. the format, profile and options are checked (ConfigError, exit 3), the store is opened (exit 2 if it is not one),
   the output folder must be creatable and writable (exit 2), and the USD layer of the bake (``--layer``, default
   ``<store stem>.bake.usda`` / ``.usdc`` beside the store when it exists) must be a bakery baked-results layer
   that records this store (:func:`bakery.usd.layer.open_export_layer`): the scene's own layers, a user's file, a
   text file, a missing ``--layer`` or another store's layer are exit 2 — before anything is built or written, and
   there is no ``--force`` for it (an export never edits a layer bakery does not own). The layer is edited under
   the store's writer lock (exit 2 while a bake of the store runs), which also removes the staged layers dead
   processes left beside it;
2. the output folder is created if needed and locked: ``.bakery-export.lock`` in it (:class:`bakery.files.FileLock`;
   a second export into the folder is exit 2 at once, a dead export's lock is taken over with a warning); then, still
   before anything else, what a killed export left is recovered (see "Recovery" below);
3. the format yields its files one at a time (``build`` is a generator: a store without the encodings it needs is
   exit 2 before the first file; reflection formats prefilter a chunk of probes at a time,
   :class:`bakery.export.source.ProfileChains`), and each is staged at once — written and fsync'ed to its temporary
   name beside its target (``.<name>.tmp-<pid>``, :func:`bakery.files.staged_path`) and dropped from memory, so an
   export holds one chunk, not the whole output;
4. files already in the folder are overwritten only if the folder's manifest ``bakery-export.json`` lists them with
   their current sha256 (i.e. bakery wrote them and nobody changed them); any other existing file is *foreign* and
   the export is refused (exit 2) before any target is replaced;
5. once every file is staged, the layer is staged too, with ``bakery:export:<format>`` asset attributes on each
   exported probe (:func:`bakery.usd.layer.staged_export_attributes`), and so is the new manifest. A failure up to
   here (a foreign file, a format error, a layer USD cannot write, a full disk, SIGTERM, Ctrl-C) removes the staged
   files and the folders the export created: the previous export is unchanged and nothing is left;
6. the commit: the journal ``.bakery-export.journal`` is written atomically — every staged file with its target and
   sha256 in rename order, the previous manifest and the new one — then the files are renamed, the manifest last,
   and the journal is removed (:func:`bakery.files.recover_staged` applies its pairs); then the staged layer is
   renamed over the layer. An exception during the commit (SIGTERM, Ctrl-C, an OS error) completes it first, as the
   next export would (:func:`_complete`), so a terminated export leaves the new export whole and no staged file;
   into a new folder the committed files are then taken out again, as on any failure.

Recovery (:func:`recover_folder`, step 2: every export into the folder, holding its lock). A SIGKILL can strike at
any point; what it leaves is repaired before the next export does anything else:

* a journal (killed during the commit): each staged file that is intact (its sha256) is renamed over its target if
  the target is still bakery's — missing, or holding the previous or the new content (a file someone changed
  meanwhile is left alone and stays foreign) — and the manifest is rewritten to describe what is then on disk (per
  file the new entry, or the previous one where the previous content is still there), then the journal is removed.
  Idempotent: a kill during recovery is recovered the same way. So the interrupted export is completed (the layer
  keeps its previous attributes until an export of that format runs again), and files that match neither manifest
  are refused as before;
* staged files (``.<name>.tmp-<pid>``): anywhere in the folder those of the dead export whose journal or stale lock
  names its pid, and beside every file either manifest lists those of processes no longer running; before its own
  commit an export also removes dead processes' staged files beside its own targets (what an older bakery, without
  journal or lock, left). Other hidden files are not touched;
* each repair is reported as a warning (``BakeryWarning``: the CLI prints ``warning: …``).
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
import unicodedata
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from bakery.encodings.base import EncodingParams, NoParams
from bakery.errors import BakeryWarning, ConfigError, InputError
from bakery.export.profiles import Profile, get_profile
from bakery.files import (
    FileLock,
    OutputError,
    folder_problem,
    fsync_directory,
    pid_alive,
    recover_staged,
    remove_stale_temporaries,
    sha256_bytes,
    sha256_file,
    staged_path,
    terminate_as_exit,
    with_filename,
    write_bytes_atomic,
)

MANIFEST = "bakery-export.json"
MANIFEST_FORMAT = "bakery.export"
#: The commit journal: present only while an export renames its files (or after it was killed doing so).
JOURNAL = ".bakery-export.journal"
JOURNAL_FORMAT = "bakery.export.journal"
#: The folder's export lock is ``.bakery-export.lock`` (:class:`bakery.files.FileLock` of this name).
LOCK = ".bakery-export"
#: A staged file: ``.<name>.tmp-<pid>`` beside ``<name>`` (:func:`bakery.files.staged_path`).
_TEMPORARY = re.compile(r"\.(?P<name>.+)\.tmp-(?P<pid>\d+)")


@dataclass(frozen=True)
class ExportedFile:
    """One file of an export: ``path`` relative to the output folder (POSIX separators)."""

    path: str
    data: bytes
    probes: tuple[str, ...] = ()  # probe prims (volume prims for volume atlases) that reference this file
    role: str = ""  # what the file is, e.g. "cube", "light-probes", "volume-atlas"


@dataclass
class ExportContext:
    store: Any  # bakery.api.ProbeStore
    probes: list[str]  # selected probe names, store order
    profile: Profile
    params: EncodingParams
    format_name: str
    _validity: dict[str, dict[str, Any]] | None = field(default=None, repr=False)

    def provenance(self) -> dict[str, Any]:
        """What every exported file records about its origin (metadata / KVD / extras)."""
        from bakery.conventions import CONVENTIONS

        return {"generator": "bakery", "store": os.path.basename(self.store.path),
                "settings_hash": str(self.store.attributes.get("settings_hash", "")),
                "conventions": CONVENTIONS}

    def validity(self, probes: Iterable[str]) -> dict[str, dict[str, Any]]:
        """Each rendered probe's validity, for engines that weight or skip probes inside geometry (DDGI's rule):
        ``backface_fraction`` (the share of its camera rays that saw the back of single-sided surfaces),
        ``inside_geometry`` (≥ the store's threshold) and, for a relocated volume probe, ``capture_offset`` (metres,
        bake frame: where it was captured from, relative to its position) and, for a dilated one, ``dilated_from``
        (how many valid probes of its volume it stores the weighted mean of; :mod:`bakery.pipeline.dilate`).
        Probes without the diagnostic (loaded images, older stores) are left out."""
        if self._validity is None:  # every probe's, once per export (formats ask per file)
            self._validity = self._all_validity()
        return {name: self._validity[name] for name in probes if name in self._validity}

    def _all_validity(self) -> dict[str, dict[str, Any]]:
        from bakery.conventions import INSIDE_BACKFACE_FRACTION
        from bakery.pipeline.dilate import NEIGHBOURS_KEY

        diagnostics = self.store.diagnostics
        fraction = diagnostics.get("capture/backface_fraction")
        if fraction is None:
            return {}
        fraction = np.asarray(fraction, dtype=np.float64)
        offsets = diagnostics.get("capture/offset")
        offsets = None if offsets is None else np.asarray(offsets, dtype=np.float64)
        threshold = float(self.store.attributes.get("inside_geometry_backface_fraction", INSIDE_BACKFACE_FRACTION))
        sources = diagnostics.get(NEIGHBOURS_KEY)
        sources = None if sources is None else np.nan_to_num(np.asarray(sources, dtype=np.float64))
        out: dict[str, dict[str, Any]] = {}
        for i, name in enumerate(self.store.probe_names):
            value = float(np.float32(fraction[i]))
            if not np.isfinite(value):
                continue
            record: dict[str, Any] = {"backface_fraction": value, "inside_geometry": bool(value >= threshold)}
            if offsets is not None and np.any(offsets[i] != 0):
                record["capture_offset"] = [float(np.float32(v)) for v in offsets[i]]
            if sources is not None and sources[i] > 0:
                record["dilated_from"] = int(sources[i])
            out[name] = record
        return out


class ExportFormat(ABC):
    """An export format (see the module docstring)."""

    name: ClassVar[str]
    description: ClassVar[str]
    default_profile: ClassVar[str]
    Params: ClassVar[type[EncodingParams]] = NoParams

    @abstractmethod
    def build(self, context: ExportContext) -> Iterable[ExportedFile]:
        """Every file of the export, best yielded one at a time (a generator: the writer stages each as it comes).
        Raise :class:`InputError` (before the first file) if the store lacks what is needed."""


#: name → format class, in registration order.
EXPORT_FORMATS: dict[str, type[ExportFormat]] = {}


def register_format(cls: type[ExportFormat]) -> type[ExportFormat]:
    name = cls.__dict__.get("name")
    if not isinstance(name, str) or not name:
        raise ValueError(f"export format {cls.__qualname__} does not declare its name")
    if name in EXPORT_FORMATS and EXPORT_FORMATS[name] is not cls:
        raise ValueError(f"export format {name!r} registered twice")
    params = cls.__dict__.get("Params", cls.Params)
    if not (isinstance(params, type) and issubclass(params, EncodingParams)):
        raise ValueError(f"export format {name!r}: Params must be an EncodingParams dataclass")
    get_profile(cls.default_profile)
    EXPORT_FORMATS[name] = cls
    return cls


def get_format(name: str) -> type[ExportFormat]:
    if name not in EXPORT_FORMATS:
        raise ConfigError(f"unknown export format {name!r}; formats: {', '.join(EXPORT_FORMATS)}")
    return EXPORT_FORMATS[name]


#: Longest stem :func:`slug` returns (ASCII, so bytes = characters): file systems cap one name at 255 bytes (ext4,
#: APFS, NTFS), and the staged ``.<stem><suffix>.tmp-<pid>`` (:func:`bakery.files.staged_path`) must fit as well.
SLUG_MAX = 160
#: Hex digits of the probe name's sha256 appended where the stem alone would lose or shorten the name.
SLUG_DIGEST = 12


def slug(name: str) -> str:
    """A file-name-safe ASCII stem of a probe name: ``/Room/Probes/Volume[1,2,0]`` → ``Room_Probes_Volume_1_2_0``.

    Accented letters keep their base letter (NFKD: ``Prüfung`` → ``Prufung``); a name that is not plain ASCII, or
    whose stem would exceed :data:`SLUG_MAX` (a long USD prim path), ends in ``-`` + the first :data:`SLUG_DIGEST` hex
    digits of the sha256 of the name (UTF-8), so such names stay distinct and every stem fits a file name. Plain-ASCII
    names that differ only in punctuation still share a stem (``write_files`` refuses them by name)."""
    ascii_name = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode("ascii")
    s = re.sub(r"[^A-Za-z0-9_.-]+", "_", ascii_name.strip("/")).strip("_") or "probe"
    if len(s) > SLUG_MAX or not name.isascii():
        digest = sha256_bytes(name.encode("utf-8", "surrogatepass"))[:SLUG_DIGEST]
        s = f"{s[:SLUG_MAX - SLUG_DIGEST - 1].rstrip('_.-')}-{digest}"
    return s


def select_probes(store, pattern: str | None) -> list[str]:  # noqa: ANN001
    if pattern is None:
        return list(store.probe_names)
    selected = [p for p in store.probe_names if fnmatch.fnmatchcase(p, pattern)]
    if not selected:
        raise InputError(f"{store.path}: no probe matches --probes {pattern!r}")
    return selected


# ------------------------------------------------------------------------------------------------ writing
@dataclass
class ExportResult:
    format: str
    profile: str
    output: Path
    files: list[str] = field(default_factory=list)
    manifest: Path | None = None
    layer: Path | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"format": self.format, "profile": self.profile, "output": str(self.output), "files": self.files,
                "manifest": str(self.manifest) if self.manifest else None,
                "layer": str(self.layer) if self.layer else None}


def _read_manifest(folder: Path) -> dict[str, Any]:
    path = folder / MANIFEST
    if not path.exists():
        return {"format": MANIFEST_FORMAT, "version": 1, "files": {}}
    try:
        data = json.loads(path.read_text())
        if data.get("format") != MANIFEST_FORMAT or not isinstance(data.get("files"), dict):
            raise ValueError("not a bakery export manifest")
        return data
    except (OSError, ValueError) as error:
        raise InputError(f"{path}: unreadable export manifest ({error}); refusing to write into {folder}") from None


def _check_writable(folder: Path) -> None:
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: the export output must be a folder, and this is a file")
    probe = folder
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{folder}: {probe} is a file, so the output folder cannot be created")
    if not os.access(probe, os.W_OK | os.X_OK) or not _can_create_in(probe):
        raise InputError(f"{folder}: the output folder is not writable ({probe} does not allow writing)")


def _can_create_in(folder: Path) -> bool:
    """Whether a file can be created in ``folder`` (tried and removed: permission bits do not bind root)."""
    import tempfile

    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".bakery-export-probe-"):
            return True
    except OSError:
        return False


@dataclass(frozen=True)
class WrittenFile:
    """What the writer keeps of a staged file (its bytes are on disk, not in memory)."""

    path: str
    probes: tuple[str, ...]
    role: str


def _foreign(folder: Path, f: ExportedFile, manifest: dict[str, Any],
             export_format: str | None = None) -> str | None:
    """Why ``f`` may not replace what is at its target (a folder, a file bakery did not write or that changed since,
    or another format's file: ``ktx2`` and ``three`` both write ``<probe>.ktx2``, at different profiles), or None."""
    target = folder / f.path
    if target.is_dir():
        return f"{f.path} (a folder)"
    if not target.exists():
        return None
    entry = manifest["files"].get(f.path)
    if entry is None or entry.get("sha256") != sha256_file(target):
        return f.path
    written_by = entry.get("format")
    if export_format and written_by and written_by != export_format:
        return f"{f.path} (written by the {written_by} export: export each format to its own folder)"
    return None


def _make_parents(target: Path, created: list[Path]) -> None:
    """Create the missing folders down to ``target``'s parent, recording each in ``created`` (outermost first)."""
    missing = []
    probe = target.parent
    while not probe.exists():
        missing.append(probe)
        probe = probe.parent
    for m in reversed(missing):
        m.mkdir()
        created.append(m)


def write_files(folder: Path, files: Iterable[ExportedFile], record: dict[str, Any],
                then: Callable[[list[WrittenFile], ExitStack], None] | None = None) -> tuple[Path, list[WrittenFile]]:
    """Lock the folder, recover what a killed export left in it, stage every file of ``files`` as it comes, then
    commit them with the updated manifest through the journal, all-or-nothing (module docstring, steps 2–6).
    Returns the manifest path and the files written; when ``files`` is empty nothing is written (and no folder is
    left behind).

    ``then(written, stack)``, called once every file is staged (and none is foreign) but before any is renamed, may
    stage more files in ``stack`` (e.g. the USD layer): they are renamed after the files and the manifest, and an
    error in ``then`` removes every staged file, so nothing is written."""
    folder = Path(folder)
    _check_writable(folder)
    created: list[Path] = []
    with terminate_as_exit():
        try:
            _make_parents(folder / MANIFEST, created)  # the folder itself: its lock file lives in it
            with _folder_lock(folder) as lock:
                for note in recover_folder(folder, lock.stale):
                    warnings.warn(f"{folder}: {note}", BakeryWarning, stacklevel=2)
                return _write_locked(folder, files, record, then, created)
        finally:
            for d in reversed(created):  # what this export created and left empty (on failure, or nothing to write)
                if d.is_dir() and not any(d.iterdir()):
                    d.rmdir()


@contextmanager
def _folder_lock(folder: Path) -> Iterator[FileLock]:
    """The folder's export lock (``.bakery-export.lock`` in it): one export into a folder at a time."""
    lock = FileLock(folder / LOCK, what="export folder", writer="export")
    lock.acquire()
    try:
        if lock.stale:
            warnings.warn(f"{folder}: took over the lock of an export that is no longer running "
                          f"({FileLock.describe(lock.stale)})", BakeryWarning, stacklevel=4)
        yield lock
    finally:
        lock.release()


def _write_locked(folder: Path, files: Iterable[ExportedFile], record: dict[str, Any],
                  then: Callable[[list[WrittenFile], ExitStack], None] | None,
                  created: list[Path]) -> tuple[Path, list[WrittenFile]]:
    """:func:`write_files` once the folder is locked and recovered."""
    manifest = _read_manifest(folder)
    previous = {**manifest, "files": dict(manifest["files"])}  # as it was: the journal's fallback for recovery
    journal = folder / JOURNAL
    staged: list[tuple[Path, Path, str]] = []  # (temporary, target, sha256), in rename order
    written: list[WrittenFile] = []
    seen: dict[str, tuple[str, ...]] = {MANIFEST: (), JOURNAL: (), f"{LOCK}.lock": ()}  # file → the probes it holds
    foreign: list[str] = []
    committing = committed = False
    try:
        with ExitStack() as late:  # what ``then`` staged: renamed last
            for f in files:
                if f.path in seen:
                    probes = ", ".join(dict.fromkeys([*seen[f.path], *f.probes])) or "bakery's manifest"
                    raise InputError(f"{folder / f.path}: two exported files have this name ({probes}: probe "
                                     f"names that differ only in punctuation?); export them to separate folders "
                                     f"with --probes")
                seen[f.path] = tuple(f.probes)
                reason = _foreign(folder, f, manifest, record.get("format"))
                if reason:
                    foreign.append(reason)
                    continue
                target = folder / f.path
                _make_parents(target, created)
                digest = sha256_bytes(f.data)
                staged.append((staged_path(target), target, digest))
                _write_staged(staged[-1][0], f.data)
                manifest["files"][f.path] = {"sha256": digest, **record, "role": f.role, "probes": list(f.probes)}
                written.append(WrittenFile(f.path, tuple(f.probes), f.role))
            if foreign:
                raise InputError(f"{folder}: refusing to overwrite file(s) bakery did not write or that changed "
                                 f"since ({', '.join(sorted(foreign)[:5])}{' …' if len(foreign) > 5 else ''}); "
                                 f"choose another folder or remove them")
            if not written:
                return folder / MANIFEST, written
            if then is not None:
                then(written, late)
            # temporaries of dead processes beside this export's files (killed before a journal or a lock told
            # whose they were, e.g. by a bakery without them): ours now
            _remove_temporaries(folder, {w.path for w in written})
            data = _manifest_bytes(manifest)
            staged.append((staged_path(folder / MANIFEST), folder / MANIFEST, sha256_bytes(data)))
            _write_staged(staged[-1][0], data)
            committing = True
            _commit(folder, staged, previous, manifest)
            committed = True
        # leaving ``late`` renamed the layer
    except BaseException:
        state = _finish_interrupted_commit(folder, staged) if committing and not committed else committed
        if state is None or not committing:  # nothing was renamed: the staged files go
            for tmp, _, _ in staged:
                tmp.unlink(missing_ok=True)
        committed = bool(state)
        if committed and folder in created:  # a new folder: take the export out again, nothing is left
            for w in written:
                (folder / w.path).unlink(missing_ok=True)
            (folder / MANIFEST).unlink(missing_ok=True)
        raise
    return folder / MANIFEST, written


def _write_staged(tmp: Path, data: bytes) -> None:
    """Write ``data`` to the staged file ``tmp`` and fsync it (a link in its place is not followed)."""
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o666)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
    except OSError as error:
        raise with_filename(error, tmp) from None


def _manifest_bytes(manifest: dict[str, Any]) -> bytes:
    return (json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode()


def _commit(folder: Path, staged: list[tuple[Path, Path, str]], previous: dict[str, Any],
            manifest: dict[str, Any]) -> None:
    """Write the journal (atomically: every staged file, its target and sha256, the previous and the new manifest),
    then rename the staged files in order — the manifest last — and remove the journal
    (:func:`bakery.files.recover_staged` applies the journal's ``pairs``)."""
    journal = {"format": JOURNAL_FORMAT, "version": 1, "pid": os.getpid(), "previous": previous,
               "manifest": manifest,
               "staged": [{"path": target.relative_to(folder).as_posix(), "name": tmp.name, "sha256": digest}
                          for tmp, target, digest in staged],
               "pairs": [[os.path.abspath(tmp), os.path.abspath(target)] for tmp, target, _ in staged]}
    write_bytes_atomic(folder / JOURNAL, json.dumps(journal).encode())
    recover_staged(folder / JOURNAL)


def _finish_interrupted_commit(folder: Path, staged: list[tuple[Path, Path, str]]) -> bool | None:
    """After an exception (SIGTERM, Ctrl-C, an OS error) during :func:`_commit`: complete the commit if the journal
    was written (as the next export would), so that no temporary file and no half-replaced export is left. Returns
    True if the export is committed, None if nothing was renamed (the journal was never written), False if
    completing failed too (the journal is left for the next export)."""
    journal = _read_journal(folder / JOURNAL)
    if journal is None:  # never written (every staged file is there) or already applied (none is)
        return None if any(tmp.exists() for tmp, _, _ in staged) else True
    try:
        _complete(folder, journal)
        _remove_temporaries(folder, set(), pids={os.getpid()})
    except BaseException:  # noqa: BLE001 - a second signal, or the file system fails again: the next run recovers
        return False
    return True


# ------------------------------------------------------------------------------------------------ recovery
def recover_folder(folder: Path, stale: dict[str, Any] | None = None) -> list[str]:
    """With the folder's export lock held: repair what a killed export left (module docstring, "Recovery"). ``stale``
    is the lock-file content of a dead export whose lock was taken over (its pid names its temporaries). Returns
    notes for warnings."""
    folder = Path(folder)
    notes = []
    journal = _read_journal(folder / JOURNAL)
    pids = set()
    if stale and isinstance(stale.get("pid"), int):
        pids.add(stale["pid"])
    owned = {MANIFEST, JOURNAL}
    if journal is not None:
        if isinstance(journal.get("pid"), int):
            pids.add(journal["pid"])
        renamed = _complete(folder, journal)
        owned |= set(_manifest_files(journal.get("manifest"))) | set(_manifest_files(journal.get("previous")))
        notes.append(f"completed an export that was interrupted while replacing its files ({renamed} staged "
                     f"file(s) renamed into place, {MANIFEST} brought up to date)" if journal else
                     f"removed an unreadable export journal {JOURNAL}")
    try:
        owned |= set(_read_manifest(folder)["files"])
    except InputError:
        pass  # an unreadable manifest: refused by the export that follows
    removed = _remove_temporaries(folder, owned, pids=pids)
    if removed:
        notes.append(f"removed {len(removed)} temporary file(s) of an interrupted export "
                     f"({', '.join(p.name for p in removed[:3])}{' …' if len(removed) > 3 else ''})")
    return notes


def _read_journal(path: Path) -> dict[str, Any] | None:
    """The journal at ``path``, None if there is none; {} if it is not one bakery can read (it is then only
    removed: journals are written atomically, so that does not happen to bakery's own)."""
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) and data.get("format") == JOURNAL_FORMAT else {}


def _manifest_files(manifest: Any) -> dict[str, dict[str, Any]]:
    files = manifest.get("files") if isinstance(manifest, dict) else None
    return {k: v for k, v in files.items() if isinstance(k, str) and isinstance(v, dict)} \
        if isinstance(files, dict) else {}


def _inside(folder: Path, relative: Any) -> Path | None:
    """``folder / relative`` if ``relative`` is a plain relative path inside the folder (no ``..``), else None."""
    if not isinstance(relative, str) or not relative or relative.startswith("/") or "\\" in relative:
        return None
    parts = relative.split("/")
    if any(p in ("", ".", "..") for p in parts):
        return None
    return folder.joinpath(*parts)


def _content(path: Path) -> str | None:
    """sha256 of a regular file, None if nothing is there, "" for anything else (a folder: never a match)."""
    if not os.path.lexists(path):
        return None
    if not path.is_file():
        return ""
    try:
        return sha256_file(path)
    except OSError:
        return ""


def _complete(folder: Path, journal: dict[str, Any]) -> int:
    """Finish the commit a journal describes: rename each staged file that is intact (its sha256) over its target
    if the target is still bakery's (missing, or holding the previous or the new content: a file a user changed
    meanwhile is left alone, and stays foreign), write the manifest that describes what is then on disk (per file
    the new entry, or the previous one if the file still holds the previous content), and remove the journal.
    Idempotent: a kill during it is completed by the next run the same way. Returns how many files it renamed."""
    path = folder / JOURNAL
    previous = _manifest_files(journal.get("previous"))
    new = _manifest_files(journal.get("manifest"))
    pairs: list[tuple[Path, Path]] = []
    for item in journal.get("staged") or []:
        if not isinstance(item, dict) or item.get("path") == MANIFEST:
            continue  # the manifest is written below, from what is on disk
        relative, name, digest = item.get("path"), item.get("name"), item.get("sha256")
        target = _inside(folder, relative)
        match = _TEMPORARY.fullmatch(name) if isinstance(name, str) else None
        if target is None or match is None or match["name"] != target.name or new.get(relative, {}).get(
                "sha256") != digest:
            continue
        tmp = target.with_name(name)
        if tmp.is_symlink() or not tmp.is_file() or _content(tmp) != digest:
            continue  # gone or damaged: removed with the other temporaries
        if _content(target) not in (None, digest, previous.get(relative, {}).get("sha256")):
            continue  # changed by someone since: not bakery's any more
        pairs.append((tmp, target))
    renamed = {target for _, target in pairs}
    files = {}
    for relative, entry in new.items():
        old = previous.get(relative)
        target = _inside(folder, relative)
        if old == entry or target is None or target in renamed:
            files[relative] = entry
            continue
        current = _content(target)
        files[relative] = old if old is not None and current != entry.get("sha256") and \
            current == old.get("sha256") else entry
    manifest = {**(journal["manifest"] if isinstance(journal.get("manifest"), dict) else {}), "files": files}
    manifest.setdefault("format", MANIFEST_FORMAT)
    manifest.setdefault("version", 1)
    if pairs:  # the journal names exactly these renames from now on (a kill below: the next run redoes this)
        write_bytes_atomic(path, json.dumps({**journal, "pairs": [[os.path.abspath(a), os.path.abspath(b)]
                                                                  for a, b in pairs]}).encode())
    if new:
        data = _manifest_bytes(manifest)
        try:
            same = (folder / MANIFEST).read_bytes() == data
        except OSError:
            same = False
        if not same:
            write_bytes_atomic(folder / MANIFEST, data)
    if pairs:
        recover_staged(path)  # renames them, then removes the journal
    else:
        path.unlink(missing_ok=True)
        fsync_directory(folder)
    return len(pairs)


def _remove_temporaries(folder: Path, owned: set[str], pids: set[int] = frozenset()) -> list[Path]:  # noqa: B006
    """Remove staged files (``.<name>.tmp-<pid>``) in ``folder``: anywhere under it those of ``pids`` (the dead export
    whose journal or lock names them, unless a process of that pid runs again: a reused pid), and beside each file of
    ``owned`` (paths relative to the folder) those of processes that are no longer running. Returns what was
    removed."""
    if pids:
        candidates = list(folder.rglob(".*.tmp-*"))
    else:
        folders = {folder}
        for relative in owned:
            target = _inside(folder, relative)
            if target is not None:
                folders.add(target.parent)
        candidates = [c for d in sorted(folders) if d.is_dir() for c in d.glob(".*.tmp-*")]
    removed = []
    for candidate in candidates:
        match = _TEMPORARY.fullmatch(candidate.name)
        if match is None or (candidate.is_dir() and not candidate.is_symlink()):
            continue
        pid = int(match["pid"])
        relative = (candidate.parent / match["name"]).relative_to(folder).as_posix()
        ours = pid == os.getpid()  # a commit of this process that failed: its own staged files
        if (pid in pids and (ours or not pid_alive(pid))) or (relative in owned and not ours and not pid_alive(pid)):
            try:
                candidate.unlink()
            except FileNotFoundError:
                continue
            removed.append(candidate)
    return removed


def default_layer(store_path: Path) -> Path | None:
    """The bake's layer beside the store (``<stem>.bake.usda`` / ``.usdc``), if it exists."""
    for suffix in (".usda", ".usdc", ".usd"):
        candidate = store_path.with_name(f"{store_path.stem}.bake{suffix}")
        if candidate.is_file():
            return candidate
    return None


def export_store(store_path: str | os.PathLike[str], output: str | os.PathLike[str], format: str,  # noqa: A002
                 profile: str | None = None, probes: str | None = None, options: dict[str, Any] | None = None,
                 layer: str | os.PathLike[str] | None | bool = None) -> ExportResult:
    """Export a store (module docstring). ``layer``: a baked layer path, None = the default layer if it exists,
    False = do not touch any layer.

    The layer is checked before anything is built or written (:func:`bakery.usd.layer.open_export_layer`): it must
    be a bakery baked-results layer of this store — never the scene's own layers or any other file, and there is no
    way to force it — else :class:`~bakery.errors.SceneError` (exit 2) and nothing is written. Its new content is
    staged with the export's files and renamed after them (:func:`write_files`), under the store's writer lock
    (:class:`bakery.files.FileLock`: exit 2 while a bake of the store runs). SIGTERM raises ``SystemExit(143)``
    meanwhile (:func:`bakery.files.terminate_as_exit`), so the cleanup runs as for any other error."""
    cls = get_format(format)
    prof = get_profile(profile or cls.default_profile)
    params = cls.Params.from_mapping(dict(options or {}), where=f"export {format}")
    store_path = Path(store_path)
    if not store_path.is_file():
        raise InputError(f"{store_path}: no such store")
    layer_path = None if layer is False else (Path(layer) if layer else default_layer(store_path))
    with ExitStack() as held:
        held.enter_context(terminate_as_exit())
        locked = layer_path is not None and folder_problem(store_path.parent) is None
        if locked:
            # the store's writer lock while the layer is read and replaced: a bake of the store writes the layer
            # too, and an export must not put back the attributes of a layer the bake has just replaced (a store
            # in a read-only folder has no writer to wait for)
            held.enter_context(FileLock(store_path))
        return _export_locked(store_path, output, format, cls, prof, params, probes, layer, layer_path, locked)


def _export_locked(store_path: Path, output: str | os.PathLike[str], format: str, cls: type[ExportFormat],
                   prof: Profile, params: Any, probes: str | None, layer: Any, layer_path: Path | None,
                   locked: bool = False) -> ExportResult:
    """:func:`export_store` once the store's lock is held (``locked``, when a layer is edited)."""
    from bakery.api import open_store

    with open_store(store_path, lazy=True) as store:  # the chains' levels read a block of probes at a time
        return _export_opened(store, store_path, output, format, cls, prof, params, probes, layer, layer_path,
                              locked)


def _export_opened(store: Any, store_path: Path, output: str | os.PathLike[str], format: str,  # noqa: A002
                   cls: type[ExportFormat], prof: Profile, params: Any, probes: str | None, layer: Any,
                   layer_path: Path | None, locked: bool) -> ExportResult:
    """:func:`_export_locked` with the store open (``bakery.api.ProbeStore``, lazy)."""
    from bakery.usd.layer import open_export_layer, staged_export_attributes

    selected = select_probes(store, probes)
    output = Path(output)
    _check_writable(output)
    target = None if layer_path is None else open_export_layer(layer_path, store_path, default=not layer)
    if target is not None and locked:  # the staged layer of a killed export or bake (dead processes only)
        removed = remove_stale_temporaries(target.path)
        if removed:
            warnings.warn(f"{target.path}: removed {len(removed)} temporary file(s) of an interrupted run "
                          f"({', '.join(p.name for p in removed[:3])})", BakeryWarning, stacklevel=3)
    context = ExportContext(store=store, probes=selected, profile=prof, params=params, format_name=format)
    record = {"format": format, "profile": prof.name, "store": os.path.relpath(store_path.resolve(),
                                                                              output.resolve())}

    def stage_layer(files: list[WrittenFile], stack: ExitStack) -> None:
        assets: dict[str, dict[str, str]] = {}
        for f in files:
            for probe in f.probes:
                assets.setdefault(probe, {})[f"{format}" + (f":{f.role}" if f.role else "")] = str(
                    os.path.relpath((output / f.path).resolve(), target.path.parent))
        stack.enter_context(staged_export_attributes(target, assets))

    manifest, files = write_files(output, cls().build(context), record, then=None if target is None else stage_layer)
    if not files:
        raise InputError(f"{store_path}: nothing to export as {format} (no selected probe of a kind it exports)")
    if probes is None:  # a whole-store export: files this format wrote before for probes it no longer has
        _warn_stale(output, format, {f.path for f in files})
    result = ExportResult(format, prof.name, output, [f.path for f in files], manifest)
    result.layer = None if target is None else target.path
    return result


def _warn_stale(folder: Path, format: str, written: set[str]) -> None:  # noqa: A002
    """Warn about files an earlier export of ``format`` wrote into ``folder`` (the manifest lists them) that this
    whole-store export did not write: probes removed from the store or renamed since. They are left in place (a
    manifest entry is not a licence to delete), but an engine that loads the folder would load them too."""
    stale = sorted(path for path, entry in _read_manifest(folder)["files"].items()
                   if entry.get("format") == format and path not in written and (folder / path).is_file())
    if stale:
        warnings.warn(f"{folder}: {len(stale)} file(s) of an earlier {format} export are not part of this one "
                      f"(probes removed from the store or renamed since: {', '.join(stale[:3])}"
                      f"{' …' if len(stale) > 3 else ''}); an engine loading the folder would load them too: remove "
                      f"them, or export into an empty folder", BakeryWarning, stacklevel=4)


def parse_options(pairs: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs → options; VALUE is read as JSON when it parses (numbers, true/false, lists), else as
    text."""
    options: dict[str, Any] = {}
    for pair in pairs:
        if "=" not in pair:
            raise ConfigError(f"--option takes KEY=VALUE, got {pair!r}")
        key, value = pair.split("=", 1)
        try:
            options[key.strip()] = json.loads(value)
        except ValueError:
            options[key.strip()] = value
    return options
