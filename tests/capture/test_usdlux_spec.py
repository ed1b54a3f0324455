"""UsdLux lights against the UsdLux specification (OpenUSD's usdLux/schema.usda documentation as clarified for
OpenUSD 25.x — ``inputs:normalize`` size factors, ``inputs:angle``, RectLight texture orientation, colorTemperature
range — and HdEmbree's reference implementation). One light, one probe, no geometry: the probe's irradiance on the
normal facing the light, E = Σ L·cos·Ω over its cube, against closed forms derived here (never numbers produced by
the code)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from usd_scenes import header, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.usd.scene import blackbody_rgb, read_scene

N = 32


def _light(kind: str, body: str, translate=(0.0, 0.0, 0.0), rotate_x: float | None = None, scale=None) -> str:
    ops, lines = ['"xformOp:translate"'], [f"    double3 xformOp:translate = {tuple(translate)}"]
    if rotate_x is not None:
        ops.append('"xformOp:rotateX"')
        lines.append(f"    float xformOp:rotateX = {rotate_x}")
    if scale is not None:
        ops.append('"xformOp:scale"')
        lines.append(f"    float3 xformOp:scale = {tuple(scale)}")
    order = f"    uniform token[] xformOpOrder = [{', '.join(ops)}]"
    return f'\ndef {kind} "L"\n{{\n{body}\n' + "\n".join(lines) + f"\n{order}\n}}\n"


def _read(tmp_path, text: str, meters_per_unit: float = 1.0):
    return read_scene(write(tmp_path / "light.usda", header(meters_per_unit=meters_per_unit) + text + probe("P")))


def _irradiance(tmp_path, text: str, normal=(0.0, 1.0, 0.0), samples: int = 16, meters_per_unit: float = 1.0,
                copies: int = 1) -> np.ndarray:
    """E (3,) on ``normal`` at the probe at the origin: Σ L·max(0, n·ω)·Ω over the captured cube (the mean over
    ``copies`` probes there, each with its own random numbers)."""
    reading = _read(tmp_path, text + "".join(probe(f"Copy{i}") for i in range(1, copies)), meters_per_unit)
    cubes, _ = capture_probes(reading.scene, N, samples=samples, bounces=0)
    cos = np.maximum(0.0, cube_texel_directions(N) @ np.asarray(normal, dtype=np.float64))
    return np.einsum("pfijc,fij->c", np.asarray(cubes, dtype=np.float64), cos * cube_texel_solid_angles(N)) / copies


def _issues(reading) -> list[str]:
    return [str(i) for i in reading.issues]


# ---- area lights: E on the axis ----------------------------------------------------------------------------------
def test_disk_light_on_its_axis(tmp_path):
    """DiskLight (radius R, emitting −Z, turned to face down) at height d: E = π·L·R²/(R² + d²); normalized, L is
    divided by πR²."""
    intensity, r, d = 10.0, 0.5, 2.0
    body = f"    float inputs:intensity = {intensity}\n    float inputs:radius = {r}"
    e = _irradiance(tmp_path, _light("DiskLight", body, (0, d, 0), -90))
    np.testing.assert_allclose(e, math.pi * intensity * r * r / (r * r + d * d), rtol=0.01)
    e = _irradiance(tmp_path, _light("DiskLight", body + "\n    bool inputs:normalize = 1", (0, d, 0), -90))
    np.testing.assert_allclose(e, intensity / (r * r + d * d), rtol=0.01)


def _rect_e(radiance: float, a: float, b: float, d: float) -> float:
    """E at distance d on the axis of a rectangle of half-sides a, b and radiance L (four corner form factors):
    2L·[X/√(1+X²)·atan(Y/√(1+X²)) + Y/√(1+Y²)·atan(X/√(1+Y²))], X = a/d, Y = b/d."""
    x, y = a / d, b / d
    return 2 * radiance * (x / math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x))
                           + y / math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y)))


def test_rect_light_normalize_divides_by_the_scaled_world_area(tmp_path):
    """RectLight w × h under scale (2, 3, 5), normalized: its world rectangle is 2w × 3h and L = intensity / (6wh)
    (UsdLux: "the surface area (in world space) of the shape of the light, including any scaling applied to the
    light by its transform stack"); z's scale does not enter."""
    intensity, w, h, d = 10.0, 1.0, 0.5, 2.0
    body = f"    float inputs:intensity = {intensity}\n    float inputs:width = {w}\n    float inputs:height = {h}\n" \
           "    bool inputs:normalize = 1"
    e = _irradiance(tmp_path, _light("RectLight", body, (0, d, 0), -90, (2, 3, 5)))
    np.testing.assert_allclose(e, _rect_e(intensity / (6 * w * h), w, 1.5 * h, d), rtol=0.01)


def test_negative_sizes_are_their_magnitudes(tmp_path):
    """A negative RectLight width or SphereLight radius is the mirrored shape of the same area (HdEmbree's areas
    are lengths of transformed vectors), reported; before, they emitted nothing."""
    intensity, d = 10.0, 2.0
    text = _light("RectLight", f"    float inputs:intensity = {intensity}\n    float inputs:width = -1\n"
                               "    float inputs:height = 0.5", (0, d, 0), -90)
    np.testing.assert_allclose(_irradiance(tmp_path, text), _rect_e(intensity, 0.5, 0.25, d), rtol=0.01)
    assert any("width -1.0 is negative" in i for i in _issues(_read(tmp_path, text)))
    r = 0.05  # small enough to be splatted from the probe (flux-exact; a wider sphere is ray-seen, noisier)
    text = _light("SphereLight", f"    float inputs:intensity = {intensity}\n    float inputs:radius = {-r}", (0, d, 0))
    np.testing.assert_allclose(_irradiance(tmp_path, text), math.pi * intensity * r * r / (d * d), rtol=0.01)


def test_disk_light_under_a_non_uniform_scale_keeps_its_power(tmp_path):
    """A normalized DiskLight scaled (2, 1, 1) is an ellipse of semi-axes 2R, R (UsdLux: world-space area π·2R·R,
    L = intensity / area). On its axis at d ≫ R (small enough to be splatted from the probe, flux-exact): E = ∫
    L·d²/(ρ² + d²)² dA over the ellipse (integrated here), within 1 %. Before 12-04, the mean radius 1.5R drew
    1.5²/2 = 1.125 × the power."""
    intensity, r, d = 10.0, 0.1, 8.0
    body = f"    float inputs:intensity = {intensity}\n    float inputs:radius = {r}\n    bool inputs:normalize = 1"
    e = _irradiance(tmp_path, _light("DiskLight", body, (0, d, 0), -90, (2, 1, 1)))
    n = 400
    rho, phi = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n * 2 * np.pi)
    x, y = 2 * r * rho * np.cos(phi), r * rho * np.sin(phi)
    da = 2 * r * r * rho * (1 / n) * (2 * np.pi / n)
    expected = intensity / (math.pi * 2 * r * r) * float((d * d / (x * x + y * y + d * d) ** 2 * da).sum())
    np.testing.assert_allclose(e, expected, rtol=0.01)


