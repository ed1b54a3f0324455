"""MaterialX node graphs over several images (``bakery/usd/mtlx_graph.py``): a surface input computed from images
by stdlib nodes is flattened into a texture of its own.

References: the MaterialX stdlib formulas (specification v1.39, "Standard Nodes"), written out per texel here in
numpy independently of the flattener; scipy's bilinear interpolation for images of different sizes; and the
capture itself, which must see at each texel centre of an emissive floor exactly the graph's value there."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from scipy import ndimage
from usd_scenes import (
    glowing_mtlx_document,
    glowing_mtlx_material,
    header,
    probe,
    textured_floor,
    write,
)

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

SIZE = 8
#: MaterialX stdlib ``luminance`` default ``lumacoeffs`` (stdlib_defs.mtlx, ND_luminance_color3)
LUMA = np.array([0.2722287, 0.6740818, 0.0536895])
#: the probes' height over the floor (m)
HEIGHT = 0.01
#: texel (row, column) centres the capture test looks at (row 0 = the top of the image, t = 1)
TEXELS = [(0, 0), (1, 6), (3, 3), (5, 2), (6, 7), (7, 4)]


def _exr(path, pixels: np.ndarray) -> str:
    pixels = np.asarray(pixels, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], oiio.FLOAT))
    out.write_image(pixels)
    out.close()
    return path.name


def _images(tmp_path) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    images = {"a": rng.uniform(0.05, 1.0, (SIZE, SIZE, 3)), "b": rng.uniform(0.05, 1.0, (SIZE, SIZE, 3)),
              "m": rng.uniform(0.0, 1.0, (SIZE, SIZE))}
    for name, pixels in images.items():
        _exr(tmp_path / f"{name}.exr", pixels)
    return {k: v.astype(np.float32).astype(np.float64) for k, v in images.items()}




def _document(graph: str, output: str) -> str:
    images = "".join(
        f'<image name="{name}" type="{kind}"><input name="file" type="filename" value="{name}.exr" /></image>'
        for name, kind in (("a", "color3"), ("b", "color3"), ("m", "float")))
    return glowing_mtlx_document(images + graph, output)


def _scene(tmp_path, document: str, probes: bool = True, extra: str = ""):  # noqa: ANN202
    """The floor bound to ``document``'s material Glow (``extra``: more floor attributes), probes over TEXELS."""
    (tmp_path / "glow.mtlx").write_text(document)
    points = [(2 * (c + 0.5) / SIZE - 1, 2 * (r + 0.5) / SIZE - 1) for r, c in TEXELS]  # z = 1 − 2t, t = 1 − row
    text = header() + 'def Scope "Looks" (\n    references = @./glow.mtlx@</MaterialX>\n)\n{\n}\n' + textured_floor(
        "/Looks/Materials/Glow", extra) + ("".join(probe(f"P{k}", (x, HEIGHT, z)) for k, (x, z) in enumerate(points))
                                    if probes else "")
    return read_scene(write(tmp_path / "scene.usda", text))


def _seen_below(reading) -> np.ndarray:  # noqa: ANN001
    """(probes, 3) radiance straight below each probe (the floor's emission at its texel centre)."""
    cubes, _ = capture_probes(reading.scene, 16, samples=2, bounces=0)
    d = cube_texel_directions(16)
    down = np.unravel_index(np.argmin(d[..., 1]), d.shape[:3])
    return np.array([cube[down] for cube in cubes], dtype=np.float64)


def _node(category: str, name: str, kind: str, **inputs: str) -> str:
    """A document node; each input is "<type> node:<name>[.<output>]" or "<type> <value>" (``in_``: ``in``)."""
    body = []
    for key, spec in inputs.items():
        kind_of, value = spec.split(" ", 1)
        key = key.rstrip("_")
        if value.startswith("node:"):
            target, _, output = value[5:].partition(".")
            body.append(f'<input name="{key}" type="{kind_of}" nodename="{target}"'
                        + (f' output="{output}"' if output else "") + " />")
        else:
            body.append(f'<input name="{key}" type="{kind_of}" value="{value}" />')
    return f'<{category} name="{name}" type="{kind}">' + "".join(body) + f"</{category}>"


