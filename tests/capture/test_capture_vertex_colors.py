"""Colours read per vertex: ``displayColor`` of Hydra's fallback surface when it varies over a mesh, and colour
inputs fed by a ``UsdPrimvarReader_float3``, interpolated with the hit's barycentrics as Hydra does. Closed forms on
emissive surfaces seen by a probe (no lights, black diffuse, no specular: the probe sees the emission exactly):
per-face colours are piecewise constant; vertex colours at a triangle's centroid are the corners' mean."""

from __future__ import annotations

import numpy as np
import pytest
from usd_scenes import (
    glowing_material,
    glowing_mtlx_document,
    glowing_mtlx_material,
    header,
    probe,
    write,
)

from bakery.capture import capture_probes
from bakery.capture.snapshot import read_capture_scene, write_capture_scene
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16


def _glowing(primvar: str = "Cd", fallback=(0.3, 0.3, 0.3)) -> str:
    """A black, specular-free surface whose emission reads the colour primvar ``primvar``."""
    return glowing_material("Glow", "</Glow/Reader.outputs:result>", f"""
    def Shader "Reader"
    {{
        uniform token info:id = "UsdPrimvarReader_float3"
        string inputs:varname = "{primvar}"
        float3 inputs:fallback = {fallback}
        float3 outputs:result
    }}""")


def _floor(colours: str, interpolation: str, material: str = "/Glow", primvar: str = "Cd") -> str:
    """Two triangles covering [-10, 10]² at y = 0 (x < 0: the first, x > 0: the second, split along x = 0 by a
    shared edge), wound upwards, with a colour primvar."""
    return f"""
def Mesh "Floor" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4, 4]
    int[] faceVertexIndices = [0, 1, 4, 3,  1, 2, 5, 4]
    point3f[] points = [(-10, 0, 10), (0, 0, 10), (10, 0, 10), (-10, 0, -10), (0, 0, -10), (10, 0, -10)]
    color3f[] primvars:{primvar} = [{colours}] (
        interpolation = "{interpolation}"
    )
    rel material:binding = <{material}>
}}
"""


def _capture(tmp_path, text: str) -> tuple[np.ndarray, object]:
    reading = read_scene(write(tmp_path / "scene.usda", text))
    assert not reading.errors, reading.errors
    cubes, _ = capture_probes(reading.scene, N, samples=4, bounces=0)
    return cubes[0].astype(np.float64), reading


def test_per_face_colours_are_seen_face_by_face(tmp_path):
    left, right = (0.9, 0.2, 0.1), (0.1, 0.3, 0.8)
    cube, _ = _capture(tmp_path, header() + _glowing() + _floor(f"{left}, {right}", "uniform")
                       + probe("P", (0.0, 1.0, 0.0)))
    d = cube_texel_directions(N)
    down = d[..., 1] < -0.5
    x_at_floor = d[..., 0] / np.maximum(-d[..., 1], 1e-9)  # where the texel centre's ray meets the floor
    margin = 0.15  # texels whose footprint straddles x = 0 are left out
    np.testing.assert_allclose(cube[down & (x_at_floor < -margin)], np.broadcast_to(left, ((down & (
        x_at_floor < -margin)).sum(), 3)), rtol=1e-6)
    np.testing.assert_allclose(cube[down & (x_at_floor > margin)], np.broadcast_to(right, ((down & (
        x_at_floor > margin)).sum(), 3)), rtol=1e-6)


def test_vertex_colours_interpolate_barycentrically(tmp_path):
    """One triangle, corners red, green, blue: straight below the probe, at the centroid, their mean."""
    text = header() + _glowing() + """
def Mesh "Tri" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(-3, 0, 3), (6, 0, 0), (-3, 0, -3)]
    color3f[] primvars:Cd = [(1, 0, 0), (0, 1, 0), (0, 0, 1)] (
        interpolation = "vertex"
    )
    rel material:binding = </Glow>
}
""" + probe("P", (0.0, 0.05, 0.0))  # above the centroid (0, 0, 0)
    cube, reading = _capture(tmp_path, text)
    (mesh,) = reading.scene.meshes
    assert mesh.colors is not None and mesh.colors.shape == (1, 3, 3)
    d = cube_texel_directions(N)
    centre = np.unravel_index(np.argmin(d[..., 1]), d.shape[:3])  # the texel looking straight down
    np.testing.assert_allclose(cube[centre], [1 / 3, 1 / 3, 1 / 3], atol=0.01)


