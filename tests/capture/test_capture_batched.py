"""Batched capture (ProbeRenderer.render_many, UsdSceneSource.capture_many): a probe's cube and stats are
bit-identical whether it is rendered alone or together with any other probes, in any order and batch size."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import bakery.capture.render as render_module
from bakery.capture.render import ProbeRenderer
from bakery.capture.scene import Light
from bakery.capture.snapshot import write_capture_scene
from bakery.capture.tracer import SceneTracer
from bakery.pipeline.settings import CaptureSettings
from bakery.sources.base import SourceHandle
from bakery.sources.usd_scene import SceneProbeCapture, UsdSceneSource

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = {"indoor": ROOT / "examples/indoor/indoor.usda", "outdoor": ROOT / "examples/outdoor/outdoor.usda"}
FACE = 8


@pytest.fixture(scope="module")
def usd_scenes():
    from bakery.usd.scene import read_scene

    scenes = {name: read_scene(path).scene for name, path in EXAMPLES.items()}
    # every other mesh of the room half present (opacity 0.5, no threshold): presence draws random numbers in the
    # camera, bounce and shadow rays' intersections
    indoor = scenes["indoor"]
    scenes["translucent"] = dataclasses.replace(indoor, meshes=tuple(
        dataclasses.replace(m, material=dataclasses.replace(m.material, opacity=0.5)) if i % 2 == 0 else m
        for i, m in enumerate(indoor.meshes)))
    # the room with 20 more sphere lamps inside it: more lights than are enumerated, so next-event lights are drawn
    # from the light BVH (random numbers per path vertex, draws that depend on each point)
    corners = np.concatenate([np.asarray(m.triangles, dtype=np.float64).reshape(-1, 3) for m in indoor.meshes])
    low, high = np.percentile(corners, 10, axis=0), np.percentile(corners, 90, axis=0)
    rng = np.random.default_rng(4)
    lamps = tuple(Light("sphere", f"/Lamp{i}", radiance=tuple(rng.uniform(1, 10, 3)),
                        position=tuple(rng.uniform(low, high)), size=(float(rng.uniform(0.01, 0.1)), 0.0))
                  for i in range(20))
    scenes["many_lights"] = dataclasses.replace(indoor, lights=indoor.lights + lamps)
    return scenes


def _key(result):
    cube, stats = result
    return cube.tobytes(), stats.rays, stats.samples, repr(stats.sh_noise)


def _render_many(renderer, probes):
    return renderer.render_many([np.asarray(p.position) for p in probes], FACE, [p.name for p in probes])


@pytest.mark.parametrize("adaptive", [False, True])
@pytest.mark.parametrize("name", ["indoor", "outdoor", "translucent", "many_lights"])
def test_a_probe_renders_the_same_alone_batched_and_reordered(name, adaptive, usd_scenes, monkeypatch):
    """Small chunks and calls (several chunks per probe, chunks of several probes per call) so packing matters;
    adaptive: a noise target between the probes' first-pass noises, so some drop out after one pass."""
    monkeypatch.setattr(render_module, "BATCH", 160)
    monkeypatch.setattr(render_module, "CALL_RAYS", 400)
    probes = [p for p in usd_scenes[name].probes if not p.image][:5]
    renderer = ProbeRenderer(usd_scenes[name], samples=2, max_samples=12)
    assert (renderer._light_grid is not None) == (name == "many_lights")  # lights drawn from the light grid
    if adaptive:
        first = sorted(stats.sh_noise for _cube, stats in _render_many(renderer, probes))
        renderer.target_noise = 0.5 * (first[1] + first[2])
    alone = [_key(renderer.render(np.asarray(p.position), FACE, p.name)) for p in probes]
    together = [_key(r) for r in _render_many(renderer, probes)]
    order = [3, 0, 4, 2, 1]
    reordered = [_key(r) for r in _render_many(renderer, [probes[i] for i in order])]
    pairs = [_key(r) for k in range(0, 5, 2) for r in _render_many(renderer, probes[k:k + 2])]
    assert together == alone
    assert reordered == [alone[i] for i in order]
    assert pairs == alone
    assert all(rays > 0 for _cube, rays, _s, _n in alone)
    if adaptive:
        assert len({samples for _c, _r, samples, _n in alone}) > 1  # the probes stopped at different passes


def test_call_packing_keeps_each_probe_s_chunks_in_order(monkeypatch):
    monkeypatch.setattr(render_module, "BATCH", 100)
    monkeypatch.setattr(render_module, "CALL_RAYS", 250)
    calls = render_module._pack_chunks([4, 7, 9], 230)
    assert all(sum(stop - start for _, start, stop in call) <= 250 for call in calls)
    assert all(len({p for p, _, _ in call}) == len(call) for call in calls)
    for p in (4, 7, 9):
        chunks = [(start, stop) for call in calls for q, start, stop in call if q == p]
        assert chunks == [(0, 100), (100, 200), (200, 230)]


