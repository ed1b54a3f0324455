"""A capture scene written once by the bake's parent process and read by workers without ``pxr`` or the stage.

Layout of a snapshot directory::

    scene.json       every field of the CaptureScene except the large arrays, plus the array manifest and the hash
    triangles.npy    (T, 3, 3) all meshes' triangles concatenated (mesh i is rows offsets[i]:offsets[i+1])
    uvs.npy          (U, 3, 2) texture coordinates of the meshes that have them, concatenated (only if any)
    normals.npy      (S, 3, 3) shading normals of the meshes that have them, concatenated (only if any)
    colors.npy       (C, 3, 3) per-corner colours of the meshes that read them, concatenated (only if any)
    dome.npy         (H, W, 3) dome pixels (only when the dome has a texture)
    texture_<i>.npy  (H, W, 4) pixels of CaptureScene.textures[i] (linear, float32)

Content hash
    ``content_hash`` = sha256 of the canonical JSON body (``scene.json`` without the ``content_hash`` key: sorted
    keys, compact separators), and the body records every array's dtype, shape, ``.npy`` file size and the sha256
    of its bytes, so the hash covers the arrays too. It does not depend on the directory, and numpy scalars hash as
    the Python scalars they equal (a scene read back hashes like the original). :func:`read_capture_scene` checks
    the JSON hash and the array files' sizes, dtypes and shapes (cheap); ``verify=True`` also re-hashes the arrays.

Types
    Field values are written by a small tagged JSON encoding that keeps Python types: JSON arrays are tuples,
    lists are ``{"__list__": [...]}``, dicts with non-string (or tag-like) keys are ``{"__dict__": [[k, v], ...]}``
    and small numpy arrays inside fields are ``{"__ndarray__": ...}``. Floats are written with ``repr`` and read
    back exactly (NaN and ±inf included). Numpy scalars (e.g. the ``np.float64`` entries of a rotation read from
    USD) come back as the equal Python ``float``/``int``/``bool``.

Atomicity
    The snapshot is written into a fresh temporary sibling directory, fsync'ed and renamed into place. If the
    target already holds a valid snapshot with the same content hash it is left untouched (and nothing is written).
    A different snapshot at the target is moved aside, replaced and removed.

This module uses only numpy, json and the standard library (no ``pxr``, ``h5py`` or OpenImageIO).
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from bakery.capture.ies import IesProfile, IesShaping
from bakery.capture.scene import CaptureScene, Dome, Light, Material, Mesh, ProbeSpec, Texture
from bakery.errors import InputError
from bakery.files import sha256_bytes

__all__ = ["SNAPSHOT_FORMAT", "SNAPSHOT_VERSION", "read_capture_scene", "scene_content_hash", "write_capture_scene"]

SNAPSHOT_FORMAT = "bakery.capture-scene"
SNAPSHOT_VERSION = 2
SCENE_JSON = "scene.json"
_ARRAY_FILES = {"triangles": "triangles.npy", "dome": "dome.npy", "uvs": "uvs.npy", "normals": "normals.npy",
                "colors": "colors.npy"}
#: Mesh fields stored as slices of the concatenated arrays (or, for the material, as its own record).
_MESH_ARRAYS = ("triangles", "material", "uvs", "normals", "colors")


def _array_file(name: str) -> str | None:
    """File name of a snapshot array (fixed names, plus ``texture_<i>``)."""
    if name in _ARRAY_FILES:
        return _ARRAY_FILES[name]
    if name.startswith("texture_") and name[len("texture_"):].isdigit():
        return f"{name}.npy"
    return None
_TAGS = ("__list__", "__dict__", "__ndarray__", "__float__")


# ----------------------------------------------------------------------------------------------------------------
# Tagged JSON values
def _encode(value: Any) -> Any:
    """A JSON-able form of ``value`` that :func:`_decode` turns back into an equal value of the same type."""
    kind = type(value)  # exact built-in types first (a scene has thousands of probes): same result, fewer checks
    if kind is str or kind is int or kind is bool or value is None:
        return value
    if kind is float:
        return value if math.isfinite(value) else {"__float__": repr(value)}
    if kind is tuple:
        return [_encode(v) for v in value]
    if isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.generic):
        return _encode(value.item())
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        value = float(value)
        if not math.isfinite(value):  # strict JSON has no NaN/Infinity
            return {"__float__": repr(value)}
        return value
    if isinstance(value, tuple):
        return [_encode(v) for v in value]
    if isinstance(value, list):
        return {"__list__": [_encode(v) for v in value]}
    if isinstance(value, dict):
        if all(isinstance(k, str) and k not in _TAGS for k in value):
            return {k: _encode(v) for k, v in value.items()}
        return {"__dict__": [[_encode(k), _encode(v)] for k, v in value.items()]}
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        if array.dtype.kind not in "biuf":
            raise TypeError(f"cannot snapshot a numpy array of dtype {array.dtype}")
        return {"__ndarray__": _encode(tuple(array.ravel().tolist())), "dtype": array.dtype.str,
                "shape": list(array.shape)}
    raise TypeError(f"cannot snapshot a value of type {type(value).__name__}: {value!r}")


def _decode(value: Any) -> Any:
    if isinstance(value, list):  # JSON scalars are their own decoding: no call for them (thousands of probes)
        return tuple([_decode(v) if type(v) is list or type(v) is dict else v for v in value])
    if isinstance(value, dict):
        if "__list__" in value:
            return [_decode(v) for v in value["__list__"]]
        if "__dict__" in value:
            return {_decode(k): _decode(v) for k, v in value["__dict__"]}
        if "__float__" in value:
            return float(value["__float__"])
        if "__ndarray__" in value:
            flat = np.array(_decode(value["__ndarray__"]), dtype=np.dtype(value["dtype"]))
            return flat.reshape(tuple(value["shape"]))
        return {k: _decode(v) for k, v in value.items()}
    return value


_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


def _field_names(cls: type) -> tuple[str, ...]:
    """A dataclass's field names, once per class (a scene has thousands of probes)."""
    names = _FIELD_NAMES.get(cls)
    if names is None:
        names = _FIELD_NAMES[cls] = tuple(f.name for f in dataclasses.fields(cls))
    return names


