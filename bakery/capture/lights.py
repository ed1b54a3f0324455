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
    sphere    uniform in the cone the sphere subtends, pdf = 1/(2π(1−cos θmax)) [pbrt-v4 §12.2.2].
    rect      uniform on the area, pdf_ω = d²/(A·cos θ_l); emits towards local −Z only.
    disk      uniform on the area (r = R·√u), as rect.
    cylinder  uniform on the half of the lateral surface facing the point (axis = local X, as UsdLuxCylinderLight;
              no caps, as HdEmbree), pdf_ω = d²/(½A·cos θ_l); the cylinder's own surface occludes shadow rays.

Shaping (UsdLuxShapingAPI, as HdEmbree evaluates it)
    with c = cos of the angle between the emission direction and the light's −Z axis:
    focus: L *= lerp(focusTint, 1, |c|^focus); cone: L *= 1 − smoothstep(θ, (1 − softness)·θ_cone, θ_cone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bakery.capture.scene import FAR, Light
from bakery.sphere.sampling import orthonormal_frame

#: Relative shortening of shadow segments so the sampled light point itself does not occlude.
SHADOW_EPSILON = 1e-4


def sample_cone(axis: np.ndarray, one_minus_cos_max: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Uniform directions (M, 3) in cones around unit axes (M, 3) with 1 − cos θmax (M,); u (M, 2)."""
    one_minus_cos = u[:, 0] * one_minus_cos_max
    cos_t = 1.0 - one_minus_cos
    sin_t = np.sqrt(np.maximum(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = 2.0 * np.pi * u[:, 1]
    t, s = orthonormal_frame(axis)
    return (sin_t * np.cos(phi))[:, None] * t + (sin_t * np.sin(phi))[:, None] * s + cos_t[:, None] * axis


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
        return np.where(t <= lo, 0.0, 1.0)
    x = np.clip((t - lo) / (hi - lo), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class LightModel:
    """Interface of one light kind (module docstring). Instances wrap one :class:`Light`."""

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

    # -- reading (called by bakery.usd.scene with plain values) ----------------------------------------------------
    @classmethod
    def from_usd(cls, name: str, inputs: dict[str, Any], placement: Placement, emission: np.ndarray,
                 normalize: bool) -> tuple[Light, list[str]]:
        """The :class:`Light` for a prim of this kind, and messages about what was approximated."""
        raise NotImplementedError

    # -- rendering ------------------------------------------------------------------------------------------------
    def sample(self, points: np.ndarray, u: np.ndarray) -> LightSample:
        raise NotImplementedError

    def pdf(self, points: np.ndarray, wi: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (M,) of :meth:`sample` from ``points`` for directions wi that reach the light at t."""
        raise NotImplementedError

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest intersection t (M,) (FAR if none) of rays with the light's surface and its local (a, b) surface
        coordinates (M, 2) (for textures). Distant lights have no surface."""
        m = origins.shape[0]
        return np.full(m, FAR), np.zeros((m, 2))

    def emitted(self, wi: np.ndarray, coords: np.ndarray, facing: np.ndarray) -> np.ndarray:
        """Radiance (M, 3) arriving along wi (receiver → light) from surface points with local coordinates
        ``coords``; ``facing`` (M,) whether the surface emits towards the receiver there."""
        m = wi.shape[0]
        radiance = np.broadcast_to(self.colour, (m, 3)).copy()
        if self.texture is not None:
            radiance *= self._texel(coords)
        shaping = self.light.shaping
        if shaping:
            cone, softness, focus = shaping[0], shaping[1], shaping[2]
            tint = np.asarray(shaping[3:6], dtype=np.float64)
            c = np.clip(wi @ self.axes[2], -1.0, 1.0)  # emission direction (−wi) against the light's −Z
            if focus > 0:
                ff = np.abs(c) ** focus
                radiance *= (1.0 - ff)[:, None] * tint + ff[:, None]
            if cone < 180.0:
                theta = np.arccos(c)
                cone_r = math.radians(cone)
                radiance *= (1.0 - _smoothstep(theta, (1.0 - softness) * cone_r, cone_r))[:, None]
        return np.where(facing[:, None], radiance, 0.0)

    def _texel(self, coords: np.ndarray) -> np.ndarray:
        return np.ones((coords.shape[0], 3))

    def occludes(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray) -> np.ndarray:
        """Whether the light's surface blocks the segments origin + t·direction, 0 < t < distance."""
        if not self.visible:
            return np.zeros(origins.shape[0], dtype=bool)
        t, _ = self.intersect(origins, directions)
        return t < distances

    # -- incremental bakes ----------------------------------------------------------------------------------------
    @property
    def bounding_radius(self) -> float:
        return 0.0

    def bound(self) -> tuple[tuple[float, float, float], float, float]:
        """(centre, bounding radius, largest radiance channel × emitting area) (the dependency bound's inputs)."""
        return tuple(float(c) for c in self.centre), float(self.bounding_radius), float(
            np.max(self.colour) * self.light.area)


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


# ----------------------------------------------------------------------------------------------------------------
@register_light
class DistantLightModel(LightModel):
    kind = "distant"
    usd_types = ("DistantLight",)
    usd_inputs = {"angle": 0.53}
    is_global = True

    def __init__(self, light: Light, textures: tuple = ()) -> None:
        super().__init__(light, textures)
        self.alpha = math.radians(0.5 * light.angle)
        self.direction = self.axes[2] / np.linalg.norm(self.axes[2])
        self.illuminance = np.asarray(light.illuminance, dtype=np.float64)
        self.one_minus_cos = 2.0 * math.sin(0.5 * self.alpha) ** 2
        # radiance inside the disc: E = L·π·sin²α (UsdLux: illuminance at normal incidence)
        self.disc_radiance = self.illuminance / (math.pi * math.sin(self.alpha) ** 2) if self.alpha > 0 else None

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        angle = float(inputs["angle"])
        alpha = math.radians(0.5 * angle)
        illuminance = emission if normalize else emission * math.pi * math.sin(alpha) ** 2
        notes = []
        if not normalize and angle <= 0:
            notes.append("DistantLight with angle 0 and normalize off emits nothing (its illuminance is radiance × "
                         "the disc's solid angle); set inputs:normalize = 1")
        return Light("distant", name, illuminance=tuple(float(c) for c in illuminance), axes=placement.axes,
                     angle=angle), notes

    @property
    def delta(self) -> bool:
        return self.alpha <= 0

    def sample(self, points, u):  # noqa: ANN001, ANN201
        m = points.shape[0]
        axis = np.broadcast_to(self.direction, (m, 3))
        if self.delta:
            return LightSample(np.array(axis), np.full(m, FAR), np.broadcast_to(self.illuminance, (m, 3)).copy(),
                               np.full(m, np.inf))
        wi = sample_cone(axis, np.full(m, self.one_minus_cos), u)
        pdf = np.full(m, 1.0 / (2.0 * np.pi * self.one_minus_cos))
        return LightSample(wi, np.full(m, FAR), np.broadcast_to(self.disc_radiance, (m, 3)).copy(), pdf)

    def pdf(self, points, wi, t):  # noqa: ANN001, ANN201
        if self.delta:
            return np.zeros(wi.shape[0])
        inside = wi @ self.direction >= math.cos(self.alpha)
        return np.where(inside, 1.0 / (2.0 * np.pi * self.one_minus_cos), 0.0)

    def escaped(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (M, 3) seen by rays escaping the scene along ``directions`` (inside the disc)."""
        if self.delta:
            return np.zeros((directions.shape[0], 3))
        inside = directions @ self.direction >= math.cos(self.alpha)
        return np.where(inside[:, None], self.disc_radiance, 0.0)

    def occludes(self, origins, directions, distances):  # noqa: ANN001, ANN201
        return np.zeros(origins.shape[0], dtype=bool)

    def bound(self):  # noqa: ANN201
        return (0.0, 0.0, 0.0), math.inf, float(np.max(self.illuminance))


@register_light
class SphereLightModel(LightModel):
    kind = "sphere"
    usd_types = ("SphereLight",)
    usd_inputs = {"radius": 0.5, "treatAsPoint": False}

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        lengths = np.asarray(placement.lengths)
        radius_local = float(inputs["radius"])
        radius = radius_local * float(np.mean(lengths))
        # world-space (stage units) ellipsoid area, Knud Thomsen's p = 1.6 formula as HdEmbree's _AreaSphere
        a, b, c = (radius_local * lengths / placement.meters_per_unit).tolist()
        p = 1.6
        area_su = 4.0 * math.pi * (((a * b) ** p + (a * c) ** p + (b * c) ** p) / 3.0) ** (1.0 / p)
        radiance = _normalized(emission, normalize, area_su)
        if bool(inputs["treatAsPoint"]) or radius <= 0:
            # a point of the same radiant intensity I = L·πr² as the sphere, drawn as a tiny, surface-less sphere
            tiny = 1e-4
            factor = (radius / tiny) ** 2 if radius > 0 else 1.0 / (math.pi * tiny**2)
            return Light("sphere", name, radiance=tuple(float(x) for x in radiance * factor),
                         position=placement.position, axes=placement.axes, size=(tiny, 0.0), visible=False), []
        return Light("sphere", name, radiance=tuple(float(x) for x in radiance), position=placement.position,
                     axes=placement.axes, size=(radius, 0.0)), []

    @property
    def radius(self) -> float:
        return float(self.light.size[0])

    @property
    def bounding_radius(self) -> float:
        return self.radius

    def _cone(self, points: np.ndarray):  # noqa: ANN202
        r = self.radius
        to_c = self.centre - points
        d2 = np.einsum("ij,ij->i", to_c, to_c)
        d = np.sqrt(d2)
        outside = d > r * (1.0 + 1e-9)
        sin2 = np.where(outside, r * r / np.maximum(d2, 1e-300), 1.0)
        cos_max = np.sqrt(np.maximum(0.0, 1.0 - sin2))
        one_minus_cos = sin2 / (1.0 + cos_max)  # 1 − cos θmax without cancellation
        return to_c, d2, d, outside, one_minus_cos

    def sample(self, points, u):  # noqa: ANN001, ANN201
        r = self.radius
        to_c, d2, d, outside, one_minus_cos = self._cone(points)
        axis = to_c / np.maximum(d, 1e-300)[:, None]
        wi = sample_cone(axis, one_minus_cos, u)
        b = np.einsum("ij,ij->i", wi, to_c)
        disc = np.maximum(0.0, b * b - (d2 - r * r))
        dist = np.maximum(0.0, b - np.sqrt(disc))
        pdf = np.where(outside, 1.0 / (2.0 * np.pi * np.maximum(one_minus_cos, 1e-300)), 0.0)
        radiance = self.emitted(wi, np.zeros((wi.shape[0], 2)), outside)
        return LightSample(wi, dist, radiance, pdf)

    def pdf(self, points, wi, t):  # noqa: ANN001, ANN201
        _, _, _, outside, one_minus_cos = self._cone(points)
        return np.where(outside, 1.0 / (2.0 * np.pi * np.maximum(one_minus_cos, 1e-300)), 0.0)

    def intersect(self, origins, directions):  # noqa: ANN001, ANN201
        m = origins.shape[0]
        if not self.visible:
            return np.full(m, FAR), np.zeros((m, 2))
        r = self.radius
        oc = origins - self.centre
        b = np.einsum("ij,ij->i", oc, directions)
        c = np.einsum("ij,ij->i", oc, oc) - r * r
        disc = b * b - c
        sq = np.sqrt(np.maximum(disc, 0.0))
        t0, t1 = -b - sq, -b + sq
        t = np.where(t0 > 0, t0, t1)
        hit = (disc >= 0) & (t > 0)
        return np.where(hit, t, FAR), np.zeros((m, 2))


class _PlanarLight(LightModel):
    """Rect and disk: a surface in the local XY plane emitting towards local −Z, sampled uniformly by area."""

    def _surface_point(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _inside(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def sample(self, points, u):  # noqa: ANN001, ANN201
        a, b = self._surface_point(u)
        q = self.centre + a[:, None] * self.axes[0] + b[:, None] * self.axes[1]
        to_q = q - points
        dist = np.linalg.norm(to_q, axis=-1)
        wi = to_q / np.maximum(dist, 1e-300)[:, None]
        cos_l = wi @ self.axes[2]  # the emitting side is −Z: seen from points where ωᵢ·Z > 0
        facing = cos_l > 0
        pdf = np.where(facing, dist * dist / (self.light.area * np.maximum(cos_l, 1e-300)), 0.0)
        radiance = self.emitted(wi, np.stack([a, b], axis=-1), facing)
        return LightSample(wi, dist, radiance, pdf)

    def pdf(self, points, wi, t):  # noqa: ANN001, ANN201
        cos_l = wi @ self.axes[2]
        return np.where(cos_l > 0, t * t / (self.light.area * np.maximum(np.abs(cos_l), 1e-300)), 0.0)

    def intersect(self, origins, directions):  # noqa: ANN001, ANN201
        m = origins.shape[0]
        if not self.visible:
            return np.full(m, FAR), np.zeros((m, 2))
        denom = directions @ self.axes[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.centre - origins) @ self.axes[2]) / denom
        finite = np.isfinite(t)
        p = origins + np.where(finite, t, 0.0)[:, None] * directions - self.centre
        a, b = p @ self.axes[0], p @ self.axes[1]
        hit = finite & (t > 0) & self._inside(a, b)
        return np.where(hit, t, FAR), np.stack([a, b], axis=-1)

    @property
    def bounding_radius(self) -> float:
        if self.kind == "rect":
            return 0.5 * math.hypot(self.light.size[0], self.light.size[1])
        return float(self.light.size[0])


@register_light
class RectLightModel(_PlanarLight):
    kind = "rect"
    usd_types = ("RectLight",)
    usd_inputs = {"width": 1.0, "height": 1.0}

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        width = float(inputs["width"]) * placement.lengths[0]
        height = float(inputs["height"]) * placement.lengths[1]
        area_su = width * height / placement.meters_per_unit**2
        radiance = _normalized(emission, normalize, area_su)
        return Light("rect", name, radiance=tuple(float(x) for x in radiance), position=placement.position,
                     axes=placement.axes, size=(width, height)), []

    def _surface_point(self, u):  # noqa: ANN001, ANN202
        return (u[:, 0] - 0.5) * self.light.size[0], (u[:, 1] - 0.5) * self.light.size[1]

    def _inside(self, a, b):  # noqa: ANN001, ANN202
        return (np.abs(a) <= 0.5 * self.light.size[0]) & (np.abs(b) <= 0.5 * self.light.size[1])

    def _texel(self, coords):  # noqa: ANN001, ANN202
        """HdEmbree's RectLight lookup: s = a/width + ½ (local +X to the right), t = 1 − (b/height + ½) (row 0 at
        local +Y), nearest texel."""
        h, w = self.texture.shape[:2]
        s = np.clip(coords[:, 0] / self.light.size[0] + 0.5, 0.0, 1.0 - 1e-9)
        t = np.clip(0.5 - coords[:, 1] / self.light.size[1], 0.0, 1.0 - 1e-9)
        return self.texture[(t * h).astype(np.int64), (s * w).astype(np.int64)]


@register_light
class DiskLightModel(_PlanarLight):
    kind = "disk"
    usd_types = ("DiskLight",)
    usd_inputs = {"radius": 0.5}

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        r_local = float(inputs["radius"])
        radius = r_local * 0.5 * (placement.lengths[0] + placement.lengths[1])
        area_su = math.pi * (r_local * placement.lengths[0]) * (r_local * placement.lengths[1]) \
            / placement.meters_per_unit**2
        radiance = _normalized(emission, normalize, area_su)
        return Light("disk", name, radiance=tuple(float(x) for x in radiance), position=placement.position,
                     axes=placement.axes, size=(radius, 0.0)), []

    def _surface_point(self, u):  # noqa: ANN001, ANN202
        rad = self.light.size[0] * np.sqrt(u[:, 0])
        phi = 2.0 * np.pi * u[:, 1]
        return rad * np.cos(phi), rad * np.sin(phi)

    def _inside(self, a, b):  # noqa: ANN001, ANN202
        return a * a + b * b <= self.light.size[0] ** 2


@register_light
class CylinderLightModel(LightModel):
    kind = "cylinder"
    usd_types = ("CylinderLight",)
    usd_inputs = {"radius": 0.5, "length": 1.0, "treatAsLine": False}

    @classmethod
    def from_usd(cls, name, inputs, placement, emission, normalize):  # noqa: ANN001, ANN206
        r_local, l_local = float(inputs["radius"]), float(inputs["length"])
        lengths = placement.lengths
        radius = r_local * 0.5 * (lengths[1] + lengths[2])
        length = l_local * lengths[0]
        mpu = placement.meters_per_unit
        a, b, c = r_local * lengths[1] / mpu, r_local * lengths[2] / mpu, l_local * lengths[0] / mpu
        perimeter = math.pi * (3.0 * (a + b) - math.sqrt((3.0 * a + b) * (a + 3.0 * b)))  # Ramanujan, as HdEmbree
        radiance = _normalized(emission, normalize, perimeter * c)
        notes = ["treatAsLine is a hint; the cylinder's surface is rendered"] if bool(inputs["treatAsLine"]) else []
        return Light("cylinder", name, radiance=tuple(float(x) for x in radiance), position=placement.position,
                     axes=placement.axes, size=(radius, length)), notes

    @property
    def bounding_radius(self) -> float:
        return math.hypot(self.light.size[0], 0.5 * self.light.size[1])

    def _facing_angle(self, points: np.ndarray) -> np.ndarray:
        """Azimuth (M,) around the axis of the points' projections: the surface facing them lies within ±π/2."""
        o = points - self.centre
        return np.arctan2(o @ self.axes[2], o @ self.axes[1])

    def sample(self, points, u):  # noqa: ANN001, ANN201
        """Uniform on the half of the lateral surface that faces the point (everything it can see lies there)."""
        r, length = self.light.size
        z = (u[:, 0] - 0.5) * length
        phi = self._facing_angle(points) + np.pi * (u[:, 1] - 0.5)
        normal = np.cos(phi)[:, None] * self.axes[1] + np.sin(phi)[:, None] * self.axes[2]
        q = self.centre + z[:, None] * self.axes[0] + r * normal
        to_q = q - points
        dist = np.linalg.norm(to_q, axis=-1)
        wi = to_q / np.maximum(dist, 1e-300)[:, None]
        cos_l = -np.einsum("ij,ij->i", wi, normal)
        facing = cos_l > 0
        pdf = np.where(facing, dist * dist / (0.5 * self.light.area * np.maximum(cos_l, 1e-300)), 0.0)
        return LightSample(wi, dist, self.emitted(wi, np.zeros((wi.shape[0], 2)), facing), pdf)

    def _hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, length = self.light.size
        o = origins - self.centre
        ox, dx = o @ self.axes[0], directions @ self.axes[0]
        oy, oz = o @ self.axes[1], o @ self.axes[2]
        dy, dz = directions @ self.axes[1], directions @ self.axes[2]
        a = dy * dy + dz * dz
        b = oy * dy + oz * dz
        c = oy * oy + oz * oz - r * r
        disc = b * b - a * c
        sq = np.sqrt(np.maximum(disc, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (-b - sq) / a
            t1 = (-b + sq) / a
        best = np.full(origins.shape[0], FAR)
        for t in (t1, t0):  # t0 last so it wins when both are valid
            x = ox + t * dx
            ok = (disc >= 0) & (a > 0) & np.isfinite(t) & (t > 0) & (np.abs(x) <= 0.5 * length)
            best = np.where(ok & (t < best), t, best)
        p = o + np.where(best < FAR, best, 0.0)[:, None] * directions
        radial = p - (p @ self.axes[0])[:, None] * self.axes[0]
        return best, radial

    def pdf(self, points, wi, t):  # noqa: ANN001, ANN201
        _, radial = self._hit(points, wi)
        n = radial / np.maximum(np.linalg.norm(radial, axis=-1), 1e-300)[:, None]
        cos_l = np.abs(np.einsum("ij,ij->i", wi, n))
        return np.where(cos_l > 0, t * t / (0.5 * self.light.area * np.maximum(cos_l, 1e-300)), 0.0)

    def intersect(self, origins, directions):  # noqa: ANN001, ANN201
        m = origins.shape[0]
        if not self.visible:
            return np.full(m, FAR), np.zeros((m, 2))
        t, _ = self._hit(origins, directions)
        return t, np.zeros((m, 2))


# ----------------------------------------------------------------------------------------------------------------
class LightSet:
    """All analytic lights of a scene for the renderer: surfaces along rays, occlusion by light shapes."""

    def __init__(self, lights: tuple[Light, ...], textures: tuple = ()) -> None:
        self.models = tuple(light_model(light, textures) for light in lights)
        self.surfaces = tuple(m for m in self.models if m.visible and not m.is_global)
        self.distant = tuple(m for m in self.models if isinstance(m, DistantLightModel))

    def nearest(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest light surface along rays: distance (M,) (FAR if none), light index into :attr:`surfaces` (M,)
        (−1 if none) and the radiance it sends back along the ray (M, 3)."""
        m = origins.shape[0]
        best = np.full(m, FAR)
        which = np.full(m, -1, dtype=np.int64)
        coords = np.zeros((m, 2))
        for k, model in enumerate(self.surfaces):
            t, c = model.intersect(origins, directions)
            closer = t < best
            best = np.where(closer, t, best)
            which = np.where(closer, k, which)
            coords[closer] = c[closer]
        radiance = np.zeros((m, 3))
        for k, model in enumerate(self.surfaces):
            sel = np.flatnonzero(which == k)
            if sel.size:
                facing = self._facing(model, origins[sel], directions[sel], best[sel])
                radiance[sel] = model.emitted(directions[sel], coords[sel], facing)
        return best, which, radiance

    @staticmethod
    def _facing(model: LightModel, origins: np.ndarray, directions: np.ndarray, t: np.ndarray) -> np.ndarray:
        if isinstance(model, _PlanarLight):
            return directions @ model.axes[2] > 0
        return np.ones(origins.shape[0], dtype=bool)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray) -> np.ndarray:
        """Whether any light surface blocks the segments (shadow rays)."""
        blocked = np.zeros(origins.shape[0], dtype=bool)
        for model in self.surfaces:
            blocked |= model.occludes(origins, directions, distances)
        return blocked


def intersect_light_shapes(
    lights: tuple[Light, ...], origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest visible area-light surface along rays: distance (M,) (FAR if none) and its radiance (M, 3)."""
    t, _which, radiance = LightSet(lights).nearest(origins, directions)
    return t, radiance
