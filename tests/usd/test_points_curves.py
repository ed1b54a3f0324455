"""UsdGeomPoints and UsdGeomBasisCurves read as geometry (bakery.usd.gprims). Closed forms: Cauchy's formula (a
convex body's mean projected area is a quarter of its surface) gives the icosahedron of a point the mean shadow of
its sphere and the prism of a curve that of its tube; the cubic bases' defining properties (Bézier endpoints and
midpoint, Catmull-Rom through its interior points, a uniform B-spline of collinear evenly spaced points moving
uniformly, pinned ends reached, periodic curves closed); outward winding; a probe at the centre of a point's sphere
sees only back faces."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from usd_scenes import header, probe, write

from bakery.usd import gprims
from bakery.usd.scene import read_scene


def _area(tris: np.ndarray) -> float:
    return float(0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1).sum())


def _outward(tess: gprims.Tessellation, centre_of) -> bool:  # noqa: ANN001
    tris = tess.triangles
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    faces_out = np.einsum("ij,ij->i", n, tris.mean(axis=1) - centre_of(tris.mean(axis=1))) > 0
    normals_agree = np.einsum("ijk,ik->ij", tess.normals, n) > 0
    return bool(faces_out.all() and normals_agree.all())


@settings(max_examples=25, deadline=None)
@given(st.floats(0.01, 10.0))
def test_a_points_icosahedron_has_its_spheres_mean_shadow(width):
    tess = gprims.point_spheres(np.array([[1.0, -2.0, 3.0]]), np.array([width]))
    assert tess.triangles.shape == (20, 3, 3)
    assert _area(tess.triangles) / 4 == pytest.approx(math.pi * (width / 2) ** 2, rel=1e-12)
    assert _outward(tess, lambda c: np.array([1.0, -2.0, 3.0]))


def test_a_curves_prism_has_its_tubes_mean_shadow_and_faces_out():
    line = np.stack([np.zeros(9), np.zeros(9), np.linspace(0.0, 8.0, 9)], axis=1)
    tess = gprims.curve_tubes([line], [np.full(9, 0.25)])
    assert _area(tess.triangles) == pytest.approx(2 * math.pi * 0.25 * 8.0, rel=1e-12)  # lateral, ends open
    assert _outward(tess, lambda c: c * np.array([0.0, 0.0, 1.0]))


def test_cubic_bases_as_usdgeom_defines_them():
    p = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.0], [3.0, 2.0, 1.0], [4.0, 0.0, 0.0]])
    bezier = gprims.curve_samples(p, "cubic", "bezier", "nonperiodic", samples=2)
    np.testing.assert_allclose(bezier[[0, 1, 2]], [p[0], (p[0] + 3 * p[1] + 3 * p[2] + p[3]) / 8, p[3]], atol=1e-12)
    catmull = gprims.curve_samples(p, "cubic", "catmullRom", "nonperiodic", samples=4)
    np.testing.assert_allclose(catmull[[0, -1]], p[[1, 2]], atol=1e-12)  # through the interior control points
    pinned = gprims.curve_samples(p, "cubic", "catmullRom", "pinned", samples=4)
    np.testing.assert_allclose(pinned[[0, -1]], p[[0, 3]], atol=1e-12)
    evenly = np.stack([np.arange(7.0), np.zeros(7), np.zeros(7)], axis=1)
    spline = gprims.curve_samples(evenly, "cubic", "bspline", "nonperiodic", samples=4)
    np.testing.assert_allclose(np.diff(spline[:, 0]), 0.25, atol=1e-12)  # uniform motion along the line
    np.testing.assert_allclose(gprims.curve_samples(evenly, "cubic", "bspline", "pinned")[[0, -1], 0], [0.0, 6.0])
    ring = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)])
    closed = gprims.curve_samples(ring, "cubic", "bspline", "periodic")
    np.testing.assert_allclose(closed[0], closed[-1], atol=1e-12)
    assert len(gprims.curve_samples(ring, "linear", "bezier", "periodic")) == 7


def _points(extra: str = "", widths: str = "float[] widths = [2, 2]") -> str:
    return header() + f"""
def Points "Dust"
{{
    point3f[] points = [(0, 0, 0), (5, 0, 0)]
    {widths}
    {extra}
}}
def BasisCurves "Wires"
{{
    uniform token type = "cubic"
    uniform token basis = "catmullRom"
    int[] curveVertexCounts = [4, 5]
    point3f[] points = [(0, 3, 0), (1, 3, 0), (2, 3, 0), (3, 3, 0), (0, 4, 0), (1, 4, 1), (2, 4, 0), (3, 4, 1), (4, 4, 0)]
    float[] widths = [0.1, 0.2]
}}
"""


def test_points_and_curves_are_read_and_capture_their_inside(tmp_path):
    from bakery.capture import capture_probes

    reading = read_scene(write(tmp_path / "scene.usda", _points() + probe("P", (0.0, 0.0, 0.0))))
    assert not reading.errors, reading.errors
    meshes = {m.name: m for m in reading.scene.meshes}
    assert np.asarray(meshes["/Dust"].triangles).reshape(-1, 3, 3).shape[0] == 40
    wires = np.asarray(meshes["/Wires"].triangles).reshape(-1, 3, 3)
    spans = (4 - 3) + (5 - 3)  # catmullRom, nonperiodic: n − 3 spans per curve
    assert wires.shape[0] == spans * gprims.CURVE_SPAN_SAMPLES * gprims.CURVE_SIDES * 2
    _cubes, report = capture_probes(reading.scene, 8, samples=1, bounces=0)
    assert report.backface_fraction[0] == 1.0  # the probe at the centre of the first point's sphere


def test_bad_points_and_curves_are_errors_or_warnings_naming_the_prim(tmp_path):
    unset = read_scene(write(tmp_path / "unset.usda", _points(widths="")))
    assert any(i.prim == "/Dust" and "widths not authored" in i.message for i in unset.issues)
    wrong = read_scene(write(tmp_path / "wrong.usda", _points(widths="float[] widths = [1, 2, 3]")))
    assert any(i.prim == "/Dust" and i.severity == "error" and "3 widths for 2 points" in i.message
               for i in wrong.issues)
    counts = _points().replace("int[] curveVertexCounts = [4, 5]", "int[] curveVertexCounts = [4, 9]")
    errors = [i for i in read_scene(write(tmp_path / "counts.usda", counts)).issues if i.severity == "error"]
    assert any(i.prim == "/Wires" and "curveVertexCounts sum to 13" in i.message for i in errors)
