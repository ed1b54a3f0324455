"""The baked-results layer and the schema plugin: a scene baked end to end, the layer read back through a composed
stage equals the store, the user's layers are untouched, and the packaged plugin matches its source."""

from __future__ import annotations

import filecmp
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

import bakery
from pxr import Sdf, Usd
from usd_scenes import box_mesh, header, material, probe, write

from bakery.errors import SceneError
from bakery.store.format import read_store
from bakery.usd.layer import attribute_name, content_hash, read_baked_values
from bakery.usd.plugin import FALLBACKS, PLUGIN_DIR, PROBE_TYPES, schemas_registered

REPO = Path(__file__).resolve().parents[2]


def _scene(tmp_path):
    body = "float3 bakery:volume:extent = (1, 0.5, 1)\n    int3 bakery:volume:counts = (2, 1, 2)"
    probes = write(tmp_path / "probes.usda", header() + probe("Irr", (0, 2, 0))
                   + probe("Refl", (1, 2, 0), type_name="BakeryReflectionProbe")
                   + probe("Vol", (0, 2, 0), type_name="BakeryIrradianceProbeVolume", body=body))
    shared = write(tmp_path / "shared.usda", header() + material("M", diffuse=(0.5, 0.4, 0.3))
                   + box_mesh("Box", 0.5, "/M") + 'def DomeLight "Sky"\n{\n    float inputs:intensity = 2\n}\n')
    return write(tmp_path / "scene.usda", header(extra=f"    subLayers = [@{probes.name}@, @{shared.name}@]\n"))


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("bake")
    scene = _scene(tmp_path)
    before = {p.name: p.read_bytes() for p in tmp_path.glob("*.usda")}
    summary = bakery.bake(scene, tmp_path / "scene.h5", face_size=8, encodings=["sh3", "sh2"], samples=1)
    return tmp_path, scene, before, summary


def test_user_layers_are_untouched(baked):
    tmp_path, _, before, summary = baked
    for name, data in before.items():
        assert (tmp_path / name).read_bytes() == data
    assert Path(summary.layer).name == "scene.bake.usda"
    # irradiance encodings only were requested: the reflection probe is planned but skipped, and reported
    assert (summary.baked + summary.reused) == 1 + 4 and summary.timings["capture_rays"] > 0 and summary.timings["rays_per_second"] > 0
    assert [s["probe"] for s in summary.skipped] == ["/Refl"]


def test_layer_round_trips_the_store_through_a_composed_stage(baked):
    tmp_path, scene, _, summary = baked
    session = Sdf.Layer.CreateAnonymous(".usda")
    session.subLayerPaths = [summary.layer, str(scene)]
    stage = Usd.Stage.Open(session)
    # the engine's view: typed probes carrying their coefficients
    for path, type_name in [("/Irr", "BakeryIrradianceProbe"), ("/Vol", "BakeryIrradianceProbeVolume")]:
        prim = stage.GetPrimAtPath(path)
        assert prim.GetTypeName() == type_name
        assert "BakeryBakedProbeAPI" in prim.GetAppliedSchemas()
    assert stage.GetPrimAtPath("/Refl").GetTypeName() == "BakeryReflectionProbe"
    assert "BakeryBakedProbeAPI" not in stage.GetPrimAtPath("/Refl").GetAppliedSchemas()  # skipped: not baked
    values = read_baked_values(stage)
    store = read_store(summary.store)
    names = list(store.probe_names)
    for encoding in ("sh2", "sh3"):
        fields = store.encodings[encoding]["fields"]
        rows = {names[int(r)]: k for k, r in enumerate(fields["probe_index"])}
        stored = fields["radiance_sh"]
        np.testing.assert_array_equal(values["/Irr"][attribute_name("irradiance", encoding, "radiance_sh")][0],
                                      stored[rows["/Irr"]])
        vol = values["/Vol"][attribute_name("irradiance", encoding, "radiance_sh")]
        order = [f"/Vol[{i},0,{k}]" for k in range(2) for i in range(2)]  # i fastest
        np.testing.assert_array_equal(vol, stored[[rows[n] for n in order]])
    # bookkeeping attributes
    irr = stage.GetPrimAtPath("/Irr")
    assert irr.GetAttribute("bakery:baked:settingsHash").Get() == summary.settings_hash
    assert irr.GetAttribute("bakery:baked:probeCount").Get() == 1
    assert stage.GetPrimAtPath("/Vol").GetAttribute("bakery:baked:probeCount").Get() == 4
    store_asset = irr.GetAttribute("bakery:baked:store").Get()
    assert Path(store_asset.resolvedPath).resolve() == Path(summary.store).resolve()
    assert irr.GetAttribute("bakery:baked:contentHash").Get() == content_hash(values["/Irr"])
    assert json.loads(irr.GetAttribute("bakery:baked:conventions").Get())["frame"] == "right-handed, +Y up"


