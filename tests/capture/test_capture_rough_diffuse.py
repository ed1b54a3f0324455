"""Oren–Nayar diffuse (MaterialX oren_nayar_diffuse_bsdf): standard_surface's qualitative model and
open_pbr_surface's energy-preserving EON, as floors under a uniform dome L (bounces 0), whose radiance towards the
probe at view cosine μ is L·∫ f cos dω. References: EON's defining property — a white surface reflects everything at
every view angle — and its closed-form directional albedo [PKH25] Eq. 8 (as MaterialX writes it); the qualitative
model's albedo by brute-force quadrature of [ON94]'s formula written out here."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, mtlx_material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16
L = 1.5


def _floor(tmp_path, shader: str, inputs: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    text = header() + f'def DomeLight "Sky"\n{{\n    float inputs:intensity = {L}\n}}\n'
    text += mtlx_material("Clay", shader, inputs) + plane_mesh("Floor", 1e4, "/Clay")
    reading = read_scene(write(tmp_path / f"{name}.usda", text + probe("P", (0.0, 1.0, 0.0))))
    assert not reading.errors and not [i for i in reading.issues if "roughness" in i.message], reading.issues
    cube = capture_probes(reading.scene, N, samples=64, bounces=0)[0][0].astype(np.float64)
    d = cube_texel_directions(N)
    below = d[..., 1] < -0.3
    return cube[below], -d[below][:, 1]


def _qualitative_albedo(mu: float, sigma: float, n: int = 800) -> float:
    """∫ (A + B·max(0, s)/max(n·l, n·v)) n·l/π dω, s = l·v − n·l n·v [ON94], on a midpoint grid."""
    c = (np.arange(n) + 0.5) / n
    phi = (np.arange(n) + 0.5) * (2 * math.pi / n)
    cl, ph = np.meshgrid(c, phi, indexing="ij")
    sl = np.sqrt(1 - cl * cl)
    lv = sl * np.cos(ph) * math.sqrt(1 - mu * mu) + cl * mu
    s = lv - cl * mu
    st = np.where(s > 0, s / np.maximum(cl, mu), 0)
    s2 = sigma * sigma
    f = (1 - 0.5 * s2 / (s2 + 0.33)) + 0.45 * s2 / (s2 + 0.09) * st
    return float(np.sum(f * cl / math.pi) * (1 / n) * (2 * math.pi / n))


def _eon_albedo(mu: np.ndarray, r: float, rho: float) -> np.ndarray:
    """[PKH25]'s directional albedo: mix(ρ_ms, ρ, E_F(μ)), E_F Fujii's, ρ_ms = ρ² Ē/(1 − ρ(1 − Ē))."""
    c1, c2 = 0.5 - 2 / (3 * math.pi), 2 / 3 - 28 / (15 * math.pi)
    a = 1 / (1 + c1 * r)
    sin = np.sqrt(1 - mu * mu)
    theta = np.arccos(mu)
    g = sin * (theta - sin * mu) + 2 * ((sin / mu) * (1 - sin ** 3) - sin) / 3
    e = a + r * a * g / math.pi
    average = a * (1 + c2 * r)
    multi = rho * rho * average / (1 - rho * (1 - average))
    return multi + (rho - multi) * e


@pytest.mark.parametrize("r", [0.5, 1.0])
def test_a_white_eon_floor_reflects_all_the_light_at_every_view(tmp_path, r):
    inputs = (f"color3f inputs:base_color = (1, 1, 1)\n        float inputs:specular_weight = 0\n        "
              f"float inputs:base_diffuse_roughness = {r}")
    radiance, _mu = _floor(tmp_path, "ND_open_pbr_surface_surfaceshader", inputs, "white")
    np.testing.assert_allclose(radiance.mean(axis=0), L, rtol=0.01)
    np.testing.assert_allclose(np.median(radiance, axis=0), L, rtol=0.02)


def test_an_eon_floor_has_its_closed_form_albedo(tmp_path):
    inputs = ("color3f inputs:base_color = (0.5, 0.5, 0.5)\n        float inputs:specular_weight = 0\n        "
              "float inputs:base_diffuse_roughness = 1")
    radiance, mu = _floor(tmp_path, "ND_open_pbr_surface_surfaceshader", inputs, "grey")
    expected = L * _eon_albedo(mu, 1.0, 0.5)
    np.testing.assert_allclose(radiance.mean(axis=0), expected.mean(), rtol=5e-3)  # measured 0.1 %
    assert abs(expected.mean() - L * 0.5) > 0.03 * L * 0.5  # not the Lambertian floor


@pytest.mark.parametrize("sigma", [0.4, 1.0])
def test_a_qualitative_oren_nayar_floor_has_its_albedo(tmp_path, sigma):
    inputs = ("float inputs:base = 1\n        color3f inputs:base_color = (0.5, 0.5, 0.5)\n        "
              f"float inputs:specular = 0\n        float inputs:diffuse_roughness = {sigma}")
    radiance, mu = _floor(tmp_path, "ND_standard_surface_surfaceshader", inputs, "clay")
    nodes = np.linspace(0.3, 1.0, 8)
    albedo = np.interp(mu, nodes, [_qualitative_albedo(float(m), sigma) for m in nodes])
    np.testing.assert_allclose(radiance.mean(axis=0), L * 0.5 * albedo.mean(), rtol=5e-3)  # measured ≤ 0.06 %
    assert albedo.mean() < 0.97  # darker than Lambertian