def _fields(obj: Any, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    return {name: _encode(getattr(obj, name)) for name in _field_names(type(obj)) if name not in skip}


def _build(cls: type, record: dict[str, Any], **extra: Any) -> Any:
    names = _field_names(cls)
    values = {k: _decode(v) if type(v) is list or type(v) is dict else v for k, v in record.items() if k in names}
    values.update(extra)
    return cls(**values)


def _light_record(light: Light) -> dict[str, Any]:
    """A light's fields, its IES shaping as a nested record (only when it has one: the hash of a scene without
    profiles is unchanged)."""
    record = _fields(light, skip=("ies",))
    if light.ies is not None:
        record["ies"] = {**_fields(light.ies, skip=("profile",)), "profile": _fields(light.ies.profile)}
    return record


def _light(record: dict[str, Any]) -> Light:
    ies = record.get("ies")
    if ies is None:
        return _build(Light, record)
    profile = _build(IesProfile, ies["profile"])
    return _build(Light, {k: v for k, v in record.items() if k != "ies"},
                  ies=_build(IesShaping, {k: v for k, v in ies.items() if k != "profile"}, profile=profile))


def _dumps(body: dict[str, Any]) -> bytes:
    return json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode()


# ----------------------------------------------------------------------------------------------------------------
# Arrays
def _npy_header(array: np.ndarray) -> bytes:
    """The ``.npy`` (format 1.0) header numpy writes for ``array`` (depends only on its dtype and shape)."""
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, np.lib.format.header_data_from_array_1_0(array))
    return buffer.getvalue()


def _array_entry(array: np.ndarray) -> dict[str, Any]:
    return {
        "file": None,  # filled by the caller
        "dtype": array.dtype.str,
        "shape": list(array.shape),
        "file_size": len(_npy_header(array)) + array.nbytes,
        "sha256": sha256_bytes(memoryview(array).cast("B")) if array.size else sha256_bytes(b""),
    }


def _concatenated_triangles(meshes: tuple[Mesh, ...]) -> tuple[np.ndarray, list[int]]:
    """All meshes' triangles as one C-contiguous little-endian (T, 3, 3) array and the offsets table (len M + 1)."""
    arrays = []
    for mesh in meshes:
        tris = np.asarray(mesh.triangles)
        if tris.size % 9:
            raise ValueError(f"mesh {mesh.name!r}: triangles of shape {tris.shape} are not (T, 3, 3)")
        arrays.append(tris.reshape(-1, 3, 3))
    dtype = np.result_type(*arrays) if arrays else np.dtype(np.float32)
    dtype = dtype.newbyteorder("<")
    offsets = [0]
    for tris in arrays:
        offsets.append(offsets[-1] + tris.shape[0])
    if len(arrays) == 1 and arrays[0].dtype == dtype:
        return np.ascontiguousarray(arrays[0]), offsets
    if not arrays:
        return np.zeros((0, 3, 3), dtype=dtype), offsets
    return np.concatenate(arrays, axis=0, dtype=dtype), offsets


