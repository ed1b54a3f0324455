"""What a capture needs from a scene, as plain frozen dataclasses (no ``pxr``).

:mod:`bakery.usd.scene` fills these from a USD stage; tests and other front ends can build them directly. Every
position, direction and length is already in the **bake frame** (right-handed, +Y up, metres; see
:mod:`bakery.conventions`): the reader applies the stage's ``upAxis`` and ``metersPerUnit``.

Light radiometry (UsdLux, "Light units" in the UsdLux overview)
    An unnormalised light's emitted radiance is L = intensity · 2^exposure · color.
    ``normalize`` divides area lights' radiance by their emitting area (in **m²**, so that a scene authored in
    centimetres and the same scene in metres bake identically) and makes a distant light's intensity its
    illuminance at normal incidence. An unnormalised distant light of angular diameter 2α has illuminance
    E = L · π·sin²α (a uniform disc of half-angle α). These are resolved by the reader: :class:`Light` carries
    ``radiance`` (area lights) or ``illuminance`` (distant lights) directly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

LIGHT_TYPES = ("distant", "sphere", "rect", "disk")


@dataclass(frozen=True)
class Light:
    """One analytic light in the bake frame.

    Attributes:
        kind: one of :data:`LIGHT_TYPES`.
        name: prim path (for messages).
        radiance: (3,) emitted radiance of the light's surface (area lights; unused for ``distant``).
        illuminance: (3,) illuminance at normal incidence (``distant`` only).
        position: (3,) centre in metres (area lights).
        axes: (3, 3) rows = local X, Y, Z axes in the bake frame, unit length (the light emits towards -Z for
            ``rect``/``disk``; a ``distant`` light shines along -Z, i.e. it comes *from* +Z).
        size: (2,) ``rect`` width, height in metres; ``sphere``/``disk`` radius in ``size[0]`` (metres).
        angle: distant light angular diameter in degrees.
        visible: whether the light's shape is seen by camera (probe) rays.
    """

    kind: str
    name: str
    radiance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    illuminance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axes: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    size: tuple[float, float] = (0.0, 0.0)
    angle: float = 0.53
    visible: bool = True

    def __post_init__(self) -> None:
        if self.kind not in LIGHT_TYPES:
            raise ValueError(f"unknown light kind {self.kind!r}; expected one of {LIGHT_TYPES}")

    @property
    def direction_to_light(self) -> np.ndarray:
        """Unit direction towards a distant light (its local +Z)."""
        z = np.asarray(self.axes[2], dtype=np.float64)
        return z / np.linalg.norm(z)

    @property
    def area(self) -> float:
        if self.kind == "rect":
            return float(self.size[0] * self.size[1])
        if self.kind == "disk":
            return float(np.pi * self.size[0] ** 2)
        if self.kind == "sphere":
            return float(4.0 * np.pi * self.size[0] ** 2)
        return 0.0


@dataclass(frozen=True)
class Dome:
    """An environment (UsdLux DomeLight) seen by rays that escape the scene.

    Attributes:
        name: prim path.
        scale: (3,) color · intensity · 2^exposure, multiplying the texture (or the constant if no texture).
        rotation: (3, 3) dome-local → bake-frame rotation (columns are the dome's local axes in the bake frame),
            including the dome's pole-axis alignment (see :mod:`bakery.usd.scene`).
        pixels: (H, W, 3) float32 texture radiance, or ``None`` for a constant dome.
        layout: environment layout of ``pixels`` (:data:`bakery.environment.LAYOUTS`).
        source: texture file, for messages.
    """

    name: str
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    pixels: np.ndarray | None = None
    layout: str = "equirect"
    source: str = ""


@dataclass(frozen=True)
class Material:
    """A diffuse + emissive surface (UsdPreviewSurface reduced to what irradiance capture needs).

    ``roughness`` and ``metallic`` are read and kept for reports; the capture shades diffusely with
    albedo = diffuse · (1 − metallic).
    """

    name: str = "<default>"
    diffuse: tuple[float, float, float] = (0.18, 0.18, 0.18)
    emission: tuple[float, float, float] = (0.0, 0.0, 0.0)
    roughness: float = 0.5
    metallic: float = 0.0

    @property
    def albedo(self) -> np.ndarray:
        return np.clip(np.asarray(self.diffuse, dtype=np.float64) * (1.0 - self.metallic), 0.0, 1.0)


@dataclass(frozen=True)
class Mesh:
    """Triangles in the bake frame (metres) with one material.

    Attributes:
        name: prim path (with an instance suffix for point instances).
        triangles: (T, 3, 3) float32 vertex positions.
        material: the bound material.
    """

    name: str
    triangles: np.ndarray
    material: Material = field(default_factory=Material)


@dataclass(frozen=True)
class ProbeSpec:
    """A probe to capture, as read from the scene.

    Attributes:
        name: unique identity (prim path; volume members are ``<volume path>[i,j,k]``).
        kind: ``"irradiance"`` or ``"reflection"``.
        position: (3,) bake-frame position in metres.
        rotation: (3, 3) probe-local → bake-frame rotation (orients a captured image).
        resolution: requested capture face size (0 = the bake's default).
        image: optional captured environment image file (absolute path).
        encodings: optional per-probe encoding names.
        volume: prim path of the owning probe volume, or "".
        volume_index: (i, j, k) within the volume.
        influence: JSON-able influence description (shape, radius/extent in metres).
    """

    name: str
    kind: str
    position: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    resolution: int = 0
    image: str = ""
    encodings: tuple[str, ...] = ()
    volume: str = ""
    volume_index: tuple[int, int, int] = (0, 0, 0)
    influence: dict = field(default_factory=dict)


@dataclass(frozen=True)
class CaptureScene:
    """Everything a capture sees, in the bake frame."""

    meshes: tuple[Mesh, ...] = ()
    lights: tuple[Light, ...] = ()
    dome: Dome | None = None
    probes: tuple[ProbeSpec, ...] = ()
    meters_per_unit: float = 1.0
    up_axis: str = "Y"

    def triangle_count(self) -> int:
        return int(sum(m.triangles.shape[0] for m in self.meshes))
