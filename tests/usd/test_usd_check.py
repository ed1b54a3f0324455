"""Broken inputs give clear per-prim errors or warnings, ``bake_scene`` refuses untrustworthy scenes, and
``bakery check`` exits non-zero on errors. Fixtures: one clean scene and one small bad scene per problem."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from usd_scenes import box_mesh, header, material, probe, write

import bakery
from bakery.errors import CHECK_FAILED_EXIT_CODE, SceneError
from bakery.usd.check import check_exit_code, check_scene

CLEAN = (header() + material("M", diffuse=(0.5, 0.5, 0.5)) + box_mesh("Box", 1.0, "/M") + probe("P", (0, 3, 0))
         + 'def SphereLight "Lamp"\n{\n    float inputs:radius = 0.1\n    double3 xformOp:translate = (0, 5, 0)\n'
         '    uniform token[] xformOpOrder = ["xformOp:translate"]\n}\n')

BAD = {
    "missing_material_texture": (
        header() + material("M", extra="""
    def Shader "Tex"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @./does_not_exist.png@
        float3 outputs:rgb
    }
""").replace("color3f inputs:diffuseColor = (0.18, 0.18, 0.18)",
             "color3f inputs:diffuseColor = (0.3, 0.3, 0.3)\n        color3f inputs:diffuseColor.connect = "
             "</M/Tex.outputs:rgb>") + box_mesh("Box", 1.0, "/M") + probe("P", (0, 3, 0)),
        "warning", "/M/Tex", "not found",
    ),
    "missing_dome_texture": (
        header() + 'def DomeLight "Sky"\n{\n    asset inputs:texture:file = @./nowhere.hdr@\n}\n' + probe("P"),
        "error", "/Sky", "not found",
    ),
    "unknown_probe_type": (
        header() + probe("P") + 'def LightProbe "Mystery"\n{\n}\n',
        "error", "/Mystery", "unknown probe type",
    ),
    "non_invertible_transform": (
        header() + """
def BakeryIrradianceProbe "Flat"
{
    float3 xformOp:scale = (1, 0, 1)
    uniform token[] xformOpOrder = ["xformOp:scale"]
}
""" + probe("P"),
        "error", "/Flat", "non-invertible",
    ),
    "materialx_only_material": (
        header() + """
