"""standard_surface sheen: the Imageworks sheen lobe layered over the diffuse lobe (MaterialX sheen_bsdf,
conty_kulla). References: the directional albedo by brute-force quadrature of the formula written out here, and
MaterialX's own rational fit of it; floors under a uniform dome L, whose radiance towards the probe is
L·(ρ·(1 − w·E(μ)) + w·C·E(μ)) at view cosine μ (the layer's energy balance, a closed form in E)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, mtlx_material, plane_mesh, probe, write

from bakery.brdf.sheen import directional_albedo
from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16
L = 1.5


def _brute_albedo(mu: float, roughness: float, n: int = 1500) -> float:
    """∫ D/(4(n·l + n·v − n·l n·v)) n·l dl on a midpoint grid in (cos θ, φ), D = (2 + 1/r) sin(θ_h)^(1/r)/(2π)."""
    cos_l = (np.arange(n) + 0.5) / n
    phi = (np.arange(n) + 0.5) * (2 * math.pi / n)
    c, p = np.meshgrid(cos_l, phi, indexing="ij")
    s = np.sqrt(1 - c * c)
    lx, ly, lz = s * np.cos(p), s * np.sin(p), c
    vx, vz = math.sqrt(1 - mu * mu), mu
    hx, hy, hz = lx + vx, ly, lz + vz
    nh = hz / np.sqrt(hx * hx + hy * hy + hz * hz)
    inv_r = 1 / max(roughness, 0.005)
    d = (2 + inv_r) * np.maximum(1 - nh * nh, 0) ** (0.5 * inv_r) / (2 * math.pi)
    f = d / (4 * (lz + mu - lz * mu))
    return float(np.sum(f * lz) * (1 / n) * (2 * math.pi / n))


def _materialx_fit(mu: float, roughness: float) -> float:
    """MaterialX's mx_imageworks_sheen_dir_albedo_curve_fit (pbrlib/genglsl/lib/mx_microfacet_sheen.glsl)."""
    a = np.array([13.67300, 1.0]) + np.array([-68.78018, 61.57746]) * mu + np.array([799.08825, 442.78211]) * roughness
    a = a + np.array([-905.00061, 2597.49308]) * mu * roughness + np.array([60.28956, 121.81241]) * mu * mu
    a = a + np.array([1086.96473, 3045.55075]) * roughness * roughness
    return float(a[0] / a[1])


@pytest.mark.parametrize("mu", [0.2, 0.5, 0.875])
@pytest.mark.parametrize("roughness", [0.25, 0.5, 1.0])
def test_the_directional_albedo_table_is_the_lobes_integral(mu, roughness):
    """At table nodes: the brute-force integral to 2·10⁻³; MaterialX's rational fit of it to 0.015."""
    table = float(directional_albedo(mu, roughness))
    assert table == pytest.approx(_brute_albedo(mu, roughness), abs=2e-3)
    assert table == pytest.approx(_materialx_fit(mu, roughness), abs=0.015)


def _floor(tmp_path, inputs: str, name: str):
    text = header() + f'def DomeLight "Sky"\n{{\n    float inputs:intensity = {L}\n}}\n'
    text += mtlx_material("Cloth", "ND_standard_surface_surfaceshader", inputs) + plane_mesh("Floor", 1e4, "/Cloth")
    reading = read_scene(write(tmp_path / f"{name}.usda", text + probe("P", (0.0, 1.0, 0.0))))
    assert not reading.errors, reading.errors
    return reading


