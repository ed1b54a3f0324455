"""The baked-results layer: an ``over`` per probe prim carrying its encodings as USD attributes.

The layer never edits the user's layers. It holds only ``over`` specs (typeless, so the scene's probe types show
through), each with the ``BakeryBakedProbeAPI`` schema applied and:

==========================================  ====================================================================
attribute                                   value
==========================================  ====================================================================
``bakery:<kind>:<encoding>:<field>``        the field's values: float3[] when the last axis is RGB, else float[]
                                            (uchar[] for 8-bit, int[] for other integer fields); customData
                                            ``shape`` = per-probe shape, ``probeCount`` = probes in the array
``bakery:baked:store``                      asset path of the HDF5 store (relative to the layer)
``bakery:baked:contentHash``                SHA-256 of the prim's baked values (see :func:`content_hash`)
``bakery:baked:settingsHash``               the bake's settings hash
``bakery:baked:encodings``                  token[] of encodings written on this prim
``bakery:baked:probeCount``                 1, or the number of probes of a probe volume
``bakery:baked:storeOnlyFields``            ``<encoding>:<field>`` of fields too large for the layer
                                            (> :data:`MAX_VALUES_PER_PROBE` values per probe): store only
``bakery:baked:conventions``                JSON of :data:`bakery.conventions.CONVENTIONS`
==========================================  ====================================================================

A probe volume gets one ``over`` whose arrays hold its probes one after another in the volume's flat order
(i fastest). The layer copies the scene's ``upAxis`` and ``metersPerUnit`` (so it composes without metrics
warnings) and records the scene and store in ``customLayerData["bakery"]``. Use it by sublayering it above the
scene, e.g. a session or shot layer with ``subLayers = [@scene.bake.usda@, @scene.usda@]``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

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

    def split_by_size(self) -> tuple[dict[str, np.ndarray], list[str]]:
        """(fields small enough for the layer, ``<encoding>:<field>`` names of the others)."""
        small, large = {}, []
        for name, array in self.fields.items():
            per_probe = int(np.prod(np.shape(array)[1:], dtype=np.int64))
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


def _usd_value(array: np.ndarray) -> tuple[Sdf.ValueTypeName, object, np.ndarray]:
    """USD type, Vt value and the exact numpy array written (after any dtype conversion)."""
    array = np.asarray(array)
    if array.dtype.kind == "f":
        data = np.ascontiguousarray(array, dtype=np.float32)
        if array.ndim >= 2 and array.shape[-1] == 3:
            return Sdf.ValueTypeNames.Float3Array, Vt.Vec3fArray.FromNumpy(data.reshape(-1, 3)), data
        return Sdf.ValueTypeNames.FloatArray, Vt.FloatArray.FromNumpy(data.reshape(-1)), data
    if array.dtype == np.uint8:
        data = np.ascontiguousarray(array)
        return Sdf.ValueTypeNames.UCharArray, Vt.UCharArray.FromNumpy(data.reshape(-1)), data
    if array.dtype.kind in "iu":
        data = np.ascontiguousarray(array, dtype=np.int32)
        return Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(data.reshape(-1)), data
    raise SceneError(f"cannot write a {array.dtype} array as a USD attribute")


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
) -> Path:
    """Write the baked-results layer atomically (temporary file + rename). Refuses to overwrite any path in
    ``protected`` (the scene's own layers). Returns the layer path."""
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
    conventions = json.dumps(CONVENTIONS, sort_keys=True)
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
            attr.customData = {"shape": Vt.IntArray(list(data.shape[1:])), "probeCount": baked.probe_count}
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
