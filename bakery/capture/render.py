"""Rendering a probe's radiance cube with Embree: what each probe sees, on the bake grid.

For every cube texel (:func:`bakery.sphere.cubemap.cube_texel_directions`) ``samples`` rays leave the probe through
jittered points of the texel (Latin-hypercube stratified in u and v); the texel's value is their mean radiance. Along a ray:

- a visible area light in front of all geometry contributes its radiance;
- a miss sees the dome (:class:`bakery.capture.dome.DomeSampler`);
- a hit is shaded (Lambertian, two-sided) as
      L = Le + (ρ/π)·[Σ_lights ∫ L_l cos dω  +  ∫ L_dome cos dω  +  ∫ L_indirect cos dω],
  with one next-event sample per light (shadow ray) and one dome sample (mixture of luminance importance
  sampling and cosine sampling, pdf = ½·p_dome + ½·cos/π: the balance heuristic of the two strategies), and
  a cosine-sampled continuation ray for each of ``bounces`` diffuse bounces (the estimate ρ/π·L·cos/(cos/π) = ρ·L).
  Continuation rays add emission of the surfaces they hit but neither the dome nor the lights (those are
  counted by next-event estimation), so nothing is counted twice. Light shapes are visible to probe rays but do
  not occlude (they are not in the Embree scene).

Distant lights smaller than one texel are splatted: if the probe sees the light's direction unoccluded, its
illuminance E is added to the texel containing that direction as E/Ω_texel (flux preserved exactly). Wider distant
lights are seen by escaping rays inside their cone with radiance E/(π·sin²α).

Randomness comes from ``numpy.random.default_rng(seed)`` with the seed derived from the probe's name
(:func:`probe_seed`), so captures are identical across runs and worker counts.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from bakery.capture.dome import DomeSampler
from bakery.capture.lights import intersect_light_shapes, sample_light
from bakery.capture.scene import CaptureScene, Light
from bakery.capture.tracer import FAR, SceneTracer
from bakery.files import sha256_bytes
from bakery.sphere.cubemap import (
    cube_face_uv_to_direction,
    cube_mean_texel_solid_angle,
    cube_texel_solid_angles,
    direction_to_cube_texel,
)
from bakery.sphere.sampling import orthonormal_frame


def probe_seed(name: str, base_seed: int = 0) -> int:
    """Stable 63-bit seed from a probe identity (SHA-256 of the name, mixed with ``base_seed``)."""
    digest = bytes.fromhex(sha256_bytes(f"{base_seed}:{name}".encode())[:16])
    return int.from_bytes(digest, "little") & ((1 << 63) - 1)


@dataclass(frozen=True)
class CaptureStats:
    """Work done by one capture: rays traced and wall time (seconds)."""

    rays: int
    seconds: float

    @property
    def rays_per_second(self) -> float:
        return self.rays / self.seconds if self.seconds > 0 else 0.0


def _jittered_texel_directions(face_size: int, samples: int, rng: np.random.Generator) -> np.ndarray:
    """(samples, 6, N, N, 3) directions through jittered points of every texel.

    The ``samples`` points of a texel are a Latin hypercube: sample j takes the u-stratum j and a random v-stratum
    (a per-texel permutation), jittered uniformly inside its stratum cell, so every texel's u and v are each
    stratified into ``samples`` intervals (lower variance than independent jitter, same expectation).
    """
    n = face_size
    jitter = rng.random((samples, 6, n, n, 2))
    strata_u = np.arange(samples, dtype=np.float64)[:, None, None, None]
    strata_v = rng.permuted(np.broadcast_to(strata_u, (samples, 6, n, n)), axis=0)
    fu = (strata_u + jitter[..., 0]) / samples
    fv = (strata_v + jitter[..., 1]) / samples
    idx = np.arange(n, dtype=np.float64)
    u = (idx[None, None, None, :] + fu) / n * 2.0 - 1.0
    v = (idx[None, None, :, None] + fv) / n * 2.0 - 1.0
    face = np.broadcast_to(np.arange(6)[None, :, None, None], u.shape)
    return cube_face_uv_to_direction(face, u, v)


class ProbeRenderer:
    """Renders radiance cubes of probes in one scene (the Embree scene is built once and shared)."""

    def __init__(self, scene: CaptureScene, samples: int = 4, bounces: int = 1, base_seed: int = 0) -> None:
        if samples < 1:
            raise ValueError(f"samples must be >= 1, got {samples}")
        if bounces < 0:
            raise ValueError(f"bounces must be >= 0, got {bounces}")
        self.scene = scene
        self.samples = samples
        self.bounces = bounces
        self.base_seed = base_seed
        self.tracer = SceneTracer(scene)
        self.dome = DomeSampler(scene.dome)
        self.area_lights = tuple(light for light in scene.lights if light.kind != "distant")
        self.distant_lights = tuple(light for light in scene.lights if light.kind == "distant")

    # ------------------------------------------------------------------------------------------------------------
    def render(self, position: np.ndarray, face_size: int, name: str) -> tuple[np.ndarray, CaptureStats]:
        """Radiance cube (6, N, N, 3) float32 seen from ``position`` (bake frame, metres), and its stats."""
        start_time = time.perf_counter()
        start_rays = self.tracer.rays_cast
        rng = np.random.default_rng(probe_seed(name, self.base_seed))
        n = face_size
        directions = _jittered_texel_directions(n, self.samples, rng).reshape(-1, 3)
        origins = np.broadcast_to(np.asarray(position, dtype=np.float64), directions.shape)
        radiance = self.trace_camera_rays(origins, directions, rng, face_size)
        cube = radiance.reshape(self.samples, 6, n, n, 3).mean(axis=0)
        cube = self._add_distant_lights(cube, np.asarray(position, dtype=np.float64))
        stats = CaptureStats(self.tracer.rays_cast - start_rays, time.perf_counter() - start_time)
        return cube.astype(np.float32), stats

    def trace_camera_rays(
        self, origins: np.ndarray, directions: np.ndarray, rng: np.random.Generator, face_size: int
    ) -> np.ndarray:
        """Radiance (M, 3) arriving at ``origins`` from ``directions`` (both (M, 3)); distant lights smaller
        than a texel of a ``face_size`` cube are left out (:meth:`render` splats them)."""
        m = origins.shape[0]
        prim, t = self.tracer.intersect(origins, directions)
        t_light, l_light = intersect_light_shapes(self.area_lights, origins, directions)
        result = np.zeros((m, 3))
        sees_light = (t_light < FAR) & (t_light < t)
        result[sees_light] = l_light[sees_light]
        miss = (prim < 0) & ~sees_light
        if miss.any():
            result[miss] = self.dome.radiance(directions[miss])
            for light in self.distant_lights:
                alpha = np.radians(0.5 * light.angle)
                if not self._splat_distant(light, face_size):
                    inside = directions[miss] @ light.direction_to_light >= np.cos(alpha)
                    l_sun = np.asarray(light.illuminance) / (np.pi * np.sin(alpha) ** 2)
                    result[np.flatnonzero(miss)[inside]] += l_sun
        hit = (prim >= 0) & ~sees_light
        if hit.any():
            idx = np.flatnonzero(hit)
            result[idx] = self._shade(origins[idx], directions[idx], prim[idx], t[idx], rng)
        return result

    # ------------------------------------------------------------------------------------------------------------
    def _shade(
        self, origins: np.ndarray, directions: np.ndarray, prim: np.ndarray, t: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """Outgoing radiance (M, 3) at the first hits of rays, with next-event estimation and diffuse bounces."""
        m = origins.shape[0]
        out = np.zeros((m, 3))
        throughput = np.ones((m, 3))
        ray_index = np.arange(m)
        for depth in range(self.bounces + 1):
            if ray_index.size == 0:
                break
            albedo = self.tracer.albedo[prim]
            out_add = throughput * self.tracer.emission[prim]
            normals = self.tracer.normals[prim]
            flip = np.einsum("ij,ij->i", normals, directions) > 0
            normals = np.where(flip[:, None], -normals, normals)
            hits = origins + t[:, None] * directions
            points = hits + self.tracer.offset(hits)[:, None] * normals
            direct = self._direct(points, normals, rng)
            out_add += throughput * albedo / np.pi * direct
            out[ray_index] += out_add  # ray_index holds each surviving path once
            if depth == self.bounces:
                break
            new_dirs = self._cosine_sample(normals, rng.random((ray_index.size, 2)))
            throughput = throughput * albedo
            alive = throughput.max(axis=1) > 0
            prim2, t2 = self.tracer.intersect(points[alive], new_dirs[alive])
            keep = prim2 >= 0
            ray_index = ray_index[alive][keep]
            throughput = throughput[alive][keep]
            origins, directions = points[alive][keep], new_dirs[alive][keep]
            prim, t = prim2[keep], t2[keep]
        return out

    def _direct(self, points: np.ndarray, normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Σ over lights and dome of the estimate of ∫ L cos dω, with shadow rays: (M, 3)."""
        m = points.shape[0]
        total = np.zeros((m, 3))
        for light in self.scene.lights:
            wi, dist, weight, colour = sample_light(light, points, normals, rng.random((m, 2)))
            idx = np.flatnonzero(weight > 0)
            if idx.size == 0:
                continue
            blocked = self.tracer.occluded(points[idx], wi[idx], dist[idx] * (1.0 - 1e-6))
            lit = idx[~blocked]
            total[lit] += weight[lit, None] * colour
        if not self.dome.black and self.dome.scale.max() > 0:
            total += self._dome_direct(points, normals, rng)
        return total

    def _dome_direct(self, points: np.ndarray, normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        m = points.shape[0]
        u = rng.random((m, 4))
        use_cosine = u[:, 3] < 0.5
        wi_dome, _ = self.dome.sample(u[:, :3])
        wi_cos = self._cosine_sample(normals, u[:, 1:3])
        wi = np.where(use_cosine[:, None], wi_cos, wi_dome)
        cos = np.einsum("ij,ij->i", normals, wi)
        # one-sample mixture of two strategies: pdf = ½ p_dome + ½ cos/π (balance heuristic)
        pdf = 0.5 * self.dome.pdf(wi) + 0.5 * np.maximum(cos, 0.0) / np.pi
        active = (cos > 0) & (pdf > 0)
        result = np.zeros((m, 3))
        if not active.any():
            return result
        idx = np.flatnonzero(active)
        blocked = self.tracer.occluded(points[idx], wi[idx], np.full(idx.size, FAR))
        idx = idx[~blocked]
        result[idx] = self.dome.radiance(wi[idx]) * (cos[idx] / pdf[idx])[:, None]
        return result

    @staticmethod
    def _cosine_sample(normals: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Cosine-distributed directions (M, 3) about unit normals (M, 3) (Malley's method)."""
        r = np.sqrt(u[:, 0])
        phi = 2.0 * np.pi * u[:, 1]
        x, y = r * np.cos(phi), r * np.sin(phi)
        z = np.sqrt(np.maximum(0.0, 1.0 - u[:, 0]))
        t, s = orthonormal_frame(normals)
        return x[:, None] * t + y[:, None] * s + z[:, None] * normals

    # ------------------------------------------------------------------------------------------------------------
    def _splat_distant(self, light: Light, face_size: int) -> bool:
        """Whether a distant light is splatted into one texel (disc smaller than a texel) rather than ray-seen."""
        alpha = np.radians(0.5 * light.angle)
        disc = 2.0 * np.pi * (1.0 - np.cos(alpha))
        return disc < cube_mean_texel_solid_angle(face_size)

    def _add_distant_lights(self, cube: np.ndarray, position: np.ndarray) -> np.ndarray:
        n = cube.shape[1]
        for light in self.distant_lights:
            if not self._splat_distant(light, n):
                continue
            d = light.direction_to_light[None, :]
            if self.tracer.occluded(position[None, :], d, np.array([FAR]))[0]:
                continue
            t_light, _ = intersect_light_shapes(self.area_lights, position[None, :], d)
            if t_light[0] < FAR:
                continue
            face, row, col = direction_to_cube_texel(d, n)
            omega = cube_texel_solid_angles(n)[face[0], row[0], col[0]]
            cube[face[0], row[0], col[0]] += np.asarray(light.illuminance) / omega
        return cube


def capture_probe_cube(
    scene: CaptureScene, position: np.ndarray, face_size: int, name: str, samples: int = 4, bounces: int = 1
) -> np.ndarray:
    """Convenience: radiance cube (6, N, N, 3) of one probe (builds the Embree scene; prefer
    :class:`ProbeRenderer` for many probes)."""
    renderer = ProbeRenderer(scene, samples=samples, bounces=bounces)
    cube, _ = renderer.render(position, face_size, name)
    return cube
