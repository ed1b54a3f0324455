"""Where a DomeLight's texels land, against the UsdLux specification and Hydra, not against bakery's own layouts.

One bright texel on a dim texture, a probe under the dome and nothing else: the flux centroid of the captured cube
is the marker's direction. The expected directions are written out here from the sources:

- latlong: the OpenEXR text UsdLux quotes (``pxr/usd/usdLux/schema.usda``, DomeLight and DomeLight_1): pixel
  (min x, min y) at latitude +π/2, longitude +π; latitude ±π/2 = ±Y, (0, 0) = +Z, longitude π/2 = +X;
- the dome's transform as HdEmbree applies it (``hdEmbree`` ``_SampleDomeLight``: the local direction is
  ``xformWorldToLight.TransformDir(direction)``, so a texel at local l is seen along M·l, mirrors included) and
  Storm (``hdSt/light.cpp``: ``transform = domeOffset * transform``; ``simpleLighting.glslfx``
  ``projectSphericalToLatLong`` through ``worldToLightTransform``), with UsdImaging's DomeLight_1 pole offset
  (``usdImaging/domeLight_1Adapter.cpp`` ``_GetDomeOffset``: rotate 90° about X for poleAxis "Z", or "scene" on a
  Z-up stage);
- the other formats, which UsdLux names without orientation and Hydra does not read: the conventions bakery
  documents (``bakery/conventions.py``), each from its definition — the mirrored ball as the view ray (0, 0, −1)
  reflected about the ball's normal, Debevec's angular map (u, v) = (D_x, D_y)·acos(D_z)/(π·√(D_x² + D_y²)), the
  vertical cross as the inside of the cube unfolded around its +Z centre face.

The bake frame is the stage's for a Y-up stage and (x, y, z) ↦ (x, z, −y) for a Z-up one (bakery's documented
stage → bake turn, applied to everything alike).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom
from usd_scenes import header, probe, write

from bakery.capture import capture_probes
from bakery.capture.dome import DomeSampler
from bakery.environment.io import write_exr
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.usd.scene import read_scene

FACE = 32
H, W = 64, 128  # latlong markers: 2.8° texels
MARKER = (20, 40)  # an asymmetric texel: latitude 33.75°, longitude 67.5°


def _marker(height: int, width: int, texel: tuple[int, int]) -> np.ndarray:
    image = np.full((height, width, 3), 1e-3, np.float32)
    image[texel] = 1e4
    return image


def _scene(tmp_path: Path, image: np.ndarray, fmt: str = "latlong", xform: str = "", up: str = "Y",
           prim: str = "DomeLight", extra: str = "") -> Path:
    tmp_path.mkdir(parents=True, exist_ok=True)
    write_exr(tmp_path / "marker.exr", image, half=False)
    text = header(up_axis=up) + f"""
def {prim} "Sky"
{{
    asset inputs:texture:file = @./marker.exr@
    token inputs:texture:format = "{fmt}"
    {xform}
    {extra}
}}
""" + probe("P", (0.0, 0.0, 0.0))
    return write(tmp_path / "dome.usda", text)


def _captured_direction(path: Path) -> np.ndarray:
    reading = read_scene(path)
    assert not reading.errors, reading.errors
    cube, _ = capture_probes(reading.scene, FACE, samples=1)
    flux = cube[0].astype(np.float64).mean(axis=-1).reshape(-1) * cube_texel_solid_angles(FACE).reshape(-1)
    bright = flux > 0.01 * flux.max()
    d = (flux[bright, None] * cube_texel_directions(FACE).reshape(-1, 3)[bright]).sum(axis=0)
    return d / np.linalg.norm(d)


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.degrees(math.acos(float(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def _openexr_latlong(i: int, j: int, height: int, width: int) -> np.ndarray:
    """Direction of texel (row i, column j)'s centre in the OpenEXR latlong map UsdLux quotes."""
    latitude = math.pi / 2 - math.pi * (i + 0.5) / height
    longitude = math.pi - 2 * math.pi * (j + 0.5) / width
    c = math.cos(latitude)
    return np.array([c * math.sin(longitude), math.sin(latitude), c * math.cos(longitude)])


