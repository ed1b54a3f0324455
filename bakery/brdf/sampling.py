"""Importance sampling of GGX in pbrt-style triples (sample / pdf), in the local frame n = +z.

Notation
    u1, u2   uniform numbers in [0, 1)
    v        view (towards the viewer), local frame, v_z = n·v > 0
    h        sampled microfacet normal; l = reflect(v, h) the light direction
    pdf_h    density of h per solid angle; pdf_l = pdf_h / (4 |v·h|) (reflection Jacobian, [WMLT07] Eq. 14)

References
    [Hei18] Heitz, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4), 2018 (Listing 1; pdf Eq. 3:
        D_v(h) = G1(v) max(0, v·h) D(h) / (n·v)).
    [WMLT07] Walter et al. 2007 (NDF sampling: θ_h = atan(α √(u/(1−u))), pdf_h = D(h)(n·h)).
"""

from __future__ import annotations

import numpy as np

from bakery.brdf.ggx import ggx_distribution, smith_g1
from bakery.sphere.sampling import orthonormal_frame


def to_local(w: np.ndarray, n: np.ndarray) -> np.ndarray:
    """World directions (..., 3) → local frame of normal n (..., 3) (z along n)."""
    t, b = orthonormal_frame(n)
    return np.stack([np.sum(w * t, -1), np.sum(w * b, -1), np.sum(w * n, -1)], axis=-1)


def to_world(w: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Local directions (..., 3) in the frame of n → world (..., 3)."""
    t, b = orthonormal_frame(n)
    return w[..., 0:1] * t + w[..., 1:2] * b + w[..., 2:3] * np.asarray(n, dtype=np.float64)


def sample_ggx_ndf(u1: np.ndarray, u2: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """h ~ D(h)(n·h) in the local frame (..., 3) ([WMLT07] Eq. 35–36)."""
    alpha = np.asarray(alpha, dtype=np.float64)
    u1 = np.asarray(u1, dtype=np.float64)
    tan2 = alpha * alpha * u1 / np.maximum(1.0 - u1, 1e-300)
    cos_t = 1.0 / np.sqrt(1.0 + tan2)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * np.asarray(u2, dtype=np.float64)
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)


def ggx_ndf_pdf(h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """pdf_h(h) = D(h)(n·h) per solid angle, local frame."""
    c = np.asarray(h)[..., 2]
    return ggx_distribution(c, alpha) * np.maximum(c, 0.0)


def sample_ggx_vndf(v: np.ndarray, u1: np.ndarray, u2: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """h ~ D_v(h), the visible normals seen from v (local, v_z > 0), isotropic α ([Hei18] Listing 1)."""
    v = np.asarray(v, dtype=np.float64)
    alpha = np.asarray(alpha, dtype=np.float64)
    # [Hei18] section 1: stretch the view into the hemisphere configuration.
    vh = np.stack([alpha * v[..., 0], alpha * v[..., 1], v[..., 2]], axis=-1)
    vh = vh / np.linalg.norm(vh, axis=-1, keepdims=True)
    # section 4.1: orthonormal basis (with special case when cross product is zero).
    lensq = vh[..., 0] ** 2 + vh[..., 1] ** 2
    inv = np.where(lensq > 0.0, 1.0 / np.sqrt(np.where(lensq > 0.0, lensq, 1.0)), 0.0)
    t1 = np.where(
        (lensq > 0.0)[..., None],
        np.stack([-vh[..., 1] * inv, vh[..., 0] * inv, np.zeros_like(lensq)], axis=-1),
        np.array([1.0, 0.0, 0.0]),
    )
    t2 = np.cross(vh, t1)
    # section 4.2: parameterisation of the projected area.
    r = np.sqrt(np.asarray(u1, dtype=np.float64))
    phi = 2.0 * np.pi * np.asarray(u2, dtype=np.float64)
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vh[..., 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
    # section 4.3: reprojection onto hemisphere.
    nh = p1[..., None] * t1 + p2[..., None] * t2 + np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))[..., None] * vh
    # section 3.4: unstretch.
    ne = np.stack([alpha * nh[..., 0], alpha * nh[..., 1], np.maximum(1e-12, nh[..., 2])], axis=-1)
    return ne / np.linalg.norm(ne, axis=-1, keepdims=True)


def vndf_pdf(v: np.ndarray, h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """pdf_h(h | v) = D_v(h) = G1(v) max(0, v·h) D(h) / (n·v) ([Hei18] Eq. 3), local frame."""
    v = np.asarray(v, dtype=np.float64)
    h = np.asarray(h, dtype=np.float64)
    nv = v[..., 2]
    vh = np.sum(v * h, axis=-1)
    return smith_g1(nv, alpha) * np.maximum(vh, 0.0) * ggx_distribution(h[..., 2], alpha) / np.maximum(nv, 1e-12)


def reflection_pdf_from_half_pdf(pdf_h: np.ndarray, v: np.ndarray, h: np.ndarray) -> np.ndarray:
    """pdf_l = pdf_h / (4 |v·h|): density of l = reflect(v, h) per solid angle ([WMLT07] Eq. 14)."""
    vh = np.abs(np.sum(np.asarray(v) * np.asarray(h), axis=-1))
    return np.asarray(pdf_h) / np.maximum(4.0 * vh, 1e-12)
