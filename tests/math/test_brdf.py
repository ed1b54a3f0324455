"""GGX / Smith / Schlick terms and samplers, against closed forms and independent quadratures (χ² for samplers)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import integrate, stats

from bakery.brdf import (
    fresnel_schlick,
    ggx_distribution,
    ggx_ndf_pdf,
    reflection_pdf_from_half_pdf,
    sample_ggx_ndf,
    sample_ggx_vndf,
    smith_g1,
    smith_visibility_correlated,
    to_local,
    to_world,
    vndf_pdf,
)
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.sampling import orthonormal_frame

ALPHAS = [0.05, 0.2, 0.5, 1.0]


def _cube_quadrature(n=96):
    return cube_texel_directions(n).reshape(-1, 3), cube_texel_solid_angles(n).reshape(-1)


def _view(theta):
    return np.array([np.sin(theta), 0.0, np.cos(theta)])


@pytest.mark.parametrize("alpha", ALPHAS)
def test_ndf_pdf_integrates_to_one(alpha):
    # ∫ D(h)(n·h) dω = 2π ∫_0^1 D(μ) μ dμ (independent 1D adaptive quadrature).
    value, _ = integrate.quad(lambda mu: 2 * np.pi * ggx_distribution(mu, alpha) * mu, 0, 1, points=[1 - alpha**2],
                              limit=200, epsabs=1e-12)
    assert value == pytest.approx(1.0, abs=1e-8)


@pytest.mark.parametrize("alpha", [0.2, 0.5, 1.0])
@pytest.mark.parametrize("theta", [0.0, 0.7, 1.3])
def test_vndf_and_reflection_pdfs_integrate_to_one(alpha, theta):
    d, omega = _cube_quadrature()
    v = _view(theta)
    pdf_h = vndf_pdf(np.broadcast_to(v, d.shape), d, alpha)
    assert np.sum(pdf_h * omega) == pytest.approx(1.0, rel=2e-3)
    # l = reflect(v, h) is a change of variables: ∫ pdf_l dω_l = 1 over the whole sphere.
    h = d + v
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    pdf_l = reflection_pdf_from_half_pdf(vndf_pdf(np.broadcast_to(v, d.shape), h, alpha), v, h)
    assert np.sum(pdf_l * omega) == pytest.approx(1.0, rel=5e-3)


def _chi2_pvalue(samples, pdf, alpha, bins=16, sub=8):
    """χ² of samples h (N, 3) (local frame) against a pdf per solid angle. Bins: φ uniform, and θ uniform in the
    GGX-CDF variable x = tan²θ / (α² + tan²θ) so that peaked lobes are resolved; expected counts by a midpoint
    quadrature with sub-intervals in x and dω = |Δμ| Δφ; bins with expectation < 5 are pooled."""
    def mu_of(x):
        return 1.0 / np.sqrt(1.0 + alpha**2 * x / np.maximum(1.0 - x, 1e-300))

    mu = np.clip(samples[:, 2], 0, 1)
    tan2 = (1 - mu**2) / np.maximum(mu**2, 1e-300)
    x = tan2 / (alpha**2 + tan2)
    phi = np.mod(np.arctan2(samples[:, 1], samples[:, 0]), 2 * np.pi)
    observed, _, _ = np.histogram2d(x, phi, bins=bins, range=[[0, 1], [0, 2 * np.pi]])
    xe = np.linspace(0, 1, bins * sub + 1)
    mue = mu_of(xe)
    mum = 0.5 * (mue[:-1] + mue[1:])
    dmu = np.abs(np.diff(mue))
    p = (np.arange(bins * sub) + 0.5) / (bins * sub) * 2 * np.pi
    mm, pp = np.meshgrid(mum, p, indexing="ij")
    s = np.sqrt(1 - mm**2)
    dirs = np.stack([s * np.cos(pp), s * np.sin(pp), mm], -1)
    dens = pdf(dirs) * dmu[:, None] * (2 * np.pi / (bins * sub))
    expected = dens.reshape(bins, sub, bins, sub).sum(axis=(1, 3)) * len(samples)
    assert expected.sum() == pytest.approx(len(samples), rel=2e-2)  # the pdf integrates to one
    expected *= observed.sum() / expected.sum()
    o, e = observed.ravel(), expected.ravel()
    small = e < 5
    if small.any():
        o = np.append(o[~small], o[small].sum())
        e = np.append(e[~small], e[small].sum())
    return stats.chisquare(o, e).pvalue


@pytest.mark.parametrize("alpha", [0.1, 0.4, 0.9])
@pytest.mark.parametrize("theta", [0.2, 1.0, 1.45])
def test_vndf_samples_pass_chi_square(alpha, theta):
    rng = np.random.default_rng(7)
    v = _view(theta)
    u = rng.random((2, 100_000))
    h = sample_ggx_vndf(np.broadcast_to(v, (u.shape[1], 3)), u[0], u[1], alpha)
    assert _chi2_pvalue(h, lambda d: vndf_pdf(np.broadcast_to(v, d.shape), d, alpha), alpha) > 1e-3


@pytest.mark.parametrize("alpha", [0.1, 0.6])
def test_ndf_samples_pass_chi_square(alpha):
    rng = np.random.default_rng(3)
    u = rng.random((2, 100_000))
    h = sample_ggx_ndf(u[0], u[1], alpha)
    assert _chi2_pvalue(h, lambda d: ggx_ndf_pdf(d, alpha), alpha) > 1e-3


@given(
    st.floats(0.0, 1.55), st.floats(0.02, 1.0), st.floats(0.0, 0.999), st.floats(0.0, 0.999),
)
def test_vndf_samples_are_visible_unit_normals(theta, alpha, u1, u2):
    v = _view(theta)
    h = sample_ggx_vndf(v, np.array(u1), np.array(u2), alpha)
    assert np.linalg.norm(h) == pytest.approx(1.0, abs=1e-9)
    assert h[2] > 0 and h @ v >= -1e-9


@pytest.mark.parametrize("alpha", [0.1, 0.5, 1.0])
@pytest.mark.parametrize("theta", [0.0, 0.8, 1.4])
def test_directional_albedo_at_most_one(alpha, theta):
    d, omega = _cube_quadrature()
    v = _view(theta)
    nl = d[:, 2]
    h = d + v
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    f = ggx_distribution(h[:, 2], alpha) * smith_visibility_correlated(v[2], nl, alpha)
    albedo = np.sum(f * np.maximum(nl, 0) * omega)
    assert 0 < albedo <= 1.0 + 2e-3


def test_visibility_closed_form_matches_height_correlated_g2():
    # V = G2 / (4 (n·v)(n·l)) with G2 = 1/(1 + Λ(v) + Λ(l)), Λ = (√(1 + α² tan²θ) − 1)/2 ([Hei14] Eq. 99).
    rng = np.random.default_rng(0)
    nv, nl, a = rng.uniform(0.01, 1, 500), rng.uniform(0.01, 1, 500), rng.uniform(0.01, 1, 500)
    lam = lambda c: 0.5 * (np.sqrt(1 + a**2 * (1 - c**2) / c**2) - 1)  # noqa: E731
    g2 = 1 / (1 + lam(nv) + lam(nl))
    np.testing.assert_allclose(smith_visibility_correlated(nv, nl, a), g2 / (4 * nv * nl), rtol=1e-10)
    np.testing.assert_allclose(smith_visibility_correlated(nv, nl, a), smith_visibility_correlated(nl, nv, a))
    assert np.all(smith_g1(nv, a) <= 1) and np.all(smith_visibility_correlated(-nv, nl, a) == 0)


def test_schlick_endpoints_and_mirror_limit():
    assert fresnel_schlick(0.04, 1.0) == pytest.approx(0.04)
    assert fresnel_schlick(0.04, 0.0) == pytest.approx(1.0)
    # D(n·h = 1) = 1/(π α²).
    assert ggx_distribution(1.0, 0.3) == pytest.approx(1 / (np.pi * 0.09))
    with pytest.raises(ValueError):
        ggx_distribution(0.5, 0.0)


@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))
def test_frame_round_trip(x, y, z):
    n = np.array([x, y, z])
    if np.linalg.norm(n) < 1e-3:
        return
    n /= np.linalg.norm(n)
    t, b = orthonormal_frame(n)
    np.testing.assert_allclose([t @ t, b @ b, t @ b, t @ n, b @ n], [1, 1, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(np.cross(t, b), n, atol=1e-9)
    w = np.array([0.3, -0.5, 0.81])
    np.testing.assert_allclose(to_local(to_world(w, n), n), w, atol=1e-9)