A, B, M = "color3 node:a", "color3 node:b", "float node:m"
#: (graph nodes, the value per texel from the stdlib formulas over the images a, b (RGB) and m); output node "out"
GRAPHS = {
    "multiply": ([_node("multiply", "out", "color3", in1=A, in2=B)], lambda a, b, m: a * b),
    "mix_by_mask": ([_node("mix", "out", "color3", fg=A, bg=B, mix=M)],
                    lambda a, b, m: a * m[..., None] + b * (1 - m[..., None])),
    "weighted_sum": ([_node("multiply", "half", "color3", in1=A, in2="float 0.5"),
                      _node("multiply", "masked", "color3", in1=B, in2=M),
                      _node("add", "out", "color3", in1="color3 node:half", in2="color3 node:masked")],
                     lambda a, b, m: 0.5 * a + b * m[..., None]),
    "swizzle": ([_node("separate3", "split", "multioutput", in_=A),
                 _node("extract", "green", "float", in_=B, index="integer 1"),
                 _node("combine3", "out", "color3", in1="float node:split.outb", in2="float node:green", in3=M)],
                lambda a, b, m: np.stack([a[..., 2], b[..., 1], m], axis=-1)),
    "clamped_difference": ([_node("subtract", "diff", "color3", in1=A, in2=B),
                            _node("clamp", "out", "color3", in_="color3 node:diff")],
                           lambda a, b, m: np.clip(a - b, 0.0, 1.0)),
    "luminance": ([_node("luminance", "out", "color3", in_=A)],
                  lambda a, b, m: np.repeat((a @ LUMA)[..., None], 3, axis=-1)),
    "power_invert": ([_node("power", "gamma", "color3", in1=A, in2="float 2.2"),
                      _node("invert", "out", "color3", in_="color3 node:gamma")], lambda a, b, m: 1.0 - a ** 2.2),
    "smoothstep_convert": ([_node("smoothstep", "edge", "float", in_=M, low="float 0.2", high="float 0.8"),
                            _node("convert", "out", "color3", in_="float node:edge")],
                           lambda a, b, m: np.repeat(_hermite(np.clip((m - 0.2) / 0.6, 0, 1))[..., None], 3, -1)),
    "ifgreater": ([_node("ifgreater", "out", "color3", value1=M, value2="float 0.5", in1=A, in2=B)],
                  lambda a, b, m: np.where(m[..., None] > 0.5, a, b)),
    "remap_divide": ([_node("remap", "lifted", "color3", in_=A, outlow="float 0.2", outhigh="float 0.6"),
                      _node("add", "denominator", "color3", in1=B, in2="float 0.5"),
                      _node("divide", "out", "color3", in1="color3 node:lifted", in2="color3 node:denominator")],
                     lambda a, b, m: (0.2 + 0.4 * a) / (b + 0.5)),
}


def _hermite(t: np.ndarray) -> np.ndarray:
    return t * t * (3 - 2 * t)


