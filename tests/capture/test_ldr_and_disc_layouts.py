"""Environment images read as radiance: integer (LDR) files decoded by their transfer function, and the disc layouts
(angular map, mirrored ball) holding exactly the image's flux at every size they accept.

Expected values are closed forms written out here: the sRGB EOTF of IEC 61966-2-1, E = π·L for a constant
environment, E(n) = π + (2π/3)·n_z for L = 1 + z, and the two disc maps' direction and solid-angle formulas (the
images are built from them, not from the functions under test)."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import numpy as np
import OpenImageIO as oiio
import pytest

import bakery
from bakery.environment.io import read_environment, write_exr
from bakery.environment.layouts import MIN_DISC_SIZE, EnvironmentImage, disc_texel_integrals
from bakery.environment.resample import source_texel_solid_angles
from bakery.errors import ImageError, InputError

NORMALS = np.array([[0, 1.0, 0], [0, -1.0, 0], [1.0, 0, 0], [0, 0, 1.0], [0, 0, -1.0], [0.6, 0, 0.8],
                    [0, -0.6, -0.8], [0.48, 0.6, -0.64]])


def srgb_eotf(c):
    """IEC 61966-2-1: c ≤ 0.04045 → c/12.92, else ((c + 0.055)/1.055)^2.4."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def write_integer(path, pixels, fmt, attributes=None):
    """Write (H, W, 3) values in [0, 1] as an integer image (``fmt``: oiio.UINT8 / oiio.UINT16)."""
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    out.write_image(np.ascontiguousarray(pixels, dtype=np.float32))
    out.close()


def stored_codes(path):
    """The file's values normalised to [0, 1], as OpenImageIO reads them (no colour decoding)."""
    buf = oiio.ImageBuf(str(path))
    return buf.get_pixels(oiio.FLOAT)[..., :3].astype(np.float64)


def bake_irradiance(path, tmp_path, layout=None, face_size=16):
    """Bake ``path`` to sh2 and return (E at NORMALS (N, 3), the bake's summary)."""
    store = tmp_path / f"{path.stem}.h5"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        summary = bakery.bake(path, store, encodings=("sh2",), face_size=face_size, layout=layout,
                              reference_errors=False)
    return bakery.open_store(store).evaluate_irradiance("sh2", NORMALS)[0], summary


# ------------------------------------------------------------------------------------------------ A: LDR colour
@pytest.mark.parametrize("code", [10, 128, 200, 255])
def test_an_8bit_png_bakes_the_srgb_decoded_radiance(tmp_path, code):
    """A constant 8-bit PNG of code/255 bakes E = π·EOTF(code/255) at every normal (128/255 → 0.2158605, not the
    0.502 read before as linear), and the store's warnings say how the file was decoded."""
    path = tmp_path / f"gray{code}.png"
    write_integer(path, np.full((16, 32, 3), code / 255.0), oiio.UINT8)
    expected = float(srgb_eotf(code / 255.0))
    if code == 128:
        assert expected == pytest.approx(0.2158605, abs=5e-8)
    if code == 10:
        assert expected == pytest.approx(10 / 255 / 12.92)  # the linear segment
    irradiance, summary = bake_irradiance(path, tmp_path)
    np.testing.assert_allclose(irradiance, np.pi * expected, rtol=1e-6, atol=1e-12)
    notice = f"{path}: 8-bit image decoded as sRGB to linear radiance"
    assert notice in summary.warnings
    assert notice in bakery.open_store(tmp_path / f"{path.stem}.h5").json_attribute("warnings")