@pytest.mark.parametrize("name", ["indoor", "outdoor"])
def test_embree_hits_do_not_depend_on_the_other_rays_of_a_query(name, usd_scenes):
    """Per-ray Embree answers (closest hit and occlusion) are the same in any batch composition and order."""
    tracer = SceneTracer(usd_scenes[name])
    rng = np.random.default_rng(5)
    lo, hi = tracer.triangles.reshape(-1, 3).min(axis=0), tracer.triangles.reshape(-1, 3).max(axis=0)
    m = 3000
    origins = (lo + (hi - lo) * rng.random((m, 3))).T.astype(np.float32)
    directions = rng.normal(size=(3, m)).astype(np.float32)
    directions /= np.sqrt((directions * directions).sum(axis=0))
    distances = rng.uniform(0.1, 20.0, m).astype(np.float32)
    prim, t, u, v = tracer.intersect_uv(origins, directions, soa=True)
    blocked = tracer.occluded(origins, directions, distances, soa=True)
    assert (prim >= 0).any() and blocked.any() and not blocked.all()
    assert (prim < 0).any() == (name == "outdoor")  # the indoor room is closed
    for index in (rng.permutation(m), np.arange(0, m, 7), np.concatenate([np.arange(m), np.arange(m)[::-1]])):
        p2, t2, u2, v2 = tracer.intersect_uv(origins[:, index], directions[:, index], soa=True)
        for a, b in ((prim, p2), (t, t2), (u, u2), (v, v2)):
            assert a[index].tobytes() == b.tobytes()
        assert blocked[index].tobytes() == tracer.occluded(origins[:, index], directions[:, index],
                                                           distances[index], soa=True).tobytes()


def test_scene_source_captures_groups_as_one_by_one_and_attributes_failures(usd_scenes, tmp_path, monkeypatch):
    """capture_many groups the rendered probes (here in groups of 2), loads image probes, and a bad spec fails
    alone: the group it was in falls back to one-by-one capture."""
    from bakery.sources import usd_scene

    monkeypatch.setattr(usd_scene, "GROUP_PROBES", 2)
    scene = usd_scenes["outdoor"]
    digest = write_capture_scene(scene, tmp_path / "scene")
    handle = SourceHandle(UsdSceneSource.kind, str(tmp_path / "scene"), digest)
    settings = CaptureSettings(samples=1)
    specs = [SceneProbeCapture(p, settings) for p in scene.probes]
    specs = specs[:6] + [s for s in specs if s.probe.image]
    assert specs[-1].probe.image
    specs[2] = SceneProbeCapture(dataclasses.replace(specs[2].probe, name="/Bad"), settings)
    # fault injection: the renderer refuses the probe named /Bad, alone or in a group
    render_many = ProbeRenderer.render_many

    def refusing(self, positions, n, names, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        if "/Bad" in names:
            raise RuntimeError("/Bad: refused by the test's renderer")
        return render_many(self, positions, n, names, *args, **kwargs)

    monkeypatch.setattr(ProbeRenderer, "render_many", refusing)  # ProbeRenderer.render calls it too
    many = UsdSceneSource.capture_many(handle, specs, FACE)
    assert isinstance(many[2], Exception) and "/Bad" in str(many[2])
    for spec, capture in zip(specs, many):
        if spec.name == "/Bad":
            continue
        one = UsdSceneSource.capture(handle, spec, FACE)
        assert capture.cube.tobytes() == one.cube.tobytes()
        assert set(capture.stats) == set(one.stats)
        assert capture.stats.get("capture_rays") == one.stats.get("capture_rays")
        assert {k: v.tobytes() for k, v in capture.diagnostics.items()} == \
            {k: v.tobytes() for k, v in one.diagnostics.items()}


def test_capture_bench_in_two_processes_traces_the_same_rays_as_in_one():
    from bakery.bench.capture import bench_scene

    one = bench_scene(EXAMPLES["outdoor"], face_size=4, samples=1, probes=5)
    two = bench_scene(EXAMPLES["outdoor"], face_size=4, samples=1, probes=5, processes=2)
    assert one["rays"] == two["rays"] > 0 and one["sh_noise_median"] == two["sh_noise_median"]
    assert len(two["process_rays_per_second"]) == 2 and min(two["process_rays_per_second"]) > 0
    assert one["scene"] == two["scene"] == "examples/outdoor/outdoor.usda"  # repo-relative: reports compare across machines