def _ellipse_e(radiance: float, a: float, b: float, d: float, normal: np.ndarray, n: int = 600) -> float:
    """E on ``normal`` at the origin from an ellipse of semi-axes a (along x), b (along z) at height d facing down,
    radiance L: ∫ L·⟨n, ω⟩₊·cos θ_l / ρ² dA by the midpoint rule in (ρ, φ) (the module's independent quadrature)."""
    rho, phi = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n * 2 * np.pi)
    x, z = a * rho * np.cos(phi), b * rho * np.sin(phi)
    da = a * b * rho * (1 / n) * (2 * np.pi / n)
    dist2 = x * x + d * d + z * z
    omega = np.stack([x, np.full_like(x, d), z]) / np.sqrt(dist2)
    cos_n = np.maximum(np.tensordot(normal, omega, axes=1), 0.0)
    return radiance * float((cos_n * (d / np.sqrt(dist2)) / dist2 * da).sum())


def test_disk_light_under_a_non_uniform_scale_is_its_ellipse(tmp_path):
    """A DiskLight scaled (3, 1/3, 1) close to the probe (d = R): the ellipse of semi-axes 3R, R/3 — the same area
    as the unscaled disk, so on the axis far away the two agree, but normals tilted along and across the long axis
    see its shape. E against the quadrature over the ellipse (the circle of equal area gives 61 % and 67 % more
    here)."""
    intensity, r, d = 10.0, 0.5, 0.5
    body = f"    float inputs:intensity = {intensity}\n    float inputs:radius = {r}"
    # rotateX −90 turns the light's local Y to world −Z: the ellipse's long axis is world x, its short axis z
    text = _light("DiskLight", body, (0, d, 0), -90, (3, 1 / 3, 1))
    for normal in (np.array([1.0, 1.0, 0.0]) / math.sqrt(2), np.array([0.0, 1.0, 1.0]) / math.sqrt(2)):
        e = _irradiance(tmp_path, text, normal=tuple(normal), samples=32)
        np.testing.assert_allclose(e, _ellipse_e(intensity, 3 * r, r / 3, d, normal), rtol=0.02)
        circle = _ellipse_e(intensity, r, r, d, normal)
        assert abs(circle / _ellipse_e(intensity, 3 * r, r / 3, d, normal) - 1.0) > 0.1  # the test sees the shape
    assert not any("non-uniform" in i for i in _issues(_read(tmp_path, text)))
    flat = _light("DiskLight", body, (0, d, 0), -90, (3, 0, 1))  # a zero-area ellipse emits nothing
    np.testing.assert_array_equal(_irradiance(tmp_path, flat), 0.0)


