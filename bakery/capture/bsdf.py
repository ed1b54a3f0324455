"""The capture's surface BSDF: Lambertian diffuse plus the GGX specular lobe of the reflection encodings.

    f(wo, wi) = (1 − F(wo·h)) · ρ_d/π  +  F(wo·h) · D(h) · V(wo, wi)

with D the GGX distribution, V the height-correlated Smith visibility G2/(4 (n·wo)(n·wi)) and F Schlick's
Fresnel — exactly the terms of :mod:`bakery.brdf.ggx` that the reflection encodings use. F = F0 + (F90 − F0)(1 −
c)⁵ with F90 = min(1, 50·luminance(F0)) (a surface with F0 = 0 has no specular lobe at all, so a purely diffuse
material is exactly Lambertian). α = roughness², clamped to ≥ :data:`MIN_ALPHA`.

Sampling: one lobe is picked with probability p_s = lum F(n·wo) / (lum F(n·wo) + lum ρ_d(1 − F(n·wo))) clamped to
[0.05, 0.95] (0 or 1 when a lobe is absent); diffuse directions are cosine-distributed, specular ones follow the
GGX distribution of visible normals (:func:`bakery.brdf.sampling.sample_ggx_vndf`). The returned pdf is the
mixture p_s·pdf_s + (1 − p_s)·pdf_d, as multiple importance sampling needs. Surfaces are two-sided (the shading
normal faces the incoming ray).
"""

from __future__ import annotations

import numpy as np

from bakery.brdf.ggx import ggx_distribution, smith_visibility_correlated
from bakery.brdf.sampling import sample_ggx_vndf, vndf_pdf
from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.sphere.sampling import orthonormal_frame

MIN_ALPHA = 1e-3


def cosine_sample(normals: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Cosine-distributed directions (M, 3) about unit normals (M, 3) (Malley's method)."""
    r = np.sqrt(u[:, 0])
    phi = 2.0 * np.pi * u[:, 1]
    x, y = r * np.cos(phi), r * np.sin(phi)
    z = np.sqrt(np.maximum(0.0, 1.0 - u[:, 0]))
    t, s = orthonormal_frame(normals)
    return x[:, None] * t + y[:, None] * s + z[:, None] * normals


class Bsdf:
    """The BSDF at M shading points: normals n (M, 3) facing wo, outgoing directions wo (M, 3) (towards the viewer),
    diffuse albedo (M, 3), F0 (M, 3) and roughness (M,)."""

    def __init__(self, normals: np.ndarray, wo: np.ndarray, albedo: np.ndarray, f0: np.ndarray,
                 roughness: np.ndarray) -> None:
        self.n = normals
        self.wo = wo
        self.roughness = np.asarray(roughness, dtype=np.float64)
        self.albedo = albedo
        self.f0 = f0
        self.f90 = np.minimum(1.0, 50.0 * (f0 @ LUMINANCE_WEIGHTS))[:, None]
        self.alpha = np.maximum(np.asarray(roughness, dtype=np.float64) ** 2, MIN_ALPHA)
        self.t, self.b = orthonormal_frame(normals)
        self.nv = np.clip(np.einsum("ij,ij->i", normals, wo), 1e-6, 1.0)
        self.specular = self.f90[:, 0] > 0
        self.diffuse = albedo.max(axis=1) > 0
        fv = self._fresnel(self.nv)
        spec_w = fv @ LUMINANCE_WEIGHTS
        diff_w = (albedo * (1.0 - fv)) @ LUMINANCE_WEIGHTS
        total = spec_w + diff_w
        ps = np.clip(np.where(total > 0, spec_w / np.where(total > 0, total, 1.0), 0.5), 0.05, 0.95)
        self.p_spec = np.where(~self.specular, 0.0, np.where(~self.diffuse, 1.0, ps))

    def take(self, index: np.ndarray) -> Bsdf:
        """The BSDF at a subset of the points."""
        return Bsdf(self.n[index], self.wo[index], self.albedo[index], self.f0[index], self.roughness[index])

    def _fresnel(self, c: np.ndarray) -> np.ndarray:
        return self.f0 + (self.f90 - self.f0) * ((1.0 - np.clip(c, 0.0, 1.0)) ** 5)[:, None]

    def _local(self, w: np.ndarray, index: np.ndarray | slice = slice(None)) -> np.ndarray:
        return np.stack([np.einsum("ij,ij->i", w, self.t[index]), np.einsum("ij,ij->i", w, self.b[index]),
                         np.einsum("ij,ij->i", w, self.n[index])], axis=-1)

    def evaluate(self, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f·cos θi (M, 3) and the sampling pdf (M,) (solid angle) for directions wi (M, 3)."""
        nl = np.einsum("ij,ij->i", self.n, wi)
        above = nl > 0
        nlc = np.maximum(nl, 0.0)
        h = self.wo + wi
        h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        vh = np.clip(np.einsum("ij,ij->i", self.wo, h), 0.0, 1.0)
        nh = np.einsum("ij,ij->i", self.n, h)
        f = self._fresnel(vh)
        value = self.albedo / np.pi * (1.0 - f) * nlc[:, None]
        pdf = (1.0 - self.p_spec) * nlc / np.pi
        if self.specular.any():
            d = ggx_distribution(nh, self.alpha)
            vis = smith_visibility_correlated(self.nv, nlc, self.alpha)
            value = value + f * (d * vis * nlc)[:, None]
            v_local = self._local(self.wo)
            h_local = self._local(h)
            pdf_h = vndf_pdf(v_local, h_local, self.alpha)
            pdf = pdf + self.p_spec * pdf_h / np.maximum(4.0 * vh, 1e-12)
        value = np.where(above[:, None], value, 0.0)
        return value, np.where(above, pdf, 0.0)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directions wi (M, 3), weights f·cos/pdf (M, 3) and pdfs (M,) from uniform numbers u (M, 3)."""
        m = self.n.shape[0]
        use_spec = u[:, 2] < self.p_spec
        wi = cosine_sample(self.n, u[:, :2])
        if use_spec.any():
            idx = np.flatnonzero(use_spec)
            v_local = self._local(self.wo[idx], idx)
            h_local = sample_ggx_vndf(v_local, u[idx, 0], u[idx, 1], self.alpha[idx])
            h = (h_local[:, 0:1] * self.t[idx] + h_local[:, 1:2] * self.b[idx] + h_local[:, 2:3] * self.n[idx])
            wi[idx] = 2.0 * np.einsum("ij,ij->i", self.wo[idx], h)[:, None] * h - self.wo[idx]
        value, pdf = self.evaluate(wi)
        ok = pdf > 0
        weight = np.where(ok[:, None], value / np.where(ok, pdf, 1.0)[:, None], 0.0)
        return wi, weight, np.where(ok, pdf, 0.0) if m else pdf
