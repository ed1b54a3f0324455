"""Environment image files bakery has never seen: orientations, windows, primaries, layers and broken files.

Every expected value comes from the file format's definition written out here (the Radiance resolution line, the
OpenEXR data/display windows, the ACES primaries' published matrix) or a closed form (a sky lit above the horizon
gives E(up) = π·L, E(down) = 0), never from the functions under test."""

from __future__ import annotations

import os
import warnings

import numpy as np
import OpenImageIO as oiio
import pytest

from bakery.environment import EnvironmentImage, environment_samples
from bakery.environment import resample as resample_module
from bakery.environment.io import read_environment
from bakery.environment.layouts import layout_directions_and_density
from bakery.environment.sanitize import sanitize_radiance
from bakery.errors import BakeryWarning, ImageError

H, W = 16, 32


def latlong_directions(height=H, width=W):
    """Texel-centre directions of a latlong by the convention's formula (row 0 zenith, column 0 longitude +π)."""
    latitude = np.pi * (0.5 - (np.arange(height) + 0.5) / height)[:, None]
    longitude = 2.0 * np.pi * (0.5 - (np.arange(width) + 0.5) / width)[None, :]
    return np.stack(np.broadcast_arrays(np.cos(latitude) * np.sin(longitude), np.sin(latitude),
                                        np.cos(latitude) * np.cos(longitude)), axis=-1)


def marked_sky(height=H, width=W):
    """1 above the horizon, 0 below, and 4 in the texels within 30° of +X: no flip or turn of it is itself."""
    d = latlong_directions(height, width)
    image = np.repeat((d[..., 1:2] > 0).astype(np.float32), 3, axis=2)
    image[d[..., 0] > np.cos(np.radians(30))] = 4.0
    return image


def irradiance(image, normals):
    samples = environment_samples(image)
    cosine = np.maximum(0.0, samples.directions @ np.asarray(normals, float).T)
    return np.einsum("kn,k,kc->nc", cosine, samples.solid_angles, samples.radiance)


def write(path, pixels, fmt=oiio.FLOAT, setup=None):
    pixels = np.asarray(pixels, dtype=np.float32)
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], fmt)
    if setup:
        setup(spec)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(pixels), out.geterror()
    out.close()


