"""Small real USD scenes for the USD and capture tests (written as .usda text into tmp_path; no mocks)."""

from __future__ import annotations

from pathlib import Path


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def header(up_axis: str = "Y", meters_per_unit: float = 1.0, extra: str = "") -> str:
    return f'#usda 1.0\n(\n    upAxis = "{up_axis}"\n    metersPerUnit = {meters_per_unit}\n{extra})\n\n'


def material(name: str, diffuse=(0.18, 0.18, 0.18), emissive=(0.0, 0.0, 0.0), extra: str = "",
             diffuse_only: bool = False, inputs: str = "") -> str:
    """A UsdPreviewSurface material. ``diffuse_only``: specular workflow with specularColor 0 (F0 = 0: no specular
    lobe, an exactly Lambertian surface); ``inputs``: extra authored shader inputs (usda lines)."""
    if diffuse_only:
        inputs = "int inputs:useSpecularWorkflow = 1\n        color3f inputs:specularColor = (0, 0, 0)\n        " + inputs
    return f"""
def Material "{name}"
{{
    token outputs:surface.connect = </{name}/Surface.outputs:surface>
    def Shader "Surface"
    {{
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor = ({diffuse[0]}, {diffuse[1]}, {diffuse[2]})
        color3f inputs:emissiveColor = ({emissive[0]}, {emissive[1]}, {emissive[2]})
        {inputs}
        token outputs:surface
    }}
    {extra}
}}
"""


def glowing_material(name: str, emission_source: str, shaders: str) -> str:
    """A black, specular-free UsdPreviewSurface (the probe sees exactly its emission) whose emissiveColor is
    connected to ``emission_source`` (e.g. ``</Glow/Texture.outputs:rgb>``), with the upstream ``shaders`` (usda
    text of the material's other Shader prims)."""
    return f"""
def Material "{name}"
{{
    token outputs:surface.connect = </{name}/Surface.outputs:surface>
    def Shader "Surface"
    {{
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor = (0, 0, 0)
        int inputs:useSpecularWorkflow = 1
        color3f inputs:specularColor = (0, 0, 0)
        color3f inputs:emissiveColor.connect = {emission_source}
        token outputs:surface
    }}{shaders}
}}
"""


def glowing_mtlx_material(name: str, emission_source: str, shaders: str) -> str:
    """:func:`glowing_material` as a MaterialX standard_surface authored in USD (base 0, specular 0, emission 1)
    whose emission_color is connected to ``emission_source``, with the upstream ``shaders`` (usda text)."""
    return f"""
def Material "{name}"
{{
    token outputs:mtlx:surface.connect = </{name}/Surf.outputs:out>
    def Shader "Surf"
    {{
        uniform token info:id = "ND_standard_surface_surfaceshader"
        float inputs:base = 0
        float inputs:specular = 0
        float inputs:emission = 1
        color3f inputs:emission_color.connect = {emission_source}
        token outputs:out
    }}{shaders}
}}
"""


def glowing_mtlx_document(nodes: str, output: str) -> str:
    """A MaterialX document whose material ``Glow`` is an emissive standard_surface (base 0, specular 0, emission 1)
    with emission_color connected to the node ``output`` among ``nodes`` (XML text)."""
    return f"""<?xml version="1.0"?>
<materialx version="1.39">
  {nodes}
  <standard_surface name="SR_glow" type="surfaceshader">
    <input name="base" type="float" value="0" />
    <input name="specular" type="float" value="0" />
    <input name="emission" type="float" value="1" />
    <input name="emission_color" type="color3" nodename="{output}" />
  </standard_surface>
  <surfacematerial name="Glow" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR_glow" />
  </surfacematerial>
</materialx>
"""