@pytest.mark.parametrize(("base", "colour", "roughness"), [(0.0, (1.0, 0.5, 0.25), 0.3), (0.8, (1.0, 1.0, 1.0), 0.6)])
def test_a_sheen_floor_under_a_uniform_dome_is_the_layers_closed_form(tmp_path, base, colour, roughness):
    """Black or white (0.8) diffuse base, specular 0, sheen 1: the floor seen at view cosine μ is
    L·(base·(1 − E(μ)) + C·E(μ)), averaged over the texels looking down steeply enough to see the floor far
    from its horizon (64 rays per texel: 0.75 %; measured ≤ 0.25 %)."""
    inputs = (f"float inputs:base = 1\n        color3f inputs:base_color = ({base}, {base}, {base})\n        "
              f"float inputs:specular = 0\n        float inputs:sheen = 1\n        "
              f"color3f inputs:sheen_color = {colour}\n        float inputs:sheen_roughness = {roughness}")
    reading = _floor(tmp_path, inputs, "cloth")
    material = reading.scene.meshes[0].material
    assert material.sheen == 1.0 and material.sheen_roughness == pytest.approx(roughness)
    assert not [i for i in reading.issues if "sheen" in i.message], reading.issues
    cube = capture_probes(reading.scene, N, samples=64, bounces=0)[0][0].astype(np.float64)
    d = cube_texel_directions(N)
    below = d[..., 1] < -0.3
    nodes = np.linspace(0.25, 1.0, 16)  # brute-force E on a μ grid, interpolated to the texels' view cosines
    albedo = np.interp(-d[below][:, 1], nodes, [_brute_albedo(float(mu), roughness, 600) for mu in nodes])
    expected = L * (base * (1 - albedo)[:, None] + np.asarray(colour) * albedo[:, None])
    np.testing.assert_allclose(cube[below].mean(axis=0), expected.mean(axis=0), rtol=7.5e-3)
    grazing, steep = d[below][:, 1] > -0.5, d[below][:, 1] < -0.9  # the sheen rises towards grazing views
    if base == 0.0:
        assert cube[below][grazing].mean() > 1.5 * cube[below][steep].mean()


# ------------------------------------------------------------- gltf_pbr sheen (over the base) and OpenPBR fuzz
def _zeltner_albedo(mu, roughness):
    """MaterialX's mx_zeltner_sheen_dir_albedo (pbrlib/genglsl/lib/mx_microfacet_sheen.glsl), roughness clamped."""
    x, y = np.asarray(mu, dtype=np.float64), min(max(roughness, 0.01), 1.0)
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    return np.exp(-0.5 * ((x - m) / s) ** 2) / (s * math.sqrt(2 * math.pi)) + o


def _capture_floor(tmp_path, node: str, inputs: str, name: str):
    text = header() + f'def DomeLight "Sky"\n{{\n    float inputs:intensity = {L}\n}}\n'
    text += mtlx_material("Cloth", node, inputs) + plane_mesh("Floor", 1e4, "/Cloth")
    reading = read_scene(write(tmp_path / f"{name}.usda", text + probe("P", (0.0, 1.0, 0.0))))
    assert not reading.errors, reading.errors
    cube = capture_probes(reading.scene, N, samples=64, bounces=0)[0][0].astype(np.float64)
    d = cube_texel_directions(N)
    below = d[..., 1] < -0.3
    return reading, cube[below], -d[below][:, 1]


@pytest.mark.parametrize(("colour", "roughness"), [((1.0, 0.5, 0.25), 0.55), ((0.3, 0.6, 0.9), 0.8)])
def test_gltf_sheen_is_weighted_by_its_colours_maximum_and_squares_its_roughness(tmp_path, colour, roughness):
    """KHR_materials_sheen as gltf_pbr's graph builds it: intensity w = max(C), lobe colour C/w, roughness r²; over
    a white (0.8) diffuse base with specular 0 the floor is L·(0.8·(1 − w·E(μ, r²)) + C·E(μ, r²))."""
    inputs = (f"color3f inputs:base_color = (0.8, 0.8, 0.8)\n        float inputs:metallic = 0\n        "
              f"float inputs:specular = 0\n        "
              f"color3f inputs:sheen_color = {colour}\n        float inputs:sheen_roughness = {roughness}")
    nodes = np.linspace(0.25, 1.0, 16)
    table = [_brute_albedo(float(m), roughness**2, 600) for m in nodes]
    _white_base_floor(tmp_path, "ND_gltf_pbr_surfaceshader", inputs, ("base", "conty_kulla"), "sheen", max(colour),
                      np.asarray(colour) / max(colour), lambda mu: np.interp(mu, nodes, table))


def _white_base_floor(tmp_path, node: str, inputs: str, model: tuple[str, str], word: str, weight: float,
                      colour: np.ndarray, albedo) -> None:  # noqa: ANN001
    """The floor of a layer (weight w, colour C, albedo E(μ)) over a white (0.8) diffuse base without specular is
    L·(0.8·(1 − w·E(μ)) + w·C·E(μ)) (0.75 %); the material reads as ``model`` (layer, mode), unreported."""
    reading, seen, mu = _capture_floor(tmp_path, node, inputs, word)
    material = reading.scene.meshes[0].material
    assert (material.sheen_layer, material.sheen_mode) == model
    assert not [i for i in reading.issues if word in i.message], reading.issues
    e = albedo(mu)[:, None]
    expected = L * (0.8 * (1 - weight * e) + weight * np.asarray(colour) * e)
    np.testing.assert_allclose(seen.mean(axis=0), expected.mean(axis=0), rtol=7.5e-3)


