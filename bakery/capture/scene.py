"""What a capture needs from a scene, as plain frozen dataclasses (no ``pxr``).

:mod:`bakery.usd.scene` fills these from a USD stage; tests and other front ends can build them directly. Every
position, direction and length is already in the **bake frame** (right-handed, +Y up, metres; see
:mod:`bakery.conventions`): the reader applies the stage's ``upAxis`` and ``metersPerUnit``.

Light radiometry (UsdLux, "Light units" in the UsdLux overview; interpretation in ``docs/capture.md``)
    An unnormalised light's emitted radiance is L = intensity · 2^exposure · color (· blackbody(colorTemperature)).
    ``normalize`` divides area lights' radiance by their world-space emitting area in **stage units²** (as
    OpenUSD's HdEmbree does) and makes a distant light's intensity its illuminance at normal incidence. An
    unnormalised distant light of angular diameter 2α has illuminance E = L · π·sin²α (a uniform disc of
    half-angle α). These are resolved by the reader: :class:`Light` carries ``radiance`` (area lights) or
    ``illuminance`` (distant lights) directly; the per-kind behaviour lives in :mod:`bakery.capture.lights`.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field

import numpy as np

from bakery.capture.ies import IesShaping

LIGHT_TYPES = ("distant", "sphere", "rect", "disk", "cylinder")
#: Distance used for "no hit" and for unbounded shadow rays (metres).
FAR = 1e30


def ellipsoid_area(a: float, b: float, c: float) -> float:
    """Surface area of the ellipsoid of semi-axes a, b, c: Knud Thomsen's approximation (p = 1.6, relative error
    ≤ 1.061 %), the formula of HdEmbree's ``_AreaSphere``; exact for a sphere."""
    p = 1.6
    return 4.0 * math.pi * (((a * b) ** p + (a * c) ** p + (b * c) ** p) / 3.0) ** (1.0 / p)


