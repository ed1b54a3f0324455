"""``bakery export`` of unusual but legal stores: radiance at the float16 ceiling, a cube array of one probe, long and
non-ASCII probe names, a face size that is not a power of two, an all-black environment, 200 probes in one cube
array, and bad face sizes / level counts on every format.

Stores are baked once per module from in-memory cubes (:class:`bakery.sources.CubeSource`, the one bake path) at
small face sizes. Every check compares the exported values with the store's own data (``level0``, the kept
capture, read through the public API) or a closed form (a uniform environment prefilters to itself at every α),
never with values the exporter computed. The real consumers (ktx-parse, libktx, three.js, Filament in Node; Babylon.js
in headless Chromium, slow) load the same files where they are installed."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.errors import ClampWarning, ConfigError, InputError
from bakery.export import EXPORT_FORMATS, PROFILES, export_store
from bakery.export import ktx2 as k2
from bakery.export.filament import read_ktx1
from bakery.probe import Probe
from bakery.sources import CubeSource
from bakery.sphere.cubemap import cube_texel_solid_angles
from conftest import chromium_or_skip, run_node

FLOAT16_MAX = 65504.0  # largest finite IEEE binary16
SKY = np.array([0.3, 0.5, 1.0], np.float32)
GROUND = np.array([0.2, 0.15, 0.1], np.float32)


def sky_cube(n: int, scale: float = 1.0) -> np.ndarray:
    """(6, n, n, 3): a blue sky on every face but −Y, a brown ground on −Y (face order +X −X +Y −Y +Z −Z)."""
    cube = np.empty((6, n, n, 3), np.float32)
    cube[...] = SKY * scale
    cube[3] = GROUND * scale
    return cube


def bake_cubes(path: Path, names: list[str], cubes: np.ndarray, encodings=("sh3", "splitsum")) -> Path:
    bakery.bake(CubeSource([Probe(n) for n in names], cubes), path, encodings=encodings, face_size=cubes.shape[2])
    return path


def store_capture(store_path: Path, probe: str) -> np.ndarray:
    """The kept capture (6, N, N, 3) of ``probe`` as the store holds it (split-sum ``level0``, float16 → float64)."""
    store = bakery.open_store(store_path)
    fields = store.fields("splitsum")
    row = int(np.flatnonzero(np.asarray(fields["probe_index"]) == store.probe_names.index(probe))[0])
    return np.asarray(fields["level0"][row], dtype=np.float64)


def mean_radiance(cube: np.ndarray) -> np.ndarray:
    """Solid-angle mean (3,) of a cube (6, N, N, ≥3): the DC term of the radiance / 4π."""
    omega = cube_texel_solid_angles(cube.shape[1])[..., None]
    return (np.asarray(cube, np.float64)[..., :3] * omega).sum(axis=(0, 1, 2)) / omega.sum()


def ktx2_header(data: bytes) -> dict[str, int]:
    """The KTX 2.0 header fields ([KTX2] §3.2–3.10), read from the bytes (not through bakery's reader)."""
    names = ("vkFormat", "typeSize", "pixelWidth", "pixelHeight", "pixelDepth", "layerCount", "faceCount",
             "levelCount", "supercompressionScheme")
    return dict(zip(names, struct.unpack_from("<9I", data, 12), strict=True))


def read_png(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(str(path))
    try:
        return np.asarray(image.read_image("uint8"))
    finally:
        image.close()


@pytest.fixture(scope="module")
def edge(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("edge_stores")
    # uniform radiance above float16's range: the bake clamps the kept capture to 65504 (and says so), every α
    # prefilters to it
    with pytest.warns(ClampWarning, match="65504"):
        bright = bake_cubes(d / "bright.h5", ["/bright"], np.full((1, 6, 8, 8, 3), 1.0e5, np.float32))
    single = bake_cubes(d / "single.h5", ["/only"], sky_cube(8)[None])
    black = bake_cubes(d / "black.h5", ["/black"], np.zeros((1, 6, 8, 8, 3), np.float32))
    npot = bake_cubes(d / "npot.h5", ["/sky"], sky_cube(12)[None])
    names = ["/Probes/Prüfung", "/Probes/Prufung", "/名前", "/名字", "/Probes/" + "Long" * 80, "/with space"]
    named = bake_cubes(d / "names.h5", names, np.stack([sky_cube(4, 1.0 + i) for i in range(len(names))]))
    return {"bright": bright, "single": single, "black": black, "npot": npot, "names": named, "root": d}


# ------------------------------------------------------------------------------------------------ float16 ceiling
def test_float16_formats_saturate_at_65504_instead_of_writing_inf(edge, tmp_path):
    """A uniform environment prefilters to itself at every α, so every texel of every level is the store's capture
    value (65504 after the bake's clamp); a re-prefiltered level that rounds or rings a hair above it must not become
    +inf in R16G16B16A16_SFLOAT (KTX2, three.js cubes) or RGBA16F (Filament KTX1)."""
    value = store_capture(edge["bright"], "/bright")
    assert np.all(value == FLOAT16_MAX)  # the bake clamped 1e5 to float16's largest finite value
    levels = []
    for profile in PROFILES:
        out = export_store(edge["bright"], tmp_path / f"ktx2-{profile}", "ktx2", profile=profile, layer=False)
        tex = k2.read_ktx2((out.output / out.files[0]).read_bytes())
        assert tex.vk_format == k2.VK_FORMAT_R16G16B16A16_SFLOAT
        levels += [np.frombuffer(b, "<f2").reshape(-1, 4)[:, :3] for b in tex.levels]
    three = export_store(edge["bright"], tmp_path / "three", "three", layer=False)
    cube = next(f for f in three.files if f.endswith(".ktx2") and "bright" in f)
    cube_levels = k2.read_ktx2((three.output / cube).read_bytes()).levels
    levels += [np.frombuffer(b, "<f2").reshape(-1, 4)[:, :3] for b in cube_levels]
    fil = export_store(edge["bright"], tmp_path / "filament", "filament", options={"gl_format": "RGBA16F"},
                       layer=False)
    levels += list(read_ktx1((fil.output / fil.files[0]).read_bytes()).levels)
    for level in levels:
        level = np.asarray(level, np.float64)
        assert np.all(np.isfinite(level))
        # the prefilter reproduces a constant within its own accuracy (≤ 0.4 % measured on the coarse levels)
        assert np.all(level <= FLOAT16_MAX) and np.all(level >= FLOAT16_MAX * 0.99)


def test_float16_packing_saturates_and_keeps_sign():
    """R16G16B16A16_SFLOAT texels: ±65504 at and beyond the range (never ±inf), NaN → 0, ordinary values rounded."""
    data = k2.encode_texels(np.array([[7e4, -7e4, np.inf], [np.nan, 65519.0, 1.5]], np.float32),
                            k2.VK_FORMAT_R16G16B16A16_SFLOAT)
    texels = np.frombuffer(data, "<f2").astype(np.float64).reshape(2, 4)
    np.testing.assert_array_equal(texels, [[FLOAT16_MAX, -FLOAT16_MAX, FLOAT16_MAX, 1.0], [0.0, FLOAT16_MAX, 1.5, 1.0]])


# ------------------------------------------------------------------------------------------------ cube arrays
def test_cube_array_of_one_probe_is_a_cube_array(edge, tmp_path):
    """``layout = "array"`` writes a cube array whatever the number of probes: layerCount 1 for one probe (an engine
    binding the file as a cube array needs layerCount ≥ 1), level 0 the store's capture (α = 0)."""
    out = export_store(edge["single"], tmp_path / "a", "ktx2", options={"layout": "array"}, layer=False)
    data = (out.output / "reflection_probes.ktx2").read_bytes()
    header = ktx2_header(data)
    assert (header["layerCount"], header["faceCount"], header["pixelDepth"]) == (1, 6, 0)
    tex = k2.read_ktx2(data)
    level0 = np.frombuffer(tex.levels[0], "<f2").astype(np.float64).reshape(1, 6, 8, 8, 4)
    np.testing.assert_array_equal(level0[0, ..., :3], store_capture(edge["single"], "/only"))
    assert json.loads(tex.key_values["bakery:probes"].rstrip(b"\0")) == ["/only"]
    cube = export_store(edge["single"], tmp_path / "c", "ktx2", layer=False)  # the default layout: one plain cube
    assert ktx2_header((cube.output / cube.files[0]).read_bytes())["layerCount"] == 0


@pytest.mark.slow
def test_two_hundred_probes_in_one_cube_array(tmp_path):
    """200 small probes: one cube array of 200 layers in store order, each layer's level 0 its own capture, and one
    cube file per probe otherwise."""
    names = [f"/Grid/p{i:03d}" for i in range(200)]
    cubes = np.stack([sky_cube(4, 0.5 + i / 100.0) for i in range(200)])
    store = bake_cubes(tmp_path / "many.h5", names, cubes, encodings=("splitsum",))
    out = export_store(store, tmp_path / "a", "ktx2", options={"layout": "array", "levels": 2}, layer=False)
    data = (out.output / "reflection_probes.ktx2").read_bytes()
    assert ktx2_header(data)["layerCount"] == 200 and ktx2_header(data)["levelCount"] == 2
    tex = k2.read_ktx2(data)
    order = json.loads(tex.key_values["bakery:probes"].rstrip(b"\0"))
    assert order == names
    level0 = np.frombuffer(tex.levels[0], "<f2").astype(np.float64).reshape(200, 6, 4, 4, 4)[..., :3]
    fields = bakery.open_store(store).fields("splitsum")
    by_name = {bakery.open_store(store).probe_names[int(i)]: r for r, i in enumerate(fields["probe_index"])}
    captured = np.asarray(fields["level0"], np.float64)
    for j, name in enumerate(order):
        np.testing.assert_array_equal(level0[j], captured[by_name[name]])
    files = export_store(store, tmp_path / "c", "ktx2", options={"levels": 1}, layer=False).files
    assert len(files) == len(set(files)) == 200


# ------------------------------------------------------------------------------------------------ probe names
@pytest.mark.parametrize("fmt", list(EXPORT_FORMATS))
def test_long_and_non_ascii_probe_names_export_to_distinct_short_files(edge, fmt, tmp_path):
    """Names longer than a file name allows and names that differ only in non-ASCII letters (``Prüfung`` /
    ``Prufung``, ``名前`` / ``名字``) each get their own file, every path component fits 255 bytes, and the files
    name the probes exactly (KVD ``bakery:probes``, glTF node, KTX1 ``bakery`` key)."""
    store = bakery.open_store(edge["names"])
    out = export_store(edge["names"], tmp_path / "out", fmt, layer=False)
    for name in out.files:
        assert all(len(part.encode()) <= 255 - len(".tmp-4194304") - 1 for part in name.split("/")), name
        assert name.isascii(), name
    found = {}
    for name in out.files:
        data = (out.output / name).read_bytes()
        if name.endswith(".ktx2"):
            probes = json.loads(k2.read_ktx2(data).key_values["bakery:probes"].rstrip(b"\0"))
        elif name.endswith(".gltf"):
            probes = [json.loads(data)["nodes"][0]["name"]]
        elif name.endswith(".ktx"):
            probes = [json.loads(read_ktx1(data).key_values["bakery"].rstrip(b"\0"))["probe"]]
        elif name == "lightprobes.json":
            probes = [c["name"] for c in json.loads(data)["object"]["children"]]
        else:
            continue
        for probe in probes:
            found.setdefault(probe, []).append(name)
    assert set(found) == set(store.probe_names)
    if fmt != "three":  # three: the light probes share lightprobes.json; the cubes are one file per probe as here
        assert all(len(files) == 1 for files in found.values()) and len({f[0] for f in found.values()}) == len(found)
    for probe in store.probe_names:  # each file holds its own probe's data: level 0 mean = the store's capture's
        cube = next((f for f in found[probe] if f.endswith((".ktx2", ".ktx"))), None)
        if cube is None:
            continue
        data = (out.output / cube).read_bytes()
        level0 = k2.level_array(k2.read_ktx2(data), 0) if cube.endswith(".ktx2") else read_ktx1(data).levels[0]
        if EXPORT_FORMATS[fmt].default_profile != "babylon":
            np.testing.assert_allclose(mean_radiance(level0), mean_radiance(store_capture(edge["names"], probe)),
                                       rtol=2e-2)


def test_probe_names_still_refused_when_only_ascii_punctuation_differs(tmp_path):
    store = bake_cubes(tmp_path / "s.h5", ["/sky a", "/sky_a"], np.stack([sky_cube(4), sky_cube(4, 2.0)]),
                       encodings=("splitsum",))
    with pytest.raises(InputError, match="two exported files have this name"):
        export_store(store, tmp_path / "out", "ktx2", layer=False)


def test_a_format_does_not_replace_another_formats_file(edge, tmp_path):
    """``ktx2`` and ``three`` both write ``<probe>.ktx2`` (at different profiles): exporting the second into the
    first's folder is refused, naming the format, and leaves every file as it was (before: replaced silently,
    and the manifest then attributed the cube to the other format)."""
    out = tmp_path / "out"
    export_store(edge["single"], out, "ktx2", layer=False)
    before = {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(InputError, match="written by the ktx2 export"):
        export_store(edge["single"], out, "three", layer=False)
    assert {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    export_store(edge["single"], out, "ktx2", layer=False)  # the same format again replaces its own file


def test_gltf_says_when_rgbd_clips_and_is_silent_otherwise(edge, tmp_path):
    """RGBD (8-bit, Babylon) holds radiance up to 255: the uniform 65504 store's every specular texel is above it
    (6 faces × Σ_i N_i² over the 8² chain), and the export says so once, with the count; a sky below 255 exports
    without a warning (before: clamped silently)."""
    import warnings

    with pytest.warns(ClampWarning, match="RGBD range 255") as caught:
        export_store(edge["bright"], tmp_path / "bright", "gltf", layer=False)
    texels = 6 * sum((8 >> i) ** 2 for i in range(4))  # 8², 4², 2², 1²
    assert any(f"{texels:,} specular texels of 1 probe(s) (/bright)" in str(w.message) for w in caught), \
        [str(w.message) for w in caught]
    with warnings.catch_warnings():
        warnings.simplefilter("error", ClampWarning)
        export_store(edge["single"], tmp_path / "sky", "gltf", layer=False)


def test_a_whole_store_export_names_the_files_left_from_probes_no_longer_in_the_store(tmp_path):
    """Export two probes, then a store holding only one of them into the same folder: the other probe's cube is
    still there (bakery does not delete), and the export says so, naming it; a --probes export (a subset on
    purpose) and a fresh folder say nothing."""
    import warnings

    from bakery.errors import BakeryWarning

    both = bake_cubes(tmp_path / "both.h5", ["/keep", "/gone"], np.stack([sky_cube(4), sky_cube(4, 2.0)]),
                      encodings=("splitsum",))
    one = bake_cubes(tmp_path / "one.h5", ["/keep"], sky_cube(4)[None], encodings=("splitsum",))
    out = tmp_path / "out"
    export_store(both, out, "ktx2", layer=False)
    with pytest.warns(BakeryWarning, match=r"1 file\(s\) of an earlier ktx2 export .*gone\.ktx2"):
        export_store(one, out, "ktx2", layer=False)
    assert (out / "gone.ktx2").is_file()
    with warnings.catch_warnings():
        warnings.simplefilter("error", BakeryWarning)
        export_store(one, out, "ktx2", probes="/keep", layer=False)
        export_store(one, tmp_path / "fresh", "ktx2", layer=False)


# ------------------------------------------------------------------------------------------------ face sizes
def test_gltf_of_a_face_size_that_is_not_a_power_of_two(edge, tmp_path):
    """Babylon.js loads only power-of-two cube faces: a 12² bake exports 8² specular images (8, 4, 2, 1 per mip),
    resampled preserving flux, so mip 0's solid-angle mean is the store capture's (within RGBD's 8-bit steps)."""
    out = export_store(edge["npot"], tmp_path / "g", "gltf", layer=False)
    document = json.loads((out.output / "sky.gltf").read_text())
    light = document["extensions"]["EXT_lights_image_based"]["lights"][0]
    assert light["specularImageSize"] == 8 and len(light["specularImages"]) == 4
    assert document["extras"]["bakery"]["profile"]["face_size"] == 8
    for level, row in enumerate(light["specularImages"]):
        for index in row:
            assert read_png(out.output / document["images"][index]["uri"]).shape == (8 >> level, 8 >> level, 4)
    rgbd = np.stack([read_png(out.output / document["images"][i]["uri"]).astype(np.float64) / 255.0
                     for i in light["specularImages"][0]])
    radiance = rgbd[..., :3] ** 2.2 / rgbd[..., 3:4]  # Babylon's fromRGBD (gamma 2.2, divided by D)
    capture = store_capture(edge["npot"], "/sky")
    np.testing.assert_allclose(mean_radiance(radiance[:, :, ::-1]), mean_radiance(capture), rtol=1e-2)
    with pytest.raises(InputError, match="power of two"):
        export_store(edge["npot"], tmp_path / "g6", "gltf", options={"face_size": 6}, layer=False)
    assert not (tmp_path / "g6").exists()
    # the other formats keep the bake's 12² faces (NPOT cube maps are legal in KTX 2.0, KTX 1.1 and WebGL 2)
    ktx = export_store(edge["npot"], tmp_path / "k", "ktx2", layer=False)
    header = ktx2_header((ktx.output / ktx.files[0]).read_bytes())
    assert (header["pixelWidth"], header["levelCount"]) == (12, 4)


@pytest.mark.parametrize("fmt", ["ktx2", "gltf", "filament", "three"])
def test_bad_face_size_and_levels_are_config_errors(edge, fmt, tmp_path):
    """face_size ≤ 0 or levels ≤ 0 is exit 3 (ConfigError) before anything is read or written, never a
    ZeroDivisionError or a reshape error."""
    options = [{"levels": 0}, {"levels": -2}] + ([{"face_size": 0}, {"face_size": -4}] if fmt != "three" else [])
    for option in options:
        with pytest.raises(ConfigError):
            export_store(edge["single"], tmp_path / "out", fmt, options=option, layer=False)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------------------ black
@pytest.mark.parametrize("fmt", list(EXPORT_FORMATS))
def test_all_black_environment_exports_zeros(edge, fmt, tmp_path):
    out = export_store(edge["black"], tmp_path / "out", fmt, layer=False)
    for name in out.files:
        data = (out.output / name).read_bytes()
        if name.endswith(".ktx2"):
            tex = k2.read_ktx2(data)
            values = [k2.level_array(tex, i)[..., :3] for i in range(len(tex.levels))]
        elif name.endswith(".ktx"):
            cube = read_ktx1(data)
            values = list(cube.levels) + [np.array(cube.key_values["sh"].rstrip(b"\0").split(), float)]
        elif name.endswith(".gltf"):
            light = json.loads(data)["extensions"]["EXT_lights_image_based"]["lights"][0]
            values = [np.array(light["irradianceCoefficients"])]
        elif name.endswith(".png"):
            values = [read_png(out.output / name)[..., :3]]  # RGB 0 (D may be anything)
        elif name == "lightprobes.json":
            values = [np.array(c["sh"]) for c in json.loads(data)["object"]["children"]]
        else:
            continue
        for v in values:
            assert np.all(np.asarray(v, np.float64) == 0.0), name


# ------------------------------------------------------------------------------------------------ real consumers
def test_consumers_load_the_edge_case_files(edge, tmp_path):
    """ktx-parse, libktx and three.js read the one-layer cube array, the saturated float16 cube and the 12² cube;
    Filament reads the saturated RGBA16F KTX1 and its SH."""
    ktx2_files = [
        export_store(edge["single"], tmp_path / "array", "ktx2", options={"layout": "array"}, layer=False),
        export_store(edge["bright"], tmp_path / "bright", "ktx2", layer=False),
        export_store(edge["npot"], tmp_path / "npot", "ktx2", layer=False),
    ]
    paths = [r.output / f for r in ktx2_files for f in r.files]
    report = run_node("ktx2_consumers.mjs", *paths, packages=("ktx-parse", "three", "@khronosgroup/gltf-viewer"))
    for path in paths:
        r = report[str(path)]
        header = ktx2_header(path.read_bytes())
        assert "error" not in r["ktxParse"], r["ktxParse"]
        assert (r["ktxParse"]["layerCount"], r["ktxParse"]["pixelWidth"]) == (header["layerCount"],
                                                                              header["pixelWidth"])
        assert r["ktxParse"]["reserialisedIdentical"] and r["libktx"]["ok"] and r["three"]["ok"], r
        half = np.array(r["three"]["first"], dtype=np.uint16).view(np.float16)  # three's level-0 data, as uploaded
        assert np.all(np.isfinite(half)), path
    fil = export_store(edge["bright"], tmp_path / "fil", "filament", options={"gl_format": "RGBA16F"}, layer=False)
    path = fil.output / fil.files[0]
    r = run_node("filament_check.mjs", path, packages=("filament",))[str(path)]
    assert r["ok"] and r["isCubemap"] and r["levels"] == 4 and all(np.isfinite(r["sh"])), r


@pytest.mark.slow
def test_babylon_loads_the_gltf_of_a_12_pixel_bake(edge, tmp_path):
    """Babylon.js refuses a cube face that is not a power of two ("Texture size must be a power of two"); the
    12² bake's export loads, and its read-back mip 0 has the store capture's mean radiance."""
    import os

    from bakery.sphere.fibonacci import fibonacci_directions

    os.environ["CHROMIUM"] = chromium_or_skip()
    root = tmp_path / "root"
    export_store(edge["npot"], root / "npot", "gltf", layer=False)
    request = {"root": str(root), "assets": ["npot/sky.gltf"], "normals": fibonacci_directions(8).tolist(),
               "screenshot": {"asset": "npot/sky.gltf", "path": str(tmp_path / "shot.png")}}
    (tmp_path / "req.json").write_text(json.dumps(request))
    report = run_node("babylon_check.mjs", tmp_path / "req.json",
                      packages=("babylonjs", "babylonjs-loaders", "playwright-core"))["npot/sky.gltf"]
    assert "error" not in report, report
    faces = np.stack([np.array(f["data"], np.float64).reshape(8, 8, 4)[::-1, ::-1, :3] for f in report["faces"][0]])
    np.testing.assert_allclose(mean_radiance(faces), mean_radiance(store_capture(edge["npot"], "/sky")), rtol=1e-2)
