"""SH-exponential reflection encodings ([SHExp] Sec. 4): log-space SH of P(r) and Q(h_r) per probe, with vMF
roughness, fitted through fixed operators (:mod:`bakery.reflection.shexp`), + a DFG or Fresnel-tail table.

Defines
    class        name          what
    -----------  ------------  ---------------------------------------------------------------------------------
    SHExp        shexp         p (bands 0..p_band) and q (bands 1..q_band, no DC) float32 × RGB (33 × RGB) + the
                               fitted α range (2 float32): 404 bytes at the defaults; E = PQ (F0 A + B)
                               (albedo-normalised) or PQ (F0 + (1 − F0) τ), α clamped into the fitted range
    SHExpLights  shexp_lights  ``shexp`` of the capture without its ≤ ``max_lights`` brightest texel clusters, plus
                               those clusters as analytic GGX directional lights (beyond the paper; 596 bytes)

Parameters
    encoding      recipe key         type                 meaning
    ------------  -----------------  -------------------  ---------------------------------------------------------
    both          p_band             int                  highest band of p (0 … 16, default 4)
    both          q_band             int                  highest band of q (0 … 16, default 2; 0 = no Q)
    both          n_normals          int                  design normals (≥ 1, default 64, paper Sec. 5.1)
    both          n_views            int                  design views per normal (≥ 1, default 64)
    both          n_alphas           int                  design roughnesses (≥ 1, default 4)
    both          alpha_min          float                smallest design GGX α, 0 <= alpha_min < alpha_max (0.2);
                                                          values below FIT_ALPHA_FLOOR = 0.05 are fitted from it
    both          alpha_max          float                largest design GGX α, alpha_max ≤ 1 (1.0); the pipeline
                                                          may override both per probe (``accepts_alpha_range``)
    both          fit_face_size      int                  finest fit-grid face size (≥ 1, default 16)
    both          min_fit_face_size  int                  coarsest fit-grid face size (≥ 1, default 8; clamped to
                                                          fit_face_size)
    both          fit                "weighted" | "log"   luminance-weighted (default) or the paper's unweighted
                                                          log-space least squares (stored "dense"/"fast" read as "log")
    both          albedo_normalized  bool                 fit log(E0 / albedo) and reconstruct with the DFG table
                                                          (default true) or the paper's Fresnel-tail form
    shexp_lights  max_lights         int                  light slots per probe (≥ 0, default 8)
    shexp_lights  light_threshold    float                candidate texels: luminance > threshold × mean (> 0, 10)
    shexp_lights  light_radius_deg   float                cluster radius in degrees (0 < r < 90, default 3)

The design needs at least as many rows (n_alphas · n_normals · n_views) as coefficients ((p_band + 1)² +
(q_band + 1)² − 1). Layouts in ``schemas/store-reflection.md``. Importing this module backs the reflection operator
cache with memory-mapped files (:func:`bakery.operator_cache.install`).

References
    [SHExp] A. Silvennoinen, P.-P. Sloan, M. Iwanicki, D. Nowrouzezahrai, "Spherical Harmonic Exponentials for
            Efficient Glossy Reflections", HPG 2025 (seed 000): Eq. 9–14 (model and fit), Sec. 5.1 (design).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bakery import operator_cache
from bakery.encodings.base import Encoding, EncodingParams, FieldSpec
from bakery.encodings.registry import register
from bakery.probe import ProbeBatch
from bakery.reflection.blocks import padded_block, probe_blocks
from bakery.reflection.lights import evaluate_lights, extract_lights
from bakery.reflection.shexp import (
    TABLE_SAMPLES,
    TABLE_SIZE,
    SHExpFitFields,
    SHExpSettings,
    evaluate_shexp,
    fit_shexp,
)
from bakery.reflection.tables import compute_dfg_tables

operator_cache.install()

#: Highest band of p and q a recipe may ask for (289 coefficients per channel; the design must still have as many rows).
MAX_BAND = 16
#: SH-exp's own fit floor: a design range starting below it (e.g. a probe that sees a mirror: the pipeline passes
#: the true α_min, down to 0) is fitted from this α (r ≈ 0.22; paper Sec. 5.4: the model does not hold α < 0.25).
FIT_ALPHA_FLOOR = 0.05


class SHExp(Encoding):
    """SH exponentials ([SHExp] Sec. 4): p (bands 0..p_band) and q (bands 1..q_band) float32 + Fresnel tail."""

    @dataclass(frozen=True)
    class Params(EncodingParams, SHExpFitFields):
        """The fields (p_band … albedo_normalized) and defaults are :class:`SHExpFitFields`'s (one home)."""

        #: Fit modes of stores written before 1.1.0 (both were the unweighted log-space fit).
        LEGACY_VALUES = {"fit": {"dense": "log", "fast": "log"}}

        def normalize(self):
            changes = {"min_fit_face_size": min(self.min_fit_face_size, self.fit_face_size)}
            if 0.0 <= self.alpha_min < FIT_ALPHA_FLOOR:  # the fit floor (pipeline/roughness.py passes the true α_min)
                changes["alpha_min"] = FIT_ALPHA_FLOOR
                changes["alpha_max"] = max(self.alpha_max, round(FIT_ALPHA_FLOOR + 0.01, 6))
            return changes

        def validate(self) -> None:
            for key in ("p_band", "q_band"):
                if not 0 <= getattr(self, key) <= MAX_BAND:
                    raise ValueError(f"{key} must be in [0, {MAX_BAND}], got {getattr(self, key)}")
            for key in ("n_normals", "n_views", "n_alphas", "fit_face_size", "min_fit_face_size"):
                if getattr(self, key) < 1:
                    raise ValueError(f"{key} must be >= 1, got {getattr(self, key)}")
            # GGX α range of the design: 0 < alpha_min < alpha_max <= 1 (normalize() raised [0, floor) to the floor)
            if not self.alpha_min > 0.0:
                raise ValueError(f"alpha_min must be >= 0 (0 <= alpha_min < alpha_max <= 1; below "
                                 f"{FIT_ALPHA_FLOOR} the fit starts at {FIT_ALPHA_FLOOR}), got {self.alpha_min}")
            if not self.alpha_max <= 1.0:
                raise ValueError(f"alpha_max must be <= 1 (0 < alpha_min < alpha_max <= 1), got {self.alpha_max}")
            if not self.alpha_min < self.alpha_max:
                raise ValueError(f"alpha_min must be < alpha_max (0 < alpha_min < alpha_max <= 1), got alpha_min = "
                                 f"{self.alpha_min}, alpha_max = {self.alpha_max}")
            rows = self.n_alphas * self.n_normals * self.n_views
            coefficients = (self.p_band + 1) ** 2 + (self.q_band + 1) ** 2 - 1
            if rows < coefficients:
                raise ValueError(f"n_alphas * n_normals * n_views = {rows} design rows cannot fit {coefficients} "
                                 f"coefficients (p_band {self.p_band}, q_band {self.q_band})")

    name = "shexp"
    kind = "reflection"
    # 1.2.1: the splat multiplies Ω·L per chunk of faces (same sums, float32 rounding); 1.2.0: per-probe fitted
    # α range (evaluation clamps α into it); 1.1.0: splatted fit grid
    version = "1.2.1"
    description = ("SH exponentials PQ = exp(<vMF(1/a).Y(r), p>) exp(<vMF(1/a).Y(h_r), q>); E = PQ (F0 A + B) with "
                   "the DFG table (albedo-normalised) or PQ (F0 + (1-F0) tau) (paper)")
    accepts_alpha_range = True

    @cached_property
    def model(self) -> SHExpSettings:
        return SHExpSettings.from_fields(self.params)

    def field_specs(self) -> tuple[FieldSpec, ...]:
        return (
            FieldSpec("p", (self.model.p_count, 3), "float32",
                      "log-space SH of P(r), bands 0..p_band, index l*(l+1)+m, RGB last"),
            FieldSpec("q", (self.model.q_count, 3), "float32",
                      "log-space SH of Q(h_r), bands 1..q_band (no DC), index l*(l+1)+m-1, RGB last"),
            FieldSpec("alpha_range", (2,), "float32",
                      "GGX alpha range [lo, hi] the coefficients were fitted over; evaluation clamps alpha into it"),
        )

    def _table_name(self) -> str:
        return "dfg" if self.model.albedo_normalized else "fresnel_tail"

    def shared_tables(self) -> dict[str, np.ndarray]:
        tables = compute_dfg_tables(TABLE_SIZE, TABLE_SAMPLES)
        return {"dfg": tables.dfg} if self.model.albedo_normalized else {"fresnel_tail": tables.fresnel_tail}

    def encode(self, batch: ProbeBatch) -> dict[str, np.ndarray]:
        return self._coefficient_fields(fit_shexp_blocks(batch.cubes, self.model))

    def _coefficient_fields(self, coeffs: np.ndarray) -> dict[str, np.ndarray]:
        """(P, K_p + K_q, 3) → the stored ``p``, ``q`` and ``alpha_range`` fields."""
        k = self.model.p_count
        fitted = np.array([self.model.alpha_min, self.model.alpha_max], dtype=np.float32)
        return {"p": np.ascontiguousarray(coeffs[:, :k]), "q": np.ascontiguousarray(coeffs[:, k:]),
                "alpha_range": np.tile(fitted, (coeffs.shape[0], 1))}

    def _alpha_range(self, fields) -> np.ndarray:
        """(P, 2) fitted α range of every probe (stores before 1.2.0: the settings' range)."""
        if "alpha_range" in fields:
            return np.asarray(fields["alpha_range"], dtype=np.float64)
        return np.tile([self.model.alpha_min, self.model.alpha_max], (np.asarray(fields["p"]).shape[0], 1))

    def _table(self, shared) -> np.ndarray:
        table = shared.get(self._table_name()) if shared else None
        return self.shared_tables()[self._table_name()] if table is None else table

    def evaluate_reflection(self, fields, shared, view, normal, alpha, f0):
        """E (P, M, 3); α ∈ [0, 1] (ValueError otherwise) is clamped into each probe's fitted range for P·Q."""
        coeffs = np.concatenate([np.asarray(fields["p"]), np.asarray(fields["q"])], axis=1)
        return evaluate_shexp(coeffs, self._table(shared), view, normal, alpha, f0, self.model,
                              self._alpha_range(fields))


