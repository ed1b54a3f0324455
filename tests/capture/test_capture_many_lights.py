"""Many lights: the light BVH's culling and draws (bakery.capture.light_tree), and captures of scenes with more
lights than are enumerated, against brute force and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from usd_scenes import header, material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.capture import lights as lights_module
from bakery.capture.light_tree import CULLED_SHAPES, ENUMERATED_LIGHTS, LightBound, LightBVH, LightGrid
from bakery.capture.tracer import SphereCuller
from bakery.capture.scene import Light
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene


def _random_bounds(rng: np.random.Generator, count: int) -> list[LightBound]:
    centres = rng.uniform(-10, 10, (count, 3))
    radii = rng.uniform(0.05, 0.6, count)
    out = []
    for i, (c, r) in enumerate(zip(centres, radii)):
        if i % 3 == 0:  # one-sided emitters (rect/disk lights) facing random ways
            axis = rng.normal(size=3)
            out.append(LightBound(tuple(c - r), tuple(c + r), float(rng.uniform(0.1, 5)),
                                  tuple(axis / np.linalg.norm(axis)), 1.0, 0.0))
        else:
            out.append(LightBound(tuple(c - r), tuple(c + r), float(rng.uniform(0.1, 5))))
    return out


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 80))
def test_bvh_candidates_are_exactly_the_segments_that_meet_each_box(seed, count):
    """Against a slab test of every segment against every light's box (axis-parallel segments included)."""
    rng = np.random.default_rng(seed)
    bounds = _random_bounds(rng, count)
    tree = LightBVH(bounds)
    s = 400
    origins = rng.uniform(-12, 12, (3, s))
    directions = rng.normal(size=(3, s))
    directions[:, :20] = np.eye(3)[:, rng.integers(0, 3, 20)] * rng.choice([-1, 1], 20)  # along the axes
    directions /= np.linalg.norm(directions, axis=0)
    distances = rng.uniform(0.1, 40, s)
    seg, light = tree.candidates(origins, directions, distances)
    lower = np.array([b.lower for b in bounds])
    upper = np.array([b.upper for b in bounds])
    expected = set()
    for k in range(s):
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (lower - origins[:, k]) / directions[:, k]
            t1 = (upper - origins[:, k]) / directions[:, k]
        near = np.nanmax(np.minimum(t0, t1), axis=1)
        far = np.nanmin(np.maximum(t0, t1), axis=1)
        expected |= {(k, int(j)) for j in np.flatnonzero((near <= far) & (far >= 0) & (near <= distances[k]))}
    assert set(zip(seg.tolist(), light.tolist())) == expected
    assert np.all(np.diff(seg) >= 0)  # by segment


def test_bvh_draws_each_light_with_the_probability_it_reports():
    """Draw frequencies at fixed points match pmf() (binomial 4σ), the draws' own pmf equals pmf(), the pmfs sum to
    at most 1, and no light that can reach a point has probability 0 there (a one-sided light only behind it)."""
    rng = np.random.default_rng(7)
    bounds = _random_bounds(rng, 150)
    tree = LightBVH(bounds)
    draws = 60_000
    for point in rng.uniform(-12, 12, (4, 3)):
        points = np.repeat(point[:, None], draws, axis=1)
        light, pmf = tree.sample(points, rng.random(draws))
        reached = light >= 0
        np.testing.assert_array_equal(tree.pmf(points[:, reached], light[reached]), pmf[reached])
        every = tree.pmf(np.repeat(point[:, None], len(bounds), axis=1), np.arange(len(bounds)))
        assert every.sum() <= 1 + 1e-12
        frequency = np.bincount(light[reached], minlength=len(bounds)) / draws
        sigma = np.sqrt(every * (1 - every) / draws)
        assert np.all(np.abs(frequency - every) <= 4 * sigma + 1e-4)
        for j, b in enumerate(bounds):
            centre = 0.5 * (np.array(b.lower) + np.array(b.upper))
            half = 0.5 * np.linalg.norm(np.array(b.upper) - np.array(b.lower))
            in_front = np.dot(point - centre, b.axis) > half  # surely in front of a one-sided light
            if b.cos_normal <= -1 or in_front:
                assert every[j] > 0, j


