"""Probe placement and the baked layer as an engine reads them: probe and volume-grid positions against the schema's
closed form through USD's own transforms (pxr Gf: translation, rotation, non-uniform and negative scale, Z-up,
metersPerUnit, time samples); the irradiance an engine reconstructs from the layer alone (examples/engine_reader.py)
peaks towards the light from each probe's world position, for rotated and mirrored parents and in the volume's
documented order (i fastest); probes inside native instances keep their own values when the layer is composed;
a mirrored captured-image probe follows its transform; a re-bake of a moved probe updates the layer."""

from __future__ import annotations

import importlib.util
import itertools
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom
from usd_scenes import header, write

import bakery
from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.store.format import read_store
from bakery.usd.scene import read_scene

REPO = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("engine_reader", REPO / "examples" / "engine_reader.py")
engine_reader = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(engine_reader)

#: Z-up stage → bake frame for row vectors: (x, y, z) ↦ (x, z, −y) (docs/engine-integration.md, "Frame")
Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: translation, rotation, non-uniform and negative scale
PARENT_XFORM = """double3 xformOp:translate = (1, 2, 3)
    float3 xformOp:rotateXYZ = (30, 45, -60)
    float3 xformOp:scale = (2, -0.5, 1.5)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ", "xformOp:scale"]"""
VOLUME_XFORM = """double3 xformOp:translate = (0.5, 0, -1)
        float xformOp:rotateZ = 20
        float3 xformOp:scale = (1, 3, -1)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateZ", "xformOp:scale"]"""


def _grid_local(extent, counts) -> dict[tuple[int, int, int], tuple[float, float, float]]:
    """The schema's closed form (schemas/usd/schema.usda, BakeryIrradianceProbeVolume): probe (i, j, k) at
    −extent + 2·extent·(i, j, k)/(counts − 1), the box's mid-plane (0) along an axis of count 1."""
    axes = [[(-e + 2.0 * e * n / (c - 1)) if c > 1 else 0.0 for n in range(c)] for e, c in zip(extent, counts)]
    return {(i, j, k): (axes[0][i], axes[1][j], axes[2][k])
            for i, j, k in itertools.product(*(range(c) for c in counts))}


def _world(stage: Usd.Stage, path: str, time=Usd.TimeCode.EarliestTime()) -> Gf.Matrix4d:
    return UsdGeom.XformCache(time).GetLocalToWorldTransform(stage.GetPrimAtPath(path))


def _bake_frame(stage: Usd.Stage, world_point) -> np.ndarray:
    axes = Z_UP if UsdGeom.GetStageUpAxis(stage) == "Z" else np.eye(3)
    return UsdGeom.GetStageMetersPerUnit(stage) * np.asarray(world_point, dtype=np.float64) @ axes


@pytest.mark.parametrize(("up", "mpu", "counts", "extent"), [
    ("Y", 1.0, (3, 2, 4), (1.0, 0.5, 2.0)),
    ("Z", 0.01, (3, 2, 4), (1.0, 0.5, 2.0)),
    ("Z", 0.5, (1, 3, 1), (1.0, 0.5, 2.0)),       # count 1: the mid-plane
    ("Y", 2.0, (12, 1, 2), (3.0, 0.0, 1.0)),      # ≥ 10 along i (no lexicographic order), zero extent
])
def test_probes_and_volume_grid_sit_where_the_schema_and_usd_transforms_say(tmp_path, up, mpu, counts, extent):
    text = header(up, mpu) + f"""
def Xform "Parent"
{{
    {PARENT_XFORM}
    def BakeryIrradianceProbeVolume "Vol"
    {{
        {VOLUME_XFORM}
        float3 bakery:volume:extent = {tuple(extent)}
        int3 bakery:volume:counts = {tuple(counts)}
    }}
    def BakeryReflectionProbe "Refl"
    {{
        double3 xformOp:translate = (0.3, -0.2, 0.7)
        float xformOp:rotateY = 33
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY"]
    }}
}}
def DomeLight "Sky"
{{
}}
"""
    path = write(tmp_path / "grid.usda", text)
    reading = read_scene(path, load_textures=False)
    assert not reading.errors
    stage = Usd.Stage.Open(str(path))
    got = {p.name: np.asarray(p.position) for p in reading.scene.probes}
    vol = _world(stage, "/Parent/Vol")
    grid = _grid_local(extent, counts)
    assert len(got) == len(grid) + 1
    for (i, j, k), local in grid.items():
        expected = _bake_frame(stage, vol.Transform(Gf.Vec3d(*local)))
        np.testing.assert_allclose(got[f"/Parent/Vol[{i},{j},{k}]"], expected, atol=1e-12)
    refl = _world(stage, "/Parent/Refl").ExtractTranslation()
    np.testing.assert_allclose(got["/Parent/Refl"], _bake_frame(stage, refl), atol=1e-12)
    # the volume's probes in the layer's flat order: i fastest
    order = [p.volume_index for p in reading.scene.probes if p.volume]
    assert order == [(i, j, k) for k in range(counts[2]) for j in range(counts[1]) for i in range(counts[0])]


