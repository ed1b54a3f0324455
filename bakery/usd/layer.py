"""The baked-results layer: an ``over`` per probe prim carrying its encodings as USD attributes.

The layer never edits the user's layers. It holds only ``over`` specs (typeless, so the scene's probe types show
through), each with the ``BakeryBakedProbeAPI`` schema applied and:

==========================================  ====================================================================
attribute                                   value
==========================================  ====================================================================
``bakery:<kind>:<encoding>:<field>``        the field's values: float3[] when the last axis is RGB, else float[]
                                            (uchar[] for 8-bit, int[] for other integer fields,
                                            :func:`usd_type_for`), declared with its type and documentation
                                            by ``BakeryBakedProbeAPI`` (generated from the registry); customData
                                            ``shape`` = per-probe shape, ``probeCount`` = probes in the array
``bakery:settings:<encoding>:<key>``        uniform; the encoding settings the shaders take (:func:`runtime_settings`:
                                            the ``setting`` arguments, variant conditions and chain settings of
                                            ``bakery/shaders/manifest.json``, e.g. the hallucination ``curve``
                                            as double2, ``sqrt_companding`` bool, ``level_alphas`` double[]), as
                                            stored in the store's ``/encodings/<encoding>`` ``settings``
``bakery:baked:store``                      asset path of the HDF5 store (relative to the layer)
``bakery:baked:contentHash``                SHA-256 of the prim's baked values and settings (:func:`content_hash`)
``bakery:baked:settingsHash``               the bake's settings hash
``bakery:baked:encodings``                  token[] of encodings written on this prim
``bakery:baked:probeCount``                 1, or the number of probes of a probe volume
``bakery:baked:backfaceFraction``           float[] (probeCount): each probe's share of capture rays that saw back
                                            faces (≥ 0.25: likely inside geometry; store
                                            ``capture/backface_fraction``), when the bake measured it
``bakery:baked:dilatedFrom``                int[] (probeCount): how many valid probes of its volume each probe
                                            stores the dilation of (0: its capture; store ``dilation/neighbours``),
                                            on the prims of dilating volumes
``bakery:baked:storeOnlyFields``            ``<encoding>:<field>`` of fields too large for the layer
                                            (> :data:`MAX_VALUES_PER_PROBE` values per probe): store only
``bakery:baked:conventions``                JSON of :data:`bakery.conventions.CONVENTIONS`
==========================================  ====================================================================

A probe volume gets one ``over`` whose arrays hold its probes one after another in the volume's flat order
(i fastest). A probe inside a native instance (an ``instanceable`` prim with a reference or payload, met as an
instance proxy) is baked at its own composed path, but USD ignores opinions on prims inside instances: the layer
therefore also authors ``instanceable = false`` on every instance above a baked probe (the reader's
``SceneReading.instances``),
so that each instance's probes carry their own values (those instances are no longer shared when composed).
The layer copies the scene's ``upAxis`` and ``metersPerUnit`` (so it composes without metrics warnings), sets
``defaultPrim`` (the scene's, when it is one of the layer's roots) and records the scene and store in
``customLayerData["bakery"]``. Use it by sublayering it above the scene, e.g. a session or shot layer with
``subLayers = [@scene.bake.usda@, @scene.usda@]``.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from bakery.conventions import CONVENTIONS
from bakery.errors import SceneError
from bakery.files import atomic_replace, sha256_bytes
from bakery.usd.plugin import BAKED_API

#: Fields with more values per probe than this stay in the store only (e.g. prefiltered cube maps).
MAX_VALUES_PER_PROBE = 16384


@dataclass(frozen=True)
class BakedPrim:
    """Baked values of one prim: ``fields`` maps attribute name → (probeCount, *shape) array."""

    path: str
    probe_count: int
    encodings: tuple[str, ...]
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    #: (probeCount,) float32 share of each probe's capture rays that saw back faces, or None (not measured)
    backface_fraction: np.ndarray | None = None
    #: (probeCount,) int number of valid probes each probe stores the dilation of (0: its capture), or None (the
    #: prim's probes are not dilated: :mod:`bakery.pipeline.dilate`)
    dilated_from: np.ndarray | None = None

    def split_by_size(self) -> tuple[dict[str, np.ndarray], list[str]]:
        """(fields small enough for the layer, ``<encoding>:<field>`` names of the others)."""
        small, large = {}, []
        for name, array in self.fields.items():
            per_probe = math.prod(np.shape(array)[1:])
            if per_probe > MAX_VALUES_PER_PROBE:
                large.append(name.split(":", 2)[2])
            else:
                small[name] = array
        return small, sorted(large)


def attribute_name(kind: str, encoding: str, field_name: str) -> str:
    """``bakery:<kind>:<encoding>:<field>``."""
    return f"bakery:{kind}:{encoding}:{field_name}"


def content_hash(fields: dict[str, np.ndarray]) -> str:
    """SHA-256 over the sorted attribute names, the arrays' shapes and dtypes, and their little-endian bytes."""
    parts = []
    for name in sorted(fields):
        array = np.ascontiguousarray(fields[name])
        parts.append(name.encode())
        parts.append(json.dumps([list(array.shape), array.dtype.str]).encode())
        parts.append(array.astype(array.dtype.newbyteorder("<"), copy=False).tobytes())
    return sha256_bytes(b"".join(parts))


