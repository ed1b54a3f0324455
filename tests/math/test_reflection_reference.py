"""Reference integrator and shared tables against independent quadratures (white furnace, DFG)."""

import numpy as np
import pytest
from scipy.special import roots_legendre

from bakery.reflection.reference import fdv_cosine_weights, integrate_reflection, reflected_radiance
from bakery.reflection.tables import compute_dfg_tables, integrate_dfg, lookup_table
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.grid import SphericalSamples


def independent_albedo(n_dot_v, alpha, nodes=400):
    """(A + B, B) by a Gauss–Legendre product rule over the light direction l in (cos θ_l, φ_l), with D written in
    its tan form D = 1/(π α² cos⁴θ_h (1 + tan²θ_h/α²)²) and G2 = 1/(1 + Λ(v) + Λ(l)) — independent of the code."""
    x, w = roots_legendre(nodes)
    mu = 0.5 * (x + 1)  # cos θ_l ∈ (0, 1)
    wmu = 0.5 * w
    phi = np.pi * (x + 1)  # φ ∈ (0, 2π)
    wphi = np.pi * w
    M, P = np.meshgrid(mu, phi, indexing="ij")
    W = wmu[:, None] * wphi[None, :]
    s = np.sqrt(1 - M**2)
    l = np.stack([s * np.cos(P), s * np.sin(P), M], -1)  # noqa: E741
    v = np.array([np.sqrt(1 - n_dot_v**2), 0, n_dot_v])
    h = l + v
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ch = h[..., 2]
    tan2 = (1 - ch**2) / ch**2
    D = 1 / (np.pi * alpha**2 * ch**4 * (1 + tan2 / alpha**2) ** 2)
    lam = lambda c: 0.5 * (-1 + np.sqrt(1 + alpha**2 * (1 - c**2) / c**2))  # noqa: E731
    G2 = 1 / (1 + lam(n_dot_v) + lam(M))
    f = D * G2 / (4 * n_dot_v * M)
    fc = (1 - np.sum(v * h, axis=-1)) ** 5
    return np.sum(W * f * M), np.sum(W * f * M * fc)


def _constant_samples(n, c):
    d = cube_texel_directions(n).reshape(-1, 3)
    return SphericalSamples(d, cube_texel_solid_angles(n).reshape(-1), np.full((d.shape[0], 3), c))


@pytest.mark.parametrize("n_dot_v,alpha", [(1.0, 0.3), (0.7, 0.5), (0.3, 0.8), (0.15, 1.0), (0.9, 0.25)])
def test_white_furnace_equals_independent_albedo(n_dot_v, alpha):
    c = 2.5
    samples = _constant_samples(96, c)
    rng = np.random.default_rng(1)
    normal = rng.normal(size=(4, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # a view at angle acos(n·v) from each random normal
    t = np.cross(normal, [0.3, 0.5, 0.8])
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    view = n_dot_v * normal + np.sqrt(1 - n_dot_v**2) * t
    albedo, tail = independent_albedo(n_dot_v, alpha)
    for dtype in (np.float32, np.float64):
        e0, e1 = integrate_reflection(samples, view, normal, np.full(4, alpha), dtype=dtype)
        np.testing.assert_allclose(e0, c * albedo, rtol=3e-3)
        np.testing.assert_allclose(e1, c * tail, rtol=1e-2, atol=1e-4 * c)
    # chrome (F0 = 1) sees E0, F0 = 0 sees E1
    np.testing.assert_allclose(reflected_radiance(e0, e1, np.ones(4)), e0)
    np.testing.assert_allclose(reflected_radiance(e0, e1, np.zeros(4)), e1)


def test_float32_tiles_equal_float64_weights():
    rng = np.random.default_rng(2)
    d = rng.normal(size=(5000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    samples = SphericalSamples(d, np.full(5000, 4 * np.pi / 5000), rng.lognormal(size=(5000, 3)))
    n = rng.normal(size=(40, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = n + rng.normal(size=(40, 3)) * 0.5
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    a = rng.uniform(0.2, 1.0, 40)
    e0, e1 = integrate_reflection(samples, v, n, a, dtype=np.float32)
    w0, w1 = fdv_cosine_weights(d, samples.solid_angles, v, n, a, tail=True)
    np.testing.assert_allclose(e0, w0 @ samples.radiance, rtol=2e-4)
    np.testing.assert_allclose(e1, w1 @ samples.radiance, rtol=2e-3, atol=1e-7)


@pytest.fixture(scope="module")
def tables():
    return compute_dfg_tables(16, 64)


def test_dfg_table_matches_direct_integration(tables):
    centres = (np.arange(16) + 0.5) / 16
    for i in (2, 7, 15):  # α rows
        for j in (0, 5, 15):  # n·v columns
            total, tail = independent_albedo(centres[j], centres[i], nodes=1200)
            a, b = tables.dfg[i, j]
            assert a + b == pytest.approx(total, abs=2e-3)
            assert b == pytest.approx(tail, abs=1e-3)
            assert tables.fresnel_tail[i, j] == pytest.approx(tail / total, abs=2e-3)


def test_paper_tail_mode_is_the_literal_integral():
    ratio, paper = compute_dfg_tables(8, 32, "ratio"), compute_dfg_tables(8, 32, "paper")
    np.testing.assert_allclose(paper.fresnel_tail, ratio.dfg[..., 1], rtol=1e-6)
    np.testing.assert_allclose(ratio.fresnel_tail * ratio.albedo, ratio.dfg[..., 1], rtol=1e-5, atol=1e-9)
    assert np.all(ratio.albedo <= 1.0 + 1e-3) and np.all(ratio.dfg >= 0)


def test_lookup_is_exact_at_texel_centres_and_bilinear_between():
    n_a, n_v = 8, 12
    ya, xv = np.meshgrid((np.arange(n_a) + 0.5) / n_a, (np.arange(n_v) + 0.5) / n_v, indexing="ij")
    table = 3.0 * xv - 2.0 * ya + 0.5  # bilinear in (n·v, α): reproduced exactly inside the centre range
    rng = np.random.default_rng(0)
    nv = rng.uniform(0.5 / n_v, 1 - 0.5 / n_v, 100)
    a = rng.uniform(0.5 / n_a, 1 - 0.5 / n_a, 100)
    np.testing.assert_allclose(lookup_table(table, nv, a), 3 * nv - 2 * a + 0.5, atol=1e-12)
    np.testing.assert_allclose(lookup_table(table, xv, ya), table, atol=1e-12)
    stacked = np.stack([table, -table], -1)
    np.testing.assert_allclose(lookup_table(stacked, nv, a)[:, 1], -(3 * nv - 2 * a + 0.5), atol=1e-12)


def test_integrate_dfg_broadcasts():
    out = integrate_dfg(np.array([[0.2], [0.9]]), np.array([0.3, 0.6, 1.0]), 32)
    assert out.shape == (2, 3, 2) and np.all(np.isfinite(out))
