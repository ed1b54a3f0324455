"""The UsdGeom implicit surfaces the capture tessellates: extents against USD's own extent computation, enclosed
volumes against the closed forms, watertightness, exact outward normals, and an emissive furnace inside each
closed gprim (the capture sees the emission Le in every direction only if no ray leaks out)."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from pxr import Usd, UsdGeom
from usd_scenes import header, material, probe, write

from bakery.capture import capture_probes
from bakery.usd import gprims
from bakery.usd.scene import read_scene

#: (type, authored attributes (usda lines)) with non-default sizes; the axis is appended per case
GPRIMS = {
    "Cylinder": "double radius = 0.7\n    double height = 1.6",
    "Cylinder_1": "double radiusBottom = 0.8\n    double radiusTop = 0.4\n    double height = 1.5",
    "Cone": "double radius = 0.9\n    double height = 1.4",
    "Capsule": "double radius = 0.5\n    double height = 1.2",
    "Capsule_1": "double radiusBottom = 0.6\n    double radiusTop = 0.6\n    double height = 1.0",
    "Plane": "double width = 1.5\n    double length = 0.8",
    "Sphere": "double radius = 0.9",
    "Cube": "double size = 1.3",
}


def _gprim(type_name: str, axis: str, material_path: str = "", translate=(0.0, 0.0, 0.0)) -> str:
    axis_line = f'\n    uniform token axis = "{axis}"' if type_name not in ("Sphere", "Cube") else ""
    binding = f"\n    rel material:binding = <{material_path}>" if material_path else ""
    x, y, z = translate
    return f"""
def {type_name} "Shape" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    {GPRIMS[type_name]}{axis_line}{binding}
    double3 xformOp:translate = ({x}, {y}, {z})
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""


@pytest.mark.parametrize("axis", ["X", "Y", "Z"])
@pytest.mark.parametrize("type_name", sorted(GPRIMS))
def test_tessellation_spans_the_extent_usd_computes(tmp_path, type_name, axis):
    """The bounding box of the triangles the reader produces is UsdGeom's extent of the prim (Y-up stage in metres:
    the bake frame is the world frame)."""
    path = write(tmp_path / "g.usda", header() + _gprim(type_name, axis, translate=(0.5, -1.0, 2.0)) + probe("P"))
    reading = read_scene(path)
    assert not reading.errors, reading.errors
    (mesh,) = reading.scene.meshes
    points = np.asarray(mesh.triangles, dtype=np.float64).reshape(-1, 3)
    stage = Usd.Stage.Open(str(path))
    box = UsdGeom.BBoxCache(Usd.TimeCode.Default(), ["default"]).ComputeWorldBound(stage.GetPrimAtPath("/Shape"))
    box = box.ComputeAlignedRange()
    np.testing.assert_allclose(points.min(axis=0), np.asarray(box.GetMin()), atol=1e-6)
    np.testing.assert_allclose(points.max(axis=0), np.asarray(box.GetMax()), atol=1e-6)
    assert not [i for i in reading.issues if "not supported" in i.message]


def _volume(tris: np.ndarray) -> float:
    """Signed enclosed volume (divergence theorem): positive for outward (counter-clockwise) winding."""
    return float(np.einsum("ij,ij->i", tris[:, 0], np.cross(tris[:, 1], tris[:, 2])).sum() / 6.0)


CLOSED_FORMS = [
    ("cylinder", lambda: gprims.cylinder(0.7, 0.7, 1.6, "X"), math.pi * 0.7**2 * 1.6),
    ("frustum", lambda: gprims.cylinder(0.8, 0.4, 1.5, "Y"), math.pi * 1.5 * (0.64 + 0.32 + 0.16) / 3),
    ("cone", lambda: gprims.cone(0.9, 1.4, "Z"), math.pi * 0.81 * 1.4 / 3),
    ("capsule", lambda: gprims.capsule(0.5, 0.5, 1.2, "Y"), math.pi * 0.25 * 1.2 + 4 / 3 * math.pi * 0.125),
    ("capsule_unequal", lambda: gprims.capsule(0.6, 0.3, 1.0, "X"),
     math.pi * 1.0 * (0.36 + 0.18 + 0.09) / 3 + 2 / 3 * math.pi * (0.6**3 + 0.3**3)),
]


