"""Rendering a probe's radiance cube with Embree: what each probe sees, on the bake grid.

Probe texels
    For every cube texel (:func:`bakery.sphere.cubemap.cube_texel_directions`) ``samples`` rays leave the probe
    through jittered points of the texel (Latin-hypercube stratified in u and v). A texel's value is

        (1/S)·Σ_rays [ L_surface or L_light-shape of the rays that hit something ]
        + (escaping fraction) · D_rest(texel)  +  sun splat · sun visibility  +  small distant lights splat,

    where D_rest is the rest of the dome integrated over the texel (flux-exact box filter,
    :meth:`bakery.capture.dome.DomeSampler.filtered_cube`), the sun (the dome's brightest texels) is a set of
    sub-texel points tested for visibility from the probe and splatted bilinearly
    (:func:`bakery.capture.dome.splat_bilinear`), and distant lights smaller than a texel are splatted the same way
    (E/Ω of their flux, centroid kept). So an unoccluded dome is exact at any sample count; only occluders and
    surfaces are estimated by rays. Distant lights wider than a texel are seen by escaping rays.

Surfaces (unidirectional path tracing with multiple importance sampling)
    At every hit: emission of the surface (triangles are not sampled as lights), next-event estimation of every
    analytic light (:mod:`bakery.capture.lights`), of the dome's rest and of its sun, each with a shadow ray against
    the triangles and the (opaque) light shapes; and a BSDF-sampled continuation ray
    (:class:`bakery.capture.bsdf.Bsdf`). A continuation ray that reaches a light shape, the dome or a distant light's
    disc adds that radiance with the power-heuristic weight against the light's next-event pdf, and ends; one that
    hits a surface continues. ``bounces`` is the largest number of continuations (0: direct light only); after
    bounce :data:`RR_START`, paths are ended by Russian roulette with survival probability min(0.95, max
    throughput) (unbiased), so the default (:data:`DEFAULT_BOUNCES`) converges closed rooms.

Noise and adaptive sampling
    Each of the S rays of a texel gives an independent one-ray estimate of the cube; the spread of their luminance
    SH (bands ≤ 2) gives the standard error of the probe's SH. ``sh_noise`` = ‖σ(SH)‖ / |SH₀₀| (relative). With
    ``target_noise`` > 0 the renderer adds passes of S rays per texel until the noise is below it or
    ``max_samples`` rays per texel are spent.

Randomness comes from ``numpy.random.default_rng(seed)`` with the seed derived from the probe's name
(:func:`probe_seed`), so captures are identical across runs and worker counts.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from bakery.capture.bsdf import Bsdf
from bakery.capture.dome import DomeSampler, splat_bilinear
from bakery.capture.lights import SHADOW_EPSILON, DistantLightModel, LightSet, RectLightModel
from bakery.capture.scene import CaptureScene, Light
from bakery.capture.surfaces import BOUNCE_SPREAD, Surfaces
from bakery.capture.tracer import FAR, SceneTracer
from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.files import sha256_bytes
from bakery.sh.basis import evaluate_sh_basis
from bakery.sphere.cubemap import (
    cube_face_uv_to_direction,
    cube_mean_texel_solid_angle,
    cube_texel_directions,
    cube_texel_solid_angles,
)

#: Default largest number of bounces (continuations); Russian roulette ends paths long before.
DEFAULT_BOUNCES = 64
#: Bounces up to this one are never ended by Russian roulette (exact); later ones may be.
RR_START = 3
#: Rays per Python-level batch of primary rays (memory bound for large faces × samples).
BATCH = 1 << 17


def probe_seed(name: str, base_seed: int = 0) -> int:
    """Stable 63-bit seed from a probe identity (SHA-256 of the name, mixed with ``base_seed``)."""
    digest = bytes.fromhex(sha256_bytes(f"{base_seed}:{name}".encode())[:16])
    return int.from_bytes(digest, "little") & ((1 << 63) - 1)


@dataclass(frozen=True)
class CaptureStats:
    """Work done by one capture: rays traced, wall time (seconds), rays per texel spent and the achieved SH noise."""

    rays: int
    seconds: float
    samples: int = 0
    sh_noise: float = 0.0

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


def _power(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Power-heuristic weight a²/(a² + b²) (1 where b = 0, i.e. the other strategy cannot produce the sample)."""
    a2, b2 = a * a, b * b
    with np.errstate(invalid="ignore", over="ignore"):
        w = np.where(np.isinf(a), 1.0, a2 / np.maximum(a2 + b2, 1e-300))
    return np.where(b > 0, w, 1.0)


