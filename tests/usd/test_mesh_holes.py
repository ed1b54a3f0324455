"""UsdGeomMesh ``holeIndices``: hole faces are not surfaces (before: every face was baked, so a wall's window
modelled as a hole face was closed). Closed forms: the triangles left, and the irradiance through a square hole in
the lid of a black box under a white sky — L·π·F with F the point-to-parallel-square configuration factor."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, material, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.usd.scene import read_scene


def _grid_wall(holes: str, extra: str = "") -> str:
    """A 3 × 3-face wall in the plane z = 0 (x, y ∈ [0, 3]), faces row by row from y = 0."""
    points = ", ".join(f"({x}, {y}, 0)" for y in range(4) for x in range(4))
    faces = [(4 * r + c, 4 * r + c + 1, 4 * (r + 1) + c + 1, 4 * (r + 1) + c) for r in range(3) for c in range(3)]
    return f"""
def Mesh "Wall"
{{
    int[] faceVertexCounts = [{", ".join("4" for _ in faces)}]
    int[] faceVertexIndices = [{", ".join(str(i) for f in faces for i in f)}]
    point3f[] points = [{points}]
    int[] holeIndices = [{holes}]
    {extra}
}}
"""


def _triangles(reading) -> np.ndarray:  # noqa: ANN001
    (wall,) = [m for m in reading.scene.meshes if m.name == "/Wall"]
    return np.asarray(wall.triangles, dtype=np.float64).reshape(-1, 3, 3)


def test_hole_faces_are_not_baked(tmp_path):
    reading = read_scene(write(tmp_path / "wall.usda", header() + _grid_wall("4, 0") + probe("P", (1.5, 1.5, 1))))
    tris = _triangles(reading)
    centres = tris.mean(axis=1)
    assert tris.shape[0] == 2 * 7  # nine faces, two of them holes
    inside = lambda lo, hi: np.all((centres[:, :2] > lo) & (centres[:, :2] < hi), axis=1)  # noqa: E731
    assert not inside(1, 2).any() and not inside(0, 1).any()  # the centre face and the corner face are gone
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=-1).sum()
    assert area == pytest.approx(7.0)


def test_holes_of_a_refined_mesh_stay_holes(tmp_path):
    """catmullClark refined one level: the four refined faces of the hole face are holes too (OpenSubdiv)."""
    text = header() + _grid_wall("4", 'uniform token subdivisionScheme = "catmullClark"') + probe("P", (1.5, 1.5, 1))
    whole = read_scene(write(tmp_path / "whole.usda", text.replace("int[] holeIndices = [4]", "")), subdivision=1)
    holed = read_scene(write(tmp_path / "holed.usda", text), subdivision=1)
    assert _triangles(holed).shape[0] == _triangles(whole).shape[0] * 8 // 9
    assert not [i for i in holed.issues if "holeIndices" in i.message]


def test_invalid_hole_indices_are_reported(tmp_path):
    reading = read_scene(write(tmp_path / "wall.usda", header() + _grid_wall("4, 12, -1") + probe("P", (1.5, 1.5, 1))))
    assert _triangles(reading).shape[0] == 2 * 8
    assert [i for i in reading.issues if "holeIndices [12, -1] are not faces" in i.message]


def _corner_factor(x: float, y: float) -> float:
    """Configuration factor from a point to a parallel rectangle with a corner straight above it, sides x·h, y·h."""
    return (x / math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x))
            + y / math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y))) / (2 * math.pi)


def test_the_sky_seen_through_a_hole_in_a_black_box(tmp_path):
    """A black box (2 m, double-sided, diffuse 0) whose lid is a hole face, under a white sky (L = 1): at the box's
    centre E(+Y) = π·L·F, F = 4·F_corner(1, 1) for the 2 m square 1 m above; E(−Y) = 0."""
    points = ", ".join(f"({x}, {y}, {z})" for x in (-1, 1) for y in (-1, 1) for z in (-1, 1))
    #      -x            +x            -y            +y (lid)      -z            +z
    faces = "0, 1, 3, 2,  4, 6, 7, 5,  0, 4, 5, 1,  2, 3, 7, 6,  0, 2, 6, 4,  1, 5, 7, 3"
    box = f"""
def Mesh "Box" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [{faces}]
    point3f[] points = [{points}]
    int[] holeIndices = [3]
    uniform bool doubleSided = 1
    rel material:binding = </Black>
}}
def DomeLight "Sky"
{{
    float inputs:intensity = 1
}}
"""
    reading = read_scene(write(tmp_path / "box.usda", header() + material("Black", diffuse=(0, 0, 0),
                                                                          diffuse_only=True) + box + probe("P")))
    cubes, _ = capture_probes(reading.scene, 32, samples=4, bounces=0)
    directions = cube_texel_directions(32).reshape(-1, 3)
    weights = cube_texel_solid_angles(32).reshape(-1)
    luminance = cubes[0].reshape(-1, 3).astype(np.float64).mean(axis=1)
    up = float(np.sum(luminance * weights * np.maximum(directions[:, 1], 0)))
    down = float(np.sum(luminance * weights * np.maximum(-directions[:, 1], 0)))
    assert up == pytest.approx(math.pi * 4 * _corner_factor(1.0, 1.0), rel=0.01)
    assert down == pytest.approx(0.0, abs=1e-6)
