"""Wrongly typed, non-finite and out-of-range attributes are per-prim errors naming the prim and the attribute — in
``bakery check`` (exit 5) and in the bake (one line per prim, non-zero exit, nothing written) — never a Python or pxr
traceback, never silently read (``string bakery:volume:relocate = "no"`` is not "on", ``int`` 2.5 is not 2).

The expected types are the ones the schemas declare: bakery's probe schema (``bakery/usd/schema/generatedSchema.usda``),
UsdLux and UsdGeom; floating-point precision aside (a ``double`` authored for a ``float`` reads the same)."""

from __future__ import annotations

import subprocess
import sys
import warnings

import pytest
from pxr import Sdf, Usd
from usd_scenes import header, probe, write

import bakery
from bakery.errors import CHECK_FAILED_EXIT_CODE, SceneError
from bakery.usd.check import check_exit_code, check_scene
from bakery.usd.plugin import FALLBACKS, PROBE_TYPES
from bakery.usd.scene import MAX_CAPTURE_RESOLUTION, _probe_schema_types, read_scene

R, I, V = "BakeryReflectionProbe", "BakeryIrradianceProbe", "BakeryIrradianceProbeVolume"


def light(name: str = "Lamp", body: str = "float inputs:intensity = 1", translate: str = "(0, 5, 0)",
          type_name: str = "SphereLight") -> str:
    return (f'def {type_name} "{name}"\n{{\n    {body}\n    double3 xformOp:translate = {translate}\n'
            '    uniform token[] xformOpOrder = ["xformOp:translate"]\n}\n')


def mesh(name: str = "M", points: str = "point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 0, 1)]",
         extra: str = "") -> str:
    return (f'def Mesh "{name}"\n{{\n    int[] faceVertexCounts = [3]\n    int[] faceVertexIndices = [0, 1, 2]\n'
            f'    {points}\n    {extra}\n}}\n')


def scene(body: str) -> str:
    """``body`` in a scene that is otherwise clean: a lamp and a valid probe."""
    return header() + light() + probe("Good", (0, 2, 0)) + body


def bad_probe(type_name: str, body: str) -> str:
    return probe("P", (0, 1, 0), type_name=type_name, body=body)


STRING_TRANSLATE = 'string xformOp:translate = "x"\n    uniform token[] xformOpOrder = ["xformOp:translate"]'

