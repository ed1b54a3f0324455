"""UsdLux's non-physical light controls in the capture: the ``diffuse``/``specular`` multipliers, ShadowAPI's
``shadow:enable`` and ``shadow:color``, light linking and shadow linking. References: the closed forms of a floor
under a sun or a uniform dome, and
linearity (a capture with the multipliers (1, 0) plus one with (0, 1) is the capture with (1, 1), sample for
sample, since the lobes are weighted apart on the same paths)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import box_mesh, header, material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.pipeline.dependencies import light_table
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16
RHO, E = 0.5, 2.0


def _sun(extra: str = "", api: str = "") -> str:
    schemas = f'(\n    prepend apiSchemas = ["{api}"]\n)' if api else ""
    return f"""
def DistantLight "Sun" {schemas}
{{
    float inputs:intensity = {E}
    bool inputs:normalize = 1
    float inputs:angle = 0.1
{extra}
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:rotateX"]
}}
"""


def _capture(tmp_path, text: str, name: str, **settings) -> np.ndarray:
    reading = read_scene(write(tmp_path / f"{name}.usda", text))
    assert not [i for i in reading.issues if "not applied" in i.message], reading.issues
    cubes, _ = capture_probes(reading.scene, N, **{"samples": 4, "bounces": 0, **settings})
    return cubes[0]


def _floor(position=(0.0, 0.5, 0.0)) -> np.ndarray:
    d = cube_texel_directions(N)
    return d[..., 1] < -0.3


@pytest.mark.parametrize("diffuse", [0.0, 0.25, 2.0])
def test_diffuse_multiplier_scales_a_lambertian_floor_not_the_sun_itself(tmp_path, diffuse):
    """ρE/π × diffuse on the floor; the sun's own splat in the probe's view (and so the sky texels) unchanged."""
    floor = material("Ground", diffuse=(RHO,) * 3, diffuse_only=True) + plane_mesh("Plane", 100, "/Ground")
    plain = _capture(tmp_path, header() + floor + _sun() + probe("P", (0.0, 0.5, 0.0)), "plain")
    scaled = _capture(tmp_path, header() + floor + _sun(f"    float inputs:diffuse = {diffuse}")
                      + probe("P", (0.0, 0.5, 0.0)), "scaled")
    down = _floor()
    np.testing.assert_allclose(scaled[down], diffuse * RHO * E / math.pi, rtol=1e-3, atol=1e-7)
    up = ~down & (cube_texel_directions(N)[..., 1] > 0)
    np.testing.assert_array_equal(scaled[up], plain[up])


def test_lobe_multipliers_add_up_to_the_plain_capture(tmp_path):
    """A glossy dielectric (both lobes) under the sun and a sphere light, with indirect light: (0, 0) leaves only
    what the probe sees directly (the light's shape, the sun; the floor black), and the captures with (diffuse,
    specular) = (1, 0) and (0, 1), less that, sum to the capture with (1, 1), which equals the capture without the
    inputs."""
    glossy = material("Ground", diffuse=(0.6, 0.4, 0.2), inputs="float inputs:roughness = 0.3\n        ")
    base = header() + glossy + plane_mesh("Plane", 100, "/Ground") + box_mesh("Box", 0.3, "/Ground", (1.0, 0.3, 0.0))

    def scene(d, s):
        inputs = "" if d is None else f"    float inputs:diffuse = {d}\n    float inputs:specular = {s}"
        lamp = f"""