def read_quietly(path, **kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        image, report = read_environment(path, **kwargs)
    return image, [str(w.message) for w in caught]


# ---------------------------------------------------------------------------------------------------------------
# Radiance resolution lines
def rgbe(values):
    """Flat RGBE bytes of values that are 0 or a power of two times a byte/256 (exact: 1 → (128,128,128,129))."""
    peak = values.max(axis=-1)
    exponent = np.where(peak > 0, np.floor(np.log2(np.maximum(peak, 1e-30))) + 1, 0).astype(int)
    mantissa = np.where(peak[..., None] > 0, values * (256.0 / 2.0 ** exponent[..., None]), 0)
    return np.concatenate([mantissa, np.where(peak > 0, exponent + 128, 0)[..., None]], axis=-1).astype(np.uint8)


def write_radiance(path, image, resolution, fmt=b"32-bit_rle_rgbe", extra=b""):
    """``image`` (row 0 the top, column 0 the left) stored as the Radiance resolution line says (resolu.h: the first
    axis orders the scanlines, the second the pixels in each; +X is rightwards, +Y upwards)."""
    first, second = resolution.split()
    if first[1] == "Y":  # scanlines are rows: -Y lists them top down
        scanlines = image if first[0] == "-" else image[::-1]
        scanlines = scanlines if second[0] == "+" else scanlines[:, ::-1]
        line = f"{first} {image.shape[0]} {second} {image.shape[1]}"
    else:  # scanlines are columns: +X lists them left to right, -Y each from the top down
        scanlines = np.swapaxes(image, 0, 1)
        scanlines = scanlines if first[0] == "+" else scanlines[::-1]
        scanlines = scanlines if second[0] == "-" else scanlines[:, ::-1]
        line = f"{first} {image.shape[1]} {second} {image.shape[0]}"
    header = b"#?RADIANCE\nFORMAT=" + fmt + b"\n" + extra + b"\n" + line.encode() + b"\n"
    path.write_bytes(header + rgbe(np.ascontiguousarray(scanlines)).tobytes())


@pytest.mark.parametrize("resolution", ["-Y +X", "-Y -X", "+Y -X", "+Y +X", "+X -Y", "-X -Y", "-X +Y", "+X +Y"])
def test_every_radiance_resolution_line_reads_upright(tmp_path, resolution):
    """Before, only "-Y +X" read right: "+Y +X" (bottom row first) baked the sky upside down, "-Y -X" mirrored, and
    the column-major lines were refused as 1:2 images (or, forced, transposed)."""
    path = tmp_path / "sky.hdr"
    write_radiance(path, marked_sky(), resolution)
    image, messages = read_quietly(path)
    assert image.layout == "equirect" and messages == []
    np.testing.assert_array_equal(image.pixels, marked_sky())


def test_an_upside_down_radiance_sky_lights_from_above(tmp_path):
    """L = 1 above the horizon: E(up) = π, E(down) = 0, E(horizon) = π/2 — not the mirror image."""
    path = tmp_path / "flipped.hdr"
    sky = np.repeat((latlong_directions()[..., 1:2] > 0).astype(np.float32), 3, axis=2)
    write_radiance(path, sky, "+Y +X")
    image, _ = read_quietly(path)
    e = irradiance(image, [[0, 1, 0], [0, -1, 0], [1, 0, 0]])
    np.testing.assert_allclose(e[:, 0], [np.pi, 0.0, np.pi / 2], atol=0.02)  # 16 rows of texel-centre cosines


def test_radiance_exposure_primaries_and_xyze(tmp_path):
    sky = marked_sky()
    exposed = tmp_path / "exposed.hdr"
    write_radiance(exposed, sky, "-Y +X", extra=b"EXPOSURE=0.5\n")
    image, messages = read_quietly(exposed)
    np.testing.assert_array_equal(image.pixels, sky)  # as stored, as renderers read it; said once
    assert len(messages) == 1 and "EXPOSURE=0.5 not applied" in messages[0]
    # the primaries of the header (Rec.2020, D65) convert to Rec.709 like OpenEXR chromaticities (below)
    primaries = tmp_path / "rec2020.hdr"
    grey = np.full((H, W, 3), 0.5, np.float32)
    grey[0, 0] = (0.5, 0.75, 0.625)
    write_radiance(primaries, grey, "-Y +X", extra=b"PRIMARIES=0.708 0.292 0.170 0.797 0.131 0.046 0.3127 0.3290\n")
    image, messages = read_quietly(primaries)
    np.testing.assert_allclose(image.pixels[0, 0], REC2020_TO_REC709 @ [0.5, 0.75, 0.625], atol=2e-4)
    np.testing.assert_allclose(image.pixels[5, 5], [0.5, 0.5, 0.5], atol=1e-5)  # white stays white
    assert len(messages) == 1 and "converted to linear Rec.709" in messages[0]
    # all zero: "not specified", as Photoshop writes it (every Poly Haven .hdr): Rec.709, and nothing to say
    unspecified = tmp_path / "photoshop.hdr"
    write_radiance(unspecified, sky, "-Y +X", extra=b"PRIMARIES=0 0 0 0 0 0 0 0\n")
    image, messages = read_quietly(unspecified)
    np.testing.assert_array_equal(image.pixels, sky)
    assert messages == []
    xyze = tmp_path / "xyz.hdr"
    write_radiance(xyze, sky, "-Y +X", fmt=b"32-bit_rle_xyze")
    with pytest.raises(ImageError, match=r"xyz\.hdr: .*'32-bit_rle_xyze' is not supported"):
        read_environment(xyze)


# ---------------------------------------------------------------------------------------------------------------
# OpenEXR windows, parts, channels
def windows(x, y, full=(0, 0, W, H)):
    def setup(spec):
        spec.x, spec.y = x, y
        spec.full_x, spec.full_y, spec.full_width, spec.full_height = full
    return setup


def test_the_data_window_is_placed_in_the_display_window(tmp_path):
    """OpenEXR's frame is the display window; texels outside the data window are black (an auto-cropped EXR) and
    data outside it is dropped (overscan). Before, the data window alone was the image: a 32 × 8 upper half was
    refused as 4:1, a lower half at y = 8 read as the sky, and a window shifted by 5 columns turned the sky 56°."""
    upper = tmp_path / "upper.exr"
    write(upper, np.ones((H // 2, W, 3)), setup=windows(0, 0))
    image, messages = read_quietly(upper)
    assert image.pixels.shape == (H, W, 3) and messages == []
    np.testing.assert_allclose(irradiance(image, [[0, 1, 0], [0, -1, 0], [1, 0, 0]])[:, 0],
                               [np.pi, 0.0, np.pi / 2], atol=0.02)  # 16 rows of texel-centre cosines
    lower = tmp_path / "lower.exr"
    write(lower, np.ones((H // 2, W, 3)), setup=windows(0, H // 2))
    image, _ = read_quietly(lower)
    np.testing.assert_allclose(irradiance(image, [[0, 1, 0], [0, -1, 0]])[:, 0], [0.0, np.pi], atol=0.02)

    shifted = tmp_path / "shifted.exr"
    write(shifted, marked_sky(), setup=windows(5, 0))
    image, _ = read_quietly(shifted)
    np.testing.assert_array_equal(image.pixels[:, 5:], marked_sky()[:, :-5])
    np.testing.assert_array_equal(image.pixels[:, :5], 0.0)

    overscan = tmp_path / "overscan.exr"
    big = np.zeros((H + 6, W + 8, 3), np.float32)
    big[3:3 + H, 4:4 + W] = marked_sky()
    write(overscan, big, setup=windows(-4, -3))
    image, _ = read_quietly(overscan)
    np.testing.assert_array_equal(image.pixels, marked_sky())


def test_an_openexr_cube_map_keeps_its_data_window(tmp_path):
    """OpenEXR environment maps live on the data window (ImfEnvmap); a cube's display window is one face."""
    n = 8
    faces = np.zeros((6, n, n, 3), np.float32)
    faces[2] = 1.0  # +Y

    def setup(spec):
        spec.attribute("textureformat", "CubeFace Environment")
        spec.full_width, spec.full_height = n, n

    path = tmp_path / "cube.exr"
    write(path, faces.reshape(6 * n, n, 3), setup=setup)
    image, _ = read_quietly(path)
    assert image.layout == "cube" and image.pixels.shape == (6 * n, n, 3)


# ACES AP1 (ACEScg) → Rec.709 with Bradford D60 → D65, as published (ACES; OpenColorIO's built-in configs); and
# Rec.2020 → Rec.709 (same white): ITU-R BT.2087's inverse.
AP1_TO_REC709 = np.array([[1.70505, -0.62179, -0.08326], [-0.13026, 1.14080, -0.01055], [-0.02400, -0.12897, 1.15297]])
REC2020_TO_REC709 = np.array([[1.6605, -0.5876, -0.0728], [-0.1246, 1.1329, -0.0083], [-0.0182, -0.1006, 1.1187]])
AP1 = (0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767)


@pytest.mark.parametrize("tag", ["chromaticities", "colour space"])
def test_acescg_files_are_converted_to_rec709(tmp_path, tag):
    """An ACEScg EXR (its chromaticities, or OpenImageIO's colour space from its colorInteropID) was read as Rec.709:
    a saturated sky 70 % too red. The bake's colour is linear Rec.709 (conventions)."""
    colour = np.array([0.5, 0.6, 0.7], np.float32)  # inside both gamuts
    pixels = np.tile(colour, (H, W, 1))

    def setup(spec):
        if tag == "chromaticities":
            spec.attribute("chromaticities", oiio.TypeDesc("float[8]"), AP1)
        else:
            spec.attribute("oiio:ColorSpace", "ACEScg")

    path = tmp_path / "acescg.exr"
    write(path, pixels, setup=setup)
    image, messages = read_quietly(path)
    np.testing.assert_allclose(image.pixels[3, 7], AP1_TO_REC709 @ colour, atol=2e-5)
    assert len(messages) == 1 and "converted to linear Rec.709" in messages[0] and "acescg.exr" in messages[0]
    rec709 = tmp_path / "rec709.exr"  # the default chromaticities many writers store: read as they are, silently
    write(rec709, pixels, setup=lambda spec: spec.attribute("chromaticities", oiio.TypeDesc("float[8]"),
                                                            (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)))
    image, messages = read_quietly(rec709)
    np.testing.assert_array_equal(image.pixels, pixels)
    assert messages == []
    raw, _ = read_quietly(path, decode="raw")  # callers with their own colour management get the values as stored
    np.testing.assert_array_equal(raw.pixels, pixels)


def test_parts_layers_and_alpha_only_files_say_what_they_read(tmp_path):
    multipart = tmp_path / "multipart.exr"
    first, second = oiio.ImageSpec(W, H, 3, oiio.FLOAT), oiio.ImageSpec(W, H, 3, oiio.FLOAT)
    first.attribute("name", "albedo")
    second.attribute("name", "beauty")
    out = oiio.ImageOutput.create(str(multipart))
    assert out.open(str(multipart), [first, second])
    out.write_image(np.full((H, W, 3), 0.5, np.float32))
    out.open(str(multipart), second, "AppendSubimage")
    out.write_image(marked_sky())
    out.close()
    image, messages = read_quietly(multipart)
    np.testing.assert_array_equal(image.pixels, 0.5)
    assert len(messages) == 1 and "2 subimages" in messages[0] and "'albedo'" in messages[0]

    layered = tmp_path / "layers.exr"

    def names(spec):
        spec.channelnames = ["diffuse.R", "diffuse.G", "diffuse.B", "specular.R", "specular.G", "specular.B"]

    write(layered, np.concatenate([np.full((H, W, 3), 0.5), marked_sky()], axis=2), setup=names)
    image, messages = read_quietly(layered)
    assert len(messages) == 1 and "read diffuse.R, diffuse.G, diffuse.B as RGB" in messages[0]

    alpha = tmp_path / "alpha.exr"
    write(alpha, np.ones((H, W, 1)), setup=lambda spec: setattr(spec, "channelnames", ["A"]))
    with pytest.raises(ImageError, match=r"alpha\.exr: its first channel is alpha"):
        read_environment(alpha)


def test_empty_files_and_pipes_are_named_as_such(tmp_path):
    for name in ("empty.exr", "empty.hdr"):
        (tmp_path / name).write_bytes(b"")
        with pytest.raises(ImageError, match=rf"{name}: .*empty \(0 bytes\)"):
            read_environment(tmp_path / name)
    pipe = tmp_path / "pipe.exr"  # was "environment image not found"
    os.mkfifo(pipe)
    with pytest.raises(ImageError, match=r"pipe\.exr: not a regular file"):
        read_environment(pipe)


# ---------------------------------------------------------------------------------------------------------------
# The reference quadrature in bands, and sanitising's fast path
@pytest.mark.parametrize("layout,height,width", [("equirect", 24, 48), ("angular", 24, 24),
                                                 ("vertical_cross", 32, 24), ("cube", 48, 8)])
def test_reference_samples_built_in_bands_are_the_texels(monkeypatch, layout, height, width):
    """environment_samples builds a few rows at a time (an 8K latlong: 4.6 → 2.6 GB at the peak); with bands of
    one row the samples are still each valid texel's centre direction, solid angle and radiance, in row order."""
    rng = np.random.default_rng(3)
    image = EnvironmentImage(rng.uniform(0, 2, (height, width, 3)).astype(np.float32), layout)
    monkeypatch.setattr(resample_module, "_SAMPLE_BAND_TEXELS", 1)
    samples = environment_samples(image)
    rows, cols = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    directions, _ = layout_directions_and_density(layout, rows, cols, height, width)
    valid = resample_module.source_texel_solid_angles(image) > 0
    np.testing.assert_array_equal(samples.directions, directions[valid])
    np.testing.assert_array_equal(samples.radiance, image.pixels[valid].astype(np.float64))
    np.testing.assert_allclose(samples.solid_angles.sum(), 4 * np.pi, rtol=1e-12)


def test_clean_radiance_is_reported_without_a_count():
    values = np.array([[0.0, 2.0, 3.0], [1.0, 0.5, 7.0]], np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        clean, report = sanitize_radiance(values)
    assert clean is values or np.array_equal(clean, values)
    assert (report.replaced, report.texels, report.min_value, report.max_value) == (0, 2, 0.0, 7.0)


def test_bake_warnings_are_bakery_warnings(tmp_path):
    path = tmp_path / "layers.exr"
    write(path, np.ones((H, W, 3)), setup=lambda spec: setattr(spec, "channelnames", ["X", "Y", "Z"]))
    with pytest.warns(BakeryWarning, match="read X, Y, Z as RGB"):
        read_environment(path)