#: case: (scene, prim, attribute, authored type, expected type)
WRONG_TYPES = {
    "influence_radius_string": (bad_probe(R, 'string bakery:influence:radius = "big"'),
                                "/P", "bakery:influence:radius", "string", "float"),
    "irradiance_radius_string": (bad_probe(I, 'string bakery:influence:radius = "big"'),
                                 "/P", "bakery:influence:radius", "string", "float"),
    "influence_extent_float": (bad_probe(R, "float bakery:influence:extent = 3"),  # was broadcast or a TypeError
                               "/P", "bakery:influence:extent", "float", "float3"),
    "influence_extent_string": (bad_probe(R, 'string bakery:influence:extent = "3"'),
                                "/P", "bakery:influence:extent", "string", "float3"),
    "resolution_string": (bad_probe(I, 'string bakery:capture:resolution = "8"'),
                          "/P", "bakery:capture:resolution", "string", "int"),
    "resolution_float": (bad_probe(I, "float bakery:capture:resolution = 2.5"),  # was truncated to 2
                         "/P", "bakery:capture:resolution", "float", "int"),
    "encodings_int": (bad_probe(I, "int bakery:encodings = 3"), "/P", "bakery:encodings", "int", "token[]"),
    "image_string": (bad_probe(I, 'string bakery:capture:image = "sky.hdr"'),  # was ignored: the probe rendered
                     "/P", "bakery:capture:image", "string", "asset"),
    "volume_extent_string": (bad_probe(V, 'string bakery:volume:extent = "1"'),
                             "/P", "bakery:volume:extent", "string", "float3"),
    "volume_extent_scalar": (bad_probe(V, "float bakery:volume:extent = 2"),  # was broadcast
                             "/P", "bakery:volume:extent", "float", "float3"),
    "volume_counts_string": (bad_probe(V, 'string bakery:volume:counts = "2"'),
                             "/P", "bakery:volume:counts", "string", "int3"),
    "volume_counts_float3": (bad_probe(V, "float3 bakery:volume:counts = (2.7, 2, 2)"),  # was truncated
                             "/P", "bakery:volume:counts", "float3", "int3"),
    "volume_relocate_string": (bad_probe(V, 'string bakery:volume:relocate = "no"'),  # was on: bool("no")
                               "/P", "bakery:volume:relocate", "string", "bool"),
    "volume_dilate_string": (bad_probe(V, 'string bakery:volume:dilate = "no"'),
                             "/P", "bakery:volume:dilate", "string", "bool"),
    "dilation_distance_string": (bad_probe(V, 'bool bakery:volume:dilate = 1\n    string '
                                              'bakery:volume:dilationDistance = "far"'),
                                 "/P", "bakery:volume:dilationDistance", "string", "float"),
    "probe_translate_string": (f'def BakeryIrradianceProbe "P"\n{{\n    {STRING_TRANSLATE}\n}}\n',
                               "/P", "xformOp:translate", "string", "double3, float3 or half3"),
    "mesh_translate_string": (mesh(extra=STRING_TRANSLATE), "/M", "xformOp:translate", "string", "double3"),
    "ancestor_translate_string": (f'def Xform "G"\n{{\n    {STRING_TRANSLATE}\n' + mesh() + "}\n",
                                  "/G/M", "xformOp:translate of /G", "string", "double3"),
    "mesh_points_string": (mesh(points='string points = "x"'), "/M", "points", "string", "point3f[]"),
    "mesh_counts_float": (mesh().replace("int[] faceVertexCounts", "float[] faceVertexCounts"),
                          "/M", "faceVertexCounts", "float[]", "int[]"),
    "light_intensity_string": (light("L", 'string inputs:intensity = "x"'), "/L", "inputs:intensity", "string",
                               "float"),
    "legacy_light_intensity_string": (light("L", 'string intensity = "x"'), "/L", "intensity", "string", "float"),
    "light_normalize_string": (light("L", 'string inputs:normalize = "no"'), "/L", "inputs:normalize", "string",
                               "bool"),
    "dome_texture_string": ('def DomeLight "D"\n{\n    string inputs:texture:file = "sky.hdr"\n}\n',
                            "/D", "inputs:texture:file", "string", "asset"),
    "sphere_radius_string": ('def Sphere "S"\n{\n    string radius = "x"\n}\n', "/S", "radius", "string", "double"),
    "instancer_positions_string": ("""
def PointInstancer "PI"
{
    string positions = "x"
    int[] protoIndices = [0, 0]
    rel prototypes = [</PI/Protos/Ball>]
    def Scope "Protos"
    {
        def Sphere "Ball"
        {
        }
    }
}
""", "/PI", "positions", "string", "point3f[]"),
}

