"""Solved hallucinated ZH3: the paper's Listing 1 shader with a per-probe zonal scale, the linear SH solved for it
([ZH3] Sec. 3.4 + [ZH3S]).

Defines
    class                  name                     what
    ---------------------  -----------------------  ------------------------------------------------------------
    ZH3HallucinatedSolved  zh3_hallucinated_solved  48 bytes of linear SH + a 1-byte zonal scale: Listing 1's
                                                    hallucinated zonal term ([ZH3] Eq. 21) times s = code / 64,
                                                    the band and s solved so that the reconstruction best matches
                                                    the probe's full irradiance; code 64 is Listing 1 as published,
                                                    code 0 (where nothing beats it) plain ``sh2``

Parameters
    encoding                 recipe key      type                  meaning
    -----------------------  --------------  --------------------  ----------------------------------------------
    zh3_hallucinated_solved  curve           "paper" | [c2, c1]    the (c2, c1) of Eq. 21 the shader uses and the
                                                                   solve targets ("paper" = (0.6, 0.08), the
                                                                   shader of Listing 1)
    zh3_hallucinated_solved  zonal_scale     "solved" | "paper"    "solved": the scale is solved per probe
                                                                   (codes 0–255); "paper": Listing 1 unchanged,
                                                                   codes 64 or 0 only (the 1.1.0 flag's choice)
    zh3_hallucinated_solved  negative_guard  bool                  no channel's minimum irradiance may fall below
                                                                   min(0, the paper's hallucination's): the solve
                                                                   adds no negative lobes (default true)
    zh3_hallucinated_solved  min_gain        float in [0, 1)       a non-zero code is stored only where its
                                                                   band-≤2 error is at least this fraction below
                                                                   sh2's (default 0.01)

Stored: ``radiance_sh`` (4, 3) float32 and ``zonal_scale`` (1,) uint8 (schemas/store-v1.md, version 1.2.0). The
probe is read as Listing 1 on the stored band with its zonal term multiplied by s = ``zonal_scale`` / 64 (one
multiply over ``zh3_hallucinated``; s = 1 is that encoding exactly, s = 0 is ``sh2`` exactly). Listing 1 always
adds a zonal term ≥ 0 along the luminance axis whose size is set by the linear band alone, so no 48 bytes can
switch it off or size it freely: where the capture's L2 band is not a positive zonal lobe about the light
(interiors lit by a ring of lamps) every input to Listing 1 is worse than SH2 (code 0 recovers it), and where the
lobe is larger or smaller than Eq. 21's curve predicts, the stored s sizes it — the axis and the colour of the
zonal term stay hallucinated from the band. Older stores: 1.1.0 carries a 0/1 flag ``hallucinate`` (read as s),
1.0.0 nothing (s = 1). The solve (:func:`bakery.irradiance.hallucination.solve_scaled_hallucination`) minimises
the irradiance SH error, which equals the L2 error against the capture's full irradiance up to a per-probe constant
(Parseval; derivation in :mod:`bakery.irradiance.hallucination`).
``worse_than``: the diagnostic ``solved_hallucination_hurts`` flags probes whose reference error is above
``sh2``'s (only where the brute-force reference and the capture's SH disagree on a near-tie).

References
    [ZH3]  T. Roughton, P.-P. Sloan, A. Silvennoinen, M. Iwanicki, P. Shirley, "ZH3: Quadratic Zonal Harmonics",
           Proc. ACM Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001).
    [ZH3S] kayru/Probulator ``Source/External/zh3solver`` (the authors' reference solver), re-derived.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bakery.encodings.base import Encoding, EncodingParams, FieldSpec
from bakery.encodings.registry import register
from bakery.encodings.sh import LINEAR_SH, SH2
from bakery.irradiance.hallucination import (
    ZONAL_SCALE_UNIT,
    hallucination_beats_sh2,
    solve_hallucinated_linear,
    solve_scaled_hallucination,
)
from bakery.irradiance.sh_irradiance import evaluate_sh_irradiance
from bakery.irradiance.zh3 import PAPER_HALLUCINATION_CURVE, evaluate_zh3_irradiance, hallucinate_zonal_l2
from bakery.probe import ProbeBatch


ZONAL_SCALE = FieldSpec("zonal_scale", (1,), "uint8",
                        "Listing 1's zonal term times zonal_scale / 64: 64 is Listing 1 as published, 0 plain sh2")


def zonal_scale_of(fields: dict, probes: int) -> np.ndarray:
    """The scale s (P,) float64 of each probe's zonal term: ``zonal_scale`` / 64 (1.2.0), the 0/1 flag
    ``hallucinate`` (1.1.0), or 1 (1.0.0: Listing 1 everywhere)."""
    if "zonal_scale" in fields:
        return np.asarray(fields["zonal_scale"]).reshape(-1).astype(np.float64) / ZONAL_SCALE_UNIT
    if "hallucinate" in fields:
        return np.asarray(fields["hallucinate"]).reshape(-1).astype(np.float64)
    return np.ones(probes)


class ZH3HallucinatedSolved(Encoding):
    """Linear SH and a zonal scale solved for the hallucinated reconstruction ([ZH3] Listing 1, its zonal term
    scaled per probe)."""

    @dataclass(frozen=True)
    class Params(EncodingParams):
        curve: Literal["paper"] | tuple[float, float] = "paper"
        zonal_scale: Literal["solved", "paper"] = "solved"
        negative_guard: bool = True
        min_gain: float = 0.01

        def validate(self) -> None:
            if not 0.0 <= self.min_gain < 1.0:
                raise ValueError(f"min_gain must be in [0, 1), got {self.min_gain}")
            if self.zonal_scale not in ("solved", "paper"):
                raise ValueError(f"zonal_scale must be 'solved' or 'paper', got {self.zonal_scale!r}")

    name = "zh3_hallucinated_solved"
    kind = "irradiance"
    # 1.1.0: the per-probe flag ``hallucinate``; 1.2.0: the flag becomes the solved scale ``zonal_scale``
    version = "1.2.0"
    description = ("linear SH and a per-probe scale of Listing 1's zonal term (ZH3 paper Eq. 21) solved so that the "
                   "hallucinated ZH3 best matches the full irradiance; scale 0 (plain SH2) where nothing beats it")
    max_band = 1
    radiance_sh_field = "radiance_sh"
    worse_than = ("solved_hallucination_hurts", SH2)

    def field_specs(self):
        return (LINEAR_SH, ZONAL_SCALE)

    def curve(self) -> tuple[float, float]:
        """The (c2, c1) of Eq. 21 that evaluation and the solve use."""
        curve = self.params.curve
        return PAPER_HALLUCINATION_CURVE if curve == "paper" else (float(curve[0]), float(curve[1]))

    def encode(self, batch: ProbeBatch):
        radiance_sh = batch.radiance_sh(2)
        guard = self.params.negative_guard
        if self.params.zonal_scale == "solved":
            linear, code, _ = solve_scaled_hallucination(radiance_sh, self.curve(), negative_guard=guard)
        else:
            linear, _ = solve_hallucinated_linear(radiance_sh, self.curve(), negative_guard=guard)
            code = np.full(len(linear), ZONAL_SCALE_UNIT, dtype=np.uint8)
        linear = linear.astype(np.float32)
        projected = radiance_sh[:, :4].astype(np.float32)
        # the scaled Listing 1 on the solved band as stored (float32) against plain SH2 on the projected band
        use = hallucination_beats_sh2(linear, radiance_sh, self.curve(), self.params.min_gain,
                                      scale=code / ZONAL_SCALE_UNIT)
        return {"radiance_sh": np.where(use[:, None, None], linear, projected),
                "zonal_scale": np.where(use, code, 0).astype(np.uint8)[:, None]}

    def evaluate_irradiance(self, fields, normals):
        linear = fields["radiance_sh"].astype(np.float64)
        scale = zonal_scale_of(fields, len(linear))
        # [ZH3] Listing 1: the zonal L2 term hallucinated from the stored linear band (Eq. 21, luminance axis),
        # times the probe's scale (schemas/store-v1.md); scale 0 is read exactly as sh2 reads the band.
        zonal = scale[:, None] * hallucinate_zonal_l2(linear, self.curve())
        irradiance = evaluate_zh3_irradiance(linear, zonal, normals)
        plain = scale == 0
        if plain.any():  # exactly what sh2 evaluates on the same stored band
            irradiance[plain] = evaluate_sh_irradiance(linear[plain], normals)
        return irradiance


register(ZH3HallucinatedSolved)
