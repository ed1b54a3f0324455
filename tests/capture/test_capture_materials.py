"""Materials in the capture, per hit: textured floors against analytic per-texel radiance, a white furnace with
textures, a mirror that reflects the dome exactly (GGX at roughness 0), and opacity cut-outs."""

from __future__ import annotations

import math

import numpy as np
import OpenImageIO as oiio
import pytest
from usd_scenes import header, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 32
QUADRANTS = np.array([[[230, 40, 40], [40, 200, 60]], [[50, 60, 220], [240, 230, 80]]], dtype=np.uint8)


def _srgb(v):
    v = np.asarray(v, dtype=np.float64) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _write_png(path, pixels):
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], oiio.UINT8))
    out.write_image(pixels)
    out.close()


def _textured_material(name, file, primvar="st", wrap="repeat", scale=(1, 1, 1, 1), bias=(0, 0, 0, 0),
                       diffuse_only=True, extra_inputs=""):
    spec = ('int inputs:useSpecularWorkflow = 1\n        color3f inputs:specularColor = (0, 0, 0)'
            if diffuse_only else "")
    return f"""
def Material "{name}"
{{
    token outputs:surface.connect = </{name}/Surface.outputs:surface>
    def Shader "Surface"
    {{
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </{name}/Tex.outputs:rgb>
        {spec}
        {extra_inputs}
        token outputs:surface
    }}
    def Shader "Reader"
    {{
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname = "{primvar}"
        float2 outputs:result
    }}
    def Shader "Tex"
    {{
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @{file}@
        float2 inputs:st.connect = </{name}/Reader.outputs:result>
        token inputs:wrapS = "{wrap}"
        token inputs:wrapT = "{wrap}"
        float4 inputs:scale = ({scale[0]}, {scale[1]}, {scale[2]}, {scale[3]})
        float4 inputs:bias = ({bias[0]}, {bias[1]}, {bias[2]}, {bias[3]})
        float3 outputs:rgb
    }}
}}
"""


def _uv_quad(name, corners, uvs, material_path, primvar="st"):
    points = ", ".join(f"({x}, {y}, {z})" for x, y, z in corners)
    st = ", ".join(f"({u}, {v})" for u, v in uvs)
    return f"""
def Mesh "{name}" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [{points}]
    texCoord2f[] primvars:{primvar} = [{st}] (
        interpolation = "faceVarying"
    )
    uniform token subdivisionScheme = "none"
    rel material:binding = <{material_path}>
}}
"""


def _sun(e=1.0):
    return f"""
def DistantLight "Sun"
{{
    float inputs:intensity = {e}
    bool inputs:normalize = 1
    float inputs:angle = 0.1
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:rotateX"]
}}
"""


