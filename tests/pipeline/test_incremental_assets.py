"""Incremental scene bakes when something other than the root layer changes (a sublayer, a texture file, a
captured image, the recipe's band skipping): the re-baked store must hold what a clean bake of the edited inputs
holds, every field of every encoding bit for bit — never a reused probe's stale result — and a change only one probe
can see must not re-bake the others."""

import shutil

import numpy as np
import OpenImageIO as oiio
from usd_scenes import header, probe, textured_floor, write

import bakery

FAST = {"face_size": 8, "samples": 1, "bounces": 1, "reference_errors": False}
SKY = 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'
TOP = [[[255, 255, 255], [255, 255, 255]], [[0, 0, 0], [0, 0, 0]]]  # white over black
BOTTOM = [[[0, 0, 0], [0, 0, 0]], [[255, 255, 255], [255, 255, 255]]]  # the same mean, upside down


def _image(path, pixels, kind=oiio.UINT8):
    pixels = np.asarray(pixels, dtype=np.uint8 if kind == oiio.UINT8 else np.float32)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], kind))
    out.write_image(pixels)
    out.close()


def _texture_material(name, file):
    return f"""
def Material "{name}"
{{
    token outputs:surface.connect = </{name}/Surface.outputs:surface>
    def Shader "Surface"
    {{
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </{name}/Texture.outputs:rgb>
        token outputs:surface
    }}
    def Shader "Texture"
    {{
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @{file}@
        float2 inputs:st.connect = </{name}/Reader.outputs:result>
        float3 outputs:rgb
    }}
    def Shader "Reader"
    {{
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname = "st"
        float2 outputs:result
    }}
}}
"""


def _mix_material(mix):
    """A MaterialX standard_surface authored in USD whose base colour mixes two images: flattened into one texture
    (bakery.usd.mtlx_graph), whose mean does not depend on ``mix`` (the images have the same mean)."""
    return f"""
def Material "Mix"
{{
    token outputs:mtlx:surface.connect = </Mix/Surf.outputs:out>
    def Shader "Surf"
    {{
        uniform token info:id = "ND_standard_surface_surfaceshader"
        float inputs:base = 1
        float inputs:specular = 0
        color3f inputs:base_color.connect = </Mix/Blend.outputs:out>
        token outputs:out
    }}
    def Shader "A"
    {{
        uniform token info:id = "ND_image_color3"
        asset inputs:file = @./top.png@
        color3f outputs:out
    }}
    def Shader "B"
    {{
        uniform token info:id = "ND_image_color3"
        asset inputs:file = @./bottom.png@
        color3f outputs:out
    }}
    def Shader "Blend"
    {{
        uniform token info:id = "ND_mix_color3"
        color3f inputs:fg.connect = </Mix/A.outputs:out>
        color3f inputs:bg.connect = </Mix/B.outputs:out>
        float inputs:mix = {mix}
        color3f outputs:out
    }}
}}
"""


def _floor(name, material, x0):
    """A double-sided 2 m textured floor ``name`` from x = ``x0`` to ``x0`` + 2."""
    return textured_floor(material, "\n    uniform bool doubleSided = 1").replace('"Floor"', f'"{name}"').replace(
        "[(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]",
        f"[({x0}, 0, 1), ({x0 + 2}, 0, 1), ({x0 + 2}, 0, -1), ({x0}, 0, -1)]")


def _assert_same_results(incremental, clean):
    a, b = bakery.open_store(incremental), bakery.open_store(clean)
    assert list(a.probe_names) == list(b.probe_names)
    assert sorted(a.encodings) == sorted(b.encodings)
    for encoding in b.encodings:
        fa, fb = a.fields(encoding), b.fields(encoding)
        assert set(fa) == set(fb), encoding
        for name in fb:
            assert np.asarray(fa[name]).tobytes() == np.asarray(fb[name]).tobytes(), (encoding, name)
    assert a.attributes.get("skipped") == b.attributes.get("skipped")


