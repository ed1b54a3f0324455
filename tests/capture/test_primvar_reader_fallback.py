"""A texture whose texture coordinates the gprim does not have is read at the primvar reader's fallback st — the
UsdPreviewSurface specification (OpenUSD ``docs/spec_usdpreviewsurface.rst``), Primvar Reader: "fallback - float2 -
(0.0, 0.0): fallback value to be returned if geometry fetch failed", and UsdUVTexture's ``st``: "Texture coordinate
to use to fetch this texture ... the (0, 0) st coordinate maps to a (0, 0) uv coordinate that samples the
lower-left-hand corner of the texture image, as viewed on a monitor". So a Mesh without the reader's primvar, or an
implicit gprim (Sphere, Cube, … have no st), shows the texture's value at that one st — after the UsdTransform2d
between reader and texture, with the texture's wrap modes, scale and bias — everywhere: not the texture's mean
(bakery until 2026-12). MaterialX: ``texcoord`` has no fallback input and its output's default is zero (MaterialX
Standard Nodes, Geometric nodes: texcoord ``out`` default "zero"), so an ``image`` reads st (0, 0) there.

Closed forms only: an emissive, black, specular-free floor (as ``test_preview_surface_spec.py``) whose emission is
an 8 × 8 texture with four coloured quadrants; probes just above it look straight down and see the emission."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import OpenImageIO as oiio
import pytest
from usd_scenes import (
    glowing_mtlx_document,
    glowing_mtlx_material,
    header,
    probe,
    uv_texture_material,
    write,
)

from bakery.capture import capture_probes
from bakery.pipeline.dependencies import environment_hash
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

RED, BLUE, GREEN, WHITE, BLACK = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)
#: the image's quadrants as viewed on a monitor (row 0 at the top)
QUADRANTS = {"top-left": RED, "top-right": BLUE, "bottom-left": GREEN, "bottom-right": WHITE}
#: the image's lower-left texel (row N − 1, column 0): distinct from the rest of its quadrant
CORNER = (0.5, 0.25, 0.125)
N = 8
#: floor points (u, v) ∈ [0, 1]² the probes look down at (x = 2u − 1, z = 1 − 2v), away from the quadrant edges
POINTS = [(0.2, 0.3), (0.35, 0.8), (0.85, 0.7)]
RAW = 'token inputs:sourceColorSpace = "raw"'


def _quadrant(s: float, t: float) -> tuple[float, float, float]:
    """The image at st inside [0, 1)², away from the quadrant edges: t = 0 is its bottom row (the specification)."""
    return QUADRANTS[("top" if t >= 0.5 else "bottom") + "-" + ("left" if s < 0.5 else "right")]


def _image(tmp_path) -> str:  # noqa: ANN001
    pixels = np.zeros((N, N, 3), dtype=np.float32)
    h = N // 2
    pixels[:h, :h], pixels[:h, h:] = QUADRANTS["top-left"], QUADRANTS["top-right"]
    pixels[h:, :h], pixels[h:, h:] = QUADRANTS["bottom-left"], QUADRANTS["bottom-right"]
    pixels[N - 1, 0] = CORNER
    path = tmp_path / "quadrants.exr"
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(N, N, 3, oiio.FLOAT))
    assert out.write_image(pixels)
    out.close()
    return path.name


def _material(file: str, fallback=None, inputs: str = RAW, transform: str = "", varname: str = "st") -> str:  # noqa: ANN001
    """A glowing material: emissiveColor ← UsdUVTexture(file) ← [UsdTransform2d ←] UsdPrimvarReader_float2
    (``varname``, ``fallback`` authored unless None)."""
    return uv_texture_material(file, inputs, transform=transform, varname=varname, fallback=fallback)


def _floor(material_path: str = "/Glow", st: bool = False) -> str:
    """The 2 m floor at y = 0, without texture coordinates (``st``: with primvars:st = ((x + 1)/2, (1 − z)/2))."""
    coordinates = """
    texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
        interpolation = "vertex"
    )""" if st else ""
    return f"""
def Mesh "Floor" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]{coordinates}
    rel material:binding = <{material_path}>
}}
"""


def _cube(material_path: str = "/Glow") -> str:
    """An implicit Cube gprim (no texture coordinates) whose top face is the floor's square at y = 0."""
    return f"""
def Cube "Block" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    double size = 2
    double3 xformOp:translate = (0, -1, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    rel material:binding = <{material_path}>
}}
"""


