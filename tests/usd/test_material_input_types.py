"""Material inputs are read with the types their shader definitions declare, and out-of-range constants are reported.

Types: Sdr's node definitions (UsdPreviewSurface, UsdUVTexture, UsdPrimvarReader_*) and MaterialX's standard library
(``ND_*`` shaders) — not a table of ours. A value of another type (``string inputs:roughness = "rough"`` used to
surface as a numpy error on the mesh; ``float inputs:diffuseColor = 0.5`` was silently broadcast to grey) is an error
on the prim that authored it, naming the input, its authored and its expected type. Ranges: UsdPreviewSurface's
unit inputs outside [0, 1], negative colours and reflectances above 1 are warnings, and the capture reads them
clamped — checked against a bake of the clamped values."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Sdf, Sdr
from usd_scenes import header, mtlx_material, plane_mesh, probe, write

import bakery
from bakery.errors import SceneWarning
from bakery.usd.check import check_scene
from bakery.usd.materials import declared_input_type
from bakery.usd.scene import read_scene

LAMP = """
def SphereLight "Lamp"
{
    float inputs:intensity = 20
    double3 xformOp:translate = (0, 3, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""


def preview(inputs: str, extra: str = "", interface: str = "") -> str:
    """Material /Mat with a UsdPreviewSurface /Mat/Surface of ``inputs`` (usda lines), ``extra`` shaders and
    ``interface`` inputs on the material."""
    return f"""
def Material "Mat"
{{
    {interface}
    token outputs:surface.connect = </Mat/Surface.outputs:surface>
    def Shader "Surface"
    {{
        uniform token info:id = "UsdPreviewSurface"
        {inputs}
        token outputs:surface
    }}
    {extra}
}}
"""


def scene(material_text: str, material_path: str = "/Mat") -> str:
    floor = plane_mesh("Floor", 2.0, material_path, extra="uniform bool doubleSided = 1")
    return header() + LAMP + material_text + floor + probe("P", (0, 1, 0))


READER = """def Shader "Reader"
    {
        uniform token info:id = "UsdPrimvarReader_float3"
        float inputs:fallback = 0.5
        string inputs:varname = "displayColor"
        float3 outputs:result
    }"""

#: case: (scene, prim, input, authored type, expected type)
WRONG_TYPES = {
    "roughness_string": (scene(preview('string inputs:roughness = "rough"')),
                         "/Mat/Surface", "inputs:roughness", "string", "float"),
    "diffuse_float": (scene(preview("float inputs:diffuseColor = 0.5")),  # was broadcast to (0.5, 0.5, 0.5)
                      "/Mat/Surface", "inputs:diffuseColor", "float", "color3f"),
    "metallic_colour": (scene(preview("color3f inputs:metallic = (1, 0, 0)")),  # was its mean
                        "/Mat/Surface", "inputs:metallic", "color3f", "float"),
    "roughness_float2": (scene(preview("float2 inputs:roughness = (0.1, 0.2)")),
                         "/Mat/Surface", "inputs:roughness", "float2", "float"),
    "specular_workflow_token": (scene(preview('token inputs:useSpecularWorkflow = "yes"')),
                                "/Mat/Surface", "inputs:useSpecularWorkflow", "token", "int"),
    "interface_input_string": (scene(preview("float inputs:roughness.connect = </Mat.inputs:rough>",
                                             interface='string inputs:rough = "x"')),
                               "/Mat", "inputs:rough", "string", "float"),
    "primvar_reader_fallback_float": (scene(preview("color3f inputs:diffuseColor.connect = "
                                                    "</Mat/Reader.outputs:result>", extra=READER)),
                                      "/Mat/Reader", "inputs:fallback", "float", "float3"),
    "texture_file_string": (scene(preview("color3f inputs:diffuseColor.connect = </Mat/Tex.outputs:rgb>", extra="""
    def Shader "Tex"
    {
        uniform token info:id = "UsdUVTexture"
        string inputs:file = "wood.png"
        float3 outputs:rgb
    }""")), "/Mat/Tex", "inputs:file", "string", "asset"),
    "mtlx_base_color_float": (scene(mtlx_material("Mx", "ND_standard_surface_surfaceshader",
                                                  "float inputs:base_color = 0.5"), "/Mx"),
                              "/Mx/Surf", "inputs:base_color", "float", "color3f"),
    "mtlx_roughness_string": (scene(mtlx_material("Mx", "ND_open_pbr_surface_surfaceshader",
                                                  'string inputs:specular_roughness = "x"'), "/Mx"),
                              "/Mx/Surf", "inputs:specular_roughness", "string", "float"),
}


@pytest.mark.parametrize("case", sorted(WRONG_TYPES))
def test_wrongly_typed_material_input_is_an_error_on_its_prim(tmp_path, case):
    text, prim, name, authored, expected = WRONG_TYPES[case]
    issues = check_scene(write(tmp_path / f"{case}.usda", text))
    errors = [i for i in issues if i.severity == "error"]
    assert [i.prim for i in errors] == [prim], issues  # one error, on the prim that authored the value
    message = errors[0].message
    assert f"{name} is authored as {authored}" in message and f"expected {expected}" in message, message


def mtlx_validate(document: str) -> tuple[bool, str]:
    """MaterialX's own verdict on a document (with its standard library): (valid, messages)."""
    import MaterialX as mx

    parsed = mx.createDocument()
    mx.readFromXmlString(parsed, document)
    library = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
    parsed.importLibrary(library)
    return parsed.validate()


def test_wrongly_typed_input_in_a_mtlx_document_is_an_error_on_the_material(tmp_path):
    """The same check for a ``.mtlx`` document (read with the MaterialX package): the types MaterialX's own
    validation calls an interface error."""
    document = """<?xml version="1.0"?>
<materialx version="1.39">
  <standard_surface name="SR" type="surfaceshader">
    <input name="base_color" type="float" value="0.5" />
    <input name="specular_roughness" type="float" value="0.3" />
  </standard_surface>
  <surfacematerial name="Doc" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
"""
    write(tmp_path / "looks.mtlx", document)
    valid, why = mtlx_validate(document)
    assert not valid and "base_color" in why  # MaterialX agrees that the document is wrong
    text = (header() + LAMP + 'def Scope "Looks" (\n    references = @./looks.mtlx@</MaterialX>\n)\n{\n}\n'
            + plane_mesh("Floor", 2.0, "/Looks/Materials/Doc") + probe("P", (0, 1, 0)))
    issues = check_scene(write(tmp_path / "scene.usda", text))
    errors = [i for i in issues if i.severity == "error"]
    assert len(errors) == 1 and errors[0].prim == "/Looks/Materials/Doc", issues
    assert "base_color is authored as float '0.5', expected color3" in errors[0].message, errors[0].message


GRAPH_DOCUMENT = """<?xml version="1.0"?>
<materialx version="1.39">
  <nodegraph name="NG">
    <image name="tex" type="color3">
      <input name="file" type="filename" value="missing.png" />
    </image>
    {node}
    <output name="out" type="color3" nodename="m" />
  </nodegraph>
  <standard_surface name="SR" type="surfaceshader">
    <input name="base_color" type="color3" nodegraph="NG" output="out" />
  </standard_surface>
  <surfacematerial name="Doc" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
"""

GRAPH_NODES = {  # a graph node no standard library definition matches: (node XML, expected sentence)
    "input_type": ('<multiply name="m" type="color3"><input name="in1" type="color3" nodename="tex" />'
                   '<input name="in2" type="string" value="abc" /></multiply>',
                   "node NG/m (multiply, color3): input in2 is authored as string 'abc', expected color3 or float"),
    "unknown_input": ('<multiply name="m" type="color3"><input name="in1" type="color3" nodename="tex" />'
                      '<input name="gain" type="float" value="2" /></multiply>',
                      "node NG/m (multiply, color3): gain is not an input of multiply"),
    "output_type": ('<multiply name="m" type="string"><input name="in1" type="color3" nodename="tex" /></multiply>',
                    "node NG/m (multiply, string): no definition of multiply outputs string"),
    "upstream": ('<multiply name="m" type="color3"><input name="in1" type="color3" nodename="k" /></multiply>'
                 '<constant name="k" type="color3"><input name="value" type="float" value="0.5" /></constant>',
                 "node NG/k (constant, color3): input value is authored as float '0.5', expected color3"),
}


@pytest.mark.parametrize("case", sorted(GRAPH_NODES))
def test_a_mtlx_graph_node_matching_no_definition_is_an_error_on_the_material(tmp_path, case):
    """Nodes inside a ``.mtlx`` document's graphs: MaterialX picks a node's definition by its output and input
    types, and a node that matches none is what its validate() reports; it is an error on the material, naming
    the node and the input, not a numpy error on the mesh (before: "/Floor: cannot be read: could not convert
    string to float: 'abc'")."""
    node, expected = GRAPH_NODES[case]
    document = GRAPH_DOCUMENT.replace("{node}", node)
    write(tmp_path / "looks.mtlx", document)
    assert not mtlx_validate(document)[0]  # MaterialX agrees that the document is wrong
    text = (header() + LAMP + 'def Scope "Looks" (\n    references = @./looks.mtlx@</MaterialX>\n)\n{\n}\n'
            + plane_mesh("Floor", 2.0, "/Looks/Materials/Doc") + probe("P", (0, 1, 0)))
    errors = [i for i in check_scene(write(tmp_path / "scene.usda", text)) if i.severity == "error"]
    assert [i.prim for i in errors] == ["/Looks/Materials/Doc"], errors
    assert f"MaterialX looks.mtlx: {expected}" in errors[0].message, errors[0].message


def test_bake_refuses_a_wrongly_typed_material_input_and_writes_nothing(tmp_path):
    path = write(tmp_path / "scene.usda", WRONG_TYPES["roughness_string"][0])
    with pytest.raises(bakery.errors.SceneError) as raised:
        bakery.bake(path, tmp_path / "out.h5", face_size=8, samples=1)
    assert "/Mat/Surface" in str(raised.value) and "inputs:roughness" in str(raised.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.usda"]


def test_declared_types_are_the_shader_definitions():
    """The expected types come from Sdr (UsdPreviewSurface, UsdUVTexture) and MaterialX's standard library."""
    import MaterialX as mx

    node = Sdr.Registry().GetShaderNodeByIdentifier("UsdPreviewSurface")
    for name in node.GetShaderInputNames():
        assert declared_input_type("UsdPreviewSurface", name) == node.GetShaderInput(name).GetTypeAsSdfType() \
            .GetSdfType()
    assert declared_input_type("UsdUVTexture", "file") == Sdf.ValueTypeNames.Asset
    library = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
    node_def = library.getNodeDef("ND_standard_surface_surfaceshader")
    assert node_def.getActiveInput("base_color").getType() == "color3"
    assert declared_input_type("ND_standard_surface_surfaceshader", "base_color") == Sdf.ValueTypeNames.Color3f
    assert declared_input_type("ND_standard_surface_surfaceshader", "no_such_input") is None
    assert declared_input_type("MyStudioSurface", "roughness") is None  # unknown shaders are not checked


def test_other_precisions_roles_and_string_tokens_read_as_before(tmp_path):
    text = scene(preview("double inputs:roughness = 0.25\n        double3 inputs:diffuseColor = (0.2, 0.3, 0.4)\n"
                         "        vector3f inputs:normal = (0, 0, 1)\n"
                         "        color3f inputs:emissiveColor.connect = </Mat/Reader.outputs:result>",
                         extra=READER.replace("float inputs:fallback = 0.5", "double3 inputs:fallback = (1, 0, 0)")
                         .replace("string inputs:varname", "token inputs:varname")))
    reading = read_scene(write(tmp_path / "ok.usda", text), load_textures=False)
    assert not reading.errors, reading.errors
    material = next(m.material for m in reading.scene.meshes if m.material.name == "/Mat")
    assert material.roughness == 0.25 and material.diffuse == pytest.approx((0.2, 0.3, 0.4))
    assert material.emission == pytest.approx((1.0, 0.0, 0.0))  # the reader's fallback


#: authored inputs → the values the capture reads (UsdPreviewSurface ranges)
CLAMPED = {
    "unit inputs": ("float inputs:roughness = 7\n        float inputs:metallic = -0.5",
                    "float inputs:roughness = 1\n        float inputs:metallic = 0",
                    ["roughness = 7 is outside [0, 1]", "metallic = -0.5 is outside [0, 1]"]),
    "colours": ("color3f inputs:diffuseColor = (2, 0.5, -1)",
                "color3f inputs:diffuseColor = (1, 0.5, 0)",
                ["diffuseColor = (2, 0.5, -1) has negative components", "diffuseColor = (2, 0.5, -1) has components "
                                                                        "above 1"]),
}


@pytest.mark.parametrize("case", list(CLAMPED))
def test_out_of_range_inputs_are_reported_and_read_clamped(tmp_path, case):
    authored, clamped, words = CLAMPED[case]
    issues = check_scene(write(tmp_path / "authored.usda", scene(preview(authored))))
    messages = [i.message for i in issues if i.prim == "/Mat" and i.severity == "warning"]
    for needle in words:
        assert any(needle in m for m in messages), (needle, messages)
    assert not [i for i in check_scene(write(tmp_path / "clamped.usda", scene(preview(clamped))))
                if i.prim == "/Mat"]
    settings = dict(encodings=["sh2"], face_size=8, samples=2, bounces=2, jobs=1)
    with pytest.warns(SceneWarning, match="outside|negative|above 1"):
        bakery.bake(tmp_path / "authored.usda", tmp_path / "authored.h5", **settings)
    bakery.bake(tmp_path / "clamped.usda", tmp_path / "clamped.h5", **settings)
    normals = np.eye(3)
    a = bakery.open_store(tmp_path / "authored.h5").evaluate_irradiance("sh2", normals)
    b = bakery.open_store(tmp_path / "clamped.h5").evaluate_irradiance("sh2", normals)
    np.testing.assert_array_equal(a, b)  # the same render, ray for ray
