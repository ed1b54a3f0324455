"""The ``three`` export rendered by three.js r187 (WebGLRenderer on SwiftShader WebGL2, and WebGPURenderer on
SwiftShader WebGPU, in headless Chromium, one launch each: ``js/three_render.mjs``), loaded with three's own loaders
(``KTX2Loader``, ``ObjectLoader``, ``LightProbeGridWebGL``)
and the cube loader snippet exactly as docs/exports.md ships it; and the KTX2 files of every format against the KTX 2.0
specification. Output is linear (``outputColorSpace = LinearSRGBColorSpace``, ``NoToneMapping``) and read back as
float32 from a ``FloatType`` render target.

References are closed forms, never numbers of bakery's exporter: a disc's direction in the panorama
(``test_export_conventions.BLOBS``), the store's capture through the GL face table (bilinear), the cosine integral
and the GGX prefilter of that capture by quadrature over its texels, the store's own ``evaluate_irradiance``,
three's formulas where three defines the mapping (``PMREMGenerator.lodToRoughness``, ``LOD_MIN``, the grid
shader's sample point), and the KTX 2.0 / Khronos Data Format values (transcribed below, with libktx's ``vk2dfd``).
"""

from __future__ import annotations

import base64
import json
import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.export import export_store
from bakery.export.source import captures, irradiance_encoding, require_capture_encoding
from conftest import ROOT, chromium_or_skip, run_node
from test_export_conventions import (  # noqa: F401 - blob_store is a fixture
    BLOB_COLOURS,
    BLOBS,
    angle_degrees,
    blob_store,
    cosine_irradiance_over_pi,
    gl_bilinear_taps,
    gl_face_st,
    gl_texel_directions,
    gl_texel_solid_angles,
    sky_directions,
    sphere_normals,
)
from usd_scenes import header, material, write

SIZE = 48  # pixels per view (a 90° view: 1.9° a pixel; a 32² face texel is 2.8°)
MIRROR_X = np.array([-1.0, 1.0, 1.0])


def docs_cube_loader() -> str:
    """The three.js cube loader of docs/exports.md (the fenced ``js`` block that defines ``loadBakeryCube``)."""
    text = (ROOT / "docs" / "exports.md").read_text()
    blocks = [b for b in re.findall(r"```js\n(.*?)```", text, re.S) if "export async function loadBakeryCube" in b]
    assert len(blocks) == 1, "docs/exports.md must hold exactly one loadBakeryCube block"
    return blocks[0]