def SphereLight "Lamp"
{{
    float inputs:radius = 0.2
    float inputs:intensity = 30
{inputs}
    double3 xformOp:translate = (-1, 1.5, 0.5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""
        return base + _sun(inputs) + lamp + probe("P", (0.0, 0.5, 0.0))

    cubes = {key: _capture(tmp_path, scene(*key), f"s{i}", bounces=2)
             for i, key in enumerate([(None, None), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0), (0.0, 0.0)])}
    np.testing.assert_allclose(cubes[1.0, 1.0], cubes[None, None], rtol=1e-5, atol=1e-7)
    direct = cubes[0.0, 0.0]
    np.testing.assert_allclose(cubes[1.0, 0.0] + cubes[0.0, 1.0] - direct, cubes[1.0, 1.0], rtol=1e-4, atol=1e-5)
    assert float(np.abs(cubes[0.0, 0.0][_floor()]).max()) == 0.0
    assert cubes[0.0, 1.0][_floor()].max() > 0 and cubes[1.0, 0.0][_floor()].max() > 0


def test_dome_multiplier(tmp_path):
    """A uniform dome L over a Lambertian floor: the floor is ρ·L·diffuse, the sky texels L."""
    radiance, diffuse = 1.5, 0.4
    text = header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True) + plane_mesh("Plane", 100, "/Ground")
    text += f"""
def DomeLight "Sky"
{{
    float inputs:intensity = {radiance}
    float inputs:diffuse = {diffuse}
}}
""" + probe("P", (0.0, 0.5, 0.0))
    cube = _capture(tmp_path, text, "dome", samples=64)
    d = cube_texel_directions(N)
    np.testing.assert_allclose(cube[_floor()].mean(axis=0), RHO * radiance * diffuse, rtol=0.01)
    np.testing.assert_allclose(cube[d[..., 1] > 0.05], radiance, rtol=1e-6)


def _shadowed_scene(extra: str = "", api: str = "ShadowAPI") -> str:
    """A black 1 m plate at height 1 over a Lambertian floor, under the zenith sun: a shadow under the plate."""
    plate = material("Black", diffuse=(0.0, 0.0, 0.0), diffuse_only=True)
    plate += plane_mesh("Plate", 0.5, "/Black", height=1.0)
    return (header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True) + plane_mesh("Plane", 100, "/Ground")
            + plate + _sun(extra, api) + probe("P", (0.9, 0.5, 0.0)))


def _shadow_masks():
    d = cube_texel_directions(N)
    position = np.array([0.9, 0.5, 0.0])
    t = -position[1] / np.minimum(d[..., 1], -1e-9)
    points = position + t[..., None] * d
    down = d[..., 1] < -0.3
    inside = down & (np.abs(points[..., 0]) < 0.4) & (np.abs(points[..., 2]) < 0.4)
    outside = down & ((np.abs(points[..., 0]) > 0.6) | (np.abs(points[..., 2]) > 0.6))
    return inside, outside


def test_shadows_disabled_and_coloured(tmp_path):
    """shadow:enable = false: the floor under the plate is lit as if the plate were not there (ρE/π); shadow:color
    c: the shadow is c·ρE/π per channel; outside the shadow both are ρE/π, and a plain sun leaves it black."""
    inside, outside = _shadow_masks()
    assert inside.sum() > 3 and outside.sum() > 20
    lit = RHO * E / math.pi
    plain = _capture(tmp_path, _shadowed_scene(api=""), "plain")
    assert float(np.abs(plain[inside]).max()) == 0.0
    off = _capture(tmp_path, _shadowed_scene("    bool inputs:shadow:enable = 0"), "off")
    np.testing.assert_allclose(off[inside | outside], lit, rtol=1e-3)
    colour = (0.25, 0.5, 1.0)
    tinted = _capture(tmp_path, _shadowed_scene(f"    color3f inputs:shadow:color = {colour}"), "tinted")
    np.testing.assert_allclose(tinted[inside], np.broadcast_to(np.array(colour) * lit, tinted[inside].shape),
                               rtol=1e-3)
    np.testing.assert_allclose(tinted[outside], lit, rtol=1e-3)