def test_openusd_validation_finds_no_error_in_the_layer_or_the_composed_stage(baked):
    """OpenUSD's own validation framework (UsdValidation, what ``usdchecker`` runs: every registered validator,
    the codeless schema's included) reports nothing against the baked layer opened alone or sublayered above the
    scene, as an engine's pipeline would import it."""
    from pxr import UsdValidation

    _, scene, _, summary = baked
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    assert len(validators) >= 10  # the framework is there and loaded its core validators
    context = UsdValidation.ValidationContext(validators)
    session = Sdf.Layer.CreateAnonymous(".usda")  # the importer's root: the scene's stage metadata, both below
    session.subLayerPaths = [summary.layer, str(scene)]
    user = Sdf.Layer.FindOrOpen(str(scene))
    session.defaultPrim = user.defaultPrim or Sdf.Layer.FindOrOpen(summary.layer).defaultPrim
    for key in ("metersPerUnit", "upAxis"):
        if user.pseudoRoot.HasInfo(key):
            session.pseudoRoot.SetInfo(key, user.pseudoRoot.GetInfo(key))
    for stage in (Usd.Stage.Open(summary.layer), Usd.Stage.Open(session)):
        errors = [e for e in context.Validate(stage) if e.GetType() == UsdValidation.ValidationErrorType.Error]
        assert not errors, [f"{e.GetName()}: {e.GetMessage()}" for e in errors]


def test_content_hash_is_sha256_of_names_shapes_and_bytes():
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    digest = hashlib.sha256()
    digest.update(b"x")
    digest.update(json.dumps([[2, 3], "<f4"]).encode())
    digest.update(a.tobytes())
    assert content_hash({"x": a}) == digest.hexdigest()
    assert content_hash({"x": a}) != content_hash({"x": a + 1})


def test_layer_may_not_overwrite_the_scene(tmp_path):
    scene = _scene(tmp_path)
    with pytest.raises(SceneError, match="refusing"):
        bakery.bake(scene, tmp_path / "out.h5", layer=scene, face_size=8, encodings=["sh2"], samples=1)
    with pytest.raises(SceneError, match="refusing"):
        bakery.bake(scene, tmp_path / "out.h5", layer=tmp_path / "probes.usda", face_size=8,
                   encodings=["sh2"], samples=1)


def test_schema_plugin_is_registered_and_packaged_copy_matches_source():
    assert schemas_registered()
    for name in ("plugInfo.json", "generatedSchema.usda"):
        assert filecmp.cmp(PLUGIN_DIR / name, REPO / "schemas" / "usd" / name, shallow=False), name
    registry = Usd.SchemaRegistry()
    for type_name in PROBE_TYPES:
        definition = registry.FindConcretePrimDefinition(type_name)
        assert definition is not None, type_name
        names = definition.GetPropertyNames()
        for attr, expected in FALLBACKS.items():
            if attr not in names:
                continue
            fallback = definition.GetAttributeFallbackValue(attr)
            if isinstance(expected, str):
                assert fallback == expected, attr
            else:
                np.testing.assert_allclose(np.asarray(fallback, dtype=float), np.asarray(expected, dtype=float))
        for attr in names:
            if attr.startswith("bakery:"):
                assert definition.GetPropertyDefinition(attr).GetDocumentation(), f"{type_name}.{attr} undocumented"
    shape = registry.FindConcretePrimDefinition("BakeryReflectionProbe").GetPropertyDefinition(
        "bakery:influence:shape")
    assert list(shape.GetMetadata("allowedTokens")) == ["sphere", "box"]
    assert registry.FindAppliedAPIPrimDefinition("BakeryBakedProbeAPI") is not None