def _reading(tmp_path, material: str, geometry: str | None = None, name: str = "scene"):  # noqa: ANN001, ANN202
    text = header() + material + (_floor() if geometry is None else geometry) + "".join(
        probe(f"P{k}", (2 * u - 1, 0.05, 1 - 2 * v)) for k, (u, v) in enumerate(POINTS))
    reading = read_scene(write(tmp_path / f"{name}.usda", text))
    assert not reading.errors, reading.errors
    return reading


def _seen(reading) -> list[np.ndarray]:  # noqa: ANN001
    """The colour straight below each probe."""
    cubes, _ = capture_probes(reading.scene, 16, samples=4, bounces=0)
    d = cube_texel_directions(16)
    down = np.unravel_index(np.argmin(d[..., 1]), d.shape[:3])
    return [cube[down].astype(np.float64) for cube in cubes]


def _shown(st) -> str:  # noqa: ANN001
    return "(" + ", ".join(f"{float(x):g}" for x in st) + ")"


# --- UsdPreviewSurface ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fallback", [(0.25, 0.75), (0.75, 0.25)])
def test_a_mesh_without_st_shows_the_texture_at_the_readers_fallback(tmp_path, fallback):
    reading = _reading(tmp_path, _material(_image(tmp_path), fallback))
    expected = _quadrant(*fallback)
    np.testing.assert_allclose(_seen(reading), [expected] * len(POINTS), atol=1e-4)
    assert [i.message for i in reading.issues if i.prim == "/Floor"] == [
        "textures read primvar 'st', which the mesh does not have; the textures are read at the primvar reader's "
        f"fallback st {_shown(fallback)}"]


def test_the_default_fallback_is_st_zero_the_lower_left_corner(tmp_path):
    """No authored fallback: (0, 0), the image's lower-left corner — with clamped edges exactly its lower-left
    texel (distinct from the rest of its quadrant, so not the quadrant's colour)."""
    inputs = RAW + '\n        token inputs:wrapS = "clamp"\n        token inputs:wrapT = "clamp"'
    reading = _reading(tmp_path, _material(_image(tmp_path), inputs=inputs))
    np.testing.assert_allclose(_seen(reading), [CORNER] * len(POINTS), atol=1e-4)
    assert any("fallback st (0, 0)" in i.message for i in reading.issues if i.prim == "/Floor")


def test_at_the_corner_repeat_and_black_edges_filter_as_a_bilinear_sampler(tmp_path):
    """st (0, 0) is the corner between four texels (texel centres at (i + ½)/N): a bilinear lookup — Hydra Storm's
    sampler at a constant st, whose derivatives, hence level of detail, vanish — weighs each ¼. ``repeat``: the
    four corner texels of the image; ``black`` (and ``useMetadata`` without metadata): the lower-left texel and
    three of the black outside ("Reader returns transparent black (0.0, 0.0, 0.0, 0.0) outside unit square")."""
    file = _image(tmp_path)
    repeat = RAW + '\n        token inputs:wrapS = "repeat"\n        token inputs:wrapT = "repeat"'
    seen = _seen(_reading(tmp_path, _material(file, inputs=repeat), name="repeat"))
    corners = (np.array(CORNER) + QUADRANTS["top-left"] + QUADRANTS["top-right"] + QUADRANTS["bottom-right"]) / 4
    np.testing.assert_allclose(seen, [corners] * len(POINTS), atol=1e-4)
    seen = _seen(_reading(tmp_path, _material(file), name="black"))  # wrapS/T not authored: useMetadata
    np.testing.assert_allclose(seen, [np.array(CORNER) / 4] * len(POINTS), atol=1e-4)


def test_a_reader_of_a_primvar_the_mesh_lacks_gives_its_fallback(tmp_path):
    """The floor has st, the reader reads "uv": the fetch fails, its fallback is used (st is not read instead)."""
    reading = _reading(tmp_path, _material(_image(tmp_path), (0.75, 0.75), varname="uv"), _floor(st=True))
    np.testing.assert_allclose(_seen(reading), [BLUE] * len(POINTS), atol=1e-4)
    assert [i.message for i in reading.issues if i.prim == "/Floor"] == [
        "textures read primvar 'uv', which the mesh does not have; the textures are read at the primvar reader's "
        "fallback st (0.75, 0.75)"]


