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
(i fastest). The layer copies the scene's ``upAxis`` and ``metersPerUnit`` (so it composes without metrics
warnings), sets ``defaultPrim`` (the scene's, when it is one of the layer's roots) and records the scene and store
in ``customLayerData["bakery"]``. Use it by sublayering it above the
scene, e.g. a session or shot layer with ``subLayers = [@scene.bake.usda@, @scene.usda@]``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
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
) -> Path:
    """Write the baked-results layer atomically (temporary file + rename). Refuses to overwrite any path in
    ``protected`` (the scene's own layers). ``encoding_settings`` ({encoding: its stored settings}) adds the
    ``bakery:settings:<encoding>:<key>`` attributes of :func:`runtime_settings` to every prim carrying the encoding.
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


def add_export_attributes(layer_path: str | os.PathLike[str], assets: dict[str, dict[str, str]],
                          store_path: str | os.PathLike[str] | None = None) -> Path:
    """Add ``bakery:export:<key>`` asset attributes to the probe ``over`` specs of an existing baked layer, atomically
    (temporary file + rename), for ``bakery export``.

    ``assets`` maps a probe name to {key: asset path relative to the layer}, e.g.
    ``{"/Room/Probes/TableReflection": {"ktx2": "exports/Room_Probes_TableReflection.ktx2"}}``. A probe volume's
    probes (``/Vol[i,j,k]``) map onto the volume prim ``/Vol``. Probes without an ``over`` in the layer are
    skipped. With ``store_path``, the layer must record that store (``customLayerData["bakery"]["store"]``), so an
    unrelated layer is never edited. Returns the layer path."""
    layer_path = Path(layer_path).resolve()
    layer = Sdf.Layer.FindOrOpen(str(layer_path))
    if layer is None:
        raise SceneError(f"{layer_path}: not a USD layer bakery can open")
    recorded = (layer.customLayerData or {}).get("bakery", {}).get("store")
    if store_path is not None and recorded is not None:
        if (layer_path.parent / recorded).resolve() != Path(store_path).resolve():
            raise SceneError(f"{layer_path}: this layer was baked into {recorded}, not {store_path}; pass the "
                             f"store's own layer (--layer)")
    copy = Sdf.Layer.CreateAnonymous(layer_path.suffix)
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
    with atomic_replace(layer_path, suffix=layer_path.suffix) as tmp:
        if not copy.Export(str(tmp)):
            raise SceneError(f"{layer_path}: USD could not write the layer")
    layer.Reload(force=True)
    return layer_path