def test_time_sampled_transforms_place_probes_at_the_bake_time(tmp_path):
    """Without a time, each attribute's earliest sample (USD's EarliestTime: a sample wins over an authored
    default); with --time, that time."""
    text = header() + """
def Xform "Parent"
{
    double3 xformOp:translate = (100, 100, 100)
    double3 xformOp:translate.timeSamples = { 2: (0, 0, 0), 10: (10, 0, 0) }
    float xformOp:rotateY.timeSamples = { 2: 0, 10: 90 }
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY"]
    def BakeryIrradianceProbeVolume "Vol"
    {
        double3 xformOp:translate.timeSamples = { 2: (0, 0, 0), 10: (0, 4, 0) }
        uniform token[] xformOpOrder = ["xformOp:translate"]
        float3 bakery:volume:extent = (1, 1, 1)
        int3 bakery:volume:counts = (2, 1, 1)
    }
}
def DomeLight "Sky"
{
}
"""
    path = write(tmp_path / "time.usda", text)
    stage = Usd.Stage.Open(str(path))
    closed = {  # translate (10·s, 4·s, 0) after rotateY(90·s) of the volume's local (±1, 0, 0), s = (t − 2)/8
        None: {0: (-1.0, 0.0, 0.0), 1: (1.0, 0.0, 0.0)},
        10.0: {0: (10.0, 4.0, 1.0), 1: (10.0, 4.0, -1.0)},
    }
    for time in (None, 6.0, 10.0):
        positions = {p.volume_index[0]: np.asarray(p.position)
                     for p in read_scene(path, load_textures=False, time=time).scene.probes}
        code = Usd.TimeCode.EarliestTime() if time is None else Usd.TimeCode(time)
        matrix = _world(stage, "/Parent/Vol", code)
        for i, x in ((0, -1.0), (1, 1.0)):
            np.testing.assert_allclose(positions[i], matrix.Transform(Gf.Vec3d(x, 0, 0)), atol=1e-12)
            if time in closed:
                np.testing.assert_allclose(positions[i], closed[time][i], atol=1e-12)


