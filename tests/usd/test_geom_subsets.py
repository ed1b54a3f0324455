"""UsdGeomSubset material bindings (family ``materialBind``): each subset's faces take its own material, the rest
the mesh's — before, the whole mesh took the mesh's binding. Checked on a floor of two faces under a zenith sun
(ρ_face·E/π per half), also through catmull-clark refinement."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, material, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16
GREEN, RED = (0.1, 0.6, 0.1), (0.7, 0.1, 0.1)


def _floor(subdivision: str = "none") -> str:
    return f"""
def Mesh "Floor" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4, 4]
    int[] faceVertexIndices = [0, 1, 2, 3, 1, 4, 5, 2]
    point3f[] points = [(-20, 0, 20), (0, 0, 20), (0, 0, -20), (-20, 0, -20), (20, 0, 20), (20, 0, -20)]
    uniform token subdivisionScheme = "{subdivision}"
    rel material:binding = </Green>
    uniform token subsetFamily:materialBind:familyType = "partition"

    def GeomSubset "Right" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {{
        uniform token elementType = "face"
        uniform token familyName = "materialBind"
        int[] indices = [1]
        rel material:binding = </Red>
    }}
}}
"""


SUN = """
def DistantLight "Sun"
{
    float inputs:intensity = 2
    bool inputs:normalize = 1
    float inputs:angle = 0.1
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:rotateX"]
}
"""


def _scene(subdivision: str = "none") -> str:
    return (header() + material("Green", diffuse=GREEN, diffuse_only=True)
            + material("Red", diffuse=RED, diffuse_only=True) + _floor(subdivision) + SUN
            + probe("P", (0.0, 0.5, 0.0)))


@pytest.mark.parametrize("subdivision", ["none", "catmullClark"])
def test_subset_faces_take_their_own_material(tmp_path, subdivision):
    """Face 0 (x < 0) has the mesh's green, face 1 (x > 0) the subset's red: ρE/π per half; the refined mesh
    (one catmull-clark level) maps its quads to the cage faces."""
    reading = read_scene(write(tmp_path / "floor.usda", _scene(subdivision)), subdivision=1)
    names = sorted(m.name for m in reading.scene.meshes)
    assert names == ["/Floor", "/Floor#Right"], names
    cubes, _ = capture_probes(reading.scene, N, samples=4, bounces=0)
    d = cube_texel_directions(N)
    x = 0.5 * d[..., 0] / np.maximum(-d[..., 1], 1e-9)
    down = d[..., 1] < -0.3
    for side, colour in ((x < -0.5, GREEN), (x > 0.5, RED)):
        sel = down & side
        assert sel.sum() > 50
        np.testing.assert_allclose(cubes[0][sel], np.broadcast_to(np.array(colour) * 2.0 / math.pi,
                                                                  cubes[0][sel].shape), rtol=1e-3)