#: case: (scene, prim, words of the error)
BAD_VALUES = {
    "volume_extent_nan": (bad_probe(V, "float3 bakery:volume:extent = (1, nan, 1)"),
                          "/P", "bakery:volume:extent must be finite and >= 0"),
    "volume_extent_inf": (bad_probe(V, "float3 bakery:volume:extent = (1, inf, 1)"),
                          "/P", "bakery:volume:extent must be finite and >= 0"),
    "dilation_distance_inf": (bad_probe(V, "bool bakery:volume:dilate = 1\n    float bakery:volume:dilationDistance "
                                           "= inf"), "/P", "bakery:volume:dilationDistance must be a finite"),
    "influence_radius_inf": (bad_probe(R, "float bakery:influence:radius = inf"),
                             "/P", "bakery:influence:radius must be finite"),
    "resolution_too_large": (bad_probe(I, "int bakery:capture:resolution = 100000"),  # 74.5 GiB of cube maps
                             "/P", f"bakery:capture:resolution must be >= 0 (0: the bake's face size) and <= "
                                   f"{MAX_CAPTURE_RESOLUTION}"),
    "resolution_negative": (bad_probe(I, "int bakery:capture:resolution = -1"), "/P", "bakery:capture:resolution"),
    "probe_translate_nan": (probe("P", (0, float("nan"), 0)), "/P", "world transform is not finite"),
    "probe_translate_inf": (probe("P", (0, float("inf"), 0)), "/P", "world transform is not finite"),
    "light_translate_inf": (light("L", translate="(0, inf, 0)"), "/L", "world transform is not finite"),
    "mesh_translate_nan": (mesh(extra='double3 xformOp:translate = (0, nan, 0)\n    uniform token[] xformOpOrder = '
                                      '["xformOp:translate"]'), "/M", "world transform is not finite"),
    "instancer_positions_short": ("""
def PointInstancer "PI"
{
    point3f[] positions = [(0, 0, 0)]
    int[] protoIndices = [0, 0]
    rel prototypes = [</PI/Protos/Ball>]
    def Scope "Protos"
    {
        def Sphere "Ball"
        {
        }
    }
}
""", "/PI", "need one value per protoIndices entry"),
    # USD computes an unknown visibility token as visible: a typo showed geometry meant to be hidden
    "visibility_unknown_token": (mesh(extra='token visibility = "hidden"'), "/M", "visibility is 'hidden'"),
    "purpose_unknown_token": (mesh(extra='token purpose = "guides"'), "/M", "expected one of default, render"),
}


def _errors_on(issues, prim: str) -> list:
    return [i for i in issues if i.severity == "error" and i.prim == prim]


@pytest.mark.parametrize("case", sorted(WRONG_TYPES))
def test_wrongly_typed_attribute_is_an_error_naming_prim_attribute_and_types(tmp_path, case):
    text, prim, attribute, authored, expected = WRONG_TYPES[case]
    issues = check_scene(write(tmp_path / f"{case}.usda", scene(text)))
    errors = _errors_on(issues, prim)
    assert errors, f"expected an error on {prim}, got {issues}"
    message = errors[0].message
    assert f"{attribute} is authored as {authored}" in message and f"expected {expected}" in message, message
    assert check_exit_code(issues) == CHECK_FAILED_EXIT_CODE
    assert not [i for i in issues if i.severity == "error" and i.prim != prim], issues  # nothing else is blamed


@pytest.mark.parametrize("case", sorted(BAD_VALUES))
def test_non_finite_or_out_of_range_value_is_an_error_without_numpy_warnings(tmp_path, case):
    text, prim, words = BAD_VALUES[case]
    path = write(tmp_path / f"{case}.usda", scene(text))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        issues = read_scene(path, load_textures=False).issues
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    errors = _errors_on(issues, prim)
    assert errors and words in errors[0].message, f"expected an error on {prim} with {words!r}, got {issues}"


@pytest.mark.parametrize("case", ["influence_radius_string", "volume_relocate_string", "probe_translate_string",
                                  "mesh_points_string", "light_intensity_string", "resolution_too_large",
                                  "volume_extent_nan"])
