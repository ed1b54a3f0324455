"""Emissive triangles sampled as area lights (bakery.capture.emitters). Closed forms: the irradiance under the
centre of an emissive square (the parallel-rectangle configuration factor); the same square as a UsdLux RectLight
(an independent, analytic emitter path) lights a floor identically; with no continuation at all (bounces 0) the
floor is lit, which it was not when emissive triangles were found by BSDF rays alone. Captures stay bit-identical
whether probes are rendered alone or together."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, material, plane_mesh, probe, write

from bakery.capture import ProbeRenderer, capture_probes
from bakery.usd.scene import read_scene

N = 16
RHO, LE, HALF, HEIGHT = 0.5, 4.0, 1.0, 3.0


def _corner_factor(x: float, y: float) -> float:
    """Configuration factor from a point to a parallel rectangle x·h by y·h with a corner above it, h away."""
    return (x / math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x))
            + y / math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y))) / (2 * math.pi)


def _panel(half: float = HALF, height: float = HEIGHT) -> str:
    """A black square of emission LE, 2·half wide, at ``height`` above the floor (a mesh, not a light)."""
    return material("Glow", diffuse=(0.0, 0.0, 0.0), emissive=(LE, LE, LE), diffuse_only=True) + plane_mesh(
        "Panel", half, "/Glow", height=height)


def _floor() -> str:
    return header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True) + plane_mesh("Plane", 1e4, "/Ground")


def _capture(tmp_path, text: str, name: str, samples: int = 16, bounces: int = 0) -> np.ndarray:
    reading = read_scene(write(tmp_path / f"{name}.usda", text))
    assert not reading.errors, reading.errors
    cubes, _ = capture_probes(reading.scene, N, samples=samples, bounces=bounces)
    return cubes[0].astype(np.float64)


def test_the_floor_under_an_emissive_square_is_lit_by_its_configuration_factor(tmp_path):
    """E = 4·π·L·F(a/h, a/h) under the centre; the probe's central −Y texels see the floor there (2 % at 16 rays
    per texel, measured 1.2 %). Before, at bounces 0 the floor was black."""
    cube = _capture(tmp_path, _floor() + _panel() + probe("P", (0.0, 0.5, 0.0)), "panel")
    centre = cube[3][N // 2 - 1 : N // 2 + 1, N // 2 - 1 : N // 2 + 1].mean(axis=(0, 1))
    e = 4 * math.pi * LE * _corner_factor(HALF / HEIGHT, HALF / HEIGHT)
    np.testing.assert_allclose(centre, RHO * e / math.pi, rtol=0.02)


def test_an_emissive_square_lights_a_floor_as_the_same_rect_light(tmp_path):
    """The panel as a mesh and as a RectLight of the same size, radiance and place (facing down): the floor seen by
    the probe agrees to the noise of 64 rays per texel (mean to 1 %, measured 0.17 %; texels 3 % on average), with one
    bounce so that the MIS of both strategies at both vertices is exercised."""
    rect = f"""
def RectLight "Panel"
{{
    float inputs:width = {2 * HALF}
    float inputs:height = {2 * HALF}
    float inputs:intensity = {LE}
    double3 xformOp:translate = (0, {HEIGHT}, 0)
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
}}
"""
    where = probe("P", (0.7, 0.5, -0.4))
    mesh = _capture(tmp_path, _floor() + _panel() + where, "mesh", samples=64, bounces=1)
    light = _capture(tmp_path, _floor() + rect + where, "rect", samples=64, bounces=1)
    from bakery.sphere.cubemap import cube_texel_directions

    down = cube_texel_directions(N)[..., 1] < -0.2
    np.testing.assert_allclose(mesh[down].mean(axis=0), light[down].mean(axis=0), rtol=0.01)
    assert np.abs(mesh[down] / light[down] - 1).mean() < 0.05


def test_probes_with_emitters_render_bit_identically_alone_and_together(tmp_path):
    reading = read_scene(write(tmp_path / "scene.usda", _floor() + _panel() + probe("A", (0.0, 0.5, 0.0))
                               + probe("B", (1.0, 1.0, 0.5)) + probe("C", (-2.0, 0.3, 1.0))))
    positions = [np.asarray(p.position) for p in reading.scene.probes]
    names = [p.name for p in reading.scene.probes]
    together = ProbeRenderer(reading.scene, samples=4, bounces=2).render_many(positions, 8, names)
    for k in (2, 0):
        alone = ProbeRenderer(reading.scene, samples=4, bounces=2).render(positions[k], 8, names[k])
        np.testing.assert_array_equal(together[k][0], alone[0])


def _panel_irradiance(x: np.ndarray, z: np.ndarray, half: float, height: float, radiance: float) -> np.ndarray:
    """E at floor points (x, z) under the square [−a, a]² at height h: π·L × the signed sum of the four corner
    rectangles' configuration factors (each odd in its sides)."""
    f = np.vectorize(_corner_factor)
    u1, u2, v1, v2 = (half - x) / height, (-half - x) / height, (half - z) / height, (-half - z) / height
    return math.pi * radiance * (f(u1, v1) - f(u2, v1) - f(u1, v2) + f(u2, v2))