def _floor_and_boxes(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles (T, 3, 3) of a 30 m floor at y = −11 and 40 random small boxes' worth of triangles, and their
    boxes (the surfaces a light grid is built over)."""
    floor = np.array([[[-15, -11, -15], [15, -11, -15], [15, -11, 15]], [[-15, -11, -15], [15, -11, 15],
                                                                       [-15, -11, 15]]], dtype=np.float64)
    centres = rng.uniform(-10, 10, (40, 1, 3))
    small = centres + rng.uniform(-0.6, 0.6, (40, 3, 3))
    triangles = np.concatenate([floor, small])
    return triangles, triangles.min(axis=1), triangles.max(axis=1)


def _points_on(triangles: np.ndarray, rng: np.random.Generator, count: int) -> np.ndarray:
    """Uniform barycentric points (3, count) float32 on random triangles of (T, 3, 3)."""
    which = rng.integers(0, len(triangles), count)
    b = rng.dirichlet([1.0, 1.0, 1.0], count)
    return np.einsum("tk,tkc->ct", b, triangles[which]).astype(np.float32)


def test_grid_draws_each_light_with_the_probability_it_reports():
    """The light grid: at points on its surfaces (one distribution per cell) and off them (the BVH's), draw
    frequencies match pmf() (binomial 4σ), the draws' own pmf equals pmf(), and each point's pmfs sum to 1."""
    rng = np.random.default_rng(17)
    bounds = _random_bounds(rng, 150)
    triangles, lower, upper = _floor_and_boxes(rng)
    grid = LightGrid(LightBVH(bounds), lower, upper)
    assert grid.rows > 100
    draws = 60_000
    on_surfaces = _points_on(triangles, rng, 3).T
    for point in [*on_surfaces, np.array([0.0, 14.0, 0.0], dtype=np.float32)]:  # the last: off every surface
        points = np.repeat(point[:, None], draws, axis=1)
        assert (grid._rows_of(points[:, :1])[0] >= 0) == (point[1] < 14)
        light, pmf = grid.sample(points, rng.random(draws))
        reached = light >= 0
        np.testing.assert_array_equal(grid.pmf(points[:, reached], light[reached]), pmf[reached])
        every = grid.pmf(np.repeat(point[:, None], len(bounds), axis=1), np.arange(len(bounds)))
        np.testing.assert_allclose(every.sum(), 1.0, rtol=1e-12)
        frequency = np.bincount(light[reached], minlength=len(bounds)) / draws
        sigma = np.sqrt(every * (1 - every) / draws)
        assert np.all(np.abs(frequency - every) <= 4 * sigma + 1e-4)


def test_grid_draws_several_per_point_as_single_draws_would():
    """sample(points, u, draws=K) with draw-major u gives the lights and pmfs of K single draws."""
    rng = np.random.default_rng(4)
    bounds = _random_bounds(rng, 60)
    triangles, lower, upper = _floor_and_boxes(rng)
    grid = LightGrid(LightBVH(bounds), lower, upper)
    points = np.concatenate([_points_on(triangles, rng, 500), rng.uniform(-30, 30, (3, 100)).astype(np.float32)],
                            axis=1)
    u = rng.random((4, points.shape[1]))
    light, pmf = grid.sample(points, u.reshape(-1), draws=4)
    for k in range(4):
        one_light, one_pmf = grid.sample(points, u[k])
        np.testing.assert_array_equal(light.reshape(4, -1)[k], one_light)
        np.testing.assert_array_equal(pmf.reshape(4, -1)[k], one_pmf)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(2, 60))
def test_grid_never_gives_zero_to_a_light_that_can_reach_a_point(seed, count):
    """Unbiasedness: wherever a light's own importance (its BVH leaf's, pbrt-v4's cone and distance terms) is
    positive at a point on the grid's surfaces, the grid's probability of it is positive there too (one-sided
    and ShapingAPI-like cones included)."""
    rng = np.random.default_rng(seed)
    bounds = _random_bounds(rng, count)
    for i in range(0, count, 4):  # narrow emission cones, as ShapingAPI spots
        axis = rng.normal(size=3)
        bounds[i] = LightBound(bounds[i].lower, bounds[i].upper, bounds[i].power, tuple(axis / np.linalg.norm(axis)),
                               1.0, float(np.cos(np.radians(rng.uniform(5, 40)))))
    tree = LightBVH(bounds)
    triangles, lower, upper = _floor_and_boxes(rng)
    grid = LightGrid(tree, lower, upper)
    points = _points_on(triangles, rng, 400)
    leaves = np.array([int(np.flatnonzero(tree.light == j)[0]) for j in range(count)])
    m = points.shape[1]
    reach = tree.importance(points[:, :, None], np.broadcast_to(leaves, (m, count))) > 0  # (M, L)
    pmf = grid.pmf(np.repeat(points, count, axis=1), np.tile(np.arange(count), m)).reshape(m, count)
    assert not np.any(reach & (pmf <= 0))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 40))
def test_sphere_culler_flags_every_segment_that_meets_a_sphere(seed, count):
    """SphereCuller (Embree query against enclosing icosahedra) against the closed-form segment–sphere test in
    float64: every segment that meets a sphere is flagged, also segments starting or lying inside one, grazing
    ones and broadcast origins."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-20, 20, (count, 3))
    radii = rng.uniform(0.01, 2.0, count)
    culler = SphereCuller(centres, radii)
    m = 4000
    k = rng.integers(0, count, m)
    origins = centres[k] + rng.normal(0, 1, (m, 3)) * radii[k, None] * rng.choice([0.5, 2.0, 8.0], (m, 1))
    directions = rng.normal(size=(m, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    # a third of the segments aimed to graze a sphere: closest approach at radius·(1 ± 1e-4)
    graze = np.flatnonzero(rng.random(m) < 0.3)
    side = np.cross(directions[graze], rng.normal(size=(graze.size, 3)))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    scale = radii[k[graze], None] * (1 + rng.choice([-1e-4, 1e-4], (graze.size, 1)))
    origins[graze] = centres[k[graze]] + side * scale - directions[graze] * rng.uniform(0.5, 5, (graze.size, 1))
    lengths = rng.uniform(0, 10, m)
    o32, d32 = origins.astype(np.float32), directions.astype(np.float32)
    o64, d64 = o32.astype(np.float64), d32.astype(np.float64)
    oc = o64[:, None, :] - centres[None]  # (M, K, 3)
    b = np.einsum("mkc,mc->mk", oc, d64)
    c = np.einsum("mkc,mkc->mk", oc, oc) - radii[None] ** 2
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0))
    meets = (disc >= 0) & (-b + root >= 0) & (-b - root <= lengths[:, None])  # [t0, t1] overlaps [0, length]
    flagged = culler.flag(o32.T, d32.T, lengths)
    assert not np.any(meets.any(axis=1) & ~flagged)
    # the closest-hit query names a sphere for exactly the flagged segments, one whose icosahedron the queried
    # segment (from ``back`` before its origin) can reach: its centre within the circumscribed radius of it
    first = culler.first(o32.T, d32.T, lengths)
    np.testing.assert_array_equal(first >= 0, flagged)
    hit = np.flatnonzero(first >= 0)
    oc = o64[hit] - centres[first[hit]]
    t = np.clip(-np.einsum("mc,mc->m", oc, d64[hit]), -culler.back, lengths[hit])
    gap = np.linalg.norm(oc + t[:, None] * d64[hit], axis=1)
    assert np.all(gap <= 1.3 * radii[first[hit]] + 1e-3)
    origin_of = rng.integers(0, m, m)  # (3, M) origins indexed per segment, as the renderer's shadow rays
    flagged = culler.flag(o32.T, d32.T, lengths, origin_of)
    oc = o64[origin_of][:, None, :] - centres[None]
    b = np.einsum("mkc,mc->mk", oc, d64)
    disc = b * b - (np.einsum("mkc,mkc->mk", oc, oc) - radii[None] ** 2)
    root = np.sqrt(np.maximum(disc, 0))
    meets = (disc >= 0) & (-b + root >= 0) & (-b - root <= lengths[:, None])
    assert not np.any(meets.any(axis=1) & ~flagged)


def _random_rays(rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray]:
    """m rays (3, m) float32 among the lights of :func:`_lights`: origins in a 12 m box, unit directions."""
    origins = rng.uniform(-6, 6, (3, m)).astype(np.float32)
    directions = rng.normal(size=(3, m)).astype(np.float32)
    directions /= np.linalg.norm(directions, axis=0)
    return origins, directions


def _shadow_segments(light_set, origins: np.ndarray, rng: np.random.Generator, j: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(3, J, M) shadow segments from (3, M) origins as the renderer makes them: to a sampled point of a random
    light shape, shortened by SHADOW_EPSILON, skipping that shape — or (a quarter) in a random direction with a
    random length, skipping none. Directions, lengths (J, M) and skips (J, M)."""
    m = origins.shape[1]
    directions = rng.normal(size=(3, j, m)).astype(np.float32)
    directions /= np.linalg.norm(directions, axis=0)
    lengths = rng.uniform(0.5, 12, (j, m)).astype(np.float32)
    skip = np.where(rng.random((j, m)) < 0.25, -1, rng.integers(0, len(light_set.surfaces), (j, m)))
    for row in range(j):
        for k, model in enumerate(light_set.surfaces):
            sel = np.flatnonzero(skip[row] == k)
            wi, dist, _radiance, pdf = model.sample_soa(origins[:, sel], rng.random(sel.size).astype(np.float32),
                                                        rng.random(sel.size).astype(np.float32))
            good = pdf > 0
            directions[:, row, sel[good]] = wi[:, good]
            lengths[row, sel[good]] = dist[good] * (1 - lights_module.SHADOW_EPSILON)
            skip[row, sel[~good]] = -1
    return directions, lengths, skip


def test_light_shape_culling_by_embree_matches_testing_every_shape():
    """nearest_soa / occluded_soa with the Embree culler (PROXY_CULLED_SHAPES … CULLED_SHAPES shapes) give the
    same bits as every shape's test over every segment, with and without ``where``; shadow segments end on the
    shape they skip, as the renderer's do (the culler queries them only up to that shape's culling ball), among
    shapes close enough to one another that some neighbour the end of another's segments."""
    rng = np.random.default_rng(13)
    lights = _lights(rng, 30)
    light_set = lights_module.LightSet(lights)
    assert light_set._culler is not None and light_set._shape_bvh is None
    every = lights_module.LightSet(lights)
    every._culler = None  # every shape's culling sphere on every segment
    m = 20_000
    origins, directions = _random_rays(rng, m)
    for a, b in zip(light_set.nearest_soa(origins, directions), every.nearest_soa(origins, directions)):
        np.testing.assert_array_equal(a, b)
    assert (every.nearest_soa(origins, directions)[1] >= 0).sum() > 500
    assert light_set._near_end.any() and not light_set._near_end.all()
    segments, lengths, skip = _shadow_segments(every, origins, rng, 3)
    blocked = every.occluded_soa(origins, segments, lengths, skip)
    assert blocked.sum() > 500
    np.testing.assert_array_equal(light_set.occluded_soa(origins, segments, lengths, skip), blocked)
    where = rng.random((3, m)) < 0.5
    asked = light_set.occluded_soa(origins, segments, lengths, skip, where=where)
    np.testing.assert_array_equal(asked[where], blocked[where])


def test_many_lights_capture_is_the_same_with_and_without_the_embree_culler(monkeypatch):
    """examples/plaza (32 light shapes): the Embree culler changes the capture's speed, not one bit of it."""
    from pathlib import Path

    from bakery.capture.render import ProbeRenderer

    scene = read_scene(Path(__file__).resolve().parents[2] / "examples" / "plaza" / "plaza.usda").scene
    probes = [p for p in scene.probes if not p.image][:6]
    positions, names = [np.asarray(p.position) for p in probes], [p.name for p in probes]
    culled = ProbeRenderer(scene, samples=2).render_many(positions, 8, names)
    monkeypatch.setattr(lights_module, "PROXY_CULLED_SHAPES", 10**9)
    plain = ProbeRenderer(scene, samples=2)
    assert plain.lights._culler is None
    for (a, sa), (b, sb) in zip(culled, plain.render_many(positions, 8, names)):
        np.testing.assert_array_equal(a, b)
        assert sa.rays == sb.rays


def _lights(rng: np.random.Generator, count: int) -> tuple[Light, ...]:
    out = []
    for i in range(count):
        position = tuple(rng.uniform(-5, 5, 3))
        if i % 2:
            out.append(Light("sphere", f"/S{i}", radiance=(3.0, 2.0, 1.0), position=position,
                             size=(float(rng.uniform(0.1, 0.5)), 0.0)))
        else:
            angle = rng.uniform(0, 2 * math.pi)
            c, s = math.cos(angle), math.sin(angle)
            axes = ((c, 0.0, -s), (0.0, 1.0, 0.0), (s, 0.0, c))
            out.append(Light("rect", f"/R{i}", radiance=(1.0, 1.0, 1.0), position=position, axes=axes,
                             size=(float(rng.uniform(0.2, 1.0)), float(rng.uniform(0.2, 1.0)))))
    return tuple(out)


def test_light_shape_culling_by_the_bvh_matches_testing_every_shape():
    """nearest_soa / occluded_soa with the Embree culler and the BVH (over CULLED_SHAPES shapes) give the same bits
    as the loop over every shape's culling sphere on every segment; shadow segments end on the shape they skip, as
    the renderer's do."""
    rng = np.random.default_rng(3)
    count = CULLED_SHAPES + 12
    lights = _lights(rng, count)
    light_set = lights_module.LightSet(lights)
    assert light_set._shape_bvh is not None and light_set._culler is not None
    every = lights_module.LightSet(lights)
    every._shape_bvh, every._culler = None, None  # every shape's culling sphere on every segment
    m = 20_000
    origins, directions = _random_rays(rng, m)
    for a, b in zip(light_set.nearest_soa(origins, directions), every.nearest_soa(origins, directions)):
        np.testing.assert_array_equal(a, b)
    assert (light_set.nearest_soa(origins, directions)[1] >= 0).sum() > 500  # the rays do hit lights
    # (3, J, M) segments from (3, M) origins, each ending on the shape it skips, as the renderer's shadow rays
    segments, lengths, skip = _shadow_segments(every, origins, rng, 3)
    blocked = light_set.occluded_soa(origins, segments, lengths, skip)
    np.testing.assert_array_equal(blocked, every.occluded_soa(origins, segments, lengths, skip))
    assert blocked.sum() > 500
    where = rng.random(blocked.shape) < 0.5
    np.testing.assert_array_equal(light_set.occluded_soa(origins, segments, lengths, skip, where=where)[where],
                                  blocked[where])
    # the first shape met decides most blocked segments before the BVH (occluded_soa's early test), by its own
    # exact test; and never one that is not blocked
    sel = np.arange(blocked.size)
    ends = skip.reshape(-1)
    first = light_set._first_shapes(origins, segments, np.broadcast_to(lengths, blocked.shape).reshape(-1), ends,
                                    sel)[1]
    test = np.flatnonzero((first >= 0) & (first != ends))
    early = light_set._pairs_block(origins, segments, np.broadcast_to(lengths, blocked.shape).reshape(-1),
                                   test, first[test])
    assert early.sum() > 0.5 * blocked.sum() and blocked.reshape(-1)[test[early]].all()


def _lamps(count: int, height: float, rng: np.random.Generator) -> tuple[str, list[tuple]]:
    """``count`` sphere lamps at one height, ≥ 2 m apart (none shadows another's light on the floor), every third
    a point light (treatAsPoint): usda and (x, z, radius, radiance, point) per lamp."""
    grid = [(x, z) for x in range(-4, 5, 2) for z in range(-4, 5, 2)]
    rng.shuffle(grid)
    text, lamps = "", []
    for i, (x, z) in enumerate(grid[:count]):
        x, z = x + rng.uniform(-0.3, 0.3), z + rng.uniform(-0.3, 0.3)
        radius, radiance, point = float(rng.uniform(0.15, 0.5)), float(rng.uniform(2, 20)), i % 3 == 2
        text += f"""
def SphereLight "Lamp{i}"
{{
    float inputs:radius = {radius}
    float inputs:intensity = {radiance}
    bool treatAsPoint = {int(point)}
    double3 xformOp:translate = ({x}, {height}, {z})
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""
        lamps.append((x, z, radius, radiance, point))
    return text, lamps


@pytest.mark.parametrize("count", [ENUMERATED_LIGHTS, 25])
def test_many_lamps_over_a_diffuse_plane_match_the_sum_of_their_closed_forms(tmp_path, count):
    """The floor seen through the probe's −Y face has radiance ρ/π · Σ_j E_j with, per lamp, E = π·L·(r/d)²·cos β
    (a sphere above the horizon) or I·cos β / d² with I = L·πr² (treatAsPoint). Enumerated (count = the
    threshold) and drawn from the BVH (above it; MIS against the draws' density for BSDF rays that hit a lamp)
    both converge to it: per texel within the noise, and over the face to 1.5 %."""
    assert count <= 25  # the lamp grid
    rng = np.random.default_rng(11)
    rho, height, n = 0.5, 2.5, 12
    lamps_text, lamps = _lamps(count, height, rng)
    text = header() + material("Ground", diffuse=(rho,) * 3, diffuse_only=True) + plane_mesh("Plane", 1e4, "/Ground")
    text += lamps_text + probe("P", (0.0, 1.0, 0.0))
    reading = read_scene(write(tmp_path / "lamps.usda", text))
    assert not reading.errors, reading.errors
    cubes, _ = capture_probes(reading.scene, n, samples=64, bounces=0)
    face = cube_texel_directions(n)[3]  # −Y: every texel sees the plane
    points = np.array([0.0, 1.0, 0.0]) + (1.0 / -face[..., 1])[..., None] * face
    irradiance = np.zeros(points.shape[:2])
    for x, z, radius, radiance, point in lamps:
        to_lamp = np.array([x, height, z]) - points
        d = np.linalg.norm(to_lamp, axis=-1)
        cos_beta = to_lamp[..., 1] / d
        if point:
            irradiance += radiance * math.pi * radius**2 * cos_beta / d**2
        else:
            irradiance += math.pi * radiance * (radius / d) ** 2 * cos_beta
    expected = rho * irradiance / math.pi
    seen = cubes[0][3][..., 0].astype(np.float64)
    np.testing.assert_allclose(seen.mean(), expected.mean(), rtol=0.015)
    np.testing.assert_allclose(seen, expected, rtol=0.15)


def test_drawn_lights_converge_to_the_enumerated_estimate_with_mis_on_a_glossy_floor(tmp_path, monkeypatch):
    """Large lamps (more than are enumerated) over a glossy metal-dielectric floor: BSDF rays find the lamps often, so their MIS weights
    against the draws' density K·P(light | point)·pdf decide the result. Drawn from the BVH and enumerated (the
    threshold raised), every face's mean agrees to 2 % at 256 rays per texel (measured: 1.1 % on the floor, ≤ 0.1 %
    elsewhere; 21 % off on the floor when the BSDF hits are weighted against the light's pdf alone)."""
    from bakery.capture import render

    rng = np.random.default_rng(5)
    text = header() + material("Ground", diffuse=(0.3,) * 3, inputs="float inputs:roughness = 0.25\n"
                                                                    "        float inputs:metallic = 0.5\n        ")
    text += plane_mesh("Plane", 1e4, "/Ground")
    for i in range(ENUMERATED_LIGHTS + 4):
        x, z = rng.uniform(-4, 4, 2)
        text += f"""
def SphereLight "Lamp{i}"
{{
    float inputs:radius = {rng.uniform(0.4, 0.9)}
    float inputs:intensity = {rng.uniform(1, 5)}
    double3 xformOp:translate = ({x}, {rng.uniform(1.8, 3.5)}, {z})
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""
    reading = read_scene(write(tmp_path / "glossy.usda", text + probe("P", (0.0, 1.0, 0.0))))
    assert not reading.errors, reading.errors
    drawn, _ = capture_probes(reading.scene, 12, samples=256, bounces=1)
    monkeypatch.setattr(render, "ENUMERATED_LIGHTS", 100)
    enumerated, _ = capture_probes(reading.scene, 12, samples=256, bounces=1)
    np.testing.assert_allclose(drawn[0].mean(axis=(1, 2)), enumerated[0].mean(axis=(1, 2)), rtol=0.02)


def test_drawn_lights_keep_every_light_s_linking_shadows_and_multipliers(tmp_path, monkeypatch):
    """The per-light UsdLux behaviour is a row of the strategy tables, looked up per point for drawn lights:
    lamps without shadows, with a shadow colour, a shadow distance, diffuse/specular multipliers, linked to the
    floor only or shadow-linked to no mesh, around a box on a glossy floor. Drawn and enumerated agree on every
    face's mean to 3 % at 256 rays per texel."""
    import dataclasses

    from bakery.capture import render
    from usd_scenes import box_mesh

    text = header() + material("Ground", diffuse=(0.4,) * 3, inputs="float inputs:roughness = 0.35\n        ")
    text += plane_mesh("Plane", 1e4, "/Ground") + material("Grey", diffuse=(0.5,) * 3) + box_mesh("Box", 1.0, "/Grey")
    reading = read_scene(write(tmp_path / "linked.usda", text + probe("P", (1.2, 0.8, 0.3))))
    assert not reading.errors, reading.errors
    scene = reading.scene
    floor = tuple(i for i, m in enumerate(scene.meshes) if "Plane" in m.name)
    rng = np.random.default_rng(2)
    lamps = []
    for i in range(ENUMERATED_LIGHTS + 8):
        position = (float(rng.uniform(-3, 3)), float(rng.uniform(1.5, 3)), float(rng.uniform(-3, 3)))
        lamp = Light("sphere", f"/Lamp{i}", radiance=tuple(rng.uniform(1, 4, 3)), position=position,
                     size=(float(rng.uniform(0.1, 0.4)), 0.0))
        kind = i % 6
        if kind == 0:
            lamp = dataclasses.replace(lamp, shadow=False)
        elif kind == 1:
            lamp = dataclasses.replace(lamp, shadow_color=(0.4, 0.2, 0.0))
        elif kind == 2:
            lamp = dataclasses.replace(lamp, diffuse=0.5, specular=2.0)
        elif kind == 3:
            lamp = dataclasses.replace(lamp, links=floor)
        elif kind == 4:
            lamp = dataclasses.replace(lamp, shadow_links=())
        elif kind == 5:
            lamp = dataclasses.replace(lamp, shadow_distance=0.6, shadow_falloff=0.3)
        lamps.append(lamp)
    scene = dataclasses.replace(scene, lights=tuple(lamps))
    drawn, _ = capture_probes(scene, 12, samples=256, bounces=1)
    monkeypatch.setattr(render, "ENUMERATED_LIGHTS", 100)
    enumerated, _ = capture_probes(scene, 12, samples=256, bounces=1)
    np.testing.assert_allclose(drawn[0].mean(axis=(1, 2)), enumerated[0].mean(axis=(1, 2)), rtol=0.03)


def test_spot_lights_are_drawn_only_where_their_cone_reaches_and_converge(tmp_path, monkeypatch):
    """ShapingAPI cones bound the BVH's emission cones: under a spot only that spot is drawn (a point outside
    every cone draws none: nothing can light it), and drawn and enumerated spots over a glossy floor agree on every
    face's mean to 3 % at 256 rays per texel (measured ≤ 1.1 %)."""
    import dataclasses

    from bakery.capture import render
    from bakery.capture.lights import light_model

    down = ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0))  # local −Z = world −Y
    rng = np.random.default_rng(8)
    spots = []
    for i in range(ENUMERATED_LIGHTS + 8):
        position = (float(rng.uniform(-4, 4)), float(rng.uniform(2.5, 3.5)), float(rng.uniform(-4, 4)))
        shaping = (float(rng.uniform(15, 40)), 0.2, 0.0, 1.0, 1.0, 1.0)
        if i % 4 == 0:
            spots.append(Light("rect", f"/Panel{i}", radiance=(2.0, 2.0, 2.0), position=position, axes=down,
                               size=(0.4, 0.4), shaping=shaping))
        else:
            spots.append(Light("sphere", f"/Spot{i}", radiance=(6.0, 5.0, 4.0), position=position, axes=down,
                               size=(0.1, 0.0), shaping=shaping))
    tree = LightBVH([light_model(s).tree_bound() for s in spots])
    under = np.array([[s.position[0], 0.0, s.position[2]] for s in spots]).T
    pmf = tree.pmf(np.repeat(under, len(spots), axis=1), np.tile(np.arange(len(spots)), len(spots)))
    pmf = pmf.reshape(len(spots), len(spots))
    for k, s in enumerate(spots):  # the spots whose cone (plus the light's own size) misses the point get 0
        for j, other in enumerate(spots):
            offset = np.hypot(other.position[0] - s.position[0], other.position[2] - s.position[2])
            off_axis = math.degrees(math.atan2(offset, other.position[1]))
            if off_axis > other.shaping[0] + 10.0:
                assert pmf[k, j] == 0.0, (k, j)
        assert pmf[k, k] > 0
    light, probability = tree.sample(np.array([[0.0, 5.0, 0.0]] * 8).T, np.linspace(0.05, 0.95, 8))
    assert np.all(light == -1) and np.all(probability == 0)  # above every downward spot
    text = header() + material("Ground", diffuse=(0.4,) * 3, inputs="float inputs:roughness = 0.3\n        ")
    reading = read_scene(write(tmp_path / "spots.usda", text + plane_mesh("Plane", 1e4, "/Ground")
                               + probe("P", (0.3, 1.0, -0.2))))
    scene = dataclasses.replace(reading.scene, lights=tuple(spots))
    drawn, _ = capture_probes(scene, 12, samples=256, bounces=1)
    monkeypatch.setattr(render, "ENUMERATED_LIGHTS", 100)
    enumerated, _ = capture_probes(scene, 12, samples=256, bounces=1)
    np.testing.assert_allclose(drawn[0].mean(axis=(1, 2)), enumerated[0].mean(axis=(1, 2)), rtol=0.03)


def test_a_scene_bake_records_and_inspect_prints_how_its_lights_were_sampled(tmp_path):
    """examples/plaza (272 lights): the store's capture_light_sampling says they were drawn, 4 per vertex, and
    `bakery inspect` says so in one line."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    import bakery

    plaza = Path(__file__).resolve().parents[2] / "examples" / "plaza" / "plaza.usda"
    bakery.bake(plaza, tmp_path / "plaza.h5", face_size=8, encodings=["sh3"], samples=2)
    sampling = json.loads(bakery.open_store(tmp_path / "plaza.h5").attributes["capture_light_sampling"])
    assert sampling == {"lights": 272, "non_distant": 272, "drawn": True, "draws_per_vertex": 4,
                        "enumerated_up_to": ENUMERATED_LIGHTS, "next_event_samples_per_vertex": 4,
                        "selection": "grid"}
    shown = subprocess.run([sys.executable, "-m", "bakery.cli", "inspect", str(tmp_path / "plaza.h5")],
                           capture_output=True, text=True, check=True).stdout
    assert "lights: 272; 4 of the 272 non-distant ones drawn per path vertex from the light grid" in shown
