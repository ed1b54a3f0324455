"""The capture's surface BSDF: Lambertian diffuse plus the GGX specular lobe of the reflection encodings.

    f(wo, wi) = (1 − F(wo·h)) · ρ_d/π  +  F(wo·h) · D(h) · V(wo, wi)

(UsdPreviewSurface, as Hydra Storm shades it: reciprocal; not energy-conserving at grazing views under a dielectric
lobe: a white ρ_d with F0 0.04 reflects up to 1.2–1.3 there, docs/capture.md "Materials and colour"; MaterialX
surfaces layer their lobes instead, "MaterialX layering" below) with D the GGX distribution, V the height-correlated
Smith visibility G2/(4 (n·wo)(n·wi)) and F Schlick's Fresnel — exactly the terms of :mod:`bakery.brdf.ggx` that the
reflection encodings use. F = F0 + (F90 − F0)(1 − c)⁵ with F90 = min(1, 50·luminance(F0)) (a surface with F0 = 0
has no specular lobe at all, so a purely diffuse material is exactly Lambertian), or F90 (3, M) as given: a
UsdPreviewSurface metal's, mix(F90, albedo, metallic), and a tinted lobe's (MaterialX specular weight and colour,
a coat's colour: F0 scaled by the material's ``specular_tint``, F90 by its ``specular_edge_tint``, which
:mod:`bakery.usd.mtlx` derives from the MaterialX graphs). α = roughness², clamped to ≥ :data:`MIN_ALPHA`.

MaterialX metals (:class:`Fresnel`, given as ``f90``): F(μ) = F0 + (F90 − F0)(1 − μ)⁵ − b·μ(1 − μ)⁶ + w ⊙ F_c(μ; η, κ),
both extra terms linear in the shares that carry them:
    * open_pbr_surface's ``metal_bsdf`` (generalized_schlick_bsdf, weight ``specular_weight`` w_m, color0 F0_m =
      base_weight·base_color, color82 ``specular_color``, color90 1, exponent 5): ``mx_fresnel_hoffman_schlick``,
      Schlick(F0_m, 1) − a·μ(1 − μ)⁶ with a = Schlick(F0_m, 1)(1/7)·(1 − F82)/((1/7)(6/7)⁶) — F(1/7) (θ = 81.8°) is
      F82 × Schlick's value there (Hoffman 2023, OpenPBR's F82-tint metal); the metallic share m contributes
      m·w_m·F0_m to F0, m·w_m to F90 and b = m·w_m·a. F is clamped at 0 (a dark F0 under a dark tint takes
      Hoffman's curve below 0 around μ ≈ 0.3; the graph does not clamp).
    * standard_surface's ``metal_bsdf`` (conductor_bsdf of the ``artistic_ior`` node's ior and extinction):
      F_c = ``mx_fresnel_conductor``(μ, η, κ), the exact unpolarised Fresnel of a conductor (Lagarde's memo), of
      weight w = m (the metallic share), η = mix(n_max, n_min, g), κ² = ((η + 1)²r − (η − 1)²)/(1 − r) from the
      reflectivity r = clamp(base·base_color, 0, 0.99) and the edge colour g (Gulbrandsen 2014), so F_c(1) = r.
    Either is scaled by the coat's tint like the rest of the base; with MaterialX's energy compensation ("MaterialX
    layering").

MaterialX layering (:class:`Layering`, in :class:`Fresnel`'s ``layering``; ``Material.layering`` "materialx":
standard_surface, open_pbr_surface, gltf_pbr), as the 1.39 pbrlib GLSL's reflection closure evaluates a BSDF for a
view V and a light L (``mx_dielectric_bsdf``, ``mx_generalized_schlick_bsdf``, ``mx_conductor_bsdf``,
``mx_layer_bsdf``: top.response + base.response × top.throughput):
    * every GGX lobe (the specular layer, the metal, the coat) is multiplied by Turquin's compensation
      ``mx_ggx_energy_compensation``(n·v, α, F) = 1 + F·k, k = (1 − E_ss(θo))/E_ss(θo), where F is the lobe's own
      Fresnel at the same v·h as its response (``mx_compute_fresnel``(V·H): not an average Fresnel; without the
      node's weight and tint) and E_ss the white lobe's directional albedo. The lobe's F is a sum of shares
      (dielectric, metal), each with its own compensation: F + k·Σ F_share ⊙ F_share,own, F_share = weight ⊙
      F_share,own; the metal's own Fresnel is its share divided by its weight (clamped to [0, 1]);
    * what lies under the dielectric specular layer — the diffuse lobe (Lambert or Oren–Nayar; standard_surface's
      sheen over it), gltf_pbr's whole base under its sheen — keeps the layer's throughput 1 − w·mean_rgb(E_u(θo)
      ⊙ (1 + k·F_u(v·h))) instead of 1 − F(v·h): E_u = F0·A + F90·B (``mx_ggx_dir_albedo``) of the layer's own
      Schlick terms, F_u its Fresnel, w the node's weight (``dielectric_bsdf``: standard_surface ``specular``, 1 for
      open_pbr, whose colour only tints the response; ``generalized_schlick_bsdf``: 1, its colour inside F);
    * the coat (``dielectric_bsdf`` of weight c) likewise: its lobe × (1 + k_c·F_c,own), and everything under it ×
      1 − c·E_c(θo)·(1 + k_c·F_c,own(v·h)), E_c = F0_c·A + B at the coat's α.
    The throughput takes the compensation of F at the light's half vector, as the GLSL's reflection closure does
    (its indirect closure takes F(n·v)); it is clamped at 0. A and B are the capture's own lobe's
    (:mod:`bakery.brdf.ggx_albedo`, a (√(n·v), √α) table): E_ss within 2·10⁻³, where MaterialX's default rational
    fit ``mx_ggx_dir_albedo_analytic`` is up to 0.06 off. The white furnace of this model is 1 within 4·10⁻⁴ up to
    60° (a white base under F0 0.04), +0.9 % at 80° (roughness 0.3), +2 % at 85° (up to +7 % within 1° of grazing
    for smooth lobes) — MaterialX's own residual, where Storm's 1 − F(v·h) gives +22 % at 80° —; a white
    conductor's is 1 to the table's accuracy. The lobe choice
    weighs the same terms towards the viewer (v·h = n·v); the pdf is unchanged. Points without it shade as before,
    bit for bit (UsdPreviewSurface in the same batch).

Clearcoat (UsdPreviewSurface ``clearcoat`` c, ``clearcoatRoughness`` r_c; MaterialX coat): a white GGX lobe with
F0 = ((ior − 1)/(ior + 1))² of the coat's IOR (UsdPreviewSurface: its ``ior``; given per point, else 0.04) on top,
F_c = c·Schlick(F0_c, v·h), α_c = r_c² (≥ MIN_ALPHA); the base lobes are weighted by 1 − F_c (the
light the coat transmits, as the diffuse lobe is by 1 − F under the specular one). It is picked first with
probability p_c = clip(F_c(n·v) / (F_c(n·v) + (1 − F_c(n·v))·(base weights)), 0.05, 0.95) and sampled by its visible
normals; the mixture pdf is p_c·pdf_c + (1 − p_c)·pdf_base. Without a coat the BSDF is unchanged.

Sheen (weight w, colour C, roughness r; :class:`Sheen`): a lobe S = w·C·f_sheen·n·l whose layer lets what lies
under it keep 1 − w·E(n·v, r) (MaterialX ``layer`` over ``sheen_bsdf``; E its directional albedo), where the
stdlib graphs put it (1 − F: what the specular layer passes; under MaterialX's layering, its throughput):
    * over the diffuse lobe, both under the specular one (``standard_surface``):
      (1 − F)·(ρ_d/π·(1 − w·E)·n·l + S) + specular;
    * over diffuse and specular, under the coat (``gltf_pbr``): ρ_d/π·(1 − w·E)(1 − F)·n·l + (1 − w·E)·specular + S;
    * over everything, the coat included (``open_pbr_surface`` fuzz): (1 − w·E)·(coated base) + S.
The lobe is the Imageworks one (:mod:`bakery.brdf.sheen`, mode ``conty_kulla``) or Zeltner's LTC fuzz
(:mod:`bakery.brdf.sheen_ltc`, mode ``zeltner``). It is sampled with the diffuse lobe (cosine), its directional
albedo w·C·E counting towards that lobe's choice.

Rough diffuse (MaterialX ``diffuse_roughness``, ``base_diffuse_roughness``): the diffuse lobe is Oren–Nayar
(:mod:`bakery.brdf.oren_nayar`): standard_surface's qualitative model, open_pbr_surface's energy-preserving EON;
still sampled by cosine.

Sampling: one lobe is picked with probability p_s = lum F(n·wo) / (lum F(n·wo) + lum ρ_d(1 − F(n·wo))) clamped to
[0.05, 0.95] (0 or 1 when a lobe is absent); diffuse directions are cosine-distributed, specular ones follow the
GGX distribution of visible normals (:func:`bakery.brdf.sampling.sample_ggx_vndf`). The returned pdf is the
mixture p_s·pdf_s + (1 − p_s)·pdf_d, as multiple importance sampling needs. Surfaces are two-sided (the shading
normal faces the incoming ray). With interpolated shading normals, directions below the geometric surface are
excluded (value and pdf 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bakery.brdf import ggx_albedo, oren_nayar, sheen_ltc
from bakery.brdf.sheen import directional_albedo, sheen_brdf
from bakery.capture.vec import TINY, dot, frame, luminance, vmax

MIN_ALPHA = 1e-3
#: F0 of the clearcoat lobe (UsdPreviewSurface: an IOR of 1.5)
COAT_F0 = 0.04
_INV_PI = 1.0 / math.pi


#: What a sheen layer lies over (``Material.sheen_layer``), by index: its ``Sheen.layer`` codes
SHEEN_LAYERS = ("diffuse", "base", "coat")


@dataclass(frozen=True)
class Sheen:
    """The sheen layer at M shading points (module docstring "Sheen"): weight w (M,), colour C (3, M), roughness
    (M,), ``layer`` (M,) int8 :data:`SHEEN_LAYERS` codes and ``zeltner`` (M,) bool (the LTC lobe), each None where
    every point has the default (over the diffuse lobe; the Imageworks lobe)."""

    weight: np.ndarray
    colour: np.ndarray
    roughness: np.ndarray
    layer: np.ndarray | None = None
    zeltner: np.ndarray | None = None


@dataclass(frozen=True)
class Layering:
    """MaterialX's layering and energy compensation at M points (module docstring "MaterialX layering"), passed in
    :class:`Fresnel`'s ``layering``: ``points`` (M,) bool, the points it applies to (None: all; the others shade
    as without it, bit for bit); the dielectric specular layer's share of the lobe's Fresnel, Schlick ``share0``,
    ``share90`` (3, M) (the coat's tint × (1 − metallic) × the lobe's tint included: F_d = share0 + (share90 −
    share0)(1 − v·h)⁵); that layer's own Fresnel F_u, Schlick ``own0``, ``own90`` (3, M) (MaterialX's F of
    ``mx_dielectric_bsdf`` / ``mx_generalized_schlick_bsdf``, without the tint and weight that scale the lobe:
    F_d = c ⊙ F_u for some c), and its ``weight`` (M,) (the node's weight: what the layer's throughput
    1 − weight·E_u(θo)·(…) scales); the metal share's weight ``metal`` (3, M) (F_m = metal ⊙ F_metal, F_metal ≤ 1:
    open_pbr's and gltf_pbr's generalized_schlick_bsdf weight × metallic, standard_surface's conductor's metallic,
    each × the coat's tint)."""

    points: np.ndarray | None
    share0: np.ndarray
    share90: np.ndarray
    own0: np.ndarray
    own90: np.ndarray
    weight: np.ndarray
    metal: np.ndarray