def test_a_mesh_with_the_primvar_ignores_the_fallback(tmp_path):
    """The fallback only stands in for a failed fetch: with st the texture varies over the floor as before."""
    reading = _reading(tmp_path, _material(_image(tmp_path), (0.75, 0.75)), _floor(st=True))
    np.testing.assert_allclose(_seen(reading), [_quadrant(u, v) for u, v in POINTS], atol=1e-4)
    assert not [i for i in reading.issues if i.prim == "/Floor"]
    assert all("st_fallback" not in entry for entry in reading.scene.meshes[0].material.maps)


def test_the_fallback_goes_through_the_transform2d(tmp_path):
    """st' = R(rotation)·(scale ⊙ fallback) + translation ("in * scale * rotate + translation", counter-clockwise
    degrees): (0.1, 0.2) → (0.4, 0.7), the top-left quadrant; unrotated it would be (0.8, 0.7) (top-right),
    untransformed (0.1, 0.2) (bottom-left)."""
    fallback, scale, rotation, translation = (0.1, 0.2), (2.0, 1.0), 90.0, (0.6, 0.5)
    x, y = fallback[0] * scale[0], fallback[1] * scale[1]
    c, s = math.cos(math.radians(rotation)), math.sin(math.radians(rotation))
    st = (c * x - s * y + translation[0], s * x + c * y + translation[1])
    assert st == pytest.approx((0.4, 0.7))
    transform = (f"float2 inputs:scale = {scale}\n        float inputs:rotation = {rotation}\n"
                 f"        float2 inputs:translation = {translation}")
    reading = _reading(tmp_path, _material(_image(tmp_path), fallback, transform=transform))
    np.testing.assert_allclose(_seen(reading), [_quadrant(*st)] * len(POINTS), atol=1e-4)


@pytest.mark.parametrize("wrap, expected", [("repeat", RED), ("mirror", WHITE), ("black", BLACK)])
def test_the_fallback_is_wrapped_scaled_and_biased_as_any_lookup(tmp_path, wrap, expected):
    """st (1.25, −0.25): repeat → (0.25, 0.75), the top-left quadrant; mirror ("flip and repeat") → (2 − 1.25,
    −(−0.25)) = (0.75, 0.25), the bottom-right one; black → transparent black ("outside unit square"); then value
    = scale · texel + bias."""
    scale, bias = (0.5, 0.5, 0.5, 1.0), (0.1, 0.2, 0.3, 0.0)
    inputs = (RAW + f'\n        token inputs:wrapS = "{wrap}"\n        token inputs:wrapT = "{wrap}"'
              f"\n        float4 inputs:scale = {scale}\n        float4 inputs:bias = {bias}")
    reading = _reading(tmp_path, _material(_image(tmp_path), (1.25, -0.25), inputs=inputs))
    value = np.array(expected) * scale[:3] + bias[:3]
    np.testing.assert_allclose(_seen(reading), [value] * len(POINTS), atol=1e-4)


def test_an_implicit_gprim_shows_the_texture_at_the_fallback(tmp_path):
    """A Cube has no texture coordinates: its top face shows the texture at (0.75, 0.75), the top-right quadrant."""
    reading = _reading(tmp_path, _material(_image(tmp_path), (0.75, 0.75)), _cube())
    np.testing.assert_allclose(_seen(reading), [BLUE] * len(POINTS), atol=1e-4)
    assert [i.message for i in reading.issues if i.prim == "/Block"] == [
        "Cube gprims have no texture coordinates; the textures are read at the primvar reader's fallback st "
        "(0.75, 0.75)"]