def usd_type_for(dtype: str | np.dtype, shape: tuple[int, ...]) -> Sdf.ValueTypeName:
    """USD type of a field of per-probe ``shape`` and ``dtype``: float3[] when the last axis is RGB, else float[]
    (float16/32/64 are written as float32), uchar[] for uint8, int[] for other integers. The layer writer and the
    generated schema (:func:`bakery.usd.plugin.baked_field_attributes`) both use it, so they agree."""
    kind = np.dtype(dtype)
    if kind.kind == "f":
        return Sdf.ValueTypeNames.Float3Array if len(shape) >= 1 and shape[-1] == 3 else Sdf.ValueTypeNames.FloatArray
    if kind == np.uint8:
        return Sdf.ValueTypeNames.UCharArray
    if kind.kind in "iu":
        return Sdf.ValueTypeNames.IntArray
    raise SceneError(f"cannot write a {kind} array as a USD attribute")


@lru_cache(maxsize=256)
def _shape_array(shape: tuple[int, ...]) -> Vt.IntArray:
    """A field's per-probe shape as the ``customData["shape"]`` value (one per shape: thousands of prims share it)."""
    return Vt.IntArray(list(shape))


def _usd_value(array: np.ndarray) -> tuple[Sdf.ValueTypeName, object, np.ndarray]:
    """USD type (:func:`usd_type_for`), Vt value and the exact numpy array written (after any dtype conversion)."""
    array = np.asarray(array)
    type_name = usd_type_for(array.dtype, array.shape[1:])
    if type_name == Sdf.ValueTypeNames.Float3Array:
        data = np.ascontiguousarray(array, dtype=np.float32)
        return type_name, Vt.Vec3fArray.FromNumpy(data.reshape(-1, 3)), data
    if type_name == Sdf.ValueTypeNames.FloatArray:
        data = np.ascontiguousarray(array, dtype=np.float32)
        return type_name, Vt.FloatArray.FromNumpy(data.reshape(-1)), data
    if type_name == Sdf.ValueTypeNames.UCharArray:
        data = np.ascontiguousarray(array)
        return type_name, Vt.UCharArray.FromNumpy(data.reshape(-1)), data
    data = np.ascontiguousarray(array, dtype=np.int32)
    return type_name, Vt.IntArray.FromNumpy(data.reshape(-1)), data


#: USD types of the manifest's setting types (``bakery/shaders/manifest.json`` "argument_kinds"). Real-valued
#: settings are written in double precision: the layer records the exact values the bake used (an engine rounds them
#: to its uniforms' float), so a reader evaluating in float64 reproduces ``evaluate_irradiance`` exactly.
_SETTING_TYPES = {"vec2": Sdf.ValueTypeNames.Double2, "bool": Sdf.ValueTypeNames.Bool,
                  "float": Sdf.ValueTypeNames.Double, "int": Sdf.ValueTypeNames.Int}