class ProbeRenderer:
    """Renders radiance cubes of probes in one scene (the Embree scene is built once and shared)."""

    def __init__(self, scene: CaptureScene, samples: int = 4, bounces: int = DEFAULT_BOUNCES, base_seed: int = 0,
                 target_noise: float = 0.0, max_samples: int | None = None) -> None:
        if samples < 1:
            raise ValueError(f"samples must be >= 1, got {samples}")
        if bounces < 0:
            raise ValueError(f"bounces must be >= 0, got {bounces}")
        if target_noise < 0:
            raise ValueError(f"target_noise must be >= 0, got {target_noise}")
        self.scene = scene
        self.samples = samples
        self.bounces = bounces
        self.base_seed = base_seed
        self.target_noise = float(target_noise)
        self.max_samples = int(max_samples) if max_samples else max(samples, 64 * samples if target_noise else samples)
        self.tracer = SceneTracer(scene)
        self.surfaces = Surfaces(scene, self.tracer)
        self.dome = DomeSampler(scene.dome)
        self.lights = LightSet(scene.lights, scene.textures)
        self.distant = self.lights.distant
        self._primary_spread = BOUNCE_SPREAD
        # PortalLights: rects through which the dome is also sampled (a sampling guide; the dome itself is unchanged)
        self.portals = tuple(RectLightModel(dataclasses.replace(p, visible=True)) for p in scene.portals
                             if p.kind == "rect" and p.size[0] * p.size[1] > 0)

    # ------------------------------------------------------------------------------------------------------------
    def render(self, position: np.ndarray, face_size: int, name: str) -> tuple[np.ndarray, CaptureStats]:
        """Radiance cube (6, N, N, 3) float32 seen from ``position`` (bake frame, metres), and its stats."""
        start_time = time.perf_counter()
        start_rays = self.tracer.rays_cast
        rng = np.random.default_rng(probe_seed(name, self.base_seed))
        n = face_size
        self._primary_spread = math.sqrt(cube_mean_texel_solid_angle(n))
        position = np.asarray(position, dtype=np.float64)
        filtered = self.dome.filtered_cube(n) if not self.dome.black else None
        basis = evaluate_sh_basis(cube_texel_directions(n).reshape(-1, 3), 2) * cube_texel_solid_angles(n).reshape(
            -1, 1)
        extra = self._add_distant_lights(self._add_sun(np.zeros((6, n, n, 3)), position), position)
        extra_dc = float((extra.reshape(-1, 3) @ LUMINANCE_WEIGHTS) @ basis[:, 0])
        total = np.zeros((6, n, n, 3))
        sub_sh: list[np.ndarray] = []
        spent = 0
        noise = 0.0
        while True:
            directions = _jittered_texel_directions(n, self.samples, rng).reshape(-1, 3)
            radiance = np.zeros((directions.shape[0], 3))
            for start in range(0, directions.shape[0], BATCH):
                stop = min(directions.shape[0], start + BATCH)
                d = directions[start:stop]
                origins = np.broadcast_to(position, d.shape)
                texel = np.arange(start, stop) % (6 * n * n)
                radiance[start:stop] = self.trace_camera_rays(origins, d, rng, n, filtered, texel)
            per_sample = radiance.reshape(self.samples, 6, n, n, 3)
            total += per_sample.sum(axis=0)
            spent += self.samples
            lum = per_sample.reshape(self.samples, -1, 3) @ LUMINANCE_WEIGHTS
            sub_sh.extend(list(lum @ basis))
            noise = _relative_sh_noise(np.asarray(sub_sh), extra_dc)
            if self.target_noise <= 0 or noise <= self.target_noise or spent + self.samples > self.max_samples:
                break
        cube = total / spent + extra
        stats = CaptureStats(self.tracer.rays_cast - start_rays, time.perf_counter() - start_time, spent, noise)
        return cube.astype(np.float32), stats

    def trace_camera_rays(self, origins: np.ndarray, directions: np.ndarray, rng: np.random.Generator,
                          face_size: int, filtered: np.ndarray | None = None,
                          texel: np.ndarray | None = None) -> np.ndarray:
        """Radiance (M, 3) arriving at ``origins`` from ``directions`` (both (M, 3)). Escaping rays see the rest of
        the dome filtered over their texel (flat index ``texel`` into a ``face_size`` cube) when ``filtered`` is
        given — the sun is then left out, as are distant lights smaller than a texel (:meth:`render` splats them)
        — else the whole dome point-sampled."""
        m = origins.shape[0]
        prim, t, bu, bv = self._intersect(origins, directions)
        t_light, _which, l_light = self.lights.nearest(origins, directions)
        result = np.zeros((m, 3))
        sees_light = (t_light < FAR) & (t_light < t)
        result[sees_light] = l_light[sees_light]
        miss = (prim < 0) & ~sees_light
        if miss.any():
            idx = np.flatnonzero(miss)
            if self.dome.black:
                pass
            elif filtered is not None and texel is not None:
                result[idx] = filtered.reshape(-1, 3)[texel[idx]]
            else:  # no texel filter given: point lookups of the whole dome, sun included
                result[idx] = self.dome.radiance(directions[idx])
            for light in self.distant:
                if not self._splat_distant(light.light, face_size):
                    result[idx] += light.escaped(directions[idx])
        hit = (prim >= 0) & ~sees_light
        if hit.any():
            idx = np.flatnonzero(hit)
            result[idx] = self._shade(origins[idx], directions[idx], prim[idx], t[idx], bu[idx], bv[idx], rng)
        return result

    # ------------------------------------------------------------------------------------------------------------
    def _intersect(self, origins: np.ndarray, directions: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest hit (prim, t, u, v) that is not cut out (opacity below the material's opacityThreshold)."""
        prim, t, bu, bv = self.tracer.intersect_uv(origins, directions)
        if not self.surfaces.cutout:
            return prim, t, bu, bv
        for _ in range(32):
            idx = np.flatnonzero(prim >= 0)
            if idx.size == 0:
                break
            cut = self.surfaces.cut(prim[idx], bu[idx], bv[idx])
            if not cut.any():
                break
            j = idx[cut]
            hits = origins[j] + t[j, None] * directions[j]
            off = self.tracer.offset(hits)
            p2, t2, u2, v2 = self.tracer.intersect_uv(hits + off[:, None] * directions[j], directions[j])
            prim[j], bu[j], bv[j] = p2, u2, v2
            t[j] = np.where(p2 >= 0, t2 + t[j] + off, FAR)
        return prim, t, bu, bv

    def _visible(self, points: np.ndarray, wi: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """Unoccluded segments (by triangles and by light shapes): bool (M,)."""
        short = np.where(dist < FAR, dist * (1.0 - SHADOW_EPSILON), FAR)
        if self.surfaces.cutout:
            _prim, t, _u, _v = self._intersect(points, wi)
            blocked = t < short
        else:
            blocked = self.tracer.occluded(points, wi, short)
        rest = np.flatnonzero(~blocked)
        if rest.size and self.lights.surfaces:
            blocked[rest] = self.lights.occluded(points[rest], wi[rest], short[rest])
        return ~blocked

    def _shade(self, origins: np.ndarray, directions: np.ndarray, prim: np.ndarray, t: np.ndarray, bu: np.ndarray,
               bv: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Outgoing radiance (M, 3) at the first hits of rays: path tracing with MIS (module docstring)."""
        m = origins.shape[0]
        out = np.zeros((m, 3))
        throughput = np.ones((m, 3))
        ray_index = np.arange(m)
        for depth in range(self.bounces + 1):
            if ray_index.size == 0:
                break
            k = ray_index.size
            hits = origins + t[:, None] * directions
            surface = self.surfaces.at(prim, bu, bv, t, self._primary_spread if depth == 0 else BOUNCE_SPREAD)
            normals = self.tracer.normals[prim]
            flip = np.einsum("ij,ij->i", normals, directions) > 0
            normals = np.where(flip[:, None], -normals, normals)
            points = hits + self.tracer.offset(hits)[:, None] * normals
            wo = -directions
            bsdf = Bsdf(normals, wo, surface.albedo, surface.f0, surface.roughness)
            out_add = surface.emission.copy()
            out_add += self._direct(points, bsdf, rng)
            # BSDF continuation: also the BSDF half of the MIS estimate of lights and dome at this vertex
            wi, weight, pdf_b = bsdf.sample(rng.random((k, 3)))
            alive = (pdf_b > 0) & (weight.max(axis=1) > 0)
            prim2 = np.full(k, -1, dtype=np.int64)
            t2 = np.full(k, FAR)
            bu2 = np.zeros(k)
            bv2 = np.zeros(k)
            ai = np.flatnonzero(alive)
            if ai.size:
                p2, tt, uu, vv = self._intersect(points[ai], wi[ai])
                prim2[ai], t2[ai], bu2[ai], bv2[ai] = p2, tt, uu, vv
                found, on_light = self._emitted_along(points[ai], wi[ai], tt, p2 < 0, pdf_b[ai])
                out_add[ai] += weight[ai] * found
                prim2[ai[on_light]] = -1  # light shapes are opaque and do not reflect: the path ends there
            out[ray_index] += throughput * out_add
            if depth == self.bounces:
                break
            throughput = throughput * weight
            keep = alive & (prim2 >= 0)
            if depth + 1 > RR_START:
                q = np.minimum(0.95, throughput.max(axis=1))
                survive = rng.random(k) < q
                keep &= survive
                throughput = throughput / np.maximum(q, 1e-300)[:, None]
            ray_index = ray_index[keep]
            throughput = throughput[keep]
            origins, directions = points[keep], wi[keep]
            prim, t, bu, bv = prim2[keep], t2[keep], bu2[keep], bv2[keep]
        return out

    def _emitted_along(self, points: np.ndarray, wi: np.ndarray, t: np.ndarray, escaped: np.ndarray,
                       pdf_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radiance (M, 3) a BSDF-sampled ray finds at a light shape, the dome or a distant disc, weighted by the
        power heuristic against the next-event pdfs, and whether the ray ended on a light shape (M,)."""
        m = points.shape[0]
        result = np.zeros((m, 3))
        on_light = np.zeros(m, dtype=bool)
        if self.lights.surfaces:
            t_l, which, l_l = self.lights.nearest(points, wi)
            on_light = (which >= 0) & (t_l < t)
            for k, model in enumerate(self.lights.surfaces):
                sel = np.flatnonzero(on_light & (which == k))
                if sel.size:
                    pdf_l = model.pdf(points[sel], wi[sel], t_l[sel])
                    result[sel] += l_l[sel] * _power(pdf_b[sel], pdf_l)[:, None]
            escaped = escaped & ~on_light
        ei = np.flatnonzero(escaped)
        if ei.size == 0:
            return result, on_light
        w_dirs = wi[ei]
        if not self.dome.black:
            rest = self.dome.rest_radiance(w_dirs)
            result[ei] += rest * _power(pdf_b[ei], self._dome_pdf(points[ei], w_dirs))[:, None]
            if self.dome.has_sun:
                result[ei] += self.dome.sun_radiance(w_dirs) * _power(pdf_b[ei], self.dome.sun_pdf(w_dirs))[:, None]
        for light in self.distant:
            if not light.delta:
                result[ei] += light.escaped(w_dirs) * _power(pdf_b[ei], light.pdf(points[ei], w_dirs, None))[:, None]
        return result, on_light

    def _direct(self, points: np.ndarray, bsdf: Bsdf, rng: np.random.Generator) -> np.ndarray:
        """Next-event estimates (M, 3) of every light, the dome's rest and its sun (MIS-weighted, shadowed)."""
        m = points.shape[0]
        total = np.zeros((m, 3))
        for model in self.lights.models:
            s = model.sample(points, rng.random((m, 2)))
            total += self._nee(points, bsdf, s.wi, s.distance, s.radiance, s.pdf,
                               can_hit=model.visible and not (isinstance(model, DistantLightModel) and model.delta))
        if not self.dome.black:
            if self.portals:
                u = rng.random((m, 4))
                wi, _radiance, _pdf = self.dome.sample_rest(u[:, :3])
                through = u[:, 3] < 0.5
                if through.any():
                    k = np.flatnonzero(through)
                    which = (u[k, 3] * 2.0 * len(self.portals)).astype(np.int64).clip(0, len(self.portals) - 1)
                    for j, portal in enumerate(self.portals):
                        sel = k[which == j]
                        if sel.size:
                            wi[sel] = portal.sample(points[sel], rng.random((sel.size, 2))).wi
                radiance = self.dome.rest_radiance(wi)
                pdf = self._dome_pdf(points, wi)
            else:
                wi, radiance, pdf = self.dome.sample_rest(rng.random((m, 3)))
            total += self._nee(points, bsdf, wi, np.full(m, FAR), radiance, pdf, can_hit=True)
            if self.dome.has_sun:
                wi, radiance, pdf = self.dome.sample_sun(rng.random((m, 3)))
                total += self._nee(points, bsdf, wi, np.full(m, FAR), radiance, pdf, can_hit=True)
        return total

    def _dome_pdf(self, points: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """Solid-angle pdf of the dome-rest next-event strategy: the dome's importance sampling, or with portals the
        mixture ½ p_dome + ½ (1/K) Σ_k p_portal_k (uniform area sampling of one of K portals)."""
        pdf = self.dome.rest_pdf(wi)
        if not self.portals:
            return pdf
        through = np.zeros(wi.shape[0])
        for portal in self.portals:
            t, _ = portal.intersect(points, wi)
            hit = t < FAR
            if hit.any():  # the density of uniform area sampling, from either side of the portal
                cos = np.abs(wi[hit] @ portal.axes[2])
                through[hit] += t[hit] ** 2 / (portal.light.area * np.maximum(cos, 1e-300))
        return 0.5 * pdf + 0.5 * through / len(self.portals)

    def _nee(self, points: np.ndarray, bsdf: Bsdf, wi: np.ndarray, dist: np.ndarray, radiance: np.ndarray,
             pdf: np.ndarray, can_hit: bool) -> np.ndarray:
        m = points.shape[0]
        result = np.zeros((m, 3))
        valid = (pdf > 0) & (radiance.max(axis=1) > 0)
        idx = np.flatnonzero(valid)
        if idx.size == 0:
            return result
        value, pdf_b = bsdf.take(idx).evaluate(wi[idx])
        good = value.max(axis=1) > 0
        idx, value, pdf_b = idx[good], value[good], pdf_b[good]
        if idx.size == 0:
            return result
        visible = self._visible(points[idx], wi[idx], dist[idx])
        idx, value, pdf_b = idx[visible], value[visible], pdf_b[visible]
        p = pdf[idx]
        weight = _power(p, pdf_b) if can_hit else np.ones(idx.size)
        inv = np.where(np.isinf(p), 1.0, 1.0 / np.where(np.isinf(p), 1.0, p))
        result[idx] = value * radiance[idx] * (weight * inv)[:, None]
        return result

    # ------------------------------------------------------------------------------------------------------------
    def _splat_distant(self, light: Light, face_size: int) -> bool:
        """Whether a distant light is splatted (disc smaller than a texel) rather than ray-seen."""
        alpha = np.radians(0.5 * light.angle)
        disc = 2.0 * np.pi * (1.0 - np.cos(alpha))
        return disc < cube_mean_texel_solid_angle(face_size)

    def _add_sun(self, cube: np.ndarray, position: np.ndarray) -> np.ndarray:
        """Splat the dome's sun points that the probe sees (bilinear, flux-exact)."""
        if self.dome.black or not self.dome.has_sun:
            return cube
        directions, flux = self.dome.sun_points()
        origins = np.broadcast_to(position, directions.shape)
        seen = self._visible(origins, directions, np.full(directions.shape[0], FAR))
        if not seen.any():
            return cube
        return self._splat(cube, directions[seen], flux[seen])

    def _splat(self, cube: np.ndarray, directions: np.ndarray, flux: np.ndarray) -> np.ndarray:
        n = cube.shape[1]
        flux_cube = np.zeros((6 * n * n, 3))
        splat_bilinear(flux_cube, directions, flux)
        return cube + (flux_cube / cube_texel_solid_angles(n).reshape(-1, 1)).reshape(cube.shape)

    def _add_distant_lights(self, cube: np.ndarray, position: np.ndarray) -> np.ndarray:
        n = cube.shape[1]
        for light in self.distant:
            if not self._splat_distant(light.light, n):
                continue
            d = light.direction[None, :]
            if not self._visible(position[None, :], d, np.array([FAR]))[0]:
                continue
            cube = self._splat(cube, d, light.illuminance[None, :])
        return cube


def _relative_sh_noise(sub_sh: np.ndarray, extra_dc: float = 0.0) -> float:
    """‖standard error of the mean SH‖ / |mean SH₀₀| from K independent sub-estimates (K, 9) of the ray-traced
    part, plus the SH₀₀ of the deterministic part (splats)."""
    k = sub_sh.shape[0]
    if k < 2:
        return math.inf
    mean = sub_sh.mean(axis=0)
    stderr = sub_sh.std(axis=0, ddof=1) / math.sqrt(k)
    dc = abs(float(mean[0]) + extra_dc)
    if dc <= 0:
        return 0.0 if not np.any(stderr > 0) else math.inf
    return float(np.linalg.norm(stderr) / dc)


def capture_probe_cube(
    scene: CaptureScene, position: np.ndarray, face_size: int, name: str, samples: int = 4,
    bounces: int = DEFAULT_BOUNCES,
) -> np.ndarray:
    """Convenience: radiance cube (6, N, N, 3) of one probe (builds the Embree scene; prefer
    :class:`ProbeRenderer` for many probes)."""
    renderer = ProbeRenderer(scene, samples=samples, bounces=bounces)
    cube, _ = renderer.render(position, face_size, name)
    return cube