def fit_shexp_blocks(cubes: np.ndarray, model: SHExpSettings,
                     removed: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """:func:`~bakery.reflection.shexp.fit_shexp` of P captures (P, 6, N, N, 3) in blocks of
    :data:`~bakery.reflection.blocks.PROBE_BLOCK` (the last padded with black captures): every fit has the same shapes, so a
    probe's coefficients (P, K_p + K_q, 3) depend on its capture alone, not on its batch. ``removed``: (probe index,
    flat texel index) of texels fitted as black."""
    cubes = np.asarray(cubes, dtype=np.float32)
    fitted = []
    for part in probe_blocks(cubes.shape[0]):
        in_part = None
        if removed is not None:
            keep = (removed[0] >= part.start) & (removed[0] < part.stop)
            in_part = (removed[0][keep] - part.start, removed[1][keep])
        fitted.append(fit_shexp(padded_block(cubes, part), model, in_part)[: part.stop - part.start])
    return np.concatenate(fitted) if fitted else fit_shexp(cubes, model, removed)


class SHExpLights(SHExp):
    """SH exponentials of the capture without its brightest texels, plus those texels as ``max_lights`` analytic
    directional lights (:mod:`bakery.reflection.lights`; beyond the paper)."""

    @dataclass(frozen=True)
    class Params(SHExp.Params):
        max_lights: int = 8
        light_threshold: float = 10.0
        light_radius_deg: float = 3.0

        def validate(self) -> None:
            super().validate()
            if self.max_lights < 0:
                raise ValueError(f"max_lights must be >= 0, got {self.max_lights}")
            if not self.light_threshold > 0.0:
                raise ValueError(f"light_threshold must be > 0, got {self.light_threshold}")
            if not 0.0 < self.light_radius_deg < 90.0:
                raise ValueError(f"light_radius_deg must be in (0, 90), got {self.light_radius_deg}")

    name = "shexp_lights"
    version = "1.0.1"  # 1.0.1: the SH-exp splat of 1.2.1
    description = ("SH exponentials (albedo-normalised) of the capture minus its brightest texel clusters, plus "
                   "the clusters as directional lights (direction, RGB flux) evaluated with the same GGX BRDF")

    def field_specs(self) -> tuple[FieldSpec, ...]:
        k = self.params.max_lights
        return super().field_specs() + (
            FieldSpec("light_direction", (k, 3), "float32",
                      "unit direction towards each light in the bake frame (unused slots: +Y with zero flux)"),
            FieldSpec("light_flux", (k, 3), "float32",
                      "RGB flux of each light: sum of radiance x solid angle over its texels (radiance x sr)"),
        )

    def encode(self, batch: ProbeBatch) -> dict[str, np.ndarray]:
        p = self.params
        directions, flux, removed = extract_lights(batch.cubes, p.max_lights, p.light_threshold, p.light_radius_deg)
        fields = self._coefficient_fields(fit_shexp_blocks(batch.cubes, self.model, removed))  # remainder, not copied
        return {**fields, "light_direction": directions, "light_flux": flux}

    def evaluate_reflection(self, fields, shared, view, normal, alpha, f0):
        """SH-exp part (α clamped into the fitted range) + the lights at the material's α (exact at any α)."""
        from bakery.reflection.validation import check_rows, clamp_view_to_horizon

        environment = super().evaluate_reflection(fields, shared, view, normal, alpha, f0)
        v, n, a = check_rows(view, normal, alpha)
        v = clamp_view_to_horizon(v, n)
        return environment + evaluate_lights(fields["light_direction"], fields["light_flux"], v, n, a, f0)


register(SHExp, SHExpLights)
