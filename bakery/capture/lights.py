"""Analytic UsdLux lights: next-event sampling from surface points and ray intersection of their visible shapes.

Every sampler returns, for points x with normals n, a direction ωᵢ towards the light, the distance to the sampled
point (for the shadow ray), and the one-sample estimate of  ∫ L(ωᵢ) max(0, n·ωᵢ) dωᵢ  over the light, i.e.
L·cos/pdf_ω, as a scalar weight w (M,) times the light's colour (3,) (every light here is uniform). Diffuse
shading multiplies it by albedo/π.

Samplers (pbrt-v4, "Light Sampling")
    distant  uniform in the cone of half-angle α around the light direction; estimate E·max(0, n·ωᵢ).
    sphere   uniform in the cone the sphere subtends, pdf = 1/(2π(1−cos θmax)) [pbrt-v4 §12.2.2].
    rect     uniform on the area, pdf_ω = d²/(A·cos θ_l); emits towards local −Z only.
    disk     uniform on the area (r = R·√u), as rect.
"""

from __future__ import annotations

import numpy as np

from bakery.capture.scene import Light
from bakery.capture.tracer import FAR
from bakery.sphere.sampling import orthonormal_frame


def sample_cone(axis: np.ndarray, one_minus_cos_max: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Uniform directions (M, 3) in cones around unit axes (M, 3) with 1 − cos θmax (M,); u (M, 2)."""
    one_minus_cos = u[:, 0] * one_minus_cos_max
    cos_t = 1.0 - one_minus_cos
    sin_t = np.sqrt(np.maximum(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = 2.0 * np.pi * u[:, 1]
    t, s = orthonormal_frame(axis)
    return (sin_t * np.cos(phi))[:, None] * t + (sin_t * np.sin(phi))[:, None] * s + cos_t[:, None] * axis


def sample_light(
    light: Light, points: np.ndarray, normals: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Direction ωᵢ (M, 3), shadow distance (M,), weight w (M,) and colour (3,) with w·colour the estimate of
    ∫ L cos dω, for points and normals (M, 3)."""
    m = points.shape[0]
    axes = np.asarray(light.axes, dtype=np.float64)
    if light.kind == "distant":
        alpha = np.radians(0.5 * light.angle)
        axis = np.broadcast_to(light.direction_to_light, (m, 3))
        wi = sample_cone(axis, np.full(m, 1.0 - np.cos(alpha)), u) if alpha > 0 else np.array(axis)
        cos = np.maximum(0.0, np.einsum("ij,ij->i", normals, wi))
        return wi, np.full(m, FAR), cos, np.asarray(light.illuminance, dtype=np.float64)
    radiance = np.asarray(light.radiance, dtype=np.float64)
    centre = np.asarray(light.position, dtype=np.float64)
    if light.kind == "sphere":
        r = light.size[0]
        to_c = centre - points
        d2 = np.einsum("ij,ij->i", to_c, to_c)
        d = np.sqrt(d2)
        outside = d > r * (1.0 + 1e-9)
        sin2 = np.where(outside, r * r / np.maximum(d2, 1e-300), 1.0)
        cos_max = np.sqrt(np.maximum(0.0, 1.0 - sin2))
        one_minus_cos = sin2 / (1.0 + cos_max)  # 1 − cos θmax without cancellation
        axis = to_c / np.maximum(d, 1e-300)[:, None]
        wi = sample_cone(axis, one_minus_cos, u)
        b = np.einsum("ij,ij->i", wi, to_c)
        disc = np.maximum(0.0, b * b - (d2 - r * r))
        dist = np.maximum(0.0, b - np.sqrt(disc))
        cos = np.maximum(0.0, np.einsum("ij,ij->i", normals, wi))
        weight = np.where(outside, cos * 2.0 * np.pi * one_minus_cos, 0.0)
        return wi, dist, weight, radiance
    # rect or disk: a point uniformly on the area
    if light.kind == "rect":
        a = (u[:, 0] - 0.5) * light.size[0]
        b = (u[:, 1] - 0.5) * light.size[1]
    else:
        rad = light.size[0] * np.sqrt(u[:, 0])
        phi = 2.0 * np.pi * u[:, 1]
        a, b = rad * np.cos(phi), rad * np.sin(phi)
    q = centre + a[:, None] * axes[0] + b[:, None] * axes[1]
    to_q = q - points
    dist = np.linalg.norm(to_q, axis=-1)
    wi = to_q / np.maximum(dist, 1e-300)[:, None]
    cos_l = np.einsum("ij,j->i", wi, axes[2])  # the light's emitting normal is −Z: seen when ωᵢ·Z > 0
    cos = np.maximum(0.0, np.einsum("ij,ij->i", normals, wi))
    weight = np.where(cos_l > 0, cos * light.area * cos_l / np.maximum(dist * dist, 1e-300), 0.0)
    return wi, dist, weight, radiance


def intersect_light_shapes(
    lights: tuple[Light, ...], origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest visible area-light surface along rays: distance (M,) (FAR if none) and its radiance (M, 3)."""
    m = origins.shape[0]
    best = np.full(m, FAR)
    radiance = np.zeros((m, 3))
    for light in lights:
        if light.kind == "distant" or not light.visible:
            continue
        centre = np.asarray(light.position, dtype=np.float64)
        if light.kind == "sphere":
            r = light.size[0]
            oc = origins - centre
            b = np.einsum("ij,ij->i", oc, directions)
            c = np.einsum("ij,ij->i", oc, oc) - r * r
            disc = b * b - c
            sq = np.sqrt(np.maximum(disc, 0.0))
            t0, t1 = -b - sq, -b + sq
            t = np.where(t0 > 0, t0, t1)
            hit = (disc >= 0) & (t > 0)
        else:
            axes = np.asarray(light.axes, dtype=np.float64)
            denom = directions @ axes[2]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((centre - origins) @ axes[2]) / denom
            p = origins + np.where(np.isfinite(t), t, 0.0)[:, None] * directions - centre
            a, bb = p @ axes[0], p @ axes[1]
            if light.kind == "rect":
                inside = (np.abs(a) <= 0.5 * light.size[0]) & (np.abs(bb) <= 0.5 * light.size[1])
            else:
                inside = a * a + bb * bb <= light.size[0] ** 2
            hit = (denom > 0) & np.isfinite(t) & (t > 0) & inside
        closer = hit & (t < best)
        best = np.where(closer, t, best)
        radiance[closer] = np.asarray(light.radiance, dtype=np.float64)
    return best, radiance