def test_bake_refuses_naming_prim_and_attribute(tmp_path, case):
    text, prim, attribute = (WRONG_TYPES[case][:3] if case in WRONG_TYPES else BAD_VALUES[case])
    attribute = attribute.split(" must ")[0]
    path = write(tmp_path / f"{case}.usda", scene(text))
    with pytest.raises(SceneError) as raised:
        bakery.bake(path, tmp_path / "out.h5", face_size=8, samples=1)
    assert any(prim in line and attribute in line for line in str(raised.value).splitlines()), str(raised.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{case}.usda"]  # no store, no layer


@pytest.mark.parametrize("command", [["check"], ["bake", "--face-size", "8", "--samples", "1"],
                                     ["bake", "--dry-run", "--face-size", "8"], ["plan", "--face-size", "8"]])
def test_cli_reports_wrong_types_without_traceback(tmp_path, command):
    bodies = [WRONG_TYPES[c][0] for c in ("influence_radius_string", "mesh_points_string", "light_intensity_string")]
    path = write(tmp_path / "typed.usda", scene("".join(bodies)))
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "out.h5"
    args = [sys.executable, "-m", "bakery.cli", *command, str(path)]
    args += [] if command == ["check"] else ["-o", str(out)]
    result = subprocess.run(args, capture_output=True, text=True, timeout=300)
    text = result.stdout + result.stderr
    assert "Traceback" not in text and "Error in '" not in text, text
    assert result.returncode == (CHECK_FAILED_EXIT_CODE if command == ["check"] else 2), text
    lines = text.splitlines()
    for prim, attribute in (("/P", "bakery:influence:radius"), ("/M", "points"), ("/L", "inputs:intensity")):
        assert any(prim in line and attribute in line and "expected" in line for line in lines), text
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written, nothing changed


def test_directory_is_reported_as_a_directory(tmp_path):
    folder = tmp_path / "scene.usda"
    folder.mkdir()
    issues = check_scene(folder)
    assert len(issues) == 1 and issues[0].severity == "error" and "is a directory" in issues[0].message
    with pytest.raises(SceneError, match="is a directory"):
        read_scene(folder)


def test_other_precisions_and_bounds_are_accepted(tmp_path):
    """Types that differ from the declared ones only in floating-point precision or role read as before; the
    resolution bounds themselves are valid."""
    text = (header() + light("L", "double inputs:intensity = 2\n    double3 inputs:color = (1, 0.5, 0.5)")
            + light("Legacy", "float intensity = 2", translate="(1, 5, 0)")
            + mesh(points="double3[] points = [(0, 0, 0), (1, 0, 0), (0, 0, 1)]")
            + 'def Sphere "S"\n{\n    float radius = 0.5\n    double3 xformOp:translate = (3, 0, 0)\n'
              '    uniform token[] xformOpOrder = ["xformOp:translate"]\n}\n'
            + probe("Zero", (0, 1, 0), body="int bakery:capture:resolution = 0")
            + probe("Max", (0, 2, 0), body=f"int bakery:capture:resolution = {MAX_CAPTURE_RESOLUTION}")
            + probe("Vol", (0, 3, 0), type_name=V, body="double3 bakery:volume:extent = (1, 1, 1)\n"
                    '    bool bakery:volume:relocate = 1\n    uniform string[] bakery:encodings = ["sh2"]')
            + probe("Refl", (0, 4, 0), type_name=R, body='uniform token bakery:influence:shape = "box"\n'
                    "    vector3f bakery:influence:extent = (1, 2, 3)"))
    reading = read_scene(write(tmp_path / "ok.usda", text), load_textures=False)
    assert not reading.errors, reading.errors
    names = {p.name: p for p in reading.scene.probes}
    assert names["/Max"].resolution == MAX_CAPTURE_RESOLUTION and names["/Zero"].resolution == 0
    assert names["/Vol[0,0,0]"].relocate > 0 and names["/Vol[0,0,0]"].encodings == ("sh2",)
    assert names["/Refl"].influence["extent_m"] == [1.0, 2.0, 3.0]
    assert len(reading.scene.lights) == 2 and len(reading.scene.meshes) == 2


def test_probe_attribute_types_come_from_the_packaged_schema():
    """The declared types used for the checks are the packaged schema's (also when OpenUSD's registry did not see
    the plugin) and agree with the registry's when it did."""
    types = _probe_schema_types()
    assert set(types) == set(PROBE_TYPES)
    declared = {name for attributes in types.values() for name in attributes}
    assert set(FALLBACKS) | {"bakery:capture:image", "bakery:encodings"} <= declared
    assert types[V]["bakery:volume:counts"] == Sdf.ValueTypeNames.Int3
    assert types[I]["bakery:capture:image"] == Sdf.ValueTypeNames.Asset
    for type_name, attributes in types.items():
        definition = Usd.SchemaRegistry().FindConcretePrimDefinition(type_name)
        if definition is None:
            continue
        for name, value_type in attributes.items():
            assert definition.GetAttributeDefinition(name).GetTypeName() == value_type, (type_name, name)