def settings_attribute_name(encoding: str, key: str) -> str:
    """``bakery:settings:<encoding>:<key>``."""
    return f"bakery:settings:{encoding}:{key}"


def runtime_settings(encoding: str) -> dict[str, tuple[Sdf.ValueTypeName, dict[str, Any]]]:
    """{setting key: (USD type, how the shaders use it)} of the settings an engine needs to evaluate ``encoding``'s
    arrays: the ``setting`` arguments of its shader entry points, the keys that select a variant (``when``) and the
    chain's settings (``levels``: int, ``level_alphas``: double[]), from ``bakery/shaders/manifest.json``. Empty for
    an encoding without a shader entry. String settings are converted with the argument's ``values`` (e.g. curve
    ``"paper"`` → (0.6, 0.08)); ``"value": "length"`` arguments take the whole list (double[])."""
    from bakery.shaders import manifest

    spec = manifest()["encodings"].get(encoding)
    if spec is None:
        return {}
    found: dict[str, tuple[Sdf.ValueTypeName, dict[str, Any]]] = {}
    for entry in [spec, *spec.get("variants", ())]:
        for key, value in entry.get("when", {}).items():
            kind = {bool: "bool", int: "int", float: "float"}[type(value)]
            found.setdefault(key, (_SETTING_TYPES[kind], {"use": f"selects the entry point {entry['entry']} when "
                                                                 f"{json.dumps(value)}"}))
        for argument in entry["arguments"]:
            if "setting" in argument:
                key = argument["setting"]
                if argument.get("value") == "length":
                    found.setdefault(key, (Sdf.ValueTypeNames.DoubleArray, {"use": f"the list; its length is an "
                                                                                  f"argument of {entry['entry']}"}))
                else:
                    found.setdefault(key, (_SETTING_TYPES[argument["type"]],
                                           {"use": f"argument of {entry['entry']}", "values": argument.get("values", {})}))
            if "chain" in argument:
                if "levels" in argument:
                    found.setdefault(argument["levels"], (Sdf.ValueTypeNames.Int, {"use": "L of the chain lookup"}))
                if "level_alphas" in argument:
                    found.setdefault(argument["level_alphas"], (Sdf.ValueTypeNames.DoubleArray,
                                                                {"use": "GGX alpha of each chain level (the level "
                                                                        "coordinate), L = its length"}))
    return found


def runtime_setting_values(encoding: str, settings: Mapping[str, Any]) -> dict[str, tuple[Sdf.ValueTypeName, object, np.ndarray]]:
    """{attribute name: (USD type, Vt/Gf value, the value as a numpy array)} of :func:`runtime_settings` for an
    encoding's stored ``settings`` (keys it does not hold are skipped)."""
    out = {}
    for key, (type_name, how) in runtime_settings(encoding).items():
        if key not in settings:
            continue
        value = settings[key]
        if isinstance(value, str):
            if value not in how.get("values", {}):
                raise SceneError(f"{encoding}: setting {key} = {value!r} has no numeric value for the layer")
            value = how["values"][value]
        if type_name == Sdf.ValueTypeNames.Double2:
            data = np.asarray(value, dtype=np.float64).reshape(2)
            usd = Gf.Vec2d(float(data[0]), float(data[1]))
        elif type_name == Sdf.ValueTypeNames.DoubleArray:
            data = np.asarray(value, dtype=np.float64).reshape(-1)
            usd = Vt.DoubleArray.FromNumpy(data)
        elif type_name == Sdf.ValueTypeNames.Bool:
            data = np.asarray(bool(value))
            usd = bool(value)
        elif type_name == Sdf.ValueTypeNames.Int:
            data = np.asarray(int(value), dtype=np.int32)
            usd = int(value)
        else:
            data = np.asarray(float(value), dtype=np.float64)
            usd = float(data)
        out[settings_attribute_name(encoding, key)] = (type_name, usd, data)
    return out


