"""IES (LM-63) profiles on UsdLux lights: the reader against profiles written here, the power against closed-form
integrals, ``angleScale`` against its formula, and the capture of a floor lit by a profiled point light against
E = I(θ, φ)·cos β / d² with I the profile's own (bilinear-exact) function."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.capture.ies import CANDELA_TO_EMBREE, IesError, IesShaping, evaluate_ies, parse_ies
from bakery.capture.snapshot import read_capture_scene, write_capture_scene
from bakery.pipeline.dependencies import light_table
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16


def lm63(vertical, horizontal, candela, *, kind=1, multiplier=1.0, ballast=1.0, tilt="NONE", sep=" ") -> str:
    """An LM-63-2002 file: ``candela`` (H, V) in candela."""
    candela = np.asarray(candela, dtype=float).reshape(len(horizontal), len(vertical))
    rows = "\n".join(sep.join(f"{c:g}" for c in row) for row in candela)
    return (f"IESNA:LM-63-2002\n[TEST] bakery\n[MANUFAC] none\nTILT={tilt}\n"
            f"1 -1 {multiplier:g} {len(vertical)} {len(horizontal)} {kind} 2 0.1 0.1 0.1\n"
            f"{ballast:g} 1.0 40\n" + sep.join(f"{a:g}" for a in vertical) + "\n"
            + sep.join(f"{a:g}" for a in horizontal) + "\n" + rows + "\n")


def _local(theta_deg, phi_deg) -> np.ndarray:
    """Light-local emission directions (3, M) at vertical θ (from −Z) and horizontal φ (from +X towards +Y)."""
    t, p = np.radians(np.asarray(theta_deg, float)), np.radians(np.asarray(phi_deg, float))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), -np.cos(t)])


def _value(profile_text, theta, phi, **shaping) -> np.ndarray:
    shaping_ = IesShaping(parse_ies(profile_text, "t.ies"), **shaping)
    return evaluate_ies(shaping_, _local(theta, phi)) / CANDELA_TO_EMBREE


VERTICAL = [0, 30, 60, 90]


def test_grid_values_and_the_candela_factors():
    """At the grid nodes the value is candela × multiplier × ballast factor (× HdEmbree's 4π/177.83); between
    nodes it is bilinear; below the vertical range (θ > 90° for a down light) it is dark."""
    candela = [[100, 80, 40, 10]]  # one horizontal angle: rotationally symmetric
    text = lm63(VERTICAL, [0], candela, multiplier=2.0, ballast=0.5)
    np.testing.assert_allclose(_value(text, VERTICAL, [37.0] * 4), [100, 80, 40, 10], rtol=1e-12)
    np.testing.assert_allclose(_value(text, [15, 45], [200, 0]), [90, 60], rtol=1e-12)
    assert _value(text, [91, 180], [0, 0]).tolist() == [0.0, 0.0]


@pytest.mark.parametrize("sep", [" ", ", ", "\n"])
def test_separators_and_tilt_include(sep):
    """Values separated by commas or line breaks read the same; a TILT=INCLUDE table is skipped."""
    candela = [[100, 80, 40, 10]]
    plain = lm63(VERTICAL, [0], candela)
    tilt = lm63(VERTICAL, [0], candela, tilt="INCLUDE\n1\n3\n0 45 90\n1 0.9 0.8", sep=sep)
    assert parse_ies(tilt, "a").intensity == parse_ies(plain, "a").intensity


def test_horizontal_symmetries_expand_to_a_full_turn():
    """LM-63's declared symmetries: 0–90° (quadrants: I(φ) = I(180° − φ) = I(180° + φ) = I(360° − φ)), 0–180°
    (I(360° − φ) = I(φ)) and 90–270° (mirror about that plane: I(180° − φ) = I(φ))."""
    rows = [[100, 90, 50, 0], [100, 60, 30, 0], [100, 20, 10, 0]]
    quadrant = lm63(VERTICAL, [0, 45, 90], rows)
    for phi, row in ((0, 0), (45, 1), (90, 2), (135, 1), (180, 0), (225, 1), (270, 2), (315, 1), (360, 0)):
        np.testing.assert_allclose(_value(quadrant, [30], [phi]), [rows[row][1]], err_msg=f"φ={phi}")
    half = lm63(VERTICAL, [0, 90, 180], rows)
    for phi, row in ((0, 0), (90, 1), (180, 2), (270, 1), (300, None)):
        expected = rows[row][2] if row is not None else (30 * 2 + 50) / 3  # bilinear between 270° and 360°
        np.testing.assert_allclose(_value(half, [60], [phi]), [expected], err_msg=f"φ={phi}")
    plane = lm63(VERTICAL, [90, 180, 270], rows)
    for phi, row in ((90, 0), (180, 1), (270, 2), (0, 1), (45, None)):
        expected = rows[row][1] if row is not None else (90 + 60) / 2  # between 0° (= 180°) and 90°
        np.testing.assert_allclose(_value(plane, [30], [phi]), [expected], err_msg=f"φ={phi}")


def test_full_turn_without_its_closing_entry_wraps():
    """A 0…270° file (no 360° entry, as some files are written) interpolates across the wrap to 0°."""
    rows = [[100, 40, 0, 0], [100, 80, 0, 0], [100, 60, 0, 0], [100, 20, 0, 0]]
    text = lm63(VERTICAL, [0, 90, 180, 270], rows)
    np.testing.assert_allclose(_value(text, [30, 30], [315, 0]), [(20 + 40) / 2, 40])


def test_horizontal_angle_is_counter_clockwise_from_x_seen_from_above():
    """φ = 0 is light-local +X and φ = 90° is +Y, with θ from −Z: a profile bright only at φ = 90° lights +Y."""
    rows = [[50, 0, 0, 0], [50, 0, 0, 0], [50, 100, 100, 0], [50, 0, 0, 0], [50, 0, 0, 0]]  # one nadir value
    text = lm63(VERTICAL, [0, 45, 90, 135, 180], rows)  # bilateral about the 0–180° plane
    shaping = IesShaping(parse_ies(text, "t.ies"))
    emission = np.array([[0.0, 0.6, -0.8], [0.0, -0.6, -0.8], [0.6, 0.0, -0.8], [0.0, 0.0, -1.0]]).T
    value = evaluate_ies(shaping, emission) / CANDELA_TO_EMBREE
    np.testing.assert_allclose(value, [100, 100, 0, 50])  # ±Y mirror each other; +X dark


def test_power_is_the_mean_intensity_over_the_covered_sphere():
    """normalize divides by the profile's power: ∫ I dΩ / 4π (sphere) or / 2π (hemisphere). Closed forms on a
    1° grid: a constant c over the sphere → c; I = I0 cos θ over the lower hemisphere → ∫ = π I0 → I0/2."""
    vertical = np.arange(0, 181)
    constant = parse_ies(lm63(vertical, [0], np.full((1, 181), 7.0)), "c")
    assert constant.power / CANDELA_TO_EMBREE == pytest.approx(7.0, rel=1e-4)
    down = np.arange(0, 91)
    cosine = parse_ies(lm63(down, [0], 100 * np.cos(np.radians(down))[None]), "cos")
    assert cosine.power / CANDELA_TO_EMBREE == pytest.approx(50.0, rel=1e-3)
    normalized = evaluate_ies(IesShaping(cosine, normalize=True), _local([0, 60], [0, 0]))
    np.testing.assert_allclose(normalized, [2.0, 1.0], rtol=1e-3)  # I/mean = cos θ / (1/2)


def test_angle_scale_follows_usdlux():
    """θ_ies = θ/s for s > 0 (about the down axis), (θ − π)/(−s) + π for s < 0 (about the up axis)."""
    vertical = np.arange(0, 181, 5)
    candela = (180 - vertical)[None].astype(float)  # I = 180 − θ°: linear, so bilinear reads it exactly
    text = lm63(vertical, [0], candela)
    theta = np.array([10.0, 40.0, 80.0])
    np.testing.assert_allclose(_value(text, theta, 0 * theta, angle_scale=0.5), 180 - theta / 0.5)
    np.testing.assert_allclose(_value(text, theta, 0 * theta, angle_scale=2.0), 180 - theta / 2.0)
    up = np.array([100.0, 150.0, 175.0])
    np.testing.assert_allclose(_value(text, up, 0 * up, angle_scale=-0.5), 180 - ((up - 180) / 0.5 + 180))
    assert _value(text, [120.0], [0.0], angle_scale=0.5).tolist() == [0.0]  # θ/s beyond 180°: dark


@pytest.mark.parametrize("text, message", [
    ("no tilt line here\n1 2 3", "no TILT= line"),
    ("TILT=NONE\n1 -1 1 4 1 1 2 0 0 0\n1 1 40\n0 30 60 90\n0\n100 80", "ends before"),
    ("TILT=NONE\n1 -1 1 2 1 4 2 0 0 0\n1 1 40\n0 90\n0\n1 1", "photometric type 4"),
    ("TILT=NONE\n1 -1 1 2 1 1 2 0 0 0\n1 1 40\n90 0\n0\n1 1", "not strictly increasing"),
    ("TILT=NONE\n1 -1 1 2 1 1 2 0 0 0\n1 1 40\n0 90\n0\n1 -1", "negative candela"),
    ("TILT=NONE\n1 -1 1 2 1 1 2 0 0 0\n1 1 40\n0 90\n0\n1 x", "could not convert"),
])
def test_malformed_profiles_are_one_line_errors(text, message):
    with pytest.raises(IesError, match=message) as info:
        parse_ies(text, "lamp.ies")
    assert str(info.value).startswith("lamp.ies: ") and "\n" not in str(info.value)


def _spot(ies_path: str, extra: str = "", height: float = 2.0) -> str:
    return f"""
def SphereLight "Lamp" (
    prepend apiSchemas = ["ShapingAPI"]
)
{{
    float inputs:radius = 0.05
    bool treatAsPoint = 1
    float inputs:intensity = 50
    asset inputs:shaping:ies:file = @{ies_path}@
{extra}
    double3 xformOp:translate = (0, {height}, 0)
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
}}
"""


def _floor_points(position, directions):
    t = -position[1] / directions[..., 1]
    return position + t[..., None] * directions


def test_capture_of_a_floor_under_a_profiled_point_light(tmp_path):
    """A treat-as-point SphereLight (I = L·πr² × the profile) 2 m above a Lambertian floor: the probe sees
    ρ/π · I(θ, φ) · cos β / d² on the floor, with I(θ, φ) = (90 − θ°)·g(φ), g piecewise linear on the 45° nodes
    and bright only around φ = 90° (so a mirrored or half-turned φ would show), through the light's rotation
    (local −Z down, local +Y towards world −Z). Each texel averages its footprint: per texel within 4 %, and the
    mean ratio per 45° sector of φ within 1 %."""
    rho, radiance, radius, height = 0.5, 50.0, 0.05, 2.0
    vertical = np.arange(0, 91, 10)
    horizontal = np.arange(0, 361, 45)
    g = np.array([1.0, 1.5, 2.5, 1.5, 1.0, 1.0, 1.0, 1.0, 1.0])
    (tmp_path / "lamp.ies").write_text(lm63(vertical, horizontal, (90 - vertical)[None, :] * g[:, None]))
    text = header() + material("Ground", diffuse=(rho,) * 3, diffuse_only=True) + plane_mesh("Plane", 100, "/Ground")
    text += _spot("./lamp.ies", height=height) + probe("P", (0.1, 0.5, -0.1))
    reading = read_scene(write(tmp_path / "ies.usda", text))
    assert not [i for i in reading.issues if "ies" in i.message.lower()]
    assert reading.scene.lights[0].ies is not None
    cubes, _ = capture_probes(reading.scene, N, samples=16, bounces=0)
    d = cube_texel_directions(N)
    position = np.array([0.1, 0.5, -0.1])
    points = _floor_points(position, d)
    emission = points - np.array([0.0, height, 0.0])
    dist = np.linalg.norm(emission, axis=-1)
    e = emission / dist[..., None]
    local = np.stack([e[..., 0], -e[..., 2], e[..., 1]], axis=-1)  # rotateX(−90°): X, −Z, Y of the bake frame
    theta = np.degrees(np.arccos(-local[..., 2]))
    phi = np.mod(np.degrees(np.arctan2(local[..., 1], local[..., 0])), 360)
    profile = np.where(theta <= 90, (90 - theta) * np.interp(phi, horizontal, g), 0.0)
    intensity = radiance * math.pi * radius**2 * profile * CANDELA_TO_EMBREE
    expected = rho / math.pi * intensity * (-e[..., 1]) / dist**2
    down = (d[..., 1] < -0.2) & (theta > 25) & (theta < 75)  # away from the dark horizon and the pole of φ
    assert down.sum() > 150
    ratio = cubes[0][down][:, 0] / expected[down]
    np.testing.assert_allclose(ratio, 1.0, atol=0.04)
    for lo in range(0, 360, 45):
        sector = (phi[down] >= lo) & (phi[down] < lo + 45)
        assert sector.sum() > 10 and abs(ratio[sector].mean() - 1) < 0.01, lo


def test_normalize_and_angle_scale_are_read_and_applied(tmp_path):
    """``shaping:ies:normalize`` divides by the power and ``angleScale`` rescales θ: the floor under the light
    (θ = 0 there) sees I(0)/power, and with angleScale 0.5 the ring at θ = 30° sees I(60°)."""
    vertical = np.arange(0, 91, 10)
    (tmp_path / "lamp.ies").write_text(lm63(vertical, [0], (90 - vertical)[None]))
    extra = "    bool inputs:shaping:ies:normalize = 1\n    float inputs:shaping:ies:angleScale = 0.5"
    text = header() + material("Ground", diffuse=(0.5,) * 3, diffuse_only=True) + plane_mesh("Plane", 100, "/Ground")
    text += _spot("./lamp.ies", extra) + probe("P", (0.0, 0.5, 0.0))
    light = read_scene(write(tmp_path / "ies.usda", text)).scene.lights[0]
    assert light.ies.normalize and light.ies.angle_scale == 0.5
    value = evaluate_ies(light.ies, _local([0.0, 30.0], [0.0, 0.0]))
    power = light.ies.profile.power
    np.testing.assert_allclose(value, np.array([90.0, 30.0]) * CANDELA_TO_EMBREE / power, rtol=1e-12)


def test_missing_and_malformed_profiles(tmp_path):
    """A profile that does not resolve is a warning (the light is not shaped); a malformed one is an error on the
    light naming the file."""
    text = header() + material("Ground", diffuse=(0.5,) * 3, diffuse_only=True) + plane_mesh("Plane", 10, "/Ground") + _spot("./absent.ies") + probe("P", (0.0, 0.5, 0.0))
    reading = read_scene(write(tmp_path / "missing.usda", text))
    assert reading.scene.lights[0].ies is None
    assert any(i.severity == "warning" and "absent.ies" in i.message and i.prim == "/Lamp" for i in reading.issues)
    (tmp_path / "bad.ies").write_text("TILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1 40\n0 45 90\n0\n100 50\n")
    text = header() + material("Ground", diffuse=(0.5,) * 3, diffuse_only=True) + plane_mesh("Plane", 10, "/Ground") + _spot("./bad.ies") + probe("P", (0.0, 0.5, 0.0))
    reading = read_scene(write(tmp_path / "bad.usda", text))
    errors = [i for i in reading.issues if i.severity == "error"]
    assert len(errors) == 1 and errors[0].prim == "/Lamp" and "bad.ies" in errors[0].message


def test_snapshot_round_trip_and_the_light_table(tmp_path):
    """The profile crosses to the workers in the snapshot unchanged; the light table's radiance bound includes the
    profile's peak; a light without a profile hashes without an ``ies`` field."""
    vertical = np.arange(0, 91, 10)
    (tmp_path / "lamp.ies").write_text(lm63(vertical, [0], (90 - vertical)[None]))
    text = header() + material("Ground", diffuse=(0.5,) * 3, diffuse_only=True) + plane_mesh("Plane", 10, "/Ground") + _spot("./lamp.ies") + probe("P", (0.0, 0.5, 0.0))
    scene = read_scene(write(tmp_path / "ies.usda", text)).scene
    write_capture_scene(scene, tmp_path / "snap")
    back = read_capture_scene(tmp_path / "snap")
    assert back.lights[0].ies == scene.lights[0].ies
    record = light_table(scene)[0]
    peak = 90 * CANDELA_TO_EMBREE
    np.testing.assert_allclose(record["radiance"], np.asarray(scene.lights[0].radiance) * peak)
    plain = light_table(back.__class__(lights=(scene.lights[0].__class__(**{**scene.lights[0].__dict__,
                                                                          "ies": None}),)))[0]
    assert plain["hash"] != record["hash"] and plain["geometry"] != record["geometry"]
