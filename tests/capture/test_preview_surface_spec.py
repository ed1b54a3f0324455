"""UsdUVTexture, UsdPrimvarReader_float2 and UsdTransform2d read as the UsdPreviewSurface specification (OpenUSD
``docs/spec_usdpreviewsurface.rst``, version 2.5) says, and MaterialX ``image`` nodes as the MaterialX specification
says — closed forms, never numbers the code produced.

Every scene is an emissive, black, specular-free floor (``usd_scenes.textured_floor``: st = ((x + 1)/2, (1 − z)/2))
whose emission is a texture; a probe just above floor point p looks straight down and sees exactly the texture at p's
texture coordinates. The test image's quadrants, as viewed on a monitor (row 0 at the top): top-left red, top-right
blue, bottom-left green, bottom-right white. The specification: "the (0, 0) st coordinate maps to a (0, 0) uv
coordinate that samples the lower-left-hand corner of the texture image, as viewed on a monitor, while the (1, 1)
st coordinate ... samples the upper-right-hand corner"."""

from __future__ import annotations

import math
import struct
import zlib

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
from bakery.usd.scene import read_scene

RED, BLUE, GREEN, WHITE, BLACK = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)
QUADRANTS = {"top-left": RED, "top-right": BLUE, "bottom-left": GREEN, "bottom-right": WHITE}
N = 8  # texels a side of the test image


def _srgb_eotf(c: float) -> float:
    """IEC 61966-2-1: c/12.92 for c ≤ 0.04045, else ((c + 0.055)/1.055)^2.4."""
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def _quadrant_pixels(colours=QUADRANTS) -> np.ndarray:  # noqa: ANN001
    pixels = np.zeros((N, N, 3), dtype=np.float32)
    h = N // 2
    pixels[:h, :h], pixels[:h, h:] = colours["top-left"], colours["top-right"]
    pixels[h:, :h], pixels[h:, h:] = colours["bottom-left"], colours["bottom-right"]
    return pixels


def _write_image(path, pixels: np.ndarray, fmt=oiio.FLOAT, attributes=None):  # noqa: ANN001, ANN202
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(pixels)
    out.close()
    return path


