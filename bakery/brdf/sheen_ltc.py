"""Zeltner et al.'s LTC sheen: the fuzz lobe of OpenPBR (MaterialX ``sheen_bsdf`` in mode ``zeltner``, which
``open_pbr_surface``'s fuzz layer uses), a linearly transformed cosine fitted to a volumetric microflake sheen layer.

In the frame (X, Y, N) with X the direction of v projected on the surface (v = (√(1 − μ²), 0, μ), μ = n·v), a
direction l = (x, y, z) is taken back to the clamped-cosine configuration by

    M⁻¹ = [[a⁻¹, 0, b⁻¹], [0, a⁻¹, 0], [0, 0, 1]],   l_o = M⁻¹ l,                          [ZBD22] (its LTC)
    D(l) = D_o(l_o/‖l_o‖) · |M⁻¹| / ‖l_o‖³ = (z/π) · (a⁻¹ / ‖l_o‖²)²            [HDHN16] (change of variables)

(D_o = cos/π, |M⁻¹| = a⁻², and l_o's z is l's), a distribution over the hemisphere with ∫ D dl = 1, so the lobe
f(l, v)·n·l = E(μ, r) · D(l) has exactly the directional albedo E. a⁻¹(μ, r), b⁻¹(μ, r) and E(μ, r) are the
paper's rational and Gaussian fits, as MaterialX's GLSL writes them (``mx_microfacet_sheen.glsl``, adapted there
from the authors' code), with the roughness clamped to [0.01, 1] as there. A fuzz layer of weight w and colour C
over a base adds w·C·E·D and lets the base keep 1 − w·E(μ, r) (MaterialX ``layer``).

References
    [ZBD22] T. Zeltner, B. Burley, M. J.-Y. Chiang, "Practical Multiple-Scattering Sheen Using Linearly
    Transformed Cosines", SIGGRAPH 2022 Talks.
    [HDHN16] E. Heitz, J. Dupuy, S. Hill, D. Neubelt, "Real-Time Polygonal-Light Shading with Linearly
    Transformed Cosines", ACM TOG 35(4), 2016.
"""

from __future__ import annotations

import math

import numpy as np

#: The roughness range of the fits (MaterialX clamps to it)
MIN_ROUGHNESS, MAX_ROUGHNESS = 0.01, 1.0


def _clamped(nv: np.ndarray, roughness: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.clip(nv, 1e-6, 1.0), np.clip(roughness, MIN_ROUGHNESS, MAX_ROUGHNESS)


def directional_albedo(nv: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """E(μ, r) (…): [ZBD22]'s Gaussian fit of the layer's albedo (MaterialX ``mx_zeltner_sheen_dir_albedo``),
    clipped to [0, 1]."""
    x, y = _clamped(np.asarray(nv), np.asarray(roughness))
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    value = np.exp(-0.5 * ((x - m) / s) ** 2) / (s * math.sqrt(2.0 * math.pi)) + o
    return np.clip(value, 0.0, 1.0)


def ltc_inverse(nv: np.ndarray, roughness: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a⁻¹, b⁻¹) (…) of M⁻¹: [ZBD22]'s rational fits (MaterialX ``mx_zeltner_sheen_ltc_aInv``/``bInv``)."""
    x, y = _clamped(np.asarray(nv), np.asarray(roughness))
    a_inv = (2.58126 * x + 0.813703 * y) * y / (1.0 + 0.310327 * x * x + 2.60994 * x * y)
    b_inv = np.sqrt(1.0 - x) * (y - 1.0) * y * y * y / (0.0000254053 + 1.71228 * x - 1.71506 * x * y
                                                       + 1.34174 * y * y)
    return a_inv, b_inv


def ltc_distribution(x: np.ndarray, y2: np.ndarray, z: np.ndarray, nv: np.ndarray,
                     roughness: np.ndarray) -> np.ndarray:
    """D(l) (…) of the module docstring for l = (x, y, z) in the (X, Y, N) frame (y enters squared: ``y2``)."""
    a_inv, b_inv = ltc_inverse(nv, roughness)
    ox = a_inv * x + b_inv * z
    length2 = ox * ox + a_inv * a_inv * y2 + z * z
    return np.maximum(z, 0.0) / math.pi * (a_inv / np.maximum(length2, 1e-30)) ** 2


def sheen_lobe(nl: np.ndarray, nv: np.ndarray, vl: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """f·n·l (…) = E(μ, r)·D(l) from the cosines n·l, n·v and v·l: x = (v·l − μ n·l)/√(1 − μ²) (0 at normal
    view, where D depends on x² + y² alone), y² = 1 − x² − z²."""
    mu = np.clip(nv, 1e-6, 1.0)
    sin_v = np.sqrt(np.maximum(1.0 - mu * mu, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(sin_v > 1e-6, (vl - mu * nl) / np.where(sin_v > 1e-6, sin_v, 1.0), 0.0)
    z = np.clip(nl, 0.0, 1.0)
    x = np.clip(x, -1.0, 1.0)
    y2 = np.maximum(1.0 - x * x - z * z, 0.0)
    return directional_albedo(mu, roughness) * ltc_distribution(x, y2, z, mu, roughness)