# ---- sphere and point lights ---------------------------------------------------------------------------------------
def test_sphere_light_and_its_point_limits(tmp_path):
    """SphereLight radius R at distance d: E = π·L·R²/d² on the facing normal (normalized: L / 4πR² → L/(4d²)).
    treatAsPoint keeps that intensity I = πR²L (and the probe sees it: before, point lights were missing from every
    probe's own irradiance); a normalized radius-0 sphere is the limit of the normalized ones, I = intensity/4
    (× metersPerUnit² in a centimetre stage)."""
    intensity, r, d = 10.0, 0.05, 2.0
    body = f"    float inputs:intensity = {intensity}\n    float inputs:radius = {r}"
    sphere = math.pi * intensity * r * r / (d * d)
    np.testing.assert_allclose(_irradiance(tmp_path, _light("SphereLight", body, (0, d, 0))), sphere, rtol=0.01)
    np.testing.assert_allclose(_irradiance(tmp_path, _light("SphereLight", body + "\n    bool treatAsPoint = 1",
                                                            (0, d, 0))), sphere, rtol=0.01)
    normalized = intensity / (4 * d * d)
    np.testing.assert_allclose(_irradiance(tmp_path, _light("SphereLight", body + "\n    bool inputs:normalize = 1",
                                                            (0, d, 0))), normalized, rtol=0.01)
    zero = f"    float inputs:intensity = {intensity}\n    float inputs:radius = 0\n    bool inputs:normalize = 1"
    np.testing.assert_allclose(_irradiance(tmp_path, _light("SphereLight", zero, (0, d, 0))), normalized, rtol=0.01)
    np.testing.assert_allclose(_irradiance(tmp_path, _light("SphereLight", zero, (0, 100 * d, 0)),
                                           meters_per_unit=0.01), normalized * 1e-4, rtol=0.01)


