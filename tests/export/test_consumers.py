"""The real consumers of ``bakery export`` (no mocks): ktx-parse, KTX-Software's libktx (WASM), three.js r187,
Filament, the Khronos glTF validator (Node, one process each) and Babylon.js in headless Chromium (one launch).
Pinned in tests/package.json / package-lock.json; `.ci/run` runs `npm ci --prefix tests`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.export import export_store
from bakery.export import ktx2 as k2
from bakery.export.gltf import FACE_TRANSFORM, decode_rgbd, encode_rgbd
from bakery.export.source import captures, prefilter_for_profile, require_capture_encoding
from bakery.sphere.fibonacci import fibonacci_directions
from conftest import chromium_or_skip, run_node

NORMALS = fibonacci_directions(24)


@pytest.fixture(scope="module")
def exports(stores, tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("exports")
    for scene in ("indoor", "outdoor", "sun"):
        for fmt in ("ktx2", "gltf", "three", "filament"):
            export_store(stores[scene], d / scene / fmt, fmt, layer=False)
    export_store(stores["outdoor"], d / "outdoor" / "array", "ktx2", layer=False,
                 options={"layout": "array", "vk_format": "B10G11R11_UFLOAT_PACK32", "levels": 4})
    export_store(stores["sun"], d / "sun" / "e5", "ktx2", layer=False, profile="filament",
                 options={"vk_format": "E5B9G9R9_UFLOAT_PACK32"})
    return {"root": d}


def test_ktx2_consumers_read_every_field(exports):
    files = sorted(exports["root"].rglob("*.ktx2"))
    root = exports["root"]
    truncated = root / "truncated.ktx2"
    truncated.write_bytes(files[0].read_bytes()[:-64])
    inconsistent = root / "inconsistent.ktx2"
    data = bytearray(files[0].read_bytes())
    data[40:44] = (20).to_bytes(4, "little")  # levelCount 20: more levels than the extent allows
    inconsistent.write_bytes(bytes(data))
    report = run_node("ktx2_consumers.mjs", *files, truncated, inconsistent,
                      packages=("ktx-parse", "three", "@khronosgroup/gltf-viewer"))
    for path in files:
        r = report[str(path)]
        tex = k2.read_ktx2(path.read_bytes())
        kp = r["ktxParse"]
        assert "error" not in kp, kp
        assert (kp["vkFormat"], kp["pixelWidth"], kp["pixelHeight"], kp["pixelDepth"], kp["layerCount"],
                kp["faceCount"], kp["levelCount"], kp["typeSize"]) == (
            tex.vk_format, tex.width, tex.height, tex.depth, tex.layers, tex.faces, len(tex.levels), tex.type_size)
        assert [lv["byteLength"] for lv in kp["levels"]] == [len(b) for b in tex.levels]
        assert kp["reserialisedIdentical"], path  # ktx-parse writes the same bytes back
        assert kp["dfd"]["colorModel"] == 1 and kp["dfd"]["transferFunction"] == 1 and kp["dfd"]["colorPrimaries"] == 1
        assert kp["keyValue"]["KTXorientation"] in ("rd", "ruo")  # cubes rd, the 3-D grid atlas ruo
        assert bytes.fromhex(kp["keyValue"]["bakery:profile"]).rstrip(b"\0") == tex.key_values["bakery:profile"].rstrip(b"\0")
        assert kp["level0Head"] == list(tex.levels[0][:32])
        assert r["libktx"]["ok"], r["libktx"]
        assert r["libktx"]["vkFormat"] == tex.vk_format and r["libktx"]["baseWidth"] == tex.width
        assert r["three"]["ok"], r["three"]
        assert r["three"]["isData3DTexture"] == (tex.depth > 0)
        assert len(r["three"]["mipmaps"]) == len(tex.levels)
    assert not report[str(truncated)]["libktx"]["ok"] and not report[str(inconsistent)]["libktx"]["ok"]


def test_three_light_probes_and_grids_match_the_store(stores, exports):
    for scene in ("indoor", "outdoor", "sun"):
        folder = exports["root"] / scene / "three"
        store = bakery.open_store(stores[scene])
        grids = json.loads((folder / "lightprobegrids.json").read_text())["grids"] if (
            folder / "lightprobegrids.json").exists() else []
        request = {"lightprobes": str(folder / "lightprobes.json") if (folder / "lightprobes.json").exists() else None,
                   "normals": NORMALS.tolist(), "ktx2": [str(folder / g["texture"]) for g in grids],
                   "grids": {str(folder / g["texture"]): g for g in grids}}
        req = folder.parent / "three_request.json"
        req.write_text(json.dumps(request))
        report = run_node("three_check.mjs", req, packages=("three",))
        checked = 0
        for name, probe in report["probes"].items():
            from bakery.export.source import irradiance_encoding

            expected = store.evaluate_irradiance(irradiance_encoding(store, name), NORMALS, probes=[name])[0]
            np.testing.assert_allclose(probe["irradiance"], expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max())
            np.testing.assert_allclose(probe["position"], store.probe_positions[store.probe_names.index(name)])
            checked += 1
        for grid in grids:
            entry = report["textures"][str(folder / grid["texture"])]
            assert entry["isData3DTexture"] and entry["depth"] == 7 * (grid["resolution"][2] + 2) and entry["paddingOk"]
            for name, got in entry["irradiance"].items():
                from bakery.export.source import irradiance_encoding

                expected = store.evaluate_irradiance(irradiance_encoding(store, name), NORMALS, probes=[name])[0]
                np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max())
                checked += 1
        assert checked >= 1, scene


def test_filament_reads_the_ktx1_and_its_sh(stores, exports):
    files = sorted(exports["root"].rglob("*.ktx"))
    report = run_node("filament_check.mjs", *files, packages=("filament",))
    for path in files:
        r = report[str(path)]
        assert r["ok"], r
        assert r["isCubemap"] and r["glInternalFormat"] == 0x8C3A and len(r["sh"]) == 27
        assert all(np.isfinite(r["sh"]))
    sun = report[str(exports["root"] / "sun" / "filament" / "environment.ktx")]
    towards_sun = np.array(json.loads(stores["sun_direction"].read_text()))
    # Filament's estimate is the direction the light travels (its DirectionalLight convention): −estimate points
    # at the light
    angle = np.degrees(np.arccos(np.clip(np.dot(-np.array(sun["direction"]), towards_sun), -1, 1)))
    assert angle < 10.0, angle


def test_gltf_validator_reports_no_errors(exports):
    files = sorted(exports["root"].rglob("*.gltf"))
    report = run_node("gltf_validate.mjs", *files, packages=("gltf-validator",))
    for path in files:
        assert report[str(path)]["numErrors"] == 0, report[str(path)]["messages"][:10]


def test_babylon_loads_the_gltf_in_headless_chromium(stores, exports, tmp_path):
    chromium = chromium_or_skip()
    import os

    os.environ["CHROMIUM"] = chromium
    root = exports["root"]
    assets = [str(p.relative_to(root)) for p in sorted(root.rglob("*.gltf"))]
    shot = tmp_path / "babylon.png"
    # Babylon's default scene is left-handed: its glTF loader maps glTF (x, y, z) to world (−x, y, z), and its
    # shaders evaluate the SH at world normals (bakery/export/gltf.py, "Orientation")
    request = {"root": str(root), "assets": assets, "normals": (NORMALS * [-1.0, 1.0, 1.0]).tolist(),
               "screenshot": {"asset": "sun/gltf/environment.gltf", "path": str(shot)}}
    (tmp_path / "req.json").write_text(json.dumps(request))
    report = run_node("babylon_check.mjs", tmp_path / "req.json", packages=("babylonjs", "babylonjs-loaders",
                                                                           "playwright-core"))
    for asset in assets:
        r = report[asset]
        assert "error" not in r, r
        assert r["consoleErrors"] == [], r["consoleErrors"]
        scene = asset.split("/")[0]
        store = bakery.open_store(stores[scene])
        document = json.loads((root / asset).read_text())
        probe = document["nodes"][0]["name"]
        # irradiance: Babylon's own SH (what its PBR shader evaluates at the world normal) = E/π of the store at the
        # glTF normal, within 1 %
        from bakery.export.source import irradiance_encoding, radiance_sh_from_capture

        encoding = irradiance_encoding(store, probe)
        if encoding:
            expected = store.evaluate_irradiance(encoding, NORMALS, probes=[probe])[0] / np.pi
        else:
            cap = captures(store, require_capture_encoding(store), [probe])[probe]
            from bakery.export.source import COSINE_BANDS
            from bakery.sh.basis import evaluate_sh_basis, sh_bands

            design = evaluate_sh_basis(NORMALS, 2) * COSINE_BANDS[sh_bands(2)]
            expected = design @ radiance_sh_from_capture(cap) / np.pi
        scale = np.abs(expected).max()
        assert np.abs(np.array(r["shEval"]) - expected).max() <= 0.01 * scale, asset
        # specular: every read-back texel = the store's capture prefiltered at the profile's α, within RGBD
        record = document["extras"]["bakery"]["profile"]
        cap = captures(store, require_capture_encoding(store), [probe])[probe]
        sizes = [max(1, record["face_size"] >> i) for i in range(record["levels"])]
        chain = prefilter_for_profile(cap, np.array(record["level_alphas"]), tuple(sizes))
        assert r["lodGenerationScale"] == pytest.approx((record["levels"] - 1) / np.log2(record["face_size"]))
        for level, faces in enumerate(r["faces"]):
            n = sizes[level]
            expected_faces = FACE_TRANSFORM(chain[level])
            for face in range(6):
                got = np.array(faces[face]["data"], dtype=np.float64).reshape(n, n, 4)[::-1, :, :3]  # rows bottom-up
                quantised = decode_rgbd(encode_rgbd(expected_faces[face]))
                # Babylon decodes RGBD into a half-float texture: float16 rounding on top of the RGBD quantisation
                assert np.allclose(got, quantised, rtol=2e-3, atol=1e-4 * quantised.max()), (asset, level, face)
                bound = np.abs(quantised - expected_faces[face]) + 2e-3 * np.abs(quantised) + 1e-4 * quantised.max()
                assert np.all(np.abs(got - expected_faces[face]) <= bound + 1e-6)
    assert shot.stat().st_size > 10_000