def _lit_scene(up: str, mpu: float, light_world, volume_body: str = "") -> str:
    lx, ly, lz = light_world
    return header(up, mpu) + f"""
def Xform "Parent"
{{
    float3 xformOp:rotateXYZ = (30, 75, -60)
    float3 xformOp:scale = (2, -0.5, 1.5)
    uniform token[] xformOpOrder = ["xformOp:rotateXYZ", "xformOp:scale"]
    def BakeryIrradianceProbeVolume "Vol"
    {{
        float3 bakery:volume:extent = ({0.6 / mpu}, {0.6 / mpu}, {0.6 / mpu})
        int3 bakery:volume:counts = (3, 2, 2)
        {volume_body}
    }}
    def BakeryIrradianceProbe "Irr"
    {{
    }}
}}
def SphereLight "Lamp"
{{
    float inputs:intensity = 3000
    float inputs:radius = {0.05 / mpu}
    double3 xformOp:translate = ({lx}, {ly}, {lz})
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""


def _fibonacci(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


@pytest.mark.parametrize(("up", "mpu", "light"), [("Y", 1.0, (1.5, 0.8, -0.6)), ("Z", 0.01, (150.0, -60.0, 80.0))])
def test_layer_irradiance_peaks_towards_the_light_from_each_probes_world_position(tmp_path, up, mpu, light):
    """A SphereLight beside a rotated, mirrored, non-uniformly scaled parent: for every probe (the volume's in the
    layer's documented order), the irradiance engine_reader.py reconstructs from the layer alone is largest at the
    normal pointing from the probe's world position (Gf) to the light, given in the stage's frame
    (``--stage-normals``' conversion)."""
    scene = write(tmp_path / "lit.usda", _lit_scene(up, mpu, light))
    summary = bakery.bake(scene, tmp_path / "lit.h5", face_size=8, encodings=["sh3", "zh3"], samples=2)
    layer = Sdf.Layer.FindOrOpen(summary.layer)
    assert layer.pseudoRoot.GetInfo("upAxis") == up and layer.pseudoRoot.GetInfo("metersPerUnit") == mpu
    assert engine_reader.layer_up_axis(summary.layer) == up
    stage = Usd.Stage.Open(str(scene))
    normals = _fibonacci(4000)  # stage-frame unit normals
    grid = _grid_local((0.6 / mpu,) * 3, (3, 2, 2))
    vol = _world(stage, "/Parent/Vol")
    points = {"/Parent/Irr": [np.asarray(_world(stage, "/Parent/Irr").ExtractTranslation())],
              "/Parent/Vol": [np.asarray(vol.Transform(Gf.Vec3d(*grid[(i, j, k)])))
                              for k in range(2) for j in range(2) for i in range(3)]}
    result = engine_reader.irradiance_of_layer(summary.layer, engine_reader.stage_to_bake(normals, up))
    worst = 0.0
    for key, irradiance in result.items():
        prim = key.split("|")[0]
        assert irradiance.shape == (len(points[prim]), len(normals), 3)
        for probe, position in zip(irradiance, points[prim]):
            towards = np.asarray(light) - position
            towards /= np.linalg.norm(towards)
            best = normals[np.argmax(probe @ engine_reader.LUMINANCE)]
            worst = max(worst, float(np.degrees(np.arccos(np.clip(best @ towards, -1.0, 1.0)))))
    assert worst < 12.0, worst  # the light spans 3–6° from the probes; face size 8, 2 samples
    # the directions differ between the volume's probes by far more than that: a wrong order would fail
    spread = [np.asarray(light) - p for p in points["/Parent/Vol"]]
    spread = [d / np.linalg.norm(d) for d in spread]
    assert max(np.degrees(np.arccos(np.clip(a @ b, -1, 1))) for a in spread for b in spread) > 40.0


def test_rebake_of_a_moved_probe_updates_the_layer(tmp_path):
    scene = tmp_path / "move.usda"
    write(scene, _lit_scene("Y", 1.0, (1.5, 0.8, -0.6)))
    first = bakery.bake(scene, tmp_path / "move.h5", face_size=8, encodings=["sh2"], samples=1)
    before = engine_reader.read_layer(first.layer)["/Parent/Irr"]["bakery:irradiance:sh2:radiance_sh"]
    write(scene, _lit_scene("Y", 1.0, (1.5, 0.8, -0.6)).replace(  # the probe 0.3 from the light
        'def BakeryIrradianceProbe "Irr"\n    {\n', 'def BakeryIrradianceProbe "Irr"\n    {\n'
        '        matrix4d xformOp:transform = ( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (1.2, 0.8, -0.6, 1) )\n'
        '        uniform token[] xformOpOrder = ["!resetXformStack!", "xformOp:transform"]\n'))
    second = bakery.bake(scene, tmp_path / "move.h5", face_size=8, encodings=["sh2"], samples=1)
    assert second.baked == 1 and second.reused == 12  # the volume is unchanged
    after = engine_reader.read_layer(second.layer)["/Parent/Irr"]["bakery:irradiance:sh2:radiance_sh"]
    store = read_store(second.store)
    row = store.probe_names.index("/Parent/Irr")
    np.testing.assert_allclose(store.probe_positions[row], (1.2, 0.8, -0.6), atol=1e-12)
    np.testing.assert_array_equal(after[0], store.encodings["sh2"]["fields"]["radiance_sh"][
        list(store.encodings["sh2"]["fields"]["probe_index"]).index(row)])
    # inverse square: ~ (1.87 / 0.3)² brighter DC at the moved position
    assert after[0, 0, 0] > 10.0 * before[0, 0, 0]


def test_probes_inside_native_instances_keep_their_own_values_in_the_composed_layer(tmp_path):
    """Two instances of an asset holding a probe (one nested inside a second level of instancing) and one payload:
    each composed probe path carries its own baked values (the store's row of that probe); USD drops opinions on
    instance proxies, so the layer de-instances the instances above probes. OpenUSD's validators report no
    error on the composed stage."""
    from pxr import UsdValidation

    write(tmp_path / "asset.usda", (header() + """
def Xform "Asset"
{
    def BakeryIrradianceProbe "P"
    {
        double3 xformOp:translate = (0, 1, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
""").replace("(\n", '(\n    defaultPrim = "Asset"\n', 1))
    write(tmp_path / "nest.usda", (header() + """
def Xform "Outer"
{
    def Xform "Inner" (
        instanceable = true
        references = @asset.usda@
    )
    {
    }
}
""").replace("(\n", '(\n    defaultPrim = "Outer"\n', 1))

    def placed(name, arc, asset, x, instanceable=True):
        flag = "instanceable = true\n    " if instanceable else ""
        return (f'def Xform "{name}" (\n    {flag}{arc} = @{asset}@\n)\n{{\n'
                f'    double3 xformOp:translate = ({x}, 0, 0)\n'
                f'    uniform token[] xformOpOrder = ["xformOp:translate"]\n}}\n')

    write(tmp_path / "empty.usda", (header() + 'def Xform "Empty"\n{\n    def Xform "Child"\n    {\n    }\n}\n')
          .replace("(\n", '(\n    defaultPrim = "Empty"\n', 1))
    scene = write(tmp_path / "inst.usda", header() + placed("A", "references", "asset.usda", -3)
                  + placed("E", "references", "empty.usda", 9)
                  + placed("B", "references", "asset.usda", 3) + placed("N", "references", "nest.usda", 0)
                  + placed("C", "payload", "asset.usda", 6, instanceable=False) + """
def SphereLight "Lamp"
{
    float inputs:intensity = 1000
    double3 xformOp:translate = (4, 1, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
""")
    probes = ["/A/P", "/B/P", "/N/Inner/P", "/C/P"]
    assert Usd.Stage.Open(str(scene)).GetPrimAtPath("/A/P").IsInstanceProxy()
    summary = bakery.bake(scene, tmp_path / "inst.h5", face_size=8, encodings=["sh2"], samples=1)
    assert summary.baked == 4
    session = Sdf.Layer.CreateAnonymous(".usda")
    session.subLayerPaths = [summary.layer, str(scene)]
    user = Sdf.Layer.FindOrOpen(str(scene))  # held: a spec of a released layer is expired
    for key in ("metersPerUnit", "upAxis"):
        session.pseudoRoot.SetInfo(key, user.pseudoRoot.GetInfo(key))
    baked_layer = Sdf.Layer.FindOrOpen(summary.layer)
    session.defaultPrim = baked_layer.defaultPrim  # the scene has none: the layer's (its first root)
    composed = Usd.Stage.Open(session)
    store = read_store(summary.store)
    fields = store.encodings["sh2"]["fields"]
    row_of = {store.probe_names[int(p)]: r for r, p in enumerate(fields["probe_index"])}
    values = {}
    for path in probes:
        prim = composed.GetPrimAtPath(path)
        assert prim.GetTypeName() == "BakeryIrradianceProbe" and not prim.IsInstanceProxy(), path
        attr = prim.GetAttribute("bakery:irradiance:sh2:radiance_sh")
        assert attr.HasAuthoredValue(), path
        values[path] = np.asarray(attr.Get()).reshape(4, 3)
        np.testing.assert_array_equal(values[path], fields["radiance_sh"][row_of[path]], err_msg=path)
    assert values["/B/P"][0, 0] > 2.0 * values["/A/P"][0, 0]  # B is next to the lamp, A 7 away
    assert sorted(engine_reader.read_layer(summary.layer)) == sorted(probes)
    # the instances above probes are de-instanced; one without probes stays instanced
    assert not composed.GetPrimAtPath("/A").IsInstance() and not composed.GetPrimAtPath("/N/Inner").IsInstance()
    assert composed.GetPrimAtPath("/E").IsInstance()
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    for stage in (composed, Usd.Stage.Open(baked_layer)):
        errors = [e for e in UsdValidation.ValidationContext(validators).Validate(stage)
                  if e.GetType() == UsdValidation.ValidationErrorType.Error]
        assert not errors, [f"{e.GetName()}: {e.GetMessage()}" for e in errors]


def test_layer_of_a_scene_without_instances_has_no_instanceable_opinion(tmp_path):
    scene = write(tmp_path / "plain.usda", _lit_scene("Y", 1.0, (1.5, 0.8, -0.6)))
    summary = bakery.bake(scene, tmp_path / "plain.h5", face_size=8, encodings=["sh2"], samples=1)
    layer = Sdf.Layer.FindOrOpen(summary.layer)
    specs = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: specs.append(layer.GetPrimAtPath(p)) if p.IsPrimPath() else 0)
    assert specs and not any(spec.HasInfo("instanceable") for spec in specs)


@pytest.mark.parametrize("scale", [(-2.0, 1.0, 1.0), (1.0, -0.5, 1.0), (1.5, 1.5, -1.5)])
def test_mirrored_captured_image_probe_follows_its_transform(tmp_path, scale):
    """``bakery:capture:image`` is in the probe's local frame (schema): the image's zenith (+Y local) lands on the
    world direction of the probe's local +Y, and its +X hemisphere on local +X's, mirrors included — as a mirrored
    DomeLight's sky. Before, a mirror became an arbitrary rotation: scale (−2, 1, 1) turned the image upside down."""
    h, w = 32, 64
    rows = (np.arange(h) + 0.5) / h
    cols = (np.arange(w) + 0.5) / w
    pixels = np.zeros((h, w, 3), dtype=np.float32)
    pixels[..., 0] = (rows < 0.5)[:, None] * 1.0                       # R: the upper hemisphere (+Y)
    pixels[..., 1] = (np.sin(2 * np.pi * (0.5 - cols)) > 0)[None, :]  # G: longitude in (0, π): the +X hemisphere
    out = oiio.ImageOutput.create(str(tmp_path / "cap.exr"))
    assert out.open(str(tmp_path / "cap.exr"), oiio.ImageSpec(w, h, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()
    text = header() + f"""
def BakeryIrradianceProbe "P"
{{
    asset bakery:capture:image = @./cap.exr@
    float xformOp:rotateY = 30
    float3 xformOp:scale = {scale}
    uniform token[] xformOpOrder = ["xformOp:rotateY", "xformOp:scale"]
}}
"""
    path = write(tmp_path / "mirror.usda", text)
    reading = read_scene(path)
    assert not reading.errors
    world = np.array(_world(Usd.Stage.Open(str(path)), "/P"), dtype=np.float64)[:3, :3]
    local_axes = world / np.linalg.norm(world, axis=1, keepdims=True)  # rows: local X, Y, Z in the world
    np.testing.assert_allclose(np.asarray(reading.scene.probes[0].rotation).T, local_axes, atol=1e-9)
    n = 16
    cube, _ = capture_probes(reading.scene, n)
    d = cube_texel_directions(n).reshape(-1, 3)
    values = cube[0].reshape(-1, 3)
    for channel, axis in ((0, local_axes[1]), (1, local_axes[0])):
        side = d @ axis
        assert values[side > 0.3, channel].mean() > 0.95 and values[side < -0.3, channel].mean() < 0.05


def test_layer_overs_land_on_utf8_names_and_variant_probes(tmp_path):
    """UTF-8 prim names (USD ≥ 24) and a probe defined inside the selected variant: each composed probe prim gets
    its baked attributes and keeps its type; the unselected variant's probe is not baked."""
    scene = write(tmp_path / "names.usda", header() + """
def Xform "Wörld" (
    variants = { string look = "b" }
    prepend variantSets = "look"
)
{
    def BakeryIrradianceProbe "Probé_日本"
    {
    }
    variantSet "look" = {
        "a" {
            def BakeryIrradianceProbe "Unselected" { }
        }
        "b" {
            def BakeryIrradianceProbeVolume "VarVolume"
            {
                int3 bakery:volume:counts = (1, 1, 2)
            }
        }
    }
}
def DomeLight "Sky"
{
}
""")
    summary = bakery.bake(scene, tmp_path / "names.h5", face_size=8, encodings=["sh2"], samples=1)
    session = Sdf.Layer.CreateAnonymous(".usda")
    session.subLayerPaths = [summary.layer, str(scene)]
    composed = Usd.Stage.Open(session)
    expected = {"/Wörld/Probé_日本": ("BakeryIrradianceProbe", 1),
                "/Wörld/VarVolume": ("BakeryIrradianceProbeVolume", 2)}
    assert sorted(engine_reader.read_layer(summary.layer)) == sorted(expected)
    for path, (type_name, count) in expected.items():
        prim = composed.GetPrimAtPath(path)
        assert prim.GetTypeName() == type_name
        assert prim.GetAttribute("bakery:baked:probeCount").Get() == count
        assert len(prim.GetAttribute("bakery:irradiance:sh2:radiance_sh").Get()) == 4 * count