def test_sphere_light_under_a_non_uniform_scale_is_its_ellipsoid(tmp_path):
    """A SphereLight of radius R scaled (3, 1/3, 1) is the ellipsoid of semi-axes 3R, R/3, R. Close to the probe
    (seen by its rays) on normals along and across the long axis, and far away edge-on and face-on (splatted from
    its next-event samples), E against the quadrature over the ellipsoid's surface. The sphere of the ellipsoid's
    area, which bakery drew before, differs by more than 10 % in every case: the test sees the shape."""
    from test_capture_lights import ellipsoid_solid_angles

    intensity, r = 10.0, 0.5
    body = f"    float inputs:intensity = {intensity}\n    float inputs:radius = {r}"
    semi_axes = (3 * r, r / 3, r)
    a, b, c = semi_axes
    p = 1.6
    equal_area = math.sqrt((((a * b) ** p + (a * c) ** p + (b * c) ** p) / 3.0) ** (1.0 / p))
    cases = [((0, 1.0, 0), None, (1.0, 1.0, 0.0), 32), ((0, 1.0, 0), None, (0.0, 1.0, 1.0), 32),
             ((0, 40.0, 0), None, (0.0, 1.0, 0.0), 16), ((0, 40.0, 0), -90, (0.0, 1.0, 0.0), 16)]
    for centre, rotate_x, normal, samples in cases:
        normal = np.asarray(normal) / np.linalg.norm(normal)
        text = _light("SphereLight", body, centre, rotate_x, (3, 1 / 3, 1))
        # rotateX −90 turns local Y (the short axis) to world −Z and local Z to world +Y (face-on from below)
        axes = ((1, 0, 0), (0, 0, -1), (0, 1, 0)) if rotate_x else ((1, 0, 0), (0, 1, 0), (0, 0, 1))
        omega, d_omega = ellipsoid_solid_angles(semi_axes, axes, centre, (0, 0, 0))
        expected = intensity * float((np.maximum(omega @ normal, 0.0) * d_omega).sum())
        np.testing.assert_allclose(_irradiance(tmp_path, text, normal=tuple(normal), samples=samples), expected,
                                   rtol=0.02)
        omega, d_omega = ellipsoid_solid_angles((equal_area,) * 3, axes, centre, (0, 0, 0))
        sphere = intensity * float((np.maximum(omega @ normal, 0.0) * d_omega).sum())
        assert abs(sphere / expected - 1.0) > 0.1
    assert not any("SphereLight" in i for i in _issues(_read(tmp_path, _light("SphereLight", body, (0, 1, 0), None,
                                                                                 (3, 1 / 3, 1)))))


def test_cylinder_light_with_a_non_uniformly_scaled_section_is_its_elliptic_cylinder(tmp_path):
    """A CylinderLight (axis local X) of radius R, length 2 scaled (1, 3, 1/3) is the elliptic cylinder of
    semi-axes 3R (local Y), R/3 (local Z). Close to the probe (seen by its rays) on two normals, and far away
    broadside and edge-on (splatted from its next-event samples), E against the quadrature over its surface. The
    circular cylinder of the same perimeter, which bakery drew before, differs by more than 10 % in every case."""
    from test_capture_lights import elliptic_cylinder_solid_angles

    intensity, r, length = 10.0, 0.3, 2.0
    body = f"    float inputs:intensity = {intensity}\n    float inputs:radius = {r}\n    float inputs:length = {length}"
    a, b = 3 * r, r / 3
    circle = (3.0 * (a + b) - math.sqrt((3.0 * a + b) * (a + 3.0 * b))) / 2.0  # Ramanujan's perimeter / 2π
    # far away, each probe's splat is a stratified grid of 36 samples (≈ 3 % noise on a tube): 8 probes' mean
    cases = [((0, 1.2, 0), None, (0.0, 1.0, 1.0), 32, 1), ((0, 1.2, 0), None, (1.0, 1.0, 0.0), 32, 1),
             ((0, 40.0, 0), None, (0.0, 1.0, 0.0), 16, 8), ((0, 40.0, 0), -90, (0.0, 1.0, 0.0), 16, 8)]
    for centre, rotate_x, normal, samples, copies in cases:
        normal = np.asarray(normal) / np.linalg.norm(normal)
        text = _light("CylinderLight", body, centre, rotate_x, (1, 3, 1 / 3))
        # unturned, the wide semi-axis (local Y) faces the probe edge-on; rotateX −90 turns it to world −Z,
        # the thin one (local Z) to world +Y: the probe below sees the tube's broad side
        axes = ((1, 0, 0), (0, 0, -1), (0, 1, 0)) if rotate_x else ((1, 0, 0), (0, 1, 0), (0, 0, 1))
        omega, d_omega = elliptic_cylinder_solid_angles(a, b, length, axes, centre, (0, 0, 0))
        expected = intensity * float((np.maximum(omega @ normal, 0.0) * d_omega).sum())
        np.testing.assert_allclose(_irradiance(tmp_path, text, normal=tuple(normal), samples=samples, copies=copies),
                                   expected, rtol=0.02)
        omega, d_omega = elliptic_cylinder_solid_angles(circle, circle, length, axes, centre, (0, 0, 0))
        assert abs(intensity * float((np.maximum(omega @ normal, 0.0) * d_omega).sum()) / expected - 1.0) > 0.1
    assert not any("CylinderLight" in i for i in _issues(_read(tmp_path, _light("CylinderLight", body, (0, 1, 0),
                                                                                   None, (1, 3, 1 / 3)))))