@pytest.mark.parametrize("graph", list(GRAPHS), ids=list(GRAPHS))
def test_a_graph_over_several_images_is_what_the_capture_sees_at_every_texel(tmp_path, graph):
    """Before: "input emission_color is computed by a multiply node, which the capture does not evaluate" and the
    default (black) was used. Now every texel of the flattened texture is the stdlib formula of the images' texels,
    and the capture sees the floor as it sees the floor textured with one image of the formula's values."""
    nodes, formula = GRAPHS[graph]
    images = _images(tmp_path)
    reading = _scene(tmp_path, (_document("".join(nodes), "out")))
    assert not [i for i in reading.issues if "emission_color" in i.message], reading.issues
    expected = formula(images["a"], images["b"], images["m"])
    (floor,) = [m for m in reading.scene.meshes if m.name.endswith("Floor")]
    (entry,) = [e for e in floor.material.maps if e["input"] == "emissiveColor"]
    texture = reading.scene.textures[entry["texture"]].pixels[..., :3]
    np.testing.assert_allclose(texture, expected, rtol=2e-6, atol=2e-7)
    # The capture sees the graph as it sees one image of the formula's values (the single-image path).
    baked = tmp_path / "baked"
    baked.mkdir()
    _exr(baked / "baked.exr", expected)
    reference = _scene(baked, glowing_mtlx_document(
        '<image name="baked" type="color3"><input name="file" type="filename" value="baked.exr" /></image>', "baked"))
    np.testing.assert_allclose(_seen_below(reading), _seen_below(reference), rtol=1e-5, atol=1e-7)


def test_images_of_different_sizes_are_sampled_on_the_largest_images_texel_grid(tmp_path):
    """A 3 × 5 image times an 8 × 8 one: the small image is looked up bilinearly (repeat) at the large one's texel
    centres — scipy's ``map_coordinates`` (grid-wrap) at the same points."""
    images = _images(tmp_path)
    small = np.random.default_rng(3).uniform(0.1, 1.0, (3, 5, 3)).astype(np.float32).astype(np.float64)
    _exr(tmp_path / "small.exr", small)
    document = _document('<image name="small" type="color3"><input name="file" type="filename" value="small.exr" />'
                         "</image>" + _node("multiply", "out", "color3", in1=A, in2="color3 node:small"), "out")
    reading = _scene(tmp_path, (document), probes=False)
    rows = (np.arange(SIZE) + 0.5) * 3 / SIZE - 0.5
    cols = (np.arange(SIZE) + 0.5) * 5 / SIZE - 0.5
    grid = np.meshgrid(rows, cols, indexing="ij")
    resampled = np.stack([ndimage.map_coordinates(small[..., c], grid, order=1, mode="grid-wrap")
                          for c in range(3)], axis=-1)
    (floor,) = [m for m in reading.scene.meshes if m.name.endswith("Floor")]
    (entry,) = [e for e in floor.material.maps if e["input"] == "emissiveColor"]
    np.testing.assert_allclose(reading.scene.textures[entry["texture"]].pixels[..., :3], images["a"] * resampled,
                               rtol=2e-6, atol=1e-7)


def test_an_orm_image_split_into_roughness_and_metalness(tmp_path):
    """The glTF packing: occlusion, roughness, metalness in R, G, B of one image, split by separate3 (and extract):
    the surface's roughness map is the image's G, its metalness map the image's B."""
    rng = np.random.default_rng(5)
    orm = rng.uniform(0.0, 1.0, (SIZE, SIZE, 3)).astype(np.float32)
    _exr(tmp_path / "orm.exr", orm)
    document = """<?xml version="1.0"?>
<materialx version="1.39">
  <image name="orm" type="vector3"><input name="file" type="filename" value="orm.exr" /></image>
  <separate3 name="split" type="multioutput"><input name="in" type="vector3" nodename="orm" /></separate3>
  <extract name="metal" type="float"><input name="in" type="vector3" nodename="orm" />
    <input name="index" type="integer" value="2" /></extract>
  <standard_surface name="SR" type="surfaceshader">
    <input name="specular_roughness" type="float" nodename="split" output="outy" />
    <input name="metalness" type="float" nodename="metal" />
  </standard_surface>
  <surfacematerial name="Glow" type="material"><input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
"""
    reading = _scene(tmp_path, document, probes=False)
    assert not [i for i in reading.issues if "roughness" in i.message or "metalness" in i.message], reading.issues
    (floor,) = [m for m in reading.scene.meshes if m.name.endswith("Floor")]
    maps = {e["input"]: e for e in floor.material.maps}
    for target, channel in (("roughness", 1), ("metallic", 2)):
        pixels = reading.scene.textures[maps[target]["texture"]].pixels
        np.testing.assert_array_equal(pixels[..., 0], orm[..., channel])
    assert floor.material.roughness == pytest.approx(float(orm[..., 1].mean()), rel=1e-6)


