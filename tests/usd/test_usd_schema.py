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
from bakery.usd.layer import (BakedPrim, attribute_name, read_baked_values, runtime_settings, settings_attribute_name,
                               usd_type_for, write_bake_layer)
from bakery.usd.plugin import (BAKED_API, PLUGIN_DIR, baked_field_attributes, runtime_setting_attributes,
                               update_schema_source)

REPO = Path(__file__).resolve().parents[2]
SCHEMA_SOURCE = REPO / "schemas" / "usd" / "schema.usda"
INDOOR = REPO / "examples" / "indoor" / "indoor.usda"


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """The indoor example baked with every registered encoding (its layer and store)."""
    folder = tmp_path_factory.mktemp("schema_bake")
    summary = bakery.bake(INDOOR, folder / "indoor.h5", encodings=tuple(ENCODINGS), face_size=8, samples=1)
    return Path(summary.layer), Path(summary.store)


@pytest.fixture(scope="module")
def settings_layer(baked, tmp_path_factory):
    """The baked layer rewritten by :func:`write_bake_layer` with encoding settings: the same prims and arrays plus
    every ``bakery:settings:<encoding>:<key>`` attribute, from the store's settings with a non-default curve and
    companding (from a second bake) for ``zh3_hallucinated`` / ``zh3_quantized``."""
    layer_path, store_path = baked
    folder = tmp_path_factory.mktemp("settings_layer")
    variant = folder / "variant.h5"
    bakery.bake(INDOOR, variant, encodings=("zh3_hallucinated", "zh3_quantized"), face_size=8, samples=1,
                encoding_settings={"zh3_hallucinated": {"curve": [0.5, 0.1]},
                                   "zh3_quantized": {"sqrt_companding": False}})
    settings = {name: info.settings for name, info in bakery.open_store(store_path).encodings.items()}
    settings.update({name: info.settings for name, info in bakery.open_store(variant).encodings.items()})
    layer = Sdf.Layer.OpenAsAnonymous(str(layer_path))
    prims = []
    for prim_path, values in read_baked_values(str(layer_path)).items():
        spec = layer.GetPrimAtPath(prim_path)
        prims.append(BakedPrim(prim_path, int(spec.attributes["bakery:baked:probeCount"].default),
                               tuple(spec.attributes["bakery:baked:encodings"].default), values))
    out = write_bake_layer(folder / "indoor.bake.usda", prims, store_path, "settings-test", INDOOR,
                           up_axis=layer.pseudoRoot.GetInfo("upAxis"),
                           meters_per_unit=layer.pseudoRoot.GetInfo("metersPerUnit"), encoding_settings=settings)
    return out, settings


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


def test_the_schema_declares_every_field_the_recipe_presets_write():
    """A preset may turn on a setting that adds fields (``shexp_hybrid`` ``gap_level``, ``gap_levels``: levels L,
    L + 1 and ``gap_skipped``), and a bake's face size sets the level count of the encodings that follow it (the
    hybrid's chain has 7 levels at 4², 16 at 4096² with 4 gap levels): the layer of a bake with any preset at any face
    size writes only declared attributes (``Encoding.schema_layouts``, at the largest face size as well)."""
    from bakery.conventions import MAX_FACE_SIZE
    from bakery.pipeline.recipe import RECIPE_DIR, load_recipe

    declared = declared_attributes()
    problems = []
    presets = sorted(path.stem for path in RECIPE_DIR.glob("*.toml"))
    assert {"console", "pc-high"} <= set(presets)
    face_sizes = [4, 5, 7, 48, 100, 1000, 3000, *(1 << k for k in range(2, MAX_FACE_SIZE.bit_length()))]
    for preset in presets:
        recipe = load_recipe(preset)
        for name in recipe.encodings:
            cls = ENCODINGS[name]
            settings = recipe.encoding_settings.get(name, {})
            for face_size in face_sizes if cls.follows_bake_face_size else [None]:
                overrides = settings | ({"face_size": face_size} if face_size else {})
                for spec in cls(**overrides).field_specs():
                    attribute = attribute_name(cls.kind, cls.name, spec.name)
                    if attribute not in declared or declared[attribute][0] != usd_type_for(spec.dtype, spec.shape):
                        problems.append(f"{preset} at face size {face_size}: {attribute}")
    assert problems == [], "declare them through Encoding.schema_layouts and run `python -m bakery.usd.sync_schemas`"


def test_the_schema_declares_every_level_of_the_largest_chain():
    """Every encoding whose levels follow the bake's face size, at every layout the schema declares and every face
    size a bake accepts, writes only declared attributes (before, levels 11–15 of a 4 gap-level chain above 64² were
    written undeclared)."""
    from bakery.conventions import MAX_FACE_SIZE
    from bakery.usd.plugin import schema_layouts

    declared = declared_attributes()
    problems = []
    for cls in ENCODINGS.values():
        if not cls.follows_bake_face_size:
            continue
        for overrides in schema_layouts(cls).values():
            for face_size in (4, 64, 129, 1024, 2047, MAX_FACE_SIZE):
                for spec in cls(**(overrides | {"face_size": face_size})).field_specs():
                    if attribute_name(cls.kind, cls.name, spec.name) not in declared:
                        problems.append(f"{cls.name} {overrides} at {face_size}: {spec.name}")
    assert problems == []


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