def _default_prim(prims: list[BakedPrim], scene_path: str | os.PathLike[str]) -> str:
    """The layer's defaultPrim: the scene's own when it is among the layer's root prims, else the first root."""
    roots = sorted({Sdf.Path(baked.path).GetPrefixes()[0].name for baked in prims})
    scene_default = ""
    try:
        scene = Sdf.Layer.FindOrOpen(str(scene_path))
        scene_default = scene.defaultPrim if scene is not None else ""
    except Exception:  # noqa: BLE001 - a scene layer USD cannot open has no defaultPrim to copy
        scene_default = ""
    return scene_default if scene_default in roots else (roots[0] if roots else "")


#: File formats of the baked layer: text, crate (binary), or crate under the generic extension.
LAYER_SUFFIXES = (".usda", ".usdc", ".usd")


def write_bake_layer(
    layer_path: str | os.PathLike[str],
    prims: list[BakedPrim],
    store_path: str | os.PathLike[str],
    settings_hash: str,
    scene_path: str | os.PathLike[str],
    up_axis: str = "Y",
    meters_per_unit: float = 1.0,
    protected: tuple[str, ...] = (),
    encoding_settings: Mapping[str, Mapping[str, Any]] | None = None,
    instances: tuple[str, ...] = (),
) -> Path:
    """Write the baked-results layer atomically (temporary file + rename). Refuses to overwrite any path in
    ``protected`` (the scene's own layers). ``encoding_settings`` ({encoding: its stored settings}) adds the
    ``bakery:settings:<encoding>:<key>`` attributes of :func:`runtime_settings` to every prim carrying the encoding.
    ``instances``: the scene's native instances above probe prims; those above a baked prim are de-instanced.
    Returns the layer path."""
    layer_path = Path(layer_path).resolve()
    if str(layer_path) in {str(Path(p).resolve()) for p in protected}:
        raise SceneError(f"{layer_path}: refusing to overwrite one of the scene's own layers; choose another --layer")
    if layer_path.suffix not in LAYER_SUFFIXES:
        raise SceneError(f"{layer_path}: the baked layer must be a {', '.join(LAYER_SUFFIXES)} file")
    store_rel = os.path.relpath(Path(store_path).resolve(), layer_path.parent)
    scene_rel = os.path.relpath(Path(scene_path).resolve(), layer_path.parent)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.comment = "Baked light probes written by bakery; sublayer it above the scene. Do not edit by hand."
    layer.customLayerData = {
        "bakery": {"scene": scene_rel, "store": store_rel, "settingsHash": settings_hash,
                   "conventions": json.dumps(CONVENTIONS, sort_keys=True)}
    }
    pseudo = layer.pseudoRoot
    pseudo.SetInfo(UsdGeom.Tokens.upAxis, up_axis)
    pseudo.SetInfo(UsdGeom.Tokens.metersPerUnit, float(meters_per_unit))
    default_prim = _default_prim(prims, scene_path)
    if default_prim:  # a layer opened or referenced on its own needs one (OpenUSD's StageMetadataChecker)
        layer.defaultPrim = default_prim
    conventions = json.dumps(CONVENTIONS, sort_keys=True)
    settings_values: dict[str, dict] = {}  # an encoding's setting attributes are the same on every prim: once
    for baked in prims:
        spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(baked.path))
        spec.specifier = Sdf.SpecifierOver
        spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=[BAKED_API]))
        written: dict[str, np.ndarray] = {}
        small, store_only = baked.split_by_size()
        for name in sorted(small):
            type_name, value, data = _usd_value(small[name])
            attr = Sdf.AttributeSpec(spec, name, type_name, Sdf.VariabilityVarying)
            attr.default = value
            attr.customData = {"shape": _shape_array(data.shape[1:]), "probeCount": baked.probe_count}
            written[name] = data
        if baked.backface_fraction is not None:
            fraction = np.asarray(baked.backface_fraction, dtype=np.float32).reshape(baked.probe_count)
            attr = Sdf.AttributeSpec(spec, "bakery:baked:backfaceFraction", Sdf.ValueTypeNames.FloatArray,
                                     Sdf.VariabilityVarying)
            attr.default = Vt.FloatArray.FromNumpy(fraction)  # a diagnostic: not part of the content hash
        if baked.dilated_from is not None:
            count = np.asarray(baked.dilated_from, dtype=np.int32).reshape(baked.probe_count)
            attr = Sdf.AttributeSpec(spec, "bakery:baked:dilatedFrom", Sdf.ValueTypeNames.IntArray,
                                     Sdf.VariabilityVarying)
            attr.default = Vt.IntArray.FromNumpy(count)  # a diagnostic: not part of the content hash
        for encoding in baked.encodings:
            if encoding_settings is None or encoding not in encoding_settings:
                continue
            if encoding not in settings_values:
                settings_values[encoding] = runtime_setting_values(encoding, encoding_settings[encoding])
            for name, (type_name, value, data) in settings_values[encoding].items():
                attr = Sdf.AttributeSpec(spec, name, type_name, Sdf.VariabilityUniform)
                attr.default = value
                written[name] = data
        meta = {
            "bakery:baked:store": (Sdf.ValueTypeNames.Asset, Sdf.AssetPath(store_rel)),
            "bakery:baked:contentHash": (Sdf.ValueTypeNames.String, content_hash(written)),
            "bakery:baked:settingsHash": (Sdf.ValueTypeNames.String, settings_hash),
            "bakery:baked:encodings": (Sdf.ValueTypeNames.TokenArray, Vt.TokenArray(list(baked.encodings))),
            "bakery:baked:probeCount": (Sdf.ValueTypeNames.Int, int(baked.probe_count)),
            "bakery:baked:storeOnlyFields": (Sdf.ValueTypeNames.TokenArray, Vt.TokenArray(store_only)),
            "bakery:baked:conventions": (Sdf.ValueTypeNames.String, conventions),
        }
        for name, (type_name, value) in meta.items():
            attr = Sdf.AttributeSpec(spec, name, type_name, Sdf.VariabilityVarying)
            attr.default = value
    # a probe inside a native instance: de-instance the instance (and any nested one) in this layer, the only way
    # USD lets a per-instance opinion through (``instanceable = false`` over the scene's ``true``)
    baked_paths = [Sdf.Path(baked.path) for baked in prims]
    for path in map(Sdf.Path, instances):
        if any(p.HasPrefix(path) for p in baked_paths):
            Sdf.CreatePrimInLayer(layer, path).instanceable = False
    layer_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_replace(layer_path, suffix=layer_path.suffix) as tmp:  # USD picks the file format by extension
        if not layer.Export(str(tmp)):
            raise SceneError(f"{layer_path}: USD could not write the layer")
    return layer_path