def ellipse_perimeter(a: float, b: float) -> float:
    """Perimeter of the ellipse of semi-axes a, b: Ramanujan's first approximation, as HdEmbree's
    ``_AreaCylinder``; exact for a circle."""
    return math.pi * (3.0 * (a + b) - math.sqrt((3.0 * a + b) * (a + 3.0 * b)))


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
        size: (2,) ``rect`` width, height in metres; ``sphere`` radius in ``size[0]`` (metres), or (3,) an
            ellipsoid's semi-axes along local X, Y, Z; ``disk`` semi-axes along local X, Y (metres), or (radius, 0)
            for a circle; ``cylinder`` radius, length (along local X) in metres, or (3,) an elliptic section's
            semi-axes along local Y, Z and the length.
        angle: distant light angular diameter in degrees.
        visible: whether the light's shape is a surface in the scene: seen by camera and bounce rays, and
            occluding (False for point-like lights, which are reached by next-event estimation only).
        shaping: UsdLuxShapingAPI as (cone angle°, cone softness, focus, focus tint r, g, b); () = unshaped.
        texture: index into :attr:`CaptureScene.textures` of a RectLight's ``texture:file`` (−1: none).
        ies: the light's IES profile with ``shaping:ies:angleScale`` and ``normalize`` (:mod:`bakery.capture.ies`),
            or None.
        diffuse, specular: UsdLux's non-physical multipliers of the light's effect on the diffuse and the specular
            lobe of surfaces (their next-event and MIS-weighted BSDF estimates at every path vertex; a camera ray
            sees the light's shape unscaled).
        shadow: UsdLuxShadowAPI ``shadow:enable``: False lets the light's next-event rays through every occluder
            (the light is then sampled by next-event estimation alone, without MIS).
        shadow_color: ``shadow:color``: the fraction of the light (RGB) an occluded next-event ray still delivers.
        shadow_distance, shadow_falloff, shadow_falloff_gamma: ``shadow:distance`` d, ``shadow:falloff`` f (metres;
            ≤ 0: no limit, no falloff zone) and ``shadow:falloffGamma`` γ: an occluder nearer to the shaded point than
            d − f shadows fully, one between d − f and d with strength ((d − t)/f)^γ at distance t, one beyond d not
            at all (the nearest occluder along the next-event ray counts; the light is then sampled by next-event
            estimation alone, as a BSDF ray cannot pass the far occluders).
        links: UsdLux light linking (``collection:lightLink``): indices into :attr:`CaptureScene.meshes` of the
            meshes the light illuminates; None: every mesh. A probe still sees an unlinked light directly.
        shadow_links: UsdLux shadow linking (``collection:shadowLink``): indices of the meshes that cast the light's
            shadows; None: every mesh. Its next-event rays pass the others (the light is then sampled by next-event
            estimation alone, as without shadows); what rays see is unchanged.
    """

    kind: str
    name: str
    radiance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    illuminance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axes: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    size: tuple[float, ...] = (0.0, 0.0)
    angle: float = 0.53
    visible: bool = True
    shaping: tuple[float, ...] = ()
    texture: int = -1
    ies: IesShaping | None = None
    diffuse: float = 1.0
    specular: float = 1.0
    shadow: bool = True
    shadow_color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    links: tuple[int, ...] | None = None
    shadow_links: tuple[int, ...] | None = None
    shadow_distance: float = -1.0
    shadow_falloff: float = -1.0
    shadow_falloff_gamma: float = 1.0

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
        """Emitting area in m² (0 for distant lights)."""
        if self.kind == "rect":
            return float(self.size[0] * self.size[1])
        if self.kind == "disk":  # semi-axes (a, b), or (r, 0) for a circle
            return float(np.pi * self.size[0] * (self.size[1] if self.size[1] > 0 else self.size[0]))
        if self.kind == "sphere" and len(self.size) == 3:
            return ellipsoid_area(*self.size)
        if self.kind == "sphere":
            return float(4.0 * np.pi * self.size[0] ** 2)
        if self.kind == "cylinder" and len(self.size) == 3:
            a, b, length = self.size
            return ellipse_perimeter(a, b) * length
        if self.kind == "cylinder":
            return float(2.0 * np.pi * self.size[0] * self.size[1])
        return 0.0


@dataclass(frozen=True)
class Dome:
    """An environment (UsdLux DomeLight) seen by rays that escape the scene.

    Attributes:
        name: prim path.
        scale: (3,) color · intensity · 2^exposure, multiplying the texture (or the constant if no texture).
        rotation: (3, 3) dome-local → bake-frame orthogonal matrix (columns are the dome's local axes in the bake
            frame), including the dome's pole-axis alignment; a reflection (det −1) when the dome's transform
            mirrors (see :mod:`bakery.usd.scene`).
        pixels: (H, W, 3) float32 texture radiance, or ``None`` for a constant dome.
        layout: environment layout of ``pixels`` (:data:`bakery.environment.LAYOUTS`).
        source: texture file, for messages.
        diffuse, specular: UsdLux's multipliers of the dome's effect on the diffuse and specular lobes of surfaces
            (:class:`Light`); the dome seen by escaping camera rays is unscaled.
        links: light linking as :attr:`Light.links` (None: every mesh).
        shadow_links: shadow linking as :attr:`Light.shadow_links` (None: every mesh shadows the dome).
        shadow, shadow_color, shadow_distance, shadow_falloff, shadow_falloff_gamma: UsdLuxShadowAPI on the dome,
            as on a :class:`Light`.
    """

    name: str
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    pixels: np.ndarray | None = None
    layout: str = "equirect"
    source: str = ""
    diffuse: float = 1.0
    specular: float = 1.0
    links: tuple[int, ...] | None = None
    shadow_links: tuple[int, ...] | None = None
    shadow: bool = True
    shadow_color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    shadow_distance: float = -1.0
    shadow_falloff: float = -1.0
    shadow_falloff_gamma: float = 1.0


@dataclass(frozen=True)
class Material:
    """A UsdPreviewSurface-like surface (the capture's one material model; MaterialX surfaces map onto it).

    Attributes:
        diffuse, emission: (3,) linear Rec.709 diffuse colour and emitted radiance.
        roughness: perceptual roughness r (GGX α = r², clamped to ≥ 1e-3 when shaded).
        metallic: metalness (metallic workflow): F0 = lerp(F0_dielectric(ior), diffuse, metallic), diffuse
            weight (1 − metallic).
        specular: (3,) F0 of the specular workflow (``use_specular_workflow``).
        ior: index of refraction of the dielectric Fresnel (F0 = ((ior − 1)/(ior + 1))²).
        clearcoat, clearcoat_roughness: a white GGX coat (F0 0.04) of that amount and roughness over the base
            (:mod:`bakery.capture.bsdf`, "Clearcoat").
        diffuse_roughness, diffuse_energy_compensation: an Oren–Nayar diffuse lobe of that roughness (0: Lambertian),
            the qualitative model or the energy-preserving EON (:mod:`bakery.brdf.oren_nayar`).
        sheen, sheen_color, sheen_roughness: a sheen layer of that weight, colour and roughness
            (:mod:`bakery.capture.bsdf`, "Sheen").
        sheen_layer: what the sheen lies over: ``"diffuse"`` (MaterialX standard_surface: the diffuse lobe of the
            dielectric share, under the specular lobe and the coat), ``"base"`` (gltf_pbr: diffuse, specular and
            metal, under the coat) or ``"coat"`` (open_pbr_surface fuzz: everything, the coat included).
        sheen_mode: the lobe, MaterialX ``sheen_bsdf``'s mode: ``"conty_kulla"`` (the Imageworks lobe,
            :mod:`bakery.brdf.sheen`) or ``"zeltner"`` (the LTC fuzz, :mod:`bakery.brdf.sheen_ltc`).
        clearcoat_f0: the coat's F0, ((ior − 1)/(ior + 1))² of the coat's IOR: a MaterialX coat's ``coat_IOR`` /
            ``coat_ior``, UsdPreviewSurface's ``ior`` ("including the clearcoat if clearcoat > 0"; 0.04 at 1.5).
        metal_edge_albedo: the metallic share's F90 is the albedo, not white (UsdPreviewSurface: "If metallic is 1,
            then both F0 ... and edge F90 reflectivity will simply be the Albedo ... In between, we interpolate":
            F90 = (1 − metallic)·F90_dielectric + metallic·diffuse); MaterialX surfaces' metals keep F90 = 1.
        opacity, opacity_threshold: cut-outs: a hit whose opacity is below the threshold (threshold > 0) is
            passed through; without a threshold, opacity is the surface's presence: a hit is passed through with
            probability 1 − opacity (stochastic alpha: a window of opacity 0.2 passes 80 % of the light).
        transmission_tint: (3,) the colour that multiplies light passing through the surface where it is absent
            (a passed-through hit: the thin, straight transmission of MaterialX surfaces, tinted by their
            ``transmission_color``); 1 for UsdPreviewSurface, whose opacity is colourless.
        specular_tint: (3,) the dielectric specular lobe's weight × colour (MaterialX ``specular``·``specular_color``):
            it scales that lobe's whole Fresnel curve, F0 and F90 alike (the metal's is unscaled).
        specular_edge_tint: (3,) the tint of F90 alone when it differs from ``specular_tint``'s (glTF
            KHR_materials_specular: F0 × specular·specular_color, F90 × specular); None: ``specular_tint``.
        coat_tint: (3,) what the coat lets through to the base, both ways (MaterialX mix(1, coat_color, coat)): it
            scales the base's diffuse and specular lobes.
        dielectric_f90: (3,) the dielectric share's Schlick F90 as the graph gives it, whatever the IOR (gltf_pbr's
            ``dielectric_f90`` = ``specular``: white at every IOR, where min(1, 50·F0(ior)) would dim it below
            1.33); None: min(1, 50·F0(ior)) × ``specular_edge_tint``.
        metal_weight: the metallic share's weight (open_pbr_surface ``metal_bsdf``, a generalized_schlick_bsdf of
            weight ``specular_weight``): it scales the metal's whole Fresnel curve.
        metal_f82: (3,) the metal's F82 tint (open_pbr_surface ``metal_bsdf`` color82 = ``specular_color``): the
            metallic share's Fresnel is ``mx_fresnel_hoffman_schlick``(F0 = diffuse, F82, F90 = 1), Schlick(F0, 1)
            − a·μ(1 − μ)⁶ with F(1/7) = F82·Schlick(F0, 1)(1/7); None: the tint 1 (Schlick).
        metal_edge_color: (3,) the metal's edge colour (standard_surface ``artistic_ior`` edge_color =
            ``specular``·``specular_color``): the metallic share is ``conductor_bsdf`` of the complex IOR that
            ``artistic_ior`` (Gulbrandsen 2014) makes of reflectivity = diffuse and this edge colour, with the
            exact conductor Fresnel (``mx_fresnel_conductor``); None: Schlick (``metal_weight``, ``metal_f82``).
            Any of these four fields away from its default makes the material's F0 and F90 explicit, share by share
            (:mod:`bakery.capture.surfaces`).
        layering: how the lobes combine (:mod:`bakery.capture.bsdf`): ``"preview"`` (UsdPreviewSurface, Hydra Storm's
            model: the diffuse lobe weighted by 1 − F(v·h), the base by 1 − F_coat(v·h), single-scattering GGX
            lobes) or ``"materialx"`` (MaterialX's pbrlib ``layer``: what lies under the specular lobe and under
            the coat keeps 1 − weight·E(θo)·(1 + k·F), the GGX lobes times Turquin's compensation 1 + k·F,
            k = (1 − E_ss)/E_ss; "MaterialX layering").
        specular_layer: (u0, u90, w): a MaterialX ``dielectric_bsdf`` specular layer's own Fresnel and weight, which
            its layering needs apart from the tint that scales the lobe (standard_surface: weight ``specular``, tint
            ``specular_color``; open_pbr_surface: weight 1, tint ``specular_color``): its Schlick F0 = F0(ior)·u0,
            F90 = min(1, 50·F0(ior))·u90, and w. None: the lobe's own Schlick terms (``specular_tint``,
            ``specular_edge_tint``, ``dielectric_f90``) and weight 1 — a ``generalized_schlick_bsdf`` (gltf_pbr), or a
            ``dielectric_bsdf`` of white tint and weight 1.
        maps: textured inputs, each a dict {"input": name, "texture": index into CaptureScene.textures,
            "channels": "rgb" | "r" | "g" | "b" | "a", "scale": (4,), "bias": (4,), "fallback": (4,),
            "wrap": (wrapS, wrapT)} and optionally "st_transform": ((a, b, tx), (c, d, ty)), the affine map
            applied to the coordinates first (UsdTransform2d, MaterialX place2d/tiledimage); texture coordinates
            come from the mesh's ``uvs``. Colour inputs read per
            vertex are {"input": name, "primvar": primvar name, "scale": (4,), "bias": (4,)}: the mesh's
            ``colors`` at the hit.
    """

    name: str = "<default>"
    diffuse: tuple[float, float, float] = (0.18, 0.18, 0.18)
    emission: tuple[float, float, float] = (0.0, 0.0, 0.0)
    roughness: float = 0.5
    metallic: float = 0.0
    specular: tuple[float, float, float] = (0.0, 0.0, 0.0)
    use_specular_workflow: bool = False
    ior: float = 1.5
    opacity: float = 1.0
    opacity_threshold: float = 0.0
    maps: tuple[dict, ...] = ()
    clearcoat: float = 0.0
    clearcoat_roughness: float = 0.01
    clearcoat_f0: float = 0.04
    metal_edge_albedo: bool = False
    diffuse_roughness: float = 0.0
    diffuse_energy_compensation: bool = False
    sheen: float = 0.0
    sheen_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    sheen_roughness: float = 0.3
    sheen_layer: str = "diffuse"
    sheen_mode: str = "conty_kulla"
    transmission_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    specular_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    specular_edge_tint: tuple[float, float, float] | None = None
    coat_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    dielectric_f90: tuple[float, float, float] | None = None
    metal_weight: float = 1.0
    metal_f82: tuple[float, float, float] | None = None
    metal_edge_color: tuple[float, float, float] | None = None
    layering: str = "preview"
    specular_layer: tuple[float, float, float] | None = None

    @property
    def explicit_fresnel(self) -> bool:
        """Whether the specular lobe's F0 and F90 are built share by share (a MaterialX metal's weight, F82 tint or
        conductor edge, or a dielectric F90 given as is), not from the capture's min(1, 50·luminance(F0)) rule."""
        return (self.dielectric_f90 is not None or self.metal_weight != 1.0 or self.metal_f82 is not None
                or self.metal_edge_color is not None) and not self.use_specular_workflow \
            and not self.metal_edge_albedo

    @property
    def emits(self) -> bool:
        """Whether the surface emits: a positive emissive colour, or a textured one."""
        return max(self.emission) > 0 or any(entry.get("input") == "emissiveColor" for entry in self.maps)

    @property
    def albedo(self) -> np.ndarray:
        """Diffuse albedo diffuse · (1 − metallic) (metallic workflow), clipped to [0, 1]."""
        weight = 1.0 if self.use_specular_workflow else 1.0 - self.metallic
        return np.clip(np.asarray(self.diffuse, dtype=np.float64) * weight, 0.0, 1.0)

    @property
    def f0(self) -> np.ndarray:
        """(3,) normal-incidence specular reflectance of the metallic workflow's Schlick lobe (UsdPreviewSurface; a
        MaterialX metal's explicit terms, ``explicit_fresnel``, are :mod:`bakery.capture.surfaces`')."""
        if self.use_specular_workflow:
            return np.clip(np.asarray(self.specular, dtype=np.float64), 0.0, 1.0)
        dielectric = ((self.ior - 1.0) / (self.ior + 1.0)) ** 2 if self.ior > 0 else 0.0
        return np.clip((1.0 - self.metallic) * dielectric + self.metallic * np.asarray(self.diffuse, dtype=np.float64),
                       0.0, 1.0)


