"""The Imageworks sheen lobe: a microfacet BRDF for cloth and velvet, as MaterialX's ``sheen_bsdf`` evaluates it
(its default mode ``conty_kulla``, which ``standard_surface``'s sheen layer uses).

    D(h)    = (2 + 1/r) · sin(θ_h)^(1/r) / (2π)                      [EK17] Eq. 2, r = max(roughness, 0.005)
    f(l, v) = D(h) / (4 (n·l + n·v − (n·l)(n·v)))                     [NP13] the "smoother" visibility
    E(μ, r) = ∫ f(l, v) n·l dl over the hemisphere, μ = n·v           (directional albedo)

A sheen layer of weight w and colour C over a base adds w·C·f·n·l and lets the base keep 1 − w·E(n·v, r) of its
reflection (MaterialX ``layer``: the top's throughput). E is tabulated here by quadrature of f itself (Gauss–Legendre
in cos θ_l, midpoint in φ), so the layer's energy balance is that of the lobe it evaluates; MaterialX's GLSL uses a
rational fit of the same integral.

References
    [EK17] A. Estevez, C. Kulla, "Production Friendly Microfacet Sheen BRDF", Sony Pictures Imageworks, 2017.
    [NP13] D. Neubelt, M. Pettineo, "Crafting a Next-Gen Material Pipeline for The Order: 1886", SIGGRAPH 2013
    course notes (the denominator 4(n·l + n·v − n·l n·v)).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

#: MaterialX's floor on the sheen roughness (mx_imageworks_sheen_NDF)
MIN_ROUGHNESS = 0.005
#: Table nodes in μ = n·v and in roughness, both over [0, 1]
TABLE_SIZE = 33


def sheen_distribution(cos_h: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """[EK17] Eq. 2: D (…) of the half vector's cosine with the normal."""
    inv_r = 1.0 / np.maximum(roughness, MIN_ROUGHNESS)
    sin2 = np.maximum(1.0 - cos_h * cos_h, 0.0)
    return (2.0 + inv_r) * sin2 ** (0.5 * inv_r) / (2.0 * math.pi)


def sheen_brdf(nl: np.ndarray, nv: np.ndarray, nh: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """f (…) = D / (4 (n·l + n·v − n·l n·v)) ([NP13]); cosines clamped to [1e-6, 1] as MaterialX clamps them."""
    nl, nv = np.clip(nl, 1e-6, 1.0), np.clip(nv, 1e-6, 1.0)
    return sheen_distribution(np.clip(nh, 1e-6, 1.0), roughness) / (4.0 * (nl + nv - nl * nv))


@lru_cache(maxsize=1)
def directional_albedo_table() -> np.ndarray:
    """E (R, M) at roughness r_i = i/(R − 1) and μ_j = j/(M − 1) (μ = 0 evaluated at 1e-4), R = M = TABLE_SIZE."""
    x, w = np.polynomial.legendre.leggauss(96)
    cos_l = 0.5 * (x + 1.0)  # n·l on (0, 1)
    weight_l = 0.5 * w
    phi = (np.arange(96) + 0.5) * (math.pi / 96)  # the half plane; f is even in φ
    sin_l = np.sqrt(1.0 - cos_l * cos_l)
    lx = sin_l[:, None] * np.cos(phi)[None, :]  # (96, 96)
    lz = np.broadcast_to(cos_l[:, None], lx.shape)
    mu = np.maximum(np.linspace(0.0, 1.0, TABLE_SIZE), 1e-4)
    roughness = np.linspace(0.0, 1.0, TABLE_SIZE)
    table = np.empty((TABLE_SIZE, TABLE_SIZE))
    for j, m in enumerate(mu):
        vx, vz = math.sqrt(1.0 - m * m), m
        hx, hy, hz = lx + vx, sin_l[:, None] * np.sin(phi)[None, :], lz + vz
        nh = hz / np.sqrt(hx * hx + hy * hy + hz * hz)
        for i, r in enumerate(roughness):
            f = sheen_brdf(lz, m, nh, r)
            table[i, j] = 2.0 * (math.pi / 96) * float(np.sum(f * lz * weight_l[:, None]))
    return table


def directional_albedo(nv: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """E(n·v, r) (…) by bilinear interpolation of :func:`directional_albedo_table`, clipped to [0, 1]."""
    table = directional_albedo_table()
    scale = TABLE_SIZE - 1
    x = np.clip(np.asarray(nv, dtype=np.float64), 0.0, 1.0) * scale
    y = np.clip(np.asarray(roughness, dtype=np.float64), 0.0, 1.0) * scale
    j0 = np.minimum(x.astype(np.int64), scale - 1)
    i0 = np.minimum(y.astype(np.int64), scale - 1)
    fx, fy = x - j0, y - i0
    value = ((1 - fy) * ((1 - fx) * table[i0, j0] + fx * table[i0, j0 + 1])
             + fy * ((1 - fx) * table[i0 + 1, j0] + fx * table[i0 + 1, j0 + 1]))
    return np.clip(value, 0.0, 1.0)