def read_baked_values(stage_or_path: Usd.Stage | str | os.PathLike[str]) -> dict[str, dict[str, np.ndarray]]:
    """Baked attributes of every prim with ``BakeryBakedProbeAPI`` as {prim: {attribute: (probeCount, *shape)}}.

    Accepts a composed stage (the scene with the layer sublayered) or the path of a layer/stage to open.
    """
    stage = stage_or_path if isinstance(stage_or_path, Usd.Stage) else Usd.Stage.Open(str(stage_or_path))
    result: dict[str, dict[str, np.ndarray]] = {}
    for prim in stage.TraverseAll():
        if BAKED_API not in [str(s) for s in prim.GetAppliedSchemas()] and not prim.HasAttribute(
            "bakery:baked:contentHash"
        ):
            continue
        values: dict[str, np.ndarray] = {}
        for attr in prim.GetAttributes():
            name = attr.GetName()
            if not name.startswith("bakery:") or name.startswith("bakery:baked:") or not attr.HasAuthoredValue():
                continue
            parts = name.split(":")
            if len(parts) != 4 or parts[1] not in ("irradiance", "reflection"):
                continue
            data = np.asarray(attr.Get())
            shape = list(attr.GetCustomDataByKey("shape") or [])
            count = int(attr.GetCustomDataByKey("probeCount") or 1)
            values[name] = data.reshape((count, *shape))
        result[str(prim.GetPath())] = values
    return result


@dataclass
class ExportLayer:
    """A baked-results layer ``bakery export`` may add asset attributes to, checked by :func:`open_export_layer`:
    ``path`` (resolved), the name it was ``given`` by, the ``store`` it belongs to and an anonymous copy of its
    content as it was checked (re-read if the file changes before :func:`staged_export_attributes` writes it)."""

    path: Path
    given: Path
    store: Path | None
    layer: Sdf.Layer
    stamp: tuple[int, ...]
    default: bool = False