def _usd_graph(tmp_path) -> str:
    """mix(fg = a · b, bg = b, mix = m) authored as MaterialX shaders in USD."""
    def image(name: str, kind: str) -> str:
        return f"""
    def Shader "{name}"
    {{
        uniform token info:id = "ND_image_{kind}"
        asset inputs:file = @./{name}.exr@
        {"color3f" if kind == "color3" else "float"} outputs:out
    }}"""

    return glowing_mtlx_material("Glow", "</Glow/Blend.outputs:out>", image("a", "color3") + image("b", "color3")
                                 + image("m", "float") + """
    def Shader "Product"
    {
        uniform token info:id = "ND_multiply_color3"
        color3f inputs:in1.connect = </Glow/a.outputs:out>
        color3f inputs:in2.connect = </Glow/b.outputs:out>
        color3f outputs:out
    }
    def Shader "Blend"
    {
        uniform token info:id = "ND_mix_color3"
        color3f inputs:fg.connect = </Glow/Product.outputs:out>
        color3f inputs:bg.connect = </Glow/b.outputs:out>
        float inputs:mix.connect = </Glow/m.outputs:out>
        color3f outputs:out
    }""")


def test_a_graph_authored_in_usd_is_flattened_as_the_same_graph_in_a_document(tmp_path):
    images = _images(tmp_path)
    text = header() + _usd_graph(tmp_path) + textured_floor("/Glow")
    reading = read_scene(write(tmp_path / "usd.usda", text))
    assert not [i for i in reading.issues if "emission_color" in i.message], reading.issues
    (floor,) = [m for m in reading.scene.meshes if m.name.endswith("Floor")]
    (entry,) = [e for e in floor.material.maps if e["input"] == "emissiveColor"]
    m = images["m"][..., None]
    expected = images["a"] * images["b"] * m + images["b"] * (1 - m)
    np.testing.assert_allclose(reading.scene.textures[entry["texture"]].pixels[..., :3], expected, rtol=2e-6,
                               atol=1e-7)
    nodes = [_node("multiply", "product", "color3", in1=A, in2=B),
             _node("mix", "out", "color3", fg="color3 node:product", bg=B, mix=M)]
    (tmp_path / "doc").mkdir()
    for name in "abm":
        (tmp_path / "doc" / f"{name}.exr").write_bytes((tmp_path / f"{name}.exr").read_bytes())
    reading_doc = _scene(tmp_path / "doc", (_document("".join(nodes), "out")), probes=False)
    (floor_doc,) = [m for m in reading_doc.scene.meshes if m.name.endswith("Floor")]
    (entry_doc,) = [e for e in floor_doc.material.maps if e["input"] == "emissiveColor"]
    np.testing.assert_array_equal(reading.scene.textures[entry["texture"]].pixels,
                                  reading_doc.scene.textures[entry_doc["texture"]].pixels)


def test_a_graph_of_constants_is_a_value(tmp_path):
    nodes = [_node("constant", "c", "color3", value="color3 0.5, 0.25, 1"),
             _node("multiply", "out", "color3", in1="color3 node:c", in2="float 2")]
    reading = _scene(tmp_path, (_document("".join(nodes), "out")))
    (floor,) = [m for m in reading.scene.meshes if m.name.endswith("Floor")]
    assert not floor.material.maps and floor.material.emission == pytest.approx((1.0, 0.5, 2.0))
    np.testing.assert_allclose(_seen_below(reading), np.tile([1.0, 0.5, 2.0], (len(TEXELS), 1)), rtol=1e-6)


