"""Light shapes that look small from a probe are splatted (bakery.capture.render, "Small lights"): their flux is
sampled from the probe and splatted into the cube, not found by the probe's camera rays. Against closed forms."""

from __future__ import annotations

import math

import numpy as np
from usd_scenes import header, probe, write

from bakery.capture import capture_probes
from bakery.capture.render import SPLAT_LIGHT_TEXELS
from bakery.sphere.cubemap import cube_mean_texel_solid_angle, cube_texel_directions, cube_texel_solid_angles
from bakery.usd.scene import read_scene


def _sphere(name: str, position, radius: float, radiance: float) -> str:
    x, y, z = position
    return f"""
def SphereLight "{name}"
{{
    float inputs:radius = {radius}
    float inputs:intensity = {radiance}
    double3 xformOp:translate = ({x}, {y}, {z})
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""


def _flux(cube: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Σ L·Ω over the cube (3,) and its flux-weighted mean direction (3,)."""
    n = cube.shape[1]
    omega = cube_texel_solid_angles(n).reshape(-1, 1)
    flux = cube.reshape(-1, 3).astype(np.float64) * omega
    d = cube_texel_directions(n).reshape(-1, 3)
    centroid = (flux[:, 0:1] * d).sum(axis=0)
    return flux.sum(axis=0), centroid / np.linalg.norm(centroid)


def test_a_small_sphere_light_is_its_exact_flux_in_its_direction_without_noise(tmp_path):
    """A sphere of radiance L and radius r at distance D, sub-texel from the probe, nothing else in the scene: the
    cube holds L·2π(1 − cos θmax) (uniform cone samples each carry L·Ω exactly), centred on the light's direction
    within a texel, and no camera ray adds to it (SH noise 0, the total not doubled)."""
    n, radius, radiance = 16, 0.05, 40.0
    position = np.array([3.0, 2.0, -4.0])
    distance = float(np.linalg.norm(position))
    assert math.asin(radius / distance) < SPLAT_LIGHT_TEXELS * 0.5 * math.sqrt(cube_mean_texel_solid_angle(n))
    reading = read_scene(write(tmp_path / "bulb.usda", header() + _sphere("Bulb", position, radius, radiance)
                               + probe("P")))
    cubes, report = capture_probes(reading.scene, n, samples=2)
    total, centroid = _flux(cubes[0])
    expected = radiance * 2 * math.pi * (1 - math.sqrt(1 - (radius / distance) ** 2))
    np.testing.assert_allclose(total, expected, rtol=1e-4)
    assert np.degrees(np.arccos(np.clip(centroid @ (position / distance), -1, 1))) < 360 / (4 * n)
    assert report.sh_noise == (0.0,)


def test_a_half_hidden_small_light_delivers_half_its_flux(tmp_path):
    """An opaque sheet whose edge runs through the bulb's centre, as seen from the probe: the splat's stratified
    samples see half the light, not all or none of it — to one of the 8 strata in azimuth at the splat limit
    (8 × 8 samples), to one in 4 for a bulb ten times smaller (4 × 4)."""
    n, radiance = 16, 40.0
    position = (0.0, 0.0, -6.0)
    limit = SPLAT_LIGHT_TEXELS * 0.5 * math.sqrt(cube_mean_texel_solid_angle(n))
    sheet = """
def Mesh "Sheet"
{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-3, -3, -3), (0, -3, -3), (0, 3, -3), (-3, 3, -3)]
    uniform bool doubleSided = 1
}
"""
    def flux(radius: float, with_sheet: bool) -> np.ndarray:
        text = header() + _sphere("Bulb", position, radius, radiance) + (sheet if with_sheet else "") + probe("P")
        reading = read_scene(write(tmp_path / f"half{int(with_sheet)}.usda", text))
        cubes, _ = capture_probes(reading.scene, n, samples=2, bounces=0)
        return _flux(cubes[0])[0]
    # the sheet x ≤ 0 at z = −3 halves the bulb at x = 0 (the probe at the origin)
    for radius, strata in ((6.0 * math.sin(0.95 * limit), 8), (0.6 * math.sin(0.95 * limit), 4)):
        np.testing.assert_allclose(flux(radius, True) / flux(radius, False), 0.5, atol=1 / strata)


def test_a_light_that_looks_large_is_still_seen_by_the_camera_rays(tmp_path):
    """The same bulb near the probe (angular radius above the splat limit): texels inside its disc see exactly its
    radiance, as camera rays do."""
    n, radius, radiance = 16, 0.5, 7.0
    position = np.array([0.0, 2.0, 0.0])
    reading = read_scene(write(tmp_path / "near.usda", header() + _sphere("Bulb", position, radius, radiance)
                               + probe("P")))
    cubes, _ = capture_probes(reading.scene, n, samples=2)
    up = cube_texel_directions(n)[2]
    inside = np.arccos(np.clip(up[..., 1], -1, 1)) < math.asin(radius / 2.0) - math.atan(math.sqrt(2) / n)
    assert inside.any()
    np.testing.assert_allclose(cubes[0][2][inside], radiance, rtol=1e-6)