# ---- distant lights --------------------------------------------------------------------------------------------------
def _distant(intensity: float, angle: float, normalize: bool) -> str:
    body = f"    float inputs:intensity = {intensity}\n    float inputs:angle = {angle}\n" \
           f"    bool inputs:normalize = {int(normalize)}"
    return _light("DistantLight", body, rotate_x=-90)  # emitting −Z turned to −Y: light from +Y


@pytest.mark.parametrize("angle", [0.0, 60.0, 240.0, 359.0, 400.0, -10.0])
def test_distant_light_angle_and_normalize(tmp_path, angle):
    """θmax = clamp(angle/2, 0, π); the disc's radiance is L = intensity / sizeFactor when normalized,
    sizeFactor = 1 (θmax = 0), π·sin²θmax (≤ π/2), (2 − sin²θmax)·π (> π/2); E on the facing normal =
    L·π·sin²θmax, or L·π when the disc covers that hemisphere, or L for the parallel light (θmax = 0, either way —
    before: 0 unnormalized, and a normalized light wider than 180° was 1/sin² too bright, ∞ at 360°)."""
    intensity = 3.0
    t = min(max(math.radians(angle / 2), 0.0), math.pi)
    size = 1.0 if t == 0 else (math.pi * math.sin(t) ** 2 if t <= math.pi / 2 else (2 - math.sin(t) ** 2) * math.pi)
    proj = None if t == 0 else (math.pi * math.sin(t) ** 2 if t <= math.pi / 2 else math.pi)
    for normalize in (True, False):
        radiance = intensity / size if normalize else intensity
        expected = radiance if proj is None else radiance * proj
        np.testing.assert_allclose(_irradiance(tmp_path, _distant(intensity, angle, normalize), samples=8),
                                   expected, rtol=0.01)


# ---- emission: exposure and colour temperature -----------------------------------------------------------------------
def test_exposure_and_its_overflow(tmp_path):
    """L = intensity · 2^exposure (UsdLux); an exposure whose emission exceeds float32 is an error on the light
    (before: an infinite, NaN-noised probe)."""
    intensity, r, d = 1.0, 0.5, 2.0
    body = f"    float inputs:intensity = {intensity}\n    float inputs:radius = {r}\n    float inputs:exposure = 3"
    e = _irradiance(tmp_path, _light("DiskLight", body, (0, d, 0), -90))
    np.testing.assert_allclose(e, 8 * math.pi * intensity * r * r / (r * r + d * d), rtol=0.01)
    reading = _read(tmp_path, _light("DiskLight", body.replace("= 3", "= 200"), (0, d, 0), -90))
    assert not reading.scene.lights
    assert any("exceeds" in i and "/L" in i for i in _issues(reading))


