"""The export plug-in contract and the one export path: formats declared once, files written all-or-nothing.

An export format is one module of ``bakery/export/`` with an :class:`ExportFormat` subclass (``name``,
``description``, ``default_profile``, a frozen dataclass ``Params`` of typed options — the same
:class:`~bakery.encodings.base.EncodingParams` machinery as the encodings: wrong types, unknown keys and
out-of-range values are exit 3 — and ``build(context) -> [ExportedFile]``), registered with :func:`register_format`
at the bottom of the module and imported in ``bakery/export/__init__.py``. The CLI (``bakery export``), the recipe
key ``exports`` and ``tests/export/test_export_conformance.py`` pick formats up from :data:`EXPORT_FORMATS`.

:func:`export_store` is the only writer:

1. the format, profile and options are checked (ConfigError, exit 3), the store is opened (exit 2 if it is not one),
   the output folder must be creatable and writable (exit 2);
2. the format builds every file in memory (a store without the encodings it needs is exit 2 before any write);
3. files already in the folder are overwritten only if the folder's manifest ``bakery-export.json`` lists them with
   their current sha256 (i.e. bakery wrote them and nobody changed them); any other existing file is *foreign* and
   the export is refused (exit 2) before anything is written;
4. every file is written to a temporary file beside its target, fsync'ed, then all are renamed
   (:func:`bakery.files.atomic_replace`); a failure before the renames removes the temporaries and the folders the
   export created, so nothing is left;
5. the manifest is updated last, then the USD layer of the bake (``--layer``, default ``<store stem>.bake.usda`` /
   ``.usdc`` beside the store when it exists and names this store) gets ``bakery:export:<format>`` asset attributes
   on each exported probe (:func:`bakery.usd.layer.add_export_attributes`, atomic).
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
from abc import ABC, abstractmethod
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from bakery.encodings.base import EncodingParams, NoParams
from bakery.errors import ConfigError, InputError
from bakery.export.profiles import Profile, get_profile
from bakery.files import atomic_replace, sha256_bytes, sha256_file

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

    def provenance(self) -> dict[str, Any]:
        """What every exported file records about its origin (metadata / KVD / extras)."""
        from bakery.conventions import CONVENTIONS

        return {"generator": "bakery", "store": os.path.basename(self.store.path),
                "settings_hash": str(self.store.attributes.get("settings_hash", "")),
                "conventions": CONVENTIONS}


class ExportFormat(ABC):
    """An export format (see the module docstring)."""

    name: ClassVar[str]
    description: ClassVar[str]
    default_profile: ClassVar[str]
    Params: ClassVar[type[EncodingParams]] = NoParams

    @abstractmethod
    def build(self, context: ExportContext) -> list[ExportedFile]:
        """Every file of the export, in memory. Raise :class:`InputError` if the store lacks what is needed."""


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


def _check_foreign(folder: Path, files: list[ExportedFile], manifest: dict[str, Any]) -> None:
    foreign = []
    for f in files:
        target = folder / f.path
        if target.is_dir():
            foreign.append(f"{f.path} (a folder)")
            continue
        if not target.exists():
            continue
        entry = manifest["files"].get(f.path)
        if entry is None or entry.get("sha256") != sha256_file(target):
            foreign.append(f.path)
    if foreign:
        raise InputError(f"{folder}: refusing to overwrite file(s) bakery did not write or that changed since "
                         f"({', '.join(sorted(foreign)[:5])}{' …' if len(foreign) > 5 else ''}); choose another "
                         f"folder or remove them")
    names = [f.path for f in files]
    if len(set(names)) != len(names) or MANIFEST in names:
        raise InputError("export produced duplicate file names (probe names that differ only in punctuation?)")


def write_files(folder: Path, files: list[ExportedFile], record: dict[str, Any]) -> Path:
    """Write ``files`` and the updated manifest all-or-nothing (module docstring, steps 3–5). Returns the
    manifest path."""
    folder = Path(folder)
    _check_writable(folder)
    manifest = _read_manifest(folder)
    _check_foreign(folder, files, manifest)
    created: list[Path] = []
    needed = sorted({(folder / f.path).parent for f in files} | {folder}, key=lambda p: len(p.parts))
    try:
        for d in needed:
            missing = []
            probe = d
            while not probe.exists():
                missing.append(probe)
                probe = probe.parent
            for m in reversed(missing):
                m.mkdir()
                created.append(m)
        for f in files:
            manifest["files"][f.path] = {"sha256": sha256_bytes(f.data), **record, "role": f.role,
                                         "probes": list(f.probes)}
        manifest_bytes = (json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode()
        with ExitStack() as stack:
            for f in files:
                tmp = stack.enter_context(atomic_replace(folder / f.path))
                tmp.write_bytes(f.data)
        # the manifest last: a crash between the renames and here leaves files the manifest does not list, which the
        # next export refuses to overwrite (safe side)
        with atomic_replace(folder / MANIFEST) as tmp:
            tmp.write_bytes(manifest_bytes)
    except BaseException:
        for f in files:
            target = folder / f.path
            if target.parent in created and target.exists():
                target.unlink()
        for d in reversed(created):
            if d.exists() and not any(d.iterdir()):
                d.rmdir()
        raise
    return folder / MANIFEST


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
    False = do not touch any layer."""
    from bakery.api import open_store

    cls = get_format(format)
    prof = get_profile(profile or cls.default_profile)
    params = cls.Params.from_mapping(dict(options or {}), where=f"export {format}")
    store_path = Path(store_path)
    if not store_path.is_file():
        raise InputError(f"{store_path}: no such store")
    store = open_store(store_path)
    selected = select_probes(store, probes)
    output = Path(output)
    _check_writable(output)
    context = ExportContext(store=store, probes=selected, profile=prof, params=params, format_name=format)
    files = cls().build(context)
    if not files:
        raise InputError(f"{store_path}: nothing to export as {format} (no selected probe of a kind it exports)")
    record = {"format": format, "profile": prof.name, "store": os.path.relpath(store_path.resolve(),
                                                                              output.resolve())}
    manifest = write_files(output, files, record)
    result = ExportResult(format, prof.name, output, [f.path for f in files], manifest)
    layer_path = None if layer is False else (Path(layer) if layer else default_layer(store_path))
    if layer_path is not None:
        from bakery.usd.layer import add_export_attributes

        assets: dict[str, dict[str, str]] = {}
        for f in files:
            for probe in f.probes:
                assets.setdefault(probe, {})[f"{format}" + (f":{f.role}" if f.role else "")] = str(
                    os.path.relpath((output / f.path).resolve(), layer_path.resolve().parent))
        result.layer = add_export_attributes(layer_path, assets, store_path=store_path)
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