def _write_png(path, value: int, channels: int, chunks: dict[bytes, bytes] | None = None,  # noqa: ANN001, ANN202
               alpha: int = 255):
    """A 4 × 4 8-bit PNG of one grey level (and ``alpha`` in a 2nd/4th channel) with exactly the ancillary
    ``chunks`` given (OpenImageIO's writer adds sRGB/gAMA chunks of its own)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[channels]
    texel = [value] * channels if channels in (1, 3) else [value] * (channels - 1) + [alpha]
    rows = b"".join(b"\x00" + bytes(texel * 4) for _ in range(4))
    body = chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, colour_type, 0, 0, 0))
    body += b"".join(chunk(kind, data) for kind, data in (chunks or {}).items())
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + body + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
    return path


_texture_material = uv_texture_material


def _floor(material_path: str, st=((0, 0), (1, 0), (1, 1), (0, 1))) -> str:  # noqa: ANN001
    """The shared 2 m textured floor (:func:`usd_scenes.textured_floor`) with texture coordinates ``st`` at its
    corners (−1, 1), (1, 1), (1, −1), (−1, −1) (x, z)."""
    return textured_floor(material_path, st=st)


def _seen(tmp_path, material: str, points, floor: str | None = None, extra_header: str = ""):  # noqa: ANN001, ANN202
    """(colours straight below probes above the floor points (u, v) ∈ [0, 1]² — u along +x, v along −z, the
    default st —, the reading)."""
    floor = _floor("/Glow") if floor is None else floor
    text = header(extra=extra_header) + material + floor + "".join(
        probe(f"P{k}", (2 * u - 1, 0.05, 1 - 2 * v)) for k, (u, v) in enumerate(points))
    reading = read_scene(write(tmp_path / "scene.usda", text))
    assert not reading.errors, reading.errors
    cubes, _ = capture_probes(reading.scene, 16, samples=4, bounces=0)
    d = cube_texel_directions(16)
    down = np.unravel_index(np.argmin(d[..., 1]), d.shape[:3])
    return [cube[down].astype(np.float64) for cube in cubes], reading


def _quadrant(s: float, t: float) -> tuple[float, float, float]:
    """The test image at st in [0, 1)²: t = 0 is the image's bottom row (the specification's orientation)."""
    return QUADRANTS[("top" if t >= 0.5 else "bottom") + "-" + ("left" if s < 0.5 else "right")]


CENTRES = [(0.25, 0.75), (0.75, 0.75), (0.25, 0.25), (0.75, 0.25)]


# --- orientation ---------------------------------------------------------------------------------------------------
def test_st_origin_is_the_lower_left_corner_of_the_image(tmp_path):
    file = _write_image(tmp_path / "quadrants.exr", _quadrant_pixels()).name
    seen, _ = _seen(tmp_path, _texture_material(file, 'token inputs:sourceColorSpace = "raw"'), CENTRES)
    np.testing.assert_allclose(seen, [RED, BLUE, GREEN, WHITE], atol=1e-4)


# --- wrap modes ----------------------------------------------------------------------------------------------------
#: st ∈ [−1, 2]² over the floor: st = 3·(u, v) − 1
WRAP_FLOOR = ((-1, -1), (2, -1), (2, 2), (-1, 2))
WRAP_POINTS = [(-0.25, 0.25), (1.25, 0.25), (0.25, 1.25), (1.75, 1.75), (-0.4, -0.3)]


def _wrapped(st: float, mode: str) -> float | None:
    """The specification's wrap of one coordinate (None: black)."""
    if mode == "repeat":
        return st % 1.0
    if mode == "mirror":  # "flip and repeat texture outside unit square"
        period = st % 2.0
        return period if period < 1.0 else 2.0 - period
    if mode == "clamp":  # "extend edge values outside unit square"
        return min(max(st, 0.0), 1.0 - 1e-9)
    return st if 0.0 <= st < 1.0 else None  # black: "returns black outside unit square"


@pytest.mark.parametrize("mode", ["repeat", "mirror", "clamp", "black", "useMetadata", None])
def test_wrap_modes_outside_the_unit_square(tmp_path, mode):
    """``useMetadata`` — also the fallback when wrapS/wrapT are not authored — "look[s] for wrapS and wrapT metadata
    in the texture file itself ... If the texture contains no such metadata, then fall back to black"; an EXR
    written without a ``wrapmodes`` attribute has none (before: read as repeat)."""
    file = _write_image(tmp_path / "quadrants.exr", _quadrant_pixels()).name
    inputs = 'token inputs:sourceColorSpace = "raw"'
    if mode is not None:
        inputs += f'\n        token inputs:wrapS = "{mode}"\n        token inputs:wrapT = "{mode}"'
    points = [((s + 1) / 3, (t + 1) / 3) for s, t in WRAP_POINTS]
    seen, _ = _seen(tmp_path, _texture_material(file, inputs), points, floor=_floor("/Glow", WRAP_FLOOR))
    effective = mode if mode in ("repeat", "mirror", "clamp") else "black"
    expected = []
    for s, t in WRAP_POINTS:
        ws, wt = _wrapped(s, effective), _wrapped(t, effective)
        expected.append(BLACK if ws is None or wt is None else _quadrant(ws, wt))
    np.testing.assert_allclose(seen, expected, atol=1e-4)


# --- UsdTransform2d ------------------------------------------------------------------------------------------------
def _srt(s: float, t: float, scale, rotation: float, translation) -> tuple[float, float]:  # noqa: ANN001
    """The specification: "result = in * scale * rotate * translation", rotation "Counter-clockwise ... in
    degrees around the origin"."""
    x, y = s * scale[0], t * scale[1]
    c, n = math.cos(math.radians(rotation)), math.sin(math.radians(rotation))
    return c * x - n * y + translation[0], n * x + c * y + translation[1]


