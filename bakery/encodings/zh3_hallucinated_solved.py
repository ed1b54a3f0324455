"""Solved hallucinated ZH3: the paper's Listing 1 shader, with linear SH solved for it ([ZH3] Sec. 3.4 + [ZH3S]).

Defines
    class                  name                     what
    ---------------------  -----------------------  ------------------------------------------------------------
    ZH3HallucinatedSolved  zh3_hallucinated_solved  48 bytes of linear SH, solved so that the hallucinated ZH3 of
                                                    [ZH3] Eq. 21 / Listing 1 (evaluated unchanged) best matches the
                                                    probe's full irradiance; per probe the projected SH2 band (=
                                                    ``zh3_hallucinated``) is kept where the solve does not beat it

Parameters
    encoding                 recipe key  type                  meaning
    -----------------------  ----------  --------------------  ----------------------------------------------
    zh3_hallucinated_solved  curve           "paper" | [c2, c1]  the (c2, c1) of Eq. 21 the shader uses and the
                                                                   solve targets ("paper" = (0.6, 0.08), the
                                                                   shader of Listing 1)
    zh3_hallucinated_solved  negative_guard  bool                no channel's minimum irradiance may fall below
                                                                   min(0, the paper's hallucination's): the solve
                                                                   adds no negative lobes (default true)

Stored: ``radiance_sh`` (4, 3) float32, read exactly as ``zh3_hallucinated`` (schemas/store-v1.md); engines that
evaluate Listing 1 change nothing. The solve (:func:`bakery.irradiance.hallucination.solve_hallucinated_linear`)
minimises the irradiance SH error, which equals the L2 error against the capture's full irradiance up to a
per-probe constant (Parseval; derivation in :mod:`bakery.irradiance.hallucination`).
``worse_than``: the diagnostic ``solved_hallucination_hurts`` flags probes where even the best 48 bytes for
Listing 1 are worse than plain ``sh2`` (interiors whose L2 band is not a positive zonal lobe about the light).

References
    [ZH3]  T. Roughton, P.-P. Sloan, A. Silvennoinen, M. Iwanicki, P. Shirley, "ZH3: Quadratic Zonal Harmonics",
           Proc. ACM Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001).
    [ZH3S] kayru/Probulator ``Source/External/zh3solver`` (the authors' reference solver), re-derived.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bakery.encodings.base import Encoding, EncodingParams
from bakery.encodings.registry import register
from bakery.encodings.sh import LINEAR_SH, SH2
from bakery.irradiance.hallucination import solve_hallucinated_linear
from bakery.irradiance.zh3 import PAPER_HALLUCINATION_CURVE, evaluate_zh3_irradiance, hallucinate_zonal_l2
from bakery.probe import ProbeBatch


class ZH3HallucinatedSolved(Encoding):
    """Linear SH solved for the hallucinated reconstruction ([ZH3] Listing 1 unchanged at evaluation)."""

    @dataclass(frozen=True)
    class Params(EncodingParams):
        curve: Literal["paper"] | tuple[float, float] = "paper"
        negative_guard: bool = True

    name = "zh3_hallucinated_solved"
    kind = "irradiance"
    description = ("linear SH solved so that the hallucinated ZH3 of Listing 1 (ZH3 paper Eq. 21) best matches the "
                   "full irradiance; projected SH2 kept where that is better")
    max_band = 1
    radiance_sh_field = "radiance_sh"
    worse_than = ("solved_hallucination_hurts", SH2)

    def field_specs(self):
        return (LINEAR_SH,)

    def curve(self) -> tuple[float, float]:
        """The (c2, c1) of Eq. 21 that evaluation and the solve use."""
        curve = self.params.curve
        return PAPER_HALLUCINATION_CURVE if curve == "paper" else (float(curve[0]), float(curve[1]))

    def encode(self, batch: ProbeBatch):
        linear, _ = solve_hallucinated_linear(batch.radiance_sh(2), self.curve(),
                                              negative_guard=self.params.negative_guard)
        return {"radiance_sh": linear.astype(np.float32)}

    def evaluate_irradiance(self, fields, normals):
        linear = fields["radiance_sh"].astype(np.float64)
        # [ZH3] Listing 1: the zonal L2 term hallucinated from the stored linear band (Eq. 21, luminance axis).
        return evaluate_zh3_irradiance(linear, hallucinate_zonal_l2(linear, self.curve()), normals)


register(ZH3HallucinatedSolved)