def test_schema_declares_the_runtime_settings_the_shaders_take():
    declared = declared_attributes()
    from bakery.shaders import manifest

    expected = {"zh3_hallucinated": {"curve"}, "zh3_hallucinated_solved": {"curve"},
                "zh3_quantized": {"sqrt_companding"}, "sh3_quantized": {"sqrt_companding"},
                "shexp": {"albedo_normalized"}, "splitsum": {"n_levels"},
                "shexp_hybrid": {"level_alphas", "crossover", "tail_crossover", "blend_octaves"}}
    assert {name: set(runtime_settings(name)) for name in ENCODINGS if runtime_settings(name)} == expected
    for name, type_name, doc in runtime_setting_attributes():
        assert name in declared and str(declared[name][0]) == type_name and name.split(":")[3] in doc, name
    for encoding, spec in manifest()["encodings"].items():  # every setting a shader entry takes is declared
        for entry in [spec, *spec.get("variants", ())]:
            for argument in entry["arguments"]:
                if "setting" in argument:
                    assert settings_attribute_name(encoding, argument["setting"]) in declared, (encoding, argument)


def test_layer_carries_the_runtime_settings(settings_layer):
    path, settings = settings_layer
    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    declared = declared_attributes()
    found = {}

    def visit(spec_path):
        spec = layer.GetObjectAtPath(spec_path)
        if isinstance(spec, Sdf.AttributeSpec) and spec.name.startswith("bakery:settings:"):
            assert spec.name in declared and spec.typeName == declared[spec.name][0], spec.name
            assert spec.variability == Sdf.VariabilityUniform, spec.name
            found.setdefault(spec.name, []).append(spec.default)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    name = settings_attribute_name
    assert {n for n, _, _ in runtime_setting_attributes()} == set(found)
    for values in found.values():
        assert all(v == values[0] for v in values)  # the same on every prim carrying the encoding
    assert tuple(found[name("zh3_hallucinated", "curve")][0]) == pytest.approx((0.5, 0.1))
    assert tuple(found[name("zh3_hallucinated_solved", "curve")][0]) == pytest.approx((0.6, 0.08))  # "paper"
    assert found[name("zh3_quantized", "sqrt_companding")][0] is False
    assert found[name("sh3_quantized", "sqrt_companding")][0] is True
    assert found[name("shexp", "albedo_normalized")][0] is True
    assert found[name("splitsum", "n_levels")][0] == settings["splitsum"]["n_levels"]
    assert list(found[name("shexp_hybrid", "level_alphas")][0]) == pytest.approx(settings["shexp_hybrid"]["level_alphas"])
    for key in ("crossover", "tail_crossover", "blend_octaves"):
        assert found[name("shexp_hybrid", key)][0] == pytest.approx(settings["shexp_hybrid"][key])
    # the arrays are untouched: read_baked_values (and the engine reader's 4-part filter) skip the settings
    for prim, values in read_baked_values(str(path)).items():
        assert not any(k.startswith("bakery:settings:") for k in values), prim


# ------------------------------------------------------------------------------------------------ UsdValidation
VALIDATE = r"""
import json, sys
import bakery.usd  # registers bakery's schema plugin before OpenUSD builds its schema registry
from pxr import Sdf, Usd, UsdGeom, UsdValidation
from bakery.usd.plugin import BAKED_API

layer_path, scene_path, broken_path, settings_path = sys.argv[1:5]
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
    "settings": errors(Usd.Stage.Open(settings_path)),
    "settings composed": errors(shot(settings_path)),
}))
"""


def test_baked_layer_passes_usd_validation(baked, settings_layer, tmp_path):
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
    result = subprocess.run([sys.executable, "-c", VALIDATE, str(layer_path), str(INDOOR), str(broken_path),
                             str(settings_layer[0])],
                            capture_output=True, text=True, timeout=300, cwd=REPO, env=environment)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["validators"] > 10
    assert {n for n, _, _ in baked_field_attributes()} <= set(report["declared"]), "the schema registry lacks them"
    for stage in ("layer", "composed", "settings", "settings composed"):
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


def _reader_irradiance_matches_the_store(layer_path: Path, store_path: Path, tmp_path: Path) -> set[str]:
    """Run the engine reader (without bakery importable) on the layer; assert it reproduces
    ``evaluate_irradiance`` of the store for every prim and encoding it reads; return those encodings."""
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
    return compared


def test_engine_reader_reproduces_evaluate_irradiance(baked, tmp_path):
    compared = _reader_irradiance_matches_the_store(*baked, tmp_path)
    irradiance = {n for n, c in ENCODINGS.items() if c.kind == "irradiance"}
    assert compared == irradiance, f"the reader does not evaluate {irradiance - compared}"


def test_engine_reader_follows_the_settings_a_bake_writes_into_its_layer(tmp_path):
    """A real bake with a non-default hallucination curve and linear (not square-root) companding: its layer carries
    ``bakery:settings:…`` and the reader, which reads them, still reproduces the store (it would not with the
    defaults)."""
    summary = bakery.bake(INDOOR, tmp_path / "variant.h5", encodings=("zh3_hallucinated", "zh3_quantized"),
                          face_size=8, samples=1, encoding_settings={"zh3_hallucinated": {"curve": [0.5, 0.1]},
                                                                      "zh3_quantized": {"sqrt_companding": False}})
    text = Path(summary.layer).read_text()
    assert "bakery:settings:zh3_hallucinated:curve = (0.5, 0.1)" in text
    assert "bakery:settings:zh3_quantized:sqrt_companding = 0" in text
    compared = _reader_irradiance_matches_the_store(Path(summary.layer), Path(summary.store), tmp_path)
    assert compared >= {"zh3_hallucinated", "zh3_quantized"}  # (and what they depend on)