def test_transform2d_is_scale_then_rotate_in_degrees_then_translate(tmp_path):
    scale, rotation, translation = (1.5, 0.7), 30.0, (0.35, 0.1)
    file = _write_image(tmp_path / "quadrants.exr", _quadrant_pixels()).name
    inputs = 'token inputs:sourceColorSpace = "raw"\n        token inputs:wrapS = "repeat"\n' \
             '        token inputs:wrapT = "repeat"'
    transform = (f"float2 inputs:scale = {scale}\n        float inputs:rotation = {rotation}\n"
                 f"        float2 inputs:translation = {translation}")

    def margin(s: float, t: float) -> float:  # distance of the transformed point from a quadrant edge
        return min(min(abs(x % 0.5), 0.5 - abs(x % 0.5)) for x in _srt(s, t, scale, rotation, translation))

    grid = [(u, v) for u in np.linspace(0.1, 0.9, 9) for v in np.linspace(0.1, 0.9, 9)]
    points = [p for p in grid if margin(*p) > 0.09][:8]  # well inside a quadrant (texel 1/8, footprint below)
    assert len(points) >= 6
    seen, _ = _seen(tmp_path, _texture_material(file, inputs, transform=transform), points)
    expected = [_quadrant(*(x % 1.0 for x in _srt(u, v, scale, rotation, translation))) for u, v in points]
    np.testing.assert_allclose(seen, expected, atol=1e-3)
    # the other orders and radians would differ at these points: the test tells them apart
    def trs(s: float, t: float):  # noqa: ANN202
        x, y = s + translation[0], t + translation[1]
        c, n = math.cos(math.radians(rotation)), math.sin(math.radians(rotation))
        return (c * x - n * y) * scale[0], (n * x + c * y) * scale[1]
    assert any(_quadrant(*(x % 1 for x in trs(u, v))) != e for (u, v), e in zip(points, expected))
    assert any(_quadrant(*(x % 1 for x in _srt(u, v, scale, math.degrees(rotation), translation))) != e
               for (u, v), e in zip(points, expected))


# --- sourceColorSpace ----------------------------------------------------------------------------------------------
LEVEL = 128  # the grey level of the 8-bit files: 128/255


def _grey_files(tmp_path) -> dict[str, tuple[str, str]]:
    """name → (file, how "auto" reads it by the specification: "srgb" or "linear")."""
    g = np.full((4, 4, 3), LEVEL / 255, dtype=np.float32)
    return {
        # "mark texture as sRGB if it is either 8-bit and has 3 channels or if it is 8-bit and has 4 channels"
        "png8 rgb, no chunks": (_write_png(tmp_path / "rgb8.png", LEVEL, 3).name, "srgb"),
        "png8 rgba, no chunks": (_write_png(tmp_path / "rgba8.png", LEVEL, 4).name, "srgb"),
        "jpeg8 rgb": (_write_image(tmp_path / "rgb8.jpg", g, oiio.UINT8).name, "srgb"),
        # "Otherwise, do not mark texture as sRGB and use texture data as it was read from the texture"
        "png8 grey, no chunks": (_write_png(tmp_path / "grey8.png", LEVEL, 1).name, "linear"),
        "png8 grey+alpha, no chunks": (_write_png(tmp_path / "greyalpha8.png", LEVEL, 2).name, "linear"),
        "tiff16 rgb": (_write_image(tmp_path / "rgb16.tif", g, oiio.UINT16).name, "linear"),
        "exr half rgb": (_write_image(tmp_path / "rgb.exr", g, oiio.HALF).name, "linear"),
        # "Check for gamma/color space metadata in the texture file itself; if metadata is indicative of sRGB, mark
        # texture as sRGB" (a PNG sRGB chunk, a gAMA of 1/2.2) — and a gAMA of 1 is linear
        "png8 grey, sRGB chunk": (_write_png(tmp_path / "grey8srgb.png", LEVEL, 1, {b"sRGB": b"\x00"}).name, "srgb"),
        "png8 grey, gAMA 1/2.2": (_write_png(tmp_path / "grey8g.png", LEVEL, 1,
                                             {b"gAMA": struct.pack(">I", 45455)}).name, "srgb"),
        "png8 rgb, gAMA 1": (_write_png(tmp_path / "rgb8lin.png", LEVEL, 3,
                                        {b"gAMA": struct.pack(">I", 100000)}).name, "linear"),
    }