def uv_texture_material(file: str, inputs: str = "", output: str = "rgb", transform: str = "", varname: str = "st",
                        fallback=None) -> str:  # noqa: ANN001
    """Material </Glow> whose emission is a UsdUVTexture of ``file`` (its ``output``: rgb, r, g, b or a) read at the
    primvar ``varname`` through a UsdPrimvarReader_float2 (its ``fallback`` authored unless None), and through a
    UsdTransform2d when ``transform`` (its input lines) is given; ``inputs``: more texture inputs (usda lines)."""
    authored = "" if fallback is None else f"\n        float2 inputs:fallback = ({fallback[0]}, {fallback[1]})"
    st_source = "</Glow/Transform.outputs:result>" if transform else "</Glow/Reader.outputs:result>"
    transform_shader = f"""
    def Shader "Transform"
    {{
        uniform token info:id = "UsdTransform2d"
        float2 inputs:in.connect = </Glow/Reader.outputs:result>
        {transform}
        float2 outputs:result
    }}""" if transform else ""
    output_type = "float3" if output == "rgb" else "float"
    return glowing_material("Glow", f"</Glow/Texture.outputs:{output}>", f"""
    def Shader "Texture"
    {{
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @{file}@
        {inputs}
        float2 inputs:st.connect = {st_source}
        {output_type} outputs:{output}
    }}
    def Shader "Reader"
    {{
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname = "{varname}"{authored}
        float2 outputs:result
    }}{transform_shader}""")


def textured_floor(material_path: str, extra: str = "", st=((0, 0), (1, 0), (1, 1), (0, 1))) -> str:  # noqa: ANN001
    """A 2 m square Mesh "Floor" at y = 0, corners (x, z) = (−1, 1), (1, 1), (1, −1), (−1, −1), with texture
    coordinates ``st`` there (default st = ((x + 1)/2, (1 − z)/2): t grows towards −z) bound to
    ``material_path``; ``extra``: more attributes (usda lines)."""
    coordinates = ", ".join(f"({s}, {t})" for s, t in st)
    return f"""
def Mesh "Floor" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]
    texCoord2f[] primvars:st = [{coordinates}] (
        interpolation = "vertex"
    )
    rel material:binding = <{material_path}>{extra}
}}
"""


def mtlx_material(name: str, shader_id: str, inputs: str) -> str:
    """A MaterialX surface authored in USD (a ``mtlx`` surface output of a shader ``shader_id``, e.g.
    ``ND_standard_surface_surfaceshader``); ``inputs``: its authored inputs (usda lines)."""
    return f"""
def Material "{name}"
{{
    token outputs:mtlx:surface.connect = </{name}/Surf.outputs:out>
    def Shader "Surf"
    {{
        uniform token info:id = "{shader_id}"
        {inputs}
        token outputs:out
    }}
}}
"""


def box_mesh(name: str, half: float, material_path: str, centre=(0.0, 0.0, 0.0)) -> str:
    """A closed axis-aligned box Mesh with shared vertices (watertight for ray tracing)."""
    cx, cy, cz = centre
    pts = ", ".join(
        f"({cx + sx * half}, {cy + sy * half}, {cz + sz * half})"
        for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)
    )
    return f"""
def Mesh "{name}" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [0, 1, 3, 2,  4, 6, 7, 5,  0, 4, 5, 1,  2, 3, 7, 6,  0, 2, 6, 4,  1, 5, 7, 3]
    point3f[] points = [{pts}]
    rel material:binding = <{material_path}>
}}
"""


def plane_mesh(name: str, half: float, material_path: str, up_axis: str = "Y", height: float = 0.0,
               extra: str = "") -> str:
    """A square ground plane of half-size ``half`` at ``height`` along the up axis; ``extra``: more usda lines of
    the mesh (normals, subdivisionScheme, …)."""
    if up_axis == "Y":
        pts = [(-half, height, -half), (half, height, -half), (half, height, half), (-half, height, half)]
    else:
        pts = [(-half, -half, height), (half, -half, height), (half, half, height), (-half, half, height)]
    text = ", ".join(f"({x}, {y}, {z})" for x, y, z in pts)
    return f"""
def Mesh "{name}" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [{text}]
    {extra}
    rel material:binding = <{material_path}>
}}
"""


def probe(name: str, translate=(0.0, 0.0, 0.0), type_name: str = "BakeryIrradianceProbe", body: str = "") -> str:
    x, y, z = translate
    return f"""
def {type_name} "{name}"
{{
    double3 xformOp:translate = ({x}, {y}, {z})
    uniform token[] xformOpOrder = ["xformOp:translate"]
    {body}
}}
"""
