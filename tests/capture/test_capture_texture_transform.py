"""Texture-coordinate transforms: UsdTransform2d between the primvar reader and a UsdUVTexture (specification:
st' = R(rotation, counter-clockwise)·(scale ⊙ st) + translation), MaterialX ``tiledimage`` tiling and ``place2d``
(stdlib: R = rotate2d's [[c, s], [−s, c]], out = R·((tc − pivot)/scale) − offset + pivot). Closed forms on an
emissive floor whose texture is red for s < ½ and blue for s > ½ (repeat): the colour straight below a probe is the
texture at the transformed coordinates of the point it looks at. And MaterialX graphs of constant arithmetic
(multiply, add, subtract, mix) over an image: the texel through the same arithmetic."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from usd_scenes import (
    glowing_mtlx_document,
    glowing_mtlx_material,
    header,
    probe,
    textured_floor,
    uv_texture_material,
    write,
)

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.mtlx import place2d_affine
from bakery.usd.scene import read_scene

RED, BLUE = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)


def _halves(path) -> str:
    pixels = np.zeros((64, 64, 3), dtype=np.float32)
    pixels[:, :32] = RED
    pixels[:, 32:] = BLUE
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(64, 64, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()
    return path.name


def _floor(material: str) -> str:
    """The textured floor (``usd_scenes.textured_floor``) bound to </Glow>, after ``material``."""
    return material + textured_floor("/Glow")


def _preview(file: str, transform: str) -> str:
    return uv_texture_material(file, 'token inputs:sourceColorSpace = "raw"\n        token inputs:wrapS = "repeat"\n'
                                     '        token inputs:wrapT = "repeat"', transform=transform)


def _materialx(file: str, image: str, place: str = "") -> str:
    """standard_surface emission from an ND_image / ND_tiledimage (``image``: its id and inputs), optionally
    through an ND_place2d_vector2 on its texcoord."""
    texcoord = "float2 inputs:texcoord.connect = </Glow/Place.outputs:out>" if place else ""
    place_shader = f"""
    def Shader "Place"
    {{
        uniform token info:id = "ND_place2d_vector2"
        {place}
        float2 outputs:out
    }}""" if place else ""
    image_id, image_inputs = image
    return glowing_mtlx_material("Glow", "</Glow/Image.outputs:out>", f"""
    def Shader "Image"
    {{
        uniform token info:id = "{image_id}"
        asset inputs:file = @{file}@
        {image_inputs}
        {texcoord}
        color3f outputs:out
    }}{place_shader}""")


#: probes above floor points (x, z) ↔ st = ((x + 1)/2, (1 − z)/2)
POINTS = [(-0.4, 0.5), (0.4, 0.5), (-0.4, -0.5), (0.4, -0.5)]


def _seen(tmp_path, material: str) -> list[np.ndarray]:
    text = header() + _floor(material) + "".join(probe(f"P{k}", (x, 0.05, z)) for k, (x, z) in enumerate(POINTS))
    reading = read_scene(write(tmp_path / "scene.usda", text))
    assert not reading.errors, reading.errors
    cubes, _ = capture_probes(reading.scene, 16, samples=4, bounces=0)
    d = cube_texel_directions(16)
    down = np.unravel_index(np.argmin(d[..., 1]), d.shape[:3])
    return [cube[down].astype(np.float64) for cube in cubes]


def _expected(transform) -> list[tuple[float, float, float]]:  # noqa: ANN001 - st → st'
    colours = []
    for x, z in POINTS:
        s, _t = transform((x + 1) / 2, (1 - z) / 2)
        colours.append(RED if (s % 1.0) < 0.5 else BLUE)
    return colours


@pytest.mark.parametrize(("inputs", "transform"), [
    ("", lambda s, t: (s, t)),
    ("float2 inputs:translation = (0.5, 0)", lambda s, t: (s + 0.5, t)),
    ("float2 inputs:scale = (2, 1)", lambda s, t: (2 * s, t)),
    ("float inputs:rotation = 90", lambda s, t: (-t, s)),  # counter-clockwise: (s, t) ↦ (−t, s)
])
def test_usd_transform2d(tmp_path, inputs, transform):
    file = _halves(tmp_path / "halves.exr")
    seen = _seen(tmp_path, _preview(file, inputs))
    np.testing.assert_allclose(seen, _expected(transform), atol=1e-3)


@pytest.mark.parametrize(("image", "place", "transform"), [
    (("ND_tiledimage_color3", "float2 inputs:uvtiling = (2, 1)"), "", lambda s, t: (2 * s, t)),
    (("ND_tiledimage_color3", "float2 inputs:uvoffset = (0.5, 0)"), "", lambda s, t: (s - 0.5, t)),
    (("ND_image_color3", ""), "float2 inputs:offset = (0.5, 0)", lambda s, t: (s - 0.5, t)),
    (("ND_image_color3", ""), "float inputs:rotate = 90", lambda s, t: (t, -s)),  # rotate2d: (s, t) ↦ (t, −s)
    (("ND_image_color3", ""), "float2 inputs:scale = (0.5, 1)", lambda s, t: (2 * s, t)),
])
def test_materialx_tiling_and_place2d(tmp_path, image, place, transform):
    file = _halves(tmp_path / "halves.exr")
    seen = _seen(tmp_path, _materialx(file, image, place))
    np.testing.assert_allclose(seen, _expected(transform), atol=1e-3)


def test_place2d_pivot_and_order_follow_the_stdlib_graph():
    """The affine map against the stdlib node graph evaluated step by step (subtract pivot, divide by scale,
    rotate2d, subtract offset, add pivot; TRS: offset before rotate and scale)."""
    def rotate2d(v, degrees):  # noqa: ANN001, ANN202 - mx_rotate_vector2
        c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
        return np.array([c * v[0] + s * v[1], -s * v[0] + c * v[1]])

    pivot, scale, rotate, offset = np.array([0.3, 0.6]), np.array([2.0, 0.5]), 30.0, np.array([0.1, -0.2])
    tc = np.array([0.7, 0.2])
    srt = rotate2d((tc - pivot) / scale, rotate) - offset + pivot
    trs = rotate2d((tc - pivot) - offset, rotate) / scale + pivot
    for order, expected in ((0, srt), (1, trs)):
        (a, b, tx), (c, d, ty) = place2d_affine(pivot, scale, rotate, offset, order)
        np.testing.assert_allclose([a * tc[0] + b * tc[1] + tx, c * tc[0] + d * tc[1] + ty], expected, atol=1e-12)


# --- MaterialX graphs of constant arithmetic over an image, folded into the map's scale and bias ------------------
def _document(file: str, graph: str, output: str) -> str:
    return glowing_mtlx_document(f'<image name="halves" type="color3"><input name="file" type="filename" '
                                 f'value="{file}" /></image>{graph}', output)


def _seen_through_document(tmp_path) -> list[np.ndarray]:
    """:func:`_seen` of the floor bound to ``glow.mtlx``'s material, checking that no input was left unevaluated."""
    text = header() + 'def Scope "Looks" (\n    references = @./glow.mtlx@</MaterialX>\n)\n{\n}\n' + _floor("").replace(
        "</Glow>", "</Looks/Materials/Glow>") + "".join(probe(f"P{k}", (x, 0.05, z)) for k, (x, z) in enumerate(POINTS))
    reading = read_scene(write(tmp_path / "scene.usda", text))
    assert not [i for i in reading.issues if "does not evaluate" in i.message], reading.issues
    cubes, _ = capture_probes(reading.scene, 16, samples=4, bounces=0)
    d = cube_texel_directions(16)
    down = np.unravel_index(np.argmin(d[..., 1]), d.shape[:3])
    return [cube[down].astype(np.float64) for cube in cubes]


