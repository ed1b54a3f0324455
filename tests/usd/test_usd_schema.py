"""The typed USD schema of the baked attributes: generated from the encodings' declarations, declaring every
``bakery:<kind>:<encoding>:<field>`` with the type the layer writer uses; a baked layer passes OpenUSD's validation
framework (``pxr.UsdValidation``) with no errors; and the integration guide's reader (examples/engine_reader.py,
pxr + numpy only) reproduces ``evaluate_irradiance`` from the layer."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf

import bakery
from bakery.encodings import ENCODINGS, Encoding, FieldSpec, NoParams, register
from bakery.usd.layer import attribute_name, usd_type_for
from bakery.usd.plugin import BAKED_API, PLUGIN_DIR, baked_field_attributes, update_schema_source

REPO = Path(__file__).resolve().parents[2]
SCHEMA_SOURCE = REPO / "schemas" / "usd" / "schema.usda"
INDOOR = REPO / "examples" / "indoor" / "indoor.usda"


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """The indoor example baked with every registered encoding (its layer and store)."""
    folder = tmp_path_factory.mktemp("schema_bake")
    summary = bakery.bake(INDOOR, folder / "indoor.h5", encodings=tuple(ENCODINGS), face_size=8, samples=1)
    return Path(summary.layer), Path(summary.store)


def declared_attributes() -> dict[str, tuple[Sdf.ValueTypeName, str]]:
    """{attribute: (type, userDocBrief)} that BakeryBakedProbeAPI declares in the packaged generatedSchema.usda."""
    layer = Sdf.Layer.OpenAsAnonymous(str(PLUGIN_DIR / "generatedSchema.usda"))
    spec = layer.GetPrimAtPath(f"/{BAKED_API}")
    return {a.name: (a.typeName, a.customData.get("userDocBrief", "")) for a in spec.attributes}


def undeclared_fields() -> list[str]:
    """``name (type)`` of every registered encoding field the schema does not declare with the writer's type."""
    declared = declared_attributes()
    problems = []
    for cls in ENCODINGS.values():
        for spec in cls().field_specs():
            name = attribute_name(cls.kind, cls.name, spec.name)
            expected = usd_type_for(spec.dtype, spec.shape)
            if name not in declared or declared[name][0] != expected:
                problems.append(f"{name} ({expected})")
    return problems


# ------------------------------------------------------------------------------------------------ generation
def test_schema_source_is_generated_from_the_registry():
    text = SCHEMA_SOURCE.read_text()
    assert update_schema_source(text) == text, (
        "schemas/usd/schema.usda is out of date with bakery.encodings: run `python -m bakery.usd.sync_schemas`")


def test_schema_declares_every_encoding_field_with_its_type_and_documentation():
    assert undeclared_fields() == [], "run `python -m bakery.usd.sync_schemas`"
    declared = declared_attributes()
    for name, type_name, _ in baked_field_attributes():
        doc = declared[name][1]
        assert str(declared[name][0]) == type_name and name.split(":")[3] in doc and len(doc) > 60, name


def test_a_new_field_without_a_schema_declaration_fails():
    class SchemaProbe(Encoding):
        name = "schema_probe_encoding"
        kind = "irradiance"
        Params = NoParams
        max_band = 1

        def field_specs(self):
            return (FieldSpec("extra", (4, 3), "float32", "a field no schema declares"),)

        def encode(self, batch):  # pragma: no cover - never baked
            raise NotImplementedError

    register(SchemaProbe)
    try:
        assert undeclared_fields() == ["bakery:irradiance:schema_probe_encoding:extra (float3[])"]
        assert update_schema_source(SCHEMA_SOURCE.read_text()) != SCHEMA_SOURCE.read_text()
    finally:
        ENCODINGS.pop("schema_probe_encoding")


def test_baked_layer_attributes_agree_with_the_schema(baked):
    layer_path, _ = baked
    layer = Sdf.Layer.OpenAsAnonymous(str(layer_path))
    declared = declared_attributes()
    seen = set()

    def visit(path):
        spec = layer.GetObjectAtPath(path)
        if isinstance(spec, Sdf.AttributeSpec) and spec.name.startswith("bakery:"):
            if not spec.name.startswith("bakery:export:"):  # bakery export's asset attributes are another schema's
                assert spec.name in declared, f"{spec.name} is written but not declared by {BAKED_API}"
                assert spec.typeName == declared[spec.name][0], spec.name
                seen.add(spec.name.split(":")[2])

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    assert seen >= {n for n, c in ENCODINGS.items()}  # every encoding of the bake is in the layer


