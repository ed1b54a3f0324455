"""UDIM textures (``<UDIM>`` in a UsdUVTexture file): a floor whose texture coordinates run over s ∈ [0, 3) reads
tile 1001, 1002 and — missing — 1003 (black, as Hydra), under a zenith sun: ρ_tile·E/π per third."""

from __future__ import annotations

import math

import numpy as np
import OpenImageIO as oiio
from harness import single_scattering
from usd_scenes import header, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16
TILES = {1001: (0.8, 0.2, 0.1), 1002: (0.1, 0.7, 0.3)}


def _write_exr(path, rgb):
    pixels = np.broadcast_to(np.asarray(rgb, dtype=np.float32), (8, 8, 3)).copy()
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(8, 8, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()


SCENE = """
def Material "Floor"
{
    token outputs:surface.connect = </Floor/Surface.outputs:surface>
    def Shader "Surface"
    {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </Floor/Tex.outputs:rgb>
        int inputs:useSpecularWorkflow = 1
        color3f inputs:specularColor = (0, 0, 0)
        token outputs:surface
    }
    def Shader "Reader"
    {
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname = "st"
        float2 outputs:result
    }
    def Shader "Tex"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @./tiles/albedo.<UDIM>.exr@
        token inputs:sourceColorSpace = "raw"
        float2 inputs:st.connect = </Floor/Reader.outputs:result>
        float3 outputs:rgb
    }
}
def Mesh "Ground" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-3, 0, 1), (3, 0, 1), (3, 0, -1), (-3, 0, -1)]
    texCoord2f[] primvars:st = [(0, 0), (3, 0), (3, 1), (0, 1)] (
        interpolation = "faceVarying"
    )
    rel material:binding = </Floor>
}
def DistantLight "Sun"
{
    float inputs:intensity = 2
    bool inputs:normalize = 1
    float inputs:angle = 0.1
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:rotateX"]
}
"""


def test_udim_tiles_are_read_per_hit(tmp_path):
    (tmp_path / "tiles").mkdir()
    for tile, colour in TILES.items():
        _write_exr(tmp_path / "tiles" / f"albedo.{tile}.exr", colour)
    reading = read_scene(write(tmp_path / "udim.usda", header() + SCENE + probe("P", (0.0, 1.5, 0.0))))
    assert not [i for i in reading.issues if "not found" in i.message], reading.issues
    entry = reading.scene.meshes[0].material.maps[0]
    assert [tile for tile, _ in entry["udim"]] == [1001, 1002]
    cubes, _ = capture_probes(reading.scene, N, samples=4, bounces=0)
    d = cube_texel_directions(N)
    down = d[..., 1] < -0.3
    x = 1.5 * d[..., 0] / np.maximum(-d[..., 1], 1e-9)
    z = 1.5 * d[..., 2] / np.maximum(-d[..., 1], 1e-9)
    inside = down & (np.abs(z) < 0.9)
    for lo, hi, colour in ((-3, -1, TILES[1001]), (-1, 1, TILES[1002]), (1, 3, (0.0, 0.0, 0.0))):
        sel = inside & (x > lo + 0.15) & (x < hi - 0.15)
        assert sel.sum() > 10, (lo, hi)
        np.testing.assert_allclose(cubes[0][sel], np.broadcast_to(np.array(colour) * 2.0 / math.pi,
                                                                  cubes[0][sel].shape), rtol=1e-3, atol=1e-7)


MTLX = """<?xml version="1.0"?>
<materialx version="1.39">
  <image name="albedo" type="color3">
    <input name="file" type="filename" value="tiles/albedo.<UDIM>.exr" colorspace="lin_rec709" />
  </image>
  <standard_surface name="SR_floor" type="surfaceshader">
    <input name="base" type="float" value="0.8" />
    <input name="base_color" type="color3" nodename="albedo" />
    <input name="specular_roughness" type="float" value="0.3" />
  </standard_surface>
  <surfacematerial name="Floor" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR_floor" />
  </surfacematerial>
</materialx>
"""


def test_materialx_udim_image_matches_its_preview_surface_twin(tmp_path):
    """A standard_surface whose base_color image has <UDIM> tiles captures as the UsdPreviewSurface twin (base ×
    base_color as the texture's scale, the same roughness and IOR)."""
    (tmp_path / "tiles").mkdir()
    for tile, colour in TILES.items():
        _write_exr(tmp_path / "tiles" / f"albedo.{tile}.exr", colour)
    (tmp_path / "floor.mtlx").write_text(MTLX)
    twin = SCENE.replace('''        int inputs:useSpecularWorkflow = 1
        color3f inputs:specularColor = (0, 0, 0)''', '''        float inputs:roughness = 0.3''').replace(
        '''        float3 outputs:rgb''', '''        float4 inputs:scale = (0.8, 0.8, 0.8, 1)
        float3 outputs:rgb''')
    document = SCENE[SCENE.index('def Mesh "Ground"'):].replace("</Floor>", "</Looks/Materials/Floor>")
    document = 'def Scope "Looks" (\n    references = @./floor.mtlx@</MaterialX>\n)\n{\n}\n' + document
    cubes = []
    for name, text in (("twin", twin), ("document", document)):
        reading = read_scene(write(tmp_path / f"{name}.usda", header() + text + probe("P", (0.0, 1.5, 0.0))))
        assert not [i for i in reading.issues if "not found" in i.message], reading.issues
        assert [tile for tile, _ in reading.scene.meshes[0].material.maps[0]["udim"]] == [1001, 1002]
        cubes.append(capture_probes(single_scattering(reading.scene), N, samples=4, bounces=0)[0][0])
    np.testing.assert_allclose(cubes[1], cubes[0], rtol=1e-5, atol=1e-8)


def test_udim_sets_keep_one_texture_budget(tmp_path):
    """A set of k tiles is filtered to 2^⌊log2(1024/√k)⌋ texels a side (≥ 64): about one 1024² texture in all."""
    from bakery.usd.materials import udim_tile_size

    assert [udim_tile_size(k) for k in (1, 4, 5, 16, 100)] == [1024, 512, 256, 256, 64]
    (tmp_path / "tiles").mkdir()
    big = np.full((600, 600, 3), 0.5, dtype=np.float32)
    for tile in (1001, 1002, 1003, 1004, 1011):
        out = oiio.ImageOutput.create(str(tmp_path / "tiles" / f"albedo.{tile}.exr"))
        assert out.open(str(tmp_path / "tiles" / f"albedo.{tile}.exr"), oiio.ImageSpec(600, 600, 3, oiio.FLOAT))
        out.write_image(big)
        out.close()
    reading = read_scene(write(tmp_path / "udim.usda", header() + SCENE + probe("P", (0.0, 1.5, 0.0))))
    tiles = reading.scene.meshes[0].material.maps[0]["udim"]
    assert [t for t, _ in tiles] == [1001, 1002, 1003, 1004, 1011]
    assert all(max(reading.scene.textures[i].pixels.shape[:2]) <= 256 for _, i in tiles)
