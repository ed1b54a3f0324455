"""Skip decisions for reflection probes: the SH-exp fit range comes from the materials in the influence volume."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import bakery
from bakery.pipeline.roughness import fit_alpha_range
from usd_scenes import header, write

ENV = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000"}


@pytest.mark.parametrize("roughness,expected", [
    ([0.9], (0.64, 0.81)),  # r ∈ [0.8, 0.9] after widening to one 0.1 step
    ([0.3, 0.9], (0.09, 0.81)),
    ([0.35, 0.62], (0.09, 0.49)),
    ([0.0], (0.0, 0.01)),  # the true range, down to a mirror (SH-exp applies its own fit floor, 0.05)
    ([0.05, 0.2], (0.0, 0.04)),
    ([], None),
])
def test_alpha_range_from_roughness(roughness, expected):
    result = fit_alpha_range(roughness)
    assert result == (pytest.approx(expected) if expected else None)


def _material(name, roughness):
    return f"""
def Material "{name}"
{{
    token outputs:surface.connect = </{name}/S.outputs:surface>
    def Shader "S"
    {{
        uniform token info:id = "UsdPreviewSurface"
        float inputs:roughness = {roughness}
        token outputs:surface
    }}
}}
"""


def _quad(name, material, centre, half):
    cx, cy, cz = centre
    pts = [(cx - half, cy, cz - half), (cx + half, cy, cz - half), (cx + half, cy, cz + half), (cx - half, cy, cz + half)]
    points = ", ".join(f"({x}, {y}, {z})" for x, y, z in pts)
    return f"""
def Mesh "{name}" (prepend apiSchemas = ["MaterialBindingAPI"])
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 3, 2, 1]
    point3f[] points = [{points}]
    rel material:binding = </{material}>
}}
"""


def _reflection_probe(name, position, radius):
    x, y, z = position
    return f"""
def BakeryReflectionProbe "{name}"
{{
    float bakery:influence:radius = {radius}
    double3 xformOp:translate = ({x}, {y}, {z})
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""


def test_reflection_probes_fit_the_roughness_they_can_see(tmp_path):
    # A rough floor patch (r = 0.9) under probe A; a glossy patch (r = 0.3) next to it under probe B, whose
    # influence also reaches the rough patch; probe C sees nothing and keeps the default range.
    text = (header() + _material("Rough", 0.9) + _material("Glossy", 0.3)
            + _quad("RoughFloor", "Rough", (0, 0, 0), 1.0) + _quad("GlossyFloor", "Glossy", (10, 0, 0), 1.0)
            + 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'
            + _reflection_probe("A", (0, 1, 0), 2.0) + _reflection_probe("B", (8, 1, 0), 8.0)
            + _reflection_probe("C", (100, 50, 100), 2.0))
    scene = write(tmp_path / "scene.usda", text)
    store = tmp_path / "s.h5"
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "bake", str(scene), "-o", str(store), "-e", "shexp",
                             "--face-size", "8", "-j", "1", "--json"], capture_output=True, text=True, env=ENV)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    s = bakery.open_store(store)
    ranges = dict(zip(s.probe_names, s.diagnostics["fit_alpha_range"]))
    np.testing.assert_allclose(ranges["/A"], [0.64, 0.81], rtol=1e-6)
    np.testing.assert_allclose(ranges["/B"], [0.09, 0.81], rtol=1e-6)
    assert np.all(np.isnan(ranges["/C"]))
    assert summary["skipped"] == []
    notes = json.loads(str(s.attributes["roughness_ranges"]))
    assert {note["probe"] for note in notes} == {"/A", "/B"}
    # Every probe is still evaluable at any α.
    values = s.evaluate_reflection("shexp", np.array([[0, 1.0, 0]]), np.array([[0, 1.0, 0]]), np.array([0.5]),
                                   np.array([1.0]))
    assert np.all(np.isfinite(values))


@pytest.mark.parametrize("gap_levels", [1, 2])
def test_a_mirror_probe_skips_the_hybrid_gap_level_its_materials_never_read(tmp_path, gap_levels):
    """With ``gap_level``, probe A sees a mirror and r = 0.4 (α ≥ 0.16 ≥ α_1 = 0.144 at face 16, the first kernel
    level): its gap levels (α_1/2, and α_1/4 with ``gap_levels`` = 2) are never read, so they are skipped (not
    uploaded); probe B sees a mirror and r = 0.12 (α ≈ 0.014 < α_1/4): kept."""
    from bakery.encodings.hybrid import SHExpHybrid

    text = (header() + _material("Mirror", 0.0) + _material("Satin", 0.4) + _material("Gloss", 0.12)
            + _quad("MirrorA", "Mirror", (0, 0, 0), 1.0) + _quad("SatinA", "Satin", (0, 0, 2), 1.0)
            + _quad("MirrorB", "Mirror", (20, 0, 0), 1.0) + _quad("GlossB", "Gloss", (20, 0, 2), 1.0)
            + 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'
            + _reflection_probe("A", (0, 1, 1), 3.0) + _reflection_probe("B", (20, 1, 1), 3.0))
    scene = write(tmp_path / "scene.usda", text)
    store_path = tmp_path / "s.h5"
    summary = bakery.bake(scene, store_path, encodings=("shexp_hybrid",), face_size=16, samples=1,
                          encoding_settings={"shexp_hybrid": {"gap_level": True, "gap_levels": gap_levels}})
    store = bakery.open_store(store_path)
    fields = store.fields("shexp_hybrid")
    by_probe = dict(zip(store.probe_names, np.asarray(fields["gap_skipped"]).reshape(-1).tolist(), strict=True))
    assert by_probe == {"/A": gap_levels, "/B": 0}
    assert np.asarray(fields["first_level"]).reshape(-1).tolist() == [0, 0]
    encoding = SHExpHybrid(**store.encodings["shexp_hybrid"].settings)
    upload = dict(zip(store.probe_names, encoding.upload_bytes(fields).tolist(), strict=True))
    assert upload["/B"] - upload["/A"] == gap_levels * 6 * 16 * 16 * 3 * 2  # the gap levels at the capture's face
    from pxr import Usd  # the layer an engine imports holds each probe's upload: A's has no gap level

    stage = Usd.Stage.Open(summary.layer)
    for k in range(1, gap_levels + 2):
        attribute = f"bakery:reflection:shexp_hybrid:level{k}"  # (the schema declares them)
        assert stage.GetPrimAtPath("/A").GetAttribute(attribute).HasAuthoredValue() == (k > gap_levels)
        assert stage.GetPrimAtPath("/B").GetAttribute(attribute).HasAuthoredValue()
    assert stage.GetPrimAtPath("/A").GetAttribute("bakery:reflection:shexp_hybrid:gap_skipped").Get() == [gap_levels]