# ------------------------------------------------------------------------------------------------ UsdValidation
VALIDATE = r"""
import json, sys
import bakery.usd  # registers bakery's schema plugin before OpenUSD builds its schema registry
from pxr import Sdf, Usd, UsdGeom, UsdValidation
from bakery.usd.plugin import BAKED_API

layer_path, scene_path, broken_path = sys.argv[1:4]
definition = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(BAKED_API)
validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()

def errors(stage):
    found = UsdValidation.ValidationContext(validators).Validate(stage)
    return [{"type": str(e.GetType()).split(".")[-1], "validator": e.GetValidator().GetMetadata().name
             if e.GetValidator() else "", "message": e.GetMessage()} for e in found]

def shot(baked_layer):
    # what an engine or a shot does: the baked layer sublayered above the scene (with the scene's stage metadata)
    scene = Sdf.Layer.FindOrOpen(scene_path)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.subLayerPaths = [baked_layer, scene_path]
    for key in (UsdGeom.Tokens.upAxis, UsdGeom.Tokens.metersPerUnit):
        layer.pseudoRoot.SetInfo(key, scene.pseudoRoot.GetInfo(key))
    layer.defaultPrim = scene.defaultPrim
    return Usd.Stage.Open(layer)

print(json.dumps({
    "validators": len(validators),
    "declared": sorted(definition.GetPropertyNames()) if definition else [],
    "layer": errors(Usd.Stage.Open(layer_path)),
    "composed": errors(shot(layer_path)),
    "broken": errors(shot(broken_path)),
}))
"""


def test_baked_layer_passes_usd_validation(baked, tmp_path):
    layer_path, _ = baked
    # A negative control: the same layer with one baked attribute retyped must be reported (on the composed stage:
    # AttributeTypeMismatch checks defined prims, and the layer holds only overs).
    broken = Sdf.Layer.OpenAsAnonymous(str(layer_path))
    spec = broken.GetPrimAtPath("/Room/Probes/Volume")
    name = attribute_name("irradiance", next(iter(ENCODINGS)), "radiance_sh")
    value = np.asarray(spec.attributes[name].default)
    spec.RemoveProperty(spec.properties[name])
    attr = Sdf.AttributeSpec(spec, name, Sdf.ValueTypeNames.FloatArray)
    attr.default = value.reshape(-1).tolist()
    broken_path = layer_path.parent / "broken.bake.usda"
    broken.Export(str(broken_path))
    # A fresh process: bakery's plugin is registered before the schema registry is first used.
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-c", VALIDATE, str(layer_path), str(INDOOR), str(broken_path)],
                            capture_output=True, text=True, timeout=300, cwd=REPO, env=environment)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["validators"] > 10
    assert {n for n, _, _ in baked_field_attributes()} <= set(report["declared"]), "the schema registry lacks them"
    for stage in ("layer", "composed"):
        errors = [e for e in report[stage] if e["type"] == "Error"]
        assert errors == [], f"{stage}: {json.dumps(errors, indent=1)}"
    mismatches = [e for e in report["broken"] if e["validator"] == "usdValidation:AttributeTypeMismatch"]
    assert mismatches and name in mismatches[0]["message"], report["broken"]


# ------------------------------------------------------------------------------------------------ engine reader
READER = REPO / "examples" / "engine_reader.py"
RUN_WITHOUT_BAKERY = (
    "import runpy, sys\n"
    "sys.modules['bakery'] = None  # `import bakery` raises ImportError: the reader must not need it\n"
    "sys.argv = sys.argv[1:]\n"
    "runpy.run_path(sys.argv[0], run_name='__main__')\n"
)


def _volume_order(names: list[str], prim: str) -> list[int]:
    """Store rows of a probe volume's probes in the layer's flat order (i fastest)."""
    index = {}
    for row, name in enumerate(names):
        match = re.fullmatch(re.escape(prim) + r"\[(\d+),(\d+),(\d+)\]", name)
        if match:
            i, j, k = (int(g) for g in match.groups())
            index[(k, j, i)] = row
    return [index[key] for key in sorted(index)]


def test_engine_reader_reproduces_evaluate_irradiance(baked, tmp_path):
    layer_path, store_path = baked
    normals = np.random.default_rng(4).normal(size=(40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    np.save(tmp_path / "normals.npy", normals)
    out = tmp_path / "irradiance.npz"
    result = subprocess.run([sys.executable, "-c", RUN_WITHOUT_BAKERY, str(READER), str(layer_path),
                             str(tmp_path / "normals.npy"), "-o", str(out)],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    read = dict(np.load(out))
    store = bakery.open_store(store_path)
    compared = set()
    for key, value in read.items():
        prim, encoding = key.split("|")
        rows_of = {store.probe_names[int(p)]: r for r, p in enumerate(store.fields(encoding)["probe_index"])}
        probes = [store.probe_names[r] for r in _volume_order(store.probe_names, prim)] or [prim]
        expected = store.evaluate_irradiance(encoding, normals, probes=probes)
        assert all(p in rows_of for p in probes)
        np.testing.assert_allclose(value, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max(), err_msg=key)
        compared.add(encoding)
    irradiance = {n for n, c in ENCODINGS.items() if c.kind == "irradiance"}
    assert compared == irradiance, f"the reader does not evaluate {irradiance - compared}"