def ggx_prefilter(capture: np.ndarray, directions: np.ndarray, alpha: float) -> np.ndarray:
    """The split-sum prefilter (v = n) of a cube capture at GGX α, by quadrature over its texels (exact solid
    angles): ∫ L D(h) ⟨n, l⟩₊ dω / ∫ D(h) ⟨n, l⟩₊ dω, n·h = √((1 + n·l)/2) — what three's PMREMGenerator estimates
    (``_getGGXMaterial``: VNDF samples with pdf D/4 at v = n, weighted by n·l; ``_getIntegrationMaterial``)."""
    n = capture.shape[1]
    omega = gl_texel_directions(n).reshape(-1, 3)
    weights = np.tile(gl_texel_solid_angles(n).reshape(-1), 6)
    radiance = capture.reshape(-1, 3).astype(np.float64)
    a2 = alpha * alpha
    out = []
    for chunk in np.array_split(directions, max(1, len(directions) // 512)):
        c = chunk @ omega.T
        d = a2 / (np.pi * ((1 + c) / 2 * (a2 - 1) + 1) ** 2)
        k = d * np.maximum(c, 0.0) * weights
        out.append((k @ radiance) / k.sum(1, keepdims=True))
    return np.concatenate(out)


def three_lod_to_roughness(lod: float, max_lod: float) -> float:
    """three's ``PMREMGenerator.lodToRoughness`` (src/extras/PMREMGenerator.js), the inverse of ``roughnessToMip``
    (``envmap_common_pars_fragment``: maxLod·r(2 − r))."""
    return 1 - math.sqrt(1 - lod / max_lod) if max_lod > 0 else 0.0


# ------------------------------------------------------------------------------------------ fixtures

#: A 3 × 2 × 2 probe volume (1 m spacing) under a sky and a warm lamp off to one side, over a grey floor: the probes
#: see different light, so the grid's interpolation between them shows.
GRID_SCENE = header() + material("Grey", diffuse=(0.5, 0.5, 0.5), diffuse_only=True) + """
def DomeLight "Sky"
{
    float inputs:intensity = 1
    color3f inputs:color = (0.4, 0.6, 1.0)
}
def SphereLight "Lamp"
{
    float inputs:intensity = 300
    float inputs:radius = 0.2
    color3f inputs:color = (1.0, 0.7, 0.4)
    double3 xformOp:translate = (2.5, 2.5, 1.5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Cube "Floor" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{
    double size = 1
    rel material:binding = </Grey>
    double3 xformOp:translate = (0, -0.5, 0)
    float3 xformOp:scale = (8, 1, 8)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
}
def BakeryIrradianceProbeVolume "Volume"
{
    float3 bakery:volume:extent = (1, 0.5, 0.5)
    int3 bakery:volume:counts = (3, 2, 2)
    double3 xformOp:translate = (0, 1, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""
#: Spheres (centre, radius) lit by the grid: sample points between probes on every axis.
GRID_SPHERES = (((-0.4, 1.1, 0.2), 0.15), ((0.6, 0.7, -0.3), 0.15))
R1 = three_lod_to_roughness(1, 2)  # the roughness three reads level 1 of a 3-level chain at (32² faces: 32, 16, 8)
ROUGH = (R1, 1.0)

JOBS = {
    "sky": {"kind": "sky", "env": "pmrem"},
    "mirror_pmrem": {"kind": "sphere", "material": "standard", "metalness": 1, "roughness": 0, "env": "pmrem"},
    "mirror_chain": {"kind": "sphere", "material": "standard", "metalness": 1, "roughness": 0, "env": "chain"},
    **{f"blur{r:.3f}_{env}": {"kind": "sky", "env": env, "blurriness": r} for r in ROUGH for env in ("pmrem", "chain")},
    "lambert_pmrem": {"kind": "sphere", "material": "lambert", "env": "pmrem"},
    "lambert_chain": {"kind": "sphere", "material": "lambert", "env": "chain"},
    "lambert_full_chain": {"kind": "sphere", "material": "lambert", "env": "chain", "cube": "full"},
    "diffuse_pmrem": {"kind": "sphere", "material": "diffuse", "env": "pmrem"},
    "diffuse_chain": {"kind": "sphere", "material": "diffuse", "env": "chain"},
    "probe": {"kind": "sphere", "material": "lambert", "probe": True},
    **{f"grid{i}": {"kind": "sphere", "material": "lambert", "grid": True, "centre": c, "radius": r}
       for i, (c, r) in enumerate(GRID_SPHERES)},
}


@pytest.fixture(scope="module")
def grid_store(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("three_grid")
    bakery.bake(write(d / "grid.usda", GRID_SCENE), d / "grid.h5", encodings=("sh3",), face_size=8, samples=2)
    return d / "grid.h5"


def render_three(blob_store, grid_store, root: Path, renderer: str, jobs: dict) -> dict:
    """The disc store (32² faces, sh3 + splitsum) exported as ``three`` (its defaults, and with the full chain down
    to 1×1, bakery's default until 2026-12-07), the grid store as ``three``, ``jobs`` rendered by three's
    ``renderer`` ("webgl" or "webgpu") in one Chromium launch."""
    import os

    os.environ["CHROMIUM"] = chromium_or_skip()
    blobs = export_store(blob_store, root / "blobs", "three", layer=False)
    export_store(blob_store, root / "full", "three", layer=False, options={"levels": 6})
    export_store(grid_store, root / "grid", "three", layer=False)
    (root / "loader.js").write_text(docs_cube_loader())
    cube = next(f for f in blobs.files if f.endswith(".ktx2"))
    request = {"root": str(root), "loader": str(root / "loader.js"), "size": SIZE, "renderer": renderer,
               "cubes": {"default": f"blobs/{cube}", "full": f"full/{cube}"},
               "lightprobes": "blobs/lightprobes.json", "grids": "grid/lightprobegrids.json",
               "jobs": list(jobs.values())}
    (root / "request.json").write_text(json.dumps(request))
    report = run_node("three_render.mjs", root / "request.json", packages=("three", "playwright-core"))
    if renderer == "webgpu" and "no WebGPU adapter" in report.get("error", ""):
        pytest.skip("this Chromium offers no WebGPU adapter (SwiftShader Vulkan): three's WebGPURenderer not run")
    assert "error" not in report, report["error"]
    problems = [m for m in report["consoleErrors"] if "GPU stall due to ReadPixels" not in m]
    assert problems == [], problems
    w, h = report["width"], report["height"]
    images = {name: [np.frombuffer(base64.b64decode(v), np.float32).reshape(h, w, 4)[..., :3].astype(np.float64)
                     for v in views] for name, views in zip(jobs, report["renders"], strict=True)}
    store = bakery.open_store(blob_store)
    probe = store.probe_names[0]
    return {"report": report, "images": images, "store": store, "probe": probe, "root": root,
            "capture": captures(store, require_capture_encoding(store), [probe])[probe],
            "grid_store": bakery.open_store(grid_store)}


@pytest.fixture(scope="module")
def three(blob_store, grid_store, tmp_path_factory) -> dict:
    return render_three(blob_store, grid_store, tmp_path_factory.mktemp("three_render"), "webgl", JOBS)


#: The jobs three's WebGPURenderer renders: all but ``MeshLambertMaterial`` under scene.environment (in r187's
#: WebGPURenderer it takes no light from it: a white Lambert sphere in a white environment renders 0, three's own
#: ``CubeTexture`` of canvases as well as our cube, where a ``MeshStandardMaterial`` of roughness 1 renders 1). The grid
#: jobs use three's WebGPU ``LightProbeGrid`` with the same atlas.
WEBGPU_JOBS = {name: job for name, job in JOBS.items() if not name.startswith("lambert")}


@pytest.fixture(scope="module")
def three_webgpu(blob_store, grid_store, tmp_path_factory) -> dict:
    return render_three(blob_store, grid_store, tmp_path_factory.mktemp("three_webgpu"), "webgpu", WEBGPU_JOBS)


@pytest.fixture(params=["webgl", "webgpu"])
def three_both(request) -> dict:
    """The renders of three's WebGLRenderer, then of its WebGPURenderer."""
    return request.getfixturevalue({"webgl": "three", "webgpu": "three_webgpu"}[request.param])


def disc_centres(directions: list[np.ndarray], images: list[np.ndarray], masks=None) -> dict[int, np.ndarray]:
    """{disc: mean direction of the pixels of its colour (every channel ≥ 50 where the disc has it, < 50 where
    not)} over all views."""
    out = {}
    for k, colour in enumerate(BLOB_COLOURS):
        found = [d[np.all((img >= 50) == colour, -1) & (True if masks is None else masks[i])]
                 for i, (d, img) in enumerate(zip(directions, images, strict=True))]
        found = np.concatenate(found)
        if len(found):
            out[k] = found.mean(0) / np.linalg.norm(found.mean(0))
    return out


# ------------------------------------------------------------------------------------------ cubes


def test_three_renders_the_cube_where_the_store_has_it(three_both):
    """scene.background (``backgroundCube``: textureCube(envMap, backgroundRotation · direction), the rotation
    premultiplied by diag(−1, 1, 1) for a cube that is not a render target, ``WebGLBackground``) and mirror spheres
    (metalness 1, roughness 0) lit by scene.environment — three's own PMREM of the cube (``PMREMGenerator``,
    ``flipEnvMap = −1``) and the exported chain as the PMREM (``isPMREMTexture``; ``WebGLMaterials``: the same
    diag(−1, 1, 1)) — show every disc at its direction in the panorama. (Written in bakery's frame, every disc
    showed at (−x, y, z): 123° off for the +X disc.) Also with three's WebGPURenderer (WebGPU on SwiftShader):
    measured ≤ 2.6° (sky) and ≤ 3.2° (mirrors)."""
    report, images = three_both["report"], three_both["images"]
    centres = disc_centres(sky_directions(report), images["sky"])
    assert sorted(centres) == list(range(6)), sorted(centres)
    for k, c in centres.items():
        assert angle_degrees(c, BLOBS[k]) < 3.0, (k, c)  # measured ≤ 2.6°
        assert angle_degrees(c, BLOBS[k] * MIRROR_X) > 20.0
    normals = sphere_normals(report)
    for job in ("mirror_pmrem", "mirror_chain"):
        reflected = [2 * (n @ np.array(v))[..., None] * n - np.array(v)
                     for (n, _), v in zip(normals, report["views"], strict=True)]
        centres = disc_centres(reflected, images[job], [m for _, m in normals])
        assert sorted(centres) == list(range(6)), (job, sorted(centres))
        for k, c in centres.items():
            assert angle_degrees(c, BLOBS[k]) < 6.0, (job, k, c)  # measured ≤ 3.2°; discs stretch at the limb
            assert angle_degrees(c, BLOBS[k] * MIRROR_X) > 20.0


def test_three_skybox_pixels_are_the_store_capture(three_both):
    """Every skybox pixel away from face edges is the store's capture, bilinear at the pixel's direction through the
    GL face table (the file's texels are the capture mirrored in x and three mirrors the lookup back), within
    the filtering of a 32-bit float target."""
    report, capture = three_both["report"], three_both["capture"]
    n, checked = capture.shape[1], 0
    for directions, image in zip(sky_directions(report), three_both["images"]["sky"], strict=True):
        _, s, t = gl_face_st(directions)
        interior = (np.minimum(s, t) > 1.5 / n) & (np.maximum(s, t) < 1 - 1.5 / n)
        texels, weights = gl_bilinear_taps(capture, directions)
        expected = np.sum(texels * weights, axis=0)
        error = np.abs(image - expected)
        tolerance = 2e-4 * expected + 5e-4  # the file holds the float16 capture itself; measured ≤ 1e-5 relative
        if three_both["report"]["info"]["renderer"] == "WebGLRenderer":
            assert np.all(error[interior] <= tolerance[interior]), error[interior].max()
        else:
            # WebGPU on SwiftShader: exact where the four texels agree; across the discs' edges (100× contrast) the
            # blend weights are coarser (measured: up to 0.79 off, 0.8 % of the step), but within the four texels
            flat = np.all(np.ptp(texels, axis=0) <= 1e-3 * expected, axis=-1)
            assert np.all(error[interior & flat] <= tolerance[interior & flat]), error[interior & flat].max()
            low, high = texels.min(axis=0) - tolerance, texels.max(axis=0) + tolerance
            assert np.all(((image >= low) & (image <= high))[interior])
            assert np.median(error[interior]) <= 1e-5, np.median(error[interior])
        checked += int(interior.sum())
    assert checked > 0.6 * 6 * SIZE * SIZE


def test_three_reads_the_exported_chain_at_three_s_roughness(three_both):
    """The background at ``backgroundBlurriness`` r samples the PMREM at ``roughnessToMip(r)``
    (``backgroundCube``, ``envmap_common_pars_fragment``: maxLod·r(2 − r)). With the exported chain as the PMREM,
    r = ``lodToRoughness(1, 2)`` lands on level 1 and r = 1 on the last (8²) level: both are the GGX prefilter of the
    store's capture at α = r² (quadrature), as the ``three`` profile prefilters them. three's own PMREM of the same
    cube (level 0 re-filtered: ≥ 256² faces, VNDF sampling) agrees more loosely."""
    report, capture = three_both["report"], three_both["capture"]
    directions = [d.reshape(-1, 3) for d in sky_directions(report)]
    measured = {}
    for r in ROUGH:
        expected = [ggx_prefilter(capture, d, r * r) for d in directions]
        for env in ("chain", "pmrem"):
            got = [img.reshape(-1, 3) for img in three_both["images"][f"blur{r:.3f}_{env}"]]
            l1 = sum(np.abs(g - e).sum() for g, e in zip(got, expected, strict=True)) / sum(e.sum() for e in expected)
            measured[(r, env)] = l1
    assert measured[(R1, "chain")] < 0.06 and measured[(1.0, "chain")] < 0.02, measured  # measured 5.2 %, 0.8 %
    # measured 9.8 %, 1.1 % (WebGL) and 9.7 %, 1.1 % (WebGPU, on a fresh copy of the cube: three_render_page.html)
    assert measured[(R1, "pmrem")] < 0.15 and measured[(1.0, "pmrem")] < 0.03, measured


def diffuse_errors(render: dict, jobs: tuple[str, ...]) -> tuple[dict[str, float], float]:
    """({job: worst |pixel − E(n)/π| over the sphere's views}, max E/π): E the cosine integral of the store's
    capture at each pixel's world normal."""
    worst, peak = {job: 0.0 for job in jobs}, 0.0
    for view, (normals, inside) in enumerate(sphere_normals(render["report"])):
        expected = cosine_irradiance_over_pi(render["capture"], normals[inside])
        peak = max(peak, float(expected.max()))
        for job in jobs:
            worst[job] = max(worst[job], float(np.abs(render["images"][job][view][inside] - expected).max()))
    return worst, peak


def test_three_diffuse_light_of_the_cube_is_the_cosine_integral_of_the_store(three):
    """A white Lambertian sphere (``MeshLambertMaterial``) lit by scene.environment shades E(n)/π with E from
    ``getIBLIrradiance``: π × the PMREM's last level at the world normal (``envmap_physical_pars_fragment``,
    ``textureLod(envMap, n, ENVMAP_MAX_LOD)``). Both the exported chain (last level 8², α = 1) and three's own
    PMREM give the exact cosine integral of the store's capture; with the full chain down to 1×1 (the former
    default) the chain path was 35 % of the maximum off."""
    worst, peak = diffuse_errors(three, ("lambert_chain", "lambert_pmrem", "lambert_full_chain"))
    assert worst["lambert_chain"] < 0.04 * peak and worst["lambert_pmrem"] < 0.04 * peak, (worst, peak)  # 2.7, 2.8 %
    assert worst["lambert_full_chain"] > 0.2 * peak, (worst, peak)  # measured 35 %: why the chain stops at 8²


def test_three_diffuse_material_lit_by_three_s_pmrem_of_the_cube_is_the_cosine_integral(three_both):
    """A white ``MeshPhysicalMaterial`` with no specular lobe (roughness 1, metalness 0, ``specularIntensity`` 0)
    lit by scene.environment = the exported cube — three's own PMREM of it, and the exported chain as the PMREM
    (``isPMREMTexture``, read at its last level; WebGPU: ``PMREMNode`` takes such a texture as it is) — shades the
    cosine integral of the store's capture / π, with both renderers (WebGPURenderer's ``MeshLambertMaterial`` takes
    no light from scene.environment: ``WEBGPU_JOBS``)."""
    worst, peak = diffuse_errors(three_both, ("diffuse_pmrem", "diffuse_chain"))
    # measured 2.8 % (three's PMREM) and 2.7 % (the chain) with either renderer; Lambert under WebGL: 2.8 %, 2.7 %
    assert all(w < 0.04 * peak for w in worst.values()), (worst, peak)


def test_three_cube_levels_are_three_s_pmrem_layout(three):
    """The default chain is three's PMREM layout at the capture's face size: faces halving down to the last ≥ 8²
    (``PMREMGenerator``: ``LOD_MIN = 3``), level i prefiltered at α = r_i², r_i = ``lodToRoughness(i, maxLod)``;
    the file's levels are what three's renderer counts (``WebGLPrograms``: ``envMapMaxLod`` = levels − 1), and the
    loader snippet's default takes the chain as the PMREM only from 5 levels (128² faces) on."""
    from bakery.export.ktx2 import read_ktx2

    cube = read_ktx2(next((three["root"] / "blobs").glob("*.ktx2")).read_bytes())
    record = json.loads(cube.key_values["bakery:profile"].rstrip(b"\0"))
    sizes = [max(1, cube.width >> i) for i in range(len(cube.levels))]
    assert sizes == [32, 16, 8] and record["levels"] == 3
    np.testing.assert_allclose(record["level_alphas"], [three_lod_to_roughness(i, 2) ** 2 for i in range(3)],
                               atol=1e-12)
    info = three["report"]["info"]["cubes"]
    assert info["default"]["levels"] == 3 and info["full"]["levels"] == 6
    assert info["default"]["colorSpace"] == "srgb-linear" and not info["default"]["defaultIsPMREM"]
    assert b"mirrored in x" in cube.key_values["bakery:cube_frame"]


def test_three_cube_faces_are_the_environment_mirrored_in_x():
    """Closed form of the three cube frame: filled with each texel's own direction, the three cube's texel at GL
    direction d holds (−d.x, d.y, d.z)."""
    from bakery.export.three import three_cube_faces

    for n in (1, 4, 5):
        directions = gl_texel_directions(n)
        np.testing.assert_allclose(three_cube_faces(directions), directions * MIRROR_X, atol=1e-12)


# ------------------------------------------------------------------------------------------ irradiance


def test_three_light_probe_shades_the_store_irradiance(three_both):
    """A white Lambertian sphere lit only by the exported ``LightProbe`` (``lights_pars_begin``:
    ``shGetIrradianceAt`` at the world normal; ``RE_IndirectDiffuse_Lambert``: × albedo/π; WebGPU: the same
    ``getShIrradianceAt``) shades the store's E(n)/π, not a mirrored one. The disc store's SH3 irradiance rings below
    zero on the dark side (−0.06 at worst): WebGLRenderer's float target keeps the negative values, WebGPURenderer
    shows 0 there (measured: 3.1 % of the maximum against the unclamped E/π, all of it where E < 0)."""
    store, probe = three_both["store"], three_both["probe"]
    encoding = irradiance_encoding(store, probe)
    webgl = three_both["report"]["info"]["renderer"] == "WebGLRenderer"
    worst = mirrored = peak = 0.0
    views = zip(sphere_normals(three_both["report"]), three_both["images"]["probe"], strict=True)
    for (normals, inside), image in views:
        expected = store.evaluate_irradiance(encoding, normals[inside], probes=[probe])[0] / np.pi
        flipped = store.evaluate_irradiance(encoding, normals[inside] * MIRROR_X, probes=[probe])[0] / np.pi
        if not webgl:
            expected, flipped = np.maximum(expected, 0.0), np.maximum(flipped, 0.0)
        worst = max(worst, float(np.abs(image[inside] - expected).max()))
        mirrored = max(mirrored, float(np.abs(image[inside] - flipped).max()))
        peak = max(peak, float(expected.max()))
    assert worst < 0.01 * peak, worst / peak  # measured 0.3 % (tessellation), both renderers
    assert mirrored > 0.2 * peak

def test_three_light_probe_grid_shades_the_store_irradiance_between_probes(three_both):
    """Spheres lit only by the exported ``LightProbeGridWebGL`` (atlas from KTX2Loader, box from
    lightprobegrids.json): ``getLightProbeGridIrradiance`` samples at p + n·spacing/2, clamped to the outer probe
    centres, trilinearly between the probes, and clamps at 0 — so each pixel is that trilinear blend of the store's
    E(n) at the probes around the sample point (positions from the store), / π. A wrong lattice (x reversed) is far
    off. WebGPURenderer: the same atlas in three's ``LightProbeGrid`` (``LightProbeGridNode``, the same sampling);
    measured 0.49 % and 0.43 % of the maximum with either renderer."""
    store = three_both["grid_store"]
    positions, names = np.asarray(store.probe_positions), store.probe_names
    lo, hi = positions.min(0), positions.max(0)
    resolution = np.array([3, 2, 2])
    spacing = (hi - lo) / (resolution - 1)
    index = {tuple(i): k for k, i in enumerate(np.rint((positions - lo) / spacing).astype(int).tolist())}
    info = three_both["report"]["info"]["grid"]
    np.testing.assert_allclose(info["min"], lo - spacing / 2, atol=1e-6)
    np.testing.assert_allclose(info["max"], hi + spacing / 2, atol=1e-6)

    def expected_at(normals: np.ndarray, centre, radius, reverse_x: bool = False) -> np.ndarray:
        sample = np.asarray(centre) + radius * normals + normals * spacing / 2
        u = np.clip((sample - lo) / spacing, 0, resolution - 1)
        base = np.minimum(np.floor(u).astype(int), resolution - 2)
        f = u - base
        irradiance = np.stack([store.evaluate_irradiance("sh3", normals, probes=[p])[0] for p in names])
        total = 0.0
        for corner in np.ndindex(2, 2, 2):
            weight = np.prod(np.where(np.array(corner) == 1, f, 1 - f), axis=1)
            cells = base + np.array(corner)
            if reverse_x:
                cells[:, 0] = resolution[0] - 1 - cells[:, 0]
            rows = np.array([index[tuple(c)] for c in cells.tolist()])
            total = total + weight[:, None] * irradiance[rows, np.arange(len(normals))]
        return np.maximum(total, 0.0) / np.pi

    normals = sphere_normals(three_both["report"])
    for i, (centre, radius) in enumerate(GRID_SPHERES):
        worst = wrong = peak = 0.0
        for (n, inside), image in zip(normals, three_both["images"][f"grid{i}"], strict=True):
            expected = expected_at(n[inside], centre, radius)
            worst = max(worst, float(np.abs(image[inside] - expected).max()))
            wrong = max(wrong, float(np.abs(image[inside] - expected_at(n[inside], centre, radius, True)).max()))
            peak = max(peak, float(expected.max()))
        assert worst < 0.015 * peak, (i, worst / peak)  # measured 0.5 %
        assert wrong > 5 * worst, (i, wrong / peak, worst / peak)


# ------------------------------------------------------------------------------------------ KTX 2.0 specification

#: [KTX2] §3.1 identifier.
KTX2_IDENTIFIER = bytes([0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A])
#: vkFormat → (typeSize ([KTX2] §3.3: the component size; 4 for *_PACK32), texel block bytes)
SPEC_FORMATS = {97: (2, 8), 109: (4, 16), 122: (4, 4), 123: (4, 4)}
F32_ONE, F32_MINUS_ONE, F32_ZERO = 0x3F800000, 0xBF800000, 0


def spec_samples(vk_format: int) -> list[tuple[int, int, int, int, int]]:
    """(bitOffset, bitLength, channelType, sampleLower, sampleUpper) of the basic DFD ([KDFS] 1.3 §5.6–5.18) as
    libktx's vk2dfd writes it (lib/dfdutils/createdfd.c: ``createDFDUnpacked`` for SFLOAT: FLOAT|SIGNED, −1.0f/1.0f;
    ``createDFDPacked`` for UFLOAT: FLOAT, 0/1.0f; the E5B9G9R9 special case: 9-bit mantissas UNORM 0..8448 and the
    shared exponent (EXPONENT flag) 15..31 per channel). Channel ids RGBSDA: R 0, G 1, B 2, A 15."""
    if vk_format in (97, 109):
        bits = 16 if vk_format == 97 else 32
        return [(i * bits, bits, ch | 0xC0, F32_MINUS_ONE, F32_ONE) for i, ch in enumerate((0, 1, 2, 15))]
    if vk_format == 122:
        return [(0, 11, 0x80, F32_ZERO, F32_ONE), (11, 11, 0x81, F32_ZERO, F32_ONE), (22, 10, 0x82, F32_ZERO, F32_ONE)]
    return [s for ch in range(3) for s in ((9 * ch, 9, ch, 0, 8448), (27, 5, ch | 0x20, 15, 31))]


def check_ktx2_against_the_specification(data: bytes) -> dict:
    """Parse ``data`` from the KTX 2.0 text alone and assert its rules; returns the header and key/values."""
    assert data[:12] == KTX2_IDENTIFIER
    vk, type_size, width, height, depth, layers, faces, level_count, scheme = struct.unpack_from("<9I", data, 12)
    dfd_offset, dfd_length, kvd_offset, kvd_length, sgd_offset, sgd_length = struct.unpack_from("<IIIIQQ", data, 48)
    assert vk in SPEC_FORMATS and type_size == SPEC_FORMATS[vk][0]
    assert scheme == 0 and sgd_offset == sgd_length == 0  # no supercompression, no global data
    assert faces in (1, 6) and (faces == 1 or (width == height and depth == 0))  # §3.9 cube faces square, 2-D
    levels = max(level_count, 1)
    assert 1 <= levels <= int(math.log2(max(width, height, depth or 1))) + 1
    index = [struct.unpack_from("<QQQ", data, 80 + 24 * i) for i in range(levels)]
    assert dfd_offset == 80 + 24 * levels  # §3.11: the DFD follows the level index
    # DFD: dfdTotalSize, then one basic block (vendor 0, type 0, version 2) with model RGBSDA, BT.709, linear
    (total,) = struct.unpack_from("<I", data, dfd_offset)
    assert total == dfd_length
    vendor_type, version, block_size = struct.unpack_from("<IHH", data, dfd_offset + 4)
    assert vendor_type == 0 and version == 2 and block_size == dfd_length - 4
    model, primaries, transfer, flags = data[dfd_offset + 12:dfd_offset + 16]
    assert (model, primaries, transfer, flags) == (1, 1, 1, 0)  # RGBSDA, BT709, LINEAR (float data), straight alpha
    assert data[dfd_offset + 16:dfd_offset + 20] == bytes(4)  # 1×1×1×1 texel block
    assert data[dfd_offset + 20] == SPEC_FORMATS[vk][1] and data[dfd_offset + 21:dfd_offset + 28] == bytes(7)
    samples = []
    for s in range((block_size - 24) // 16):
        at = dfd_offset + 28 + 16 * s
        offset, length, channel = struct.unpack_from("<HBB", data, at)
        assert data[at + 4:at + 8] == bytes(4)
        lower, upper = struct.unpack_from("<II", data, at + 8)
        samples.append((offset, length + 1, channel, lower, upper))
    assert samples == spec_samples(vk)
    # KVD: sorted by key bytes, each entry padded to 4, KTX* values NUL-terminated
    keys, pos = {}, kvd_offset
    assert kvd_offset == dfd_offset + dfd_length
    while pos < kvd_offset + kvd_length:
        (length,) = struct.unpack_from("<I", data, pos)
        key, value = data[pos + 4:pos + 4 + length].split(b"\0", 1)
        keys[key.decode()] = value
        pos += 4 + length + (-length % 4)
    assert pos == kvd_offset + kvd_length and list(keys) == sorted(keys, key=str.encode)
    assert "KTXcubemapIncomplete" not in keys  # complete cubes only
    assert keys["KTXwriter"].endswith(b"\0") and keys["KTXwriter"].startswith(b"bakery ")
    orientation = keys["KTXorientation"]
    assert orientation == (b"rd\0" if depth == 0 else b"ruo\0")  # cubes: must be rd (§faceCount); 3-D: below
    # level data: smallest level first, each at a multiple of lcm(texel block size, 4), sizes from the header
    align = math.lcm(SPEC_FORMATS[vk][1], 4)
    previous_end = kvd_offset + kvd_length
    for i in range(levels - 1, -1, -1):
        offset, length, uncompressed = index[i]
        expected = (max(1, width >> i) * max(1, height >> i) * max(1, (depth >> i) if depth else 1) * max(layers, 1)
                    * faces * SPEC_FORMATS[vk][1])
        assert length == uncompressed == expected and offset % align == 0
        assert previous_end <= offset < previous_end + align  # mipPadding only
        previous_end = offset + length
    assert previous_end == len(data)
    return {"vk_format": vk, "faces": faces, "layers": layers, "depth": depth, "levels": level_count, "keys": keys}


def test_ktx2_files_follow_the_ktx2_specification(blob_store, grid_store, tmp_path):
    """Every KTX2 bakery writes — the ``ktx2`` cube in each vkFormat, the cube array, the ``three`` cube and 3-D
    grid atlas — against [KTX2] §3 (header, index, DFD, KVD, level order, mipPadding) and the DFD values of each
    vkFormat ([KDFS], libktx ``vk2dfd``). The 3-D atlas's ``KTXorientation`` is ``ruo``: its rows run along +y
    (up) and its slices along +z (out of the screen in a right-handed, y-up view), the upload order
    ``LightProbeGridWebGL`` samples; the cubes' is ``rd``, the only value [KTX2] allows for cube maps."""
    files = []
    for vk in ("R16G16B16A16_SFLOAT", "R32G32B32A32_SFLOAT", "B10G11R11_UFLOAT_PACK32", "E5B9G9R9_UFLOAT_PACK32"):
        result = export_store(blob_store, tmp_path / vk, "ktx2", layer=False, options={"vk_format": vk})
        files += [result.output / f for f in result.files]
    result = export_store(blob_store, tmp_path / "array", "ktx2", layer=False, options={"layout": "array"})
    files += [result.output / f for f in result.files]
    for store in (blob_store, grid_store):
        result = export_store(store, tmp_path / f"three-{store.stem}", "three", layer=False)
        files += [result.output / f for f in result.files if f.endswith(".ktx2")]
    seen = set()
    for path in files:
        info = check_ktx2_against_the_specification(path.read_bytes())
        seen.add((info["vk_format"], info["faces"], info["layers"] > 0, info["depth"] > 0))
    assert seen == {(97, 6, False, False), (109, 6, False, False), (122, 6, False, False), (123, 6, False, False),
                    (97, 6, True, False), (109, 1, False, True)}, seen