def test_source_color_space_auto_raw_and_srgb(tmp_path):
    files = _grey_files(tmp_path)
    stored = {name: (LEVEL / 255 if "8" in name else (0.5 if "exr" in name else round(LEVEL / 255 * 65535) / 65535))
              for name in files}
    stored["exr half rgb"] = float(np.float16(LEVEL / 255))
    for mode in ("auto", "raw", "sRGB"):
        for name, (file, auto) in files.items():
            seen, _ = _seen(tmp_path, _texture_material(file, f'token inputs:sourceColorSpace = "{mode}"'),
                            [(0.5, 0.5)])
            decode = mode == "sRGB" or (mode == "auto" and auto == "srgb")
            expected = _srgb_eotf(stored[name]) if decode else stored[name]
            np.testing.assert_allclose(seen[0], [expected] * 3, rtol=2e-4, err_msg=f"{name}, {mode}")


def test_srgb_decode_of_128_is_the_iec_formula(tmp_path):
    """128/255 decodes to ((128/255 + 0.055)/1.055)^2.4 = 0.2158605 (IEC 61966-2-1)."""
    file = _write_png(tmp_path / "rgb8.png", 128, 3).name
    seen, _ = _seen(tmp_path, _texture_material(file, 'token inputs:sourceColorSpace = "sRGB"'), [(0.5, 0.5)])
    np.testing.assert_allclose(seen[0], [0.2158605] * 3, rtol=1e-5)


def test_png_colours_are_straight_alpha(tmp_path):
    """"All color inputs to the UsdPreviewSurface are straight alpha (no pre-multiplication)" and PNG stores
    straight alpha: the rgb output of a texel (200, 200, 200, 128) is exactly 200/255, not 200/255 · 128/255 (as
    read before: OpenImageIO premultiplies PNG colours on reading unless asked not to). The a output is 128/255."""
    file = _write_png(tmp_path / "half.png", 200, 4, alpha=128).name
    seen, _ = _seen(tmp_path, _texture_material(file, 'token inputs:sourceColorSpace = "raw"'), [(0.5, 0.5)])
    np.testing.assert_allclose(seen[0], [200 / 255] * 3, atol=1e-6)
    seen, _ = _seen(tmp_path, _texture_material(file, 'token inputs:sourceColorSpace = "raw"', "a"), [(0.5, 0.5)])
    np.testing.assert_allclose(seen[0], [128 / 255] * 3, atol=1e-6)


# --- scale, bias, outputs ------------------------------------------------------------------------------------------
ALPHAS = {"top-left": 0.1, "top-right": 0.3, "bottom-left": 0.6, "bottom-right": 0.9}


def _rgba_file(tmp_path) -> str:
    alpha = _quadrant_pixels({k: (a, a, a) for k, a in ALPHAS.items()})[..., :1]
    return _write_image(tmp_path / "rgba.exr", np.concatenate([_quadrant_pixels(), alpha], axis=2)).name


@pytest.mark.parametrize("output", ["r", "g", "b", "a", "rgb"])
def test_outputs_scale_and_bias(tmp_path, output):
    """"output = textureValue * scale + bias", per component; r, g, b, a are single channels."""
    scale, bias = (0.5, 2.0, 0.25, 3.0), (0.1, 0.2, 0.3, -0.2)
    inputs = f'token inputs:sourceColorSpace = "raw"\n        float4 inputs:scale = {scale}\n' \
             f'        float4 inputs:bias = {bias}'
    seen, _ = _seen(tmp_path, _texture_material(_rgba_file(tmp_path), inputs, output), CENTRES)
    for (u, v), colour in zip(CENTRES, seen):
        texel = np.array([*_quadrant(u, v), ALPHAS[("top" if v >= 0.5 else "bottom") + "-" +
                                                    ("left" if u < 0.5 else "right")]])
        value = texel * scale + bias
        expected = value[:3] if output == "rgb" else [value["rgba".index(output)]] * 3
        np.testing.assert_allclose(colour, expected, atol=1e-4)