@pytest.mark.parametrize(("shadow", "strength"), [
    ("float inputs:shadow:distance = 2", 1.0),  # the plate (1 m above the floor) is within reach
    ("float inputs:shadow:distance = 0.5", 0.0),  # beyond it: no shadow
    ("float inputs:shadow:distance = 0.9\n    float inputs:shadow:falloff = 3", 0.0),  # the zone is clipped at d
    ("float inputs:shadow:distance = 1.5\n    float inputs:shadow:falloff = 1", 0.5),  # in the zone, linear
    ("float inputs:shadow:distance = 1.5\n    float inputs:shadow:falloff = 1\n    float inputs:shadow:falloffGamma = 2",
     0.25),
    ("float inputs:shadow:distance = 1.2\n    float inputs:shadow:falloff = 0.1", 1.0),  # nearer than d − f
])
def test_shadow_distance_and_falloff(tmp_path, shadow, strength):
    """ShadowAPI's distance d, falloff f and gamma γ: the plate at t = 1 m above the floor shadows it with strength
    1 (t < d − f), ((d − t)/f)^γ (in the zone) or 0 (t ≥ d): the floor under it is (1 − s)·ρE/π, and with a
    shadow colour c, (1 − s + c·s)·ρE/π; outside the shadow ρE/π."""
    inside, outside = _shadow_masks()
    lit = RHO * E / math.pi
    cube = _capture(tmp_path, _shadowed_scene("    " + shadow), "ranged")
    np.testing.assert_allclose(cube[inside], (1 - strength) * lit, rtol=1e-3, atol=1e-7)
    np.testing.assert_allclose(cube[outside], lit, rtol=1e-3)
    colour = np.array([0.25, 0.5, 1.0])
    tinted = _capture(tmp_path, _shadowed_scene(f"    {shadow}\n    color3f inputs:shadow:color = (0.25, 0.5, 1.0)"),
                      "ranged_tinted")
    np.testing.assert_allclose(tinted[inside], np.broadcast_to((1 - strength + colour * strength) * lit,
                                                               tinted[inside].shape), rtol=1e-3, atol=1e-7)


def test_a_dome_whose_shadow_distance_stops_short_of_a_plate_is_unshadowed(tmp_path):
    """A uniform dome L over a floor under a wide plate h = 1 m up: with shadow:distance 0.5 the plate casts nothing
    and the floor is ρL; with d = 2 it shadows the directions within θ₀ = acos(h/d) = 60° of the zenith (farther
    along the others), so the floor is ρL·cos²θ₀ = ρL/4 — the irradiance of the sky beyond θ₀."""
    def scene(distance: float) -> str:
        plate = material("Black", diffuse=(0.0, 0.0, 0.0), diffuse_only=True)
        plate += plane_mesh("Plate", 20, "/Black", height=1.0)
        return (header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True)
                + plane_mesh("Plane", 100, "/Ground") + plate + f"""
def DomeLight "Sky" (
    prepend apiSchemas = ["ShadowAPI"]
)
{{
    float inputs:intensity = 2
    float inputs:shadow:distance = {distance}
}}
""" + probe("P", (0.0, 0.5, 0.0)))
    near = _capture(tmp_path, scene(0.5), "near", samples=64)
    np.testing.assert_allclose(near[_floor()].mean(axis=0), RHO * 2.0, rtol=0.01)
    far = _capture(tmp_path, scene(2.0), "far", samples=64)
    np.testing.assert_allclose(far[_floor()].mean(axis=0), RHO * 2.0 * 0.25, rtol=0.02)


def test_shadow_disabled_sphere_light_counts_once(tmp_path):
    """A shadowless SphereLight over an unoccluded floor delivers what the shadowed one does (next-event estimation
    alone instead of MIS: no double counting), E = π·L·(r/d)²·cos β on the floor."""
    def scene(extra):
        return header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True) + plane_mesh(
            "Plane", 100, "/Ground") + f"""
def SphereLight "Lamp" (
    prepend apiSchemas = ["ShadowAPI"]
)
{{
    float inputs:radius = 0.3
    float inputs:intensity = 20
{extra}
    double3 xformOp:translate = (0, 2, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
""" + probe("P", (0.0, 0.5, 0.0))
    with_mis = _capture(tmp_path, scene(""), "mis", samples=64)
    without = _capture(tmp_path, scene("    bool inputs:shadow:enable = 0"), "nee", samples=64)
    down = _floor()
    np.testing.assert_allclose(without[down].mean(), with_mis[down].mean(), rtol=0.01)


