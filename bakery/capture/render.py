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
    At every hit: emission of the surface (weighted by the power heuristic against the emissive triangles'
    next-event pdf, except where a camera ray hits it), next-event estimation of every analytic light (or of
    lights drawn from a BVH, "Many lights" below)
    (:mod:`bakery.capture.lights`), of the dome's rest and of its sun, and of the emissive triangles
    (:mod:`bakery.capture.emitters`), each with a shadow ray against the triangles and the (opaque) light shapes;
    and a BSDF-sampled continuation ray
    (:class:`bakery.capture.bsdf.Bsdf`). A continuation ray that reaches a light shape, the dome or a distant light's
    disc adds that radiance with the power-heuristic weight against the light's next-event pdf, and ends; one that
    hits a surface continues. ``bounces`` is the largest number of continuations (0: direct light only); after
    bounce :data:`RR_START`, paths are ended by Russian roulette with survival probability min(0.95, max
    throughput) (unbiased), so the default (:data:`DEFAULT_BOUNCES`) converges closed rooms.

Small lights
    A light shape whose bounding sphere's angular radius from the probe is at most SPLAT_LIGHT_TEXELS texel
    half-widths (a bulb across the room) would be found by a few of the probe's camera rays, each carrying its full
    radiance: most of a lamp-lit probe's noise (measured on examples/plaza: relative SH noise 0.12–0.51, 0.02–0.04
    with the splat). Such a light is sampled from the probe instead (:meth:`ProbeRenderer._add_small_lights`): a
    stratified grid of next-event samples, each shadow-tested and splatting its flux L·V/(pdf·K) bilinearly at its
    direction (flux-exact, as the sun's points), and the probe's camera rays end on its shape without its light.
    Bounce rays and next-event estimation see it as before.

Many lights (:mod:`bakery.capture.light_tree`)
    Above ``ENUMERATED_LIGHTS`` non-distant lights, next-event estimation draws ``LIGHT_SAMPLES`` lights per
    vertex instead of sampling every light (:meth:`ProbeRenderer._sample_drawn`), from the light grid's
    distribution of the vertex's cell (the light BVH's off the grid's surfaces): sample j of light ℓ has pdf
    K·P(ℓ | x)·pdf_ℓ(ω), which the power heuristic also uses for BSDF rays that reach ℓ's shape
    (:meth:`ProbeRenderer._drawn_pdf`). Distant lights, the dome and the emissive triangles keep their strategies.
    Every per-strategy property (linking, shadows, multipliers) is a row of one table
    (:meth:`ProbeRenderer._strategy_tables`), indexed per slot — or per point for the drawn lights.

Noise and adaptive sampling
    Each of the S rays of a texel gives an independent one-ray estimate of the cube; the spread of their luminance
    SH (bands ≤ 2) gives the standard error of the probe's SH. ``sh_noise`` = ‖σ(SH)‖ / |SH₀₀| (relative). With
    ``target_noise`` > 0 the renderer adds passes of S rays per texel until the noise is below it or
    ``max_samples`` rays per texel are spent.

Batching and precision (issue 14)
    :meth:`ProbeRenderer.render_many` renders several probes together: each pass of each probe is cut into chunks
    of at most :data:`BATCH` camera rays, and chunks of different probes share one call of the path tracer (up to
    :data:`CALL_RAYS` camera rays). Each bounce shades all live paths of the call as one batch: next-event samples
    of every light, the dome's rest and its sun form one (3, J, M) array, evaluated by the BSDF in one call, culled
    against the light shapes' bounding spheres and traced in one Embree occlusion query; continuations are one
    closest-hit query. Per-ray arrays are float32 structure-of-arrays (:mod:`bakery.capture.vec`); sums over rays
    are float64. A light's own shape is not tested as an occluder of its own samples (convex shapes cannot shadow
    their own facing points; this also removes float32 self-shadowing).