@dataclass(frozen=True)
class Texture:
    """An image used by materials or lights, as linear Rec.709 float32 pixels (H, W, 4) (RGBA; alpha 1 if absent).

    Attributes:
        name: source file (for messages).
        pixels: (H, W, 4) float32, row 0 = the top of the image (t = 1 in UsdUVTexture's st convention).
        color_space: the source colour space it was converted from (recorded in the store).
    """

    name: str
    pixels: np.ndarray
    color_space: str = "lin_rec709"


@dataclass(frozen=True)
class Mesh:
    """Triangles in the bake frame (metres) with one material.

    Attributes:
        name: prim path (with an instance suffix for point instances).
        triangles: (T, 3, 3) float32 vertex positions.
        material: the bound material.
        uvs: (T, 3, 2) float32 texture coordinates per triangle corner (the primvar the material's textures
            read), or None.
        normals: (T, 3, 3) float32 unit shading normals per triangle corner in the bake frame (the mesh's authored
            ``normals``), interpolated with the hit's barycentrics; None: the geometric normal is the shading normal.
        colors: (T, 3, 3) float32 per-corner colours of the colour primvar that the material's per-hit colour
            entries read (``Material.maps`` entries with a ``primvar``: ``displayColor``, or the ``varname`` of a
            ``UsdPrimvarReader_float3``), interpolated with the hit's barycentrics; None: none.
        front: which side of each triangle is the surface's front (outside) in the bake frame: 1 the side its
            winding normal (v1 − v0) × (v2 − v0) points to, −1 the other (UsdGeom ``orientation`` leftHanded, or a
            mirroring transform), 0 both (``doubleSided``). Shading is two-sided either way; the side tells a probe
            inside geometry (rays that see back faces, ``CaptureStats.backface_fraction``).
    """

    name: str
    triangles: np.ndarray
    material: Material = field(default_factory=Material)
    uvs: np.ndarray | None = None
    normals: np.ndarray | None = None
    front: int = 1
    colors: np.ndarray | None = None