def test_color_temperature_is_clamped_to_the_usdlux_range_and_stays_non_negative(tmp_path):
    """colorTemperature: valid 1000–10000 K (UsdLux), clamped as UsdLuxBlackbodyTemperatureAsRgb (warned);
    components clamped at 0 after the luminance normalisation (Gf's Planckian locus leaves Rec.709 in the blue
    below ~1900 K: a 1500 K light was an error, "emission is negative"); NaN an error (it crashed Gf)."""
    for kelvin in (1000.0, 1500.0, 3000.0, 6500.0, 10000.0):
        rgb = blackbody_rgb(kelvin)
        assert (rgb >= 0).all()
        assert rgb @ np.array([0.2126, 0.7152, 0.0722]) >= 1.0 - 1e-9  # luminance 1, or above where clamped
    np.testing.assert_array_equal(blackbody_rgb(20000.0), blackbody_rgb(10000.0))
    np.testing.assert_array_equal(blackbody_rgb(500.0), blackbody_rgb(1000.0))
    assert blackbody_rgb(10000.0)[2] > blackbody_rgb(10000.0)[0]  # cool: blue above red
    with pytest.raises(ValueError):
        blackbody_rgb(float("nan"))
    body = "    float inputs:intensity = 1\n    bool inputs:enableColorTemperature = 1\n" \
           "    float inputs:colorTemperature = {}\n    float inputs:radius = 0.5"
    reading = _read(tmp_path, _light("DiskLight", body.format(1500), (0, 2, 0), -90))
    assert len(reading.scene.lights) == 1 and min(reading.scene.lights[0].radiance) >= 0
    reading = _read(tmp_path, _light("DiskLight", body.format(20000), (0, 2, 0), -90))
    assert any("outside UsdLux's valid range" in i for i in _issues(reading))
    reading = _read(tmp_path, _light("DiskLight", body.format("nan"), (0, 2, 0), -90))
    assert not reading.scene.lights


def test_cone_softness_is_clamped_to_zero_one(tmp_path):
    """ShapingAPI cone softness outside [0, 1] is clamped (UsdLux): softness 3 reads as 1."""
    text = _light("SphereLight", '    float inputs:shaping:cone:angle = 40\n    float inputs:shaping:cone:softness = 3',
                  (0, 2, 0)).replace('def SphereLight "L"', 'def SphereLight "L" (\n    prepend apiSchemas = '
                                                               '["ShapingAPI"]\n)')
    assert _read(tmp_path, text).scene.lights[0].shaping[1] == 1.0


def test_point_instanced_normalized_lights_divide_by_their_instance_area(tmp_path):
    """A normalized SphereLight in a point instancer's prototype, instanced at scale 1 and 2: each instance emits
    the same power (L = intensity / (4π(sR)²)), so far away each gives E = intensity/(4d²)."""
    intensity, r, d = 10.0, 0.02, 3.0
    text = f"""
def PointInstancer "Lamps"
{{
    rel prototypes = [</Lamps/Protos/Bulb>]
    int[] protoIndices = [0, 0]
    point3f[] positions = [({-d}, 0, 0), ({d}, 0, 0)]
    float3[] scales = [(1, 1, 1), (2, 2, 2)]
    def Scope "Protos"
    {{
        def SphereLight "Bulb"
        {{
            float inputs:intensity = {intensity}
            float inputs:radius = {r}
            bool inputs:normalize = 1
        }}
    }}
}}
"""
    reading = _read(tmp_path, text)
    assert len(reading.scene.lights) == 2
    for normal in ((-1.0, 0.0, 0.0), (1.0, 0.0, 0.0)):
        np.testing.assert_allclose(_irradiance(tmp_path, text, normal=normal), intensity / (4 * d * d), rtol=0.01)


# ---- RectLight texture orientation ---------------------------------------------------------------------------------
def test_rect_light_texture_min_corner_is_at_plus_x_plus_y():
    """UsdLuxRectLight: "a texture file's min coordinates should be at (+X, +Y) and max coordinates at (-X, -Y)":
    the file's first pixel (row 0, column 0) lights local (+X, +Y), the last local (−X, −Y)."""
    from bakery.capture.lights import RectLightModel
    from bakery.capture.scene import Light

    pixels = np.zeros((2, 2, 3))
    pixels[0, 0], pixels[0, 1], pixels[1, 0], pixels[1, 1] = (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)

    class _Texture:
        def __init__(self, p):
            self.pixels = p

    model = RectLightModel(Light("rect", "/R", radiance=(1.0, 1.0, 1.0), size=(2.0, 2.0), texture=0),
                           (_Texture(pixels),))
    coords = np.array([[0.5, -0.5, 0.5, -0.5], [0.5, 0.5, -0.5, -0.5]])  # (a, b): +X+Y, −X+Y, +X−Y, −X−Y
    np.testing.assert_array_equal(model._texel(coords).T, [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)])