def _stage_to_bake(direction: np.ndarray, up: str) -> np.ndarray:
    x, y, z = direction
    return np.array([x, z, -y]) if up == "Z" else np.array([x, y, z])


def _hydra_direction(path: Path, local: np.ndarray) -> np.ndarray:
    """Where Hydra shows the texel at dome-local direction ``local``: the dome's world matrix (after UsdImaging's
    DomeLight_1 pole offset) applied to it, normalised, in the bake frame."""
    stage = Usd.Stage.Open(str(path))
    dome = stage.GetPrimAtPath("/Sky")
    world = UsdGeom.Xformable(dome).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
    offset = Gf.Matrix4d(1.0)
    if dome.GetTypeName() == "DomeLight_1":
        pole = dome.GetAttribute("poleAxis").Get()
        up = stage.GetMetadata("upAxis")
        if pole == "Z" or (pole == "scene" and up == "Z"):
            offset.SetRotate(Gf.Rotation(Gf.Vec3d(1, 0, 0), 90.0))
    d = np.array((offset * world).TransformDir(Gf.Vec3d(*local)))
    return _stage_to_bake(d / np.linalg.norm(d), str(UsdGeom.GetStageUpAxis(stage)))


@pytest.mark.parametrize("name,texel,expected", [
    ("centre", (31, 63), None), ("column 0, the equator", (31, 0), None), ("a quarter in: +X", (31, 31), None),
    ("near the zenith", (4, 96), None), ("the marker", MARKER, None)])
def test_latlong_texels_land_where_openexr_puts_them(tmp_path, name, texel, expected):
    """An untransformed DomeLight: each marker within 0.5° of its OpenEXR direction (measured ≤ 0.04°; a texel is
    2.8°). The image centre looks down +Z, a quarter in from the left edge +X, the top row is +Y."""
    measured = _captured_direction(_scene(tmp_path, _marker(H, W, texel)))
    assert _angle(measured, _openexr_latlong(*texel, H, W)) < 0.5


def test_latlong_axes_in_words(tmp_path):
    """The spec's sentences, independently of any formula: the centre column at the equator looks down +Z, the
    column a quarter of the width in from the left along +X, and the first row at the zenith +Y."""
    for texel, axis in (((31, 63), (0, 0, 1)), ((31, 31), (1, 0, 0)), ((31, 95), (-1, 0, 0)), ((0, 10), (0, 1, 0)),
                        ((63, 10), (0, -1, 0))):
        measured = _captured_direction(_scene(tmp_path / f"{texel}", _marker(H, W, texel)))
        assert _angle(measured, axis) < 4.0, (texel, axis, measured)


_ORDER = 'uniform token[] xformOpOrder = [{}]'


def _ops(*ops: tuple[str, str]) -> str:
    return "\n    ".join(f"{kind} xformOp:{op} = {value}" for kind, op, value in ops) + "\n    " + _ORDER.format(
        ", ".join(f'"xformOp:{op}"' for _, op, _ in ops))


