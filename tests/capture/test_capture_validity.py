"""Probe validity: the share of a probe's camera rays whose first hit is the back of a single-sided surface
(``CaptureStats.backface_fraction``; Majercik et al. 2021, Sec. 4). Closed forms: 1 inside a closed, outward-wound
mesh or gprim (also under a mirroring transform, which USD's winding rule follows, and inside a left-handed
implicit gprim, which has no winding); 0 outside it, inside a ``doubleSided`` one, or inside a left-handed Mesh; 5/6
exactly at the centre of a box without one face (each cube face of the probe sees one box face); a bake names the
probes ≥ 25 % in one warning and stores the fractions."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest
from usd_scenes import box_mesh, header, material, probe, write

import bakery
from bakery.capture import capture_probes
from bakery.errors import SceneWarning
from bakery.usd.scene import read_scene

DOME = 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'
GREY = material("Grey", diffuse=(0.5, 0.5, 0.5), diffuse_only=True)


def _fractions(tmp_path, text: str) -> tuple[float, ...]:
    reading = read_scene(write(tmp_path / "scene.usda", text))
    assert not reading.errors, reading.errors
    _cubes, report = capture_probes(reading.scene, 8, samples=2, bounces=0)
    return report.backface_fraction


def _gprim(kind: str, extra: str = "", scale: str = "(1, 1, 1)") -> str:
    size = "double radius = 1" if kind == "Sphere" else "double size = 2"
    return f"""
