"""Samplers of the capture: dome importance sampling (rest and sun) is consistent with its pdf and lookup
(pbrt-style triples), the sun split is exact, and bilinear splats keep flux and centroid."""

from __future__ import annotations

import numpy as np

from bakery.capture.dome import DomeSampler
from bakery.capture.lights import sample_cone
from bakery.capture.scene import Dome


def _dome(layout="equirect"):
    rng = np.random.default_rng(3)
    pixels = rng.uniform(0.1, 1.0, size=(16, 32, 3)).astype(np.float32)
    pixels[3, 7] = 500.0
    angle = 0.7
    rot = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    return Dome("/d", scale=(2.0, 2.0, 2.0), rotation=tuple(map(tuple, rot)), pixels=pixels, layout=layout)


def test_dome_pdf_integrates_to_one_and_matches_sampled_pdf():
    sampler = DomeSampler(_dome())
    rng = np.random.default_rng(0)
    # ∫ pdf dω over the sphere on a fine latitude-longitude midpoint grid with exact cell solid angles
    h, w = 512, 1024
    lat_edges = np.pi * (0.5 - np.arange(h + 1) / h)
    lat = 0.5 * (lat_edges[:-1] + lat_edges[1:])
    lon = np.pi * (1 - 2 * (np.arange(w) + 0.5) / w)
    cell = (2 * np.pi / w) * (np.sin(lat_edges[:-1]) - np.sin(lat_edges[1:]))
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    v = np.stack([np.cos(la) * np.sin(lo), np.sin(la), np.cos(la) * np.cos(lo)], axis=-1).reshape(-1, 3)
    assert sampler.has_sun and sampler.sun_index.size == 1  # the 500 texel is the sun
    for pdf_of, sample in ((sampler.rest_pdf, sampler.sample_rest), (sampler.sun_pdf, sampler.sample_sun)):
        total = (pdf_of(v).reshape(h, w) * cell[:, None]).sum()
        assert abs(total - 1.0) < 2e-3
        directions, _radiance, pdf = sample(rng.random((20_000, 3)))
        np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose(pdf_of(directions), pdf, rtol=1e-6)
    # rest + sun = the dome, texel for texel
    np.testing.assert_allclose(sampler.rest_radiance(v) + sampler.sun_radiance(v), sampler.radiance(v), rtol=1e-12)


def test_dome_importance_estimate_of_flux_is_unbiased_and_low_variance():
    """With p ∝ luminance·Ω and nearest lookup, E[L_lum/pdf] = Σ lum·Ω, and each sample deviates only by the
    variation of cos(latitude) inside its texel."""
    dome = _dome()
    sampler = DomeSampler(dome)
    h, w = dome.pixels.shape[:2]
    edges = np.pi * (0.5 - np.arange(h + 1) / h)
    omega = (2 * np.pi / w) * (np.sin(edges[:-1]) - np.sin(edges[1:]))
    lum = (np.asarray(dome.pixels, dtype=np.float64) * 2.0) @ np.array([0.2126, 0.7152, 0.0722])
    flux = (lum * omega[:, None]).sum()
    rng = np.random.default_rng(1)
    weights = np.array([0.2126, 0.7152, 0.0722])
    d_rest, l_rest, pdf_rest = sampler.sample_rest(rng.random((200_000, 3)))
    d_sun, l_sun, pdf_sun = sampler.sample_sun(rng.random((20_000, 3)))
    rest = (l_rest @ weights) / pdf_rest
    sun = (l_sun @ weights) / pdf_sun
    np.testing.assert_allclose(l_rest, sampler.rest_radiance(d_rest))
    assert abs((rest.mean() + sun.mean()) / flux - 1.0) < 5e-3
    rest_flux = flux - float(sampler.sun_flux @ weights)
    away_from_poles = np.abs(d_rest[:, 1]) < 0.5  # cos(lat) varies < 15% across a 1/16-of-π row there
    assert np.abs(rest[away_from_poles] / rest_flux - 1.0).max() < 0.15
    np.testing.assert_allclose(sun, float(sampler.sun_flux @ weights), rtol=0.15)  # one texel: its cos(lat) spread


def test_cone_samples_stay_in_the_cone():
    rng = np.random.default_rng(2)
    axis = rng.normal(size=(1000, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    one_minus_cos = np.full(1000, 0.1)
    d = sample_cone(axis, one_minus_cos, rng.random((1000, 2)))
    cos = np.einsum("ij,ij->i", d, axis)
    assert (cos >= 0.9 - 1e-12).all()
    # uniform in solid angle: cos θ uniform on [0.9, 1]
    assert abs(cos.mean() - 0.95) < 0.003


def test_filtered_cube_and_sun_points_are_flux_exact_with_rotation():
    """The rest of the dome integrated over bake texels keeps its flux exactly; the sun points carry exactly the
    sun's flux; both follow the dome's rotation (the sun lands where R maps its local direction)."""
    from bakery.capture.dome import splat_bilinear
    from bakery.environment.layouts import equirect_directions
    from bakery.sphere.cubemap import cube_texel_solid_angles

    dome = _dome()
    sampler = DomeSampler(dome)
    h, w = dome.pixels.shape[:2]
    omega = cube_texel_solid_angles(16)
    cube = sampler.filtered_cube(16)
    rest_flux = (cube * omega[..., None]).sum(axis=(0, 1, 2))
    edges = np.pi * (0.5 - np.arange(h + 1) / h)
    texel_omega = (2 * np.pi / w) * (np.sin(edges[:-1]) - np.sin(edges[1:]))
    pixels = np.asarray(dome.pixels, dtype=np.float64) * 2.0
    total = (pixels * texel_omega[:, None, None]).sum(axis=(0, 1))
    sun_flux = pixels[3, 7] * texel_omega[3]
    np.testing.assert_allclose(rest_flux, total - sun_flux, rtol=1e-10)
    directions, flux = sampler.sun_points()
    np.testing.assert_allclose(flux.sum(axis=0), sun_flux, rtol=1e-12)
    local_centre = equirect_directions(np.array([3.5]), np.array([7.5]), h, w)[0]
    mean_direction = (directions * flux[:, :1]).sum(axis=0)
    mean_direction /= np.linalg.norm(mean_direction)
    np.testing.assert_allclose(mean_direction, np.asarray(dome.rotation) @ local_centre, atol=2e-3)
    # bilinear splat: flux exact, centroid kept (to second order in the texel size)
    flux_cube = np.zeros((6 * 16 * 16, 3))
    splat_bilinear(flux_cube, directions, flux)
    np.testing.assert_allclose(flux_cube.sum(axis=0), sun_flux, rtol=1e-12)
