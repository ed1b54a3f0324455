"""The renderer's structure-of-arrays float32 hot path (issue 14) against the reference formulas and layouts.

The BSDF written out for (3, M) arrays equals the terms of :mod:`bakery.brdf.ggx` / :mod:`bakery.brdf.sampling`;
lights, textures and camera directions computed in float32 (3, M) agree with the float64 (M, 3) paths; the
bounding-sphere cull of light-shape occlusion never changes an answer."""

from __future__ import annotations

import numpy as np
import pytest

from bakery.brdf.ggx import ggx_distribution, smith_visibility_correlated
from bakery.brdf.sampling import sample_ggx_vndf, vndf_pdf
from bakery.capture.bsdf import MIN_ALPHA, Bsdf
from bakery.capture.lights import LightSet, light_model
from bakery.capture.scene import Light
from bakery.capture.surfaces import MipTexture
from bakery.capture.vec import power
from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.sphere.sampling import orthonormal_frame


def _unit(rng: np.random.Generator, m: int) -> np.ndarray:
    v = rng.normal(size=(m, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _inputs(m: int = 4000, seed: int = 0, min_roughness: float = 0.05):
    rng = np.random.default_rng(seed)
    n, wo, wi = _unit(rng, m), _unit(rng, m), _unit(rng, m)
    wo = np.where((np.sum(n * wo, axis=1) < 0)[:, None], -wo, wo)
    albedo = rng.random((m, 3))
    f0 = np.where(rng.random((m, 1)) < 0.5, rng.random((m, 3)), 0.04)
    f0[:50] = 0.0  # purely diffuse
    rough = rng.uniform(min_roughness, 1.0, m)
    return rng, n, wo, wi, albedo, f0, rough


@pytest.mark.parametrize("min_roughness", [0.0, 0.3])  # sharp lobes (the |n × h|² form of D) or not
def test_bsdf_evaluate_is_the_ggx_reference(min_roughness):
    _rng, n, wo, wi, albedo, f0, rough = _inputs(min_roughness=min_roughness)
    bsdf = Bsdf(n.T.copy(), wo.T.copy(), albedo.T.copy(), f0.T.copy(), rough)
    assert (bsdf.sharp.size > 0) == (min_roughness == 0.0)
    value, pdf = bsdf.evaluate(wi.T.copy())
    # reference, straight from bakery.brdf (AoS float64)
    alpha = np.maximum(rough**2, MIN_ALPHA)
    nl = np.sum(n * wi, axis=1)
    nv = np.clip(np.sum(n * wo, axis=1), 1e-6, 1.0)
    h = wo + wi
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    vh = np.clip(np.sum(wo * h, axis=1), 0.0, 1.0)
    f90 = np.minimum(1.0, 50.0 * (f0 @ LUMINANCE_WEIGHTS))[:, None]
    fresnel = f0 + (f90 - f0) * ((1.0 - vh) ** 5)[:, None]
    nlc = np.maximum(nl, 0.0)
    d = ggx_distribution(np.sum(n * h, axis=1), alpha)
    vis = smith_visibility_correlated(nv, nlc, alpha)
    spec = (f90[:, 0] > 0)[:, None]
    expected = albedo / np.pi * (1 - fresnel) * nlc[:, None] + np.where(spec, fresnel * (d * vis * nlc)[:, None], 0)
    expected = np.where((nl > 0)[:, None], expected, 0.0)
    np.testing.assert_allclose(value.T, expected, rtol=1e-9, atol=1e-12)
    # the specular pdf: VNDF pdf of h over 4 v·h, in the local frame
    t, b = orthonormal_frame(n)
    local = lambda w: np.stack([np.sum(w * t, 1), np.sum(w * b, 1), np.sum(w * n, 1)], axis=-1)
    pdf_s = vndf_pdf(local(wo), local(h), alpha) / np.maximum(4.0 * vh, 1e-12)
    p_spec = bsdf.p_spec
    expected_pdf = np.where(nl > 0, (1 - p_spec) * nlc / np.pi + np.where(spec[:, 0], p_spec * pdf_s, 0.0), 0.0)
    np.testing.assert_allclose(pdf, expected_pdf, rtol=1e-6, atol=1e-12)


def test_bsdf_many_directions_per_point_and_float32():
    _rng, n, wo, wi, albedo, f0, rough = _inputs(seed=1)
    soa = [a.T.astype(np.float32).copy() for a in (n, wo, albedo, f0)]
    b32 = Bsdf(*soa, rough.astype(np.float32))
    b64 = Bsdf(n.T.copy(), wo.T.copy(), albedo.T.copy(), f0.T.copy(), rough)
    stacked = np.stack([wi.T, -wi.T, wo.T], axis=1)  # (3, J=3, M)
    value, pdf = b32.evaluate(stacked.astype(np.float32))
    assert value.dtype == np.float32 and value.shape == (3, 3, n.shape[0]) and pdf.shape == (3, n.shape[0])
    for j in range(3):
        v64, p64 = b64.evaluate(np.ascontiguousarray(stacked[:, j]))
        np.testing.assert_allclose(value[:, j], v64, rtol=2e-3, atol=1e-6)
        np.testing.assert_allclose(pdf[j], p64, rtol=2e-3, atol=1e-6)


def test_bsdf_sample_matches_the_reference_vndf_and_its_own_pdf():
    rng, n, wo, _wi, albedo, f0, rough = _inputs(seed=2)
    bsdf = Bsdf(n.T.copy(), wo.T.copy(), albedo.T.copy(), f0.T.copy(), rough)
    u = rng.random((3, n.shape[0]))
    wi, weight, pdf = bsdf.sample(u[0], u[1], u[2])
    value, pdf_again = bsdf.evaluate(wi)
    ok = pdf > 0
    np.testing.assert_allclose(pdf, pdf_again)
    np.testing.assert_allclose(weight[:, ok], value[:, ok] / pdf[ok], rtol=1e-12)
    spec = u[2] < bsdf.p_spec
    t, b = orthonormal_frame(n)
    v_local = np.stack([np.sum(wo * t, 1), np.sum(wo * b, 1), np.sum(wo * n, 1)], axis=-1)
    alpha = np.maximum(rough**2, MIN_ALPHA)
    h_local = sample_ggx_vndf(v_local[spec], u[0][spec], u[1][spec], alpha[spec])
    h = h_local[:, :1] * t[spec] + h_local[:, 1:2] * b[spec] + h_local[:, 2:] * n[spec]
    reflected = 2 * np.sum(wo[spec] * h, 1)[:, None] * h - wo[spec]
    np.testing.assert_allclose(wi.T[spec], reflected, atol=1e-12)


@pytest.mark.parametrize("kind", ["sphere", "rect", "disk", "cylinder"])
def test_light_float32_soa_agrees_with_float64(kind):
    light = Light(kind, f"/{kind}", radiance=(1.0, 2.0, 3.0), position=(0.3, 2.0, -0.2),
                  axes=((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)), size=(0.4, 0.8),
                  shaping=(60.0, 0.3, 2.0, 0.5, 0.5, 1.0))
    model = light_model(light)
    rng = np.random.default_rng(4)
    points = rng.uniform(-1, 1, (2000, 3)) * np.array([1.0, 0.2, 1.0])
    u = rng.random((2000, 2))
    s = model.sample(points, u)
    wi, dist, radiance, pdf = model.sample_soa(points.T.astype(np.float32), *u.T.astype(np.float32))
    assert wi.dtype == dist.dtype == radiance.dtype == pdf.dtype == np.float32
    ok = (s.pdf > 0) & (pdf > 0)
    assert ok.mean() > 0.3 and np.mean((s.pdf > 0) != (pdf > 0)) < 0.01
    np.testing.assert_allclose(wi.T[ok], s.wi[ok], atol=1e-5)
    np.testing.assert_allclose(dist[ok], s.distance[ok], rtol=1e-4)
    # the estimators weigh a sample by 1/pdf: at a grazing sample (cos θ_l ~ 1e-5) float32 loses the pdf's digits
    # to cancellation (one of 2 000 here, 1.3 %), and its weight is 1e-5 of the typical one
    weight = 1.0 / s.pdf[ok]
    np.testing.assert_allclose(1.0 / pdf[ok], weight, rtol=1e-3, atol=1e-5 * np.median(weight))
    np.testing.assert_allclose(radiance.T[ok], s.radiance[ok], rtol=1e-3, atol=1e-5)


def test_light_shape_occlusion_cull_never_changes_the_answer():
    lights = tuple(
        Light(kind, f"/{kind}{i}", radiance=(1.0, 1.0, 1.0), position=tuple(p),
              axes=((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)), size=(0.5, 0.7))
        for i, (kind, p) in enumerate(zip(("sphere", "rect", "disk", "cylinder"),
                                          np.random.default_rng(5).uniform(-1, 1, (4, 3)))))
    ls = LightSet(lights)
    rng = np.random.default_rng(6)
    m = 20000
    origins = rng.uniform(-2, 2, (3, m))
    directions = _unit(rng, m).T.copy()
    distances = rng.uniform(0.1, 4.0, m)
    culled = ls.occluded_soa(origins, directions, distances)
    brute = np.zeros(m, dtype=bool)
    for model in ls.surfaces:
        brute |= model.occludes_soa(origins, directions, distances)
    assert brute.mean() > 0.05
    np.testing.assert_array_equal(culled, brute)
    # J segments per origin, with a skipped light per row
    fan = np.stack([directions, -directions], axis=1)
    skip = np.array([[0], [-1]])
    got = ls.occluded_soa(origins, fan, np.stack([distances, distances]), skip)
    ref0 = np.zeros(m, dtype=bool)
    for k, model in enumerate(ls.surfaces):
        if k != 0:
            ref0 |= model.occludes_soa(origins, directions, distances)
    np.testing.assert_array_equal(got[0], ref0)
    np.testing.assert_array_equal(got[1], ls.occluded_soa(origins, -directions, distances))
    t, which, _radiance = ls.nearest_soa(origins, directions)
    best = np.full(m, 1e30)
    for model in ls.surfaces:
        best = np.minimum(best, model.intersect_soa(origins, directions)[0])
    np.testing.assert_array_equal(t, best)
    assert (which >= 0).sum() == (best < 1e30).sum()


@pytest.mark.parametrize("wrap", [("repeat", "repeat"), ("mirror", "clamp"), ("black", "repeat")])
def test_texture_soa_lookup_equals_the_reference(wrap):
    rng = np.random.default_rng(7)
    texture = MipTexture(rng.random((13, 7, 4)))
    st = rng.uniform(-2, 3, (3000, 2))
    lod = rng.uniform(-1, 6, 3000)
    reference = texture.lookup(st, lod, wrap)
    soa = texture.lookup_soa(st[:, 0].astype(np.float32), st[:, 1].astype(np.float32), lod.astype(np.float32), wrap,
                             (0, 1, 2, 3))
    np.testing.assert_allclose(np.stack(soa, axis=1), reference, atol=1e-5)


def test_jittered_directions_are_the_cube_directions():
    from bakery.capture.render import _jittered_texel_directions
    from bakery.sphere.cubemap import direction_to_cube_texel

    n, samples = 8, 3
    d = _jittered_texel_directions(n, samples, np.random.default_rng(8))
    assert d.shape == (3, samples, 6, n, n) and d.dtype == np.float32
    face, row, col = direction_to_cube_texel(np.moveaxis(d, 0, -1).reshape(-1, 3).astype(np.float64), n)
    grid = np.stack(np.meshgrid(np.arange(6), np.arange(n), np.arange(n), indexing="ij"), axis=-1).reshape(-1, 3)
    np.testing.assert_array_equal(np.stack([face, row, col], axis=-1).reshape(samples, -1, 3),
                                  np.broadcast_to(grid, (samples, 6 * n * n, 3)))


def test_power_heuristic_edges():
    a = np.array([1.0, 2.0, np.inf, 0.0, 0.0, 1e30], dtype=np.float32)
    b = np.array([1.0, 0.0, 3.0, 2.0, 0.0, 1e30], dtype=np.float32)
    np.testing.assert_allclose(power(a, b), [0.5, 1.0, 1.0, 0.0, 1.0, 0.5])
    assert power(a, b).dtype == np.float32


@pytest.mark.parametrize("weights", ["dome", "peaky", "one texel", "uniform"])
def test_dome_texel_choice_is_the_cdf_binary_search(weights):
    """The guide-table sampler returns exactly the index of a binary search of the CDF (so the samples, and the
    captures, are those of the plain inverse-CDF method), also where many tiny texels share a guide cell."""
    from bakery.capture.dome import _Distribution

    rng = np.random.default_rng(3)
    w = {"dome": rng.random(5000) ** 8, "peaky": np.r_[1e7, np.ones(20000), 1e5, np.ones(3)],
         "one texel": np.r_[np.zeros(6), 2.0, np.zeros(9)], "uniform": np.ones(1)}[weights]
    dist = _Distribution(w)
    u = np.r_[rng.random(20000), 0.0, np.nextafter(1.0, 0.0), dist.cdf[dist.cdf < 1]]  # u ∈ [0, 1), CDF steps too
    expected = np.minimum(np.searchsorted(dist.cdf, u, side="right"), dist.cdf.size - 1)
    np.testing.assert_array_equal(dist.sample(u), expected)