@pytest.mark.parametrize("name,xform,up,prim,extra", [
    ("rotateY 90", _ops(("float", "rotateY", "90")), "Y", "DomeLight", ""),
    ("rotateX 30 after rotateY 40", _ops(("float", "rotateX", "30"), ("float", "rotateY", "40")), "Y", "DomeLight", ""),
    ("mirrored in X", _ops(("float3", "scale", "(-1, 1, 1)")), "Y", "DomeLight", ""),
    ("mirrored in Z", _ops(("float3", "scale", "(1, 1, -1)")), "Y", "DomeLight", ""),
    ("mirrored in Y", _ops(("float3", "scale", "(1, -1, 1)")), "Y", "DomeLight", ""),
    ("mirrored and turned", _ops(("float", "rotateY", "30"), ("float3", "scale", "(-2, 2, 2)")), "Y", "DomeLight", ""),
    ("uniformly scaled", _ops(("float3", "scale", "(3, 3, 3)")), "Y", "DomeLight", ""),
    ("Z-up stage", "", "Z", "DomeLight", ""),
    ("Z-up stage, rotateX 90", _ops(("float", "rotateX", "90")), "Z", "DomeLight", ""),
    ("DomeLight_1, Y-up, scene", "", "Y", "DomeLight_1", ""),
    ("DomeLight_1, Y-up, Z", "", "Y", "DomeLight_1", 'uniform token poleAxis = "Z"'),
    ("DomeLight_1, Z-up, scene", "", "Z", "DomeLight_1", ""),
    ("DomeLight_1, Z-up, Y", "", "Z", "DomeLight_1", 'uniform token poleAxis = "Y"'),
    ("DomeLight_1, Z-up, Z, rotateZ 90", _ops(("float", "rotateZ", "90")), "Z", "DomeLight_1",
     'uniform token poleAxis = "Z"'),
    ("DomeLight_1, Z-up, scene, mirrored", _ops(("float3", "scale", "(-1, 1, 1)")), "Z", "DomeLight_1", ""),
])
def test_transformed_dome_shows_its_texels_where_hydra_does(tmp_path, name, xform, up, prim, extra):
    """The marker within 0.5° of M·l (measured 0.02°): rotations, the DomeLight_1 pole and a negative scale as
    HdEmbree and Storm apply them. A mirroring scale mirrors the sky (before: bakery turned it into a rotation,
    40° off for this marker)."""
    path = _scene(tmp_path, _marker(H, W, MARKER), xform=xform, up=up, prim=prim, extra=extra)
    expected = _hydra_direction(path, _openexr_latlong(*MARKER, H, W))
    assert _angle(_captured_direction(path), expected) < 0.5


def test_dome_light_1_pole_axis_in_words(tmp_path):
    """DomeLight_1's text: with poleAxis "Z", "latitudes -pi/2 and +pi/2 will instead correspond to the negative
    and positive Z direction, and latitude 0, longitude 0 will instead point into the negative Y direction". On a
    Y-up stage (the bake frame = the stage's) the top row is +Z and the image centre −Y."""
    for texel, axis in (((0, 10), (0, 0, 1)), ((31, 63), (0, -1, 0)), ((31, 31), (1, 0, 0))):
        path = _scene(tmp_path / f"{texel}", _marker(H, W, texel), prim="DomeLight_1",
                      extra='uniform token poleAxis = "Z"')
        assert _angle(_captured_direction(path), axis) < 4.0, (texel, axis)


def test_a_non_uniformly_scaled_dome_is_reported(tmp_path):
    """Hydra stretches the sky by a non-uniform scale; bakery keeps the rotation and says so."""
    path = _scene(tmp_path, _marker(H, W, MARKER), xform=_ops(("float3", "scale", "(1, 2, 1)")))
    reading = read_scene(path)
    assert not reading.errors
    assert any(i.prim == "/Sky" and "non-uniform scale" in i.message for i in reading.issues)
    uniform = _scene(tmp_path / "u", _marker(H, W, MARKER), xform=_ops(("float3", "scale", "(-2, 2, 2)")))
    assert not any("non-uniform" in i.message for i in read_scene(uniform).issues)