@dataclass(frozen=True)
class Fresnel:
    """A specular lobe's Fresnel at M points beyond Schlick's F0 and F90 (module docstring "MaterialX metals"),
    passed to :class:`Bsdf` as its ``f90``: F90 (3, M), or None (the BSDF's min(1, 50·luminance(F0))); the F82
    term's coefficient b (3, M) (F −= b·μ(1 − μ)⁶), or None; the conductor term's weight w, η and κ (3, M) each
    (F += w ⊙ F_c(μ; η, κ)), or None; and MaterialX's layering (:class:`Layering`), or None."""

    f90: np.ndarray | None
    f82: np.ndarray | None = None
    conductor: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    layering: Layering | None = None


#: cos θ of the F82 tint's angle (θ = 81.79°) and 1/(μ(1 − μ)⁶) there (MaterialX ``mx_fresnel_hoffman_schlick``)
F82_COS = 1.0 / 7.0
F82_FACTOR = 1.0 / (F82_COS * (1.0 - F82_COS) ** 6)


def f82_coefficient(f0: np.ndarray, f82: np.ndarray) -> np.ndarray:
    """a of ``mx_fresnel_hoffman_schlick`` (F90 = 1, exponent 5): Schlick(F0, 1)(1/7)·(1 − F82)/((1/7)(6/7)⁶), so
    that Schlick(F0, 1)(μ) − a·μ(1 − μ)⁶ is F82 × Schlick's value at μ = 1/7."""
    return (f0 + (1 - f0) * (1 - F82_COS) ** 5) * (1 - f82) * F82_FACTOR


