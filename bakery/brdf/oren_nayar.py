"""Rough diffuse reflection: Oren–Nayar, as MaterialX's ``oren_nayar_diffuse_bsdf`` evaluates it.

Qualitative model [ON94] (``energy_compensation`` false; ``standard_surface``'s ``diffuse_roughness`` σ):
    f = ρ/π · (A + B·s/t),   A = 1 − σ²/(2(σ² + 0.33)),   B = 0.45 σ²/(σ² + 0.09),
    s = l·v − (n·l)(n·v),     s/t = s/max(n·l, n·v) where s > 0, else 0.

Energy-preserving Oren–Nayar, "EON" [PKH25] (``energy_compensation`` true; ``open_pbr_surface``'s
``base_diffuse_roughness`` r): Fujii's single-scatter lobe plus a multiple-scattering lobe that restores the energy
the single-scatter one loses, so a white (ρ = 1) surface reflects all the light it receives at every view angle:
    f_ss = ρ/π · A_F (1 + r·s/t),  A_F = 1/(1 + c₁ r),  s/t = s/max(n·l, n·v) where s > 0, else s,
    f_ms = ρ_ms/π · (1 − E_F(n·v)) (1 − E_F(n·l)) / (1 − Ē_F),   ρ_ms = ρ² Ē_F / (1 − ρ (1 − Ē_F)),
with E_F Fujii's directional albedo, Ē_F its cosine-weighted average, c₁ = ½ − 2/(3π), c₂ = ⅔ − 28/(15π):
    E_F(μ) = A_F + r A_F G(μ)/π,  G(μ) = sin θ (θ − sin θ cos θ) + ⅔ ((sin θ / cos θ)(1 − sin³θ) − sin θ),
    Ē_F = A_F (1 + c₂ r).

References
    [ON94] M. Oren, S. K. Nayar, "Generalization of Lambert's Reflectance Model", SIGGRAPH 1994 (the qualitative
    model, in MaterialX's simplified form).
    [PKH25] J. Portsmouth, P. Kutz, S. Hill, "EON: A practical energy-preserving rough diffuse BRDF", JCGT 14(1),
    2025 (after Y. Fujii, "A tiny improvement of Oren-Nayar reflectance model"); OpenPBR Surface.
"""

from __future__ import annotations

import math

import numpy as np

FUJII_1 = 0.5 - 2.0 / (3.0 * math.pi)
FUJII_2 = 2.0 / 3.0 - 28.0 / (15.0 * math.pi)


def qualitative(nl: np.ndarray, nv: np.ndarray, lv: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """[ON94]'s factor A + B·s/t (…) that multiplies ρ/π."""
    s = lv - nl * nv
    st = np.where(s > 0, s / np.maximum(np.maximum(nl, nv), 1e-12), 0.0)
    sigma2 = sigma * sigma
    return (1.0 - 0.5 * sigma2 / (sigma2 + 0.33)) + (0.45 * sigma2 / (sigma2 + 0.09)) * st


def fujii_albedo(mu: np.ndarray, r: np.ndarray) -> np.ndarray:
    """E_F(μ) (…): the directional albedo of Fujii's single-scatter lobe at white ρ."""
    mu = np.clip(mu, 1e-6, 1.0)
    a = 1.0 / (1.0 + FUJII_1 * r)
    sin = np.sqrt(np.maximum(0.0, 1.0 - mu * mu))
    theta = np.arccos(mu)
    g = sin * (theta - sin * mu) + 2.0 * ((sin / mu) * (1.0 - sin ** 3) - sin) / 3.0
    return a + r * a * g / math.pi


def energy_preserving(nl: np.ndarray, nv: np.ndarray, lv: np.ndarray, r: np.ndarray, albedo: np.ndarray
                      ) -> np.ndarray:
    """[PKH25]: π·f (3, …) = f_ss + f_ms times π for albedo ρ (3, …) (broadcast with the cosines (…))."""
    s = lv - nl * nv
    st = np.where(s > 0, s / np.maximum(np.maximum(nl, nv), 1e-12), s)
    a = 1.0 / (1.0 + FUJII_1 * r)
    single = albedo * (a * (1.0 + r * st))
    average = a * (1.0 + FUJII_2 * r)
    multi_albedo = albedo * albedo * average / (1.0 - albedo * np.maximum(0.0, 1.0 - average))
    multi = multi_albedo * (np.maximum(1e-7, 1.0 - fujii_albedo(nv, r)) * np.maximum(1e-7, 1.0 - fujii_albedo(nl, r))
                            / np.maximum(1e-7, 1.0 - average))
    return single + multi
