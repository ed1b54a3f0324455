"""The export plug-in contract and the one export path: formats declared once, files written all-or-nothing.

An export format is one module of ``bakery/export/`` with an :class:`ExportFormat` subclass (``name``,
``description``, ``default_profile``, a frozen dataclass ``Params`` of typed options — the same
:class:`~bakery.encodings.base.EncodingParams` machinery as the encodings: wrong types, unknown keys and
out-of-range values are exit 3 — and ``build(context)``, a generator of :class:`ExportedFile`), registered with
:func:`register_format` at the bottom of the module and imported in ``bakery/export/__init__.py``. The CLI
(``bakery export``), the recipe key ``exports`` and ``tests/export/test_export.py``'s conformance suite pick formats
up from :data:`EXPORT_FORMATS`.

:func:`export_store` is the only writer:

1. the format, profile and options are checked (ConfigError, exit 3), the store is opened (exit 2 if it is not one),
   the output folder must be creatable and writable (exit 2), and the USD layer of the bake (``--layer``, default
   ``<store stem>.bake.usda`` / ``.usdc`` beside the store when it exists) must be a bakery baked-results layer
   that records this store (:func:`bakery.usd.layer.open_export_layer`): the scene's own layers, a user's file, a
   text file, a missing ``--layer`` or another store's layer are exit 2 — before anything is built or written, and
   there is no ``--force`` for it (an export never edits a layer bakery does not own);
2. the format yields its files one at a time (``build`` is a generator: a store without the encodings it needs is
   exit 2 before the first file; reflection formats prefilter a chunk of probes at a time,
   :class:`bakery.export.source.ProfileChains`), and each is staged at once — written to a temporary file beside its
   target (:func:`bakery.files.atomic_replace`) and dropped from memory, so an export holds one chunk, not the whole
   output;
3. files already in the folder are overwritten only if the folder's manifest ``bakery-export.json`` lists them with
   their current sha256 (i.e. bakery wrote them and nobody changed them); any other existing file is *foreign* and
   the export is refused (exit 2) before any target is replaced;
4. once every file is staged (fsync'ed), the layer is staged too, with ``bakery:export:<format>`` asset attributes
   on each exported probe (:func:`bakery.usd.layer.staged_export_attributes`); then all files are renamed; a
   failure before the renames (a foreign file, a format error, a layer USD cannot write, a full disk) removes the
   temporaries and the folders the export created, so nothing is left;
5. the manifest is updated after the files, then the staged layer is renamed over the layer.
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from bakery.encodings.base import EncodingParams, NoParams
from bakery.errors import ConfigError, InputError
from bakery.export.profiles import Profile, get_profile
from bakery.files import FileLock, atomic_replace, folder_problem, sha256_bytes, sha256_file

MANIFEST = "bakery-export.json"
MANIFEST_FORMAT = "bakery.export"


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


def slug(name: str) -> str:
    """A file-name-safe form of a probe name: ``/Room/Probes/Volume[1,2,0]`` → ``Room_Probes_Volume_1_2_0``."""
    s = re.sub(r"[^A-Za-z0-9_.-]+", "_", name.strip("/")).strip("_")
    return s or "probe"


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


def _foreign(folder: Path, f: ExportedFile, manifest: dict[str, Any]) -> str | None:
    """Why ``f`` may not replace what is at its target (a folder, or a file bakery did not write or that changed
    since), or None."""
    target = folder / f.path
    if target.is_dir():
        return f"{f.path} (a folder)"
    if not target.exists():
        return None
    entry = manifest["files"].get(f.path)
    return f.path if entry is None or entry.get("sha256") != sha256_file(target) else None


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
    """Stage every file of ``files`` as it comes, then rename them all and write the updated manifest,
    all-or-nothing (module docstring, steps 2–5). Returns the manifest path and the files written; when ``files``
    is empty nothing is written (and no folder is left behind).

    ``then(written, stack)``, called once every file is staged (and none is foreign) but before any is renamed, may
    stage more files in ``stack`` (e.g. the USD layer): they are renamed after the files and the manifest, and an
    error in ``then`` removes every staged file, so nothing is written."""
    folder = Path(folder)
    _check_writable(folder)
    manifest = _read_manifest(folder)
    created: list[Path] = []
    written: list[WrittenFile] = []
    seen: dict[str, tuple[str, ...]] = {MANIFEST: ()}  # file → the probes it holds
    foreign: list[str] = []
    new_manifest = not (folder / MANIFEST).exists()
    manifest_written = False
    try:
        with ExitStack() as late:  # what ``then`` staged: renamed last
            with ExitStack() as stack:  # leaving it renames every staged file; an error removes them instead
                for f in files:
                    if f.path in seen:
                        probes = ", ".join(dict.fromkeys([*seen[f.path], *f.probes])) or "bakery's manifest"
                        raise InputError(f"{folder / f.path}: two exported files have this name ({probes}: probe "
                                         f"names that differ only in punctuation?); export them to separate folders "
                                         f"with --probes")
                    seen[f.path] = tuple(f.probes)
                    reason = _foreign(folder, f, manifest)
                    if reason:
                        foreign.append(reason)
                        continue
                    _make_parents(folder / f.path, created)
                    tmp = stack.enter_context(atomic_replace(folder / f.path))
                    tmp.write_bytes(f.data)
                    manifest["files"][f.path] = {"sha256": sha256_bytes(f.data), **record, "role": f.role,
                                                 "probes": list(f.probes)}
                    written.append(WrittenFile(f.path, tuple(f.probes), f.role))
                if foreign:
                    raise InputError(f"{folder}: refusing to overwrite file(s) bakery did not write or that changed "
                                     f"since ({', '.join(sorted(foreign)[:5])}{' …' if len(foreign) > 5 else ''}); "
                                     f"choose another folder or remove them")
                if written and then is not None:
                    then(written, late)
            if written:
                # the manifest after the files: a crash between the renames and here leaves files the manifest
                # does not list, which the next export refuses to overwrite (safe side)
                with atomic_replace(folder / MANIFEST) as tmp:
                    tmp.write_bytes((json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode())
                manifest_written = True
    except BaseException:
        _remove_written(folder, written, created, folder / MANIFEST if manifest_written and new_manifest else None)
        raise
    return folder / MANIFEST, written


def _remove_written(folder: Path, written: list[WrittenFile], created: list[Path],
                    manifest: Path | None = None) -> None:
    """After a failed export: the files it renamed into folders it created (and the ``manifest`` it created, if
    given, when its folder is one of them), then those folders if empty."""
    for w in written:
        target = folder / w.path
        if target.parent in created and target.exists():
            target.unlink()
    if manifest is not None and manifest.parent in created and manifest.exists():
        manifest.unlink()
    for d in reversed(created):
        if d.exists() and not any(d.iterdir()):
            d.rmdir()


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
    (:class:`bakery.files.FileLock`: exit 2 while a bake of the store runs)."""
    cls = get_format(format)
    prof = get_profile(profile or cls.default_profile)
    params = cls.Params.from_mapping(dict(options or {}), where=f"export {format}")
    store_path = Path(store_path)
    if not store_path.is_file():
        raise InputError(f"{store_path}: no such store")
    layer_path = None if layer is False else (Path(layer) if layer else default_layer(store_path))
    with ExitStack() as held:
        if layer_path is not None and folder_problem(store_path.parent) is None:
            # the store's writer lock while the layer is read and replaced: a bake of the store writes the layer
            # too, and an export must not put back the attributes of a layer the bake has just replaced (a store
            # in a read-only folder has no writer to wait for)
            held.enter_context(FileLock(store_path))
        return _export_locked(store_path, output, format, cls, prof, params, probes, layer, layer_path)


def _export_locked(store_path: Path, output: str | os.PathLike[str], format: str, cls: type[ExportFormat],
                   prof: Profile, params: Any, probes: str | None, layer: Any, layer_path: Path | None
                   ) -> ExportResult:
    """:func:`export_store` once the store's lock is held (when a layer is edited)."""
    from bakery.api import open_store
    from bakery.usd.layer import open_export_layer, staged_export_attributes

    store = open_store(store_path)
    selected = select_probes(store, probes)
    output = Path(output)
    _check_writable(output)
    target = None if layer_path is None else open_export_layer(layer_path, store_path, default=not layer)
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
    result = ExportResult(format, prof.name, output, [f.path for f in files], manifest)
    result.layer = None if target is None else target.path
    return result


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