def _usd_error_reason(error: BaseException) -> str:
    """The message of a USD (Tf) error on one line, without its C++ location."""
    text = " ".join(str(error).split())
    parts = re.split(r"Error in '[^']*' at line \d+ in file \S+ : ", text)
    return parts[-1].strip().strip("'").strip() or type(error).__name__


def _stamp(path: Path) -> tuple[int, ...]:
    stat = path.stat()
    return (stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns)


def open_export_layer(layer_path: str | os.PathLike[str], store_path: str | os.PathLike[str] | None,
                      default: bool = False) -> ExportLayer:
    """Check, before anything is written, that ``bakery export`` may add to ``layer_path``, and read it.

    ``bakery export`` never edits a layer it does not own: the file must exist, be a ``.usda``/``.usdc``/``.usd``
    layer in a writable folder (:func:`bakery.files.check_output_file`; never the store), carry the baked-results
    marker (:func:`bakery.pipeline.run.layer_overwrite_refusal`, the test ``bakery bake`` applies before replacing
    a layer), open in USD, and record ``store_path`` as its store (``customLayerData["bakery"]["store"]``, relative to
    the layer; with ``store_path`` None, any recorded store). Anything else — the scene or one of its layers, a
    user's own file, a text file, the layer of another store — is a :class:`SceneError` (exit 2) naming the layer
    and the reason; there is no ``--force`` for it. ``default``: the path is the default ``<store stem>.bake.usda``
    (said in the message)."""
    from bakery.files import check_output_file, same_file
    from bakery.pipeline.run import layer_overwrite_refusal

    given = Path(layer_path)
    which = f"{given} (the default layer beside the store)" if default else str(given)
    store = Path(store_path) if store_path is not None else None
    hint = (f"bakery export edits only the baked-results layer bakery bake wrote for "
            f"{store.name if store is not None else 'the store'} (pass it with --layer) or none (--no-layer)")
    if given.suffix.lower() not in LAYER_SUFFIXES:
        kinds = ", ".join(LAYER_SUFFIXES[:-1]) + " or " + LAYER_SUFFIXES[-1]
        raise SceneError(f"{which}: not a USD layer (a baked layer is a {kinds} file); {hint}")
    if not given.exists() and not given.is_symlink():
        raise SceneError(f"{which}: no such layer; {hint}")
    # the folder must be writable, the path a regular file and not the store (an existing layer is allowed here:
    # whether it is one bakery may edit is checked below, with a message for export)
    check_output_file(given, "layer", inputs=[store] if store is not None else [], refusal=lambda _path: None)
    path = given.resolve()
    try:
        stamp = _stamp(path)  # before reading: a change from here on is seen when the layer is staged
    except OSError as error:
        raise SceneError(f"{which}: cannot be read ({error.strerror or error})") from None
    reason = layer_overwrite_refusal(given)  # the test a bake applies before replacing a layer
    if reason is not None:
        raise SceneError(f"{which}: {reason.removeprefix('exists and ')}; {hint}")
    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path))
    except Exception as error:  # noqa: BLE001 - USD raises Tf errors for files it cannot parse
        if not type(error).__module__.startswith("pxr"):
            raise
        raise SceneError(f"{which}: USD cannot read it ({_usd_error_reason(error)})") from None
    if layer is None:
        raise SceneError(f"{which}: USD cannot read it")
    data = dict(layer.customLayerData or {}).get("bakery")
    recorded = data.get("store") if isinstance(data, Mapping) else None
    if not isinstance(recorded, str) or not recorded:
        raise SceneError(f"{which}: records no store (customLayerData bakery.store), so it is not a baked-results "
                         f"layer bakery export can edit; {hint}")
    if store is not None and not same_file(path.parent / recorded, store):
        raise SceneError(f"{which}: is the baked-results layer of the store {recorded}, not of {store}; {hint}")
    return ExportLayer(path, given, store, layer, stamp, default)


