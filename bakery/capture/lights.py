"""UsdLux lights of the capture: one class per light kind, behind one interface (no ``pxr``).

Every light kind is a :class:`LightModel` subclass registered by its :attr:`LightModel.kind`. The class is the one
place that knows the kind:

- reading: :attr:`usd_types` (the UsdLux schema names it reads), :attr:`usd_inputs` (its shape inputs with their
  schema fallbacks) and :meth:`from_usd` (inputs + placement → :class:`~bakery.capture.scene.Light`), used by
  :mod:`bakery.usd.scene` (which does the ``pxr`` part: attribute values and transforms);
- rendering: :meth:`sample` (next-event estimation from surface points), :meth:`pdf` (the solid-angle density of
  :meth:`sample`, for multiple importance sampling), :meth:`intersect` (the light's surface along rays: camera,
  bounce and shadow rays — light shapes are opaque and occlude) and :meth:`emitted` (radiance leaving the surface
  towards a receiver, with UsdLuxShapingAPI and RectLight textures), used by :mod:`bakery.capture.render`;
- incremental bakes: :attr:`is_global` and :meth:`bound` (centre, bounding radius and an upper bound of the
  radiant power per steradian used by :func:`bakery.pipeline.dependencies.light_table`).

Samplers (pbrt-v4, "Light Sampling")
    distant   uniform in the cone of half-angle α around the light direction (a delta direction when α = 0).
    sphere    uniform in the cone the sphere subtends, pdf = 1/(2π(1−cos θmax)) [pbrt-v4 §12.2.2]; an ellipsoid
              (a sphere under a non-uniform scale, E = M·S²) the same cone in the space where it is the unit
              sphere, mapped back: pdf_ω = pdf_ω' · |det M⁻¹| / |M⁻¹ω|³ (the Jacobian of ω' = M⁻¹ω/|M⁻¹ω|).
    rect      uniform on the area, pdf_ω = d²/(A·cos θ_l); emits towards local −Z only.
    disk      uniform on the area (ρ = √u on the unit disk, stretched to the semi-axes a, b), as rect.
    cylinder  on the half of the lateral surface facing the point (axis = local X, as UsdLuxCylinderLight; no
              caps, as HdEmbree): uniform along the axis and in the projected width, φ = φ₀ + asin(2u − 1) around
              the point's azimuth φ₀, area density cos(φ − φ₀)/(2·L·arc), arc = r or, for an elliptic section
              (a·cos φ, b·sin φ), √(a²sin²φ + b²cos²φ); pdf_ω = d²·density/cos θ_l; the cylinder's own surface
              occludes shadow rays.

Shaping (UsdLuxShapingAPI, as HdEmbree evaluates it)
    with c = cos of the angle between the emission direction and the light's −Z axis:
    focus: L *= lerp(focusTint, 1, |c|^focus); cone: L *= 1 − smoothstep(θ, (1 − softness)·θ_cone, θ_cone);
    IES profile: L *= the profile's value along the emission direction (:mod:`bakery.capture.ies`). Distant
    lights are not shaped.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bakery.capture import vec
from bakery.capture.ies import evaluate_ies
from bakery.capture.light_tree import CULLED_SHAPES, LightBound, LightBVH
from bakery.capture.scene import FAR, Light, ellipse_perimeter, ellipsoid_area
from bakery.capture.tracer import SphereCuller
from bakery.capture.vec import TINY, dot, dotc
from bakery.conventions import LUMINANCE_WEIGHTS

#: From this many light shapes, the segments that may meet a shape are found by one Embree query
#: (:class:`bakery.capture.tracer.SphereCuller`) before the shapes' tests (or the shape BVH's pairs, above
#: CULLED_SHAPES); below, every shape tests every segment.
PROXY_CULLED_SHAPES = 4

#: Relative shortening of shadow segments so the sampled light point itself does not occlude.
SHADOW_EPSILON = 1e-4


def sample_cone(axis: np.ndarray, one_minus_cos_max: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Uniform directions (M, 3) in cones around unit axes (M, 3) with 1 − cos θmax (M,); u (M, 2)."""
    u = np.asarray(u, dtype=np.float64)
    return np.ascontiguousarray(vec.cone(np.asarray(axis, dtype=np.float64).T, one_minus_cos_max, u[:, 0],
                                         u[:, 1]).T)


@dataclass(frozen=True)
class Placement:
    """Where a light is, as the USD reader found it (bake frame, metres).

    Attributes:
        position: (3,) origin of the light's local frame.
        axes: (3, 3) rows = unit local X, Y, Z axes.
        lengths: (3,) lengths of the local axes in metres (xform scale × metersPerUnit).
        meters_per_unit: the stage's metersPerUnit (``normalize`` divides by areas in stage units²).
    """

    position: tuple[float, float, float]
    axes: tuple[tuple[float, float, float], ...]
    lengths: tuple[float, float, float]
    meters_per_unit: float = 1.0


@dataclass(frozen=True)
class LightSample:
    """Next-event samples: direction to the light wi (M, 3), shadow distance (M,), radiance arriving along wi (M, 3)
    and the solid-angle pdf (M,) (``inf`` for delta lights; 0 where the sample is invalid)."""

    wi: np.ndarray
    distance: np.ndarray
    radiance: np.ndarray
    pdf: np.ndarray


def _smoothstep(t: np.ndarray, lo: float, hi: float) -> np.ndarray:
    if hi - lo <= 0:
        return (t > lo).astype(t.dtype)
    x = np.clip((t - lo) / (hi - lo), 0, 1)
    return x * x * (3 - 2 * x)