def test_multipliers_and_shadows_are_read_hashed_and_bounded(tmp_path):
    """The reader fills the Light fields; the light table's radiance bound takes max(1, diffuse, specular); a light
    at the defaults hashes without the new fields; shadow:distance is read (stage units → metres: 4 cm at
    metersPerUnit 0.01); negative multipliers and a non-positive falloff gamma are errors."""
    text = header() + plane_mesh("Plane", 10, "/Ground") + material("Ground") + """
def SphereLight "Lamp" (
    prepend apiSchemas = ["ShadowAPI"]
)
{
    float inputs:intensity = 3
    float inputs:diffuse = 2
    float inputs:specular = 0.5
    bool inputs:shadow:enable = 0
    color3f inputs:shadow:color = (0.1, 0.2, 0.3)
    float inputs:shadow:distance = 4
}
""" + probe("P", (0.0, 0.5, 0.0))
    reading = read_scene(write(tmp_path / "lamp.usda", text))
    light = reading.scene.lights[0]
    assert (light.diffuse, light.specular, light.shadow) == (2.0, 0.5, False)
    assert light.shadow_color == pytest.approx((0.1, 0.2, 0.3))
    assert not [i for i in reading.issues if "shadow" in i.message], reading.issues
    assert (light.shadow_distance, light.shadow_falloff) == (4.0, -1.0)
    centimetres = read_scene(write(tmp_path / "cm.usda", text.replace("metersPerUnit = 1.0", "metersPerUnit = 0.01")
                                   .replace("float inputs:shadow:distance = 4", "float inputs:shadow:distance = 4\n"
                                            "    float inputs:shadow:falloff = 9\n    float inputs:shadow:falloffGamma"
                                            " = 2"))).scene.lights[0]
    assert (centimetres.shadow_distance, centimetres.shadow_falloff, centimetres.shadow_falloff_gamma) == \
        pytest.approx((0.04, 0.04, 2.0))  # the falloff zone never exceeds the distance
    record = light_table(reading.scene)[0]
    np.testing.assert_allclose(record["radiance"], np.asarray(light.radiance) * 2.0)
    import dataclasses

    default = dataclasses.replace(light, diffuse=1.0, specular=1.0, shadow=True, shadow_color=(0.0, 0.0, 0.0))
    from bakery.pipeline.dependencies import _light_fields

    default = dataclasses.replace(default, shadow_distance=-1.0)
    assert not {"diffuse", "specular", "shadow", "shadow_color", "ies", "shadow_distance", "shadow_falloff",
                "shadow_falloff_gamma"} & set(_light_fields(default))
    gamma = text.replace("float inputs:shadow:distance = 4", "float inputs:shadow:distance = 4\n"
                         "    float inputs:shadow:falloffGamma = 0")
    errors = [i for i in read_scene(write(tmp_path / "gamma.usda", gamma)).issues if i.severity == "error"]
    assert len(errors) == 1 and errors[0].prim == "/Lamp" and "falloffGamma 0" in errors[0].message
    bad = text.replace("float inputs:diffuse = 2", "float inputs:diffuse = -1")
    errors = [i for i in read_scene(write(tmp_path / "bad.usda", bad)).issues if i.severity == "error"]
    assert len(errors) == 1 and errors[0].prim == "/Lamp" and "diffuse -1" in errors[0].message


def _two_floors() -> str:
    """Two Lambertian floor halves, /A (x < 0) and /B (x > 0)."""
    mat = material("Ground", diffuse=(RHO,) * 3, diffuse_only=True)
    quad = """
def Mesh "{name}" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [({x0}, 0, 50), ({x1}, 0, 50), ({x1}, 0, -50), ({x0}, 0, -50)]
    rel material:binding = </Ground>
}}
"""
    return mat + quad.format(name="A", x0=-50, x1=0) + quad.format(name="B", x0=0, x1=50)


def _halves():
    d = cube_texel_directions(N)
    down = d[..., 1] < -0.3
    x = 0.5 * d[..., 0] / np.maximum(-d[..., 1], 1e-9)  # the floor point's x, seen from the probe at height 0.5
    return down & (x < -0.1), down & (x > 0.1)


LINK_A = '    uniform bool collection:lightLink:includeRoot = 0\n    rel collection:lightLink:includes = </A>'


