"""Next-event estimation of emissive triangles: the surfaces whose material emits (emissive colours and textures,
GeometryLight and MeshLightAPI meshes) sampled as area lights, so that geometry lit by a neon sign, a screen or a
glowing panel converges like geometry lit by a UsdLux light.

Sampling (area lights as in pbrt; combined with BSDF sampling by Veach's power heuristic, thesis 1997 Ch. 9)
    A triangle k is chosen with probability P_k = Φ_k / Σ Φ, Φ_k = A_k · lum(L̄_k) its power proxy (area × the
    luminance of the emission at its centroid, a texture read at its coarsest level), and a point on it uniformly
    (the square-root parametrisation of Osada et al. 2002: b₁ = 1 − √u₁, b₂ = u₂·√u₁). The solid-angle density
    towards a shading point x at distance d is

        p(ω) = P_k / A_k · d² / |n_k·ω|          (the area density times the area-to-solid-angle Jacobian)

    emission is two-sided (as the capture's surfaces), and the radiance delivered is the material's emission at
    the sampled point (textures, vertex colours). A BSDF-sampled ray that hits an emissive triangle adds its
    emission with the power-heuristic weight against the same density (the renderer); triangles whose proxy is 0
    are never sampled and their emission is found by BSDF rays alone (density 0 there, weight 1), so the estimate
    is unbiased whatever the proxy.

Share (one-sample selection of the strategy)
    A scene's lights are all sampled at every vertex. The emissive triangles' share of the power of the emitters
    with an area, s = Φ_e / (Φ_e + Σ Φ_lights) (A·lum(L): UsdLux sphere, rect, disk and cylinder lights and the
    triangles, each emission read at its mean; distant lights and the dome have none), decides what they cost:
    below :data:`SAMPLED_SHARE` they are not sampled at all (BSDF rays find them with weight 1: a dim screen in a
    lamp-lit room costs no shadow rays), else a vertex samples them with probability q = max(s, 1/4), the
    strategy's density then being q·p(ω) (Veach's multi-sample model with an expected sample count q) in its own
    estimate and in the MIS weights of BSDF rays that hit the triangles.
"""

from __future__ import annotations

import numpy as np

from bakery.capture.vec import luminance

#: Smallest share q of the vertices that sample the emissive triangles (module docstring "Share")
MIN_SHARE = 0.25
#: Power share below which the emissive triangles are not sampled (module docstring "Share")
SAMPLED_SHARE = 0.05


def _mean_emission(material, textures) -> np.ndarray:  # noqa: ANN001 - Material, CaptureScene.textures
    """A material's mean emission (3,): its emissive colour, or its emissive map's texture mean × scale + bias."""
    for entry in material.maps:
        if entry.get("input") == "emissiveColor" and "texture" in entry and 0 <= entry["texture"] < len(textures):
            mean = np.asarray(textures[entry["texture"]].pixels, dtype=np.float64).reshape(-1, 4).mean(axis=0)
            channels = entry.get("channels", "rgb")
            value = mean[:3] if channels == "rgb" else np.full(3, mean["rgba".index(channels)])
            scale, bias = np.asarray(entry.get("scale", (1,) * 4))[:3], np.asarray(entry.get("bias", (0,) * 4))[:3]
            return np.maximum(value * scale + bias, 0.0)
    return np.maximum(np.asarray(material.emission, dtype=np.float64), 0.0)


def emitter_share(scene) -> float:  # noqa: ANN001 - CaptureScene
    """s of the module docstring "Share" (0 when nothing emits) — also what decides a scene's content hash."""
    emitted = 0.0
    for mesh in scene.meshes:
        if not mesh.material.emits or not np.asarray(mesh.triangles).size:
            continue
        tris = np.asarray(mesh.triangles, dtype=np.float64).reshape(-1, 3, 3)
        area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=-1).sum()
        emitted += area * float(luminance(_mean_emission(mesh.material, getattr(scene, "textures", ()))))
    if emitted <= 0:
        return 0.0
    others = sum(light.area * max(float(luminance(np.asarray(light.radiance, dtype=np.float64))), 0.0)
                 for light in scene.lights)
    return emitted / (emitted + others)


#: Distance (m) used for the texture footprint of the centroid reads: the coarsest mip, the texture's mean
_FOOTPRINT = 1e6