class LightModel:
    """Interface of one light kind (module docstring). Instances wrap one :class:`Light`.

    Rendering methods come in two layouts: the ``*_soa`` methods used by the renderer take and return
    structure-of-arrays vectors (3, M) of any float dtype (float32 in the renderer, see :mod:`bakery.capture.vec`);
    :meth:`sample`, :meth:`pdf`, :meth:`intersect`, :meth:`emitted` and :meth:`occludes` are the same with (M, 3)
    arrays. Subclasses implement the ``*_soa`` methods.
    """

    kind: ClassVar[str] = ""
    usd_types: ClassVar[tuple[str, ...]] = ()
    usd_inputs: ClassVar[dict[str, Any]] = {}
    is_global: ClassVar[bool] = False

    def __init__(self, light: Light, textures: tuple = ()) -> None:
        self.light = light
        self.name = light.name
        self.axes = np.asarray(light.axes, dtype=np.float64)
        self.centre = np.asarray(light.position, dtype=np.float64)
        self.colour = np.asarray(light.radiance, dtype=np.float64)
        self.visible = bool(light.visible)
        self.texture = None
        if light.texture >= 0 and light.texture < len(textures):
            self.texture = np.asarray(textures[light.texture].pixels, dtype=np.float64)[..., :3]
        # constants as Python floats (keep float32 arrays float32) and (3, 1) columns per dtype
        self.x_axis, self.y_axis, self.z_axis = (vec.const(a) for a in self.axes)
        self.c = vec.const(self.centre)
        self._columns: dict[Any, tuple[np.ndarray, np.ndarray]] = {}

    def _cols(self, dtype) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
        """(centre, colour) as (3, 1) columns of ``dtype``."""
        key = np.dtype(dtype)
        if key not in self._columns:
            self._columns[key] = (vec.column(self.c, key), vec.column(vec.const(self.colour), key))
        return self._columns[key]

    # -- reading (called by bakery.usd.scene with plain values) ----------------------------------------------------
    @classmethod
    def from_usd(cls, name: str, inputs: dict[str, Any], placement: Placement, emission: np.ndarray,
                 normalize: bool) -> tuple[Light, list[str]]:
        """The :class:`Light` for a prim of this kind, and messages about what was approximated."""
        raise NotImplementedError

    # -- rendering, (3, M) ----------------------------------------------------------------------------------------
    def sample_soa(self, points: np.ndarray, u0: np.ndarray, u1: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Next-event samples from points (3, M) with uniform numbers u0, u1 (M,): direction to the light (3, M),
        shadow distance (M,), radiance arriving along it (3, M), solid-angle pdf (M,) (∞ for delta lights, 0 where
        invalid)."""
        raise NotImplementedError

    def pdf_soa(self, points: np.ndarray, wi: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (M,) of :meth:`sample_soa` from points (3, M) for directions wi that reach the light
        at t."""
        raise NotImplementedError

    def intersect_soa(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Nearest intersection t (M,) (FAR if none) of rays (3, M) with the light's surface, and its local (a, b)
        surface coordinates (2, M) (for textures; None if the light has none). Distant lights have no surface."""
        return np.full(origins.shape[1], FAR, dtype=origins.dtype), None

    def emitted_soa(self, wi: np.ndarray, coords: np.ndarray | None, facing: np.ndarray) -> np.ndarray:
        """Radiance (3, M) arriving along wi (3, M) (receiver → light) from surface points with local coordinates
        ``coords`` (2, M); ``facing`` (M,) whether the surface emits towards the receiver there."""
        _centre, colour = self._cols(wi.dtype)
        scale = facing.astype(wi.dtype)
        shaping = self.light.shaping
        if shaping:
            cone, softness, focus = float(shaping[0]), float(shaping[1]), float(shaping[2])
            c = np.clip(dotc(self.z_axis, wi), -1, 1)  # emission direction (−wi) against the light's −Z
            if cone < 180.0:
                cone_r = math.radians(cone)
                scale = scale * (1 - _smoothstep(np.arccos(c), (1.0 - softness) * cone_r, cone_r))
            radiance = colour * scale
            if focus > 0:
                tint = vec.column(vec.const(shaping[3:6]), wi.dtype)
                ff = np.abs(c) ** focus
                radiance = radiance * ((1 - ff) * tint + ff)
        else:
            radiance = colour * scale
        if self.light.ies is not None:  # the profile sampled along the emission direction −wi, light-local
            local = -np.stack([dotc(self.x_axis, wi), dotc(self.y_axis, wi), dotc(self.z_axis, wi)])
            radiance = radiance * evaluate_ies(self.light.ies, local)
        if self.texture is not None and coords is not None:
            radiance = radiance * self._texel(coords)
        return radiance

    def _texel(self, coords: np.ndarray) -> np.ndarray:
        return np.ones((3, coords.shape[1]), dtype=coords.dtype)

    def occludes_soa(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray) -> np.ndarray:
        """Whether the light's surface blocks the segments origin + t·direction, 0 < t < distance (M,)."""
        if not self.visible:
            return np.zeros(origins.shape[1], dtype=bool)
        t, _ = self.intersect_soa(origins, directions)
        return t < distances

    # -- rendering, (M, 3) ----------------------------------------------------------------------------------------
    def sample(self, points: np.ndarray, u: np.ndarray) -> LightSample:
        u = np.asarray(u, dtype=np.float64)
        wi, dist, radiance, pdf = self.sample_soa(_soa(points), u[:, 0], u[:, 1])
        return LightSample(_aos(wi), dist, _aos(radiance), pdf)

    def pdf(self, points: np.ndarray, wi: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (M,) of :meth:`sample` from ``points`` for directions wi that reach the light at t."""
        return self.pdf_soa(_soa(points), _soa(wi), None if t is None else np.asarray(t, dtype=np.float64))

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest intersection t (M,) (FAR if none) of rays with the light's surface and its local (a, b) surface
        coordinates (M, 2) (for textures). Distant lights have no surface."""
        t, coords = self.intersect_soa(_soa(origins), _soa(directions))
        return t, np.zeros((t.size, 2)) if coords is None else _aos(coords)

    def emitted(self, wi: np.ndarray, coords: np.ndarray, facing: np.ndarray) -> np.ndarray:
        """Radiance (M, 3) arriving along wi (receiver → light) from surface points with local coordinates
        ``coords``; ``facing`` (M,) whether the surface emits towards the receiver there."""
        return _aos(self.emitted_soa(_soa(wi), _soa(coords), np.asarray(facing, dtype=bool)))

    def occludes(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray) -> np.ndarray:
        """Whether the light's surface blocks the segments origin + t·direction, 0 < t < distance."""
        return self.occludes_soa(_soa(origins), _soa(directions), np.asarray(distances, dtype=np.float64))

    # -- incremental bakes ----------------------------------------------------------------------------------------
    @property
    def bounding_radius(self) -> float:
        return 0.0

    def bound(self) -> tuple[tuple[float, float, float], float, float]:
        """(centre, bounding radius, largest radiance channel × emitting area) (the dependency bound's inputs)."""
        return tuple(float(c) for c in self.centre), float(self.bounding_radius), float(
            np.max(self.colour) * self.light.area)

    # -- many lights ----------------------------------------------------------------------------------------------
    def tree_bound(self) -> LightBound:
        """The light for the light BVH and grid (:mod:`bakery.capture.light_tree`): its bounding sphere's box, its
        power (luminance of the radiance × area; shaping, IES and textures only ever lower it) and its emission cone:
        every direction, or the directions within its ShapingAPI cone angle of −Z."""
        r, c = self.bounding_radius, self.centre
        power = float(np.dot(LUMINANCE_WEIGHTS, np.maximum(self.colour, 0.0))) * self.light.area
        bound = LightBound(tuple(c - r), tuple(c + r), power)
        cone = float(self.light.shaping[0]) if self.light.shaping else 180.0
        if cone < 180.0:  # ShapingAPI's cone: no emission beyond it (1 − smoothstep reaches 0 at the cone angle)
            bound = dataclasses.replace(bound, axis=tuple(-self.axes[2]), cos_normal=1.0,
                                        cos_emission=math.cos(math.radians(cone)))
        return bound


def _soa(a: np.ndarray) -> np.ndarray:
    """(M, k) → (k, M) float64 (the (M, 3) wrappers compute in float64)."""
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).T)


def _aos(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a.T)


LIGHT_MODELS: dict[str, type[LightModel]] = {}


def register_light(cls: type[LightModel]) -> type[LightModel]:
    LIGHT_MODELS[cls.kind] = cls
    return cls


def light_model(light: Light, textures: tuple = ()) -> LightModel:
    """The :class:`LightModel` of ``light`` (by its kind)."""
    return LIGHT_MODELS[light.kind](light, textures)


def model_for_usd_type(type_name: str) -> type[LightModel] | None:
    """The light class reading UsdLux prims of schema type ``type_name``, or None."""
    for cls in LIGHT_MODELS.values():
        if type_name in cls.usd_types:
            return cls
    return None


def _normalized(scale: np.ndarray, normalize: bool, area_stage_units: float) -> np.ndarray:
    return scale / area_stage_units if normalize and area_stage_units > 0 else scale


def _magnitude(what: str, value: float, notes: list[str]) -> float:
    """A light's size input as a magnitude: HdEmbree's areas are lengths of transformed vectors, so a negative
    size is the mirrored shape of the same area (reported); non-finite sizes are an error."""
    if not math.isfinite(value):
        raise ValueError(f"{what} {value} is not finite")
    if value < 0:
        notes.append(f"{what} {value} is negative; its magnitude is used")
        return -value
    return value


def _non_uniform(lengths) -> bool:  # noqa: ANN001
    """Whether axis lengths differ (relative 1e-6)."""
    lengths = np.asarray(lengths, dtype=np.float64)
    return bool(np.ptp(lengths) > 1e-6 * np.max(lengths))


def distant_half_angle(angle_degrees: float) -> float:
    """θmax of a DistantLight: half its ``inputs:angle``, clamped to [0, π] (UsdLux)."""
    return min(max(math.radians(0.5 * float(angle_degrees)), 0.0), math.pi)


def distant_size_factor(alpha: float) -> float:
    """UsdLux's ``normalize`` divisor of a DistantLight of half-angle θmax = ``alpha``: 1 at 0, π·sin²θmax up to
    π/2, (2 − sin²θmax)·π beyond."""
    if alpha <= 0:
        return 1.0
    s2 = math.sin(alpha) ** 2
    return math.pi * s2 if alpha <= 0.5 * math.pi else math.pi * (2.0 - s2)


def facing_projected_solid_angle(alpha: float) -> float:
    """∫ cos θ dω over a cone of half-angle ``alpha`` (≤ π) around the normal, counting only the hemisphere above
    it: π·sin²α up to π/2, π beyond."""
    return math.pi * math.sin(alpha) ** 2 if alpha <= 0.5 * math.pi else math.pi


# ----------------------------------------------------------------------------------------------------------------
@register_light
class DistantLightModel(LightModel):
    kind = "distant"
    usd_types = ("DistantLight",)
    usd_inputs = {"angle": 0.53}
    is_global = True

    def __init__(self, light: Light, textures: tuple = ()) -> None:
        super().__init__(light, textures)
        self.alpha = distant_half_angle(light.angle)
        self.direction = self.axes[2] / np.linalg.norm(self.axes[2])
        self.illuminance = np.asarray(light.illuminance, dtype=np.float64)
        self.one_minus_cos = 2.0 * math.sin(0.5 * self.alpha) ** 2
        # radiance inside the disc: E = L·(projected solid angle of the disc on the facing normal)
        self.disc_radiance = self.illuminance / facing_projected_solid_angle(self.alpha) if self.alpha > 0 else None

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        """UsdLux (OpenUSD 25.x ``inputs:normalize``/``inputs:angle``): θmax = clamp(angle/2, 0, π) (the angle clipped
        to [0°, 360°]); the disc's radiance is L = emission / sizeFactor, sizeFactor = 1 (normalize off, or
        θmax = 0), π·sin²θmax (θmax ≤ π/2) or (2 − sin²θmax)·π (θmax > π/2). Stored as the illuminance on the
        normal facing the light, E = L·π·sin²θmax (θmax ≤ π/2), L·π (wider: the whole hemisphere is lit), or E = L
        for the parallel light of θmax = 0 (HdEmbree's delta light delivers Le)."""
        raw = float(inputs["angle"])
        notes = []
        if not math.isfinite(raw):
            raise ValueError(f"DistantLight angle {raw} is not finite")
        angle = min(max(raw, 0.0), 360.0)
        if angle != raw:
            notes.append(f"DistantLight angle {raw}° clipped to {angle}° (UsdLux: 0 ≤ angle < 360)")
        alpha = distant_half_angle(angle)
        radiance = emission / distant_size_factor(alpha) if normalize else emission
        illuminance = radiance * facing_projected_solid_angle(alpha) if alpha > 0 else radiance
        return Light("distant", name, illuminance=tuple(float(c) for c in illuminance), axes=placement.axes,
                     angle=angle), notes

    @property
    def delta(self) -> bool:
        return self.alpha <= 0

    def sample_soa(self, points, u0, u1):  # noqa: ANN001, ANN201
        m, dtype = points.shape[1], points.dtype
        axis = np.broadcast_to(np.asarray(self.direction, dtype=dtype)[:, None], (3, m))
        if self.delta:
            return (np.array(axis), np.full(m, FAR, dtype=dtype),
                    np.broadcast_to(np.asarray(self.illuminance, dtype=dtype)[:, None], (3, m)).copy(),
                    np.full(m, np.inf, dtype=dtype))
        wi = vec.cone(axis, self.one_minus_cos, u0, u1)
        pdf = np.full(m, 1.0 / (2.0 * np.pi * self.one_minus_cos), dtype=dtype)
        return (wi, np.full(m, FAR, dtype=dtype),
                np.broadcast_to(np.asarray(self.disc_radiance, dtype=dtype)[:, None], (3, m)).copy(), pdf)

    def pdf_soa(self, points, wi, t):  # noqa: ANN001, ANN201
        if self.delta:
            return np.zeros(wi.shape[1], dtype=wi.dtype)
        inside = dotc(vec.const(self.direction), wi) >= math.cos(self.alpha)
        return inside.astype(wi.dtype) * (1.0 / (2.0 * np.pi * self.one_minus_cos))

    def escaped_soa(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (3, M) seen by rays escaping the scene along ``directions`` (3, M) (inside the disc)."""
        if self.delta:
            return np.zeros(directions.shape, dtype=directions.dtype)
        inside = dotc(vec.const(self.direction), directions) >= math.cos(self.alpha)
        return np.asarray(self.disc_radiance, dtype=directions.dtype)[:, None] * inside.astype(directions.dtype)

    def escaped(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (M, 3) seen by rays escaping the scene along ``directions`` (inside the disc)."""
        return _aos(self.escaped_soa(_soa(directions)))

    def occludes_soa(self, origins, directions, distances):  # noqa: ANN001, ANN201
        return np.zeros(origins.shape[1], dtype=bool)

    def bound(self):  # noqa: ANN201
        return (0.0, 0.0, 0.0), math.inf, float(np.max(self.illuminance))


def _sphere_cone(points: np.ndarray, centre: np.ndarray, r: np.ndarray | float):  # noqa: ANN202
    """Points (3, M), sphere centres (3, 1 | M) and radii (scalar or (M,)) → (vector to the centre (3, M), squared
    distance, outside, 1 − cos θmax)."""
    to_c = centre - points
    d2 = dot(to_c, to_c)
    outside = d2 > (r * r) * (1.0 + 1e-6)
    sin2 = np.where(outside, (r * r) / np.maximum(d2, TINY), 1).astype(points.dtype, copy=False)
    cos_max = np.sqrt(np.maximum(0, 1 - sin2))
    one_minus_cos = sin2 / (1 + cos_max)  # 1 − cos θmax without cancellation
    return to_c, d2, outside, one_minus_cos


def _sample_sphere(points: np.ndarray, centre: np.ndarray, r: np.ndarray | float, u0: np.ndarray, u1: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Uniform in the cone each sphere (centre (3, 1 | M), radius scalar or (M,)) subtends from points (3, M)
    [pbrt-v4 §12.2.2]: directions (3, M), distances to the sphere (M,), outside (M,) and the pdf (M,)."""
    to_c, d2, outside, one_minus_cos = _sphere_cone(points, centre, r)
    axis = to_c / np.sqrt(np.maximum(d2, TINY))
    wi = vec.cone(axis, one_minus_cos, u0, u1)
    # nearest root of |p + t·wi − c| = r, in the forms without cancellation: the squared distance of the centre
    # from the ray, and t = (d² − r²) / (b + √disc)
    b = dot(wi, to_c)
    perp = to_c - b * wi
    disc = np.maximum(0, (r * r) - dot(perp, perp))
    dist = np.maximum(0, (d2 - r * r) / np.maximum(b + np.sqrt(disc), TINY))
    pdf = outside / (2.0 * np.pi * np.maximum(one_minus_cos, TINY))
    return wi, dist, outside, pdf.astype(points.dtype, copy=False)


def _sphere_hits(origins: np.ndarray, directions: np.ndarray, centre: np.ndarray, r2: np.ndarray | float
                 ) -> np.ndarray:
    """Nearest hit t (M,) (FAR if none) of rays (3, M) with spheres of centres (3, 1 | M) and squared radii r² (a
    Python float, or (M,) of the rays' dtype holding the same rounded values): one sphere, or one per ray."""
    oc = origins - centre
    b = dot(oc, directions)
    c = dot(oc, oc) - r2
    perp = oc - b * directions
    disc = r2 - dot(perp, perp)
    sq = np.sqrt(np.maximum(disc, 0))
    q = sq - b  # the far root −b + √disc
    with np.errstate(divide="ignore", invalid="ignore"):
        near = c / q  # (−b − √disc) without cancellation (the product of the roots is c)
    t = np.where(c > 0, near, q)
    hit = (disc >= 0) & (t > 0) & (q > 0)
    return np.where(hit, t, FAR).astype(origins.dtype, copy=False)


class LightSampler:
    """Next-event samples of many lights at once, point i sampling light ``which[i]`` of ``models``: the plain sphere
    lights (:attr:`SphereLightModel.plain`) in one call with per-point centres, radii and radiances — the arithmetic
    of :meth:`SphereLightModel.sample_soa` — and every other light with its own :meth:`LightModel.sample_soa` on its
    points. Used for the lights drawn from the light grid and for the splatted small lights
    (:mod:`bakery.capture.render`)."""

    def __init__(self, models: list[LightModel] | tuple[LightModel, ...]) -> None:
        self.models = tuple(models)
        plain = [k for k, m in enumerate(self.models) if isinstance(m, SphereLightModel) and m.plain]
        #: per model, its index among the plain spheres (−1: sampled on its own)
        self.sphere_of = np.full(len(self.models), -1, dtype=np.int64)
        self.sphere_of[plain] = np.arange(len(plain))
        self._centres = np.array([self.models[k].centre for k in plain], dtype=np.float64).reshape(-1, 3).T
        self._radii = np.array([self.models[k].radius for k in plain], dtype=np.float64)
        self._colours = np.array([self.models[k].colour for k in plain], dtype=np.float64).reshape(-1, 3).T

    def sample(self, points: np.ndarray, which: np.ndarray, u0: np.ndarray, u1: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Directions (3, M), shadow distances (M,), radiances (3, M) and solid-angle pdfs (M,) of points (3, M),
        each sampling ``models[which[i]]`` with u0, u1 (M,); ``which`` < 0: no sample (pdf 0)."""
        m, dtype = points.shape[1], points.dtype
        wi = np.zeros((3, m), dtype=dtype)
        wi[2] = 1
        dist = np.zeros(m, dtype=dtype)
        radiance = np.zeros((3, m), dtype=dtype)
        pdf = np.zeros(m, dtype=dtype)
        chosen = np.flatnonzero(which >= 0)
        sphere = self.sphere_of[which[chosen]]
        sel = chosen[sphere >= 0]
        if sel.size:  # the plain spheres together
            k = sphere[sphere >= 0]
            centres = self._centres.astype(dtype).take(k, axis=1)
            radii = self._radii.astype(dtype).take(k)
            wi[:, sel], dist[sel], outside, pdf[sel] = _sample_sphere(np.take(points, sel, axis=1), centres, radii,
                                                                      u0[sel], u1[sel])
            radiance[:, sel] = self._colours.astype(dtype).take(k, axis=1) * outside.astype(dtype)
        rest = chosen[sphere < 0]
        rest = rest[np.argsort(which[rest], kind="stable")]  # grouped by light, ascending within
        lights = which[rest]
        starts = np.flatnonzero(np.r_[True, lights[1:] != lights[:-1]]) if rest.size else np.zeros(0, np.int64)
        for a, b in zip(starts, np.r_[starts[1:], rest.size]):
            sel = rest[a:b]
            wi[:, sel], dist[sel], radiance[:, sel], pdf[sel] = self.models[int(lights[a])].sample_soa(
                np.take(points, sel, axis=1), u0[sel], u1[sel])
        return wi, dist, radiance, pdf


@register_light
class SphereLightModel(LightModel):
    kind = "sphere"
    usd_types = ("SphereLight",)
    usd_inputs = {"radius": 0.5, "treatAsPoint": False}

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        """The sphere of ``radius`` (its magnitude, as HdEmbree's areas) under the light's transform: under a
        non-uniform scale the ellipsoid of semi-axes a, b, c (the radius × the scale of local X, Y, Z; ``size`` =
        (a, b, c), a sphere keeps (r, 0) so its capture hash is unchanged; before 2026-12-08 it was drawn as the
        sphere of the ellipsoid's area). UsdLux's ``normalize`` divides by the world-space surface area (stage
        units²) of that ellipsoid (Knud Thomsen's p = 1.6 formula, as HdEmbree's ``_AreaSphere``).
        ``treatAsPoint`` (and radius 0): a point of the same radiant intensity I = L·πr² as the sphere of the
        ellipsoid's area, drawn as a tiny sphere that probes see (splatted, as small light shapes) and nothing
        hits; a normalized one of radius 0 is the limit of the normalized spheres, I = intensity/4 (in stage-unit²
        areas: × metersPerUnit²), an unnormalized one I = intensity (UsdLux leaves zero-area lights to the renderer;
        HdEmbree's emit nothing)."""
        lengths = np.asarray(placement.lengths)
        notes = []
        radius_local = float(inputs["radius"])
        if not math.isfinite(radius_local):
            raise ValueError(f"SphereLight radius {radius_local} is not finite")
        if radius_local < 0:
            notes.append(f"SphereLight radius {radius_local} is negative; its magnitude is used")
            radius_local = -radius_local
        # world-space (stage units) ellipsoid area, as HdEmbree's _AreaSphere
        area_su = ellipsoid_area(*(radius_local * lengths / placement.meters_per_unit).tolist())
        # the sphere of the ellipsoid's area (the mean axis for a uniform scale: the same sphere)
        radius = math.sqrt(area_su / (4.0 * math.pi)) * placement.meters_per_unit
        radiance = _normalized(emission, normalize, area_su)
        if bool(inputs["treatAsPoint"]) or radius <= 0:
            # a point of the same radiant intensity I = L·πr² as the sphere, drawn as a tiny sphere
            tiny = 1e-4
            if radius > 0:
                factor = (radius / tiny) ** 2
            elif normalize:  # lim r→0 of L/(4πr²)·πr² (areas in stage units², radius in metres)
                factor = placement.meters_per_unit**2 / (4.0 * math.pi * tiny**2)
            else:
                factor = 1.0 / (math.pi * tiny**2)
            return Light("sphere", name, radiance=tuple(float(x) for x in radiance * factor),
                         position=placement.position, axes=placement.axes, size=(tiny, 0.0)), notes
        semi_axes = tuple(float(x) for x in radius_local * lengths)
        flat = min(semi_axes) <= 1e-9 * max(semi_axes)
        if flat:  # scaled to zero along an axis: no volume to draw; the sphere of its area keeps its power
            notes.append("SphereLight scaled to zero along an axis is drawn as the sphere of its ellipsoid's area "
                         f"(radius {radius:.4g} m)")
        size = semi_axes if _non_uniform(lengths) and not flat else (radius, 0.0)
        return Light("sphere", name, radiance=tuple(float(x) for x in radiance), position=placement.position,
                     axes=placement.axes, size=size), notes

    def __init__(self, light: Light, textures: tuple = ()) -> None:
        super().__init__(light, textures)
        #: an ellipsoid (size = semi-axes a, b, c): M = [a·X | b·Y | c·Z] maps the unit sphere onto it, M⁻¹ back
        self.ellipsoid = len(light.size) == 3
        if self.ellipsoid:
            self._from_unit = self.axes.T * np.asarray(light.size, dtype=np.float64)
            self._to_unit = np.linalg.inv(self._from_unit)
            self._det_to_unit = abs(float(np.linalg.det(self._to_unit)))

    @property
    def radius(self) -> float:
        """The sphere's radius (an ellipsoid's largest semi-axis)."""
        return float(max(self.light.size))

    @property
    def bounding_radius(self) -> float:
        return self.radius

    @property
    def plain(self) -> bool:
        """A sphere of radiance independent of direction (no shaping, no IES profile): :class:`LightSampler`
        samples it with the other plain spheres."""
        return not self.ellipsoid and not self.light.shaping and self.light.ies is None

    def _unit_space(self, v: np.ndarray) -> np.ndarray:
        """Vectors (3, M) in the space where the ellipsoid is the unit sphere at the origin: M⁻¹·v."""
        return self._to_unit.astype(v.dtype) @ v

    def _unit_points(self, points: np.ndarray) -> np.ndarray:
        """Points (3, M) in that space: M⁻¹·(p − c)."""
        centre, _ = self._cols(points.dtype)
        return self._unit_space(points - centre)

    def sample_soa(self, points, u0, u1):  # noqa: ANN001, ANN201
        centre, _ = self._cols(points.dtype)
        if not self.ellipsoid:
            wi, dist, outside, pdf = _sample_sphere(points, centre, self.radius, u0, u1)
            return wi, dist, self.emitted_soa(wi, None, outside), pdf
        origin = np.zeros((3, 1), dtype=points.dtype)
        wi_unit, dist_unit, outside, pdf_unit = _sample_sphere(self._unit_points(points), origin, 1.0, u0, u1)
        v = self._from_unit.astype(points.dtype) @ wi_unit  # M·ω'
        length = np.sqrt(dot(v, v))
        wi = v / np.maximum(length, TINY)
        # the hit p' + t'·ω' maps to p + t'·M·ω': world distance t'·|M·ω'|; |M⁻¹ω| = 1/|M·ω'|
        pdf = pdf_unit * self._det_to_unit * length**3
        return wi, dist_unit * length, self.emitted_soa(wi, None, outside), pdf.astype(points.dtype, copy=False)

    def pdf_soa(self, points, wi, t):  # noqa: ANN001, ANN201
        if not self.ellipsoid:
            centre, _ = self._cols(points.dtype)
            _, _, outside, one_minus_cos = _sphere_cone(points, centre, self.radius)
            return (outside / (2.0 * np.pi * np.maximum(one_minus_cos, TINY))).astype(points.dtype, copy=False)
        origin = np.zeros((3, 1), dtype=points.dtype)
        _, _, outside, one_minus_cos = _sphere_cone(self._unit_points(points), origin, 1.0)
        w = self._unit_space(wi)
        inv_length = np.sqrt(dot(w, w))  # |M⁻¹ω|
        pdf = outside / (2.0 * np.pi * np.maximum(one_minus_cos, TINY)) * self._det_to_unit / inv_length**3
        return pdf.astype(points.dtype, copy=False)

    def intersect_soa(self, origins, directions):  # noqa: ANN001, ANN201
        m = origins.shape[1]
        if not self.visible:
            return np.full(m, FAR, dtype=origins.dtype), None
        centre, _ = self._cols(origins.dtype)
        if not self.ellipsoid:
            return _sphere_hits(origins, directions, centre, self.radius * self.radius), None
        # the unit sphere along M⁻¹(o − c) + t·M⁻¹d: the same t once the direction is normalised back
        d = self._unit_space(directions)
        scale = np.sqrt(dot(d, d))
        t_unit = _sphere_hits(self._unit_points(origins), d / np.maximum(scale, TINY),
                              np.zeros((3, 1), dtype=origins.dtype), 1.0)
        return np.where(t_unit < FAR, t_unit / np.maximum(scale, TINY), FAR).astype(origins.dtype, copy=False), None


class _PlanarLight(LightModel):
    def tree_bound(self) -> LightBound:
        """One-sided: every emission direction is within 90° of the light's −Z (and of its shaping cone)."""
        bound = super().tree_bound()
        return dataclasses.replace(bound, axis=tuple(-self.axes[2]), cos_normal=1.0,
                                   cos_emission=max(0.0, bound.cos_emission))

    """Rect and disk: a surface in the local XY plane emitting towards local −Z, sampled uniformly by area."""

    def _surface_point(self, u0: np.ndarray, u1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _inside(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def sample_soa(self, points, u0, u1):  # noqa: ANN001, ANN201
        a, b = self._surface_point(u0, u1)
        centre, _ = self._cols(points.dtype)
        x, y = self.x_axis, self.y_axis
        to_q = np.stack([a * x[0] + b * y[0], a * x[1] + b * y[1], a * x[2] + b * y[2]]) + (centre - points)
        dist = np.sqrt(dot(to_q, to_q))
        wi = to_q / np.maximum(dist, TINY)
        cos_l = dotc(self.z_axis, wi)  # the emitting side is −Z: seen from points where ωᵢ·Z > 0
        facing = cos_l > 0
        with np.errstate(over="ignore"):  # the far points behind the light (masked out) may overflow float32
            pdf = np.where(facing, dist * dist / (self.light.area * np.maximum(cos_l, TINY)), 0)
        radiance = self.emitted_soa(wi, np.stack([a, b]), facing)
        return wi, dist, radiance, pdf.astype(points.dtype, copy=False)

    def pdf_soa(self, points, wi, t):  # noqa: ANN001, ANN201
        cos_l = dotc(self.z_axis, wi)
        with np.errstate(over="ignore"):  # as in sample_soa
            pdf = np.where(cos_l > 0, t * t / (self.light.area * np.maximum(np.abs(cos_l), TINY)), 0)
        return pdf.astype(wi.dtype, copy=False)

    def intersect_soa(self, origins, directions):  # noqa: ANN001, ANN201
        m = origins.shape[1]
        if not self.visible:
            return np.full(m, FAR, dtype=origins.dtype), None
        centre, _ = self._cols(origins.dtype)
        denom = dotc(self.z_axis, directions)
        rel = origins - centre
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -dotc(self.z_axis, rel) / denom
        finite = np.isfinite(t)
        t = np.where(finite, t, 0)
        p = rel + t * directions
        a, b = dotc(self.x_axis, p), dotc(self.y_axis, p)
        hit = finite & (t > 0) & self._inside(a, b)
        return np.where(hit, t, FAR).astype(origins.dtype, copy=False), np.stack([a, b])

    @property
    def bounding_radius(self) -> float:
        if self.kind == "rect":
            return 0.5 * math.hypot(self.light.size[0], self.light.size[1])
        return float(max(self.light.size[0], self.light.size[1]))  # a disk's larger semi-axis


@register_light
class RectLightModel(_PlanarLight):
    kind = "rect"
    usd_types = ("RectLight",)
    usd_inputs = {"width": 1.0, "height": 1.0}

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        notes: list[str] = []
        w = _magnitude("RectLight width", float(inputs["width"]), notes)
        h = _magnitude("RectLight height", float(inputs["height"]), notes)
        width = w * placement.lengths[0]
        height = h * placement.lengths[1]
        area_su = width * height / placement.meters_per_unit**2
        radiance = _normalized(emission, normalize, area_su)
        return Light("rect", name, radiance=tuple(float(x) for x in radiance), position=placement.position,
                     axes=placement.axes, size=(width, height)), notes

    def _surface_point(self, u0, u1):  # noqa: ANN001, ANN202
        return (u0 - 0.5) * float(self.light.size[0]), (u1 - 0.5) * float(self.light.size[1])

    def _inside(self, a, b):  # noqa: ANN001, ANN202
        return (np.abs(a) <= 0.5 * float(self.light.size[0])) & (np.abs(b) <= 0.5 * float(self.light.size[1]))

    def _texel(self, coords):  # noqa: ANN001, ANN202
        """UsdLuxRectLight: "in the default position, a texture file's min coordinates should be at (+X, +Y) and max
        coordinates at (-X, -Y)": s = ½ − a/width (column 0 at local +X), t = ½ − b/height (row 0, the file's top
        row, at local +Y), nearest texel — the image upright and unmirrored seen from the lit side (−Z), as HdEmbree
        shows a rect light to the camera (its next-event lookup, s = a/width + ½, is mirrored)."""
        h, w = self.texture.shape[:2]
        s = np.clip(0.5 - coords[0].astype(np.float64) / self.light.size[0], 0.0, 1.0 - 1e-9)
        t = np.clip(0.5 - coords[1].astype(np.float64) / self.light.size[1], 0.0, 1.0 - 1e-9)
        index = (t * h).astype(np.int64) * w + (s * w).astype(np.int64)
        flat = self.texture.reshape(-1, 3)
        return np.stack([np.take(flat[:, c], index) for c in range(3)]).astype(coords.dtype, copy=False)


@register_light
class DiskLightModel(_PlanarLight):
    kind = "disk"
    usd_types = ("DiskLight",)
    usd_inputs = {"radius": 0.5}

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        """The disk of ``radius`` (its magnitude) under the light's transform: the ellipse of semi-axes a, b (the
        radius × the scale of local X, Y; ``size`` = (a, b), or (r, 0) for a circle); ``normalize`` divides by its
        world-space area π·a·b (stage units², as HdEmbree's ``_AreaDisk``). Before 2026-12-07 a non-uniformly scaled
        disk was drawn as the circle of the ellipse's area (its power exact, its shape not)."""
        notes: list[str] = []
        r_local = _magnitude("DiskLight radius", float(inputs["radius"]), notes)
        a, b = r_local * placement.lengths[0], r_local * placement.lengths[1]
        # a circle keeps size (r, 0), so its capture hash is unchanged; a degenerate ellipse (a·b = 0) is (0, 0)
        size = (a, b) if a * b > 0 and _non_uniform(placement.lengths[:2]) else (math.sqrt(a * b), 0.0)
        area_su = math.pi * a * b / placement.meters_per_unit**2
        radiance = _normalized(emission, normalize, area_su)
        return Light("disk", name, radiance=tuple(float(x) for x in radiance), position=placement.position,
                     axes=placement.axes, size=size), notes

    @property
    def _semi_axes(self) -> tuple[float, float]:
        a, b = float(self.light.size[0]), float(self.light.size[1])
        return a, (b if b > 0 else a)

    def _surface_point(self, u0, u1):  # noqa: ANN001, ANN202
        """Uniform by area: the unit disk's polar map (ρ = √u0) stretched to the ellipse (a constant Jacobian)."""
        a, b = self._semi_axes
        rad = np.sqrt(u0)
        phi = (2.0 * np.pi) * u1
        return a * rad * np.cos(phi), b * rad * np.sin(phi)

    def _inside(self, x, y):  # noqa: ANN001, ANN202
        a, b = self._semi_axes
        return (x / a) ** 2 + (y / b) ** 2 <= 1.0


@register_light
class CylinderLightModel(LightModel):
    kind = "cylinder"
    usd_types = ("CylinderLight",)
    usd_inputs = {"radius": 0.5, "length": 1.0, "treatAsLine": False}

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        """The lateral surface of ``radius`` and ``length`` (their magnitudes) under the light's transform: a
        section scaled non-uniformly is the ellipse of semi-axes a, b (the radius × the scale of local Y, Z;
        ``size`` = (a, b, length), a circular one keeps (r, length) so its capture hash is unchanged; before
        2026-12-08 it was drawn as the circle of the same perimeter). ``normalize`` divides by its world-space area,
        Ramanujan's perimeter of the section × the length (stage units², as HdEmbree's ``_AreaCylinder``)."""
        notes: list[str] = []
        r_local = _magnitude("CylinderLight radius", float(inputs["radius"]), notes)
        l_local = _magnitude("CylinderLight length", float(inputs["length"]), notes)
        lengths = placement.lengths
        length = l_local * lengths[0]
        mpu = placement.meters_per_unit
        a, b, c = r_local * lengths[1] / mpu, r_local * lengths[2] / mpu, l_local * lengths[0] / mpu
        perimeter = ellipse_perimeter(a, b)
        radius = perimeter / (2.0 * math.pi) * mpu  # the circle of the same perimeter (a for a = b)
        size: tuple[float, ...] = (radius, length)
        if r_local > 0 and _non_uniform(lengths[1:]):
            if min(a, b) > 1e-9 * max(a, b):
                size = (a * mpu, b * mpu, length)
            else:  # flattened to a strip: no section to draw; the circle of its perimeter keeps its power
                notes.append("CylinderLight scaled to zero across its axis is drawn as the circular cylinder of the "
                             f"same area (radius {radius:.4g} m)")
        radiance = _normalized(emission, normalize, perimeter * c)
        if bool(inputs["treatAsLine"]):
            notes.append("treatAsLine is a hint; the cylinder's surface is rendered")
        return Light("cylinder", name, radiance=tuple(float(x) for x in radiance), position=placement.position,
                     axes=placement.axes, size=size), notes

    @property
    def _section(self) -> tuple[float, float]:
        """The section's semi-axes (along local Y, Z): (r, r) for a circle."""
        size = self.light.size
        return (float(size[0]), float(size[1])) if len(size) == 3 else (float(size[0]), float(size[0]))

    @property
    def _length(self) -> float:
        return float(self.light.size[-1])

    @property
    def bounding_radius(self) -> float:
        return math.hypot(max(self._section), 0.5 * self._length)

    def _facing(self, rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(cos φ₀, sin φ₀) (M,) each: the unit-circle direction of the points' projections (rel = point − centre,
        (3, M)) in the section's coordinates (y/a, z/b). The surface the points see lies within ±π/2 of φ₀
        (facing, n·(p − q) > 0, is affine-invariant)."""
        a, b = self._section
        cy, cz = dotc(self.y_axis, rel) / a, dotc(self.z_axis, rel) / b
        norm = np.sqrt(cy * cy + cz * cz)
        axial = norm <= 0  # on the axis: no outside point is seen; any direction
        norm = np.where(axial, 1, norm)
        return np.where(axial, 1, cy / norm), cz / norm

    def sample_soa(self, points, u0, u1):  # noqa: ANN001, ANN201
        """On the half of the lateral surface that faces the point (everything it can see lies there), uniform
        along the axis and in the azimuth φ = φ₀ + asin(2u − 1) around the points' direction φ₀: density
        cos(φ − φ₀)/2, the surface's projected width seen from afar, so a distant tube's samples all weigh the same
        (uniform in φ, until 2026-12-08: 3 % noise on a splatted tube's 36 samples, 65–90 % per sample on a floor
        beside it). The area density is that over L·(arc element): r for a circle, √(a²sin²φ + b²cos²φ) for the
        ellipse (a·cos φ, b·sin φ)."""
        length = self._length
        centre, _ = self._cols(points.dtype)
        if not self.light.area > 0:  # radius or length 0: nothing emits (no sample)
            m = points.shape[1]
            wi = np.zeros_like(points)
            wi[2] = 1
            return wi, np.zeros(m, points.dtype), np.zeros_like(points), np.zeros(m, points.dtype)
        rel = points - centre
        z = (u0 - 0.5) * length
        c0, s0 = self._facing(rel)
        s = 2.0 * u1 - 1.0  # sin(φ − φ₀), uniform: the projected width
        c = 2.0 * np.sqrt(np.maximum(0, u1 * (1.0 - u1)))  # cos(φ − φ₀) = √((1 − s)(1 + s)), no cancellation
        cp, sp = c * c0 - s * s0, c * s0 + s * c0  # cos φ, sin φ
        x, y, zz = self.x_axis, self.y_axis, self.z_axis
        a, b = self._section
        arc = np.sqrt((a * sp) ** 2 + (b * cp) ** 2) if len(self.light.size) == 3 else a
        # the outward normal ∝ (b·cos φ, a·sin φ) (Y, Z), ÷ the arc element; the point (a·cos φ, b·sin φ)
        ny, nz = b * cp / arc, a * sp / arc
        normal = np.stack([ny * y[0] + nz * zz[0], ny * y[1] + nz * zz[1], ny * y[2] + nz * zz[2]])
        ay, bz = a * cp, b * sp
        point = np.stack([ay * y[0] + bz * zz[0], ay * y[1] + bz * zz[1], ay * y[2] + bz * zz[2]])
        to_q = point - rel + np.stack([z * x[0], z * x[1], z * x[2]])
        area_density = 0.5 * c / (length * arc)
        dist = np.sqrt(dot(to_q, to_q))
        wi = to_q / np.maximum(dist, TINY)
        cos_l = -dot(wi, normal)
        facing = cos_l > 0
        with np.errstate(over="ignore"):  # as the planar lights'
            pdf = np.where(facing, dist * dist * area_density / np.maximum(cos_l, TINY), 0)
        return wi, dist, self.emitted_soa(wi, None, facing), pdf.astype(points.dtype, copy=False)

    def _hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest t (M,) (FAR if none) of rays with the lateral surface, and the outward normal's direction there
        (3, M) (unnormalised): an elliptic section is the unit circle in coordinates (y/a, z/b)."""
        length = self._length
        centre, _ = self._cols(origins.dtype)
        o = origins - centre
        ox, dx = dotc(self.x_axis, o), dotc(self.x_axis, directions)
        oy, oz = dotc(self.y_axis, o), dotc(self.z_axis, o)
        dy, dz = dotc(self.y_axis, directions), dotc(self.z_axis, directions)
        elliptic = len(self.light.size) == 3
        if elliptic:
            sa, sb = self._section
            oy, dy, oz, dz = oy / sa, dy / sa, oz / sb, dz / sb
            r = 1.0
        else:
            r = float(self.light.size[0])
        a = dy * dy + dz * dz
        b = oy * dy + oz * dz
        c = oy * oy + oz * oz - r * r
        disc = b * b - a * c
        sq = np.sqrt(np.maximum(disc, 0))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t0 = (-b - sq) / a
            t1 = (-b + sq) / a
        best = np.full(origins.shape[1], FAR, dtype=origins.dtype)
        ok0 = (disc >= 0) & (a > 0)
        for t in (t1, t0):  # t0 last so it wins when both are valid
            x = ox + t * dx
            ok = ok0 & np.isfinite(t) & (t > 0) & (np.abs(x) <= 0.5 * length)
            best = np.where(ok & (t < best), t, best)
        if elliptic:  # ∇((y/a)² + (z/b)²) ∝ (y'/a)·Y + (z'/b)·Z with the unit-circle coordinates y', z'
            hit = np.where(best < FAR, best, 0)
            ny, nz = (oy + hit * dy) / sa, (oz + hit * dz) / sb
            y_axis, z_axis = (np.asarray(v, dtype=origins.dtype)[:, None] for v in (self.y_axis, self.z_axis))
            return best, ny * y_axis + nz * z_axis
        p = o + np.where(best < FAR, best, 0) * directions
        radial = p - dotc(self.x_axis, p) * np.asarray(self.x_axis, dtype=origins.dtype)[:, None]
        return best, radial

    def pdf_soa(self, points, wi, t):  # noqa: ANN001, ANN201
        if not self.light.area > 0:
            return np.zeros(points.shape[1], dtype=wi.dtype)
        _, radial = self._hit(points, wi)
        n = radial / np.maximum(np.sqrt(dot(radial, radial)), TINY)
        cos_l = np.abs(dot(wi, n))
        # the sampler's area density at the hit: cos(φ − φ₀)/(2·L·arc element), φ from the hit's unit-circle point
        a, b = self._section
        centre, _ = self._cols(points.dtype)
        rel = points - centre
        q = rel + t * wi
        cp, sp = dotc(self.y_axis, q) / a, dotc(self.z_axis, q) / b
        c0, s0 = self._facing(rel)
        arc = np.sqrt((a * sp) ** 2 + (b * cp) ** 2) if len(self.light.size) == 3 else a
        area_density = 0.5 * np.maximum(cp * c0 + sp * s0, 0) / (self._length * arc)
        return np.where(cos_l > 0, t * t * area_density / np.maximum(cos_l, TINY), 0).astype(wi.dtype, copy=False)

    def intersect_soa(self, origins, directions):  # noqa: ANN001, ANN201
        if not self.visible:
            return np.full(origins.shape[1], FAR, dtype=origins.dtype), None
        t, _ = self._hit(origins, directions)
        return t, None


# ----------------------------------------------------------------------------------------------------------------
class LightSet:
    """All analytic lights of a scene for the renderer: surfaces along rays, occlusion by light shapes."""

    def __init__(self, lights: tuple[Light, ...], textures: tuple = ()) -> None:
        self.models = tuple(light_model(light, textures) for light in lights)
        self.surfaces = tuple(m for m in self.models if m.visible and not m.is_global)
        self.distant = tuple(m for m in self.models if isinstance(m, DistantLightModel))
        #: from PROXY_CULLED_SHAPES light shapes, an Embree query against icosahedra around their culling spheres
        #: finds the segments that may meet any (:class:`bakery.capture.tracer.SphereCuller`); only those run the
        #: shapes' tests — every shape's, or above CULLED_SHAPES the pairs a BVH over the culling spheres finds
        #: (:mod:`bakery.capture.light_tree`) — so the same pairs are tested as on every segment. Above CULLED_SHAPES
        #: the shape a flagged shadow segment meets first is tested alone before the BVH (:meth:`occluded_soa`)
        self._culler = None
        self._shape_bvh = None
        centres = np.array([m.centre for m in self.surfaces], dtype=np.float64).reshape(-1, 3)
        radii = np.array([self._cull_radius(m) for m in self.surfaces], dtype=np.float64)
        if len(self.surfaces) >= PROXY_CULLED_SHAPES:
            self._culler = SphereCuller(centres, radii)
            #: a shadow segment that ends on shape k is queried up to 2·R_k before its end: the rest lies within
            #: 3·R_k of k's centre, where only the shapes whose culling spheres reach that ball can be met
            self._end_margin = 2.0 * radii * (1.0 + 1e-3) + 1e-5
            #: per shape k, those shapes (CSR: offsets (K + 1,), indices) whose culling spheres reach that ball
            self._end_neighbours = _balls_reached(centres, 3.0 * radii, radii)
            self._near_end = np.r_[np.diff(self._end_neighbours[0]) > 0, False]  # index −1: no shape
        if self._culler is not None and len(self.surfaces) > CULLED_SHAPES:  # the BVH's pairs need the culler
            self._shape_bvh = LightBVH([LightBound(tuple(c - r), tuple(c + r), 1.0)
                                        for c, r in zip(centres, radii, strict=True)])
        #: with the BVH, the sphere shapes' (segment, shape) pairs are intersected together (:func:`_sphere_hits`)
        self._sphere = np.array([isinstance(m, SphereLightModel) and not m.ellipsoid for m in self.surfaces],
                                dtype=bool)
        self._sphere_centres = np.array([m.centre for m in self.surfaces], dtype=np.float64).reshape(-1, 3).T
        self._sphere_r2 = [m.radius * m.radius if isinstance(m, SphereLightModel) else 0.0 for m in self.surfaces]

    def _sphere_pairs_hits(self, origins: np.ndarray, directions: np.ndarray, seg: np.ndarray, light: np.ndarray,
                           origin_of: np.ndarray | None = None) -> np.ndarray:
        """t (K,) of the (segment, sphere shape) pairs, all at once: the arithmetic of
        :meth:`SphereLightModel.intersect_soa` with per-pair centres and radii."""
        dtype = directions.dtype
        o = np.take(origins, seg if origin_of is None else origin_of[seg], axis=1)
        centres = np.take(self._sphere_centres.astype(dtype), light, axis=1)
        r2 = np.array(self._sphere_r2, dtype=dtype).take(light)  # each r·r rounded once, as a Python float would be
        return _sphere_hits(o, np.take(directions, seg, axis=1), centres, r2)

    @staticmethod
    def _cull_radius(model: LightModel) -> float:
        return model.bounding_radius * 1.01 + 1e-4

    def _pairs(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray | float,
               skip: np.ndarray | int | None = None, where: np.ndarray | None = None, near: np.ndarray | None = None
               ) -> tuple[list[tuple[int, np.ndarray]], tuple[np.ndarray, np.ndarray] | None]:
        """Per light shape k (ascending), the segments (ascending flat indices of ``directions`` (3, ..., M)) that
        pass its culling sphere — every shape's test over all segments, or the BVH's pairs (above CULLED_SHAPES
        shapes; the same segments up to the looser boxes, which the exact tests then reject) — without those whose
        ``skip`` is k; with the BVH, the sphere shapes' pairs apart as (segment, shape) arrays, by segment then
        shape (None without it). With ``where`` (bool, shape of the segments) the Embree culler looks at those
        segments alone (the other paths may still list others); ``near`` (one bool per ``where`` segment, in
        order) is the culler's answer for them if already known."""
        shape = directions.shape[1:]
        m = directions.shape[-1]
        skip_flat = None if skip is None or np.ndim(skip) == 0 else np.broadcast_to(skip, shape).reshape(-1)
        out = []
        if self._culler is None:  # a few shapes: each tests every segment
            for k, model in enumerate(self.surfaces):
                cand = self._candidates(model, origins, directions, distances)
                if skip is not None:
                    cand &= np.asarray(skip) != k
                idx = np.flatnonzero(cand)
                if idx.size:
                    out.append((k, idx))
            return out, None
        d_flat = directions.reshape(3, -1)
        broadcast = origins.ndim != directions.ndim
        o_flat = origins if broadcast else origins.reshape(3, -1)
        origin_of = np.arange(d_flat.shape[1]) % m if broadcast else None
        dist_flat = np.broadcast_to(np.asarray(distances, dtype=np.float64), shape).reshape(-1)
        tails = self._shape_bvh is not None  # with the BVH, a segment's end near other shapes lists them as pairs
        sel, tail = self._near_segments(o_flat, d_flat, dist_flat, origin_of,
                                        skip_flat if skip_flat is not None else skip,
                                        None if where is None else np.broadcast_to(where, shape).reshape(-1), tails,
                                        near)
        if sel.size == 0 and tail[0].size == 0:
            return out, None
        rows = sel if origin_of is None else origin_of[sel]  # the selected segments' origins
        d_sel, dist_sel = np.take(d_flat, sel, axis=1), dist_flat[sel]
        if self._shape_bvh is None:
            o_sel = np.take(o_flat, rows, axis=1)
            for k, model in enumerate(self.surfaces):
                cand = self._candidates(model, o_sel, d_sel, dist_sel)
                if skip is not None:
                    cand &= (skip_flat[sel] if skip_flat is not None else int(skip)) != k
                idx = sel[cand]
                if idx.size:
                    out.append((k, idx))
            return out, None
        seg, light = self._shape_bvh.candidates(o_flat, d_sel, dist_sel, rows)
        seg = sel[seg]  # ascending like the selection: still by segment, then light
        if tail[0].size:  # segments whose head met no shape, tested against the shapes near their end
            seg, light = np.r_[seg, tail[0]], np.r_[light, tail[1]]
            order = np.lexsort((light, seg))
            seg, light = seg[order], light[order]
        if skip is not None:
            keep = light != (skip_flat[seg] if skip_flat is not None else int(skip))
            seg, light = seg[keep], light[keep]
        sphere = self._sphere[light]
        spheres = (seg[sphere], light[sphere])
        seg, light = seg[~sphere], light[~sphere]
        out.extend((k, seg[positions]) for k, positions in _runs_by_shape(light))  # each shape's segments ascending
        return out, spheres

    def _near_segments(self, o_flat: np.ndarray, d_flat: np.ndarray, dist_flat: np.ndarray,
                       origin_of: np.ndarray | None, skip: np.ndarray | int | None, where: np.ndarray | None,
                       tails: bool = False, near: np.ndarray | None = None
                       ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """Flat indices (ascending) of the segments (directions (3, S), distances (S,); origins (3, S), or (3, M)
        by ``origin_of``) that may meet a light shape, by the Embree culler: those in ``where`` (S,) (all
        without); a segment that ends on shape k (``skip``: (S,) or one int, −1 none) is queried up to k's culling
        ball only (the rest lies within 3·R_k of k's centre), and kept whenever another shape's culling sphere
        reaches that ball — or, with ``tails``, not kept but listed with those shapes as (segment, shape) pairs
        (by segment, then shape; the second item). ``near`` (one bool per selected segment): the culler's answer,
        if already known."""
        sel = np.arange(d_flat.shape[1]) if where is None else np.flatnonzero(where)
        ends = None
        if skip is not None:
            ends = np.asarray(skip)[sel] if np.ndim(skip) else np.full(sel.size, int(skip))
        if near is None:
            query = self._query_lengths(dist_flat[sel], ends)
            if where is None:
                near = self._culler.flag(o_flat, d_flat, query, origin_of)
            else:
                near = self._culler.flag(o_flat, np.take(d_flat, sel, axis=1), query,
                                         sel if origin_of is None else origin_of[sel])
        empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
        if ends is None:
            return sel[near], empty
        if not tails:
            return sel[near | self._near_end[ends]], empty
        rest = np.flatnonzero(~near & self._near_end[ends])
        offsets, indices = self._end_neighbours
        k = ends[rest]
        counts = offsets[k + 1] - offsets[k]
        first = np.repeat(offsets[k] - (np.cumsum(counts) - counts), counts)
        pairs = (np.repeat(sel[rest], counts), indices[first + np.arange(int(counts.sum()))])
        return sel[near], pairs

    def _query_lengths(self, distances: np.ndarray, ends: np.ndarray | None) -> np.ndarray:
        """How far the culler queries segments of lengths (S,) that end on shapes ``ends`` (S,) (−1: none): up to
        2·R_k before the end on shape k (:meth:`_near_segments`)."""
        if ends is None:
            return distances
        on = ends >= 0
        return np.where(on, np.maximum(0.0, distances - self._end_margin[np.where(on, ends, 0)]), distances)

    def _candidates(self, model: LightModel, origins: np.ndarray, directions: np.ndarray,
                    distances: np.ndarray | float) -> np.ndarray:
        """Conservative cull (bool, broadcast shape of the rays): segments origin + t·direction, 0 < t < distance,
        that pass within the light's bounding sphere; origins (3, ..., M) may broadcast against directions."""
        radius = model.bounding_radius * 1.01 + 1e-4
        centre, _ = model._cols(directions.dtype)
        oc = origins - (centre if origins.ndim == 2 else centre[:, None, :])
        c2 = dot(oc, oc)
        b = dot(oc, directions)
        perp2 = c2 - b * b  # squared distance of the centre from the ray's line (unit directions)
        return (perp2 <= radius * radius + 1e-6 * c2) & (b < radius) & (-b < distances + radius)

    def nearest_soa(self, origins: np.ndarray, directions: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Nearest light surface along rays (3, M): distance (M,) (FAR if none), light index into :attr:`surfaces`
        (M,) (−1 if none) and the radiance (3, M) it sends back along the ray (None when there are no surfaces).
        Only rays passing a light's bounding sphere are intersected with it."""
        m, dtype = directions.shape[1], directions.dtype
        best = np.full(m, FAR, dtype=dtype)
        which = np.full(m, -1, dtype=np.int64)
        if not self.surfaces:
            return best, which, None
        coords: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # per textured light: (tested rays, their coords)
        groups, spheres = self._pairs(origins, directions, FAR)
        if spheres is not None and spheres[0].size:  # the nearest sphere per ray: least t, then least index
            seg, light = spheres
            t = self._sphere_pairs_hits(origins, directions, seg, light)
            order = np.lexsort((light, t, seg))
            first = order[np.r_[True, seg[order][1:] != seg[order][:-1]]]
            first = first[t[first] < FAR]
            best[seg[first]], which[seg[first]] = t[first], light[first]
        for k, idx in groups:  # every other shape in index order, as the loop over all shapes
            model = self.surfaces[k]
            t, c = model.intersect_soa(np.take(origins, idx, axis=1), np.take(directions, idx, axis=1))
            closer = (t < best[idx]) | ((t == best[idx]) & (t < FAR) & (k < which[idx]))
            sel = idx[closer]
            best[sel] = t[closer]
            which[sel] = k
            if c is not None:
                coords[k] = (idx, c)
        radiance = np.zeros((3, m), dtype=dtype)
        hits = np.flatnonzero(which >= 0)
        hits = hits[np.argsort(which[hits], kind="stable")]  # grouped by light, ascending within
        ks = which[hits]
        starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]]) if hits.size else np.zeros(0, np.int64)
        for a, b in zip(starts, np.r_[starts[1:], hits.size]):
            k, sel = int(ks[a]), hits[a:b]
            model = self.surfaces[k]
            d = np.take(directions, sel, axis=1)
            facing = self._facing(model, d)
            c = None
            if k in coords:
                tested, values = coords[k]
                c = np.take(values, np.searchsorted(tested, sel), axis=1)
            radiance[:, sel] = model.emitted_soa(d, c, facing)
        return best, which, radiance

    def nearest(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """As :meth:`nearest_soa` with (M, 3) rays and radiance."""
        best, which, radiance = self.nearest_soa(_soa(origins), _soa(directions))
        return best, which, np.zeros((best.size, 3)) if radiance is None else _aos(radiance)

    @staticmethod
    def _facing(model: LightModel, directions: np.ndarray) -> np.ndarray:
        if isinstance(model, _PlanarLight):
            return dotc(model.z_axis, directions) > 0
        return np.ones(directions.shape[1], dtype=bool)

    def occluded_soa(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray,
                     skip: np.ndarray | int | None = None, where: np.ndarray | None = None) -> np.ndarray:
        """Whether any light surface blocks the segments (3, ..., M) (shadow rays; ``origins`` may be (3, M) against
        directions (3, J, M), J segments per origin); ``skip`` (shape of the segments, or one int): index into
        :attr:`surfaces` of a light each segment ends on (−1: none), which is not tested against it (a convex
        shape cannot occlude a point of it that faces the segment's origin). Only segments passing a light's
        bounding sphere are intersected with it; with ``where`` (bool, shape of the segments), only those segments
        need an answer (the others may be reported unblocked)."""
        shape = directions.shape[1:]
        blocked = np.zeros(shape, dtype=bool)
        flat = blocked.reshape(-1)
        m = directions.shape[-1]
        d_flat = directions.reshape(3, -1)
        dist_flat = np.broadcast_to(distances, shape).reshape(-1)
        near = None
        if self._shape_bvh is not None:  # the shape a segment meets first blocks most blocked segments: test it alone
            # before descending the shape BVH (with a few shapes, testing every one on the flagged segments is cheap)
            sel = np.arange(d_flat.shape[1]) if where is None else np.flatnonzero(np.broadcast_to(where, shape))
            ends = None if skip is None else np.broadcast_to(skip, shape).reshape(-1)[sel]
            near, first = self._first_shapes(origins, directions, dist_flat, ends, sel)
            test = np.flatnonzero(first >= 0)
            if ends is not None:
                test = test[first[test] != ends[test]]  # not the shape the segment ends on
            early = np.zeros(sel.size, dtype=bool)
            early[test] = self._pairs_block(origins, directions, dist_flat, sel[test], first[test])
            if early.any():  # the others as before, with the culler's answer for them known
                flat[sel[early]] = True
                rest = np.ones(flat.size, dtype=bool)
                rest[sel[early]] = False
                where = (rest if where is None else rest & np.broadcast_to(where, shape).reshape(-1)).reshape(shape)
                near = near[~early]
        groups, spheres = self._pairs(origins, directions, distances, skip, where, near)
        if spheres is not None and spheres[0].size:
            seg, light = spheres
            flat[seg[self._pairs_block(origins, directions, dist_flat, seg, light)]] = True
        for k, idx in groups:
            o = np.take(origins.reshape(3, -1) if origins.ndim == directions.ndim else origins,
                        idx if origins.ndim == directions.ndim else idx % m, axis=1)
            hit = self.surfaces[k].occludes_soa(o, np.take(d_flat, idx, axis=1), dist_flat[idx])
            flat[idx[hit]] = True
        return blocked

    def _first_shapes(self, origins: np.ndarray, directions: np.ndarray, dist_flat: np.ndarray,
                      ends: np.ndarray | None, sel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For the segments ``sel`` (flat indices) ending on shapes ``ends`` (len(sel),) (−1: none; None: no
        ends), over the culler's query (:meth:`_query_lengths`): whether each meets a culling icosahedron (the
        culler's occlusion query, bool) and, for those, the shape whose icosahedron it enters first (a
        closest-hit query on them alone; −1 elsewhere): both (len(sel),)."""
        broadcast = origins.ndim != directions.ndim
        o, d = (origins if broadcast else origins.reshape(3, -1)), directions.reshape(3, -1)
        every = sel.size == d.shape[1]  # sel is every segment: no gathers
        rows = sel % directions.shape[-1] if broadcast else (None if every else sel)
        if not every:
            d = np.take(d, sel, axis=1)
        query = self._query_lengths(dist_flat if every else dist_flat[sel], ends)
        near = self._culler.flag(o, d, query, rows)
        first = np.full(sel.size, -1, dtype=np.int64)
        met = np.flatnonzero(near)
        if met.size:
            first[met] = self._culler.first(o, np.take(d, met, axis=1), query[met],
                                            met if rows is None else rows[met])
        return near, first

    def _pairs_block(self, origins: np.ndarray, directions: np.ndarray, dist_flat: np.ndarray,
                     seg: np.ndarray, light: np.ndarray) -> np.ndarray:
        """Whether shape ``light`` blocks segment ``seg`` (pairs (K,), flat segment indices): bool (K,). With the
        shape BVH the sphere shapes' pairs are intersected together (:meth:`_sphere_pairs_hits`); the others, and
        every pair without the BVH, by their shape's own test — the tests :meth:`occluded_soa` runs on its pairs."""
        broadcast, m, d_flat = origins.ndim != directions.ndim, directions.shape[-1], directions.reshape(3, -1)
        o_flat = origins if broadcast else origins.reshape(3, -1)
        out = np.zeros(seg.size, dtype=bool)
        together = self._sphere[light] if self._shape_bvh is not None else np.zeros(seg.size, dtype=bool)
        if together.any():
            idx = np.flatnonzero(together)
            t = self._sphere_pairs_hits(o_flat, d_flat, seg[idx], light[idx],
                                        np.arange(d_flat.shape[1]) % m if broadcast else None)
            out[idx] = t < dist_flat[seg[idx]]
        rest = np.flatnonzero(~together)
        for k, positions in _runs_by_shape(light[rest]):
            idx = rest[positions]
            o = np.take(o_flat, seg[idx] % m if broadcast else seg[idx], axis=1)
            out[idx] = self.surfaces[k].occludes_soa(o, np.take(d_flat, seg[idx], axis=1), dist_flat[seg[idx]])
        return out

    def occluded(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray) -> np.ndarray:
        """Whether any light surface blocks the segments (M, 3) (shadow rays)."""
        return self.occluded_soa(_soa(origins), _soa(directions), np.asarray(distances, dtype=np.float64))


def _runs_by_shape(light: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """The positions of each shape's pairs (``light`` (K,) shape per pair): (shape, positions ascending) per shape
    that occurs, shapes ascending (one stable sort, not a scan per shape)."""
    if light.size == 0:
        return []
    order = np.argsort(light, kind="stable")
    ordered = light[order]
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    return [(int(ordered[a]), order[a:b]) for a, b in zip(starts, np.r_[starts[1:], ordered.size], strict=True)]


def _balls_reached(centres: np.ndarray, reach: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per sphere k (centres (K, 3), radii (K,)), the other spheres j that meet the ball of radius ``reach[k]``
    about k's centre (|c_j − c_k| ≤ reach_k + r_j, with a relative float margin), by a k-d tree: CSR offsets
    (K + 1,) and ascending indices."""
    from scipy.spatial import cKDTree

    margin = 1e-4 * (1.0 + float(np.abs(centres).max(initial=0.0)))
    found = cKDTree(centres).query_ball_point(centres, reach + radii.max(initial=0.0) + margin)
    lists = []
    for k, others in enumerate(found):
        others = np.sort(np.asarray([j for j in others if j != k], dtype=np.int64))
        gap = np.linalg.norm(centres[others] - centres[k], axis=1) - reach[k] - radii[others]
        lists.append(others[gap <= margin])
    offsets = np.r_[0, np.cumsum([len(x) for x in lists])].astype(np.int64)
    return offsets, np.concatenate(lists) if lists else np.zeros(0, dtype=np.int64)


def intersect_light_shapes(
    lights: tuple[Light, ...], origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest visible area-light surface along rays: distance (M,) (FAR if none) and its radiance (M, 3)."""
    t, _which, radiance = LightSet(lights).nearest(origins, directions)
    return t, radiance
