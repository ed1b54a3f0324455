"""Split-sum reflection encoding ([Kar13]): a GGX-prefiltered cube-map chain (float16) + the shared DFG table.

Defines
    class     name      what
    --------  --------  ---------------------------------------------------------------------------------------
    SplitSum  splitsum  ``n_levels`` prefiltered cube maps, level i at GGX α_i = (i / (n_levels − 1))², face size
                        max(face_size >> i, min(min_face_size, face_size)), float16 RGB; shared ``dfg`` table

Parameters
    recipe key     type          meaning
    -------------  ------------  ------------------------------------------------------------------------------
    face_size      int or unset  level-0 face size (≥ 1); unset = the bake's face size (``follows_bake_face_size``:
                                 the pipeline resolves it before constructing; an instance built unset uses 64)
    n_levels       int           levels of the chain (≥ 1, default 6)
    min_face_size  int           smallest level face size (≥ 1, default 32)

Derived settings (stored, informative): ``level_alphas`` and ``roughness_to_level``. Reconstruction
E(v, n, α, F0) = chain(reflect(v, n), level √α (n_levels − 1)) · (F0 A + B)(n·v, α)
(:mod:`bakery.reflection.splitsum`); layout in ``schemas/store-reflection.md``.

References
    [Kar13] B. Karis, "Real Shading in Unreal Engine 4", SIGGRAPH 2013 course notes (split-sum approximation).
    [SHExp] A. Silvennoinen, P.-P. Sloan, M. Iwanicki, D. Nowrouzezahrai, "Spherical Harmonic Exponentials for
            Efficient Glossy Reflections", HPG 2025 (seed 000), Sec. 3.2 (the split-sum baseline).
    [KC08]  J. Křivánek, M. Colbert, "Real-time Shading with Filtered Importance Sampling", EGSR 2008.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bakery.encodings.base import Encoding, EncodingParams, FieldSpec
from bakery.encodings.registry import register
from bakery.errors import ClampWarning
from bakery.probe import ProbeBatch
from bakery.reflection.blocks import probe_blocks
from bakery.reflection.shexp import TABLE_SAMPLES, TABLE_SIZE
from bakery.reflection.splitsum import SplitSumSettings, evaluate_split_sum, prefilter_batch
from bakery.reflection.tables import compute_dfg_tables
from bakery.sphere.cubemap import resample_cube

#: Largest finite float16; prefiltered radiance above it is clamped (and counted) before storage.
FLOAT16_MAX = 65504.0


def store_float16(values: np.ndarray, out: np.ndarray) -> int:
    """Write float32 ``values`` into the float16 array ``out`` (same shape) clamped to [0, :data:`FLOAT16_MAX`],
    without a full-size temporary; returns how many values were clamped above.

    Below: prefiltered radiance is ≥ 0, but an SH-domain level rings around a sun (the kernel's bands are cut where
    |λ_l| < tolerance: lobes of about that fraction of the peak; 25 % of the texels of the rough levels of a sun
    map, down to −1e-3 of the peak). Clamping them to 0 is the projection onto the non-negative values, so it never
    increases any texel's error, and no lobe of a bright sun can overflow to −inf."""
    values = np.asarray(values)
    np.clip(values, np.float32(0.0), np.float32(FLOAT16_MAX), out=out, casting="same_kind")
    return int(np.count_nonzero(values > FLOAT16_MAX))


#: Level-0 face size of an instance built without one (``face_size`` unset outside a bake).
DEFAULT_FACE_SIZE = 64


def _cubes_at(batch: ProbeBatch, face_size: int) -> np.ndarray:
    """The batch's captures at ``face_size`` (P, 6, F, F, 3) float32, resampled flux-exactly when the sizes differ
    (:func:`bakery.sphere.cubemap.resample_cube`)."""
    if batch.face_size == face_size:
        return batch.cubes
    return np.stack([resample_cube(c, face_size) for c in batch.cubes]).astype(np.float32)


class SplitSum(Encoding):
    """Split-sum ([Kar13]): ``n_levels`` prefiltered cube maps (float16) + the shared DFG table."""

    @dataclass(frozen=True)
    class Params(EncodingParams):
        face_size: int | None = None
        n_levels: int = 6
        min_face_size: int = 32

        def validate(self) -> None:
            if self.face_size is not None and self.face_size < 1:
                raise ValueError(f"face_size must be >= 1 (or unset: the bake's face size), got {self.face_size}")
            if self.n_levels < 1:
                raise ValueError(f"n_levels must be >= 1, got {self.n_levels}")
            if self.min_face_size < 1:
                raise ValueError(f"min_face_size must be >= 1, got {self.min_face_size}")

    name = "splitsum"
    kind = "reflection"
    version = "1.0.2"  # 1.0.1: SH-domain levels projected through the cube's reflection symmetry (float32 rounding);
    # 1.0.2: SH-domain levels with the suns added exactly (no ringing), every level clamped to [0, 65504]
    description = "split-sum GGX prefiltered cube-map chain (v = n), float16 RGB, + DFG scale/bias table"
    follows_bake_face_size = True

    def _resolve(self, params):
        return params.replace(face_size=DEFAULT_FACE_SIZE) if params.face_size is None else params

    @cached_property
    def chain(self) -> SplitSumSettings:
        p = self.params
        return SplitSumSettings(face_size=p.face_size, n_levels=p.n_levels, min_face_size=p.min_face_size)

    def derived_settings(self):
        return {"level_alphas": [float(a) for a in self.chain.level_alphas()],
                "roughness_to_level": "level = sqrt(alpha) * (n_levels - 1), linear between levels"}

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
        cubes = _cubes_at(batch, self.chain.face_size)
        levels = [np.zeros((batch.count, 6, s, s, 3), np.float16) for s in self.chain.level_sizes()]
        clamped = 0
        for part in probe_blocks(batch.count):  # bounded temporaries (≈ 12 MB per probe at 128²)
            for level, out in zip(prefilter_batch(cubes[part], self.chain), levels, strict=True):
                clamped += store_float16(level, out[part])
        if clamped:
            warnings.warn(f"{self.name}: {clamped} prefiltered values above float16's maximum {FLOAT16_MAX:g} were "
                          f"clamped to it", ClampWarning, stacklevel=2)
        return {f"level{i}": level for i, level in enumerate(levels)}

    def evaluate_reflection(self, fields, shared, view, normal, alpha, f0):
        levels = [np.asarray(fields[f"level{i}"], dtype=np.float32) for i in range(self.chain.n_levels)]
        dfg = shared.get("dfg") if shared else None
        if dfg is None:
            dfg = self.shared_tables()["dfg"]
        return evaluate_split_sum(levels, self.chain, dfg, view, normal, alpha, f0)


register(SplitSum)