def Material "Mx"
{
    token outputs:mtlx:surface.connect = </Mx/Surf.outputs:out>
    def Shader "Surf"
    {
        uniform token info:id = "ND_disney_principled_surfaceshader"
        color3f inputs:baseColor = (0.8, 0.1, 0.1)
        token outputs:out
    }
}
""" + box_mesh("Box", 1.0, "/Mx") + probe("P", (0, 3, 0)),
        "warning", "/Mx", "MaterialX-only",
    ),
    "empty_scene": (header(), "error", "/", "no probes"),
    "nothing_emits": (
        header() + material("M", diffuse=(0.5, 0.5, 0.5)) + box_mesh("Box", 1.0, "/M") + probe("P", (0, 3, 0)),
        "warning", "/", "every probe will be black",
    ),
    "unknown_encoding": (
        header() + probe("P", body='uniform token[] bakery:encodings = ["sh99"]'),
        "error", "/P", "unknown encoding",
    ),
    "negative_influence_radius": (  # would silently select no material: a sharp mirror baked as rough
        header() + probe("P", type_name="BakeryReflectionProbe", body="float bakery:influence:radius = -3"),
        "error", "/P", "bakery:influence:radius must be finite and >= 0",
    ),
    "nan_influence_extent": (
        header() + probe("P", type_name="BakeryReflectionProbe",
                         body="float3 bakery:influence:extent = (1, nan, 1)"),
        "error", "/P", "bakery:influence:extent must be finite and >= 0",
    ),
    "bad_influence_shape": (
        header() + probe("P", type_name="BakeryReflectionProbe",
                         body='uniform token bakery:influence:shape = "cone"'),
        "error", "/P", "influence:shape",
    ),
}


def test_clean_scene_has_no_issues(tmp_path):
    issues = check_scene(write(tmp_path / "clean.usda", CLEAN))
    assert issues == []
    assert check_exit_code(issues) == 0


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_scene_reports_per_prim(tmp_path, case):
    text, severity, prim, words = BAD[case]
    issues = check_scene(write(tmp_path / f"{case}.usda", text))
    matching = [i for i in issues if i.prim == prim and words in i.message]
    assert matching, f"expected a {severity} on {prim} mentioning {words!r}, got {issues}"
    assert matching[0].severity == severity
    assert check_exit_code(issues) == (CHECK_FAILED_EXIT_CODE if severity == "error" else 0)


@pytest.mark.parametrize("case", [c for c in sorted(BAD) if BAD[c][1] == "error"])
def test_bake_refuses_scenes_with_errors(tmp_path, case):
    text, _, prim, _ = BAD[case]
    path = write(tmp_path / f"{case}.usda", text)
    with pytest.raises(SceneError, match=prim if prim != "/" else "no probes"):
        bakery.bake(path, tmp_path / "out.h5", face_size=8, samples=1)
    assert not (tmp_path / "out.h5").exists()


def test_unopenable_scene_is_one_error(tmp_path):
    path = write(tmp_path / "broken.usda", "#usda 1.0\ndef Xform {{{ nonsense\n")
    issues = check_scene(path)
    assert len(issues) == 1 and issues[0].severity == "error" and issues[0].prim == "/"
    assert check_scene(tmp_path / "missing.usda")[0].severity == "error"


def test_cli_check_exit_codes(tmp_path):
    clean = write(tmp_path / "clean.usda", CLEAN)
    bad = write(tmp_path / "bad.usda", BAD["unknown_probe_type"][0])
    ok = subprocess.run([sys.executable, "-m", "bakery.cli", "check", str(clean)], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    failed = subprocess.run([sys.executable, "-m", "bakery.cli", "check", str(bad)], capture_output=True, text=True)
    assert failed.returncode != 0
    assert "/Mystery" in failed.stdout
    # each issue on a line of its own, file: severity: prim: message (grep- and editor-friendly, as compilers)
    issue_lines = [line for line in failed.stdout.splitlines() if "/Mystery" in line]
    assert issue_lines and all(line.startswith(f"{bad}: error: /Mystery: ") for line in issue_lines), failed.stdout


def test_check_names_the_sublayer_that_defines_a_prim(tmp_path):
    """A scene of sublayers: an issue on a prim defined in a sublayer names that file (the one to open), an issue on
    a prim of the root layer names the scene; over-only opinions in the root do not move it."""
    sub = write(tmp_path / "props.usda", header() + 'def LightProbe "Mystery"\n{\n}\n')
    root = write(tmp_path / "shot.usda", header(extra=f"    subLayers = [@./{sub.name}@]\n") + probe("P")
                 + 'def LightProbe "Local"\n{\n}\nover "Mystery"\n{\n}\n')
    issues = {i.prim: i for i in check_scene(root)}
    assert Path(issues["/Mystery"].layer).resolve() == sub.resolve() and issues["/Local"].layer == ""
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "check", str(root)], capture_output=True, text=True)
    lines = result.stdout.splitlines()
    assert any(line.startswith(f"{sub.resolve()}: error: /Mystery: ") for line in lines), result.stdout
    assert any(line.startswith(f"{root}: error: /Local: ") for line in lines), result.stdout
    # the bake refuses the same scene and names the same files, one line per error (check and bake never disagree)
    baked = subprocess.run([sys.executable, "-m", "bakery.cli", "bake", str(root), "-o", str(tmp_path / "out.h5")],
                           capture_output=True, text=True)
    assert baked.returncode != 0 and "Traceback" not in baked.stderr and not (tmp_path / "out.h5").exists()
    assert f"  {sub.resolve()}: error: /Mystery: " in baked.stderr, baked.stderr
    assert f"  {root}: error: /Local: " in baked.stderr, baked.stderr


def test_composition_errors_are_errors_in_check_and_bake(tmp_path):
    """A sublayer that fails to parse, a missing sublayer and a missing reference silently drop their contents from
    a stage; check reports each as an error (not just a pxr warning on stderr) and the bake refuses."""
    write(tmp_path / "broken.usda", "#usda 1.0\ndef Xform {{{ nonsense\n")
    text = header(extra='    subLayers = [@./broken.usda@, @./gone.usda@]\n') + probe("P") + """
