"""Samplers of the capture: dome importance sampling is consistent with its pdf and lookup (pbrt-style triple)."""

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
    h, w = 1024, 2048
    lat_edges = np.pi * (0.5 - np.arange(h + 1) / h)
    lat = 0.5 * (lat_edges[:-1] + lat_edges[1:])
    lon = np.pi * (1 - 2 * (np.arange(w) + 0.5) / w)
    cell = (2 * np.pi / w) * (np.sin(lat_edges[:-1]) - np.sin(lat_edges[1:]))
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    v = np.stack([np.cos(la) * np.sin(lo), np.sin(la), np.cos(la) * np.cos(lo)], axis=-1).reshape(-1, 3)
    total = (sampler.pdf(v).reshape(h, w) * cell[:, None]).sum()
    assert abs(total - 1.0) < 2e-3
    directions, pdf = sampler.sample(rng.random((20_000, 3)))
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(sampler.pdf(directions), pdf, rtol=1e-6)


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
    directions, pdf = sampler.sample(np.random.default_rng(1).random((200_000, 3)))
    estimate = (sampler.radiance(directions) @ np.array([0.2126, 0.7152, 0.0722])) / pdf
    assert abs(estimate.mean() / flux - 1.0) < 5e-3
    away_from_poles = np.abs(directions[:, 1]) < 0.5  # cos(lat) varies < 15% across a 1/16-of-π row there
    assert np.abs(estimate[away_from_poles] / flux - 1.0).max() < 0.15


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