def test_light_linking_lights_only_the_linked_meshes(tmp_path):
    """collection:lightLink = {/A}: a sun lights /A with ρE/π and leaves /B black (it is still seen directly:
    the sky texels are those of the unlinked capture); a uniform dome linked to /A lights /A with ρL and not /B;
    a sphere light linked to /B lights /B as unlinked and not /A."""
    a, b = _halves()
    assert a.sum() > 50 and b.sum() > 50
    up = cube_texel_directions(N)[..., 1] > 0
    plain = _capture(tmp_path, header() + _two_floors() + _sun() + probe("P", (0.0, 0.5, 0.0)), "plain")
    sun = _capture(tmp_path, header() + _two_floors() + _sun(LINK_A) + probe("P", (0.0, 0.5, 0.0)), "sun")
    np.testing.assert_allclose(sun[a], RHO * E / math.pi, rtol=1e-3)
    assert float(np.abs(sun[b]).max()) == 0.0
    np.testing.assert_array_equal(sun[up], plain[up])
    dome = f"""
def DomeLight "Sky"
{{
    float inputs:intensity = 1.5
{LINK_A}
}}
"""
    sky = _capture(tmp_path, header() + _two_floors() + dome + probe("P", (0.0, 0.5, 0.0)), "dome", samples=64)
    np.testing.assert_allclose(sky[a].mean(axis=0), RHO * 1.5, rtol=0.01)
    assert float(np.abs(sky[b]).max()) == 0.0
    lamp = """
def SphereLight "Lamp"
{{
    float inputs:radius = 0.2
    float inputs:intensity = 20
{links}
    double3 xformOp:translate = (0, 2, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""
    both = _capture(tmp_path, header() + _two_floors() + lamp.format(links="") + probe("P", (0.0, 0.5, 0.0)),
                    "lamp", samples=16)
    only_b = _capture(tmp_path, header() + _two_floors() + lamp.format(links=LINK_A.replace("</A>", "</B>"))
                      + probe("P", (0.0, 0.5, 0.0)), "lamp_b", samples=16)
    np.testing.assert_array_equal(only_b[b], both[b])  # same paths, same numbers on the linked half
    assert float(np.abs(only_b[a]).max()) == 0.0 and both[a].max() > 0


def _shadow_link(*targets: str, collection: str = "shadowLink") -> str:
    """A collection that includes only ``targets`` (not the root)."""
    return (f"    uniform bool collection:{collection}:includeRoot = 0\n"
            f"    rel collection:{collection}:includes = [{', '.join(f'<{t}>' for t in targets)}]")


def test_shadow_linking_leaves_out_the_shadows_of_unlinked_meshes(tmp_path):
    """collection:shadowLink = {/Plane}: the plate casts no shadow, so the floor under it is lit (ρE/π) as with
    shadow:enable = false, while the probe still sees the black plate above it; shadowLink = {/Plate}, or
    includeRoot with /Plane excluded, keeps the shadow (black), as does the plain sun."""
    inside, outside = _shadow_masks()
    lit = RHO * E / math.pi
    d = cube_texel_directions(N)
    t = 0.5 / np.maximum(d[..., 1], 1e-9)  # the texels that see the plate, 0.5 m above the probe at x = 0.9
    above = (d[..., 1] > 0.3) & (np.abs(0.9 + t * d[..., 0]) < 0.4) & (np.abs(t * d[..., 2]) < 0.4)
    assert above.sum() > 3
    unlinked = _capture(tmp_path, _shadowed_scene(_shadow_link("/Plane"), api=""), "unlinked")
    np.testing.assert_allclose(unlinked[inside | outside], lit, rtol=1e-3)
    assert float(np.abs(unlinked[above]).max()) == 0.0
    kept = _capture(tmp_path, _shadowed_scene(_shadow_link("/Plate"), api=""), "kept")
    excluded = _capture(tmp_path, _shadowed_scene(
        "    rel collection:shadowLink:excludes = </Plane>", api=""), "excluded")
    for cube in (kept, excluded):
        assert float(np.abs(cube[inside]).max()) == 0.0
        np.testing.assert_allclose(cube[outside], lit, rtol=1e-3)


def test_a_shadow_linked_sphere_light_counts_once_and_passes_the_unlinked_plate(tmp_path):
    """A large SphereLight (radius 1.2 m at 3 m: its BSDF-sampled share under MIS is large): shadow-linked to the
    floor alone, it is sampled by next-event estimation alone, so the open floor receives what the MIS capture
    does (no double counting; measured 0.7 %, the two estimators' noise) and the floor under the plate what it
    would without the plate (measured 0.06 %; with MIS kept, the BSDF rays the plate stops leave it 1.5 % dark)."""
    def scene(extra: str, plate: bool = True) -> str:
        text = header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True) + plane_mesh(
            "Plane", 100, "/Ground")
        if plate:
            text += material("Black", diffuse=(0.0, 0.0, 0.0), diffuse_only=True)
            text += plane_mesh("Plate", 0.5, "/Black", height=1.0)
        return text + f"""
def SphereLight "Lamp"
{{
    float inputs:radius = 1.2
    float inputs:intensity = 5
{extra}
    double3 xformOp:translate = (0, 3, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
""" + probe("P", (0.9, 0.5, 0.0))
    d = cube_texel_directions(N)
    t = 0.5 / np.maximum(-d[..., 1], 1e-9)
    x, z = 0.9 + t * d[..., 0], t * d[..., 2]  # the floor point each texel sees; the penumbra ends at |x| = 1.35
    down = d[..., 1] < -0.3
    inside = down & (np.abs(x) < 0.8) & (np.abs(z) < 0.8)
    outside = down & (np.maximum(np.abs(x), np.abs(z)) > 1.5)
    assert inside.sum() > 10 and outside.sum() > 10
    linked = _capture(tmp_path, scene(_shadow_link("/Plane")), "linked", samples=64)
    no_plate = _capture(tmp_path, scene("", plate=False), "no_plate", samples=64)
    plain = _capture(tmp_path, scene(""), "plain", samples=64)
    np.testing.assert_allclose(linked[outside].mean(), plain[outside].mean(), rtol=0.015)
    np.testing.assert_allclose(linked[inside].mean(), no_plate[inside].mean(), rtol=5e-3)
    assert plain[inside].mean() < 0.8 * no_plate[inside].mean()  # the plate's shadow, without the links


def test_a_dome_shadow_linked_past_a_roof_lights_the_floor_under_it(tmp_path):
    """A uniform dome L whose shadowLink leaves out a black roof over the probe: the floor below receives the
    whole sky, ρ·L (next-event estimation alone); the probe still sees the roof's black underside; without the
    links the floor under the roof is dark."""
    def scene(extra: str) -> str:
        return (header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True)
                + plane_mesh("Plane", 1e4, "/Ground") + material("Black", diffuse=(0.0, 0.0, 0.0), diffuse_only=True)
                + plane_mesh("Roof", 1e4, "/Black", height=2.0)
                + f'def DomeLight "Sky"\n{{\n    float inputs:intensity = 1.5\n{extra}\n}}\n'
                + probe("P", (0.0, 0.5, 0.0)))
    d = cube_texel_directions(N)
    down, up = d[..., 1] < -0.3, d[..., 1] > 0.3
    linked = _capture(tmp_path, scene(_shadow_link("/Plane")), "linked", samples=64)
    np.testing.assert_allclose(linked[down].mean(axis=0), RHO * 1.5, rtol=0.01)
    assert float(np.abs(linked[up]).max()) == 0.0
    plain = _capture(tmp_path, scene(""), "plain", samples=16)
    assert float(np.abs(plain[down]).max()) < 1e-3 * RHO * 1.5


def test_dome_shadow_api_lets_the_sky_through_or_colours_its_shadow(tmp_path):
    """ShadowAPI on a uniform dome L over a floor under a black infinite roof: shadow:enable = 0 lights the floor
    with the whole sky (ρ·L, next-event estimation alone), shadow:color c with c·ρ·L (every next-event ray is
    occluded, each delivering c), and the probe sees the roof's black underside either way; read and hashed."""
    from bakery.pipeline.dependencies import environment_hash

    def scene(extra: str) -> str:
        return (header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True)
                + plane_mesh("Plane", 1e4, "/Ground") + material("Black", diffuse=(0.0, 0.0, 0.0), diffuse_only=True)
                + plane_mesh("Roof", 1e4, "/Black", height=2.0)
                + 'def DomeLight "Sky" (\n    prepend apiSchemas = ["ShadowAPI"]\n)\n'
                + f'{{\n    float inputs:intensity = 1.5\n{extra}\n}}\n' + probe("P", (0.0, 0.5, 0.0)))
    d = cube_texel_directions(N)
    down, up = d[..., 1] < -0.3, d[..., 1] > 0.3
    off = _capture(tmp_path, scene("    bool inputs:shadow:enable = 0"), "off", samples=64)
    np.testing.assert_allclose(off[down].mean(axis=0), RHO * 1.5, rtol=0.01)
    colour = (0.25, 0.5, 1.0)
    tinted = _capture(tmp_path, scene(f"    color3f inputs:shadow:color = {colour}"), "coloured", samples=16)
    np.testing.assert_allclose(tinted[down].mean(axis=0), np.array(colour) * RHO * 1.5, rtol=0.01)
    for cube in (off, tinted):
        assert float(np.abs(cube[up]).max()) == 0.0
    readings = [read_scene(write(tmp_path / f"{name}.usda", scene(extra))) for name, extra in
                (("plain", ""), ("off_read", "    bool inputs:shadow:enable = 0"))]
    assert readings[0].scene.dome.shadow and not readings[1].scene.dome.shadow
    assert not [i for i in readings[1].issues if "shadow" in i.message]
    assert environment_hash(readings[0].scene) != environment_hash(readings[1].scene)


def test_shadow_links_are_read_and_hashed_and_filters_reported(tmp_path):
    from bakery.pipeline.dependencies import environment_hash

    text = header() + _two_floors() + _sun(_shadow_link("/A") + '\n    rel light:filters = </Filter>')
    text += 'def LightFilter "Filter"\n{\n}\n' + probe("P", (0.0, 0.5, 0.0))
    reading = read_scene(write(tmp_path / "links.usda", text))
    messages = [i.message for i in reading.issues if i.prim == "/Sun"]
    assert not any("shadow linking" in m for m in messages) and any("light filters" in m for m in messages)
    names = [mesh.name for mesh in reading.scene.meshes]
    (sun,) = reading.scene.lights
    assert sun.links is None and [names[i] for i in sun.shadow_links] == ["/A"]
    plain = read_scene(write(tmp_path / "plain.usda", header() + _two_floors() + _sun() + probe("P", (0.0, 0.5, 0.0))))
    assert plain.scene.lights[0].shadow_links is None
    assert environment_hash(reading.scene) != environment_hash(plain.scene)
    dome = header() + _two_floors() + f'def DomeLight "Sky"\n{{\n{_shadow_link("/B")}\n}}\n' + probe("P")
    reading = read_scene(write(tmp_path / "dome.usda", dome))
    assert [names[i] for i in reading.scene.dome.shadow_links] == ["/B"]


def test_light_shapes_end_paths_with_lobe_multipliers(tmp_path):
    """With a multiplier ≠ 1 somewhere (the lobe-weighted path), a BSDF ray that reaches a light's shape still
    ends there: a sphere light under a bright emissive ceiling hides the ceiling from the floor exactly as without
    multipliers (an extra, dark light with diffuse 0.5 switches the lobe-weighted path on)."""
    ceiling = material("Glow", diffuse=(0.0, 0.0, 0.0), emissive=(50.0, 50.0, 50.0), diffuse_only=True)
    ceiling += plane_mesh("Ceiling", 3, "/Glow", height=1.6)
    lamp = """
def SphereLight "Lamp"
{
    float inputs:radius = 0.5
    float inputs:intensity = 0.001
    double3 xformOp:translate = (0, 0.9, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""
    dark = """
def SphereLight "Dark"
{{
    float inputs:radius = 0.1
    float inputs:intensity = 0.001
    float inputs:diffuse = {diffuse}
    double3 xformOp:translate = (2.5, 1.2, 2.5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""
    base = header() + material("Ground", diffuse=(RHO,) * 3, diffuse_only=True) + plane_mesh("Plane", 3, "/Ground")
    base += ceiling + lamp + probe("P", (0.6, 0.3, 0.0))
    plain = _capture(tmp_path, base + dark.format(diffuse=1.0), "plain", samples=64, bounces=1)
    lobes = _capture(tmp_path, base + dark.format(diffuse=0.5), "lobes", samples=64, bounces=1)
    down = _floor()
    np.testing.assert_allclose(lobes[down].mean(), plain[down].mean(), rtol=0.02)
