"""Solved hallucinated ZH3: the paper's Listing 1 shader, with linear SH solved for it ([ZH3] Sec. 3.4 + [ZH3S]).

Defines
    class                  name                     what
    ---------------------  -----------------------  ------------------------------------------------------------
    ZH3HallucinatedSolved  zh3_hallucinated_solved  48 bytes of linear SH + a 1-byte flag: the linear SH solved so
                                                    that the hallucinated ZH3 of [ZH3] Eq. 21 / Listing 1 best
                                                    matches the probe's full irradiance, or — per probe, where that
                                                    is not better than SH2 — the projected SH2 band with the flag
                                                    ``hallucinate`` = 0: evaluated as plain ``sh2``

Parameters
    encoding                 recipe key  type                  meaning
    -----------------------  ----------  --------------------  ----------------------------------------------
    zh3_hallucinated_solved  curve           "paper" | [c2, c1]  the (c2, c1) of Eq. 21 the shader uses and the
                                                                   solve targets ("paper" = (0.6, 0.08), the
                                                                   shader of Listing 1)
    zh3_hallucinated_solved  negative_guard  bool                no channel's minimum irradiance may fall below
                                                                   min(0, the paper's hallucination's): the solve
                                                                   adds no negative lobes (default true)
    zh3_hallucinated_solved  min_gain        float in [0, 1)     Listing 1 is used (``hallucinate`` = 1) only
                                                                   where its band-≤2 error is at least this
                                                                   fraction below sh2's (default 0.01)

Stored: ``radiance_sh`` (4, 3) float32 and ``hallucinate`` (1,) uint8 (schemas/store-v1.md, version 1.1.0): where
``hallucinate`` is 1 the probe is read exactly as ``zh3_hallucinated`` (Listing 1 unchanged), where it is 0 as
``sh2`` (Listing 1 without its zonal term) — the one branch engines add, so the encoding is never worse than SH2.
Listing 1 always adds a zonal term ≥ 0 along the luminance axis, so no 48 bytes can switch it off; where the
capture's L2 band is not a positive zonal lobe about the light (interiors lit by a ring of lamps), every input to
Listing 1 is worse than SH2 and only the flag recovers it. Stores of version 1.0.0 have no flag: every probe is
read by Listing 1. The solve (:func:`bakery.irradiance.hallucination.solve_hallucinated_linear`)
minimises the irradiance SH error, which equals the L2 error against the capture's full irradiance up to a
per-probe constant (Parseval; derivation in :mod:`bakery.irradiance.hallucination`).
``worse_than``: the diagnostic ``solved_hallucination_hurts`` flags probes whose reference error is above
``sh2``'s (with the flag, only where the brute-force reference and the capture's SH disagree on a near-tie).

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
from bakery.irradiance.hallucination import hallucination_beats_sh2, solve_hallucinated_linear
from bakery.irradiance.sh_irradiance import evaluate_sh_irradiance
from bakery.irradiance.zh3 import PAPER_HALLUCINATION_CURVE, evaluate_zh3_irradiance, hallucinate_zonal_l2
from bakery.probe import ProbeBatch


HALLUCINATE = FieldSpec("hallucinate", (1,), "uint8",
                        "1: Listing 1 (the zonal term hallucinated from radiance_sh); 0: plain sh2 (no zonal term)")


class ZH3HallucinatedSolved(Encoding):
    """Linear SH solved for the hallucinated reconstruction ([ZH3] Listing 1 unchanged at evaluation)."""

    @dataclass(frozen=True)
    class Params(EncodingParams):
        curve: Literal["paper"] | tuple[float, float] = "paper"
        negative_guard: bool = True
        min_gain: float = 0.01

        def validate(self) -> None:
            if not 0.0 <= self.min_gain < 1.0:
                raise ValueError(f"min_gain must be in [0, 1), got {self.min_gain}")

    name = "zh3_hallucinated_solved"
    kind = "irradiance"
    version = "1.1.0"  # 1.1.0: the per-probe flag ``hallucinate`` (0: plain sh2 where Listing 1 cannot beat it)
    description = ("linear SH solved so that the hallucinated ZH3 of Listing 1 (ZH3 paper Eq. 21) best matches the "
                   "full irradiance; per probe plain SH2 (hallucinate = 0) where that is better")
    max_band = 1
    radiance_sh_field = "radiance_sh"
    worse_than = ("solved_hallucination_hurts", SH2)

    def field_specs(self):
        return (LINEAR_SH, HALLUCINATE)

    def curve(self) -> tuple[float, float]:
        """The (c2, c1) of Eq. 21 that evaluation and the solve use."""
        curve = self.params.curve
        return PAPER_HALLUCINATION_CURVE if curve == "paper" else (float(curve[0]), float(curve[1]))

    def encode(self, batch: ProbeBatch):
        radiance_sh = batch.radiance_sh(2)
        linear, _ = solve_hallucinated_linear(radiance_sh, self.curve(), negative_guard=self.params.negative_guard)
        linear = linear.astype(np.float32)
        projected = radiance_sh[:, :4].astype(np.float32)
        # Listing 1 on the solved band as stored (float32) against plain SH2 on the projected band.
        hallucinate = hallucination_beats_sh2(linear, radiance_sh, self.curve(), self.params.min_gain)
        return {"radiance_sh": np.where(hallucinate[:, None, None], linear, projected),
                "hallucinate": hallucinate.astype(np.uint8)[:, None]}

    def evaluate_irradiance(self, fields, normals):
        linear = fields["radiance_sh"].astype(np.float64)
        # [ZH3] Listing 1: the zonal L2 term hallucinated from the stored linear band (Eq. 21, luminance axis);
        # dropped where the probe's flag is 0 (plain sh2). Version 1.0.0 stores have no flag: Listing 1 everywhere.
        flag = np.asarray(fields["hallucinate"]).reshape(-1) if "hallucinate" in fields else np.ones(len(linear))
        irradiance = evaluate_zh3_irradiance(linear, hallucinate_zonal_l2(linear, self.curve()), normals)
        plain = flag == 0
        if plain.any():  # exactly what sh2 evaluates on the same stored band
            irradiance[plain] = evaluate_sh_irradiance(linear[plain], normals)
        return irradiance


register(ZH3HallucinatedSolved)
