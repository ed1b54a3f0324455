"""Incremental scene bakes on constructed USD scenes: nothing changed → zero; one probe moved → that probe;
a local light changed → only the probes it can affect (conservative bound); the dome changed → all."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from usd_scenes import header, material, plane_mesh, probe, write

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000"}


def scene_text(light_intensity=50.0, moved=0.0, dome_intensity=0.5):
    probes = "".join(probe(f"P{i}", (x + (moved if i == 3 else 0.0), 1.0, 0.0))
                     for i, x in enumerate([0.0, 0.5, 100.0, 200.0]))
    return (header() + material("Grey") + plane_mesh("Ground", 400.0, "/Grey") + f"""
def DomeLight "Sky"
{{
    float inputs:intensity = {dome_intensity}
}}
def SphereLight "Lamp"
{{
    float inputs:intensity = {light_intensity}
    float inputs:radius = 0.1
    double3 xformOp:translate = (0, 1.5, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
""" + probes)


def bake(scene, store, *encodings: str):
    flags = [a for e in encodings or ("sh2",) for a in ("-e", e)]
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "bake", str(scene), "-o", str(store), *flags,
                             "--face-size", "8", "-j", "1", "--json"], capture_output=True, text=True, env=ENV)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_incremental_scene_rebakes(tmp_path):
    scene = write(tmp_path / "scene.usda", scene_text())
    store = tmp_path / "scene.h5"
    assert bake(scene, store)["baked"] == 4
    again = bake(scene, store)
    assert (again["baked"], again["reused"]) == (0, 4)
    write(scene, scene_text(moved=1.0))  # move P3 only
    moved = bake(scene, store)
    assert (moved["baked"], moved["reused"]) == (1, 3)
    # The lamp at (0, 1.5, 0) with radius 0.1: P0 and P1 are 0.5 m from it and mostly lit by it; P2 and P3 are
    # 100–200 m away, where its bound (L·A/d²) is far below 1/256 of their dome irradiance.
    write(scene, scene_text(light_intensity=80.0, moved=1.0))
    light = bake(scene, store)
    assert (light["baked"], light["reused"]) == (2, 2)
    write(scene, scene_text(light_intensity=80.0, moved=1.0, dome_intensity=0.7))
    dome = bake(scene, store)
    assert (dome["baked"], dome["reused"]) == (4, 0)


def test_a_rebake_that_reuses_every_probe_leaves_the_store_bytes_unchanged(tmp_path):
    """Reused probes come from the old store, whose fields read back in name order; fresh batches list them in the
    encoding's order (``shexp_hybrid``: p, q, alpha_range, …). The store is written in one order whatever came
    first, so a re-bake that changes nothing changes no byte."""
    text = scene_text() + probe("Mirror", (0.0, 2.0, 0.0), "BakeryReflectionProbe")
    scene = write(tmp_path / "scene.usda", text)
    store = tmp_path / "scene.h5"
    assert bake(scene, store, "sh2", "shexp_hybrid")["baked"] == 5
    first = store.read_bytes()
    again = bake(scene, store, "sh2", "shexp_hybrid")
    assert (again["baked"], again["reused"]) == (0, 5)
    assert store.read_bytes() == first


def test_light_bound_is_conservative_against_the_render(tmp_path):
    # Bake with and without the lamp: for every probe the bound says is unaffected, the baked irradiance really
    # changes by less than τ = 1/256.
    import bakery
    from bakery.pipeline.dependencies import LIGHT_INFLUENCE_FRACTION, irradiance_bound

    with_lamp = write(tmp_path / "a.usda", scene_text(light_intensity=50.0))
    without = write(tmp_path / "b.usda", scene_text(light_intensity=0.0))
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    bake(with_lamp, a)
    bake(without, b)
    sa, sb = bakery.open_store(a), bakery.open_store(b)
    up = np.array([[0.0, 1.0, 0.0]])
    ea = sa.evaluate_irradiance("sh2", up)[:, 0].mean(axis=1)
    eb = sb.evaluate_irradiance("sh2", up)[:, 0].mean(axis=1)
    record = json.loads(str(sa.attributes["scene_lights"]))[0]
    bound = irradiance_bound(record, sa.probe_positions)
    for i in range(4):
        if bound[i] < LIGHT_INFLUENCE_FRACTION * eb[i]:
            assert abs(ea[i] - eb[i]) < LIGHT_INFLUENCE_FRACTION * eb[i]
    assert abs(ea[0] - eb[0]) <= bound[0]  # the bound bounds the real change


def test_scene_hash_covers_the_capture_model_and_shading_normals(tmp_path, monkeypatch):
    """A store baked by a capture that models the scene differently is re-baked, not reused: the scene hash
    includes the capture model's version and the meshes' shading normals."""
    import dataclasses

    import bakery.capture.render as render
    from bakery.pipeline.dependencies import environment_hash
    from bakery.usd.scene import read_scene

    scene = read_scene(write(tmp_path / "scene.usda", scene_text())).scene
    base = environment_hash(scene)
    assert environment_hash(scene) == base
    mesh = scene.meshes[0]
    up = np.broadcast_to(np.float32([0.0, 1.0, 0.0]), mesh.triangles.shape).copy()
    smooth = dataclasses.replace(scene, meshes=(dataclasses.replace(mesh, normals=up),) + scene.meshes[1:])
    assert environment_hash(smooth) != base
    monkeypatch.setattr(render, "CAPTURE_MODEL_VERSION", render.CAPTURE_MODEL_VERSION + 1)
    assert environment_hash(scene) != base


def test_a_probes_capture_resolution_and_image_orientation_enter_its_hash(tmp_path):
    """What the scene says of how one probe is captured — its capture resolution, its captured image's orientation
    — re-bakes that probe alone (the store was reused before: the probe's spec was not in its hash); what does not
    change its capture — a rendered probe's rotation, the image's path for the same bytes — re-bakes nothing."""
    import shutil

    shutil.copy(ROOT / "examples/data/StinsonBeach_512.hdr", tmp_path / "a.hdr")
    shutil.copy(ROOT / "examples/data/StinsonBeach_512.hdr", tmp_path / "b.hdr")

    def text(resolution=8, turn=0.0, spin=0.0, image="a.hdr"):
        return (header() + material("Grey") + plane_mesh("Ground", 400.0, "/Grey")
                + 'def DomeLight "Sky"\n{\n    float inputs:intensity = 0.5\n}\n'
                + probe("Plain", (0.0, 1.0, 0.0), body=f"float xformOp:rotateY = {spin}").replace(
                    '["xformOp:translate"]', '["xformOp:translate", "xformOp:rotateY"]')
                + probe("Sized", (2.0, 1.0, 0.0), body=f"int bakery:capture:resolution = {resolution}")
                + f"""
def BakeryIrradianceProbe "Captured"
{{
    asset bakery:capture:image = @./{image}@
    double3 xformOp:translate = (4, 1, 0)
    float xformOp:rotateY = {turn}
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY"]
}}
""")

    scene = write(tmp_path / "scene.usda", text())
    store = tmp_path / "scene.h5"
    assert bake(scene, store)["baked"] == 3
    write(scene, text(resolution=16))
    sized = bake(scene, store)
    assert (sized["baked"], sized["reused"]) == (1, 2)
    write(scene, text(resolution=16, turn=90.0))
    turned = bake(scene, store)
    assert (turned["baked"], turned["reused"]) == (1, 2)
    write(scene, text(resolution=16, turn=90.0, spin=45.0, image="b.hdr"))  # same bytes, another file
    assert bake(scene, store)["reused"] == 3


def test_a_probe_rebaked_alone_gets_the_bits_a_clean_bake_gives_it(tmp_path):
    """Move one of three reflection probes: the incremental bake re-bakes it alone (a batch of 1), the clean bake of
    the edited scene bakes it with the others; every field of every encoding is bit-identical (before: its
    SH-exponential fit and SH-domain levels differed in float32 rounding, 2.9e-4 relative)."""
    import bakery

    def text(moved):
        return scene_text() + "".join(probe(f"R{i}", (i + (moved if i == 1 else 0.0), 2.0, 0.5),
                                            "BakeryReflectionProbe") for i in range(3))

    encodings = ("sh2", "shexp", "shexp_lights", "splitsum", "shexp_hybrid")
    scene = write(tmp_path / "scene.usda", text(0.0))
    incremental = tmp_path / "incremental.h5"
    bake(scene, incremental, *encodings)
    write(scene, text(0.3))
    assert bake(scene, incremental, *encodings)["baked"] == 1
    clean = tmp_path / "clean.h5"
    assert bake(scene, clean, *encodings)["baked"] == 7
    a, b = bakery.open_store(incremental), bakery.open_store(clean)
    for encoding in encodings:
        fa, fb = a.fields(encoding), b.fields(encoding)
        assert set(fa) == set(fb)
        for name in fa:
            assert np.asarray(fa[name]).tobytes() == np.asarray(fb[name]).tobytes(), (encoding, name)
