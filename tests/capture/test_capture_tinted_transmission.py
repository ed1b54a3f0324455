"""Tinted transmission: MaterialX surfaces' thin, straight transmission multiplies the light that passes by the
transmission colour C (``standard_surface``/``open_pbr_surface`` ``transmission_color``, ``gltf_pbr``
``base_color``). Closed forms, on a pane that every ray passes (transmission 1, metalness 0: presence 0, so no
randomness): under a uniform dome the probe sees C·L through it; a delta sun splats C·E; a Lambertian ground
under the pane reflects C·ρ·E·cos θ/π of a sun (shadow rays) and C·ρ·L of the dome (shadow and bounce rays, MIS);
a light shape in front of the pane is not tinted; a geometry opacity o mixes the absent part (untinted) with the
transmitted one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, material, mtlx_material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.capture.scene import Material
from bakery.pipeline.dependencies import _material_fields
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.usd.scene import read_scene

N = 16
TINT = (0.9, 0.5, 0.2)
DOME = 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'


def _pane(category_id: str = "ND_standard_surface_surfaceshader", inputs: str = "", height: float = 2.0) -> str:
    """A MaterialX surface authored in USD on an infinite horizontal pane at ``height``; by default a standard
    surface of transmission 1 tinted by :data:`TINT`."""
    inputs = inputs or (f"float inputs:transmission = 1\n        float inputs:base = 0\n        "
                        f"color3f inputs:transmission_color = {TINT}")
    return mtlx_material("Glass", category_id, inputs) + plane_mesh("Pane", 1e4, "/Glass", height=height)


SUN = """
def DistantLight "Sun"
{
    float inputs:intensity = 3
    bool inputs:normalize = 1
    float inputs:angle = %s
    float xformOp:rotateX = -60
    uniform token[] xformOpOrder = ["xformOp:rotateX"]
}
"""


def _read(tmp_path, text: str):
    reading = read_scene(write(tmp_path / "scene.usda", text))
    assert not reading.errors, reading.errors
    return reading


def _capture(reading, samples: int = 16, bounces: int = 1) -> np.ndarray:
    cubes, _ = capture_probes(reading.scene, N, samples=samples, bounces=bounces)
    return cubes[0].astype(np.float64)


@pytest.mark.parametrize(("category_id", "inputs"), [
    ("ND_standard_surface_surfaceshader", ""),
    ("ND_open_pbr_surface_surfaceshader", f"float inputs:transmission_weight = 1\n        "
                                          f"color3f inputs:transmission_color = {TINT}"),
    ("ND_gltf_pbr_surfaceshader", f"float inputs:transmission = 1\n        float inputs:metallic = 0\n        "
                                  f"color3f inputs:base_color = {TINT}"),  # gltf_pbr's metallic defaults to 1
])
def test_a_tinted_pane_colours_the_sky_it_lets_through(tmp_path, category_id, inputs):
    reading = _read(tmp_path, header() + DOME + _pane(category_id, inputs) + probe("P", (0.0, 1.0, 0.0)))
    (mesh,) = reading.scene.meshes
    assert mesh.material.opacity == pytest.approx(0.0)
    np.testing.assert_allclose(mesh.material.transmission_tint, TINT, rtol=1e-6)
    cube = _capture(reading)
    d = cube_texel_directions(N)
    np.testing.assert_allclose(cube[d[..., 1] > 0.05], np.broadcast_to(TINT, (int((d[..., 1] > 0.05).sum()), 3)),
                               rtol=1e-5)
    np.testing.assert_allclose(cube[d[..., 1] < -0.05], 1.0, rtol=1e-6)  # the open lower hemisphere: untinted


def test_a_sun_splat_through_the_pane_is_tinted(tmp_path):
    """A delta-like sun (0.05°, under a texel) splats its illuminance E flux-exactly: Σ L·Ω = C·E."""
    reading = _read(tmp_path, header() + _pane() + probe("P", (0.0, 1.0, 0.0)) + SUN % 0.05)
    cube = _capture(reading)
    flux = (cube * cube_texel_solid_angles(N)[..., None]).reshape(-1, 3).sum(axis=0)
    np.testing.assert_allclose(flux, 3.0 * np.asarray(TINT), rtol=1e-5)


def test_shadow_rays_through_the_pane_are_tinted(tmp_path):
    """Ground (ρ = 0.5) under the pane, lit by a normalised sun at 30° (E = 3): C·ρ·E·⟨cos⟩/π, exactly."""
    text = header() + _pane() + material("Soil", diffuse=(0.5,) * 3, diffuse_only=True)
    text += plane_mesh("Ground", 1e4, "/Soil", height=0.0) + probe("P", (0.0, 1.0, 0.0)) + SUN % 0.53
    cube = _capture(_read(tmp_path, text))
    below = cube_texel_directions(N)[..., 1] < -0.3
    alpha = math.radians(0.53 / 2)
    expected = 0.5 * 3.0 * math.cos(math.radians(30.0)) * (1 + math.cos(alpha)) / 2 / math.pi
    np.testing.assert_allclose(cube[below].mean(axis=0), expected * np.asarray(TINT), rtol=1e-4)


def test_the_dome_lights_the_ground_through_the_pane_by_both_strategies(tmp_path):
    """Ground (ρ = 0.5) under the pane and a uniform dome L = 1: C·ρ·L (next-event and BSDF rays both pass the
    pane, MIS-weighted); the sky seen upwards is C·L."""
    text = header() + DOME + _pane() + material("Soil", diffuse=(0.5,) * 3, diffuse_only=True)
    text += plane_mesh("Ground", 1e4, "/Soil", height=0.0) + probe("P", (0.0, 1.0, 0.0))
    cube = _capture(_read(tmp_path, text), samples=64)
    below = cube_texel_directions(N)[..., 1] < -0.3
    np.testing.assert_allclose(cube[below].mean(axis=0), 0.5 * np.asarray(TINT), rtol=0.01)


def test_a_light_in_front_of_the_pane_is_not_tinted(tmp_path):
    """A sphere light between the probe and the pane is seen at its own radiance; the sky around it through C."""
    lamp = """
