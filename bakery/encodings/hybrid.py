"""Hybrid reflection encoding (issue 12): SH exponentials + lights for rough α, a bandwidth split-sum chain holding
only the sharp levels the probe needs, blended in log α (:mod:`bakery.reflection.hybrid`).

Defines
    class        name          what
    -----------  ------------  ---------------------------------------------------------------------------------
    SHExpHybrid  shexp_hybrid  ``shexp_lights`` fields (p, q, alpha_range, light_direction, light_flux) fitted over the
                               rough part of the probe's α range, + ``level0`` … ``level{L−1}`` float16 cube levels of
                               the bandwidth chain (level k ≥ 1 at face N >> (k − 1) and the α whose kernel order fits
                               it, seed 003 §5.1) + ``first_level`` (int32): levels below it are zero and not uploaded
                               + with ``gap_level``, ``gap_skipped`` (int32): how many gap levels (1 … s) are not
                               uploaded

Parameters (besides every ``shexp_lights`` parameter)
    recipe key       type          meaning
    ---------------  ------------  ------------------------------------------------------------------------------
    alpha_min        float         smallest material α of the probe, 0 ≤ alpha_min < alpha_max ≤ 1 (default 0: every
                                   chain level); the pipeline overrides it per probe (``accepts_alpha_range``)
    alpha_max        float         largest material α (default 1)
    face_size        int or unset  chain level-0 face size; unset = the bake's (``follows_bake_face_size``; 64 outside a
                                   bake)
    crossover        float         E0 hands from the chain to the SH exponential around this α (0 < · < 1, default
                                   0.3, measured: docs/reflection.md)
    tail_crossover   float         the same for the Fresnel tail E1 (≥ crossover, default 0.5)
    blend_octaves    float         width of both blends in octaves of α (> 0, default 1.5: E0 blend [0.178, 0.505],
                                   E1 blend [0.297, 0.841]; a probe whose materials all have α ≥ 0.841 has no chain)
    band_energy      float         ε of the kernel order F_ε (0 < ε < 1, default 1e-2)
    oversampling     float         chain face size / kernel order (≥ 0.5, default 1.25)
    gap_level        bool          one more chain level at α_1/2, at the capture's face, between the capture and the
                                   first kernel level (default false; true in the console and pc-high recipes).
                                   Below α_1 (0.038 at face 64, 0.019 at 128) the chain otherwise blends the capture
                                   with level 1; measured on the Poly Haven maps at face 64, α = 0.02: 3.88× → 1.29×
                                   the idealised split-sum, α ≥ 0.04 unchanged. It adds 6·N²·6 bytes to the upload of
                                   a probe that reads it: α range below α_1/2 (mirrors included) and some α in
                                   (0, α_2); none where the smallest α is in [α_1/2, α_1) (it takes the capture's
                                   place); a probe whose range starts at a mirror and whose other materials all have
                                   α ≥ α_2 never reads it and skips it (``gap_skipped``; docs/reflection.md)
    gap_levels       int           how many gap levels ``gap_level`` adds, at α_1/2, α_1/4, … α_1·2^(−G), all at N
                                   (1 ≤ G ≤ 4, default 1; 2 in the console and pc-high recipes). The second halves
                                   the capture blend again: at face 64, α = 0.005 / 0.01, the prefiltered radiance's
                                   relative MSE falls from 1.5e-2 / 1.0e-2 to 4.8e-3 / 9.4e-4, within 1.2× of a level
                                   at exactly that α (docs/reflection.md). A probe uploads gap level k only if a
                                   material reads it (α in (α_{k−1}, α_{k+1})); a mirror probe whose other materials
                                   have α ≥ α_{k+1} skips levels 1 … k (``gap_skipped`` = k)
    alpha_min_nonzero
                     float|unset   the smallest material α above 0 of a probe whose alpha_min is 0 (a mirror in
                                   range); read only with gap_level (α ≥ α_2: the gap level is skipped); unset
                                   (default): materials anywhere in the range. The pipeline sets it per probe when
                                   gap_level is on (``probe_alpha_overrides``, bakery.pipeline.roughness)
    keep_capture     bool          store ``level0`` (α = 0: the capture) for every probe, also where ``first_level``
                                   > 0, so that cube-map exports (``bakery export``) can re-prefilter it; store size
                                   only — engines still upload levels ≥ ``first_level`` and the layer omits the others
                                   (default true: a default bake can be exported; false zero-fills level0 there)

Layout and runtime (HLSL) in ``schemas/store-reflection.md``; ``bytes_per_probe`` counts every level (what the store
holds per probe, the upload of a probe that needs the whole chain); :meth:`SHExpHybrid.upload_bytes` is what an
engine uploads for each probe (levels ≥ first_level).

References
    [SHExp]   Silvennoinen et al., "Spherical Harmonic Exponentials for Efficient Glossy Reflections", HPG 2025
              (seed 000): Eq. 5 (E0/E1), Eq. 9–15, Sec. 5.4 (α < 0.25 limitation).
    [Seed003] Ramamoorthi & Hanrahan, "Frequency Space Environment Map Rendering", SIGGRAPH 2002, §5–6 (order and
              resolution from the kernel's bandwidth; frequency-space prefiltering).
    [Kar13]   Karis, "Real Shading in Unreal Engine 4" (split sum).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from bakery.encodings.base import FieldSpec
from bakery.encodings.registry import register
from bakery.encodings.shexp import SHExpLights, fit_shexp_blocks
from bakery.encodings.splitsum import DEFAULT_FACE_SIZE, FLOAT16_MAX, _cubes_at, store_float16
from bakery.errors import ClampWarning
from bakery.probe import ProbeBatch
from bakery.reflection import hybrid as hy
from bakery.reflection.blocks import probe_blocks
from bakery.reflection.lights import evaluate_light_parts, extract_lights
from bakery.reflection.shexp import SHExpSettings, clamped_pq
from bakery.reflection.splitsum import (
    BandwidthChainSettings,
    level_coordinate,
    prefilter_bandwidth_batch,
    sample_levels,
)


class SHExpHybrid(SHExpLights):
    """SH exponentials + lights for rough α, the bandwidth chain for sharp α (module doc)."""

    @dataclass(frozen=True)
    class Params(SHExpLights.Params):
        alpha_min: float = 0.0
        face_size: int | None = None
        crossover: float = 0.3
        tail_crossover: float = 0.5
        blend_octaves: float = 1.5
        band_energy: float = 1e-2
        oversampling: float = 1.25
        # added 2026-12-07; false reproduces the former chain, so it is left out of the probes' content hash there
        gap_level: bool = dataclasses.field(default=False, metadata={"hashed_at_default": False})
        # added 2026-12-07 after gap_level; 1 reproduces the former gap_level chain, so it is left out of the hash there
        gap_levels: int = dataclasses.field(default=1, metadata={"hashed_at_default": False})
        # added 2026-12-07 with the skipped gap level; unset reproduces the former output
        alpha_min_nonzero: float | None = dataclasses.field(default=None, metadata={"hashed_at_default": False})
        keep_capture: bool = True

        def normalize(self):
            # No SH-exp fit floor here: alpha_min is the probe's true smallest α (the chain goes down to it).
            return {"min_fit_face_size": min(self.min_fit_face_size, self.fit_face_size)}

        def validate(self) -> None:
            if not 0.0 <= self.alpha_min < self.alpha_max <= 1.0:
                key = "alpha_min" if not 0.0 <= self.alpha_min < self.alpha_max else "alpha_max"
                raise ValueError(f"{key} must satisfy 0 <= alpha_min < alpha_max <= 1, got alpha_min = "
                                 f"{self.alpha_min}, alpha_max = {self.alpha_max}")
            if self.alpha_min_nonzero is not None and not (self.alpha_min <= self.alpha_min_nonzero
                                                           <= self.alpha_max):
                raise ValueError(f"alpha_min_nonzero must be in [alpha_min, alpha_max] = [{self.alpha_min}, "
                                 f"{self.alpha_max}] (or unset), got {self.alpha_min_nonzero}")
            if self.face_size is not None and self.face_size < 1:
                raise ValueError(f"face_size must be >= 1 (or unset: the bake's face size), got {self.face_size}")
            if not 0.0 < self.crossover < 1.0:
                raise ValueError(f"crossover must be in (0, 1), got {self.crossover}")
            if not self.crossover <= self.tail_crossover < 1.0:
                raise ValueError(f"tail_crossover must be in [crossover, 1), got {self.tail_crossover}")
            if isinstance(self.gap_levels, bool) or not isinstance(self.gap_levels, int | np.integer) \
                    or not 1 <= self.gap_levels <= 4:
                raise ValueError(f"gap_levels must be an integer in [1, 4], got {self.gap_levels!r}")
            if not self.blend_octaves > 0.0:
                raise ValueError(f"blend_octaves must be > 0, got {self.blend_octaves}")
            if not 0.0 < self.band_energy < 1.0:
                raise ValueError(f"band_energy must be in (0, 1), got {self.band_energy}")
            if not self.oversampling >= 0.5:
                raise ValueError(f"oversampling must be >= 0.5, got {self.oversampling}")
            # the SH-exp part's own checks (bands, design size, lights) on its fit range
            SHExpLights.Params(**{f.name: getattr(self, f.name) for f in dataclasses.fields(SHExpLights.Params)
                                  if f.name not in ("alpha_min", "alpha_max")})

    name = "shexp_hybrid"
    kind = "reflection"
    version = "1.0.2"  # 1.0.1: the SH-exp splat of shexp 1.2.1, the chain's SH projection of splitsum 1.0.1;
    # 1.0.2: the chain's SH levels and clamp of splitsum 1.0.2
    description = ("hybrid: bandwidth split-sum chain (float16 cube levels, sharp alpha) blended in log alpha with SH "
                   "exponentials + directional lights (rough alpha); E0 and the Fresnel tail E1 cross over separately")
    accepts_alpha_range = True
    follows_bake_face_size = True
    schema_layouts = {"gap_level = true, gap_levels = 4 (the most levels; the console and pc-high recipes use 2)":
                      {"gap_level": True, "gap_levels": 4}}

    @classmethod
    def probe_alpha_overrides(cls, params, alpha_range, alpha_min_nonzero):
        """The range, and with ``gap_level`` where a mirror is in range, ``alpha_min_nonzero`` (it decides which gap
        levels the probe skips; left out otherwise, where it changes nothing, so those probes' hashes do not
        change)."""
        overrides = super().probe_alpha_overrides(params, alpha_range, alpha_min_nonzero)
        if params.gap_level and alpha_range[0] == 0.0 and alpha_min_nonzero is not None:
            overrides["alpha_min_nonzero"] = alpha_min_nonzero
        return overrides

    def _resolve(self, params):
        return params.replace(face_size=DEFAULT_FACE_SIZE) if params.face_size is None else params

    # ------------------------------------------------------------------------------------------------ pieces
    @cached_property
    def blends(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """([α_lo, α_hi] of the E0 blend, [α_lo, α_hi] of the E1 blend)."""
        p = self.params
        return hy.blend_range(p.crossover, p.blend_octaves), hy.blend_range(p.tail_crossover, p.blend_octaves)

    @cached_property
    def chain(self) -> BandwidthChainSettings:
        p = self.params
        return BandwidthChainSettings(face_size=p.face_size, alpha_top=self.blends[1][1], band_energy=p.band_energy,
                                      oversampling=p.oversampling,
                                      gap_levels=p.gap_levels if p.gap_level else 0)

    @cached_property
    def model(self) -> SHExpSettings:
        """The SH-exp part, fitted over the probe's range above the E0 blend's lower end (where it is used)."""
        p = self.params
        lo = max(p.alpha_min, self.blends[0][0])
        hi = max(p.alpha_max, self.blends[0][1], lo + 0.01)
        return SHExpSettings(
            p_band=p.p_band, q_band=p.q_band, n_normals=p.n_normals, n_views=p.n_views, n_alphas=p.n_alphas,
            alpha_min=float(round(lo, 6)), alpha_max=float(round(min(hi, 1.0), 6)), fit_face_size=p.fit_face_size,
            min_fit_face_size=p.min_fit_face_size, fit=p.fit, albedo_normalized=True,
        )

    @cached_property
    def first_level(self) -> int:
        """The sharpest chain level this instance's α range needs (L: none)."""
        return hy.first_chain_level(self.chain.level_alphas(), self.params.alpha_min, self.blends[1][1])

    @cached_property
    def gap_skipped(self) -> int:
        """How many gap levels (1 … s) this instance's probes skip: with ``gap_level``, where their range starts at a
        mirror (first level 0), the levels no other material's α reads
        (:func:`bakery.reflection.hybrid.gap_levels_skipped`); 0 otherwise."""
        p = self.params
        if not (p.gap_level and self.first_level == 0 and p.alpha_min == 0.0 and p.alpha_min_nonzero is not None):
            return 0
        return hy.gap_levels_skipped(self.chain.level_alphas(), p.gap_levels, p.alpha_min_nonzero)

    def _level_bytes(self) -> np.ndarray:
        return np.array([6 * s * s * 3 * 2 for s in self.chain.level_sizes()])

    def derived_settings(self):
        return {"level_alphas": [float(a) for a in self.chain.level_alphas()],
                "level_sizes": list(self.chain.level_sizes()),
                "e0_blend": list(self.blends[0]), "e1_blend": list(self.blends[1]),
                "roughness_to_level": "x = k + log(alpha/alpha_k)/log(alpha_k+1/alpha_k); below alpha_1: "
                                      "alpha/alpha_1"}

    # ------------------------------------------------------------------------------------------------ layout
    def field_specs(self) -> tuple[FieldSpec, ...]:
        levels = tuple(
            FieldSpec(f"level{k}", (6, size, size, 3), "float16",
                      f"prefiltered radiance, GGX alpha = {a:.6g}, cube faces +X,-X,+Y,-Y,+Z,-Z, rows top-down, RGB "
                      "last; " + ("not uploaded below first_level, where it holds the capture if keep_capture "
                                  "(default) and zero otherwise" if k == 0 else "zero (not uploaded) below first_level"))
            for k, (a, size) in enumerate(self.chain.levels()))
        gap = (FieldSpec("gap_skipped", (1,), "int32",
                         f"s in [0, {self.params.gap_levels}]: the gap levels level1 ... level<s> are zero and not "
                         "uploaded; the chain is read as without them (the probe's materials are a mirror and "
                         "alpha >= level_alphas[s + 1] only)"),
               ) if self.params.gap_level else ()
        return super().field_specs() + levels + (
            FieldSpec("first_level", (1,), "int32",
                      "sharpest chain level the probe needs (levels below are not uploaded: zero, but level0 holds the "
                      "capture with keep_capture); n_levels = SH exponential only"),) + gap

    @classmethod
    def layer_fields(cls, fields: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Every field except the levels below the smallest ``first_level`` of the prim's probes and the gap levels
        1 … s every probe of the prim skips: zero-filled and never uploaded (a reflection probe is one prim, so its
        layer holds exactly its upload)."""
        first = np.asarray(fields["first_level"]).reshape(-1)
        if first.size == 0:
            return fields
        skipped = int(np.min(_gap_skipped(fields, first)))
        unused = {f"level{k}" for k in [*range(int(first.min())), *range(1, skipped + 1)]}
        return {name: value for name, value in fields.items() if name not in unused}

    @classmethod
    def captures_kept(cls, fields: dict[str, np.ndarray], settings: dict[str, Any]) -> np.ndarray:
        """Level 0 holds the capture where ``first_level`` is 0, or everywhere with ``keep_capture``."""
        first = np.asarray(fields["first_level"]).reshape(-1)
        # A store records every setting; one baked before the setting existed kept no capture.
        return np.ones(first.shape, dtype=bool) if settings.get("keep_capture", False) else first == 0

    def upload_bytes(self, fields) -> np.ndarray:
        """(P,) bytes an engine uploads per probe: every field except the levels below ``first_level`` and the skipped
        gap levels (``gap_skipped``)."""
        first = np.asarray(fields["first_level"]).reshape(-1)
        skipped = _gap_skipped(fields, first)
        level_bytes = self._level_bytes()
        fixed = self.bytes_per_probe() - int(level_bytes.sum())
        return np.array([fixed + int(level_bytes[int(k):].sum()) - int(level_bytes[1:1 + s].sum())
                         for k, s in zip(first, skipped, strict=True)], dtype=np.int64)

    # ------------------------------------------------------------------------------------------------ encode
    def encode(self, batch: ProbeBatch) -> dict[str, np.ndarray]:
        p = self.params
        directions, flux, removed = extract_lights(batch.cubes, p.max_lights, p.light_threshold, p.light_radius_deg)
        fields = self._coefficient_fields(fit_shexp_blocks(batch.cubes, self.model, removed))
        fields.update(light_direction=directions, light_flux=flux)
        first = self.first_level
        skip = tuple(range(1, 1 + self.gap_skipped))
        cubes = _cubes_at(batch, self.chain.face_size)
        levels = [np.zeros((batch.count, 6, s, s, 3), np.float16) for s in self.chain.level_sizes()]
        clamped = 0
        for part in probe_blocks(batch.count):  # bounded memory; each probe's levels do not depend on its batch
            for k, level in enumerate(prefilter_bandwidth_batch(cubes[part], self.chain, first, skip)):
                if level is not None:
                    clamped += store_float16(level, levels[k][part])
        if p.keep_capture and first > 0:  # level 0 is α = 0 at the chain's face: the capture itself
            clamped += store_float16(cubes, levels[0])
        if clamped:
            warnings.warn(f"{self.name}: {clamped} prefiltered values above float16's maximum {FLOAT16_MAX:g} were "
                          f"clamped to it", ClampWarning, stacklevel=2)
        fields.update({f"level{k}": level for k, level in enumerate(levels)})
        fields["first_level"] = np.full((batch.count, 1), first, np.int32)
        if p.gap_level:
            fields["gap_skipped"] = np.full((batch.count, 1), self.gap_skipped, np.int32)
        return fields

    # ------------------------------------------------------------------------------------------------ evaluate
    def evaluate_parts(self, fields, shared, view, normal, alpha, f0) -> dict[str, np.ndarray]:
        """The pieces of the reconstruction (module doc of :mod:`bakery.reflection.hybrid`): ``chain`` and ``sh``
        (the E each part alone gives, (P, M, 3)), the chain weights ``w0``, ``w1`` (P, M) and ``E`` (P, M, 3)."""
        from bakery.brdf.ggx import reflect
        from bakery.reflection.tables import lookup_table
        from bakery.reflection.validation import check_reflection_inputs, clamp_view_to_horizon

        # the arguments' rules (bakery.reflection.validation): F0 (M,) or (M, 3), α (M,), view/normal (M, 3)
        v, n, a, f0 = check_reflection_inputs(view, normal, alpha, f0)
        v = clamp_view_to_horizon(v, n)
        coeffs = np.concatenate([np.asarray(fields["p"]), np.asarray(fields["q"])], axis=1)
        nv = np.clip(np.sum(v * n, axis=-1), 0.0, 1.0)
        ab = lookup_table(self._table(shared), nv, a)  # (M, 2)
        f0 = np.broadcast_to(f0[:, None] if f0.ndim == 1 else f0, (v.shape[0], 3))
        pq = clamped_pq(coeffs, v, n, a, self.model, self._alpha_range(fields))
        lights0, lights1 = evaluate_light_parts(fields["light_direction"], fields["light_flux"], v, n, a)
        first = np.asarray(fields["first_level"]).reshape(-1).astype(np.int64)
        skipped = _gap_skipped(fields, first)
        n_levels = self.chain.n_levels
        level_alphas = self.chain.level_alphas()
        # skipped gap levels 1 … s: the chain without them, exactly; one level coordinate per distinct s
        reads = {s: [0, *range(1 + s, n_levels)] for s in np.unique(skipped).tolist()}
        coordinate = {s: level_coordinate(level_alphas[read], a) for s, read in reads.items()}
        r = reflect(v, n)
        chain = np.zeros_like(pq)
        for i in np.flatnonzero(first < n_levels):
            read = reads[int(skipped[i])]
            levels = [np.asarray(fields[f"level{k}"][i]) for k in read]
            x = coordinate[int(skipped[i])]
            chain[i] = sample_levels(levels, np.maximum(x, read.index(first[i])), r)  # never below the sharpest
        has_chain = (first < n_levels)[:, None]
        w0 = np.where(has_chain, hy.chain_weight(a, self.params.crossover, self.params.blend_octaves)[None], 0.0)
        w1 = np.where(has_chain, hy.chain_weight(a, self.params.tail_crossover, self.params.blend_octaves)[None], 0.0)
        ones, zeros = np.ones_like(w0), np.zeros_like(w0)
        return {"E": hy.combine(chain, pq, lights0, lights1, ab, f0, w0, w1),
                "chain": hy.combine(chain, pq, lights0, lights1, ab, f0, ones, ones),
                "sh": hy.combine(chain, pq, lights0, lights1, ab, f0, zeros, zeros), "w0": w0, "w1": w1}

    def evaluate_reflection(self, fields, shared, view, normal, alpha, f0):
        """E (P, M, 3) as specified in ``schemas/store-reflection.md`` (``shexp_hybrid``): α ∈ [0, 1] or ValueError,
        n·v ≤ 0 clamped to the horizon, chain read no sharper than ``first_level``, P·Q at α clamped into the
        fitted range."""
        return self.evaluate_parts(fields, shared, view, normal, alpha, f0)["E"]


def _gap_skipped(fields, first: np.ndarray) -> np.ndarray:
    """(P,) int: how many gap levels (1 … s) each probe skips — ``gap_skipped`` where ``first_level`` (P,) is 0, the
    only case the spec gives it a meaning, else 0 (all 0 for a store without the field: no gap level)."""
    if "gap_skipped" not in fields:
        return np.zeros(first.shape, dtype=np.int64)
    return np.where(first == 0, np.asarray(fields["gap_skipped"]).reshape(-1).astype(np.int64), 0)


register(SHExpHybrid)