def test_each_texture_reads_its_own_readers_fallback(tmp_path):
    """Two textures with readers of different fallbacks: each is read at its own (every st maps to it); a
    tangent-space normal map, which has no tangent frame without texture coordinates, is not applied. Reported."""
    file = _image(tmp_path)
    material = _material(file, (0.25, 0.75)).replace("        token outputs:surface\n", """\
        color3f inputs:diffuseColor.connect = </Glow/Second.outputs:rgb>
        normal3f inputs:normal.connect = </Glow/Second.outputs:rgb>
        token outputs:surface
""", 1).replace("color3f inputs:diffuseColor = (0, 0, 0)\n", "", 1).replace("}\n}\n", f"""}}
    def Shader "Second"
    {{
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @{file}@
        {RAW}
        float2 inputs:st.connect = </Glow/SecondReader.outputs:result>
        float3 outputs:rgb
    }}
    def Shader "SecondReader"
    {{
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname = "st"
        float2 inputs:fallback = (0.75, 0.25)
        float2 outputs:result
    }}
}}
""", 1)
    reading = _reading(tmp_path, material)
    (mesh,) = reading.scene.meshes
    moved = {entry["input"]: entry["st_transform"] for entry in mesh.material.maps}
    assert moved == {"emissiveColor": ((0.0, 0.0, 0.25), (0.0, 0.0, 0.75)),
                     "diffuseColor": ((0.0, 0.0, 0.75), (0.0, 0.0, 0.25))}  # st ↦ the reader's fallback
    assert [i.message for i in reading.issues if i.prim == "/Floor"] == [
        "textures read primvar 'st', which the mesh does not have; the textures are read at their primvar readers' "
        "fallback st: (0.75, 0.25) (diffuseColor), (0.25, 0.75) (emissiveColor); the normal map is not applied (no "
        "tangent frame without texture coordinates)"]


# --- MaterialX -----------------------------------------------------------------------------------------------------
def test_a_materialx_image_without_texture_coordinates_reads_st_zero(tmp_path):
    """``image``'s texcoord defaults to the geometry's UV0 (``texcoord`` index 0), whose output defaults to zero
    where the geometry has none: the lower-left texel with clamped address modes — authored in USD and in a
    document."""
    file = _image(tmp_path)
    in_usd = glowing_mtlx_material("Glow", "</Glow/Image.outputs:out>", f"""
    def Shader "Image"
    {{
        uniform token info:id = "ND_image_color3"
        asset inputs:file = @{file}@
        string inputs:uaddressmode = "clamp"
        string inputs:vaddressmode = "clamp"
        color3f outputs:out
    }}""")
    np.testing.assert_allclose(_seen(_reading(tmp_path, in_usd, name="usd")), [CORNER] * len(POINTS), atol=1e-4)
    (tmp_path / "glow.mtlx").write_text(glowing_mtlx_document(
        f'<image name="img" type="color3"><input name="file" type="filename" value="{file}" />'
        '<input name="uaddressmode" type="string" value="clamp" />'
        '<input name="vaddressmode" type="string" value="clamp" /></image>', "img"))
    looks = 'def Scope "Looks" (\n    references = @./glow.mtlx@</MaterialX>\n)\n{\n}\n'
    reading = _reading(tmp_path, looks, _floor("/Looks/Materials/Glow"), name="document")
    np.testing.assert_allclose(_seen(reading), [CORNER] * len(POINTS), atol=1e-4)


# --- stores re-bake ------------------------------------------------------------------------------------------------
def test_the_scene_hash_follows_the_fallback_only_where_it_is_read(tmp_path):
    """A changed fallback changes what a mesh without st shows, so the environment hash (what decides a re-bake)
    changes; on a mesh with st it shows nothing different and the hash stays. The scene as bakery read it before
    (the texture dropped, its mean the constant: no maps, no texture coordinates) hashes differently too, so stores
    baked with the means re-bake."""
    file = _image(tmp_path)

    def scene(fallback, st: bool):  # noqa: ANN001, ANN202
        return _reading(tmp_path, _material(file, fallback), _floor(st=st), name=f"h{fallback}{st}").scene

    assert environment_hash(scene((0.25, 0.75), False)) != environment_hash(scene((0.75, 0.25), False))
    assert environment_hash(scene((0.25, 0.75), True)) == environment_hash(scene((0.75, 0.25), True)) \
        == environment_hash(scene(None, True))
    now = scene(None, False)
    (mesh,) = now.meshes
    before = dataclasses.replace(now, meshes=type(now.meshes)(
        [dataclasses.replace(mesh, material=dataclasses.replace(mesh.material, maps=()), uvs=None)]))
    assert environment_hash(now) != environment_hash(before)