def {kind} "Shape" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    {size}
    {extra}
    rel material:binding = </Grey>
    float3 xformOp:scale = {scale}
    uniform token[] xformOpOrder = ["xformOp:scale"]
}}
"""


@pytest.mark.parametrize("kind", ["Cube", "Sphere"])
def test_inside_a_closed_gprim_every_ray_sees_a_back_face(tmp_path, kind):
    inside, outside = _fractions(tmp_path, header() + DOME + GREY + _gprim(kind)
                                 + probe("In", (0.1, 0.2, -0.1)) + probe("Out", (0.0, 0.0, 3.0)))
    assert inside == 1.0
    assert outside == 0.0  # it sees the shape's front and the sky


def test_a_mirroring_transform_keeps_the_outside_the_front(tmp_path):
    """scale (−1, 1, 1) reverses the winding in world space; USD (and Hydra) flip the orientation with it."""
    (inside,) = _fractions(tmp_path, header() + DOME + GREY + _gprim("Cube", scale="(-1, 1, 1)")
                           + probe("In", (0.1, 0.2, -0.1)))
    assert inside == 1.0


def test_double_sided_gprims_have_no_back_face_inside(tmp_path):
    (inside,) = _fractions(tmp_path, header() + DOME + GREY + _gprim("Cube", "uniform bool doubleSided = 1")
                           + probe("In", (0.1, 0.2, -0.1)))
    assert inside == 0.0


def test_left_handed_meshes_flip_but_implicit_gprims_keep_their_outside(tmp_path):
    """UsdGeom applies the winding rule (and ``orientation``) "for all non-implicit surface and solid types"
    (usdGeom/overview.dox); Hydra meshes a Cube rightHanded whatever its orientation. A left-handed box Mesh wound
    outward is seen from the inside as its front."""
    (cube,) = _fractions(tmp_path, header() + DOME + GREY + _gprim("Cube", 'uniform token orientation = "leftHanded"')
                         + probe("In", (0.1, 0.2, -0.1)))
    assert cube == 1.0
    box = box_mesh("Box", 1.0, "/Grey").replace("rel material:binding", 'uniform token orientation = "leftHanded"\n'
                                                   "    rel material:binding")
    (mesh,) = _fractions(tmp_path, header() + DOME + GREY + box + probe("In", (0.1, 0.2, -0.1)))
    assert mesh == 0.0


def test_a_box_without_one_face_gives_five_sixths(tmp_path):
    """An outward-wound box Mesh without its +Y face, the probe at its centre: the probe's −X, +X, −Y, ±Z cube
    faces see box faces from behind, the +Y face the sky: 5/6 of the rays, exactly."""
    box = box_mesh("Box", 1.0, "/Grey")
    open_top = box.replace("[4, 4, 4, 4, 4, 4]", "[4, 4, 4, 4, 4]").replace("2, 3, 7, 6,  ", "")
    assert open_top != box
    (centre,) = _fractions(tmp_path, header() + DOME + GREY + open_top + probe("P", (0.0, 0.0, 0.0)))
    assert centre == pytest.approx(5 / 6, abs=1e-12)


def test_a_bake_names_the_probes_inside_geometry_and_stores_the_fractions(tmp_path):
    text = (header() + DOME + GREY + _gprim("Cube") + probe("Inside", (0.1, 0.2, -0.1))
            + probe("Outside", (0.0, 0.0, 3.0)))
    scene = write(tmp_path / "scene.usda", text)
    with pytest.warns(SceneWarning, match=r"1 of 2 probes are likely inside geometry.*/Inside\b"):
        bakery.bake(scene, tmp_path / "scene.h5", encodings=("sh2",), face_size=8, samples=1)
    store = bakery.open_store(tmp_path / "scene.h5")
    fraction = dict(zip(store.probe_names, store.diagnostics["capture/backface_fraction"].tolist()))
    assert fraction == {"/Inside": 1.0, "/Outside": 0.0}
    assert any("inside geometry" in w for w in json.loads(store.attributes["warnings"]))
    from pxr import Usd  # the baked layer carries the fractions for engines (bakery:baked:backfaceFraction)

    layer = Usd.Stage.Open(str(tmp_path / "scene.bake.usda"))
    for name, expected in fraction.items():
        assert list(layer.GetPrimAtPath(name).GetAttribute("bakery:baked:backfaceFraction").Get()) == [expected]


def test_inspect_and_report_list_the_probes_inside_geometry(tmp_path):
    from bakery.report.build import build_report

    text = (header() + DOME + GREY + _gprim("Cube") + probe("Inside", (0.1, 0.2, -0.1))
            + probe("Outside", (0.0, 0.0, 3.0)))
    scene = write(tmp_path / "scene.usda", text)
    with pytest.warns(SceneWarning):
        bakery.bake(scene, tmp_path / "scene.h5", encodings=("sh2",), face_size=8, samples=1)
    data, html = build_report(tmp_path / "scene.h5", previews=False)
    validity = data["capture_validity"]
    assert validity["threshold"] == 0.25 and validity["inside_count"] == 1
    assert validity["inside"] == [{"probe": "/Inside", "backface_fraction": 1.0, "dilated_from": 0}]
    assert "Probe validity" in html and "/Inside" in html
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "inspect", str(tmp_path / "scene.h5")],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "validity: 1 probe likely inside geometry" in result.stdout and "/Inside" in result.stdout


def _hall(relocate: str = "") -> str:
    """Three probes 2 m apart along X (a volume), the middle one inside a closed 1 m cube under a uniform sky."""
    return header() + DOME + GREY + _gprim("Cube").replace("double size = 2", "double size = 1") + f"""
