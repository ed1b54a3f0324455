"""Reflection encodings (seed 000): split-sum prefiltered chain and SH exponentials. Declared once here and picked
up by store, API and the conformance tests; layouts in ``schemas/store-reflection.md``.

Both reconstruct E(v, n, α, F0) = specular radiance for GGX + height-correlated Smith + Schlick Fresnel
(:mod:`bakery.brdf`), v towards the viewer, α GGX (not perceptual).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from bakery.encodings.registry import Encoding, FieldSpec, register
from bakery.probe import ProbeBatch
from bakery.reflection.lights import evaluate_lights, extract_lights
from bakery.reflection.shexp import SHExpSettings, evaluate_shexp, fit_shexp
from bakery.reflection.splitsum import SplitSumSettings, evaluate_split_sum, prefilter_batch, resize_cube
from bakery.reflection.tables import compute_dfg_tables
from bakery.errors import ClampWarning
from bakery.sphere.cubemap import cube_texel_directions, sample_cube_bilinear

from bakery import operator_cache

operator_cache.install()

#: Largest finite float16; prefiltered radiance above it is clamped (and counted) before storage.
FLOAT16_MAX = 65504.0

#: Shared-table resolution (Nα = Nv) and quadrature samples per axis.
TABLE_SIZE = 64
TABLE_SAMPLES = 64


class ReflectionEncoding(Encoding):
    kind = "reflection"


def _cubes_at(batch: ProbeBatch, face_size: int) -> np.ndarray:
    """The batch's captures at ``face_size``: as is, area-downsampled (power-of-two ratio) or bilinearly
    upsampled (P, 6, F, F, 3) float32."""
    cubes = batch.cubes
    n = batch.face_size
    if n == face_size:
        return cubes
    if n > face_size and n % face_size == 0 and ((n // face_size) & (n // face_size - 1)) == 0:
        return np.stack([resize_cube(c, face_size) for c in cubes]).astype(np.float32)
    dirs = cube_texel_directions(face_size)
    return np.stack([sample_cube_bilinear(c, dirs) for c in cubes]).astype(np.float32)


@register
class SplitSum(ReflectionEncoding):
    """Split-sum ([Kar13]): ``n_levels`` prefiltered cube maps (float16) + the shared DFG table."""

    name = "splitsum"
    version = "1.0.0"
    description = "split-sum GGX prefiltered cube-map chain (v = n), float16 RGB, + DFG scale/bias table"
    #: The chain's face size defaults to the bake's (bakery.bake.instantiate_encoding).
    follows_bake_face_size = True

    def __init__(self, **settings: Any) -> None:
        defaults = {"face_size": 64, "n_levels": 6, "min_face_size": 32}
        super().__init__(**{**defaults, **settings})
        self.chain = SplitSumSettings(
            face_size=int(self.settings["face_size"]),
            n_levels=int(self.settings["n_levels"]),
            min_face_size=int(self.settings["min_face_size"]),
        )
        self.settings["level_alphas"] = [float(a) for a in self.chain.level_alphas()]
        self.settings["roughness_to_level"] = "level = sqrt(alpha) * (n_levels - 1), linear between levels"

    @classmethod
    def from_settings(cls, settings: dict[str, Any]) -> Encoding:
        keep = {k: settings[k] for k in ("face_size", "n_levels", "min_face_size") if k in settings}
        return cls(**keep)

    def field_specs(self) -> tuple[FieldSpec, ...]:
        return tuple(
            FieldSpec(
                f"level{i}", (6, s, s, 3), "float16",
                f"prefiltered radiance, GGX alpha = {a:.6g} (perceptual {np.sqrt(a):.4g}), cube faces "
                "+X,-X,+Y,-Y,+Z,-Z, rows top-down, RGB last",
            )
            for i, (a, s) in enumerate(zip(self.chain.level_alphas(), self.chain.level_sizes(), strict=True))
        )

    def shared_tables(self) -> dict[str, np.ndarray]:
        return {"dfg": compute_dfg_tables(TABLE_SIZE, TABLE_SAMPLES).dfg}

    def encode(self, batch: ProbeBatch) -> dict[str, np.ndarray]:
        levels = prefilter_batch(_cubes_at(batch, self.chain.face_size), self.chain)
        clamped = sum(int(np.count_nonzero(np.asarray(level) > FLOAT16_MAX)) for level in levels)
        if clamped:
            warnings.warn(f"{self.name}: {clamped} prefiltered values above float16's maximum {FLOAT16_MAX:g} were "
                          f"clamped to it", ClampWarning, stacklevel=2)
        return {f"level{i}": np.minimum(np.asarray(level), FLOAT16_MAX).astype(np.float16)
                for i, level in enumerate(levels)}

    def evaluate_reflection(self, fields, shared, view, normal, alpha, f0):
        levels = [np.asarray(fields[f"level{i}"], dtype=np.float32) for i in range(self.chain.n_levels)]
        dfg = shared.get("dfg") if shared else None
        if dfg is None:
            dfg = self.shared_tables()["dfg"]
        return evaluate_split_sum(levels, self.chain, dfg, view, normal, alpha, f0)


@register
class SHExp(ReflectionEncoding):
    """SH exponentials ([SHExp] Sec. 4): p (bands 0..p_band) and q (bands 1..q_band) float32 + Fresnel tail."""

    name = "shexp"
    version = "1.1.0"  # 1.1.0: multi-resolution splatted fit grid and the weighted solve (same stored layout)
    description = ("SH exponentials PQ = exp(<vMF(1/a).Y(r), p>) exp(<vMF(1/a).Y(h_r), q>); E = PQ (F0 A + B) with "
                   "the DFG table (albedo-normalised) or PQ (F0 + (1-F0) tau) (paper)")

    _KEYS = ("p_band", "q_band", "n_normals", "n_views", "n_alphas", "alpha_min", "alpha_max", "fit_face_size",
             "min_fit_face_size", "fit", "albedo_normalized")
    #: Fit modes of stores written before 1.1.0 (both were the unweighted log-space fit).
    _LEGACY_FIT = {"dense": "log", "fast": "log"}

    def __init__(self, **settings: Any) -> None:
        defaults = {"p_band": 4, "q_band": 2, "n_normals": 64, "n_views": 64, "n_alphas": 4, "alpha_min": 0.2,
                    "alpha_max": 1.0, "fit_face_size": 16, "min_fit_face_size": 8, "fit": "weighted",
                    "albedo_normalized": True}
        merged = {**defaults, **{k: v for k, v in settings.items() if k in self._KEYS}}
        merged["fit"] = self._LEGACY_FIT.get(merged["fit"], merged["fit"])
        merged["min_fit_face_size"] = min(int(merged["min_fit_face_size"]), int(merged["fit_face_size"]))
        super().__init__(**merged)
        self.model = SHExpSettings(
            p_band=int(merged["p_band"]), q_band=int(merged["q_band"]), n_normals=int(merged["n_normals"]),
            n_views=int(merged["n_views"]), n_alphas=int(merged["n_alphas"]), alpha_min=float(merged["alpha_min"]),
            alpha_max=float(merged["alpha_max"]), fit_face_size=int(merged["fit_face_size"]),
            min_fit_face_size=int(merged["min_fit_face_size"]), fit=str(merged["fit"]),
            albedo_normalized=bool(merged["albedo_normalized"]),
        )

    def field_specs(self) -> tuple[FieldSpec, ...]:
        return (
            FieldSpec("p", (self.model.p_count, 3), "float32",
                      "log-space SH of P(r), bands 0..p_band, index l*(l+1)+m, RGB last"),
            FieldSpec("q", (self.model.q_count, 3), "float32",
                      "log-space SH of Q(h_r), bands 1..q_band (no DC), index l*(l+1)+m-1, RGB last"),
        )

    def _table_name(self) -> str:
        return "dfg" if self.model.albedo_normalized else "fresnel_tail"

    def shared_tables(self) -> dict[str, np.ndarray]:
        tables = compute_dfg_tables(TABLE_SIZE, TABLE_SAMPLES)
        return {"dfg": tables.dfg} if self.model.albedo_normalized else {"fresnel_tail": tables.fresnel_tail}

    def encode(self, batch: ProbeBatch) -> dict[str, np.ndarray]:
        return self._coefficient_fields(fit_shexp(batch.cubes, self.model))

    def _coefficient_fields(self, coeffs: np.ndarray) -> dict[str, np.ndarray]:
        """(P, K_p + K_q, 3) → the stored ``p`` and ``q`` fields."""
        k = self.model.p_count
        return {"p": np.ascontiguousarray(coeffs[:, :k]), "q": np.ascontiguousarray(coeffs[:, k:])}

    def evaluate_reflection(self, fields, shared, view, normal, alpha, f0):
        coeffs = np.concatenate([np.asarray(fields["p"]), np.asarray(fields["q"])], axis=1)
        table = shared.get(self._table_name()) if shared else None
        if table is None:
            table = self.shared_tables()[self._table_name()]
        return evaluate_shexp(coeffs, table, view, normal, alpha, f0, self.model)


@register
class SHExpLights(SHExp):
    """SH exponentials of the capture without its brightest texels, plus those texels as ``max_lights`` analytic
    directional lights (:mod:`bakery.reflection.lights`; beyond the paper)."""

    name = "shexp_lights"
    version = "1.0.0"
    description = ("SH exponentials (albedo-normalised) of the capture minus its brightest texel clusters, plus "
                   "the clusters as directional lights (direction, RGB flux) evaluated with the same GGX BRDF")

    _KEYS = SHExp._KEYS + ("max_lights", "light_threshold", "light_radius_deg")

    def __init__(self, **settings: Any) -> None:
        light_defaults = {"max_lights": 8, "light_threshold": 10.0, "light_radius_deg": 3.0}
        lights = {k: settings.get(k, v) for k, v in light_defaults.items()}
        super().__init__(**{k: v for k, v in settings.items() if k not in light_defaults})
        if int(lights["max_lights"]) < 0 or not float(lights["light_threshold"]) > 0 or \
                not 0 < float(lights["light_radius_deg"]) < 90:
            raise ValueError(f"shexp_lights: need max_lights >= 0, light_threshold > 0, 0 < light_radius_deg < 90; "
                             f"got {lights}")
        self.settings.update(max_lights=int(lights["max_lights"]), light_threshold=float(lights["light_threshold"]),
                             light_radius_deg=float(lights["light_radius_deg"]))

    def field_specs(self) -> tuple[FieldSpec, ...]:
        k = self.settings["max_lights"]
        return super().field_specs() + (
            FieldSpec("light_direction", (k, 3), "float32",
                      "unit direction towards each light in the bake frame (unused slots: +Y with zero flux)"),
            FieldSpec("light_flux", (k, 3), "float32",
                      "RGB flux of each light: sum of radiance x solid angle over its texels (radiance x sr)"),
        )

    def encode(self, batch: ProbeBatch) -> dict[str, np.ndarray]:
        directions, flux, removed = extract_lights(batch.cubes, self.settings["max_lights"],
                                                   self.settings["light_threshold"],
                                                   self.settings["light_radius_deg"])
        fields = self._coefficient_fields(fit_shexp(batch.cubes, self.model, removed))  # remainder, not copied
        return {**fields, "light_direction": directions, "light_flux": flux}

    def evaluate_reflection(self, fields, shared, view, normal, alpha, f0):
        environment = super().evaluate_reflection(fields, shared, view, normal, alpha, f0)
        a = np.broadcast_to(np.asarray(alpha, dtype=np.float64).reshape(-1), (np.asarray(view).reshape(-1, 3).shape[0],))
        return environment + evaluate_lights(fields["light_direction"], fields["light_flux"], view, normal, a, f0)