class EmissiveTriangles:
    """The emissive triangles of a scene (module docstring): built by :meth:`of`."""

    def __init__(self, prims: np.ndarray, triangles: np.ndarray, normals: np.ndarray, power: np.ndarray,
                 share: float = 1.0) -> None:
        #: q of the module docstring: the probability that a vertex samples the triangles (0: never)
        self.share = float(share)
        #: whether next-event estimation samples the triangles (their power share is at least SAMPLED_SHARE)
        self.sampled = self.share > 0
        self.prims = prims.astype(np.int32)  # (K,) indices of the emissive triangles among the scene's
        self.v0 = np.ascontiguousarray(triangles[:, 0].T, dtype=np.float32)  # (3, K)
        self.e1 = np.ascontiguousarray((triangles[:, 1] - triangles[:, 0]).T, dtype=np.float32)
        self.e2 = np.ascontiguousarray((triangles[:, 2] - triangles[:, 0]).T, dtype=np.float32)
        self.normals = np.ascontiguousarray(normals.T, dtype=np.float32)  # (3, K) unit winding normals
        area = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]),
                                    axis=-1)
        probability = power / max(power.sum(), 1e-300) * self.share  # the expected samples per vertex, q·P_k
        self.cdf = np.cumsum(power / max(power.sum(), 1e-300))
        if self.cdf.size:
            self.cdf[-1] = 1.0
        #: q·P_k / A_k of every triangle of the scene (0 where it is not sampled): the area density of a hit point
        self.area_density: np.ndarray | None = None
        #: (T,) bool: the scene's triangles whose material emits (sampled or not)
        self.emissive: np.ndarray | None = None
        self._probability_per_area = (probability / np.maximum(area, 1e-30)).astype(np.float64)

    @classmethod
    def of(cls, surfaces, tracer) -> EmissiveTriangles | None:  # noqa: ANN001 - Surfaces, SceneTracer
        """The scene's emissive triangles (not :attr:`sampled` when their power share is below
        :data:`SAMPLED_SHARE`), or None when nothing emits."""
        if not surfaces.emissive or tracer.empty:
            return None
        share = emitter_share(surfaces.scene)
        share = max(share, MIN_SHARE) if share >= SAMPLED_SHARE else 0.0
        emits = np.array([m.emits for m in surfaces.materials], dtype=bool)
        prims = np.flatnonzero(emits[np.asarray(tracer.mesh_of)]) if emits.size else np.zeros(0, dtype=np.int64)
        if prims.size == 0:
            return None
        third = np.full(prims.size, 1.0 / 3.0, dtype=np.float32)
        emission = surfaces.params_soa(prims.astype(np.int32), third, third,
                                       np.full(prims.size, _FOOTPRINT, dtype=np.float32), 1.0)[3]
        tris = tracer.triangles[prims]
        area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=-1)
        power = area * np.maximum(luminance(emission.astype(np.float64)), 0.0)
        keep = power > 0
        if not keep.any():
            share = 0.0
        out = cls(prims[keep], tris[keep], tracer.normals[prims[keep]], power[keep], share)
        density = np.zeros(len(tracer.triangles), dtype=np.float32)
        density[prims[keep]] = out._probability_per_area
        out.area_density = density
        out.emissive = np.zeros(len(tracer.triangles), dtype=bool)  # every triangle whose material emits
        out.emissive[prims] = True
        return out

    def sample_soa(self, points: np.ndarray, u0: np.ndarray, u1: np.ndarray, u2: np.ndarray,
                   u3: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For shading points (3, M) and uniform numbers (M,) (u0 float64: the triangle's choice; u3: whether the
        vertex samples at all, u3 < q): the sampled triangles' scene indices (M,), barycentrics b₁, b₂ (M,),
        directions ω (3, M), distances d (M,) and the strategy's solid-angle density q·p(ω) (M,) (0 where the
        vertex does not sample, or degenerate: d or |n·ω| ≈ 0)."""
        k = np.minimum(np.searchsorted(self.cdf, u0, side="right"), self.cdf.size - 1)
        root = np.sqrt(u1)
        b1 = (1 - root).astype(points.dtype, copy=False)
        b2 = (u2 * root).astype(points.dtype, copy=False)
        target = (np.take(self.v0, k, axis=1) + b1 * np.take(self.e1, k, axis=1) + b2 * np.take(self.e2, k, axis=1))
        delta = target - points
        d2 = (delta * delta).sum(axis=0)
        d = np.sqrt(d2)
        with np.errstate(divide="ignore", invalid="ignore"):
            wi = delta / np.where(d > 0, d, 1)
        cos = np.abs((np.take(self.normals, k, axis=1) * wi).sum(axis=0))
        prims = np.take(self.prims, k)
        pdf = self.pdf_soa(prims, d, cos)
        if u3 is not None and self.share < 1.0:
            pdf = np.where(u3 < self.share, pdf, 0).astype(pdf.dtype, copy=False)
        return prims, b1, b2, wi, d, pdf

    def pdf_soa(self, prims: np.ndarray, distance: np.ndarray, cos: np.ndarray) -> np.ndarray:
        """q·p(ω) (M,) of the hit points on triangles ``prims`` (M,) at ``distance`` (M,) seen at |n·ω| = ``cos``
        (module docstring); 0 on triangles that are not sampled and where degenerate."""
        density = np.take(self.area_density, prims)
        ok = (density > 0) & (cos > 1e-6) & (distance > 1e-7)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            pdf = density * distance * distance / np.where(ok, cos, 1)
        return np.where(ok, pdf, 0).astype(np.float32, copy=False)