def artistic_ior(reflectivity: np.ndarray, edge_color: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MaterialX ``artistic_ior`` (``mx_artistic_ior``, Gulbrandsen 2014, "Artist Friendly Metallic Fresnel"): the
    complex IOR (η, κ) whose conductor Fresnel has normal-incidence reflectance r = clamp(reflectivity, 0, 0.99), η
    mixed from n_max = (1 + √r)/(1 − √r) (edge colour 0) to n_min = (1 − r)/(1 + r) (edge colour 1)."""
    r = np.clip(reflectivity, 0, 0.99)
    root = np.sqrt(r)
    n_min = (1 - r) / (1 + r)
    n_max = (1 + root) / (1 - root)
    eta = n_max + (n_min - n_max) * edge_color
    k2 = ((eta + 1) ** 2 * r - (eta - 1) ** 2) / (1 - r)
    return eta, np.sqrt(np.maximum(k2, 0))


def fresnel_conductor(c: np.ndarray, eta: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """MaterialX ``mx_fresnel_conductor``: the exact unpolarised Fresnel reflectance ½(R_s + R_p) of a conductor of
    complex IOR η + iκ under air at cos θ = c (clamped to [0, 1]; 0 where it is 0/0: η = 1, κ = 0 at grazing)."""
    c = np.clip(c, 0, 1)
    c2 = c * c
    s2 = 1 - c2
    n2, k2 = eta * eta, kappa * kappa
    t0 = n2 - k2 - s2
    ab = np.sqrt(t0 * t0 + 4 * n2 * k2)
    t1 = ab + c2
    t2 = 2 * np.sqrt(np.maximum(0.5 * (ab + t0), 0)) * c
    rs = (t1 - t2) / np.maximum(t1 + t2, TINY)  # t1 + t2 = 0 only where t1 = t2 = 0
    t3 = c2 * ab + s2 * s2
    t4 = t2 * s2
    # ½(R_s + R_p), R_p = R_s·(t3 − t4)/(t3 + t4); at 0 where rounding leaves −ε (η = 1, κ = 0: no reflection)
    return np.maximum(0.5 * rs * (1 + (t3 - t4) / np.maximum(t3 + t4, TINY)), 0)


def _pow5(x: np.ndarray) -> np.ndarray:
    x2 = x * x
    return x2 * x2 * x


class Bsdf:
    """The BSDF at M shading points, structure-of-arrays (:mod:`bakery.capture.vec`): normals n (3, M) facing wo,
    outgoing directions wo (3, M) (towards the viewer), diffuse albedo (3, M), F0 (3, M) and roughness (M,); ``f90``
    (M,) or (3, M), or a :class:`Fresnel` (a MaterialX metal's terms beyond Schlick).

    The GGX terms are those of :func:`bakery.brdf.ggx.ggx_distribution`, :func:`~bakery.brdf.ggx.
    smith_visibility_correlated` and the VNDF of :mod:`bakery.brdf.sampling`, written out for (3, M) arrays: with
    c = wo·wi, the half vector's cosines are v·h = √((1 + c)/2) and n·h = (n·wo + n·wi)/√(2 + 2c), and the
    specular pdf of a reflected VNDF sample is G1(wo)·D(h)/(4 n·wo) (the v·h factors cancel), so evaluating needs
    no tangent frame.
    """

    def __init__(self, normals: np.ndarray, wo: np.ndarray, albedo: np.ndarray, f0: np.ndarray,
                 roughness: np.ndarray, geometric: np.ndarray | None = None,
                 coat: tuple[np.ndarray, np.ndarray] | None = None, f90: np.ndarray | Fresnel | None = None,
                 sheen: Sheen | None = None,
                 rough_diffuse: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.n = normals
        #: the geometric normal (3, M) facing wo when ``normals`` are interpolated shading normals: directions
        #: below the geometric surface get no value and no pdf (a sampled one ends its path), so shading normals
        #: never let light through a surface
        self.geometric = geometric
        self.wo = wo
        self.f0 = f0
        #: the sheen layer (module docstring "Sheen"): None, or (w·C (3, M), roughness (M,), zeltner (M,) bool or
        #: None, layer (M,) or None, 1 − w·E (M,))
        self.sheen = None
        keep_sheen = None  # (M,) what lies under a sheen over the specular lobe keeps, or None
        if sheen is not None and bool(np.any(sheen.weight > 0)):
            weight, sheen_roughness = sheen.weight, sheen.roughness
            nv_sheen = np.clip(dot(normals, wo), 0, 1)
            sheen_albedo = directional_albedo(nv_sheen, sheen_roughness)
            if sheen.zeltner is not None:
                sheen_albedo = np.where(sheen.zeltner, sheen_ltc.directional_albedo(nv_sheen, sheen_roughness),
                                        sheen_albedo)
            throughput = 1 - weight * sheen_albedo.astype(albedo.dtype)
            albedo_layer = albedo * throughput  # what the base keeps under the sheen
            self.sheen = ((weight * sheen.colour).astype(albedo.dtype, copy=False), sheen_roughness, sheen.zeltner,
                          sheen.layer, throughput)
            if sheen.layer is not None:
                keep_sheen = np.where(sheen.layer >= 1, throughput, 1).astype(albedo.dtype, copy=False)
            # the lobe's share of the diffuse branch's choice: its directional albedo, w·C·E
            sheen_albedo = self.sheen[0] * (1 - throughput) / np.maximum(weight, TINY)
            albedo = albedo_layer
            lobe_albedo = albedo_layer + sheen_albedo
        else:
            lobe_albedo = albedo
        self.albedo_pi = albedo * _INV_PI
        #: Oren–Nayar roughness (M,) and energy compensation (M,) bool of the diffuse lobe, or None (Lambertian)
        self.rough_diffuse = None
        if rough_diffuse is not None and bool(np.any(rough_diffuse[0] > 0)):
            self.rough_diffuse = (rough_diffuse[0].astype(albedo.dtype, copy=False), rough_diffuse[1])
        #: the F82 term's coefficient b (3, M) (F −= b·μ(1 − μ)⁶, F clamped at 0), or None; the conductor term
        #: (points (K,) or None for all, w, η, κ (3, K)), or None (module docstring "MaterialX metals")
        self.f82 = self.conductor = None
        conductor_lobe = layering = None
        if isinstance(f90, Fresnel):
            layering = f90.layering
            self.f82 = f90.f82
            if f90.conductor is not None:
                weight = f90.conductor[0]
                conductor_lobe = vmax(weight) > 0
                idx = np.flatnonzero(conductor_lobe)
                if idx.size == 0:
                    conductor_lobe = None
                elif idx.size == conductor_lobe.size:
                    self.conductor = (None, *f90.conductor)
                else:
                    self.conductor = (idx, *(np.take(a, idx, axis=-1) for a in f90.conductor))
            f90 = f90.f90
        #: F90 (M,) from F0 (module docstring), or (3, M) as given (a tinted specular lobe: Surfaces.params_soa)
        self.f90 = np.minimum(1, 50 * luminance(f0)) if f90 is None else f90
        alpha = np.maximum(roughness * roughness, MIN_ALPHA)
        self.alpha = alpha
        self.a2 = alpha * alpha
        self.nv_raw = dot(normals, wo)
        nv = np.clip(self.nv_raw, 1e-6, 1)
        self.nv = nv
        specular = self.f90 > 0 if self.f90.ndim == 1 else vmax(self.f90) > 0
        if conductor_lobe is not None:
            specular = specular | conductor_lobe
        diffuse = vmax(lobe_albedo) > 0
        self.any_specular = bool(specular.any())
        #: points (indices) whose lobe is sharp enough (α < 0.03) for float32 cancellation in D's denominator to
        #: matter; chosen per point, so a point's value does not depend on the other points of the batch
        self.sharp = np.flatnonzero(specular & (alpha < 0.03))
        fv = self._fresnel(nv)
        #: MaterialX's layering (module docstring "MaterialX layering"), or None: the points (M,) bool or None (all),
        #: the specular lobe's compensation k = (1 − E_ss)/E_ss (M,), the dielectric share's Schlick F0 and F90 − F0
        #: (3, M), the layer's own (M,) if grey, else (3, M), the throughput's w·mean(E_u) (M,) and w·k·E_u (M,) if
        #: grey, else w·k·E_u/3 (3, M), and 1/(the metal's weight) (3, M), or None without a metal share
        self.layer = None
        keep_v = 1 - fv  # what the base keeps under the specular lobe, towards the viewer (the lobe choice)
        if layering is not None:
            a, b = ggx_albedo.lookup(nv, alpha)
            k = (1 - (a + b)) / np.maximum(a + b, TINY)
            own0, own90 = layering.own0, layering.own90
            if bool(np.all(own0 == own0[0]) and np.all(own90 == own90[0])):  # a grey Fresnel (dielectric_bsdf)
                own0, own90 = own0[0], own90[0]
            albedo_u = own0 * a + own90 * b  # E_u(θo) = F0·A + F90·B of the layer's own Fresnel
            weight = layering.weight.astype(nv.dtype, copy=False)
            metal = layering.metal
            inv_metal = None  # 1/(the metal's weight), None without a metal share
            if bool(np.any(metal > 0)):
                with np.errstate(divide="ignore"):
                    inv_metal = np.where(metal > 0, 1 / np.where(metal > 0, metal, 1), 0).astype(nv.dtype, copy=False)
            self.layer = (layering.points, k, layering.share0, layering.share90 - layering.share0, own0, own90 - own0,
                          weight * (albedo_u if albedo_u.ndim == 1 else albedo_u.mean(axis=0)),
                          (weight * k) * (albedo_u if albedo_u.ndim == 1 else albedo_u / 3), inv_metal)
            fv, keep_v = self._layered(_pow5(1 - nv), fv)
        spec_w = luminance(fv) if keep_sheen is None else luminance(fv) * keep_sheen
        total = spec_w + luminance(lobe_albedo * keep_v)
        with np.errstate(divide="ignore", invalid="ignore"):
            ps = np.clip(np.where(total > 0, spec_w / total, 0.5), 0.05, 0.95)
        self.p_spec = np.where(specular, np.where(diffuse, ps, 1), 0).astype(nv.dtype, copy=False)
        if self.any_specular:
            a2 = self.a2
            self.sqv = np.sqrt(nv * nv * (1 - a2) + a2)  # the n·v half of the correlated Smith visibility
            tan2 = (1 - nv * nv) / (nv * nv)
            g1v = 1 / (1 + 0.5 * (np.sqrt(1 + a2 * tan2) - 1))  # Smith G1(wo)
            self.spec_pdf_scale = self.p_spec * g1v / (4 * nv)
        #: the clearcoat lobe (module docstring "Clearcoat"): None, or amount (M,) and GGX α² (M,); MaterialX's coat
        #: layer (module docstring "MaterialX layering"): None, or its compensation k_c (M,) and coat·E_c(θo) (M,)
        self.coat = self.coat_layer = None
        if coat is not None and bool(np.any(coat[0] > 0)):
            amount = np.clip(coat[0], 0, 1).astype(nv.dtype, copy=False)
            alpha_c = np.maximum(coat[1] * coat[1], MIN_ALPHA).astype(nv.dtype, copy=False)
            a2c = alpha_c * alpha_c
            f0c = coat[2] if len(coat) > 2 else COAT_F0  # (M,) from the coat's IOR, or 0.04
            fc_v = amount * (f0c + (1 - f0c) * _pow5(1 - nv))  # the coat's Fresnel towards the viewer
            keep_c = 1 - fc_v
            if self.layer is not None:
                a, b = ggx_albedo.lookup(nv, alpha_c)
                k_c = (1 - (a + b)) / np.maximum(a + b, TINY)
                self.coat_layer = (k_c, amount * (f0c * a + b))
                own_c = f0c + (1 - f0c) * _pow5(1 - nv)
                fc_v, keep_c = self._coat_layered(own_c, fc_v, keep_c, lambda x: x)
            base = (spec_w + luminance(lobe_albedo * keep_v)) * keep_c
            with np.errstate(divide="ignore", invalid="ignore"):
                pc = np.clip(np.where(fc_v + base > 0, fc_v / (fc_v + base), 0.5), 0.05, 0.95)
            self.p_coat = np.where(amount > 0, np.where(base > 0, pc, 1), 0).astype(nv.dtype, copy=False)
            tan2 = (1 - nv * nv) / (nv * nv)
            g1c = 1 / (1 + 0.5 * (np.sqrt(1 + a2c * tan2) - 1))
            self.coat = (amount, alpha_c, a2c, np.sqrt(nv * nv * (1 - a2c) + a2c), self.p_coat * g1c / (4 * nv),
                         np.flatnonzero((amount > 0) & (alpha_c < 0.03)), f0c)

    def _fresnel(self, c: np.ndarray, e=lambda a: a) -> np.ndarray:  # noqa: ANN001
        """F (3, ..., M) at cosines c (..., M) between the viewer (or light) and the microfacet normal; ``e`` expands
        per-point (…, M) arrays to c's shape (:meth:`_lobes`)."""
        c = np.clip(c, 0, 1)
        f0 = e(self.f0)
        one_minus = 1 - c
        f = f0 + (e(self.f90) - f0) * _pow5(one_minus)
        if self.f82 is not None:  # mx_fresnel_hoffman_schlick's −a·μ(1 − μ)⁶ on the metallic share
            six = _pow5(one_minus) * one_minus
            f = np.maximum(f - e(self.f82) * (c * six), 0)
        if self.conductor is not None:  # w ⊙ mx_fresnel_conductor(μ, η, κ) of the metallic share
            idx, weight, eta, kappa = self.conductor
            if idx is None:
                f = f + e(weight) * fresnel_conductor(c, e(eta), e(kappa))
            else:  # f is a fresh (3, ..., M) array
                f[..., idx] += e(weight) * fresnel_conductor(np.take(c, idx, axis=-1), e(eta), e(kappa))
        return f

    def _layered(self, tail: np.ndarray, f: np.ndarray, e=lambda a: a) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
        """MaterialX's specular lobe and what its layer passes to the base (module docstring "MaterialX layering")
        from Schlick's tail (1 − v·h)⁵ (..., M) and the lobe's Fresnel f (3, ..., M) at the same v·h: the
        compensated Fresnel f + k·Σ F_share ⊙ F_share,own (3, ..., M) and the throughput 1 − w·mean(E_u ⊙
        (1 + k·F_u)) (..., M), clamped at 0; at points without the layering, f and 1 − f as they are."""
        points, k, share0, share_slope, own0, own_slope, t0, t1, inv_metal = self.layer
        own = e(own0) + e(own_slope) * tail  # F_u: (..., M) grey, else (3, ..., M)
        share = e(share0) + e(share_slope) * tail
        squares = share * own
        if inv_metal is not None:
            metal = f - share  # the metal's share (F_m = weight ⊙ F_metal), its own Fresnel F_m/weight ≤ 1
            squares = squares + metal * np.clip(metal * e(inv_metal), 0, 1)
        compensated = f + e(k) * squares
        taken = e(t1) * own
        keep = np.maximum(1 - e(t0) - (taken if taken.ndim == tail.ndim else taken.sum(axis=0)), 0)
        if points is None:
            return compensated, keep
        mask = e(points)
        return np.where(mask, compensated, f), np.where(mask, keep, 1 - f)

    def _coat_layered(self, own: np.ndarray, fc: np.ndarray, keep: np.ndarray,
                      e) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
        """MaterialX's coat (module docstring "MaterialX layering") from its own Fresnel ``own`` (..., M), F_c =
        coat·own ``fc`` and 1 − F_c ``keep``: its compensated Fresnel F_c·(1 + k_c·own) and the throughput
        1 − coat·E_c(θo)·(1 + k_c·own), clamped at 0; at points without the layering, fc and keep as they are."""
        k_c, albedo_c = self.coat_layer
        comp = 1 + e(k_c) * own
        layered_fc, layered_keep = fc * comp, np.maximum(1 - e(albedo_c) * comp, 0)
        points = self.layer[0]
        if points is None:
            return layered_fc, layered_keep
        mask = e(points)
        return np.where(mask, layered_fc, fc), np.where(mask, layered_keep, keep)

    def evaluate(self, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f·cos θi (3, ..., M) and the sampling pdf (..., M) (solid angle) for directions wi (3, M) or (3, J, M)
        (J directions per point)."""
        diffuse, specular, pdf, above = self._lobes(wi)
        value = diffuse if specular is None else diffuse + specular
        return value * above, pdf * above

    def evaluate_lobes(self, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """As :meth:`evaluate`, the diffuse and the specular lobe's f·cos θi apart (3, ..., M) each, and the pdf
        (lights' diffuse/specular multipliers scale them separately)."""
        diffuse, specular, pdf, above = self._lobes(wi)
        return diffuse * above, (np.zeros_like(diffuse) if specular is None else specular * above), pdf * above

    def _lobes(self, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
        """The diffuse f·cos, the specular f·cos (None without a specular lobe), the pdf and the mask of directions
        above the surface, unmasked."""
        e = (lambda a: a[..., None, :]) if wi.ndim == 3 else (lambda a: a)
        n, wo = e(self.n), e(self.wo)
        nl = dot(n, wi)
        above = (nl > 0).astype(wi.dtype)
        if self.geometric is not None:
            above *= dot(e(self.geometric), wi) > 0
        nlc = np.maximum(nl, 0)
        c = dot(wo, wi)
        inv_h = 1 / np.sqrt(np.maximum(2 + 2 * c, TINY))
        vh = np.clip((1 + c) * inv_h, 0, 1)
        if self.f82 is None and self.conductor is None:
            f0 = e(self.f0)
            f = f0 + (e(self.f90) - f0) * _pow5(1 - vh)
        else:
            f = self._fresnel(vh, e)
        keep = 1 - f  # what the base keeps under the specular lobe
        if self.layer is not None:  # MaterialX: the compensated lobe over its layer's throughput
            f, keep = self._layered(_pow5(1 - vh), f, e)
        if self.rough_diffuse is None:
            diffuse = e(self.albedo_pi) * keep * nlc
        else:  # Oren–Nayar (module docstring "Rough diffuse"): ρ/π × the qualitative factor, or EON's π·f / π
            sigma, compensated = (e(a) for a in self.rough_diffuse)
            nlr, nvr = np.clip(nl, 1e-6, 1), e(self.nv)
            lobe = e(self.albedo_pi) * oren_nayar.qualitative(nlr, nvr, c, sigma)
            if bool(np.any(self.rough_diffuse[1])):
                eon = oren_nayar.energy_preserving(nlr, nvr, c, sigma, e(self.albedo_pi) * math.pi) * _INV_PI
                lobe = np.where(compensated, eon.astype(lobe.dtype, copy=False), lobe)
            diffuse = lobe * keep * nlc
        top = keep_sheen = keep_coat = None
        if self.sheen is not None:  # the sheen lobe where its layer lies (module docstring "Sheen")
            colour, sheen_roughness, zeltner, layer, throughput = self.sheen
            nh = (e(self.nv_raw) + nl) * inv_h
            lobe = sheen_brdf(nlc, e(self.nv), nh, e(sheen_roughness)).astype(diffuse.dtype, copy=False)
            lobe_cos = lobe * nlc
            if zeltner is not None:  # [ZBD22]: E·D already holds n·l
                fuzz = sheen_ltc.sheen_lobe(nl, e(self.nv), c, e(sheen_roughness)).astype(diffuse.dtype, copy=False)
                lobe_cos = np.where(e(zeltner), fuzz, lobe_cos)
            if layer is None:  # over the diffuse lobe, under the specular one
                diffuse = diffuse + e(colour) * (keep * lobe_cos)
            else:
                code = e(layer)
                sheen_cos = e(colour) * lobe_cos
                diffuse = diffuse + np.where(code == 0, keep, (code == 1).astype(diffuse.dtype)) * sheen_cos
                top = (code == 2) * sheen_cos  # over the coat: added last
                keep_sheen = e(np.where(layer >= 1, throughput, 1).astype(diffuse.dtype, copy=False))
                keep_coat = e(np.where(layer == 2, throughput, 1).astype(diffuse.dtype, copy=False))
        specular = None
        pdf = (1 - e(self.p_spec)) * _INV_PI * nlc
        if self.any_specular:
            d, vis = self._ggx(e, n, wo, wi, nl, nlc, inv_h, e(self.a2), e(self.sqv), self.sharp)
            specular = f * (d * vis * nlc)
            if keep_sheen is not None:  # under a sheen over the specular lobe
                specular = specular * keep_sheen
            pdf = pdf + e(self.spec_pdf_scale) * d
        if self.coat is not None:  # [UsdPreviewSurface] clearcoat: a white GGX lobe (F0 0.04) over the base
            amount, _alpha, a2c, sqvc, pdf_scale, sharp, f0c = self.coat
            f0c = e(f0c) if np.ndim(f0c) else f0c
            own_c = f0c + (1 - f0c) * _pow5(1 - vh)
            fc = e(amount) * own_c
            d, vis = self._ggx(e, n, wo, wi, nl, nlc, inv_h, e(a2c), e(sqvc), sharp)
            keep = 1 - fc  # the base sees what the coat transmits
            if self.coat_layer is not None:  # MaterialX: the compensated coat over its layer's throughput
                fc, keep = self._coat_layered(own_c, fc, keep, e)
            diffuse = diffuse * keep
            coat = fc * (d * vis * nlc)
            coat = np.broadcast_to(coat if keep_coat is None else coat * keep_coat, diffuse.shape)
            specular = coat if specular is None else specular * keep + coat
            pdf = (1 - e(self.p_coat)) * pdf + e(pdf_scale) * d
        if top is not None:  # a fuzz layer over the coat
            diffuse = diffuse + top
        return diffuse, specular, pdf, above

    def _ggx(self, e, n, wo, wi, nl, nlc, inv_h, a2, sqv, sharp):  # noqa: ANN001, ANN202
        """GGX D(h) and the height-correlated Smith visibility V (..., M) of a lobe with α² = ``a2``."""
        nh = (e(self.nv_raw) + nl) * inv_h
        den = nh * nh * (a2 - 1) + 1
        if sharp.size:  # 1 − (n·h)² cancels in float32 near the peak of a sharp lobe: |n × h|² there
            k = sharp
            nk, ik, nhk = (np.take(a, k, axis=-1) for a in (n, inv_h, nh))
            hk = np.take(wo, k, axis=-1) + np.take(wi, k, axis=-1)
            cx = nk[1] * hk[2] - nk[2] * hk[1]
            cy = nk[2] * hk[0] - nk[0] * hk[2]
            cz = nk[0] * hk[1] - nk[1] * hk[0]
            den[..., k] = (cx * cx + cy * cy + cz * cz) * (ik * ik) + nhk * nhk * np.take(a2, k, axis=-1)
        with np.errstate(over="ignore"):  # wi = −wo: den overflows, D = 0
            d = (nh > 0) * a2 / (math.pi * den * den)
        vis = 0.5 / np.maximum(nlc * sqv + e(self.nv) * np.sqrt(nlc * nlc * (1 - a2) + a2), TINY)
        return d, vis

    def sample(self, u0: np.ndarray, u1: np.ndarray, u2: np.ndarray, lobes: bool = False) -> tuple[np.ndarray, ...]:
        """Directions wi (3, M), weights f·cos/pdf (3, M) and pdfs (M,) from uniform numbers u0, u1, u2 (M,);
        with ``lobes``, also the diffuse and the specular lobe's part of the weight (3, M) each."""
        t, b = frame(self.n)
        r = np.sqrt(u0)
        phi = (2 * math.pi) * u1
        x, y = r * np.cos(phi), r * np.sin(phi)
        z = np.sqrt(np.maximum(0, 1 - u0))
        wi = x * t + y * b + z * self.n  # cosine-distributed (Malley)
        coat_idx = None
        if self.coat is not None:  # the coat first (u2 < p_coat), then the base's lobes on the rescaled u2
            p_coat = self.p_coat
            coat_idx = np.flatnonzero(u2 < p_coat)
            u2 = np.where(u2 < p_coat, 1, (u2 - p_coat) / np.maximum(1 - p_coat, TINY))
        if self.any_specular:
            idx = np.flatnonzero(u2 < self.p_spec)
            if idx.size:
                tk, bk, nk = (np.take(a, idx, axis=1) for a in (t, b, self.n))
                wo = np.take(self.wo, idx, axis=1)
                h = _sample_vndf(dot(wo, tk), dot(wo, bk), dot(wo, nk), np.take(u0, idx), np.take(u1, idx),
                                 np.take(self.alpha, idx))
                h = h[0] * tk + h[1] * bk + h[2] * nk
                wi[:, idx] = 2 * dot(wo, h) * h - wo
        if coat_idx is not None and coat_idx.size:
            tk, bk, nk = (np.take(a, coat_idx, axis=1) for a in (t, b, self.n))
            wo = np.take(self.wo, coat_idx, axis=1)
            h = _sample_vndf(dot(wo, tk), dot(wo, bk), dot(wo, nk), np.take(u0, coat_idx), np.take(u1, coat_idx),
                             np.take(self.coat[1], coat_idx))
            h = h[0] * tk + h[1] * bk + h[2] * nk
            wi[:, coat_idx] = 2 * dot(wo, h) * h - wo
        if not lobes:
            value, pdf = self.evaluate(wi)
            ok = pdf > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                weight = np.where(ok, value / np.where(ok, pdf, 1), 0)
            return wi, weight, pdf
        diffuse, specular, pdf = self.evaluate_lobes(wi)
        ok = pdf > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(ok, 1 / np.where(ok, pdf, 1), 0)
        weight_d, weight_s = diffuse * inv, specular * inv
        return wi, weight_d + weight_s, pdf, weight_d, weight_s


def _sample_vndf(vx: np.ndarray, vy: np.ndarray, vz: np.ndarray, u1: np.ndarray, u2: np.ndarray,
                 alpha: np.ndarray) -> np.ndarray:
    """h (3, M) ~ D_v(h), the visible normals seen from local v (v_z > 0), isotropic α ([Hei18] Listing 1, as
    :func:`bakery.brdf.sampling.sample_ggx_vndf`)."""
    hx, hy, hz = alpha * vx, alpha * vy, vz
    inv = 1 / np.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    lensq = hx * hx + hy * hy
    positive = lensq > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        il = np.where(positive, 1 / np.sqrt(lensq), 0)
    t1x = np.where(positive, -hy * il, 1)
    t1y = hx * il
    # t2 = vh × t1 (t1_z = 0)
    t2x, t2y, t2z = -hz * t1y, hz * t1x, hx * t1y - hy * t1x
    r = np.sqrt(u1)
    phi = (2 * math.pi) * u2
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1 + hz)
    p2 = (1 - s) * np.sqrt(np.maximum(0, 1 - p1 * p1)) + s * p2
    p3 = np.sqrt(np.maximum(0, 1 - p1 * p1 - p2 * p2))
    nx = p1 * t1x + p2 * t2x + p3 * hx
    ny = p1 * t1y + p2 * t2y + p3 * hy
    nz = p2 * t2z + p3 * hz
    ex, ey, ez = alpha * nx, alpha * ny, np.maximum(1e-12, nz)
    inv = 1 / np.sqrt(ex * ex + ey * ey + ez * ez)
    return np.stack([ex * inv, ey * inv, ez * inv])