def Xform "Asset" (
    references = @./nothere.usda@
)
{
}
"""
    path = write(tmp_path / "root.usda", text)
    issues = check_scene(path)
    errors = [i for i in issues if i.severity == "error"]
    assert any("broken.usda" in i.message and i.prim == "/" for i in errors)
    assert any("gone.usda" in i.message for i in errors)
    assert any("nothere.usda" in i.message and i.prim == "/Asset" for i in errors)
    assert check_exit_code(issues) == CHECK_FAILED_EXIT_CODE
    with pytest.raises(SceneError, match="composition"):
        bakery.bake(path, tmp_path / "out.h5", face_size=8, samples=1)
    # on the command line each is one line naming its prim; usd-core's own multi-line prints of them are dropped
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "check", str(path)], capture_output=True, text=True)
    assert result.returncode == CHECK_FAILED_EXIT_CODE and "nothere.usda" in result.stdout + result.stderr
    assert "_ReportErrors" not in result.stderr, result.stderr


def test_check_reports_what_a_bake_would_silently_change(tmp_path):
    """Textures read at the primvar reader's fallback st (no texture coordinates), float textures without colour
    space, subdivision surfaces baked as their cage, unsupported light types: warnings, per prim."""
    import numpy as np
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(tmp_path / "f.exr"))
    assert out.open(str(tmp_path / "f.exr"), oiio.ImageSpec(2, 2, 3, oiio.FLOAT))
    out.write_image(np.ones((2, 2, 3), dtype=np.float32))
    out.close()
    tex = """
    def Shader "Tex"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @./f.exr@
        float3 outputs:rgb
    }
"""
    text = header() + material("M", extra=tex).replace(
        "color3f inputs:diffuseColor = (0.18, 0.18, 0.18)", "color3f inputs:diffuseColor.connect = </M/Tex.outputs:rgb>")
    text += box_mesh("Box", 1.0, "/M").replace("rel material:binding", 'uniform token subdivisionScheme = "catmullClark"\n'
                                               '    rel material:binding')
    text += 'def PluginLight "Custom"\n{\n}\n' + probe("P", (0, 3, 0))
    issues = check_scene(write(tmp_path / "silent.usda", text))
    messages = {(i.prim, i.message) for i in issues}
    assert check_exit_code(issues) == 0
    assert any(p == "/Box" and "fallback st (0, 0)" in m for p, m in messages)
    assert any(p == "/Box" and "control cage" in m for p, m in messages)
    assert any(p == "/M/Tex" and "colour-space" in m for p, m in messages)
    assert any(p == "/Custom" and "not supported" in m for p, m in messages)


@pytest.mark.parametrize("emitter", ["emissive_material", "dome"])
def test_a_scene_lit_only_by_emission_or_a_dome_is_not_called_black(tmp_path, emitter):
    """The black-scene warning is about what emits: an emissive surface or a dome alone lights the probes."""
    if emitter == "emissive_material":
        text = header() + material("M", emissive=(2.0, 2.0, 2.0)) + box_mesh("Box", 1.0, "/M")
    else:
        text = header() + 'def DomeLight "Sky"\n{\n}\n'
    issues = check_scene(write(tmp_path / f"{emitter}.usda", text + probe("P", (0, 3, 0))))
    assert not [i for i in issues if "black" in i.message], issues