def test_integer_files_follow_openimageio_colour_space_and_float_files_stay_linear(tmp_path):
    """PNG/JPEG (OpenImageIO: srgb_rec709_scene, 8- and 16-bit) and untagged 8-bit TIFF decode as sRGB; an untagged
    16-bit TIFF and a PNG tagged linear read as stored; a gamma-2.2 tag decodes as c^2.2; float files are linear
    whatever their tag. Each integer file's decode is named in a one-line warning."""
    value = np.full((8, 16, 3), 0.5)
    cases = {  # name: (format, attributes, decode of the stored code, words in the warning)
        "p8.png": (oiio.UINT8, {}, srgb_eotf, "8-bit image decoded as sRGB"),
        "p16.png": (oiio.UINT16, {}, srgb_eotf, "16-bit image decoded as sRGB"),
        "j8.jpg": (oiio.UINT8, {}, srgb_eotf, "8-bit image decoded as sRGB"),
        "t8.tif": (oiio.UINT8, {}, srgb_eotf, "8-bit image decoded as sRGB"),
        "t16.tif": (oiio.UINT16, {}, lambda c: c, "16-bit image read as linear radiance (no colour-space metadata)"),
        "t16s.tif": (oiio.UINT16, {"oiio:ColorSpace": "sRGB"}, srgb_eotf, "16-bit image decoded as sRGB"),
        "lin8.png": (oiio.UINT8, {"oiio:ColorSpace": "lin_rec709_scene"}, lambda c: c, "8-bit image read as linear"),
        "g22.png": (oiio.UINT8, {"oiio:ColorSpace": "g22_rec709"}, lambda c: c**2.2, "decoded as gamma 2.2"),
        "f32.tif": (oiio.FLOAT, {}, lambda c: c, None),
        "srgb.exr": (oiio.HALF, {"oiio:ColorSpace": "srgb_rec709_scene"}, lambda c: c, None),
    }
    for name, (fmt, attributes, decode, words) in cases.items():
        path = tmp_path / name
        write_integer(path, value, fmt, attributes)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            image, _ = read_environment(path)
        np.testing.assert_allclose(image.pixels, decode(stored_codes(path)), rtol=2e-6, atol=1e-7, err_msg=name)
        messages = [str(w.message) for w in caught]
        if words is None:
            assert messages == [], (name, messages)
        else:
            assert len(messages) == 1 and messages[0].startswith(f"{path}: ") and words in messages[0], (name, messages)
    # decode="raw" leaves integer codes alone for callers with their own colour management (e.g. a USD colorSpace)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        raw, _ = read_environment(tmp_path / "p8.png", decode="raw")
    np.testing.assert_array_equal(raw.pixels, stored_codes(tmp_path / "p8.png").astype(np.float32))
    assert caught == []


# ------------------------------------------------------------------------------------------------ B: disc layouts
def disc_image(layout, n, function, sub=32):
    """An N × N disc map whose texels hold the mean of ``function`` (of unit directions (..., 3)) over the texel's
    part inside the disc, weighted by solid angle; written out from the layouts' definitions: angular θ = π·r,
    dΩ = π·sin(πr)/r du dv; mirrored ball θ = 2·asin r, dΩ = 4 du dv; direction (u·sinθ/r, v·sinθ/r, cos θ)."""
    t = (np.arange(n * sub) + 0.5) / (n * sub)
    v, u = np.meshgrid(1.0 - 2.0 * t, 2.0 * t - 1.0, indexing="ij")  # rows downwards: v up
    r = np.hypot(u, v)
    rc = np.minimum(r, 1.0)
    theta = np.pi * rc if layout == "angular" else 2.0 * np.arcsin(rc)
    s = np.sin(theta) / np.maximum(r, 1e-300)
    density = np.pi * s if layout == "angular" else np.full_like(r, 4.0)
    density = np.where(r <= 1.0, density, 0.0)
    directions = np.stack([u * s, v * s, np.cos(theta)], axis=-1)
    flux = (function(directions) * density).reshape(n, sub, n, sub).sum(axis=(1, 3))
    weight = density.reshape(n, sub, n, sub).sum(axis=(1, 3))
    return np.where(weight > 0, flux / np.where(weight > 0, weight, 1.0), 0.0)