def _little(array: np.ndarray) -> np.ndarray:
    array = np.asarray(array)
    return np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<"))


def _dome_pixels(dome: Dome | None) -> np.ndarray | None:
    if dome is None or dome.pixels is None:
        return None
    return _little(dome.pixels)


def _concatenated(meshes: tuple[Mesh, ...], attribute: str) -> tuple[np.ndarray | None, list[dict | None]]:
    """A per-corner mesh attribute (``uvs`` (T, 3, 2) or ``normals`` (T, 3, 3)) of the meshes that have it as one
    array, and per mesh its slice record (None if the mesh has none)."""
    arrays, records, start = [], [], 0
    for mesh in meshes:
        value = getattr(mesh, attribute)
        if value is None:
            records.append(None)
            continue
        value = np.asarray(value)
        arrays.append(value.reshape(-1, 3, value.shape[-1]))
        records.append({"start": start, "stop": start + arrays[-1].shape[0], "shape": list(value.shape),
                        "dtype": value.dtype.str})
        start += arrays[-1].shape[0]
    if not arrays:
        return None, records
    dtype = np.result_type(*arrays).newbyteorder("<")
    return np.ascontiguousarray(np.concatenate(arrays, axis=0, dtype=dtype)), records


def _snapshot_body(scene: CaptureScene) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The JSON body (without ``content_hash``) and the arrays to write, by name."""
    triangles, offsets = _concatenated_triangles(scene.meshes)
    arrays: dict[str, np.ndarray] = {"triangles": triangles}
    pixels = _dome_pixels(scene.dome)
    if pixels is not None:
        arrays["dome"] = pixels
    uvs, uv_records = _concatenated(scene.meshes, "uvs")
    if uvs is not None:
        arrays["uvs"] = uvs
    normals, normal_records = _concatenated(scene.meshes, "normals")
    if normals is not None:
        arrays["normals"] = normals
    colors, color_records = _concatenated(scene.meshes, "colors")
    if colors is not None:
        arrays["colors"] = colors
    textures = []
    for i, texture in enumerate(scene.textures):
        arrays[f"texture_{i}"] = _little(texture.pixels)
        record = _fields(texture, skip=("pixels",))
        record["pixels"] = f"texture_{i}"
        textures.append(record)
    manifest = {}
    for name, array in arrays.items():
        entry = _array_entry(array)
        entry["file"] = _array_file(name)
        manifest[name] = entry
    meshes = []
    for mesh, start, stop, uv_record, normal_record, color_record in zip(
            scene.meshes, offsets[:-1], offsets[1:], uv_records, normal_records, color_records):
        tris = np.asarray(mesh.triangles)
        record = _fields(mesh, skip=_MESH_ARRAYS)
        record["material"] = _fields(mesh.material)
        record["triangles"] = {"start": start, "stop": stop, "shape": list(tris.shape), "dtype": tris.dtype.str}
        record["uvs"] = uv_record
        if normal_record is not None:  # only when authored: a scene without normals hashes as before
            record["normals"] = normal_record
        if color_record is not None:  # likewise per-vertex colours
            record["colors"] = color_record
        meshes.append(record)
    dome = None
    if scene.dome is not None:
        dome = _fields(scene.dome, skip=("pixels",))
        dome["pixels"] = "dome" if pixels is not None else None
    body = {
        "format": SNAPSHOT_FORMAT,
        "version": SNAPSHOT_VERSION,
        "arrays": manifest,
        "triangle_offsets": offsets,
        "meshes": meshes,
        "lights": [_light_record(light) for light in scene.lights],
        "portals": [_light_record(light) for light in scene.portals],
        "textures": textures,
        "dome": dome,
        "probes": [_fields(probe) for probe in scene.probes],
        "scene": _fields(scene, skip=("meshes", "lights", "dome", "probes", "textures", "portals")),
    }
    return body, arrays


def scene_content_hash(scene: CaptureScene) -> str:
    """The content hash :func:`write_capture_scene` would return for ``scene`` (nothing is written)."""
    body, _arrays = _snapshot_body(scene)
    return sha256_bytes(_dumps(body))


# ----------------------------------------------------------------------------------------------------------------
# Writing
def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_npy(path: Path, array: np.ndarray) -> None:
    with open(path, "wb") as handle:
        handle.write(_npy_header(array))
        if array.size:
            handle.write(memoryview(array).cast("B"))
        handle.flush()
        os.fsync(handle.fileno())


def _existing_hash(directory: Path) -> str | None:
    """The content hash of a valid (cheaply checked) snapshot at ``directory``, else None."""
    try:
        return _read_manifest(directory)[0]
    except InputError:
        return None


def write_capture_scene(scene: CaptureScene, directory: str | os.PathLike[str]) -> str:
    """Write ``scene`` as a snapshot directory (atomically) and return its content hash.

    If ``directory`` already holds a valid snapshot with the same hash it is left as it is."""
    directory = Path(directory)
    body, arrays = _snapshot_body(scene)
    body_bytes = _dumps(body)
    content_hash = sha256_bytes(body_bytes)
    if _existing_hash(directory) == content_hash:
        return content_hash
    directory.parent.mkdir(parents=True, exist_ok=True)
    tag = f"{os.getpid()}-{uuid.uuid4().hex[:12]}"
    tmp = directory.with_name(f".{directory.name}.tmp-{tag}")
    tmp.mkdir()
    try:
        for name, array in arrays.items():
            _write_npy(tmp / _array_file(name), array)
        document = dict(body, content_hash=content_hash)
        with open(tmp / SCENE_JSON, "wb") as handle:
            handle.write(_dumps(document))
            handle.flush()
            os.fsync(handle.fileno())
        _fsync(tmp)
        _place(tmp, directory, content_hash, tag)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    _fsync(directory.parent)
    return content_hash


def _place(tmp: Path, directory: Path, content_hash: str, tag: str) -> None:
    """Rename the finished ``tmp`` to ``directory``, replacing a different snapshot there."""
    for _attempt in range(5):
        try:
            os.rename(tmp, directory)  # succeeds if directory is absent (or an empty directory)
            return
        except OSError:
            if not directory.exists() and not directory.is_symlink():
                raise
        if _existing_hash(directory) == content_hash:  # another writer placed the same snapshot
            return
        if not directory.is_dir() or directory.is_symlink():
            raise InputError(f"{directory}: exists and is not a capture scene snapshot directory")
        old = directory.with_name(f".{directory.name}.old-{tag}")
        try:
            os.rename(directory, old)
        except FileNotFoundError:  # someone else moved it away meanwhile: retry
            continue
        try:
            os.rename(tmp, directory)
            return
        except OSError:
            continue  # a concurrent writer got in first: compare with theirs
        finally:
            shutil.rmtree(old, ignore_errors=True)
    raise InputError(f"{directory}: could not place the capture scene snapshot (concurrent writers?)")


# ----------------------------------------------------------------------------------------------------------------
# Reading
def _read_manifest(directory: Path) -> tuple[str, dict[str, Any]]:
    """(content hash, body) of the snapshot at ``directory`` after the cheap checks (JSON hash, file sizes)."""
    path = directory / SCENE_JSON
    if not directory.is_dir():
        raise InputError(f"{directory}: capture scene snapshot not found")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{directory}: not a capture scene snapshot (no {SCENE_JSON})") from None
    except OSError as exc:
        raise InputError(f"{directory}: cannot read {SCENE_JSON}: {exc}") from None
    try:
        document = json.loads(raw)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"{directory}: {SCENE_JSON} is truncated or not JSON ({exc})") from None
    if not isinstance(document, dict) or document.get("format") != SNAPSHOT_FORMAT:
        raise InputError(f"{directory}: {SCENE_JSON} is not a bakery capture scene snapshot")
    if document.get("version") != SNAPSHOT_VERSION:
        raise InputError(f"{directory}: capture scene snapshot version {document.get('version')!r} is not supported "
                         f"(expected {SNAPSHOT_VERSION})")
    stored = document.pop("content_hash", None)
    try:
        actual = sha256_bytes(_dumps(document))
    except ValueError as exc:
        raise InputError(f"{directory}: {SCENE_JSON} is malformed ({exc})") from None
    if stored != actual:
        raise InputError(f"{directory}: capture scene snapshot hash mismatch ({SCENE_JSON} stored {stored!r}, "
                         f"content {actual})")
    try:
        for name, entry in document["arrays"].items():
            if _array_file(name) != entry["file"]:
                raise InputError(f"{directory}: {SCENE_JSON} names an unexpected array file {entry['file']!r}")
            file = directory / entry["file"]
            try:
                size = file.stat().st_size
            except FileNotFoundError:
                raise InputError(f"{directory}: capture scene snapshot is missing {entry['file']}") from None
            if size != entry["file_size"]:
                raise InputError(f"{directory}: {entry['file']} is truncated or corrupt ({size} bytes, expected "
                                 f"{entry['file_size']})")
    except (KeyError, TypeError, AttributeError) as exc:
        raise InputError(f"{directory}: {SCENE_JSON} is malformed (bad array manifest: {exc!r})") from None
    return actual, document


def _load_array(directory: Path, entry: dict[str, Any], mmap: bool, verify: bool) -> np.ndarray:
    file = directory / entry["file"]
    try:
        if mmap and math.prod(entry["shape"]) > 0:  # numpy cannot map an empty array
            array = np.load(file, mmap_mode="r", allow_pickle=False)
        else:
            array = np.load(file, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"{directory}: {entry['file']} cannot be read ({exc})") from None
    if array.dtype.str != entry["dtype"] or list(array.shape) != list(entry["shape"]):
        raise InputError(f"{directory}: {entry['file']} has dtype {array.dtype.str} shape {list(array.shape)}, "
                         f"expected {entry['dtype']} {entry['shape']}")
    if verify:
        digest = sha256_bytes(memoryview(np.ascontiguousarray(array)).cast("B")) if array.size else sha256_bytes(b"")
        if digest != entry["sha256"]:
            raise InputError(f"{directory}: {entry['file']} content does not match the snapshot hash")
    return array.view(np.ndarray) if isinstance(array, np.memmap) else array


def _slice(array: np.ndarray, info: dict[str, Any]) -> np.ndarray:
    view = array[info["start"]:info["stop"]]
    if view.dtype.str != info["dtype"]:
        view = view.astype(np.dtype(info["dtype"]))
    return view.reshape(tuple(info["shape"]))


def read_capture_scene(directory: str | os.PathLike[str], mmap: bool = True, verify: bool = False) -> CaptureScene:
    """Read a snapshot written by :func:`write_capture_scene`.

    Arrays are memory-mapped read-only when ``mmap`` (worker processes share the pages); every mesh's triangles
    are a view into the one ``triangles.npy`` array. The JSON hash and the array files' sizes, dtypes and shapes
    are always checked; ``verify`` also re-hashes the array bytes. Raises InputError (naming ``directory``) if the
    snapshot is missing, truncated, corrupt or of another format version."""
    directory = Path(directory)
    _hash, body = _read_manifest(directory)
    try:
        arrays = {name: _load_array(directory, entry, mmap, verify) for name, entry in body["arrays"].items()}
        triangles = arrays["triangles"]
        meshes = []
        for record in body["meshes"]:
            view = _slice(triangles, record["triangles"])
            slices = {name: _slice(arrays[name], record[name]) if record.get(name) is not None else None
                      for name in ("uvs", "normals", "colors")}
            material = _build(Material, record["material"])
            meshes.append(_build(Mesh, {k: v for k, v in record.items() if k not in _MESH_ARRAYS},
                                 triangles=view, material=material, **slices))
        lights = tuple(_light(record) for record in body["lights"])
        portals = tuple(_light(record) for record in body["portals"])
        textures = tuple(_build(Texture, {k: v for k, v in record.items() if k != "pixels"},
                                pixels=arrays[record["pixels"]]) for record in body["textures"])
        dome = None
        if body["dome"] is not None:
            record = dict(body["dome"])
            key = record.pop("pixels")
            dome = _build(Dome, record, pixels=arrays[key] if key is not None else None)
        probes = tuple(_build(ProbeSpec, record) for record in body["probes"])
        return _build(CaptureScene, body["scene"], meshes=tuple(meshes), lights=lights, dome=dome, probes=probes,
                      textures=textures, portals=portals)
    except InputError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
        raise InputError(f"{directory}: {SCENE_JSON} is malformed ({type(exc).__name__}: {exc})") from None