GRAPHS = [  # (nodes, output node, colour as a function of the texel c (RGB))
    ('<multiply name="tint" type="color3"><input name="in1" type="color3" nodename="halves" />'
     '<input name="in2" type="color3" value="0.5, 1, 2" /></multiply>', "tint",
     lambda c: c * np.array([0.5, 1.0, 2.0])),
    ('<constant name="green" type="color3"><input name="value" type="color3" value="0, 1, 0" /></constant>'
     '<mix name="blend" type="color3"><input name="fg" type="color3" nodename="halves" />'
     '<input name="bg" type="color3" nodename="green" /><input name="mix" type="float" value="0.25" /></mix>',
     "blend", lambda c: 0.25 * c + 0.75 * np.array([0.0, 1.0, 0.0])),
    ('<subtract name="invert" type="color3"><input name="in1" type="color3" value="1, 1, 1" />'
     '<input name="in2" type="color3" nodename="halves" /></subtract>', "invert", lambda c: 1.0 - c),
    ('<multiply name="twice" type="color3"><input name="in1" type="color3" nodename="halves" />'
     '<input name="in2" type="float" value="2" /></multiply>'
     '<add name="lift" type="color3"><input name="in1" type="color3" nodename="twice" />'
     '<input name="in2" type="color3" value="0.1, 0.1, 0.1" /></add>', "lift", lambda c: 2.0 * c + 0.1),
]


@pytest.mark.parametrize(("graph", "output", "colour"), GRAPHS, ids=["multiply", "mix", "subtract", "chain"])
def test_materialx_constant_arithmetic_over_an_image_is_folded(tmp_path, graph, output, colour):
    """multiply / mix / subtract / add with constant operands (a value, a constant node, a float broadcast) over
    an image: the texel through the same arithmetic, at every hit (before: the input's default)."""
    file = _halves(tmp_path / "halves.exr")
    (tmp_path / "glow.mtlx").write_text(_document(file, graph, output))
    expected = [colour(np.asarray(c)) for c in _expected(lambda s, t: (s, t))]
    np.testing.assert_allclose(_seen_through_document(tmp_path), expected, atol=2e-3)


def test_a_node_graph_with_an_interface_input_is_folded(tmp_path):
    """The usual layout of library materials: the image and a multiply inside a nodegraph whose tint is an
    interface input; the surface input reads the graph's output."""
    file = _halves(tmp_path / "halves.exr")
    graph = f"""<nodegraph name="NG_glow">
    <input name="tint" type="color3" value="0.5, 1, 2" />
    <image name="img" type="color3"><input name="file" type="filename" value="{file}" /></image>
    <multiply name="tinted" type="color3">
      <input name="in1" type="color3" nodename="img" />
      <input name="in2" type="color3" interfacename="tint" />
    </multiply>
    <output name="out" type="color3" nodename="tinted" />
  </nodegraph>"""
    document = _document(file, graph, "unused").replace(
        '<input name="emission_color" type="color3" nodename="unused" />',
        '<input name="emission_color" type="color3" nodegraph="NG_glow" output="out" />')
    (tmp_path / "glow.mtlx").write_text(document)
    expected = [np.asarray(c) * np.array([0.5, 1.0, 2.0]) for c in _expected(lambda s, t: (s, t))]
    np.testing.assert_allclose(_seen_through_document(tmp_path), expected, atol=2e-3)