@pytest.mark.parametrize(("channels", "alpha"), [(1, 1.0), (2, 0.25), (3, 1.0)])
def test_alpha_of_one_two_and_three_channel_files(tmp_path, channels, alpha):
    """"If a single-channel texture is fed into a UsdUVTexture, the r, g, and b components of the rgb output will
    repeat the channel's value, while the single a output will be set to 1.0. If a two-channel texture ..., the
    single a output will be set to the second channel's value"; three channels: a = 1."""
    pixels = np.full((4, 4, channels), 0.6, dtype=np.float32)
    if channels == 2:
        pixels[..., 1] = 0.25
    file = _write_image(tmp_path / f"c{channels}.exr", pixels).name
    for output, expected in (("a", alpha), ("r", 0.6)):
        seen, _ = _seen(tmp_path, _texture_material(file, 'token inputs:sourceColorSpace = "raw"', output),
                        [(0.5, 0.5)])
        np.testing.assert_allclose(seen[0], [expected] * 3, atol=1e-5)


# --- fallback ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("what", ["missing", "unreadable", "no file"])
@pytest.mark.parametrize(("output", "expected"), [("rgb", (0.2, 0.4, 0.6)), ("a", (0.5, 0.5, 0.5))])
def test_a_texture_that_cannot_be_read_gives_its_fallback(tmp_path, what, output, expected):
    """"fallback - float4 - (0.0, 0.0, 0.0, 1.0): Fallback value used when texture can not be read" (Sdr: "to be
    returned when no texture is connected"), with a warning naming the texture (before: the surface input's own
    value)."""
    (tmp_path / "broken.png").write_bytes(b"not an image")
    file = {"missing": "missing.png", "unreadable": "broken.png", "no file": ""}[what]
    material = _texture_material(file, "float4 inputs:fallback = (0.2, 0.4, 0.6, 0.5)", output)
    if not file:
        material = material.replace("asset inputs:file = @@", "")
    seen, reading = _seen(tmp_path, material, [(0.5, 0.5)])
    np.testing.assert_allclose(seen[0], expected, atol=1e-6)
    assert [i for i in reading.issues if i.severity == "warning" and "fallback" in i.message], reading.issues


# --- UDIM ----------------------------------------------------------------------------------------------------------
def test_udim_tiles_by_their_numbers_and_each_tile_lower_left_origin(tmp_path):
    """Tile 1001 + ⌊s⌋ + 10·⌊t⌋ (Mari's UDIM numbering; the specification: tiles in [1001, 1100], at most ten in
    u) read at (s − ⌊s⌋, t − ⌊t⌋) with the same orientation as a single image."""
    (tmp_path / "tiles").mkdir()
    _write_image(tmp_path / "tiles" / "t.1001.exr", _quadrant_pixels())
    _write_image(tmp_path / "tiles" / "t.1002.exr", np.full((N, N, 3), 0.25, dtype=np.float32))
    _write_image(tmp_path / "tiles" / "t.1011.exr", np.full((N, N, 3), 0.75, dtype=np.float32))
    floor = _floor("/Glow", ((0, 0), (2, 0), (2, 2), (0, 2)))  # st = 2·(u, v)
    material = _texture_material("./tiles/t.<UDIM>.exr", 'token inputs:sourceColorSpace = "raw"')
    st_points = [(0.25, 0.75), (0.75, 0.25), (1.5, 0.5), (0.5, 1.5), (1.5, 1.5)]
    seen, _ = _seen(tmp_path, material, [(s / 2, t / 2) for s, t in st_points], floor=floor)
    np.testing.assert_allclose(seen, [RED, WHITE, (0.25,) * 3, (0.75,) * 3, BLACK], atol=1e-4)  # 1012: missing


