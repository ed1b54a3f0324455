"""Opacity without an opacityThreshold is presence: a hit passes through with probability 1 − opacity. Closed
forms: under a uniform dome, a black half-present ceiling lets (1 − o) of the sky through; the ground under it is
lit by (1 − o) of the sun; an opaque surface (o = 1) and a cut-out keep their meaning."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, material, mtlx_material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.usd.scene import read_scene

DOME = 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'


def _ceiling(opacity: float, threshold: float = 0.0) -> str:
    """A black (no diffuse, no specular), infinite horizontal ceiling at y = 2 of the given opacity."""
    inputs = f"float inputs:opacity = {opacity}\n        float inputs:opacityThreshold = {threshold}"
    return (material("Glass", diffuse=(0.0, 0.0, 0.0), diffuse_only=True, inputs=inputs)
            + plane_mesh("Ceiling", 1e4, "/Glass", height=2.0))


def _capture(tmp_path, text: str, samples: int = 16) -> np.ndarray:
    reading = read_scene(write(tmp_path / "scene.usda", text))
    assert not reading.errors, reading.errors
    assert not [i for i in reading.issues if "opacity" in i.message], reading.issues
    cubes, _ = capture_probes(reading.scene, 16, samples=samples, bounces=1)
    return cubes[0].astype(np.float64)


@pytest.mark.parametrize("opacity", [0.0, 0.3, 0.5, 1.0])
def test_a_half_present_ceiling_passes_one_minus_opacity_of_the_sky(tmp_path, opacity):
    cube = _capture(tmp_path, header() + DOME + _ceiling(opacity) + probe("P", (0.0, 1.0, 0.0)))
    up = cube_texel_directions(16)[..., 1] > 0.2  # every texel's footprint meets the ceiling
    seen = cube[up][:, 0]
    # Bernoulli(1 − o) per camera ray, 16 per texel: 5 σ of the mean over the texels
    sigma = math.sqrt(opacity * (1 - opacity) / (seen.size * 16))
    assert abs(seen.mean() - (1.0 - opacity)) <= 5 * sigma + 1e-6
    below = cube_texel_directions(16)[..., 1] < -0.05
    np.testing.assert_allclose(cube[below], 1.0, rtol=1e-6)  # the open lower hemisphere sees the dome exactly


def test_shadow_rays_see_the_presence_too(tmp_path):
    """Ground (ρ = 0.5) under the ceiling (o = 0.6) lit by a normalised sun at 30° (E = 3): radiance
    (1 − o)·ρ·E·⟨cos⟩/π on average — the transmittance of the shadow rays."""
    text = header() + _ceiling(0.6) + material("Soil", diffuse=(0.5,) * 3, diffuse_only=True)
    text += plane_mesh("Ground", 1e4, "/Soil", height=0.0) + probe("P", (0.0, 1.0, 0.0)) + """
def DistantLight "Sun"
{
    float inputs:intensity = 3
    bool inputs:normalize = 1
    float inputs:angle = 0.53
    float xformOp:rotateX = -60
    uniform token[] xformOpOrder = ["xformOp:rotateX"]
}
"""
    cube = _capture(tmp_path, text, samples=32)
    below = cube_texel_directions(16)[..., 1] < -0.3
    seen = cube[below][:, 0]
    alpha = math.radians(0.53 / 2)
    expected = 0.4 * 0.5 * 3.0 * math.cos(math.radians(30.0)) * (1 + math.cos(alpha)) / 2 / math.pi
    sigma = expected * math.sqrt(0.6 / 0.4 / (seen.size * 32))  # Bernoulli(0.4) shadow rays
    assert abs(seen.mean() - expected) <= 5 * sigma


def test_a_cut_out_keeps_its_threshold(tmp_path):
    """opacity 0.3 with opacityThreshold 0.5: cut out entirely (the sky is seen exactly), no randomness."""
    cube = _capture(tmp_path, header() + DOME + _ceiling(0.3, threshold=0.5) + probe("P", (0.0, 1.0, 0.0)))
    omega = cube_texel_solid_angles(16)
    np.testing.assert_allclose((cube[..., 0] * omega).sum(), 4 * math.pi, rtol=1e-6)


def _glass(category_id: str, inputs: str) -> str:
    """A MaterialX surface authored in USD (a ``mtlx`` surface output) on the ceiling."""
    return mtlx_material("Glass", category_id, inputs) + plane_mesh("Ceiling", 1e4, "/Glass", height=2.0)


@pytest.mark.parametrize(("category_id", "inputs", "presence"), [
    ("ND_standard_surface_surfaceshader", "float inputs:transmission = 0.8\n        float inputs:base = 0", 0.2),
    ("ND_standard_surface_surfaceshader",
     "float inputs:transmission = 1\n        float inputs:metalness = 0.5\n        float inputs:base = 0", 0.5),
    ("ND_open_pbr_surface_surfaceshader",
     "float inputs:transmission_weight = 0.6\n        float inputs:base_weight = 0", 0.4),
])
def test_materialx_transmission_passes_light_straight_through(tmp_path, category_id, inputs, presence):
    """Transmission t is thin, straight pass-through: presence 1 − t·(1 − metalness); under a uniform dome the
    probe sees (1 − presence) of the sky through the ceiling (plus the ceiling's own specular reflection of the
    open lower hemisphere, bounded by its Fresnel: the mean stays within F(0°..90°) of the pass-through share)."""
    text = header() + DOME + _glass(category_id, inputs) + probe("P", (0.0, 1.0, 0.0))
    reading = read_scene(write(tmp_path / "glass.usda", text))
    assert not reading.errors, reading.errors
    (mesh,) = reading.scene.meshes
    assert mesh.material.opacity == pytest.approx(presence)
    assert [i for i in reading.issues if "pass-through" in i.message]
    cubes, _ = capture_probes(reading.scene, 16, samples=16, bounces=0)
    up = cube_texel_directions(16)[..., 1] > 0.2
    seen = cubes[0][up][:, 0].astype(np.float64)
    assert (1.0 - presence) - 0.02 <= seen.mean() <= (1.0 - presence) + 0.1 * presence + 0.02
