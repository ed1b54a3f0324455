"""Authored shading normals: read from USD in every interpolation and transformed by the inverse transpose, and
used by the capture's BSDF — a tilted normal on a Lambertian plane under a distant light gives ρ·E·cos(θ − β)/π
(closed form), a normal authored against the winding shades as the geometric one, and nothing passes below the
geometric surface."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene


def _quad(name: str, half: float, material_path: str, normals: str = "", extra: str = "") -> str:
    """A square y = 0 quad with authored ``normals`` and ``extra`` usda lines."""
    return plane_mesh(name, half, material_path, extra=f"{normals}\n    {extra}")


def _sun(zenith_deg: float, intensity: float = 3.0) -> str:
    # rotateX by -(90° - θ) turns the light's +Z (towards the light) to (0, cos θ, sin θ)
    return f"""
def DistantLight "Sun"
{{
    float inputs:intensity = {intensity}
    bool inputs:normalize = 1
    float inputs:angle = 0.53
    float xformOp:rotateX = {-(90.0 - zenith_deg)}
    uniform token[] xformOpOrder = ["xformOp:rotateX"]
}}
"""


def _plane_radiance(tmp_path, normals: str, zenith: float = 30.0) -> np.ndarray:
    """Radiance the probe at (0, 1, 0) sees on the plane (texels looking more than 30° down, so the view is in
    front of every tested shading normal: n_s·wo > 0), (K, 3)."""
    rho = 0.5
    text = header() + material("Ground", diffuse=(rho,) * 3, diffuse_only=True)
    text += _quad("Plane", 1e4, "/Ground", normals) + _sun(zenith) + probe("P", (0.0, 1.0, 0.0))
    reading = read_scene(write(tmp_path / "plane.usda", text))
    assert not reading.errors, reading.errors
    cubes, _ = capture_probes(reading.scene, 16, samples=2, bounces=2)
    below = cube_texel_directions(16)[..., 1] < -0.55
    return cubes[0][below].astype(np.float64)


def _sun_plane_expected(cos_normal_sun: float) -> float:
    alpha = math.radians(0.53 / 2)
    return 0.5 * 3.0 * cos_normal_sun * (1 + math.cos(alpha)) / 2 / math.pi  # ρ·E·⟨n·ω⟩/π over the sun's cone


@pytest.mark.parametrize("interpolation", ["constant", "uniform", "vertex", "faceVarying"])
def test_tilted_shading_normal_gives_the_cosine_to_the_tilted_normal(tmp_path, interpolation):
    """n_s tilted by β = 20° towards a sun at θ = 30°: radiance ρ·E·cos(θ − β)/π instead of ρ·E·cos θ/π."""
    beta = math.radians(20.0)
    n = f"(0, {math.cos(beta)}, {math.sin(beta)})"
    count = {"constant": 1, "uniform": 1, "vertex": 4, "faceVarying": 4}[interpolation]
    normals = (f"normal3f[] primvars:normals = [{', '.join([n] * count)}] (\n        interpolation = "
               f'"{interpolation}"\n    )')
    seen = _plane_radiance(tmp_path, normals)
    np.testing.assert_allclose(seen.mean(axis=0), _sun_plane_expected(math.cos(math.radians(10.0))), rtol=3e-3)


def test_normals_attribute_and_normals_against_the_winding(tmp_path):
    """The ``normals`` attribute is read when there is no primvar; normals are turned to the viewer's side
    (two-sided surfaces), so +y and −y — one of them against the quad's winding — shade alike."""
    up = _plane_radiance(tmp_path, 'normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] (\n'
                                   '        interpolation = "vertex"\n    )')
    down = _plane_radiance(tmp_path, 'normal3f[] normals = [(0, -1, 0), (0, -1, 0), (0, -1, 0), (0, -1, 0)] (\n'
                                     '        interpolation = "vertex"\n    )')
    expected = _sun_plane_expected(math.cos(math.radians(30.0)))
    np.testing.assert_allclose(up.mean(axis=0), expected, rtol=3e-3)
    np.testing.assert_allclose(down, up, rtol=1e-6)


def test_light_below_the_geometric_surface_does_not_pass(tmp_path):
    """A sun 5° below the horizon and normals tilted 60° towards it: the shading hemisphere contains the sun, but
    the plane is lit from below only through itself — it stays black."""
    beta = math.radians(60.0)
    normals = f"normal3f[] primvars:normals = [(0, {math.cos(beta)}, {math.sin(beta)})] (\n        interpolation = " \
              '"constant"\n    )'
    seen = _plane_radiance(tmp_path, normals, zenith=95.0)
    assert np.abs(seen).max() == 0.0


def test_normals_are_read_per_corner_and_transformed_by_the_inverse_transpose(tmp_path):
    """Z-up stage, non-uniform scale: corner normals equal normalise(n·M⁻ᵀ) rotated to the bake frame
    ((x, y, z) ↦ (x, z, −y)); faceVarying values land on their face-vertices."""
    local = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [-0.6, 0.0, 0.8]])
    values = ", ".join(f"({a}, {b}, {c})" for a, b, c in local)
    text = header("Z") + material("M") + f"""
def Mesh "Quad" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    normal3f[] primvars:normals = [{values}] (
        interpolation = "faceVarying"
    )
    float3 xformOp:scale = (2, 1, 0.5)
    uniform token[] xformOpOrder = ["xformOp:scale"]
    rel material:binding = </M>
}}
""" + 'def DomeLight "Sky"\n{\n}\n' + probe("P", (0, 0, 2))
    reading = read_scene(write(tmp_path / "quad.usda", text))
    assert not reading.issues, reading.issues
    (mesh,) = reading.scene.meshes
    world = local / np.array([2.0, 1.0, 0.5])  # n · M⁻ᵀ for M = diag(2, 1, 0.5)
    bake = np.stack([world[:, 0], world[:, 2], -world[:, 1]], axis=-1)
    bake /= np.linalg.norm(bake, axis=-1, keepdims=True)
    fan = np.array([[0, 1, 2], [0, 2, 3]])  # the fan triangulation's face-vertices
    np.testing.assert_allclose(mesh.normals, bake[fan], atol=1e-6)


def test_subdivided_meshes_ignore_authored_normals(tmp_path):
    """USD: subdivision surfaces define their own normals; authored ones are not used."""
    text = header() + material("M") + _quad("Plane", 1.0, "/M", 'normal3f[] normals = [(0, 1, 0)] (\n'
                                             '        interpolation = "constant"\n    )',
                                             extra='uniform token subdivisionScheme = "catmullClark"')
    reading = read_scene(write(tmp_path / "subdiv.usda", text + probe("P", (0, 2, 0))))
    assert reading.scene.meshes[0].normals is None


def test_mismatched_normals_are_reported_and_ignored(tmp_path):
    text = header() + material("M") + _quad("Plane", 1.0, "/M", 'normal3f[] normals = [(0, 1, 0)] (\n'
                                             '        interpolation = "vertex"\n    )')
    reading = read_scene(write(tmp_path / "bad.usda", text + probe("P", (0, 2, 0))))
    assert reading.scene.meshes[0].normals is None
    assert [i for i in reading.issues if i.prim == "/Plane" and "normals" in i.message]