# --- MaterialX image ------------------------------------------------------------------------------------------------
def test_materialx_image_has_the_same_orientation(tmp_path):
    """MaterialX texture space: (0, 0) is the lower-left corner of the image as well ("texture coordinates ... the
    image's lower-left corner at (0, 0)"), so an ``image`` node sees what UsdUVTexture sees — in a document and
    authored in USD."""
    file = _write_image(tmp_path / "quadrants.exr", _quadrant_pixels()).name
    in_usd = glowing_mtlx_material("Glow", "</Glow/Image.outputs:out>", f"""
    def Shader "Image"
    {{
        uniform token info:id = "ND_image_color3"
        asset inputs:file = @{file}@
        color3f outputs:out
    }}""")
    seen, _ = _seen(tmp_path, in_usd, CENTRES)
    np.testing.assert_allclose(seen, [RED, BLUE, GREEN, WHITE], atol=1e-4)
    (tmp_path / "glow.mtlx").write_text(glowing_mtlx_document(
        f'<image name="img" type="color3"><input name="file" type="filename" value="{file}" /></image>', "img"))
    looks = 'def Scope "Looks" (\n    references = @./glow.mtlx@</MaterialX>\n)\n{\n}\n'
    seen, _ = _seen(tmp_path, looks, CENTRES, floor=_floor("/Looks/Materials/Glow"))
    np.testing.assert_allclose(seen, [RED, BLUE, GREEN, WHITE], atol=1e-4)


def test_materialx_colorspace_attribute_decodes_srgb(tmp_path):
    """``colorspace="srgb_texture"`` on a file input: the sRGB EOTF; ``lin_rec709``: as stored."""
    file = _write_png(tmp_path / "rgb8.png", LEVEL, 3).name
    looks = 'def Scope "Looks" (\n    references = @./glow.mtlx@</MaterialX>\n)\n{\n}\n'
    for space, expected in (("srgb_texture", _srgb_eotf(LEVEL / 255)), ("lin_rec709", LEVEL / 255)):
        (tmp_path / "glow.mtlx").write_text(glowing_mtlx_document(
            f'<image name="img" type="color3"><input name="file" type="filename" value="{file}" '
            f'colorspace="{space}" /></image>', "img"))
        seen, _ = _seen(tmp_path, looks, [(0.5, 0.5)], floor=_floor("/Looks/Materials/Glow"))
        np.testing.assert_allclose(seen[0], [expected] * 3, rtol=2e-4, err_msg=space)


# --- asset paths ---------------------------------------------------------------------------------------------------
def test_texture_path_is_relative_to_the_layer_that_authors_it(tmp_path):
    """A material in a sublayer in another folder: its ``@./tex/q.exr@`` is resolved against that sublayer (asset
    paths are anchored to their layer), not against the root layer, where a decoy of the same name lies."""
    (tmp_path / "lib" / "tex").mkdir(parents=True)
    (tmp_path / "tex").mkdir()
    _write_image(tmp_path / "lib" / "tex" / "q.exr", _quadrant_pixels())
    _write_image(tmp_path / "tex" / "q.exr", np.full((N, N, 3), 0.3, dtype=np.float32))
    write(tmp_path / "lib" / "looks.usda", header() + _texture_material("./tex/q.exr",
                                                                          'token inputs:sourceColorSpace = "raw"'))
    seen, _ = _seen(tmp_path, "", CENTRES, extra_header="    subLayers = [@./lib/looks.usda@]\n")
    np.testing.assert_allclose(seen, [RED, BLUE, GREEN, WHITE], atol=1e-4)


def test_exif_orientation_is_not_applied(tmp_path):
    """Hydra's texture readers hand the stored rows to the GPU (Hio's stb reader: stbi_load plus a vertical flip;
    stb_image reads no EXIF), so a JPEG's EXIF ``Orientation`` does not turn the texture: the stored top-left
    quadrant is at st (¼, ¾) whatever the tag says."""
    file = _write_image(tmp_path / "turned.jpg", _quadrant_pixels(), oiio.UINT8, {"Orientation": 6}).name
    seen, _ = _seen(tmp_path, _texture_material(file, 'token inputs:sourceColorSpace = "raw"'), CENTRES)
    np.testing.assert_allclose(seen, [RED, BLUE, GREEN, WHITE], atol=0.02)  # JPEG: lossy