@pytest.mark.parametrize("layout", ["angular", "mirrored_ball"])
def test_disc_texel_solid_angles_integrate_the_jacobian_and_sum_to_4pi(layout):
    """Σ Ω = 4π to rounding at every size, odd ones included; the quadrature alone (before the scale to 4π) is
    within 10⁻⁴ of it from the smallest accepted size up (the texel-centre density read before: +0.56 % at 8²)."""
    for n in (MIN_DISC_SIZE, 9, 16, 33, 64, 257):
        omega = source_texel_solid_angles(EnvironmentImage(np.zeros((n, n, 3), np.float32), layout))
        assert omega.sum() == pytest.approx(4.0 * np.pi, rel=1e-13), n
        assert np.all(omega >= 0)
        assert disc_texel_integrals(layout, n, n).sum() == pytest.approx(4.0 * np.pi, rel=1e-4), n


@pytest.mark.parametrize("layout", ["angular", "mirrored_ball"])
@pytest.mark.parametrize("n", [MIN_DISC_SIZE, 9, 16, 33, 128])
def test_constant_disc_maps_bake_pi_times_the_radiance(tmp_path, layout, n):
    """A constant L = (0.5, 1, 2): E(n) = π·L at every normal (before: E/π = 1.0056 at 8² angular, 1.0019 for the
    8² ball; 3.14 at 1², where those are now refused)."""
    radiance = np.array([0.5, 1.0, 2.0])
    path = tmp_path / f"{layout}{n}.exr"
    write_exr(path, np.broadcast_to(radiance, (n, n, 3)).astype(np.float32), half=False)
    irradiance, _ = bake_irradiance(path, tmp_path, layout=layout)
    np.testing.assert_allclose(irradiance, np.pi * np.broadcast_to(radiance, irradiance.shape), rtol=1e-6)


def test_the_smallest_equirect_cube_and_cross_bake_pi_times_the_radiance(tmp_path):
    """The other layouts' texel solid angles are exact at their smallest sizes (2 × 1, 1 × 6, 3 × 4; 1:1 images are
    angular maps, refused below 8²)."""
    for name, (h, w) in {"latlong": (1, 2), "cube": (6, 1), "cross": (4, 3)}.items():
        path = tmp_path / f"{name}.exr"
        write_exr(path, np.full((h, w, 3), 1.5, np.float32), half=False)
        irradiance, _ = bake_irradiance(path, tmp_path)
        np.testing.assert_allclose(irradiance, 1.5 * np.pi, rtol=1e-6, err_msg=name)


@pytest.mark.parametrize("layout", ["angular", "mirrored_ball"])
def test_disc_map_of_one_plus_z_bakes_its_closed_form_irradiance(tmp_path, layout):
    """L = 1 + z: E(n) = π + (2π/3)·n_z. Normals with n_z = 0 see π to 2·10⁻⁴ at every size (the flux is exact);
    the rest converges as the texels shrink: piecewise-constant texels lose the within-texel covariance of L and
    n·ω, |E − E_exact| ≈ 4π/N² measured (N = 8: 0.063π, 16: 0.016π, 32: 0.004π); allowed 6π/N² + 5·10⁻⁴π."""
    expected = np.pi + (2.0 * np.pi / 3.0) * NORMALS[:, 2]
    equator = NORMALS[:, 2] == 0
    for n in (MIN_DISC_SIZE, 16, 32, 64):
        path = tmp_path / f"{layout}_z{n}.exr"
        image = disc_image(layout, n, lambda d: 1.0 + d[..., 2])
        write_exr(path, np.repeat(image[..., None], 3, axis=-1).astype(np.float32), half=False)
        irradiance, _ = bake_irradiance(path, tmp_path, layout=layout, face_size=32)
        np.testing.assert_allclose(irradiance[equator], np.pi, rtol=2e-4, err_msg=f"{n}²")
        error = np.abs(irradiance - expected[:, None]).max()
        assert error <= np.pi * (6.0 / n**2 + 5e-4), (n, error / np.pi)


