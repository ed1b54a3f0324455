"""UsdPreviewSurface normal maps in the capture: a Lambertian floor whose tangent-space normal map tilts the normal
by β under a sun at 30° shades as ρE·(n·l)/π with n the tilted normal (closed form), along +s and +t (tangent
frame and handedness from the texture coordinates), and a flat map changes nothing."""

from __future__ import annotations

import math

import numpy as np
import OpenImageIO as oiio
import pytest
from harness import single_scattering
from usd_scenes import header, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16
RHO, E, SUN, TURN = 0.5, 2.0, math.radians(30.0), math.radians(40.0)
#: the sun's direction: 30° from the zenith, turned 40° about +Y from +x (so it has x and z components)
LIGHT = np.array([math.sin(SUN) * math.cos(TURN), math.cos(SUN), -math.sin(SUN) * math.sin(TURN)])


def _write_exr(path, rgb):
    pixels = np.broadcast_to(np.asarray(rgb, dtype=np.float32), (4, 4, 3)).copy()
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(4, 4, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()


def _material(normal_file: str | None, colour_space: str = "raw") -> str:
    normal = "" if normal_file is None else "normal3f inputs:normal.connect = </Floor/NormalTex.outputs:rgb>"
    texture = "" if normal_file is None else f"""
    def Shader "Reader"
    {{
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname = "st"
        float2 outputs:result
    }}
    def Shader "NormalTex"
    {{
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @{normal_file}@
        token inputs:sourceColorSpace = "{colour_space}"
        token inputs:wrapS = "repeat"
        token inputs:wrapT = "repeat"
        float2 inputs:st.connect = </Floor/Reader.outputs:result>
        float4 inputs:scale = (2, 2, 2, 1)
        float4 inputs:bias = (-1, -1, -1, 0)
        float3 outputs:rgb
    }}"""
    return f"""
def Material "Floor"
{{
    token outputs:surface.connect = </Floor/Surface.outputs:surface>
    def Shader "Surface"
    {{
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor = ({RHO}, {RHO}, {RHO})
        int inputs:useSpecularWorkflow = 1
        color3f inputs:specularColor = (0, 0, 0)
        {normal}
        token outputs:surface
    }}{texture}
}}
"""


def _floor(uvs: bool = True, reverse: bool = False) -> str:
    # s along +x, t along −z (right-handed with the +Y winding normal; ``reverse``: the winding normal is −Y and
    # the probe above sees the back side)
    st = ('texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (\n        interpolation = "faceVarying"\n    )'
          if uvs else "")
    indices = "3, 2, 1, 0" if reverse else "0, 1, 2, 3"
    if reverse:
        st = st.replace("[(0, 0), (1, 0), (1, 1), (0, 1)]", "[(0, 1), (1, 1), (1, 0), (0, 0)]")
    return f"""
def Mesh "Ground" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [{indices}]
    point3f[] points = [(-20, 0, 20), (20, 0, 20), (20, 0, -20), (-20, 0, -20)]
    {st}
    uniform token subdivisionScheme = "none"
    rel material:binding = </Floor>
}}
"""


def _sun() -> str:
    return f"""
def DistantLight "Sun"
{{
    float inputs:intensity = {E}
    bool inputs:normalize = 1
    float inputs:angle = 0.1
    float xformOp:rotateY = {math.degrees(TURN)}
    float xformOp:rotateZ = {-math.degrees(SUN)}
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:rotateY", "xformOp:rotateZ", "xformOp:rotateX"]
}}
"""


def _capture(tmp_path, material: str, name: str, uvs: bool = True, reverse: bool = False):
    reading = read_scene(write(tmp_path / f"{name}.usda", header() + material + _floor(uvs, reverse) + _sun()
                               + probe("P", (0.0, 0.5, 0.0))))
    # the MaterialX floors against their UsdPreviewSurface twins: the normal map, not the lobes' layering
    cubes, _ = capture_probes(single_scattering(reading.scene), N, samples=4, bounces=0)
    return cubes[0], reading


def _down():
    return cube_texel_directions(N)[..., 1] < -0.3


@pytest.mark.parametrize("tilt_deg, axis, reverse", [(20.0, "s", False), (-20.0, "s", False), (20.0, "t", False),
                                                     (-20.0, "t", False), (45.0, "s", False), (20.0, "s", True),
                                                     (20.0, "t", True)])
def test_tilted_normal_map_shades_with_the_mapped_normal(tmp_path, tilt_deg, axis, reverse):
    """n_tangent = (sin β, 0, cos β) (along +s = world +x) or (0, sin β, cos β) (along +t = world −z); the sun
    comes from l (30° from the zenith, with x and z components): the floor is ρE·max(0, n·l)/π wherever the mapped normal faces the probe,
    and ρE·cos 30°/π (the unperturbed normal) where it faces away. Seen from the back of the triangle (reversed
    winding) the mapped normal is mirrored with the surface: −(x·T + y·B + z·N_front)."""
    beta = math.radians(tilt_deg)
    tangent = (math.sin(beta), 0.0, math.cos(beta)) if axis == "s" else (0.0, math.sin(beta), math.cos(beta))
    _write_exr(tmp_path / "n.exr", [(c + 1) / 2 for c in tangent])
    cube, reading = _capture(tmp_path, _material("./n.exr"), "tilted", reverse=reverse)
    assert not [i for i in reading.issues if "normal" in i.message], reading.issues
    world = np.array([tangent[0], tangent[2], -tangent[1]])  # T = +x, N = +y, B = −z
    if reverse:  # front N = −y (B = −z still): −(x·T + y·B − z·y)
        world = -np.array([tangent[0], -tangent[2], -tangent[1]])
    light = LIGHT
    expected = RHO * E * max(0.0, float(world @ light)) / math.pi
    d = cube_texel_directions(N)
    facing = (-d @ world) > 0.02  # wo = −d: the mapped normal faces the viewer
    away = (-d @ world) < -0.02
    np.testing.assert_allclose(cube[_down() & facing], expected, rtol=1e-3)  # the sun disc: ±5e-4
    np.testing.assert_allclose(cube[_down() & away], RHO * E * math.cos(SUN) / math.pi, rtol=1e-3)
    assert (_down() & facing).sum() > 300


def test_flat_normal_map_and_meshes_without_coordinates_change_nothing(tmp_path):
    """A map of (0, 0, 1) shades as the plain floor; a normal-mapped mesh without texture coordinates keeps its
    normals (the map needs a tangent frame)."""
    _write_exr(tmp_path / "flat.exr", (0.5, 0.5, 1.0))
    plain, _ = _capture(tmp_path, _material(None), "plain")
    flat, _ = _capture(tmp_path, _material("./flat.exr"), "flat")
    np.testing.assert_allclose(flat, plain, rtol=1e-6, atol=1e-9)
    _write_exr(tmp_path / "tilted.exr", (0.8, 0.5, 0.9))
    no_uv, reading = _capture(tmp_path, _material("./tilted.exr"), "nouv", uvs=False)
    np.testing.assert_allclose(no_uv, plain, rtol=1e-6, atol=1e-9)


def test_normal_map_decoded_as_srgb_is_reported(tmp_path):
    _write_exr(tmp_path / "flat.exr", (0.5, 0.5, 1.0))
    _cube, reading = _capture(tmp_path, _material("./flat.exr", colour_space="sRGB"), "srgb")
    assert any("normal map decoded as sRGB" in i.message for i in reading.issues)


def _document(nodes: str, normal: str, lobe: str) -> str:
    """A .mtlx document: ``nodes`` (the normal's graph), a standard_surface floor of albedo ρ whose ``normal`` is the
    node ``normal``, with the specular input line ``lobe``."""
    return f"""<?xml version="1.0"?>
<materialx version="1.39">
{nodes}
  <standard_surface name="SR_floor" type="surfaceshader">
    <input name="base" type="float" value="1" />
    <input name="base_color" type="color3" value="{RHO}, {RHO}, {RHO}" />
    {lobe}
    <input name="normal" type="vector3" nodename="{normal}" />
  </standard_surface>
  <surfacematerial name="Floor" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR_floor" />
  </surfacematerial>
</materialx>
"""


_MTLX = _document("""  <image name="bumps" type="vector3">
    <input name="file" type="filename" value="n.exr" />
  </image>
  <normalmap name="mapped" type="vector3">
    <input name="in" type="vector3" nodename="bumps" />
    <input name="scale" type="float" value="{scale}" />
  </normalmap>""", "mapped", '<input name="specular_roughness" type="float" value="0.4" />')


def _twin(scale: float) -> str:
    """The UsdPreviewSurface twin of :data:`_MTLX`: the same lobes, the normalmap's decoding as scale/bias."""
    text = _material("./n.exr").replace(
        "int inputs:useSpecularWorkflow = 1\n        color3f inputs:specularColor = (0, 0, 0)",
        "float inputs:roughness = 0.4")
    return text.replace("float4 inputs:scale = (2, 2, 2, 1)", f"float4 inputs:scale = ({2 * scale}, {2 * scale}, 2, 1)"
                        ).replace("float4 inputs:bias = (-1, -1, -1, 0)",
                                  f"float4 inputs:bias = ({-scale}, {-scale}, -1, 0)")


def _image_node(name: str, file: str) -> str:
    """A MaterialX ``image`` node of vector3 output as a USD shader under /Floor (usda)."""
    return f"""    def Shader "{name}"
    {{
        uniform token info:id = "ND_image_vector3"
        asset inputs:file = @{file}@
        float3 outputs:out
    }}
"""


def _assert_captures_as(tmp_path, authored: str, name: str, expected: np.ndarray) -> None:  # noqa: ANN001
    """The floor ``authored`` as ND_ shaders captures as ``expected`` (10⁻⁵), its normal map read unreported."""
    in_usd, reading = _capture(tmp_path, authored, name)
    assert not [i for i in reading.issues if "normal" in i.message], reading.issues
    np.testing.assert_allclose(in_usd, expected, rtol=1e-5, atol=1e-8)


def _authored_floor(normal: str, lobe: str, shaders: str) -> str:
    """The standard_surface floor as ND_ shaders in USD: albedo ρ, the specular input line ``lobe``, its ``normal``
    connected to the shader ``normal`` among ``shaders`` (usda of the graph under /Floor)."""
    return f"""
def Material "Floor"
{{
    token outputs:mtlx:surface.connect = </Floor/Surf.outputs:out>
    def Shader "Surf"
    {{
        uniform token info:id = "ND_standard_surface_surfaceshader"
        float inputs:base = 1
        color3f inputs:base_color = ({RHO}, {RHO}, {RHO})
        {lobe}
        float3 inputs:normal.connect = </Floor/{normal}.outputs:out>
        token outputs:out
    }}
{shaders}}}
"""


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_materialx_normalmap_matches_its_preview_surface_twin(tmp_path, scale):
    """A standard_surface whose ``normal`` is a tangent-space ``normalmap`` (xy × scale) of an image captures as the
    UsdPreviewSurface with the same lobes and the map decoded by scale/bias — in a .mtlx document and authored in
    USD as ND_ shaders."""
    _write_exr(tmp_path / "n.exr", (0.7, 0.4, 0.9))
    (tmp_path / "floor.mtlx").write_text(_MTLX.replace("{scale}", str(scale)))
    document = """
def Scope "Looks" (
    references = @./floor.mtlx@</MaterialX>
)
{
}
"""
    twin, _ = _capture(tmp_path, _twin(scale), "twin")
    _write_exr(tmp_path / "flat.exr", (0.5, 0.5, 1.0))
    unmapped, _ = _capture(tmp_path, _twin(scale).replace("./n.exr", "./flat.exr"), "unmapped")
    assert np.abs(twin - unmapped)[_down()].max() > 0.05 * twin[_down()].max()  # the map matters
    floor = _floor().replace("</Floor>", "</Looks/Materials/Floor>")
    reading = read_scene(write(tmp_path / "doc.usda", header() + document + floor + _sun() + probe("P", (0, 0.5, 0))))
    assert not [i for i in reading.issues if "normal" in i.message], reading.issues
    entry = next(e for e in reading.scene.meshes[0].material.maps if e["input"] == "normal")
    assert entry["scale"] == (2 * scale, 2 * scale, 2.0, 1.0) and entry["bias"] == (-scale, -scale, -1.0, 0.0)
    from_document, _ = capture_probes(single_scattering(reading.scene), N, samples=4, bounces=0)
    np.testing.assert_allclose(from_document[0], twin, rtol=1e-5, atol=1e-8)
    authored = _authored_floor("Mapped", "float inputs:specular_roughness = 0.4", f"""
    def Shader "Mapped"
    {{
        uniform token info:id = "ND_normalmap_float"
        float3 inputs:in.connect = </Floor/Bumps.outputs:out>
        float inputs:scale = {scale}
        float3 outputs:out
    }}
""" + _image_node("Bumps", "./n.exr"))
    _assert_captures_as(tmp_path, authored, "authored", twin)


def test_a_rotated_normal_map_turns_its_tangent_frame_with_its_coordinates(tmp_path):
    """UsdTransform2d rotation 90° on the normal map's st: st' = (−t, s), so dP/ds' = −dP/dt = +z and dP/dt' =
    dP/ds = +x (right-handed with N = +y): a tilt β along +s' is the world normal (0, cos β, sin β)."""
    beta = math.radians(25.0)
    _write_exr(tmp_path / "n.exr", [(c + 1) / 2 for c in (math.sin(beta), 0.0, math.cos(beta))])
    material = _material("./n.exr").replace(
        "float2 inputs:st.connect = </Floor/Reader.outputs:result>",
        "float2 inputs:st.connect = </Floor/Rotate.outputs:result>").replace("""    def Shader "NormalTex\"""", """    def Shader "Rotate"
    {
        uniform token info:id = "UsdTransform2d"
        float2 inputs:in.connect = </Floor/Reader.outputs:result>
        float inputs:rotation = 90
        float2 outputs:result
    }
    def Shader "NormalTex\"""")
    assert "Rotate.outputs" in material
    cube, reading = _capture(tmp_path, material, "rotated")
    assert not [i for i in reading.issues if "normal" in i.message], reading.issues
    world = np.array([0.0, math.cos(beta), math.sin(beta)])
    expected = RHO * E * max(0.0, float(world @ LIGHT)) / math.pi
    d = cube_texel_directions(N)
    facing = (-d @ world) > 0.1  # texels whose rays all see the mapped normal's front
    np.testing.assert_allclose(cube[_down() & facing], expected, rtol=1e-3)
    assert (_down() & facing).sum() > 300


_WORLD_MTLX = _document("""  <image name="normals" type="vector3">
    <input name="file" type="filename" value="w.exr" />
  </image>
  <multiply name="twice" type="vector3">
    <input name="in1" type="vector3" nodename="normals" />
    <input name="in2" type="float" value="2" />
  </multiply>
  <subtract name="centred" type="vector3">
    <input name="in1" type="vector3" nodename="twice" />
    <input name="in2" type="float" value="1" />
  </subtract>
  <normalize name="unit" type="vector3">
    <input name="in" type="vector3" nodename="centred" />
  </normalize>""", "unit", '<input name="specular" type="float" value="0" />')
#: a world-space normal tilted towards +x and −z in the Y-up bake frame
WORLD_NORMAL = np.array([0.35, 0.9, -0.25]) / np.linalg.norm([0.35, 0.9, -0.25])


def _world_scene(tmp_path, name: str, up_axis: str = "Y") -> tuple[np.ndarray, object]:
    """The Lambertian floor (specular 0) under the sun with the world-space normal map of :data:`_WORLD_MTLX`; for
    a Z-up stage the whole scene sits under a +90° rotation about x (the Y-up scene turned into Z-up axes), and the
    map holds the normal in those axes, (x, −z, y)."""
    normal = WORLD_NORMAL if up_axis == "Y" else WORLD_NORMAL[[0, 2, 1]] * np.array([1, -1, 1])
    _write_exr(tmp_path / "w.exr", (normal + 1) / 2)
    (tmp_path / "world.mtlx").write_text(_WORLD_MTLX)
    content = ('def Scope "Looks" (\n    references = @./world.mtlx@</MaterialX>\n)\n{\n}\n'
               + _floor().replace("</Floor>", "</Looks/Materials/Floor>") + _sun() + probe("P", (0.0, 0.5, 0.0)))
    if up_axis == "Z":  # the same content, turned: every prim under an Xform rotated +90° about x
        body = "\n".join("    " + line for line in content.replace("</Looks", "</World/Looks").splitlines())
        content = (f'def Xform "World"\n{{\n    float xformOp:rotateX = 90\n'
                   f'    uniform token[] xformOpOrder = ["xformOp:rotateX"]\n{body}\n}}\n')
    reading = read_scene(write(tmp_path / f"{name}.usda", header(up_axis) + content))
    assert not [i for i in reading.issues if "normal" in i.message], reading.issues
    cubes, _ = capture_probes(reading.scene, N, samples=4, bounces=0)
    return cubes[0], reading


def test_a_world_space_normal_map_shades_with_its_normal(tmp_path):
    """MaterialX ``normalize(2·image − 1)`` on a surface's ``normal`` (world space, MaterialX's Nworld; a 1.38
    object-space normalmap upgrades to exactly this): the floor is ρE·max(0, n·l)/π with n the map's normal
    wherever n faces the probe; a Z-up stage holding the same scene turned (and the normal in its axes) captures
    the same probe."""
    cube, reading = _world_scene(tmp_path, "world")
    (entry,) = [e for e in reading.scene.meshes[0].material.maps if e["input"] == "normal"]
    assert entry["space"] == "world" and entry["scale"][:3] == (2.0, 2.0, 2.0) and entry["bias"][:3] == (-1, -1, -1)
    d = cube_texel_directions(N)
    facing = (-d @ WORLD_NORMAL) > 0.1  # a texel whose rays all see the mapped normal
    expected = RHO * E * max(0.0, float(WORLD_NORMAL @ LIGHT)) / math.pi
    np.testing.assert_allclose(cube[_down() & facing], expected, rtol=1e-3)
    assert abs(expected - RHO * E * math.cos(SUN) / math.pi) > 0.05 * expected  # the map matters
    turned, _ = _world_scene(tmp_path, "world_z", up_axis="Z")
    # texels on the floor off the mapped normal's horizon (where a texel's rays split, by the probe path's seed)
    clear = _down() & (np.abs(d @ WORLD_NORMAL) > 0.1)
    np.testing.assert_allclose(turned[clear], cube[clear], rtol=1e-3)  # the sun disc sampled by another seed


def test_the_shared_object_space_normal_map_reads_as_world_space(shared_data):
    """OpenUSD's MaterialXvsNative normalMap.mtlx (MaterialX 1.38, normalmap space = object) upgrades to a
    normalize of the decoded image: read as a world-space map, with no report."""
    reading = read_scene(shared_data / "usd" / "openusd_MaterialXvsNative" / "materialXnormalMap.usda")
    assert not [i for i in reading.issues if "normal" in i.message], reading.issues
    entries = [e for mesh in reading.scene.meshes for e in mesh.material.maps if e["input"] == "normal"]
    assert entries and all(e["space"] == "world" for e in entries)
    assert all(e["scale"][:3] == (2.0, 2.0, 2.0) and e["bias"][:3] == (-1.0, -1.0, -1.0) for e in entries)


def test_a_world_space_normal_graph_authored_in_usd_captures_as_the_document(tmp_path):
    """The same graph as ND_ shaders in USD (ND_normalize_vector3 over ND_subtract_vector3FA / ND_multiply_vector3FA
    of ND_image_vector3) captures as the document's."""
    document, _ = _world_scene(tmp_path, "document")
    authored = _authored_floor("Unit", "float inputs:specular = 0", """
    def Shader "Unit"
    {
        uniform token info:id = "ND_normalize_vector3"
        float3 inputs:in.connect = </Floor/Centred.outputs:out>
        float3 outputs:out
    }
    def Shader "Centred"
    {
        uniform token info:id = "ND_subtract_vector3FA"
        float3 inputs:in1.connect = </Floor/Twice.outputs:out>
        float inputs:in2 = 1
        float3 outputs:out
    }
    def Shader "Twice"
    {
        uniform token info:id = "ND_multiply_vector3FA"
        float3 inputs:in1.connect = </Floor/Normals.outputs:out>
        float inputs:in2 = 2
        float3 outputs:out
    }
""" + _image_node("Normals", "./w.exr"))
    _assert_captures_as(tmp_path, authored, "authored_world", document)