@pytest.mark.parametrize(("name", "build", "volume"), CLOSED_FORMS, ids=[c[0] for c in CLOSED_FORMS])
def test_surfaces_of_revolution_are_watertight_outward_and_close_to_the_closed_form(name, build, volume):
    tris = build().triangles
    edges = Counter()
    for tri in map(tuple, tris.tolist()):
        for i in range(3):
            edges[tuple(sorted((tuple(tri[i]), tuple(tri[(i + 1) % 3]))))] += 1
    assert set(edges.values()) == {2}  # every edge shared by exactly two triangles: rays cannot leak
    inscribed = gprims.SEGMENTS * math.sin(2 * math.pi / gprims.SEGMENTS) / (2 * math.pi)  # 24-gon / circle area
    assert volume * (inscribed - 0.01) < _volume(tris) <= volume * 1.000001


@pytest.mark.parametrize(("name", "build", "volume"), [
    ("sphere", lambda: gprims.uv_sphere(0.8), 4 / 3 * math.pi * 0.8**3),
    ("cube", lambda: gprims.cube(1.3), 1.3**3),
])
def test_sphere_and_cube_are_wound_outward(name, build, volume):
    """Counter-clockwise seen from outside: the signed volume is positive (a probe inside sees back faces); every
    non-degenerate sphere facet's winding normal points away from the centre."""
    tris = build().triangles
    assert volume * 0.95 < _volume(tris) <= volume * 1.000001
    cross = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    facets = np.linalg.norm(cross, axis=1) > 1e-12
    assert np.all(np.einsum("ij,ij->i", cross, tris.mean(axis=1))[facets] > 0)


def test_plane_axes_follow_usdgeomplane():
    """axis X: width along z, length along y; Y: x, z; Z: x, y (UsdGeomPlane)."""
    for axis, (w_axis, l_axis, n_axis) in {"X": (2, 1, 0), "Y": (0, 2, 1), "Z": (0, 1, 2)}.items():
        points = gprims.plane(2.0, 4.0, axis).triangles.reshape(-1, 3)
        span = points.max(axis=0) - points.min(axis=0)
        assert span[w_axis] == 2.0 and span[l_axis] == 4.0 and span[n_axis] == 0.0
        tris = gprims.plane(2.0, 4.0, axis).triangles
        winding = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        assert np.all(winding[:, n_axis] > 0)  # wound towards +axis
    with pytest.raises(ValueError, match="axis"):
        gprims.plane(1.0, 1.0, "W")


@pytest.mark.parametrize("type_name", ["Cylinder", "Cylinder_1", "Cone", "Capsule", "Capsule_1"])
def test_no_ray_leaks_out_of_a_closed_emissive_gprim(tmp_path, type_name):
    """Inside a closed emissive black gprim every camera ray sees Le: none leaks out between the triangles. (With
    albedo a > 0 the furnace's Le·(1 + a + …) is not a closed form for these gprims: their smooth shading normals
    differ from the facets', and directions below a facet are excluded, as in pbrt — flat meshes keep the exact
    furnace, tests/capture/test_capture_analytic.py.)"""
    le, albedo = (1.0, 2.0, 3.0), 0.0
    text = header() + material("M", diffuse=(albedo,) * 3, emissive=le, diffuse_only=True)
    text += _gprim(type_name, "X", "/M") + probe("P", (0.1, 0.05, -0.05))
    reading = read_scene(write(tmp_path / "furnace.usda", text))
    assert not reading.errors, reading.errors
    cubes, _ = capture_probes(reading.scene, 8, samples=2, bounces=2)
    np.testing.assert_allclose(cubes[0], np.broadcast_to(le, cubes[0].shape), rtol=1e-6)


def test_negative_sizes_are_per_prim_errors(tmp_path):
    text = header() + _gprim("Cylinder", "Y").replace("radius = 0.7", "radius = -0.7") + probe("P")
    reading = read_scene(write(tmp_path / "bad.usda", text))
    assert [i for i in reading.errors if i.prim == "/Shape" and "radius" in i.message]


@pytest.mark.parametrize(("name", "build", "volume"), CLOSED_FORMS, ids=[c[0] for c in CLOSED_FORMS])
def test_normals_are_the_surfaces_exact_outward_normals(name, build, volume):
    """Unit normals within a facet's angle (15° around the spine at 24 segments) of the facet's outward normal;
    on a sphere exactly p/r."""
    surface = build()
    tris, normals = surface.triangles, surface.normals
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-12)
    facet = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    facet /= np.linalg.norm(facet, axis=-1, keepdims=True)
    assert np.einsum("tk,tck->tc", facet, normals).min() > math.cos(math.radians(15.0))
    sphere = gprims.uv_sphere(2.5)
    np.testing.assert_allclose(sphere.normals * 2.5, sphere.triangles, atol=1e-12)