def recorded_store(layer_path: str | os.PathLike[str]) -> Path | None:
    """The store a baked-results layer records (``customLayerData["bakery"]["store"]``, resolved against the
    layer's folder), or None if the file cannot be read by USD or records none."""
    path = Path(layer_path).resolve()
    try:  # metadata only: a re-bake checks its previous layer before any work, whatever the layer's size
        layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
    except Exception as error:  # noqa: BLE001 - USD raises Tf errors for files it cannot parse
        if not type(error).__module__.startswith("pxr"):
            raise
        return None
    data = dict(layer.customLayerData or {}).get("bakery") if layer is not None else None
    recorded = data.get("store") if isinstance(data, Mapping) else None
    return path.parent / recorded if isinstance(recorded, str) and recorded else None


def _with_export_attributes(layer: Sdf.Layer, suffix: str, assets: dict[str, dict[str, str]]) -> Sdf.Layer:
    """A copy of ``layer`` with the ``bakery:export:<key>`` attributes of ``assets`` (:func:`add_export_attributes`)."""
    copy = Sdf.Layer.CreateAnonymous(suffix)
    copy.TransferContent(layer)
    for probe, entries in sorted(assets.items()):
        prim_path = probe.split("[", 1)[0] if probe.endswith("]") else probe
        spec = copy.GetPrimAtPath(Sdf.Path(prim_path))
        if spec is None:
            continue
        for key, asset in sorted(entries.items()):
            name = f"bakery:export:{key}"
            attr = spec.attributes.get(name) if hasattr(spec.attributes, "get") else None
            if attr is None:
                attr = Sdf.AttributeSpec(spec, name, Sdf.ValueTypeNames.Asset, Sdf.VariabilityUniform)
            attr.default = Sdf.AssetPath(asset)
    return copy


@contextmanager
def staged_export_attributes(target: ExportLayer, assets: dict[str, dict[str, str]]) -> Iterator[Path]:
    """Stage ``target`` with the asset attributes of ``assets`` (:func:`add_export_attributes`) in a temporary file
    beside it; leaving the block renames it over the layer, an error removes it (:func:`bakery.files.atomic_replace`).
    If the layer changed on disk since it was checked, it is checked and read again (a bake may have replaced it)."""
    try:
        current = _stamp(target.path)
    except OSError:
        current = None
    if current != target.stamp:
        target = open_export_layer(target.given, target.store, target.default)
    copy = _with_export_attributes(target.layer, target.path.suffix, assets)
    with atomic_replace(target.path, suffix=target.path.suffix) as tmp:  # USD picks the file format by extension
        try:
            exported = copy.Export(str(tmp))
        except Exception as error:  # noqa: BLE001 - USD raises Tf errors when it cannot write
            if not type(error).__module__.startswith("pxr"):
                raise
            raise SceneError(f"{target.given}: USD could not write the layer ({_usd_error_reason(error)})") from None
        if not exported:
            raise SceneError(f"{target.given}: USD could not write the layer")
        yield tmp
    opened = Sdf.Layer.Find(str(target.path))  # a copy this process holds sees the new content
    if opened is not None:
        opened.Reload(force=True)


def add_export_attributes(layer_path: str | os.PathLike[str], assets: dict[str, dict[str, str]],
                          store_path: str | os.PathLike[str] | None = None) -> Path:
    """Add ``bakery:export:<key>`` asset attributes to the probe ``over`` specs of an existing baked layer, atomically
    (temporary file + rename), for ``bakery export``.

    ``assets`` maps a probe name to {key: asset path relative to the layer}, e.g.
    ``{"/Room/Probes/TableReflection": {"ktx2": "exports/Room_Probes_TableReflection.ktx2"}}``. A probe volume's
    probes (``/Vol[i,j,k]``) map onto the volume prim ``/Vol``. Probes without an ``over`` in the layer are
    skipped. The layer must be a bakery baked-results layer of ``store_path`` (:func:`open_export_layer`: a layer
    bakery does not own, or of another store, is refused and left untouched). Returns the layer path."""
    target = open_export_layer(layer_path, store_path)
    with staged_export_attributes(target, assets):
        pass
    return target.path