def _layered_floor(tmp_path, node: str, base: str, sheen: str, name: str, albedo, weight: float, colour: float):  # noqa: ANN001
    """(floor with the layer, what the closed form makes of the floor without it — L·w·C·E(μ) + (1 − w·E(μ))·bare
    per texel if the layer lies over everything the base reflects —, and the floor if the layer did not dim the
    base); ``albedo(μ)`` is the layer lobe's E."""
    _, without, mu = _capture_floor(tmp_path, node, base, name + "_bare")
    _, with_layer, _ = _capture_floor(tmp_path, node, base + "\n        " + sheen, name)
    e = albedo(mu)[:, None]
    expected = (L * weight * colour * e + (1 - weight * e) * without).mean(axis=0)
    return with_layer.mean(axis=0), expected, (L * weight * colour * e + without).mean(axis=0)


def test_gltf_sheen_lies_over_a_metals_specular_lobe(tmp_path):
    """A rough gold metal under a grey sheen (w = 0.5, C/w = 1): the metal's reflection keeps 1 − w·E(μ, r²) (the
    standard_surface sheen would leave a metal untouched): the two floors' closed-form relation to 1 %."""
    roughness = 0.7
    base = ("color3f inputs:base_color = (1.0, 0.8, 0.3)\n        float inputs:metallic = 1\n        "
            "float inputs:roughness = 0.5")
    sheen = f"color3f inputs:sheen_color = (0.5, 0.5, 0.5)\n        float inputs:sheen_roughness = {roughness}"
    nodes = np.linspace(0.25, 1.0, 16)
    table = [_brute_albedo(float(m), roughness**2, 600) for m in nodes]
    seen, expected, undimmed = _layered_floor(tmp_path, "ND_gltf_pbr_surfaceshader", base, sheen, "metal",
                                              lambda mu: np.interp(mu, nodes, table), 0.5, 1.0)
    np.testing.assert_allclose(seen, expected, rtol=0.01)
    assert np.all(undimmed > 1.05 * seen)


@pytest.mark.parametrize(("weight", "colour", "roughness"), [(1.0, (1.0, 1.0, 1.0), 0.5), (0.6, (0.9, 0.4, 0.2), 0.3)])
def test_open_pbr_fuzz_over_a_diffuse_base_is_the_layers_closed_form(tmp_path, weight, colour, roughness):
    """Zeltner's LTC fuzz over a white (0.8) diffuse base, no specular: L·(0.8·(1 − w·E(μ)) + w·C·E(μ)), E the
    paper's albedo fit (the LTC integrates to 1: tests/math/test_sheen_ltc.py). White fuzz of weight 1 over a white
    base would reflect all of L: the layer conserves energy."""
    inputs = (f"float inputs:base_weight = 1\n        color3f inputs:base_color = (0.8, 0.8, 0.8)\n        "
              f"float inputs:specular_weight = 0\n        float inputs:fuzz_weight = {weight}\n        "
              f"color3f inputs:fuzz_color = {colour}\n        float inputs:fuzz_roughness = {roughness}")
    _white_base_floor(tmp_path, "ND_open_pbr_surface_surfaceshader", inputs, ("coat", "zeltner"), "fuzz", weight,
                      np.asarray(colour), lambda mu: _zeltner_albedo(mu, roughness))


def test_open_pbr_fuzz_lies_over_the_coat(tmp_path):
    """A coated dark base under fuzz: the coat's reflection keeps 1 − w·E(μ) too: the two floors' closed-form
    relation to 1 %."""
    base = ("float inputs:base_weight = 1\n        color3f inputs:base_color = (0.05, 0.05, 0.05)\n        "
            "float inputs:specular_weight = 0\n        float inputs:coat_weight = 1\n        "
            "float inputs:coat_roughness = 0.3")
    sheen = "float inputs:fuzz_weight = 1\n        color3f inputs:fuzz_color = (0.5, 0.5, 0.5)\n        " \
            "float inputs:fuzz_roughness = 0.6"
    seen, expected, undimmed = _layered_floor(tmp_path, "ND_open_pbr_surface_surfaceshader", base, sheen, "coated",
                                              lambda mu: _zeltner_albedo(mu, 0.6), 1.0, 0.5)
    np.testing.assert_allclose(seen, expected, rtol=0.01)
    assert np.all(undimmed > 1.05 * seen)