def test_a_varying_display_color_is_the_fallback_surface_per_vertex(tmp_path):
    """No material: Hydra's fallback surface reads displayColor; per face it is kept per hit (the material's base
    colour is the mean), per mesh constant as before."""
    text = header() + _floor("(0.9, 0.2, 0.1), (0.1, 0.3, 0.8)", "uniform", material="/None",
                             primvar="displayColor") + probe("P", (0.0, 1.0, 0.0))
    reading = read_scene(write(tmp_path / "display.usda", text))
    (mesh,) = reading.scene.meshes
    assert [e["primvar"] for e in mesh.material.maps] == ["displayColor"]
    np.testing.assert_allclose(mesh.material.diffuse, (0.5, 0.25, 0.45), rtol=1e-6)
    # fan triangulation: 2 triangles per quad, each with its face's colour at all corners
    np.testing.assert_allclose(mesh.colors[:2], np.broadcast_to((0.9, 0.2, 0.1), (2, 3, 3)), rtol=1e-6)
    np.testing.assert_allclose(mesh.colors[2:], np.broadcast_to((0.1, 0.3, 0.8), (2, 3, 3)), rtol=1e-6)
    constant = header() + _floor("(0.9, 0.2, 0.1)", "constant", material="/None", primvar="displayColor")
    (plain,) = read_scene(write(tmp_path / "constant.usda", constant)).scene.meshes
    assert plain.colors is None and plain.material.maps == () and plain.material.diffuse == pytest.approx(
        (0.9, 0.2, 0.1))


def test_a_missing_primvar_uses_the_readers_fallback(tmp_path):
    text = header() + _glowing(primvar="Missing", fallback=(0.3, 0.6, 0.9)) + _floor(
        "(0.9, 0.2, 0.1), (0.1, 0.3, 0.8)", "uniform") + probe("P", (0.0, 1.0, 0.0))
    cube, reading = _capture(tmp_path, text)
    assert [i for i in reading.issues if "'Missing'" in i.message]
    assert reading.scene.meshes[0].colors is None
    down = cube_texel_directions(N)[..., 1] < -0.5
    np.testing.assert_allclose(cube[down], np.broadcast_to((0.3, 0.6, 0.9), (down.sum(), 3)), rtol=1e-6)


def test_colours_survive_the_worker_snapshot(tmp_path):
    _cube, reading = _capture(tmp_path, header() + _glowing() + _floor("(0.9, 0.2, 0.1), (0.1, 0.3, 0.8)",
                                                                      "uniform") + probe("P", (0.0, 1.0, 0.0)))
    write_capture_scene(reading.scene, tmp_path / "snapshot")
    (mesh,) = read_capture_scene(tmp_path / "snapshot").meshes
    np.testing.assert_array_equal(mesh.colors, reading.scene.meshes[0].colors)
    assert mesh.material == reading.scene.meshes[0].material


GEOMPROP_MTLX = glowing_mtlx_document(
    '<geompropvalue name="cd" type="color3"><input name="geomprop" type="string" value="Cd" /></geompropvalue>', "cd")


@pytest.mark.parametrize("authored", ["usd", "document"])
def test_materialx_geompropvalue_reads_the_primvar_per_hit(tmp_path, authored):
    """MaterialX's geompropvalue (color3) of a primvar: the same per-face colours as UsdPrimvarReader_float3, for
    a standard_surface authored in USD and one in a .mtlx document."""
    left, right = (0.9, 0.2, 0.1), (0.1, 0.3, 0.8)
    if authored == "usd":
        material = glowing_mtlx_material("Glow", "</Glow/Cd.outputs:out>", """
    def Shader "Cd"
    {
        uniform token info:id = "ND_geompropvalue_color3"
        string inputs:geomprop = "Cd"
        color3f outputs:out
    }""")
        binding = "/Glow"
    else:
        (tmp_path / "glow.mtlx").write_text(GEOMPROP_MTLX)
        material = 'def Scope "Looks" (\n    references = @./glow.mtlx@</MaterialX>\n)\n{\n}\n'
        binding = "/Looks/Materials/Glow"
    text = header() + material + _floor(f"{left}, {right}", "uniform", material=binding) + probe("P", (0.0, 1.0, 0.0))
    cube, reading = _capture(tmp_path, text)
    assert [e.get("primvar") for e in reading.scene.meshes[0].material.maps] == ["Cd"]
    assert not [i for i in reading.issues if "'st'" in i.message], reading.issues
    d = cube_texel_directions(N)
    x_at_floor = d[..., 0] / np.maximum(-d[..., 1], 1e-9)
    down = d[..., 1] < -0.5
    for side, colour in ((x_at_floor < -0.15, left), (x_at_floor > 0.15, right)):
        np.testing.assert_allclose(cube[down & side], np.broadcast_to(colour, ((down & side).sum(), 3)), rtol=1e-5)