@dataclass(frozen=True)
class ProbeSpec:
    """A probe to capture, as read from the scene.

    Attributes:
        name: unique identity (prim path; volume members are ``<volume path>[i,j,k]``).
        kind: ``"irradiance"`` or ``"reflection"``.
        position: (3,) bake-frame position in metres.
        rotation: (3, 3) probe-local → bake-frame orthogonal matrix, a rotation or, under a mirroring transform, a
            reflection (orients a captured image).
        resolution: requested capture face size (0 = the bake's default).
        image: optional captured environment image file (absolute path).
        encodings: optional per-probe encoding names.
        volume: prim path of the owning probe volume, or "".
        volume_index: (i, j, k) within the volume.
        influence: JSON-able influence description (shape, radius/extent in metres).
        relocate: search radius (metres) of the relocation of a probe inside geometry
            (:mod:`bakery.capture.validity`; a volume's ``bakery:volume:relocate``: half its smallest spacing);
            0: captured where it is.
        dilation: search radius (metres) of the dilation of a probe inside geometry from its volume's valid
            probes (:mod:`bakery.pipeline.dilate`; a volume's ``bakery:volume:dilate``); 0: no dilation.
        dilation_passes: the dilation's passes (``bakery:volume:dilationIterations``).

    A scene probe's content hash covers its spec (``sources.usd_scene.SceneProbeCapture``) except the fields marked
    ``content_hash: False``: the captured image by its bytes, not its path, and its orientation with it (the
    source's inputs; a rendered probe's rotation changes nothing); the dilation is applied in the parent to stored
    results, so its radius and passes re-bake nothing (:mod:`bakery.pipeline.dilate`).
    """

    name: str
    kind: str
    position: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...] = field(
        default=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), metadata={"content_hash": False})
    resolution: int = 0
    image: str = field(default="", metadata={"content_hash": False})
    encodings: tuple[str, ...] = ()
    volume: str = ""
    volume_index: tuple[int, int, int] = (0, 0, 0)
    influence: dict = field(default_factory=dict)
    relocate: float = 0.0
    dilation: float = field(default=0.0, metadata={"content_hash": False})
    dilation_passes: int = field(default=1, metadata={"content_hash": False})


@dataclass(frozen=True)
class CaptureScene:
    """Everything a capture sees, in the bake frame.

    ``textures`` are shared by materials and lights (by index); ``portals`` are PortalLights (kind "rect",
    size and frame only) that guide the dome's sampling; ``working_space`` is the colour space every colour is
    in (linear Rec.709); ``time_code`` the USD time the stage was read at (None: default/earliest).
    """

    meshes: tuple[Mesh, ...] = ()
    lights: tuple[Light, ...] = ()
    dome: Dome | None = None
    probes: tuple[ProbeSpec, ...] = ()
    meters_per_unit: float = 1.0
    up_axis: str = "Y"
    textures: tuple[Texture, ...] = ()
    portals: tuple[Light, ...] = ()
    working_space: str = "lin_rec709"
    time_code: float | None = None

    def triangle_count(self) -> int:
        return int(sum(m.triangles.shape[0] for m in self.meshes))