def BakeryIrradianceProbeVolume "Row"
{{
    float3 bakery:volume:extent = (2, 0, 0)
    int3 bakery:volume:counts = (3, 1, 1)
    {relocate}
}}
"""


def test_relocation_captures_a_probe_inside_geometry_from_just_outside_it(tmp_path):
    """bakery:volume:relocate: the middle probe (inside the cube) is captured from past the nearest face it sees
    from behind — within the search radius (half the 2 m spacing) plus the margin — where nothing is a back face;
    the capture is the one a probe placed there gets. The others do not move."""
    from bakery.capture import ProbeRenderer
    from bakery.capture.validity import RELOCATION_MARGIN

    reading = read_scene(write(tmp_path / "scene.usda", _hall("bool bakery:volume:relocate = 1")))
    assert not reading.errors, reading.errors
    assert [p.relocate for p in reading.scene.probes] == [1.0, 1.0, 1.0]
    renderer = ProbeRenderer(reading.scene, samples=2, bounces=1)
    positions = [np.asarray(p.position) for p in reading.scene.probes]
    names = [p.name for p in reading.scene.probes]
    rendered = renderer.render_many(positions, 8, names, [1.0] * 3)
    offsets = [np.asarray(stats.offset) for _cube, stats in rendered]
    assert np.all(offsets[0] == 0) and np.all(offsets[2] == 0)
    moved = positions[1] + offsets[1]
    assert np.max(np.abs(moved)) > 0.5  # outside the cube
    assert 0.5 < np.linalg.norm(offsets[1]) <= 0.5 * np.sqrt(3) + RELOCATION_MARGIN * 1.0 + 1e-6
    assert [stats.backface_fraction for _cube, stats in rendered] == [0.0, 0.0, 0.0]
    cube, _stats = ProbeRenderer(reading.scene, samples=2, bounces=1).render(moved, 8, names[1])
    np.testing.assert_array_equal(rendered[1][0], cube)


def test_without_relocation_the_probe_inside_is_reported_and_a_bake_records_offsets(tmp_path):
    scene = write(tmp_path / "plain.usda", _hall())
    with pytest.warns(SceneWarning, match=r"1 of 3 probes are likely inside geometry.*/Row\[1,0,0\]"):
        bakery.bake(scene, tmp_path / "plain.h5", encodings=("sh2",), face_size=8, samples=1)
    moved = write(tmp_path / "moved.usda", _hall("bool bakery:volume:relocate = 1"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)  # relocated: nothing is inside geometry any more
        bakery.bake(moved, tmp_path / "moved.h5", encodings=("sh2",), face_size=8, samples=1)
    store = bakery.open_store(tmp_path / "moved.h5")
    offset = np.asarray(store.diagnostics["capture/offset"])
    assert offset.shape == (3, 3) and np.all(offset[[0, 2]] == 0) and np.linalg.norm(offset[1]) > 0.5
    assert np.all(np.asarray(store.diagnostics["capture/backface_fraction"]) == 0)


def test_check_reports_probes_inside_geometry_before_a_bake(tmp_path):
    from bakery.usd.check import check_exit_code, check_scene

    text = _hall() + probe("Inside", (0.1, 0.2, -0.1)) + probe("Outside", (0.0, 0.0, 3.0))
    issues = [i for i in check_scene(write(tmp_path / "scene.usda", text)) if "inside geometry" in i.message]
    assert {i.prim for i in issues} == {"/Inside", "/Row"}
    assert all(i.severity == "warning" for i in issues) and check_exit_code(issues) == 0
    assert "1 of its probes" in next(i.message for i in issues if i.prim == "/Row") and "/Row[1,0,0]" in \
        next(i.message for i in issues if i.prim == "/Row")
    relocating = write(tmp_path / "relocating.usda", _hall("bool bakery:volume:relocate = 1"))
    (row,) = [i for i in check_scene(relocating) if "inside geometry" in i.message]
    assert "the bake relocates them" in row.message


def test_a_probe_relocation_cannot_free_is_reported_as_such(tmp_path):
    """A 6 m cube around a whole relocating row: no point outside lies within half the 2 m spacing of any probe,
    so they stay inside, and the warning says relocation found none (rather than advising to turn it on)."""
    text = _hall("bool bakery:volume:relocate = 1").replace("double size = 1", "double size = 6")
    with pytest.warns(SceneWarning, match=r"likely inside geometry.*/Row\[1,0,0\].*Relocation \(bakery:volume:"
                                          r"relocate\) found no point outside") as record:
        bakery.bake(write(tmp_path / "deep.usda", text), tmp_path / "deep.h5", encodings=("sh2",), face_size=8,
                    samples=1)
    assert not any("set bakery:volume:relocate" in str(w.message) for w in record)
