"""Clearcoat in the capture (UsdPreviewSurface ``clearcoat``/``clearcoatRoughness``): a floor under a uniform dome L
seen by a probe reflects L·∫ f(v, l) cos θ_l dω — integrated here by brute force over the hemisphere from the
coat's formula (GGX D, height-correlated Smith V, Schlick F with F0 0.04; the base weighted by 1 − F_c) — for a coat
over a black base and over a white Lambertian one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16
L = 1.5


def _reflectance(mu_v: float, coat: float, rough: float, albedo: float, count: int = 600) -> float:
    """∫ [F_c D V + (1 − F_c)·albedo/π] cos θ_l dω over the upper hemisphere, view at cos θ = mu_v (midpoint rule
    in (cos θ_l, φ))."""
    a = max(rough * rough, 1e-3)
    a2 = a * a
    mu = (np.arange(count) + 0.5) / count
    phi = (np.arange(2 * count) + 0.5) / (2 * count) * 2 * math.pi
    mu, phi = np.meshgrid(mu, phi, indexing="ij")
    sin = np.sqrt(1 - mu * mu)
    light = np.stack([sin * np.cos(phi), sin * np.sin(phi), mu], axis=-1)
    view = np.array([math.sqrt(1 - mu_v * mu_v), 0.0, mu_v])
    h = light + view
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    nh, vh = h[..., 2], h @ view
    d = a2 / (math.pi * (nh * nh * (a2 - 1) + 1) ** 2)
    vis = 0.5 / (mu * math.sqrt(mu_v * mu_v * (1 - a2) + a2) + mu_v * np.sqrt(mu * mu * (1 - a2) + a2))
    fc = coat * (0.04 + 0.96 * (1 - vh) ** 5)
    f = fc * d * vis + (1 - fc) * albedo / math.pi
    return float(np.sum(f * mu) * (1.0 / count) * (2 * math.pi / (2 * count)))


def _floor_material(coat: float, rough: float, albedo: float) -> str:
    return f"""
def Material "Coated"
{{
    token outputs:surface.connect = </Coated/Surface.outputs:surface>
    def Shader "Surface"
    {{
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor = ({albedo}, {albedo}, {albedo})
        int inputs:useSpecularWorkflow = 1
        color3f inputs:specularColor = (0, 0, 0)
        float inputs:clearcoat = {coat}
        float inputs:clearcoatRoughness = {rough}
        token outputs:surface
    }}
}}
"""


@pytest.mark.parametrize("coat, rough, albedo", [(1.0, 0.3, 0.0), (0.6, 0.5, 0.0), (1.0, 0.3, 0.8)])
def test_coated_floor_under_a_uniform_dome(tmp_path, coat, rough, albedo):
    text = header() + _floor_material(coat, rough, albedo) + plane_mesh("Plane", 200, "/Coated")
    text += f'def DomeLight "Sky"\n{{\n    float inputs:intensity = {L}\n}}\n' + probe("P", (0.0, 0.5, 0.0))
    reading = read_scene(write(tmp_path / "coat.usda", text))
    assert not [i for i in reading.issues if "clearcoat" in i.message], reading.issues
    assert reading.scene.meshes[0].material.clearcoat == pytest.approx(coat)
    cubes, _ = capture_probes(reading.scene, N, samples=256, bounces=1)
    d = cube_texel_directions(N)
    for mu_v in (0.45, 0.7, 0.9):  # texels looking down at these cosines (within ±0.03)
        sel = np.abs(-d[..., 1] - mu_v) < 0.03
        assert sel.sum() >= 8
        expected = L * _reflectance(mu_v, coat, rough, albedo)
        np.testing.assert_allclose(cubes[0][sel].mean(), expected, rtol=0.02, err_msg=f"mu_v={mu_v}")


def test_no_coat_is_the_previous_bsdf(tmp_path):
    """clearcoat = 0 shades exactly as a material without the input (the coat lobe is not even built)."""
    base = header() + plane_mesh("Plane", 200, "/Coated") + 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1.5\n}\n'
    base += probe("P", (0.0, 0.5, 0.0))
    plain = base + _floor_material(0.0, 0.3, 0.5).replace("        float inputs:clearcoat = 0.0\n", "")
    cube_a, _ = capture_probes(read_scene(write(tmp_path / "a.usda", plain)).scene, N, samples=4, bounces=1)
    cube_b, _ = capture_probes(read_scene(write(tmp_path / "b.usda", base + _floor_material(0.0, 0.3, 0.5))).scene,
                               N, samples=4, bounces=1)
    np.testing.assert_array_equal(cube_a, cube_b)


def test_coat_highlight_of_a_sun_follows_the_ggx_lobe(tmp_path):
    """A sun of illuminance E at 30° from the zenith over a coated black floor: each floor texel shows
    E·F_c·D·V·cos θ_l of its own view and light directions (the highlight's shape pins α_c = r_c²)."""
    e, rough = 2.0, 0.4
    sun = f"""
def DistantLight "Sun"
{{
    float inputs:intensity = {e}
    bool inputs:normalize = 1
    float inputs:angle = 0.1
    float xformOp:rotateZ = -30
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:rotateZ", "xformOp:rotateX"]
}}
"""
    text = header() + _floor_material(1.0, rough, 0.0) + plane_mesh("Plane", 200, "/Coated") + sun
    text += probe("P", (0.0, 0.5, 0.0))
    cubes, _ = capture_probes(read_scene(write(tmp_path / "sun.usda", text)).scene, N, samples=64, bounces=1)
    d = cube_texel_directions(N)
    down = d[..., 1] < -0.2
    view = -d  # from the floor point back to the probe
    light = np.array([0.5, math.sqrt(3) / 2, 0.0])
    h = view + light
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    a2 = (rough * rough) ** 2
    nh, vh, nv, nl = h[..., 1], np.sum(h * view, axis=-1), view[..., 1], light[1]
    dd = a2 / (math.pi * (nh * nh * (a2 - 1) + 1) ** 2)
    vis = 0.5 / (nl * np.sqrt(nv * nv * (1 - a2) + a2) + nv * math.sqrt(nl * nl * (1 - a2) + a2))
    expected = e * (0.04 + 0.96 * (1 - vh) ** 5) * dd * vis * nl
    bright = down & (expected > 0.1 * expected[down].max())
    assert bright.sum() > 30
    ratio = cubes[0][bright][:, 0] / expected[bright]
    assert abs(float(np.median(ratio)) - 1) < 0.03 and float(np.percentile(np.abs(ratio - 1), 90)) < 0.1


def test_materials_without_a_coat_hash_as_before():
    """The reuse hash leaves the coat fields out of uncoated materials (their stores are not re-baked for it) and
    keeps them for coated ones."""
    from bakery.capture.scene import Material
    from bakery.pipeline.dependencies import _material_fields

    assert not {"clearcoat", "clearcoat_roughness"} & set(_material_fields(Material()))
    assert {"clearcoat", "clearcoat_roughness"} <= set(_material_fields(Material(clearcoat=0.5)))