@pytest.mark.parametrize(("nodes", "reason"), [
    ([_node("noise2d", "noise", "color3"), _node("multiply", "out", "color3", in1=A, in2="color3 node:noise")],
     "a noise2d node, which the capture does not evaluate"),
    (['<place2d name="shift" type="vector2"><input name="offset" type="vector2" value="0.5, 0" /></place2d>'
      '<image name="a2" type="color3"><input name="file" type="filename" value="a.exr" />'
      '<input name="texcoord" type="vector2" nodename="shift" /></image>',
      _node("multiply", "out", "color3", in1=A, in2="color3 node:a2")],
     "images with different texture coordinates"),
    ([_node("geompropvalue", "tint", "color3", geomprop="string displayColor"),
      _node("mix", "out", "color3", fg=A, bg="color3 node:tint", mix="float 0.5")], "a geompropvalue (primvar) node"),
])
def test_a_graph_that_cannot_be_flattened_is_reported_and_the_default_used(tmp_path, nodes, reason):
    _images(tmp_path)
    reading = _scene(tmp_path, (_document("".join(nodes), "out")), probes=False)
    messages = [i.message for i in reading.issues if "emission_color" in i.message]
    assert messages and reason in messages[0] and "its default is used" in messages[0], reading.issues
    (floor,) = [m for m in reading.scene.meshes if m.name.endswith("Floor")]
    assert not floor.material.maps


#: the floor's corner colours, in its point order (-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)
CORNERS = np.array([(1.0, 0.2, 0.1), (0.1, 1.0, 0.3), (0.3, 0.1, 1.0), (0.8, 0.8, 0.2)])


def test_vertex_colours_tint_a_graph_at_every_hit(tmp_path):
    """multiply(mix(a, b, m), geompropvalue displayColor): the graph is flattened, and the capture multiplies its
    texel by the primvar interpolated at the hit — the floor's two triangles (0, 1, 2) and (0, 2, 3), barycentric
    weights of the corners, by hand, times what the capture sees of the untinted graph. Before: reported, and the
    default (black) used."""
    _images(tmp_path)
    nodes = [_node("mix", "blend", "color3", fg=A, bg=B, mix=M),
             _node("geompropvalue", "tint", "color3", geomprop="string displayColor"),
             _node("multiply", "out", "color3", in1="color3 node:blend", in2="color3 node:tint")]
    colours = ", ".join(f"({r}, {g}, {b})" for r, g, b in CORNERS)
    reading = _scene(tmp_path, _document("".join(nodes), "out"), extra=f"""
    color3f[] primvars:displayColor = [{colours}] (
        interpolation = "vertex"
    )""")
    assert not [i for i in reading.issues if "emission_color" in i.message], reading.issues
    untinted = tmp_path / "untinted"  # the same graph without the tint: what the capture sees of the texture
    untinted.mkdir()
    for name in "abm":
        (untinted / f"{name}.exr").write_bytes((tmp_path / f"{name}.exr").read_bytes())
    blend = _seen_below(_scene(untinted, _document(nodes[0].replace('name="blend"', 'name="out"'), "out")))
    expected = []
    corners = np.array([(-1.0, 1.0), (1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)])  # (x, z)
    d = cube_texel_directions(16)
    down = d[np.unravel_index(np.argmin(d[..., 1]), d.shape[:3])]  # the texel looked through, not exactly −y
    for k, (r, c) in enumerate(TEXELS):
        x, z = np.array([2 * (c + 0.5) / SIZE - 1, 2 * (r + 0.5) / SIZE - 1]) + HEIGHT * down[[0, 2]] / -down[1]
        triangle = (0, 1, 2) if z >= -x else (0, 2, 3)  # the diagonal from corner 0 (-1, 1) to corner 2 (1, -1)
        a, b, q = (corners[i] for i in triangle)
        weights = np.linalg.solve(np.array([[a[0], b[0], q[0]], [a[1], b[1], q[1]], [1, 1, 1]]), [x, z, 1])
        expected.append(blend[k] * (weights @ CORNERS[list(triangle)]))
    np.testing.assert_allclose(_seen_below(reading), expected, rtol=5e-3, atol=1e-6)  # measured ≤ 0.25 %