def _rebake_matches_clean(tmp_path, scene, edit, **kwargs):
    """Bake, ``edit()``, bake again into the same store and into a fresh one: the two stores hold the same results.
    Returns the incremental bake's summary."""
    store = tmp_path / "incremental.h5"
    bakery.bake(scene, store, **FAST, **kwargs)
    edit()
    summary = bakery.bake(scene, store, **FAST, **kwargs)
    bakery.bake(scene, tmp_path / "clean.h5", **FAST, **kwargs)
    _assert_same_results(store, tmp_path / "clean.h5")
    return summary


def test_textures_swapped_between_materials_in_a_sublayer_rebake(tmp_path):
    """Two materials swap their textures (of equal means) in a sublayer: no file changed, and each material map
    names its texture by index with the texture's mean — the same before and after. The texels are in the scene's
    hash now; before (until 2026-12-07) both probes were reused and stored the unswapped floors."""
    _image(tmp_path / "top.png", TOP)
    _image(tmp_path / "bottom.png", BOTTOM)

    def looks(a, b):
        return write(tmp_path / "looks.usda", header() + _texture_material("MatA", a) + _texture_material("MatB", b)
                     + _floor("FloorA", "/MatA", -1.0) + _floor("FloorB", "/MatB", 1.0))

    looks("./top.png", "./bottom.png")
    scene = write(tmp_path / "scene.usda", header(extra="    subLayers = [@./looks.usda@]\n") + SKY
                  + probe("P0", (0.0, 0.3, 0.5)) + probe("P1", (2.0, 0.3, -0.5)))
    summary = _rebake_matches_clean(tmp_path, scene, lambda: looks("./bottom.png", "./top.png"), encodings=("sh2",))
    assert summary.baked == 2


def test_a_flattened_materialx_graph_constant_in_a_sublayer_rebakes(tmp_path):
    """The mix of a MaterialX graph authored in USD changes in a sublayer: the flattened texture changes, its mean
    and every file do not (stale before 2026-12-07)."""
    _image(tmp_path / "top.png", TOP)
    _image(tmp_path / "bottom.png", BOTTOM)
    write(tmp_path / "looks.usda", header() + _mix_material(0.25))
    scene = write(tmp_path / "scene.usda", header(extra="    subLayers = [@./looks.usda@]\n") + SKY
                  + textured_floor("/Mix", "\n    uniform bool doubleSided = 1")
                  + probe("P0", (0.0, 0.3, 0.5)) + probe("P1", (0.2, 0.3, -0.5)))
    summary = _rebake_matches_clean(
        tmp_path, scene, lambda: write(tmp_path / "looks.usda", header() + _mix_material(0.75)), encodings=("sh2",))
    assert summary.baked == 2


def test_a_captured_images_bytes_rebake_its_probe_alone(tmp_path):
    """A probe's captured image (``bakery:capture:image``) is read by that probe alone: new bytes re-bake it and
    reuse the rendered probes (before 2026-12-07 the image was one of the scene's global assets: every probe was
    re-baked)."""
    _image(tmp_path / "room.hdr", np.full((8, 16, 3), 0.5), oiio.FLOAT)
    _image(tmp_path / "floor.png", TOP)
    scene = write(tmp_path / "scene.usda", header() + _texture_material("Mat", "./floor.png")
                  + _floor("Floor", "/Mat", -1.0) + SKY + probe("P0", (0.0, 0.5, 0.0)) + probe("P1", (0.5, 0.3, 0.2))
                  + probe("Captured", (0.0, 1.0, 0.0), body="asset bakery:capture:image = @./room.hdr@"))
    brighter = np.full((8, 16, 3), 0.5)
    brighter[:4] = 2.0
    summary = _rebake_matches_clean(tmp_path, scene, lambda: _image(tmp_path / "room.hdr", brighter, oiio.FLOAT),
                                    encodings=("sh2",))
    assert (summary.baked, summary.reused) == (1, 2)
    shutil.copy(tmp_path / "room.hdr", tmp_path / "same.hdr")  # the same bytes elsewhere: nothing to bake
    write(scene, scene.read_text().replace("@./room.hdr@", "@./same.hdr@"))
    again = bakery.bake(scene, tmp_path / "incremental.h5", **FAST, encodings=("sh2",))
    assert (again.baked, again.reused) == (0, 3)