@pytest.mark.parametrize(("radius", "share"), [(0.4, 0.25), (2.0, None)])
def test_a_dim_panel_beside_a_bright_lamp_is_sampled_at_a_share_of_the_vertices_unbiased(tmp_path, monkeypatch,
                                                                                         radius, share):
    """A sphere light of 12 (or 300) times the panel's power, far to the side (its irradiance on the floor below
    10⁻³ of the panel's): the panel's power share s = A·lum(L) over all area emitters is 7.4 % (0.3 %), so it is
    sampled at q = max(s, 1/4) of the vertices, with density q·p in both MIS halves (or, below 5 %, not at all:
    BSDF rays find it with weight 1, at the last vertex too), and the floor the probe sees is ρ/π·E_panel texel by
    texel either way (the −Y face's mean to 3 % at 128 rays per texel). Emissive scenes hash the emitter model."""
    from bakery.capture.emitters import emitter_share
    from bakery.pipeline import dependencies
    from bakery.pipeline.dependencies import environment_hash
    from bakery.sphere.cubemap import cube_texel_directions

    lamp = f"""
def SphereLight "Lamp"
{{
    float inputs:radius = {radius}
    float inputs:intensity = 100
    double3 xformOp:translate = (500, 40, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""
    text = _floor() + _panel() + lamp + probe("P", (0.0, 0.5, 0.0))
    reading = read_scene(write(tmp_path / "lamp.usda", text))
    power = (2 * HALF) ** 2 * LE  # A·lum(L) of the 2 × 2 m panel
    assert emitter_share(reading.scene) == pytest.approx(power / (power + 4 * math.pi * radius**2 * 100))
    emitters = ProbeRenderer(reading.scene, samples=1, bounces=0).emitters
    assert (emitters.sampled, emitters.share) == ((True, share) if share else (False, 0.0))
    before = environment_hash(reading.scene)
    monkeypatch.setattr(dependencies, "EMITTER_SAMPLING_VERSION", dependencies.EMITTER_SAMPLING_VERSION + 1)
    assert environment_hash(reading.scene) != before
    cube = _capture(tmp_path, text, "lamp", samples=128)
    d = cube_texel_directions(N)[3]  # the −Y face: every texel sees the floor
    t = 0.5 / -d[..., 1]
    e = _panel_irradiance(t * d[..., 0], t * d[..., 2], HALF, HEIGHT, LE)
    e_lamp = math.pi * 100 * (radius / math.hypot(500, 40)) ** 2 * (40 / math.hypot(500, 40))
    assert e_lamp < 1e-3 * e.mean()
    np.testing.assert_allclose(cube[3].mean(axis=(0, 1)), RHO * (e + e_lamp).mean() / math.pi, rtol=0.03)


@pytest.mark.parametrize(("opacity", "presence"), [("float inputs:opacity = 0.5", 0.5),
                                                   ("float inputs:opacity = 0.2\n        float inputs:opacityThreshold"
                                                    " = 0.5", 0.0)])
def test_a_half_present_or_cut_out_panel_lights_by_its_presence(tmp_path, opacity, presence):
    """Opacity 0.5 without a threshold (stochastic presence): the floor gets half the panel's light, from the
    next-event estimate (× the expected presence) and the BSDF rays (which pass it half the time) together; a panel
    cut out by its threshold lights nothing."""
    glow = material("Glow", diffuse=(0.0, 0.0, 0.0), emissive=(LE, LE, LE), diffuse_only=True, inputs=opacity)
    text = _floor() + glow + plane_mesh("Panel", HALF, "/Glow", height=HEIGHT) + probe("P", (0.0, 0.5, 0.0))
    cube = _capture(tmp_path, text, "present", samples=64)
    centre = cube[3][N // 2 - 1 : N // 2 + 1, N // 2 - 1 : N // 2 + 1].mean(axis=(0, 1))
    e = 4 * math.pi * LE * _corner_factor(HALF / HEIGHT, HALF / HEIGHT)
    np.testing.assert_allclose(centre, presence * RHO * e / math.pi, rtol=0.03, atol=1e-6)
