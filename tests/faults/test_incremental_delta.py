"""Issue 15 case 9 — incremental bakes by the change in emission (``bakery/pipeline/dependencies.py``): when only
a light's emission changes, (a) a relative change below τ = 1/256 re-bakes nothing, (b) otherwise the influence
bound uses |ΔL| = |L_new − L_old|, so only the probes where the change can reach τ of their irradiance re-bake.
Every probe left alone really changed by less than τ·max(E(n), Ē) (checked against a clean bake of the edited
scene; the renders are linear in emission, so this is exact), also after repeated small edits."""

from __future__ import annotations

import json

import numpy as np
import pytest
from faultkit import incli
from usd_scenes import header, material, plane_mesh, probe

import bakery
from bakery.pipeline.dependencies import (
    LIGHT_INFLUENCE_FRACTION,
    mean_irradiance_from_store,
    probes_affected_by_light_changes,
)
from bakery.store.format import read_store

pytestmark = pytest.mark.faults

FLAGS = ("-e", "sh2", "--face-size", "8", "--samples", "2", "--bounces", "0", "-j", "1", "--json")
NORMALS = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def scene(lamp: float, lamp_x: float = 0.0, dome: float = 1.0) -> str:
    """50 probes on a 10 × 5 grid (1.2 m apart, 11 × 5 m) around a sphere lamp, under a dome."""
    probes = "".join(probe(f"P{i}_{j}", (-5.4 + 1.2 * i, 1.0, -2.4 + 1.2 * j)) for i in range(10) for j in range(5))
    return (header() + material("Grey") + plane_mesh("Ground", 30.0, "/Grey") + f"""
def DomeLight "Sky"
{{
    float inputs:intensity = {dome}
}}
def SphereLight "Lamp"
{{
    float inputs:intensity = {lamp}
    float inputs:radius = 0.1
    double3 xformOp:translate = ({lamp_x}, 1.6, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
""" + probes)


def _bake(path, store, *extra):
    result = incli("bake", path, "-o", store, *FLAGS, *extra)  # in process: 50-probe bakes, a dozen of them
    assert result.returncode == 0, result.output
    return json.loads(result.stdout)


def _old_rule(previous, store):
    """How many probes the bound before issue 15 re-baked (L_max·A of old + new, no relative test)."""
    old = [{k: v for k, v in r.items() if k not in ("geometry", "projected_area")}
           for r in json.loads(previous.attributes["scene_lights"])]
    for record in old:
        record["power"] = max(record["radiance"]) * record["area"]
    new = [{k: v for k, v in r.items() if k not in ("geometry", "projected_area")}
           for r in json.loads(bakery.open_store(store).attributes["scene_lights"])]
    for record in new:
        record["power"] = max(record["radiance"]) * record["area"]
    names = list(previous.probe_names)
    affected, _ = probes_affected_by_light_changes(old, new, names, np.asarray(previous.probe_positions),
                                                   mean_irradiance_from_store(previous, names))
    return len(affected)


def _assert_conservative(tmp_path, scene_path, store, baseline):
    """Every probe of ``store`` differs from a clean bake by less than τ · max(E(n), Ē) of the bake it came from."""
    clean = tmp_path / "clean.h5"
    _bake(scene_path, clean, "--no-resume")
    incremental = bakery.open_store(store).evaluate_irradiance("sh2", NORMALS)  # (P, N, 3)
    reference = bakery.open_store(clean).evaluate_irradiance("sh2", NORMALS)
    mean = mean_irradiance_from_store(baseline, baseline.probe_names)[:, None, None]
    allowed = LIGHT_INFLUENCE_FRACTION * np.maximum(np.abs(incremental), mean) + 1e-6
    worst = np.max(np.abs(incremental - reference) / allowed)
    assert worst <= 1.0, worst
    clean.unlink()


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    folder = tmp_path_factory.mktemp("delta")
    path, store = folder / "scene.usda", folder / "s.h5"
    path.write_text(scene(50.0))
    assert _bake(path, store)["baked"] == 50
    return store


@pytest.fixture
def baked(tmp_path, baseline):
    """The scene and a copy of its baked store (content hashes do not depend on where the scene file is)."""
    import shutil

    path, store = tmp_path / "scene.usda", tmp_path / "s.h5"
    path.write_text(scene(50.0))
    shutil.copy(baseline, store)
    return path, store


def test_a_tiny_intensity_edit_rebakes_nothing(tmp_path, baked):
    path, store = baked
    previous = read_store(store)
    path.write_text(scene(50.0 * 1.0017))  # +0.17 %
    edited = _bake(path, store)
    before = _old_rule(previous, store)
    print(f"+0.17 %: {edited['baked']} of 50 probes re-baked (the bound before issue 15: {before})")
    assert edited["baked"] == 0 and before == 50
    _assert_conservative(tmp_path, path, store, previous)


def test_a_larger_edit_rebakes_only_where_the_change_reaches_tau(tmp_path, baked):
    path, store = baked
    previous = read_store(store)
    path.write_text(scene(50.0 * 1.02))  # +2 %: above τ relative, so the |ΔL| bound decides per probe
    edited = _bake(path, store)
    before = _old_rule(previous, store)
    print(f"+2 %: {edited['baked']} of 50 probes re-baked (the bound before issue 15: {before})")
    assert 0 < edited["baked"] < before
    _assert_conservative(tmp_path, path, store, previous)


def test_repeated_small_edits_do_not_accumulate(tmp_path, baked):
    path, store = baked
    original = read_store(store)
    counts = []
    for step in (1, 2, 3):  # +0.3 % each: below τ alone, above it together
        path.write_text(scene(50.0 * 1.003**step))
        counts.append(_bake(path, store)["baked"])
    print(f"three +0.3 % edits: {counts} probes re-baked")
    assert counts[0] == 0 and sum(counts) > 0  # compared with the lights each probe was baked with
    _assert_conservative(tmp_path, path, store, original)


def test_moving_the_light_uses_the_old_and_new_bound(tmp_path, baked):
    path, store = baked
    previous = read_store(store)
    path.write_text(scene(50.0, lamp_x=0.05))  # geometry changed: old + new power, not |ΔL|
    assert _bake(path, store)["baked"] > 0
    _assert_conservative(tmp_path, path, store, previous)