@pytest.mark.parametrize("layout,h,w,words", [
    (None, 1, 1, "at least 8x8"),  # 1:1 → angular (the audit's 1×1: E/π = 3.14)
    (None, 4, 4, "at least 8x8"),
    ("angular", 7, 7, "at least 8x8"),
    ("mirrored_ball", 1, 1, "at least 8x8"),  # (baked all zeros with a false "entirely black" warning)
    ("angular", 1, 2, "must be square"),  # (E/π = 2.0)
    ("angular", 8, 16, "must be square"),
    ("mirrored_ball", 32, 24, "must be square"),
])
def test_too_small_or_non_square_disc_maps_are_refused(tmp_path, layout, h, w, words):
    """One-line ImageError (exit code 2, like the other layout mismatches) naming the file, from the reader and
    from a bake."""
    path = tmp_path / f"small_{h}x{w}.exr"
    write_exr(path, np.ones((h, w, 3), np.float32), half=False)
    with pytest.raises(ImageError, match=words) as caught:
        read_environment(path, layout)
    assert str(caught.value).startswith(f"{path}: ") and "\n" not in str(caught.value)
    assert caught.value.exit_code == 2
    with pytest.raises(InputError, match=words) as caught:
        bakery.bake(path, tmp_path / "never.h5", encodings=("sh2",), face_size=8, layout=layout)
    assert path.name in str(caught.value) and caught.value.exit_code == 2
    assert not (tmp_path / "never.h5").exists()


def test_the_command_line_refuses_a_1x1_image_cleanly(tmp_path):
    path = tmp_path / "one.exr"
    write_exr(path, np.ones((1, 1, 3), np.float32), half=False)
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "bake", str(path), "-o", str(tmp_path / "o.h5"),
                             "-e", "sh2", "--face-size", "8"], capture_output=True, text=True, timeout=300,
                            env={**os.environ, "SOURCE_DATE_EPOCH": "1700000000"})
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert "one.exr" in result.stderr and "at least 8x8" in result.stderr


@pytest.mark.parametrize("name", ["g00_rec709", "Gamma0", "gamma 0.0"])
def test_a_gamma_of_zero_is_no_transfer_function(name):
    """c⁰ = 1 would turn every texel white: a zero gamma is not interpreted (the bit depth decides, with a note)."""
    from bakery.environment.colour import transfer_of

    assert transfer_of(name) is None
    assert transfer_of(name, gamma=2.2) == ("gamma", 2.2)  # OpenImageIO's oiio:Gamma, when positive, is the value


def _write_with_alpha(path, colour, alpha, fmt):
    """Write (H, W, C) colour plus an (H, W) alpha channel, declared as alpha (OpenImageIO ``alpha_channel``)."""
    h, w, c = colour.shape
    spec = oiio.ImageSpec(w, h, c + 1, fmt)
    spec.alpha_channel = c
    spec.channelnames = ("R", "G", "B", "A") if c == 3 else ("Y", "A")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.ascontiguousarray(np.concatenate([colour, alpha[..., None]], axis=-1), np.float32))
    out.close()


def test_alpha_is_not_colour_and_transparency_is_named():
    """An RGBA EXR reads as its RGB (the alpha channel is not a colour); one opaque everywhere reads silently, one
    with transparent texels warns once, with their count (before: alpha was dropped without a word). A luminance +
    alpha image is luminance, not a 'two-channel image'."""
    import tempfile
    from pathlib import Path

    colour = np.broadcast_to(np.array([0.5, 1.0, 2.0], np.float32), (16, 32, 3)).copy()
    for alpha_value, transparent in ((1.0, 0), (0.25, 16 * 32)):
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "rgba.exr"
            _write_with_alpha(path, colour, np.full((16, 32), alpha_value, np.float32), oiio.FLOAT)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                image, _ = read_environment(path)
            said = [str(w.message) for w in caught if "opaque" in str(w.message)]
            assert np.allclose(image.pixels, colour), "the colour is read as stored"
            assert len(said) == (1 if transparent else 0), said
            if transparent:
                assert f"{transparent:,} of {16 * 32:,} texels" in said[0]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "ya.exr"
        _write_with_alpha(path, np.full((16, 32, 1), 0.75, np.float32), np.ones((16, 32), np.float32), oiio.FLOAT)
        image, _ = read_environment(path)
        assert image.pixels.shape == (16, 32, 3) and np.allclose(image.pixels, 0.75)