@pytest.mark.parametrize("layout", ["latlong", "mirroredBall"])
def test_a_mirrored_dome_samples_what_it_looks_up(tmp_path, layout):
    """Surfaces see the dome through importance samples, probes through lookups: with a mirroring transform the
    two agree — every sampled direction looks up the radiance and density it was drawn with, and the sun (the
    marker) is drawn around M·l."""
    if layout == "latlong":
        image, local = _marker(H, W, MARKER), _openexr_latlong(*MARKER, H, W)
    else:
        n, (i, j) = 64, (40, 20)
        image = _marker(n, n, (i, j))
        u, v = 2 * (j + 0.5) / n - 1, 1 - 2 * (i + 0.5) / n
        normal = np.array([u, v, math.sqrt(1 - u * u - v * v)])
        local = np.array([0.0, 0.0, -1.0]) + 2 * normal[2] * normal
    path = _scene(tmp_path, image, fmt=layout, xform=_ops(("float", "rotateY", "30"), ("float3", "scale", "(-1, 1, 1)")))
    reading = read_scene(path)
    sampler = DomeSampler(reading.scene.dome)
    rng = np.random.default_rng(1)
    m = 4096
    u0, u1, u2 = rng.random(m), rng.random(m).astype(np.float32), rng.random(m).astype(np.float32)
    d, radiance, pdf = sampler.sample_rest_soa(u0, u1, u2)
    looked, looked_pdf = sampler.rest_lookup_soa(d)
    np.testing.assert_allclose(looked, radiance, rtol=1e-6)
    np.testing.assert_allclose(looked_pdf, pdf, rtol=1e-3)
    assert sampler.has_sun
    d, radiance, pdf = sampler.sample_sun_soa(u0, u1, u2)
    sun, sun_pdf = sampler.sun_lookup_soa(d)
    np.testing.assert_allclose(sun, radiance, rtol=1e-6)
    np.testing.assert_allclose(sun_pdf, pdf, rtol=1e-3)
    assert _angle(d.mean(axis=1), _hydra_direction(path, local)) < 2.0


def _ball(i: int, j: int, n: int) -> np.ndarray:
    u, v = 2 * (j + 0.5) / n - 1, 1 - 2 * (i + 0.5) / n
    normal = np.array([u, v, math.sqrt(1 - u * u - v * v)])
    return np.array([0.0, 0.0, -1.0]) + 2 * normal[2] * normal


def _angular(i: int, j: int, n: int) -> np.ndarray:
    u, v = 2 * (j + 0.5) / n - 1, 1 - 2 * (i + 0.5) / n
    r = math.hypot(u, v)
    return np.array([u / r * math.sin(math.pi * r), v / r * math.sin(math.pi * r), math.cos(math.pi * r)])


@pytest.mark.parametrize("fmt,direction", [("mirroredBall", _ball), ("angular", _angular)])
@pytest.mark.parametrize("texel", [(32, 48), (10, 32), (40, 20)])
def test_disc_formats_land_where_their_definitions_put_them(tmp_path, fmt, direction, texel):
    """64² disc maps: within 1° of the mirrored ball's reflected view ray and Debevec's angular map (measured
    ≤ 0.64°: the non-latlong dome is resampled to a 32² cube first); both centred on +Z like the latlong, u
    rightwards = +X, v up = +Y."""
    measured = _captured_direction(_scene(tmp_path, _marker(64, 64, texel), fmt=fmt))
    assert _angle(measured, direction(*texel, 64)) < 1.0


@pytest.mark.parametrize("face,cell,direction", [
    ("+Y", (0, 1), lambda a, b: (-a, 1, b)), ("+X", (1, 0), lambda a, b: (1, -b, a)),
    ("+Z", (1, 1), lambda a, b: (-a, -b, 1)), ("-X", (1, 2), lambda a, b: (-1, -b, -a)),
    ("-Y", (2, 1), lambda a, b: (-a, -1, -b)), ("-Z", (3, 1), lambda a, b: (-a, b, -1))])
def test_vertical_cross_faces_fold_around_the_latlong_centre(tmp_path, face, cell, direction):
    """A 3·16 × 4·16 cross, a marker in each face's upper-right quadrant: within 1° of the cube seen from inside,
    unfolded around +Z (its right −X, as the latlong's right of centre) — each face's (a right, b down) written
    from that folding (measured 0.1°)."""
    f, (r, c) = 16, cell
    i, j = r * f + 3, c * f + 12
    a, b = 2 * (j - c * f + 0.5) / f - 1, 2 * (i - r * f + 0.5) / f - 1
    measured = _captured_direction(_scene(tmp_path, _marker(4 * f, 3 * f, (i, j)), fmt="cubeMapVerticalCross"))
    assert _angle(measured, direction(a, b)) < 1.0