@pytest.mark.parametrize("primvar", ["st", "uv0"])
def test_textured_floor_under_a_distant_light_matches_per_texel_radiance(tmp_path, primvar):
    """A 2 m floor whose texture has four colour quadrants (64² texels, sRGB 8 bit) under a zenith sun of E = 1:
    every probe texel well inside a quadrant sees ρ_q·E/π of that quadrant, decoded from sRGB here (the old
    capture replaced the texture by its mean: 5–190 % off per texel)."""
    pixels = np.repeat(np.repeat(QUADRANTS, 32, axis=0), 32, axis=1)
    _write_png(tmp_path / "quad.png", pixels)
    # st: (0,0) at (-1, 0, 1), s along +x, t along −z; texture row 0 is the top (t = 1) → z = −1
    corners = [(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]
    text = header() + _textured_material("Floor", "./quad.png", primvar)
    text += _uv_quad("Ground", corners, [(0, 0), (1, 0), (1, 1), (0, 1)], "/Floor", primvar) + _sun()
    text += probe("P", (0.0, 0.8, 0.0))
    reading = read_scene(write(tmp_path / "floor.usda", text))
    assert not reading.errors and reading.scene.meshes[0].uvs is not None, reading.issues
    cubes, _ = capture_probes(reading.scene, N, samples=4, bounces=0)
    d = cube_texel_directions(N)
    # texels whose footprint (and mip filter: ≤ 2 texels of level ⌈lod⌉ ≈ 6 cm here) stays inside one quadrant
    down = d[..., 1] < -0.6
    t = 0.8 / -d[..., 1]
    x, z = t * d[..., 0], t * d[..., 2]
    inside = down & (np.abs(x) < 0.85) & (np.abs(z) < 0.85) & (np.abs(x) > 0.15) & (np.abs(z) > 0.15)
    row = (z > 0).astype(int)  # z < 0 → t > ½ → texture rows 0..31 (top)
    col = (x > 0).astype(int)
    expected = _srgb(QUADRANTS[row, col]) / math.pi
    assert inside.sum() > 100
    np.testing.assert_allclose(cubes[0][inside], expected[inside], rtol=2e-3)


def test_white_furnace_with_textures(tmp_path):
    """A closed box whose albedo comes from a uniform sRGB texture with scale and bias: a = 0.9·dec(188) + 0.05,
    so paths of 2 continuations see Le·(1 + a + a² + a³) (the last vertex lit directly by the emissive walls;
    texture lookups, sRGB decoding, scale/bias): the cube's mean to 0.5 % at 32 rays per texel."""
    _write_png(tmp_path / "grey.png", np.full((8, 8, 3), 188, dtype=np.uint8))
    a = 0.9 * float(_srgb(188)) + 0.05
    le = (1.0, 0.5, 0.25)
    mat = _textured_material("M", "./grey.png", scale=(0.9, 0.9, 0.9, 1), bias=(0.05, 0.05, 0.05, 0),
                             extra_inputs=f"color3f inputs:emissiveColor = ({le[0]}, {le[1]}, {le[2]})")
    quads = []
    s = 2.0
    faces = {
        "XN": [(-s, -s, -s), (-s, -s, s), (-s, s, s), (-s, s, -s)], "XP": [(s, -s, -s), (s, s, -s), (s, s, s), (s, -s, s)],
        "YN": [(-s, -s, -s), (s, -s, -s), (s, -s, s), (-s, -s, s)], "YP": [(-s, s, -s), (-s, s, s), (s, s, s), (s, s, -s)],
        "ZN": [(-s, -s, -s), (-s, s, -s), (s, s, -s), (s, -s, -s)], "ZP": [(-s, -s, s), (s, -s, s), (s, s, s), (-s, s, s)],
    }
    for name, corners in faces.items():
        quads.append(_uv_quad(name, corners, [(-1.5, 0), (2.5, 0), (2.5, 3), (-1.5, 3)], "/M"))  # repeat wrap
    text = header() + mat + "".join(quads) + probe("P", (0.3, -0.2, 0.5))
    reading = read_scene(write(tmp_path / "furnace.usda", text))
    cubes, _ = capture_probes(reading.scene, 8, samples=32, bounces=2)
    expected = np.asarray(le) * (1 + a + a * a + a**3)
    np.testing.assert_allclose(cubes[0].reshape(-1, 3).mean(axis=0), expected, rtol=5e-3)


def _gradient_dome(path):
    """A latlong that is smooth in direction (linear in x, y, z), so texel means and point samples agree."""
    from bakery.environment.layouts import equirect_directions

    h, w = 256, 512  # 4× finer than the probe: the reflection's nearest-texel lookups step by < 0.5 %
    rows, cols = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    x, y, z = np.moveaxis(equirect_directions(rows, cols, h, w), -1, 0)
    pixels = np.stack([0.6 + 0.3 * x, 0.5 + 0.3 * y, 0.6 + 0.3 * z], axis=-1).astype(np.float32)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(w, h, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()


def test_mirror_floor_reflects_the_dome_as_a_mirror(tmp_path):
    """A metallic floor (metallic 1, roughness 0, diffuseColor 1 → F0 = 1) under a smooth dome: a reflection probe
    sees the dome mirrored, texel for texel (median 0.5 %, 95th percentile 2 % at 16 rays) (before: metals were diffuse). The primary view
    is the dome filtered over each texel; the reflection point-samples it through the GGX lobe (α = 10⁻³)."""
    _gradient_dome(tmp_path / "sky.exr")
    mirror = """
def Material "Chrome"
{
    token outputs:surface.connect = </Chrome/Surface.outputs:surface>
    def Shader "Surface"
    {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor = (1, 1, 1)
        float inputs:metallic = 1
        float inputs:roughness = 0
        token outputs:surface
    }
}
"""
    text = header() + mirror + _uv_quad("Ground", [(-1e3, 0, 1e3), (1e3, 0, 1e3), (1e3, 0, -1e3), (-1e3, 0, -1e3)],
                                        [(0, 0), (1, 0), (1, 1), (0, 1)], "/Chrome")
    text += 'def DomeLight "Sky"\n{\n    asset inputs:texture:file = @./sky.exr@\n}\n'
    text += probe("P", (0.0, 1.0, 0.0), type_name="BakeryReflectionProbe")
    reading = read_scene(write(tmp_path / "mirror.usda", text))
    cubes, _ = capture_probes(reading.scene, N, samples=16)
    cube = cubes[0].astype(np.float64)
    d = cube_texel_directions(N)
    below = d[..., 1] < -0.2
    # texel (face, row, col) looking down at direction (x, −y, z) sees what the texel looking at (x, y, z) sees
    from bakery.sphere.cubemap import direction_to_cube_texel

    mirrored = d * np.array([1.0, -1.0, 1.0])
    f, r, c = direction_to_cube_texel(mirrored[below], N)
    relative = np.abs(cube[below] / cube[f, r, c] - 1.0)
    # GGX's long tail meets the dome's next-event samples under MIS: rare single-ray outliers, unbiased on average
    assert np.median(relative) < 0.005 and np.percentile(relative, 95) < 0.02 and relative.max() < 0.1
    assert abs(cube[below].mean() / cube[f, r, c].mean() - 1.0) < 3e-3


def test_opacity_cutout_is_transparent(tmp_path):
    """opacity 0 with opacityThreshold 0.5: a black plane between the probe and the sky is cut out entirely."""
    text = header() + """
def Material "Glass"
{
    token outputs:surface.connect = </Glass/Surface.outputs:surface>
    def Shader "Surface"
    {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor = (0, 0, 0)
        float inputs:opacity = 0
        float inputs:opacityThreshold = 0.5
        token outputs:surface
    }
}
""" + _uv_quad("Sheet", [(-5, 2, 5), (5, 2, 5), (5, 2, -5), (-5, 2, -5)], [(0, 0), (1, 0), (1, 1), (0, 1)],
               "/Glass")
    text += 'def DomeLight "Sky"\n{\n    float inputs:intensity = 2\n}\n' + probe("P", (0.0, 1.0, 0.0))
    reading = read_scene(write(tmp_path / "cutout.usda", text))
    cubes, _ = capture_probes(reading.scene, 8, samples=2)
    np.testing.assert_allclose(cubes[0], 2.0, rtol=1e-6)


def test_mip_mapping_filters_a_fine_checker_instead_of_aliasing_it(tmp_path):
    """A 512² one-texel checker (linear values 0.1 / 0.9 as 8-bit sRGB) on a floor: probe texels cover many checker
    texels, and the mip-mapped lookups give each texel the checker's mean (≈ 0.5·E/π) instead of a 4-ray lottery
    between 0.1 and 0.9."""
    dark, light = 89, 243  # sRGB codes of linear ≈ 0.1 and ≈ 0.9
    checker = np.where((np.add.outer(np.arange(512), np.arange(512)) % 2) == 0, dark, light).astype(np.uint8)
    _write_png(tmp_path / "checker.png", np.repeat(checker[..., None], 3, axis=2))
    corners = [(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]
    text = header() + _textured_material("Floor", "./checker.png")
    text += _uv_quad("Ground", corners, [(0, 0), (1, 0), (1, 1), (0, 1)], "/Floor") + _sun() + probe("P", (0, 0.8, 0))
    reading = read_scene(write(tmp_path / "checker.usda", text))
    cubes, _ = capture_probes(reading.scene, 16, samples=4, bounces=0)
    d = cube_texel_directions(16)
    t = 0.8 / -np.minimum(d[..., 1], -1e-9)
    floor = (d[..., 1] < -0.5) & (np.abs(t * d[..., 0]) < 0.9) & (np.abs(t * d[..., 2]) < 0.9)
    expected = 0.5 * float(_srgb(dark) + _srgb(light)) / math.pi
    values = cubes[0][floor][:, 0]
    np.testing.assert_allclose(values, expected, rtol=0.02)