Determinism
    Randomness comes from ``numpy.random.default_rng(seed)`` per probe, with the seed derived from the probe's name
    (:func:`probe_seed`). A batch's random numbers are drawn probe by probe from each probe's own generator, as
    many as it has rays, in a fixed order (per pass, chunk, bounce and strategy), and concatenated
    (:class:`_Owners`); per-ray arithmetic is element by element (no BLAS, no reductions over the rays of a batch;
    even the BSDF's sharp-lobe form is chosen per point), Embree answers each ray on its own, and each probe's
    cube, SH noise and ray count are accumulated apart. So a probe's capture is bit-identical across runs, batch
    compositions and orders, batch sizes and worker counts (``tests/capture/test_capture_batched.py``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bakery.capture.bsdf import Bsdf
from bakery.capture.dome import DomeSampler, bilinear_weights, splat_bilinear
from bakery.capture.emitters import EmissiveTriangles
from bakery.capture.lights import (
    SHADOW_EPSILON,
    DistantLightModel,
    LightSet,
    RectLightModel,
    LightSampler,
)
from bakery.capture.light_tree import ENUMERATED_LIGHTS, LIGHT_SAMPLES, LightBVH, LightGrid
from bakery.capture.scene import CaptureScene, Dome, Light
from bakery.capture.surfaces import BOUNCE_SPREAD, Surfaces
from bakery.capture.tracer import FAR, SceneTracer
from bakery.capture.validity import Relocator, back_facing, triangle_fronts
from bakery.capture.vec import REAL, TINY, dot, dotc, luminance, power, vmax
from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.files import sha256_bytes
from bakery.sh.basis import evaluate_sh_basis
from bakery.sphere.cubemap import (
    _FACE_FRAMES,
    cube_mean_texel_solid_angle,
    cube_texel_directions,
    cube_texel_solid_angles,
)

#: Default largest number of bounces (continuations); Russian roulette ends paths long before.
DEFAULT_BOUNCES = 64
#: Version of what the capture models: part of every scene probe's content hash (:func:`bakery.pipeline.
#: dependencies.environment_hash`), bumped whenever the same scene and settings capture differently, so a store
#: baked before is re-baked rather than reused. 2: partial opacity as presence (was opaque), MaterialX transmission,
#: shading normals, Cylinder/Cone/Capsule/Plane gprims. 3: UsdLux spec audit (docs/capture.md "UsdLux
#: interpretation"): RectLight textures with column 0 at local +X (were mirrored), point lights (treatAsPoint,
#: radius 0) seen by probes, DistantLight angle/normalize per UsdLux. (Splatted small light shapes are versioned
#: apart, for the scenes that have light shapes: :data:`bakery.pipeline.dependencies.SMALL_LIGHT_SPLAT_VERSION`.)
#: 4: UsdPreviewSurface spec audit (tests/capture/test_bsdf_spec.py): a metal's F90 is its albedo, F90 = mix(white,
#: diffuseColor, metallic) (was white), and the clearcoat's F0 comes from ``ior`` (was 0.04 whatever the ior).
#: 5: MaterialX surface audit (tests/capture/test_mtlx_surface_spec.py): open_pbr_surface's specular_weight scales
#: the dielectric's F0 alone through the modulated IOR (was F0 and F90) and a coated base reflects at the
#: specular/coat IOR ratio (was specular_ior); MaterialX dielectrics' Schlick F90 is the exact Fresnel's
#: hemispherical-mean one (IORs below ≈ 1.34; was min(1, 50·F0)). 6: MaterialX metals as their graphs wire them
#: (bakery.capture.bsdf "MaterialX metals"): open_pbr's F82 tint and specular_weight, standard_surface's conductor
#: of the artistic IOR (was Schlick(base_color, 1) for both), gltf_pbr's dielectric F90 = specular at every IOR.
#: 7: MaterialX layering and energy compensation (bakery.capture.bsdf "MaterialX layering"): the base under the
#: specular layer and under the coat keeps 1 − w·E(θo)·(1 + k·F) (was 1 − F(v·h)), and GGX lobes carry Turquin's
#: 1 + k·F; UsdPreviewSurface unchanged.
CAPTURE_MODEL_VERSION = 7
#: A visible light shape whose bounding sphere's angular radius, seen from the probe, is at most this many texel
#: half-widths is seen through a splat of its sampled flux instead of by the probe's camera rays (module docstring
#: "Small lights").
SPLAT_LIGHT_TEXELS = 2.0
#: Side of the stratified grid of flux samples of a splatted light at that limit (fewer for smaller lights, ≥ 4:
#: partial occlusion is resolved to 1/16 of a light at least).
SPLAT_LIGHT_GRID = 8
#: Bounces up to this one are never ended by Russian roulette (exact); later ones may be.
RR_START = 3
#: Camera rays per chunk of a probe's pass (memory bound for large faces × samples; fixes the order of its random
#: numbers, so changing it changes captures).
BATCH = 1 << 17
#: Camera rays per call of the path tracer (chunks of several probes traced together; a memory bound, free to tune):
#: 8 probes of face 32 at 4 rays per texel, and one chunk of :data:`BATCH` rays at large faces (whose peak memory is
#: that of one probe's chunk, as before batching).
CALL_RAYS = 3 << 16


def probe_seed(name: str, base_seed: int = 0) -> int:
    """Stable 63-bit seed from a probe identity (SHA-256 of the name, mixed with ``base_seed``)."""
    digest = bytes.fromhex(sha256_bytes(f"{base_seed}:{name}".encode())[:16])
    return int.from_bytes(digest, "little") & ((1 << 63) - 1)


@dataclass(frozen=True)
class _StrategyTables:
    """Next-event strategy properties by row (R = analytic lights, then the dome's rest, its sun, the emissive
    triangles): ``lobes`` (R, 2) diffuse/specular multipliers, ``shadowless`` (R,), ``nee_only`` (R,) found by
    next-event estimation alone (no MIS), ``shape`` (R,) index of the light's own shape among the light surfaces
    (−1: none), and, when any strategy has them, ``links``/``casters`` (R, meshes) bool, ``ranges`` (R, 3) ShadowAPI
    (d, f, γ) and ``shadow_color`` (R, 3); None otherwise."""

    lobes: np.ndarray
    shadowless: np.ndarray
    nee_only: np.ndarray
    shape: np.ndarray
    links: np.ndarray | None
    casters: np.ndarray | None
    ranges: np.ndarray | None
    shadow_color: np.ndarray | None


@dataclass(frozen=True)
class CaptureStats:
    """Work done by one capture: rays traced, wall time (seconds), rays per texel spent, the achieved SH noise, and
    the share of the probe's camera rays whose first hit is the back of a single-sided surface (``Mesh.front``):
    near 0 in open space, 1 inside a closed mesh — the measure of probe validity in Majercik et al., "Scaling
    Probe-Based Real-Time Dynamic Global Illumination for Production" (JCGT 10(2), 2021), Sec. 4 (backface
    fraction, threshold 25 %), and Unity's probe validity."""

    rays: int
    seconds: float
    samples: int = 0
    sh_noise: float = 0.0
    backface_fraction: float = 0.0
    #: capture position − probe position (metres, bake frame): non-zero for a probe relocated out of geometry
    #: (:mod:`bakery.capture.validity`)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def rays_per_second(self) -> float:
        return self.rays / self.seconds if self.seconds > 0 else 0.0


def _face_frame_columns() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cube faces' axis, u and v vectors as float32 (3, 1, 6, 1) arrays (broadcast over (S, 6, N·N))."""
    frames = np.asarray(_FACE_FRAMES, dtype=REAL)  # (6, 3 vectors, 3)
    return tuple(np.ascontiguousarray(frames[:, k].T).reshape(3, 1, 6, 1) for k in range(3))


_FACE_AXIS, _FACE_DU, _FACE_DV = _face_frame_columns()


def _jittered_texel_directions(face_size: int, samples: int, rng: np.random.Generator) -> np.ndarray:
    """(3, samples, 6, N, N) float32 unit directions through jittered points of every texel (structure of arrays).

    The ``samples`` points of a texel are a Latin hypercube: sample j takes the u-stratum j and a random v-stratum
    (a per-texel permutation), jittered uniformly inside its stratum cell, so every texel's u and v are each
    stratified into ``samples`` intervals (lower variance than independent jitter, same expectation). Directions
    are those of :func:`bakery.sphere.cubemap.cube_face_uv_to_direction`.
    """
    n = face_size
    jitter = rng.random((samples, 6, n, n, 2))
    strata_u = np.arange(samples, dtype=np.float64)[:, None, None, None]
    strata_v = rng.permuted(np.broadcast_to(strata_u, (samples, 6, n, n)), axis=0)
    idx = np.arange(n, dtype=np.float64)
    u = ((idx + (strata_u + jitter[..., 0]) / samples) / n * 2.0 - 1.0).astype(REAL)
    v = ((idx[:, None] + (strata_v + jitter[..., 1]) / samples) / n * 2.0 - 1.0).astype(REAL)
    shape = (samples, 6, n * n)
    d = _FACE_AXIS + u.reshape(shape) * _FACE_DU + v.reshape(shape) * _FACE_DV
    return (d / np.sqrt(dot(d, d))).reshape(3, samples, 6, n, n)


def _shadow_range(light: Light | Dome) -> tuple[float, float, float] | None:
    """(d, f, γ) of a light's ShadowAPI shadow distance (:attr:`Light.shadow_distance`), or None (unlimited)."""
    distance = float(getattr(light, "shadow_distance", -1.0))
    if distance <= 0:
        return None
    return distance, max(float(light.shadow_falloff), 0.0), float(light.shadow_falloff_gamma)


def shadow_strength(t: np.ndarray, distance: np.ndarray, falloff: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """UsdLuxShadowAPI: the strength (…) of a shadow cast by an occluder at distance t from the shaded point —
    1 nearer than d − f, ((d − t)/f)^γ in the falloff zone, 0 from d on (f = 0: no zone)."""
    start = distance - falloff
    with np.errstate(divide="ignore", invalid="ignore"):
        ramp = np.clip((distance - t) / np.where(falloff > 0, falloff, 1), 0, 1) ** gamma
    return np.where(t < start, 1, np.where(t < distance, ramp, 0)).astype(REAL, copy=False)


def _take(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Columns ``index`` of a (3, M) array (one gather per call, contiguous result)."""
    return np.take(a, index, axis=1)


def _add_at(a: np.ndarray, index: np.ndarray, value: np.ndarray) -> None:
    """a[:, index] += value for unique ``index`` (row by row: 1-D fancy indexing is the fast path)."""
    for c in range(3):
        row = a[c]
        row[index] += value[c]


class _Owners:
    """Which probe of a renderer call each ray of a (3, M) batch belongs to, the probes' generators and their counts
    of rays traced.

    Rays are grouped by probe (``owner`` non-decreasing: compaction by sorted indices keeps that). Random numbers
    are drawn per probe, as many as it has rays, from its own generator and concatenated, so a probe draws the same
    numbers in the same order whatever else shares the batch."""

    def __init__(self, rngs: list[np.random.Generator], owner: np.ndarray, rays: np.ndarray | None = None) -> None:
        self.rngs = rngs
        self.owner = owner  #: (M,) index into ``rngs``
        self.rays = np.zeros(len(rngs), dtype=np.int64) if rays is None else rays  #: (P,) shared by every take

    @classmethod
    def single(cls, rng: np.random.Generator, m: int = 0) -> _Owners:
        return cls([rng], np.zeros(m, dtype=np.int64))

    def take(self, index: np.ndarray) -> _Owners:
        """The owners of the rays ``index`` (sorted, to keep them grouped)."""
        return _Owners(self.rngs, np.take(self.owner, index), self.rays)

    def random(self, *lead: int, dtype: type = REAL) -> np.ndarray:
        """Uniform numbers (*lead, M), each probe's columns from its own generator."""
        if len(self.rngs) == 1:
            return self.rngs[0].random(lead + (self.owner.size,), dtype=dtype)
        edges = np.searchsorted(self.owner, np.arange(len(self.rngs) + 1))
        return np.concatenate([rng.random(lead + (int(b - a),), dtype=dtype)
                               for rng, a, b in zip(self.rngs, edges[:-1], edges[1:])], axis=-1)

    def traced(self, index: np.ndarray | None = None) -> None:
        """Count the rays traced: all M, or those of ``index`` (into the M, any order)."""
        if len(self.rngs) == 1:
            self.rays[0] += self.owner.size if index is None else index.size
        else:
            owner = self.owner if index is None else np.take(self.owner, index)
            self.rays += np.bincount(owner, minlength=len(self.rngs))


def _pack_chunks(probes: list[int], count: int) -> list[list[tuple[int, int, int]]]:
    """Calls of the path tracer for a pass of ``count`` camera rays of each of ``probes``: lists of (probe, start,
    stop) chunks, at most :data:`CALL_RAYS` rays and one chunk of a probe per call, each probe's chunks in order
    (so its random numbers are drawn in the same order as when it is rendered alone)."""
    chunks = [(p, start, min(count, start + BATCH)) for start in range(0, count, BATCH) for p in probes]
    calls: list[list[tuple[int, int, int]]] = []
    size = 0
    for chunk in chunks:
        rays = chunk[2] - chunk[1]
        if not calls or size + rays > CALL_RAYS or any(c[0] == chunk[0] for c in calls[-1]):
            calls.append([])
            size = 0
        calls[-1].append(chunk)
        size += rays
    return calls


class ProbeRenderer:
    """Renders radiance cubes of probes in one scene (the Embree scene is built once and shared).

    The path tracer works on structure-of-arrays float32 batches (:mod:`bakery.capture.vec`): every bounce of all
    camera rays of a call (:meth:`render_many`: chunks of several probes) is one batch, its next-event samples of
    every light are evaluated and traced together (one BSDF evaluation and one Embree occlusion query per bounce),
    and no Python code runs per ray.
    """

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
        #: emissive triangles sampled as area lights (:mod:`bakery.capture.emitters`), or None when nothing emits
        self.emitters = EmissiveTriangles.of(self.surfaces, self.tracer)
        self._front_soa = triangle_fronts(scene, self.tracer)
        self.relocator = Relocator(self.tracer, self._front_soa)
        self.dome = DomeSampler(scene.dome)
        self.lights = LightSet(scene.lights, scene.textures)
        self.distant = self.lights.distant
        self._primary_spread = BOUNCE_SPREAD
        self._basis: dict[int, np.ndarray] = {}  # per face size: SH basis × texel solid angle (6·N·N, 9)
        self._omega: dict[int, np.ndarray] = {}  # per face size: texel solid angles (6·N·N, 1)
        # per face size: the sun points (3, K) float32 and their bilinear splat (indices, weights (4, K); flux (K, 3))
        self._sun_splat: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        # PortalLights: rects through which the dome is also sampled (a sampling guide; the dome itself is unchanged)
        self.portals = tuple(RectLightModel(dataclasses.replace(p, visible=True)) for p in scene.portals
                             if p.kind == "rect" and p.size[0] * p.size[1] > 0)
        # next-event strategies of the analytic lights: whether a BSDF ray can also find the light (MIS) and the
        # light's index among the shapes (a light's own shape is not tested as an occluder of its samples)
        surfaces = {id(m): k for k, m in enumerate(self.lights.surfaces)}
        self._light_can_hit = [bool(m.visible and not (isinstance(m, DistantLightModel) and m.delta))
                               for m in self.lights.models]
        self._light_shape = [surfaces.get(id(m), -1) for m in self.lights.models]
        self._model_strategy = {id(m): j for j, m in enumerate(self.lights.models)}
        self._surface_strategy = [self._model_strategy[id(m)] for m in self.lights.surfaces]
        # UsdLux's diffuse/specular multipliers per emitter (the lobes are weighted apart only when one is ≠ 1, so
        # scenes without them shade exactly as before) and ShadowAPI per analytic light
        dome = scene.dome
        self._dome_lobes = (1.0, 1.0) if dome is None else (float(dome.diffuse), float(dome.specular))
        self._light_lobes = [(float(m.light.diffuse), float(m.light.specular)) for m in self.lights.models]
        self._lobes = any(x != (1.0, 1.0) for x in [*self._light_lobes, self._dome_lobes])
        # UsdLux light linking: per emitter, the meshes it illuminates (bool per mesh), or None for all
        meshes = np.arange(len(scene.meshes))
        self._light_links = [None if m.light.links is None else np.isin(meshes, m.light.links)
                             for m in self.lights.models]
        self._dome_links = None if dome is None or dome.links is None else np.isin(meshes, dome.links)
        self._linking = any(x is not None for x in [*self._light_links, self._dome_links])
        self._shadowless = [not m.light.shadow for m in self.lights.models]
        # UsdLux shadow linking: per analytic light, the meshes that cast its shadows (bool per mesh), or None for all
        self._casters = [None if m.light.shadow_links is None else np.isin(meshes, m.light.shadow_links)
                         for m in self.lights.models]
        #: lights sampled by next-event estimation alone, without MIS: a BSDF-sampled ray cannot pass the meshes
        #: their shadow rays pass (shadowless, or shadow-linked), so it must not count them
        # ShadowAPI shadow:distance/falloff/falloffGamma per analytic light, then the dome's: (d, f, γ) or None
        self._shadow_ranges = [_shadow_range(m.light) for m in self.lights.models]
        self._dome_shadow_range = None if dome is None else _shadow_range(dome)
        self._nee_only = [shadowless or casters is not None or ranged is not None
                          for shadowless, casters, ranged in zip(self._shadowless, self._casters, self._shadow_ranges)]
        self._dome_casters = None if dome is None or dome.shadow_links is None else np.isin(meshes, dome.shadow_links)
        # ShadowAPI on the dome: shadowless, or a shadow colour, as for the analytic lights
        self._dome_shadowless = dome is not None and not dome.shadow
        self._dome_shadow_color = (0.0, 0.0, 0.0) if dome is None or not dome.shadow else tuple(
            map(float, dome.shadow_color))
        self._dome_nee_only = (self._dome_casters is not None or self._dome_shadowless
                               or self._dome_shadow_range is not None)
        self._shadow_color = [tuple(map(float, m.light.shadow_color)) if m.light.shadow else (0.0, 0.0, 0.0)
                              for m in self.lights.models]
        self._tables: _StrategyTables | None = None
        # many lights (module docstring): above ENUMERATED_LIGHTS non-distant lights they are drawn from the light grid
        drawn = [j for j, m in enumerate(self.lights.models) if not isinstance(m, DistantLightModel)]
        self._light_grid = None
        self._drawn_models = np.zeros(0, dtype=np.int64)  # drawn light (grid/BVH index) → index into lights.models
        self._drawn_index: dict[int, int] = {}  # index into lights.models → drawn light
        if len(drawn) > ENUMERATED_LIGHTS:  # drawn per region (O(1)), from the BVH outside the grid
            boxes = [(m.triangles.min(axis=1), m.triangles.max(axis=1)) for m in scene.meshes]
            self._light_grid = LightGrid(LightBVH([self.lights.models[j].tree_bound() for j in drawn]),
                                   np.concatenate([b[0] for b in boxes]) if boxes else np.zeros((0, 3)),
                                   np.concatenate([b[1] for b in boxes]) if boxes else np.zeros((0, 3)))
            self._drawn_models = np.array(drawn, dtype=np.int64)
            self._drawn_index = {j: leaf for leaf, j in enumerate(drawn)}
        self._drawn_sampler = LightSampler([self.lights.models[j] for j in self._drawn_models])  # by drawn light
        self._enumerated = [j for j in range(len(self.lights.models)) if j not in self._drawn_index]
        # the light surfaces' culling spheres and their sampler (the small-light splat)
        surfaces = self.lights.surfaces
        self._surface_spheres = (np.array([m.centre for m in surfaces]).reshape(-1, 3),
                                 np.array([m.bounding_radius for m in surfaces], dtype=np.float64))
        self._surface_sampler = LightSampler(surfaces)

    # ------------------------------------------------------------------------------------------------------------
    def prepare(self, face_size: int) -> None:
        """Build the per-face-size caches (the dome's rest filtered over the cube's texels, the sun's splat, the SH
        basis) ahead of the first :meth:`render` at that size (they are built once per renderer either way; results
        do not depend on when)."""
        if not self.dome.black:
            self.dome.filtered_cube(face_size)
            if self.dome.has_sun:
                self._sun_points(face_size)
        self._sh_basis(face_size)

    def _sh_basis(self, n: int) -> np.ndarray:
        """SH basis (bands ≤ 2) × texel solid angle at the texel centres of an N cube: (6·N·N, 9)."""
        basis = self._basis.get(n)
        if basis is None:
            basis = self._basis[n] = evaluate_sh_basis(cube_texel_directions(n).reshape(-1, 3), 2) * \
                cube_texel_solid_angles(n).reshape(-1, 1)
        return basis

    def render(self, position: np.ndarray, face_size: int, name: str, search_radius: float = 0.0
               ) -> tuple[np.ndarray, CaptureStats]:
        """Radiance cube (6, N, N, 3) float32 seen from ``position`` (bake frame, metres), and its stats: the one
        probe of :meth:`render_many`."""
        return self.render_many([position], face_size, [name], [search_radius])[0]

    def render_many(self, positions: Sequence[np.ndarray], face_size: int, names: Sequence[str],
                    search_radii: Sequence[float] | None = None) -> list[tuple[np.ndarray, CaptureStats]]:
        """Radiance cubes (6, N, N, 3) float32 seen from ``positions`` (each (3,), bake frame, metres) of the probes
        ``names``, and each probe's stats, in order. A probe with a search radius > 0 (``search_radii``) that is
        inside geometry is captured from its relocated position (:meth:`Relocator.capture_position`; the offset
        is in its stats).

        The probes' paths are traced and shaded together (module docstring, "Batching"): each pass of each probe is
        cut into chunks of at most :data:`BATCH` camera rays, and chunks of different probes share a call of the
        path tracer (up to :data:`CALL_RAYS` camera rays), so every bounce of the call is one Embree query for all
        of them. Every probe draws from its own generator and its rays are computed element by element, so its cube
        and stats (rays, samples, noise) are identical whatever it is rendered with; ``seconds`` is the call's time
        split over its probes in proportion to their rays. With ``target_noise`` a probe that reached it takes no
        further passes while the others go on. Memory: a pass holds 24 bytes per camera ray of every probe
        (directions and radiance), the path tracer's temporaries those of one call."""
        start_time = time.perf_counter()
        if len(positions) != len(names):
            raise ValueError(f"{len(positions)} positions for {len(names)} probe names")
        count = len(names)
        n = face_size
        texels = 6 * n * n
        self._primary_spread = math.sqrt(cube_mean_texel_solid_angle(n))
        filtered = None
        if not self.dome.black:
            filtered = np.ascontiguousarray(self.dome.filtered_cube(n).reshape(-1, 3).T, dtype=REAL)
        basis = self._sh_basis(n)
        rngs = [np.random.default_rng(probe_seed(name, self.base_seed)) for name in names]
        rays = np.zeros(count, dtype=np.int64)
        backfaces = np.zeros(count, dtype=np.int64)  # camera rays whose first hit is a back face, per probe
        given = [np.asarray(p, dtype=np.float64).reshape(3) for p in positions]
        radii = list(search_radii) if search_radii is not None else [0.0] * count
        searched = [self.relocator.capture_position(p, float(r)) for p, r in zip(given, radii)]
        origins = [position for position, _rays in searched]
        rays += np.array([cast for _position, cast in searched], dtype=np.int64)  # relocation searches
        extras, hidden = [], {}
        for p, origin in enumerate(origins):
            owners = _Owners.single(rngs[p])
            cube = self._add_distant_lights(self._add_sun(np.zeros((6, n, n, 3)), origin, owners), origin, owners)
            cube, hidden[p] = self._add_small_lights(cube, origin, owners)
            extras.append(cube)
            rays[p] += owners.rays[0]
        extra_dc = [float((e.reshape(-1, 3) @ LUMINANCE_WEIGHTS) @ basis[:, 0]) for e in extras]
        totals = [np.zeros((3, texels)) for _ in range(count)]
        sub_sh: list[list[np.ndarray]] = [[] for _ in range(count)]
        spent = [0] * count
        noise = [0.0] * count
        active = list(range(count))
        while active:
            radiance = self._trace_pass(active, origins, rngs, rays, n, filtered, backfaces, hidden)
            for p in active:
                per_sample = radiance[p].reshape(3, self.samples, texels)
                totals[p] += per_sample.sum(axis=1, dtype=np.float64)
                spent[p] += self.samples
                lum = luminance(per_sample.astype(np.float64))
                sub_sh[p].extend(list(lum @ basis))
                noise[p] = _relative_sh_noise(np.asarray(sub_sh[p]), extra_dc[p])
            active = [p for p in active if self.target_noise > 0 and noise[p] > self.target_noise
                      and spent[p] + self.samples <= self.max_samples]
        seconds = time.perf_counter() - start_time
        share = rays / max(int(rays.sum()), 1)
        return [(((totals[p] / spent[p]).T.reshape(6, n, n, 3) + extras[p]).astype(np.float32),
                 CaptureStats(int(rays[p]), seconds * float(share[p]), spent[p], noise[p],
                              float(backfaces[p]) / (spent[p] * texels),
                              tuple(float(x) for x in origins[p] - given[p]))) for p in range(count)]

    def _trace_pass(self, probes: list[int], origins: list[np.ndarray], rngs: list[np.random.Generator],
                    rays: np.ndarray, n: int, filtered: np.ndarray | None,
                    backfaces: np.ndarray, hidden: dict[int, np.ndarray | None] | None = None
                    ) -> dict[int, np.ndarray]:
        """One pass (``samples`` rays per texel) of each of ``probes`` (indices into ``origins``, ``rngs`` and the
        counters ``rays`` and ``backfaces``, which it adds to): radiance (3, S·6·N·N) float32 per probe,
        sample-major. ``hidden``: per probe, the light shapes its camera rays do not see (splatted; bool per
        light surface, or None)."""
        texels = 6 * n * n
        directions = {p: _jittered_texel_directions(n, self.samples, rngs[p]).reshape(3, -1) for p in probes}
        radiance = {p: np.empty(d.shape, dtype=REAL) for p, d in directions.items()}
        for call in _pack_chunks(probes, texels * self.samples):
            sizes = [stop - start for _, start, stop in call]
            owners = _Owners([rngs[p] for p, _, _ in call], np.repeat(np.arange(len(call)), sizes))
            d = np.concatenate([directions[p][:, start:stop] for p, start, stop in call], axis=1)
            o = np.repeat(np.asarray([origins[p] for p, _, _ in call], dtype=REAL).T, sizes, axis=1)
            texel = np.concatenate([np.arange(start, stop) % texels for _, start, stop in call])
            back = np.zeros(len(call), dtype=np.int64)
            shown = None if not hidden or all(hidden.get(p) is None for p, _, _ in call) else np.stack(
                [np.zeros(len(self.lights.surfaces), bool) if hidden.get(p) is None else hidden[p] for p, _, _ in call])
            result = self._camera(o, d, owners, n, filtered, texel, back, shown)
            offsets = np.cumsum([0] + sizes)
            for k, (p, start, stop) in enumerate(call):
                radiance[p][:, start:stop] = result[:, offsets[k]:offsets[k + 1]]
                rays[p] += owners.rays[k]
                backfaces[p] += back[k]
        return radiance

    def trace_camera_rays(self, origins: np.ndarray, directions: np.ndarray, rng: np.random.Generator,
                          face_size: int, filtered: np.ndarray | None = None,
                          texel: np.ndarray | None = None) -> np.ndarray:
        """Radiance (M, 3) arriving at ``origins`` from ``directions`` (both (M, 3)). Escaping rays see the rest of
        the dome filtered over their texel (flat index ``texel`` into a ``face_size`` cube of ``filtered`` (6, N,
        N, 3)) when ``filtered`` is given — the sun is then left out, as are distant lights smaller than a texel
        (:meth:`render` splats them) — else the whole dome point-sampled."""
        soa = None if filtered is None else np.ascontiguousarray(np.reshape(filtered, (-1, 3)).T, dtype=REAL)
        d = np.ascontiguousarray(np.asarray(directions).T, dtype=REAL)
        result = self._camera(np.ascontiguousarray(np.asarray(origins).T, dtype=REAL), d,
                              _Owners.single(rng, d.shape[1]), face_size, soa, texel)
        return np.ascontiguousarray(result.T, dtype=np.float64)

    def _camera(self, origins: np.ndarray, directions: np.ndarray, owners: _Owners, face_size: int,
                filtered: np.ndarray | None, texel: np.ndarray | None,
                backfaces: np.ndarray | None = None, hidden: np.ndarray | None = None) -> np.ndarray:
        """:meth:`trace_camera_rays` on (3, M) float32 rays of the probes ``owners``; ``filtered`` is the (3, 6·N·N)
        filtered dome. ``backfaces`` (one counter per owner), if given, is added the number of each owner's rays
        whose first hit (past what they pass through, before any light shape) is a back face. ``hidden`` (owners,
        light surfaces) bool: the splatted light shapes each owner's rays end on without seeing their emission."""
        m = origins.shape[1]
        if self.lights.surfaces:  # tints count up to the nearest light shape
            t_light, which, l_light = self.lights.nearest_soa(origins, directions)
            if hidden is not None:  # splatted (:meth:`_add_small_lights`): opaque, but their light is in the splat
                off = np.flatnonzero(which >= 0)
                off = off[hidden[np.take(owners.owner, off), which[off]]]
                l_light[:, off] = 0
        prim, t, bu, bv, tint = self._intersect_through(origins, directions, owners,
                                                        t_light if self.lights.surfaces else None)
        result = np.zeros((3, m), dtype=REAL)
        sees_light = np.zeros(m, dtype=bool)
        if self.lights.surfaces:
            sees_light = t_light < t
            si = np.flatnonzero(sees_light)
            if si.size:
                result[:, si] = _take(l_light, si)
        miss = np.flatnonzero((prim < 0) & ~sees_light)
        if miss.size:
            d = _take(directions, miss)
            if self.dome.black:
                seen = np.zeros((3, miss.size), dtype=REAL)
            elif filtered is not None and texel is not None:
                seen = _take(filtered, np.take(texel, miss))
            else:  # no texel filter given: point lookups of the whole dome, sun included
                seen = self.dome.rest_radiance_soa(d) + self.dome.sun_lookup_soa(d)[0]
            for light in self.distant:
                if not self._splat_distant(light.light, face_size):
                    seen += light.escaped_soa(d)
            result[:, miss] = seen
        hit = np.flatnonzero((prim >= 0) & ~sees_light)
        if backfaces is not None and hit.size:
            back = hit[back_facing(self.tracer.normals_soa, self._front_soa, np.take(prim, hit),
                                   _take(directions, hit))]
            backfaces += np.bincount(np.take(owners.owner, back), minlength=backfaces.size)
        if hit.size:
            result[:, hit] = self._shade(_take(origins, hit), _take(directions, hit), np.take(prim, hit),
                                         np.take(t, hit), np.take(bu, hit), np.take(bv, hit), owners.take(hit))
        if tint is not None:  # what the ray found behind the tinted surfaces it passed through
            result *= tint
        return result

    # ------------------------------------------------------------------------------------------------------------
    def _intersect(self, origins: np.ndarray, directions: np.ndarray, owners: _Owners
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest hit (prim, t, u, v) of rays (3, M) that is not passed through (opacity below the material's
        opacityThreshold, or not present: u ≥ opacity on materials of partial opacity); the rays are counted for
        their probes (``owners``, in any order)."""
        return self._intersect_through(origins, directions, owners)[:4]

    def _intersect_through(self, origins: np.ndarray, directions: np.ndarray, owners: _Owners,
                           limit: np.ndarray | None = None, casters: tuple[np.ndarray, np.ndarray] | None = None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """:meth:`_intersect` and the transmittance (3, M) float32 of the surfaces each ray passed through nearer
        than ``limit`` (M,) (all, if None): the product of their materials' ``transmission_tint``; None when no
        material of the scene tints (``Surfaces.tint_soa``). ``casters``: for shadow rays of shadow-linked
        lights, a (J, meshes) bool table and each ray's row (M,); a mesh whose entry is False is passed through
        untinted, as if absent."""
        prim, t, bu, bv = self.tracer.intersect_uv(origins, directions, soa=True)
        owners.traced()
        if not self.surfaces.cutout and casters is None:
            return prim, t, bu, bv, None
        tints = self.surfaces.tint_soa
        tint = None if tints is None else np.ones((3, prim.shape[0]), dtype=REAL)
        idx = np.flatnonzero(prim >= 0)  # hits not yet tested (a hit kept once stays: presence is drawn once)
        for _ in range(32):
            if idx.size == 0:
                break
            if self.surfaces.cutout:
                u = self._presence_numbers(owners, idx) if self.surfaces.stochastic else None
                cut = self.surfaces.cut(prim[idx], bu[idx].astype(np.float64), bv[idx].astype(np.float64), u)
            else:
                cut = np.zeros(idx.size, dtype=bool)
            absent = None
            if casters is not None:
                absent = ~casters[0][casters[1][idx], np.take(self.surfaces.mesh_of_soa, prim[idx])]
                cut |= absent
            if not cut.any():
                break
            j = idx[cut]
            if tint is not None:
                jt = j if absent is None else j[~absent[cut]]
                jt = jt if limit is None else jt[t[jt] < limit[jt]]
                tint[:, jt] *= np.take(tints, np.take(self.surfaces.mesh_of_soa, prim[jt]), axis=1)
            dj = _take(directions, j)
            hits = _take(origins, j) + t[j] * dj
            off = self.tracer.offset_soa(hits)
            p2, t2, u2, v2 = self.tracer.intersect_uv(hits + off * dj, dj, soa=True)
            owners.traced(j)
            prim[j], bu[j], bv[j] = p2, u2, v2
            t[j] = np.where(p2 >= 0, t2 + t[j] + off, FAR)
            idx = j[p2 >= 0]
        return prim, t, bu, bv, tint

    @staticmethod
    def _presence_numbers(owners: _Owners, idx: np.ndarray) -> np.ndarray:
        """Uniform numbers (K,) for the rays ``idx`` whose owners may be in any order (shadow rays come strategy
        by strategy): drawn from each probe's generator in its rays' order (a stable sort by owner), so a probe
        draws the same numbers whatever shares the batch."""
        order = np.argsort(np.take(owners.owner, idx), kind="stable")
        u = np.empty(idx.size, dtype=REAL)
        u[order] = owners.take(idx[order]).random()
        return u

    def _visible(self, points: np.ndarray, wi: np.ndarray, dist: np.ndarray, owners: _Owners,
                 skip: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """Unoccluded segments (3, M) (by triangles and by light shapes other than ``skip``): bool (M,), and the
        transmittance (3, M) of the tinted surfaces they pass through (None when no material tints)."""
        short = np.where(dist < FAR, dist * (1.0 - SHADOW_EPSILON), FAR).astype(points.dtype, copy=False)
        tint = None
        if self.surfaces.cutout:
            _prim, t, _u, _v, tint = self._intersect_through(points, wi, owners, short)
            blocked = t < short
        else:
            blocked = self.tracer.occluded(points, wi, short, soa=True)
            owners.traced()
        if self.lights.surfaces:
            rest = np.flatnonzero(~blocked)
            if rest.size:
                blocked[rest] = self.lights.occluded_soa(_take(points, rest), _take(wi, rest), short[rest],
                                                         None if skip is None else skip[rest])
        return ~blocked, tint

    def _shade(self, origins: np.ndarray, directions: np.ndarray, prim: np.ndarray, t: np.ndarray, bu: np.ndarray,
               bv: np.ndarray, owners: _Owners) -> np.ndarray:
        """Outgoing radiance (3, M) at the first hits of rays (3, M) of the probes ``owners``: path tracing with MIS
        (module docstring)."""
        m = prim.shape[0]
        out = np.zeros((3, m), dtype=REAL)
        throughput = None  # ones
        ray_index = None  # arange(m)
        pdf_prev = None  # (M,) the BSDF pdf of the continuation that reached these hits (None: camera rays)
        normals = self.tracer.normals_soa
        for depth in range(self.bounces + 1):
            k = prim.shape[0]
            if k == 0:
                break
            hits = origins + t * directions
            albedo, f0, roughness, emission, f90 = self.surfaces.params_soa(
                prim, bu, bv, t, self._primary_spread if depth == 0 else BOUNCE_SPREAD)
            n = np.take(normals, prim, axis=1)
            back = dot(n, directions) > 0  # hits on the side opposite the winding normal
            n *= 1 - 2 * back.astype(REAL)  # face the incoming ray
            points = hits + self.tracer.offset_soa(hits) * n  # offset along the geometric normal
            coat, sheen = self.surfaces.coat_soa(prim), self.surfaces.sheen_soa(prim)
            rough = self.surfaces.rough_diffuse_soa(prim)
            if self.tracer.shading_soa is None and not self.surfaces.normal_maps:
                bsdf = Bsdf(n, -directions, albedo, f0, roughness, coat=coat, f90=f90, sheen=sheen,
                            rough_diffuse=rough)
            else:  # authored and mapped normals shade; the geometric normal bounds what the surface lets through
                shading = n if self.tracer.shading_soa is None else self.tracer.shading_normals(
                    prim, bu, bv, n, -directions)
                if self.surfaces.normal_maps:
                    shading = self.surfaces.mapped_normals(
                        prim, bu, bv, t, self._primary_spread if depth == 0 else BOUNCE_SPREAD, shading, back,
                        -directions)
                bsdf = Bsdf(shading, -directions, albedo, f0, roughness, geometric=n, coat=coat, f90=f90,
                            sheen=sheen, rough_diffuse=rough)
            mesh = np.take(self.surfaces.mesh_of_soa, prim) if self._linking else None  # for light linking
            out_add = self._direct(points, bsdf, owners, mesh)
            if emission is not None:
                if pdf_prev is not None and self.emitters is not None and self.emitters.sampled:  # MIS, BSDF half
                    cos = np.abs(dot(n, directions))
                    emission = emission * power(pdf_prev, self.emitters.pdf_soa(prim, t, cos))
                out_add += emission
            # BSDF continuation: also the BSDF half of the MIS estimate of lights and dome at this vertex
            u = owners.random(3)
            if self._lobes:
                wi, weight, pdf_b, weight_d, weight_s = bsdf.sample(u[0], u[1], u[2], lobes=True)
            else:
                wi, weight, pdf_b = bsdf.sample(u[0], u[1], u[2])
            alive = (pdf_b > 0) & (vmax(weight) > 0)
            prim2 = np.full(k, -1, dtype=np.int32)
            t2 = np.full(k, FAR, dtype=REAL)
            bu2 = np.zeros(k, dtype=REAL)
            bv2 = np.zeros(k, dtype=REAL)
            ai = np.flatnonzero(alive)
            if ai.size:
                pa, wa = _take(points, ai), _take(wi, ai)
                # the nearest light shape along each ray: where tints stop counting, and what the ray may find
                nearest = self.lights.nearest_soa(pa, wa) if self.lights.surfaces else None
                p2, tt, uu, vv, tint = self._intersect_through(pa, wa, owners.take(ai),
                                                               None if nearest is None else nearest[0])
                prim2[ai], t2[ai], bu2[ai], bv2[ai] = p2, tt, uu, vv
                if tint is not None:  # the path continues (and finds emitters) through what it passed
                    weight = weight.copy()
                    weight[:, ai] *= tint
                    if self._lobes:
                        weight_d, weight_s = weight_d.copy(), weight_s.copy()
                        weight_d[:, ai] *= tint
                        weight_s[:, ai] *= tint
                found, on_light = self._emitted_along(pa, wa, tt, p2 < 0, pdf_b[ai],
                                                      None if mesh is None else mesh[ai], nearest)
                if found is not None and self._lobes:  # (diffuse, specular) emitter sums
                    _add_at(out_add, ai, _take(weight_d, ai) * found[0] + _take(weight_s, ai) * found[1])
                elif found is not None:
                    _add_at(out_add, ai, _take(weight, ai) * found)
                prim2[ai[on_light]] = -1  # light shapes are opaque and do not reflect: the path ends there
                if depth == self.bounces and self.emitters is not None:  # the emitters' BSDF half, last vertex
                    h = np.flatnonzero((p2 >= 0) & ~on_light)
                    h = h[np.take(self.emitters.emissive, p2[h])]
                    if h.size:
                        ph, th = p2[h], tt[h]
                        found_e = self.surfaces.params_soa(ph, uu[h], vv[h], th, BOUNCE_SPREAD)[3]
                        cos = np.abs(dot(np.take(normals, ph, axis=1), _take(wa, h)))
                        found_e = found_e * power(pdf_b[ai[h]], self.emitters.pdf_soa(ph, th, cos))
                        _add_at(out_add, ai[h], _take(weight, ai[h]) * found_e)
            contribution = out_add if throughput is None else throughput * out_add
            if ray_index is None:
                out += contribution
            else:
                _add_at(out, ray_index, contribution)
            if depth == self.bounces:
                break
            throughput = weight if throughput is None else throughput * weight
            keep = alive & (prim2 >= 0)
            if depth + 1 > RR_START:
                q = np.minimum(0.95, vmax(throughput))
                keep &= owners.random() < q
                throughput = throughput / np.maximum(q, TINY)
            ki = np.flatnonzero(keep)
            ray_index = ki if ray_index is None else ray_index[ki]
            owners = owners.take(ki)
            throughput = _take(throughput, ki)
            origins, directions = _take(points, ki), _take(wi, ki)
            prim, t, bu, bv = prim2[ki], t2[ki], bu2[ki], bv2[ki]
            pdf_prev = pdf_b[ki]
        return out

    def _emitted_along(self, points: np.ndarray, wi: np.ndarray, t: np.ndarray, escaped: np.ndarray,
                       pdf_b: np.ndarray, mesh: np.ndarray | None = None, nearest: tuple | None = None
                       ) -> tuple[np.ndarray | tuple[np.ndarray, np.ndarray] | None, np.ndarray]:
        """Radiance (3, M) a BSDF-sampled ray finds at a light shape, the dome or a distant disc, weighted by the
        power heuristic against the next-event pdfs (None if nothing can be found), and whether the ray ended on a
        light shape (M,). With diffuse/specular multipliers the radiance is a pair: the sums weighted by each
        emitter's diffuse and specular multiplier. Lights without shadows are found by next-event estimation only
        (they add nothing here); with light linking, ``mesh`` (M,) is the mesh each ray leaves, and an emitter not
        linked to it adds nothing."""
        m = points.shape[1]
        sums = [None, None] if self._lobes else [None]  # one sum, or the (diffuse, specular) weighted ones

        def add(where: np.ndarray, value: np.ndarray, multipliers: tuple[float, float]) -> None:
            for i, total in enumerate(sums):
                if total is None:
                    total = sums[i] = np.zeros((3, m), dtype=REAL)
                factor = multipliers[i] if self._lobes else 1.0
                _add_at(total, where, value if factor == 1.0 else value * REAL(factor))

        on_light = np.zeros(m, dtype=bool)
        if self.lights.surfaces:
            sums = [np.zeros((3, m), dtype=REAL) for _ in sums]
            t_l, which, l_l = nearest if nearest is not None else self.lights.nearest_soa(points, wi)
            on_light = (which >= 0) & (t_l < t)
            for k, model in enumerate(self.lights.surfaces):
                j = self._surface_strategy[k]
                sel = np.flatnonzero(on_light & (which == k))
                if sel.size and mesh is not None and self._light_links[j] is not None:
                    sel = sel[self._light_links[j][mesh[sel]]]
                if sel.size and not self._nee_only[j]:
                    pdf_l = model.pdf_soa(_take(points, sel), _take(wi, sel), t_l[sel])
                    if j in self._drawn_index:  # drawn from the grid: the density of the K draws
                        pdf_l = pdf_l * self._drawn_pdf(_take(points, sel), j)
                    add(sel, _take(l_l, sel) * power(pdf_b[sel], pdf_l), self._light_lobes[j])
            escaped = escaped & ~on_light
        distant = [(light, self._model_strategy[id(light)]) for light in self.distant if not light.delta]
        distant = [(light, j) for light, j in distant if not self._nee_only[j]]
        dome_found = not self.dome.black and not self._dome_nee_only  # by escaping BSDF rays
        ei = np.flatnonzero(escaped) if dome_found or distant else np.zeros(0, dtype=np.int64)
        if ei.size:
            w_dirs = _take(wi, ei)
            pb = pdf_b[ei]
            parts = []  # (radiance (3, E), multipliers), summed in this order

            def linked(value: np.ndarray, links: np.ndarray | None) -> np.ndarray:
                return value if mesh is None or links is None else value * links[mesh[ei]].astype(REAL)

            if dome_found:
                rest, pdf_rest = self.dome.rest_lookup_soa(w_dirs)
                if self.portals:
                    pdf_rest = self._dome_pdf(_take(points, ei), w_dirs, pdf_rest)
                parts.append((linked(rest * power(pb, pdf_rest), self._dome_links), self._dome_lobes))
                if self.dome.has_sun:
                    sun, pdf_sun = self.dome.sun_lookup_soa(w_dirs)
                    parts.append((linked(sun * power(pb, pdf_sun), self._dome_links), self._dome_lobes))
            for light, j in distant:
                value = light.escaped_soa(w_dirs) * power(pb, light.pdf_soa(None, w_dirs, None))
                parts.append((linked(value, self._light_links[j]), self._light_lobes[j]))
            for i in range(len(sums)):
                found = np.zeros((3, ei.size), dtype=REAL)
                for value, multipliers in parts:
                    factor = multipliers[i] if self._lobes else 1.0
                    found += value if factor == 1.0 else value * REAL(factor)
                if sums[i] is None:
                    sums[i] = np.zeros((3, m), dtype=REAL)
                _add_at(sums[i], ei, found)
        if self._lobes:
            return (None if sums[0] is None else (sums[0], sums[1])), on_light
        return sums[0], on_light

    def _direct(self, points: np.ndarray, bsdf: Bsdf, owners: _Owners, mesh: np.ndarray | None = None
                ) -> np.ndarray:
        """Next-event estimates (3, M) of the analytic lights, the dome's rest and its sun, and the emissive
        triangles (MIS-weighted, shadowed); with light linking, ``mesh`` (M,) is each point's mesh, and an emitter
        not linked to it delivers nothing.

        Strategies (J slots per point): every analytic light, or — above :data:`ENUMERATED_LIGHTS` lights — the
        distant ones and :data:`LIGHT_SAMPLES` lights drawn from the light grid per point (module docstring "Many
        lights"); then the dome's rest, its sun and the emissive triangles. Each slot's rows into the strategy tables
        (:meth:`_strategy_tables`) are one per slot, or one per point for the drawn lights. All slots' samples are
        evaluated as one (3, J, M) batch and their shadow rays traced in one occlusion query."""
        m = points.shape[1]
        tables = self._strategy_tables()
        wis, dists, radiances, pdfs, rows = [], [], [], [], []
        for j in self._enumerated:
            u = owners.random(2)
            wi, dist, radiance, pdf = self.lights.models[j].sample_soa(points, u[0], u[1])
            wis.append(wi), dists.append(dist), radiances.append(radiance), pdfs.append(pdf), rows.append(j)
        if self._light_grid is not None:
            for wi, dist, radiance, pdf, row in self._sample_drawn(points, owners):
                wis.append(wi), dists.append(dist), radiances.append(radiance), pdfs.append(pdf), rows.append(row)
        n_lights = len(self.lights.models)
        if not self.dome.black:
            far = np.full(m, FAR, dtype=REAL)
            u0 = owners.random(dtype=np.float64)  # the texel choice in float64 (the CDF's resolution)
            u = owners.random(3)
            if self.portals:
                wi, _radiance, _pdf = self.dome.sample_rest_soa(u0, u[0], u[1])
                through = np.flatnonzero(u[2] < 0.5)
                if through.size:
                    which = (u[2][through] * (2 * len(self.portals))).astype(np.int64).clip(0, len(self.portals) - 1)
                    for j, portal in enumerate(self.portals):
                        sel = through[which == j]
                        if sel.size:
                            up = owners.take(sel).random(2)
                            wi[:, sel] = portal.sample_soa(_take(points, sel), up[0], up[1])[0]
                radiance, pdf = self.dome.rest_lookup_soa(wi)
                pdf = self._dome_pdf(points, wi, pdf)
            else:
                wi, radiance, pdf = self.dome.sample_rest_soa(u0, u[0], u[1])
            wis.append(wi), dists.append(far), radiances.append(radiance), pdfs.append(pdf), rows.append(n_lights)
            if self.dome.has_sun:
                u0 = owners.random(dtype=np.float64)
                u = owners.random(2)
                wi, radiance, pdf = self.dome.sample_sun_soa(u0, u[0], u[1])
                wis.append(wi), dists.append(far), radiances.append(radiance), pdfs.append(pdf)
                rows.append(n_lights + 1)
        if self.emitters is not None and self.emitters.sampled:  # the emissive triangles, last (capture.emitters)
            u0 = owners.random(dtype=np.float64)
            u = owners.random(3)
            prims, b1, b2, wi, dist, pdf = self.emitters.sample_soa(points, u0, u[0], u[1], u[2])
            radiance = np.zeros((3, m), dtype=REAL)
            sel = np.flatnonzero(pdf > 0)  # the vertices that sample the triangles (share q) and are not degenerate
            if sel.size:
                radiance[:, sel] = self.surfaces.params_soa(prims[sel], b1[sel], b2[sel], dist[sel],
                                                            BOUNCE_SPREAD)[3]
                if self.surfaces.cutout:  # a cut-out or half-present emitter delivers its expected presence
                    radiance[:, sel] *= self.surfaces.presence(prims[sel], b1[sel].astype(np.float64),
                                                               b2[sel].astype(np.float64))
            wis.append(wi), dists.append(dist), radiances.append(radiance), pdfs.append(pdf), rows.append(n_lights + 2)
        count = len(wis)
        if count == 0:
            return np.zeros((3, m), dtype=REAL)
        wi = np.stack(wis, axis=1)  # (3, J, M)
        radiance = np.stack(radiances, axis=1)
        pdf = np.stack(pdfs)  # (J, M)
        per_point = any(np.ndim(r) for r in rows)
        # (J, 1) rows, or (J, M) when drawn lights differ per point: what indexes every strategy table
        row = np.stack([np.broadcast_to(np.asarray(r, dtype=np.int64), (m,)) for r in rows]) if per_point else \
            np.asarray(rows, dtype=np.int64)[:, None]
        if self._lobes:  # each strategy's diffuse and specular multipliers weight the lobes apart
            value_d, value_s, pdf_b = bsdf.evaluate_lobes(wi)
            lobes = tables.lobes[row]  # (J, 1 | M, 2)
            value = value_d * lobes[..., 0] + value_s * lobes[..., 1]
        else:
            value, pdf_b = bsdf.evaluate(wi)
        valid = (pdf > 0) & (vmax(radiance) > 0) & (vmax(value) > 0)
        if mesh is not None and tables.links is not None:  # light linking
            valid &= tables.links[row, mesh[None, :]]
        weight = power(pdf, pdf_b)
        nee_only = tables.nee_only[row]
        if nee_only.any():
            weight = np.where(nee_only, REAL(1), weight)  # found by next-event estimation alone
        shadowless = tables.shadowless[row]  # (J, 1 | M)
        with np.errstate(divide="ignore"):
            inv = np.where(np.isinf(pdf), 1, np.where(pdf > 0, 1 / pdf, 0)).astype(REAL, copy=False)
        dist = np.stack(dists)
        short = np.where(dist < FAR, dist * (1.0 - SHADOW_EPSILON), FAR).astype(REAL, copy=False)
        unblocked = valid & ~shadowless  # the segments whose occlusion counts
        if self.lights.surfaces:  # light shapes first, on all (J, M) segments at once (no gathers)
            unblocked &= ~self.lights.occluded_soa(points, wi, short, tables.shape[row], where=unblocked)
        idx = np.flatnonzero(unblocked)
        scale = np.zeros(count * m, dtype=REAL)
        tint = None
        if idx.size:
            sp, sw, sd = _take(points, idx % m), _take(wi.reshape(3, -1), idx), short.reshape(-1)[idx]
            seg_rows = row.reshape(-1)[idx] if per_point else row[idx // m, 0]
            if self.surfaces.cutout or tables.casters is not None or tables.ranges is not None:
                _p, t_hit, _u, _v, tint = self._intersect_through(
                    sp, sw, owners.take(idx % m), sd, None if tables.casters is None else (tables.casters, seg_rows))
                visible = t_hit >= sd
            else:
                visible = ~self.tracer.occluded(sp, sw, sd, soa=True)
                owners.traced(idx % m)
            scale[idx[visible]] = 1
            if tables.ranges is not None:  # ShadowAPI shadow:distance: the nearest occluder shadows by its distance
                blocked = np.flatnonzero(~visible)
                ranged = tables.ranges[seg_rows[blocked]]
                scale[idx[blocked]] = 1 - shadow_strength(t_hit[blocked], ranged[:, 0], ranged[:, 1], ranged[:, 2])
        scale = scale.reshape(count, m)
        transmittance = None  # (3, J, M): the tint of the surfaces visible segments pass through
        if tint is not None:
            transmittance = np.ones((3, count * m), dtype=REAL)
            transmittance[:, idx] = tint
            transmittance = transmittance.reshape(3, count, m)
        if shadowless.any():
            scale = np.where(shadowless, valid.astype(REAL), scale)
        elif idx.size == 0 and tables.shadow_color is None:
            return np.zeros((3, m), dtype=REAL)
        terms = value * radiance * (scale * weight * inv)
        if transmittance is not None:
            terms *= transmittance
        if tables.shadow_color is not None:  # ShadowAPI shadow:color: occluded segments deliver that fraction,
            colours = tables.shadow_color[row]  # (J, 1 | M, 3)          # by next-event estimation alone
            for j in range(count):
                if colours[j].any():
                    occluded = (valid[j] * (1 - scale[j])).astype(REAL) * inv[j]  # the shadowed share
                    terms[:, j] += value[:, j] * radiance[:, j] * (colours[j].T * occluded)
        total = terms[:, 0]
        for j in range(1, count):  # in strategy order, element by element (a reduction's order may depend on M)
            total = total + terms[:, j]
        return total

    def _sample_drawn(self, points: np.ndarray, owners: _Owners
                     ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """:data:`LIGHT_SAMPLES` lights per point (3, M) drawn from the light grid (BVH outside it) and a next-event
        sample of each, all K·M at once: per draw, direction (3, M), shadow distance (M,), radiance (3, M), the pdf
        K·P(light | point)·pdf(ω) of the K draws (M,) (0 where no light can reach the point) and the light's index
        (M,) (the strategy-table row). The random numbers are drawn draw by draw (choice, then ω), as K calls
        would."""
        m, k = points.shape[1], LIGHT_SAMPLES
        choices, omegas = [], []
        for _ in range(k):
            choices.append(owners.random(dtype=np.float64))
            omegas.append(owners.random(2))
        leaf, pmf = self._light_grid.sample(points, np.concatenate(choices), draws=k)  # (K·M,)
        u = np.concatenate(omegas, axis=1)  # (2, K·M)
        light = np.where(leaf >= 0, self._drawn_models[np.maximum(leaf, 0)], 0)
        tiled = np.tile(points, (1, k))
        wi, dist, radiance, pdf = self._drawn_sampler.sample(tiled, leaf, u[0], u[1])
        pdf = (pdf * (k * pmf)).astype(REAL)  # delta lights: ∞ stays ∞ (their weight is 1 / (K·P))
        return [(wi[:, j * m:(j + 1) * m], dist[j * m:(j + 1) * m], radiance[:, j * m:(j + 1) * m],
                 pdf[j * m:(j + 1) * m], light[j * m:(j + 1) * m]) for j in range(k)]

    def _drawn_pdf(self, points: np.ndarray, model_index: int) -> np.ndarray:
        """K·P(light | point) (M,) float32 of the light grid's draws for the analytic light ``model_index`` (1 when
        it is not drawn from the BVH): the factor of its next-event pdf against which BSDF hits are weighted."""
        leaf = self._drawn_index.get(model_index)
        if leaf is None:
            return np.ones(points.shape[1], dtype=REAL)
        return (LIGHT_SAMPLES * self._light_grid.pmf(points, np.full(points.shape[1], leaf))).astype(REAL)

    def _strategy_tables(self) -> _StrategyTables:
        """The next-event strategies' properties, one row per analytic light, then the dome's rest, its sun and the
        emissive triangles (built once)."""
        if self._tables is not None:
            return self._tables
        n = len(self.lights.models)
        rows = n + 3
        dome, emitters = (self._dome_lobes, self._dome_lobes), (1.0, 1.0)
        lobes = np.array([*self._light_lobes, *dome, emitters], dtype=REAL)
        shadowless = np.array([*self._shadowless, self._dome_shadowless, self._dome_shadowless, False])
        can_hit = [*self._light_can_hit, True, True, True]
        nee_only = np.array([*self._nee_only, self._dome_nee_only, self._dome_nee_only, False])
        nee_only = nee_only | ~np.array(can_hit)
        shape = np.array([*self._light_shape, -1, -1, -1], dtype=np.int64)
        meshes = len(self.scene.meshes)

        def mesh_table(per_light: list, dome_row: np.ndarray | None) -> np.ndarray | None:
            entries = [*per_light, dome_row, dome_row, None]
            if all(e is None for e in entries):
                return None
            table = np.ones((rows, meshes), dtype=bool)
            for r, e in enumerate(entries):
                if e is not None:
                    table[r] = e
            return table

        links = mesh_table(self._light_links, self._dome_links)
        casters = mesh_table(self._casters, self._dome_casters)
        ranges_rows = [*self._shadow_ranges, self._dome_shadow_range, self._dome_shadow_range, None]
        ranges = None if all(r is None for r in ranges_rows) else np.array(
            [(FAR, 0.0, 1.0) if r is None else r for r in ranges_rows], dtype=REAL)
        colours = [*self._shadow_color, self._dome_shadow_color, self._dome_shadow_color, (0.0, 0.0, 0.0)]
        shadow_color = np.array(colours, dtype=REAL) if any(any(c) for c in colours) else None
        self._tables = _StrategyTables(lobes, shadowless, nee_only, shape, links, casters, ranges, shadow_color)
        return self._tables

    def _dome_pdf(self, points: np.ndarray, wi: np.ndarray, pdf: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (M,) of the dome-rest next-event strategy from the dome's own ``pdf``: with portals the
        mixture ½ p_dome + ½ (1/K) Σ_k p_portal_k (uniform area sampling of one of K portals)."""
        if not self.portals:
            return pdf
        through = np.zeros(wi.shape[1], dtype=REAL)
        for portal in self.portals:
            t, _ = portal.intersect_soa(points, wi)
            hit = t < FAR
            if hit.any():  # the density of uniform area sampling, from either side of the portal
                th = np.where(hit, t, 0)
                cos = np.abs(dotc(portal.z_axis, wi))
                through += np.where(hit, th * th / (portal.light.area * np.maximum(cos, TINY)), 0)
        return 0.5 * pdf + 0.5 * through / len(self.portals)

    # ------------------------------------------------------------------------------------------------------------
    def _splat_distant(self, light: Light, face_size: int) -> bool:
        """Whether a distant light is splatted (disc smaller than a texel) rather than ray-seen."""
        alpha = np.radians(0.5 * light.angle)
        disc = 2.0 * np.pi * (1.0 - np.cos(alpha))
        return disc < cube_mean_texel_solid_angle(face_size)

    def _visible_from(self, position: np.ndarray, directions: np.ndarray, probe: _Owners
                      ) -> tuple[np.ndarray, np.ndarray | None]:
        """Whether the probe at ``position`` sees the dome along directions (K, 3) (or (3, K) float32): bool (K,),
        and through which tint (3, K) (None when no material tints). ``probe``: the probe's (single) owner,
        counting the rays."""
        d = directions if directions.dtype == REAL else np.ascontiguousarray(directions.T, dtype=REAL)
        o = np.broadcast_to(np.asarray(position, dtype=REAL).reshape(3, 1), d.shape)
        owners = _Owners(probe.rngs, np.zeros(d.shape[1], dtype=np.int64), probe.rays)
        return self._visible(o, d, np.full(d.shape[1], FAR, dtype=REAL), owners)

    def _add_sun(self, cube: np.ndarray, position: np.ndarray, probe: _Owners) -> np.ndarray:
        """Splat the dome's sun points that the probe sees (bilinear, flux-exact)."""
        if self.dome.black or not self.dome.has_sun:
            return cube
        n = cube.shape[1]
        directions, index, weight, flux = self._sun_points(n)
        seen, tint = self._visible_from(position, directions, probe)
        if not seen.any():
            return cube
        # splat_bilinear of the seen points: the same sums, in the same order (corner by corner, point by point)
        index, weight, flux = index[:, seen].reshape(-1), weight[:, seen], flux[seen]
        if tint is not None:
            flux = flux * tint[:, seen].T
        flux_cube = np.stack([np.bincount(index, (weight * flux[:, c]).reshape(-1), 6 * n * n) for c in range(3)],
                             axis=1)
        return cube + (flux_cube / self._texel_omega(n)).reshape(cube.shape)

    def _sun_points(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The dome's sun points (3, K) float32, their bilinear splat into an N cube (texel indices and weights (4,
        K), :func:`~bakery.capture.dome.bilinear_weights`) and their flux (K, 3)."""
        if n not in self._sun_splat:
            directions, flux = self.dome.sun_points()
            index, weight = bilinear_weights(directions, n)
            self._sun_splat[n] = (np.ascontiguousarray(directions.T, dtype=REAL), index, weight, flux)
        return self._sun_splat[n]

    def _splat(self, cube: np.ndarray, directions: np.ndarray, flux: np.ndarray) -> np.ndarray:
        n = cube.shape[1]
        flux_cube = np.zeros((6 * n * n, 3))
        splat_bilinear(flux_cube, directions, flux)
        return cube + (flux_cube / self._texel_omega(n)).reshape(cube.shape)

    def _texel_omega(self, n: int) -> np.ndarray:
        """Texel solid angles (6·N·N, 1) of an N cube."""
        if n not in self._omega:
            self._omega[n] = cube_texel_solid_angles(n).reshape(-1, 1)
        return self._omega[n]

    def _add_small_lights(self, cube: np.ndarray, position: np.ndarray, probe: _Owners
                          ) -> tuple[np.ndarray, np.ndarray | None]:
        """Splat the light shapes that look small from ``position`` (module docstring "Small lights"): each visible
        light whose bounding sphere's angular radius θ is at most SPLAT_LIGHT_TEXELS texel half-widths gets a
        stratified grid of next-event samples from the probe (side ⌈SPLAT_LIGHT_GRID·θ/θ_max⌉, ≥ 4), each splatting
        its flux L·V/(pdf·K) bilinearly at its direction; returns the cube and which light surfaces were splatted
        (bool, or None if none)."""
        if not self.lights.surfaces:
            return cube, None
        n = cube.shape[1]
        limit = SPLAT_LIGHT_TEXELS * 0.5 * math.sqrt(cube_mean_texel_solid_angle(n))  # angular radius, radians
        origin = np.asarray(position, dtype=np.float64)
        centres, radii = self._surface_spheres
        distance = np.linalg.norm(centres - origin, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            angle = np.arcsin(np.clip(radii / distance, 0.0, 1.0))
        hidden = (distance > radii * 1.001) & (angle <= limit)
        chosen = np.flatnonzero(hidden)
        if chosen.size == 0:
            return cube, None
        sides = np.clip(np.ceil(SPLAT_LIGHT_GRID * angle[chosen] / limit), 4, SPLAT_LIGHT_GRID).astype(np.int64)
        counts = sides * sides
        total = int(counts.sum())
        light = np.repeat(chosen, counts)  # the light surface of each sample
        cell = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)  # index within its light's grid
        side = np.repeat(sides, counts)
        jitter = _Owners(probe.rngs, np.zeros(total, dtype=np.int64), probe.rays).random(2)
        u0 = ((cell % side + jitter[0]) / side).astype(REAL)
        u1 = ((cell // side + jitter[1]) / side).astype(REAL)
        points = np.ascontiguousarray(np.broadcast_to(origin.astype(REAL).reshape(3, 1), (3, total)))
        wi, dist, radiance, pdf = self._surface_sampler.sample(points, light, u0, u1)
        good = (pdf > 0) & np.isfinite(pdf) & (vmax(radiance) > 0)
        if good.any():
            sel = np.flatnonzero(good)
            owners = _Owners(probe.rngs, np.zeros(sel.size, dtype=np.int64), probe.rays)
            seen, tint = self._visible(points[:, sel], _take(wi, sel), dist[sel], owners, light[sel])
            weight = np.where(seen, 1.0 / pdf[sel].astype(np.float64), 0.0) / np.repeat(counts, counts)[sel]
            flux = radiance[:, sel].astype(np.float64).T * weight[:, None]  # (K, 3): L·V/(pdf·K_light)
            if tint is not None:
                flux *= tint.astype(np.float64).T
            keep = np.flatnonzero(weight > 0)
            if keep.size:
                cube = self._splat(cube, wi[:, sel].astype(np.float64).T[keep], flux[keep])
        return cube, hidden

    def _add_distant_lights(self, cube: np.ndarray, position: np.ndarray, probe: _Owners) -> np.ndarray:
        n = cube.shape[1]
        for light in self.distant:
            if not self._splat_distant(light.light, n):
                continue
            d = light.direction[None, :]
            seen, tint = self._visible_from(position, d, probe)
            if not seen[0]:
                continue
            cube = self._splat(cube, d, light.illuminance[None, :] * (1.0 if tint is None else tint[:, 0]))
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