def SphereLight "Lamp"
{
    float inputs:intensity = 7
    float inputs:radius = 0.2
    double3 xformOp:translate = (0, 1.5, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""
    cube = _capture(_read(tmp_path, header() + DOME + _pane() + lamp + probe("P", (0.0, 1.0, 0.0))))
    d = cube_texel_directions(N)
    np.testing.assert_allclose(cube[d[..., 1] > 0.98], 7.0, rtol=1e-5)
    side = (d[..., 1] > 0.2) & (d[..., 1] < 0.7)  # the lamp subtends 23.6° around +Y
    np.testing.assert_allclose(cube[side].mean(axis=0), TINT, rtol=1e-5)


def test_geometry_opacity_mixes_the_absent_and_the_transmitted_light(tmp_path):
    """open_pbr geometry_opacity o = 0.5 and transmission 1: every hit passes (the absent half untinted, the
    present half transmitted through C), so the sky is seen as (1 − o) + o·C."""
    inputs = (f"float inputs:transmission_weight = 1\n        float inputs:geometry_opacity = 0.5\n        "
              f"color3f inputs:transmission_color = {TINT}")
    reading = _read(tmp_path, header() + DOME + _pane("ND_open_pbr_surface_surfaceshader", inputs)
                    + probe("P", (0.0, 1.0, 0.0)))
    expected = 0.5 + 0.5 * np.asarray(TINT)
    np.testing.assert_allclose(reading.scene.meshes[0].material.transmission_tint, expected, rtol=1e-6)
    up = cube_texel_directions(N)[..., 1] > 0.05
    np.testing.assert_allclose(_capture(reading)[up].mean(axis=0), expected, rtol=1e-5)


def test_an_untinted_material_hashes_as_before():
    """The tint enters a material's dependency hash only when it is not white (stores of scenes without tints
    keep their hashes)."""
    assert "transmission_tint" not in _material_fields(Material())
    assert _material_fields(Material(transmission_tint=TINT))["transmission_tint"] == TINT


def test_a_pane_the_sun_is_not_shadow_linked_to_does_not_tint_its_light(tmp_path):
    """The sun's collection:shadowLink holds the ground alone: its shadow rays pass the pane as if absent, untinted
    (ρ·E·⟨cos⟩/π exactly), while the probe still sees the sky through the pane tinted (C·L)."""
    sun = SUN.replace("    float inputs:angle = %s\n", "    float inputs:angle = 0.53\n"
                      "    uniform bool collection:shadowLink:includeRoot = 0\n"
                      "    rel collection:shadowLink:includes = </Ground>\n")
    text = header() + DOME + _pane() + material("Soil", diffuse=(0.5,) * 3, diffuse_only=True)
    text += plane_mesh("Ground", 1e4, "/Soil", height=0.0) + probe("P", (0.0, 1.0, 0.0)) + sun
    reading = _read(tmp_path, text)
    cube = _capture(reading, bounces=0)
    d = cube_texel_directions(N)
    below = d[..., 1] < -0.3
    alpha = math.radians(0.53 / 2)
    sun_light = 0.5 * 3.0 * math.cos(math.radians(30.0)) * (1 + math.cos(alpha)) / 2 / math.pi
    dome_light = 0.5 * np.asarray(TINT)  # the uniform dome reaches the ground through the (shadow-casting) pane
    np.testing.assert_allclose(cube[below].mean(axis=0), sun_light + dome_light, rtol=2e-3)
    sky = np.median(cube[d[..., 1] > 0.05], axis=0)  # through the pane (the sun's own texels aside)
    np.testing.assert_allclose(sky, TINT, rtol=1e-5)