LAMP = """
def SphereLight "Lamp"
{
    float inputs:intensity = 300
    float inputs:radius = 0.02
    double3 xformOp:translate = (-3, 0.3, -3)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""


def _skipping_scene(tmp_path, moved_probe=(3.0, 0.5, 3.0)):
    """Three probes under a uniform sky, far from a small lamp: no probe needs band 2 (zh3 is skipped), unless
    ``moved_probe`` (in a sublayer) is next to the lamp."""
    write(tmp_path / "probes.usda", header() + probe("P2", moved_probe))
    return write(tmp_path / "scene.usda", header(extra="    subLayers = [@./probes.usda@]\n") + SKY + LAMP
                 + probe("P0", (3.0, 0.5, 0.0)) + probe("P1", (0.0, 0.5, 3.0)))


def test_an_encoding_a_previous_bake_skipped_is_baked_for_every_probe_once_it_is_kept(tmp_path):
    """Band skipping dropped zh3 from the store; then a probe moves next to the lamp (a sublayer edit) and needs
    band 2, so the bake keeps zh3. The reused probes had no zh3 to give: before 2026-12-07 the store held zh3 for
    the moved probe alone, where a clean bake holds it for all three; they are baked again now."""
    kwargs = {"encodings": ("sh2", "zh3"), "band_energy_tolerance": 0.01}
    scene = _skipping_scene(tmp_path)
    store = tmp_path / "incremental.h5"
    first = bakery.bake(scene, store, **FAST, **kwargs)
    assert [s["encoding"] for s in first.skipped] == ["zh3"]
    same = bakery.bake(scene, store, **FAST, **kwargs)  # the skip holds: nothing to bake, the skip is reported
    assert (same.baked, [s["encoding"] for s in same.skipped]) == (0, ["zh3"])
    summary = _rebake_matches_clean(tmp_path, scene, lambda: _skipping_scene(tmp_path, (-3.0, 0.4, -3.1)), **kwargs)
    assert "zh3" in bakery.open_store(store).encodings
    assert summary.baked == 3


def test_a_lowered_band_tolerance_restores_the_skipped_encoding(tmp_path):
    """The same with nothing moved and a lower ``band_energy_tolerance`` (not in the probes' hashes: skipping is
    decided over every probe after the bake): every probe was reused and the store had no zh3 at all while its
    summary said nothing was skipped (before 2026-12-07)."""
    scene = _skipping_scene(tmp_path)
    store = tmp_path / "incremental.h5"
    bakery.bake(scene, store, **FAST, encodings=("sh2", "zh3"), band_energy_tolerance=0.5)
    summary = bakery.bake(scene, store, **FAST, encodings=("sh2", "zh3"), band_energy_tolerance=1e-9)
    bakery.bake(scene, tmp_path / "clean.h5", **FAST, encodings=("sh2", "zh3"), band_energy_tolerance=1e-9)
    _assert_same_results(store, tmp_path / "clean.h5")
    assert "zh3" in bakery.open_store(store).encodings and not summary.skipped


def test_a_farm_merge_refuses_reused_probes_that_lack_a_kept_encoding(tmp_path):
    """The same on a farm (``bake --shard --base``, ``bakery merge``): the merge cannot bake the reused probes, so it
    refuses (before 2026-12-07 it wrote a store with zh3 for the moved probe alone) and leaves the store as it was."""
    import pytest

    from bakery.pipeline.settings import request_from
    from bakery.pipeline.shards import ShardError, ShardSpec, bake_shard, merge_shards

    options = {**FAST, "encodings": ("sh2", "zh3"), "band_energy_tolerance": 0.01}
    scene = _skipping_scene(tmp_path)
    store = tmp_path / "farm.h5"
    bakery.bake(scene, store, **options)
    before = store.read_bytes()
    _skipping_scene(tmp_path, (-3.0, 0.4, -3.1))
    shard = tmp_path / "s1.h5"
    bake_shard(request_from(scene, shard, **options), ShardSpec(shard=(1, 1), base=store))
    with pytest.raises(ShardError, match="lack an encoding this bake keeps"):
        merge_shards([shard], store)
    assert store.read_bytes() == before