def test_large_fields_stay_in_the_store_only():
    from bakery.usd.layer import MAX_VALUES_PER_PROBE, BakedPrim

    small = np.zeros((1, 9, 3), dtype=np.float32)
    large = np.zeros((1, MAX_VALUES_PER_PROBE + 1), dtype=np.float32)
    prim = BakedPrim("/P", 1, ("a", "b"), {"bakery:irradiance:a:x": small, "bakery:reflection:b:cube": large})
    kept, store_only = prim.split_by_size()
    assert list(kept) == ["bakery:irradiance:a:x"] and store_only == ["b:cube"]


def test_per_probe_capture_resolution_and_constant_radiance_dc(tmp_path):
    """A probe in a closed box of emission c, captured at resolution 16 and baked on an 8² grid: the stored
    radiance SH DC is 2√π·c (closed form for constant radiance) and the higher bands vanish."""
    from usd_scenes import box_mesh, header, material, probe

    c = np.array([0.5, 1.0, 2.0])
    text = header() + material("M", diffuse=(0.0, 0.0, 0.0), emissive=tuple(c), diffuse_only=True) + box_mesh("Box", 2.0, "/M")
    text += probe("P", (0.2, 0.1, -0.3), body="int bakery:capture:resolution = 16")
    summary = bakery.bake(write(tmp_path / "box.usda", text), tmp_path / "box.h5", face_size=8, encodings=["sh3"],
                         samples=1)
    values = read_baked_values(summary.layer)["/P"]["bakery:irradiance:sh3:radiance_sh"][0]
    np.testing.assert_allclose(values[0], 2 * np.sqrt(np.pi) * c, rtol=1e-5)
    np.testing.assert_allclose(values[1:], 0.0, atol=1e-5)


def test_scene_bake_is_identical_with_one_or_two_worker_processes(tmp_path):
    """Per-probe seeds come from prim paths, so the layer (values and content hashes) does not depend on workers."""
    from bakery.pipeline.executors import ProcessExecutor

    scene = _scene(tmp_path)
    serial = bakery.bake(scene, tmp_path / "a.h5", face_size=8, encodings=["sh3"], samples=1)
    executor = ProcessExecutor(2)
    try:
        parallel = bakery.bake(scene, tmp_path / "b.h5", face_size=8, encodings=["sh3"], samples=1,
                              executor=executor)
    finally:
        executor.close()
    a = Path(serial.layer).read_text().replace("a.h5", "X")
    b = Path(parallel.layer).read_text().replace("b.h5", "X")
    assert a == b


def test_layer_holds_only_the_chain_levels_a_reflection_probe_uploads(tmp_path):
    """``shexp_hybrid`` levels below a probe's ``first_level`` are zero in the store and not uploaded: the layer leaves
    them out (schemas/store-reflection.md "Fixed layout") and holds the others exactly as stored."""
    indoor = Path(__file__).resolve().parents[2] / "examples" / "indoor" / "indoor.usda"
    summary = bakery.bake(indoor, tmp_path / "h.h5", encodings=("shexp_hybrid",), face_size=32, samples=1,
                          bounces=1, resume=False)
    store = bakery.open_store(summary.store)
    fields = store.fields("shexp_hybrid")
    levels = sum(1 for name in fields if name.startswith("level"))
    values = read_baked_values(summary.layer)
    checked = 0
    for row, probe_row in enumerate(fields["probe_index"]):
        prim = store.probe_names[int(probe_row)]
        first = int(fields["first_level"][row, 0])
        written = {k for k in range(levels)
                   if attribute_name("reflection", "shexp_hybrid", f"level{k}") in values.get(prim, {})}
        small = {k for k in range(levels) if fields[f"level{k}"][row].size <= 16384}  # the rest is store-only
        assert written == {k for k in small if k >= first}, (prim, first, written)
        for k in written:
            np.testing.assert_array_equal(
                values[prim][attribute_name("reflection", "shexp_hybrid", f"level{k}")][0],
                np.asarray(fields[f"level{k}"][row], dtype=np.float32))
        checked += first > 0
    assert checked, "no probe of the indoor example skips a level: the test would prove nothing"
