"""ZH3 irradiance encodings: linear SH plus one zonal L2 coefficient per channel on a shared axis ([ZH3]).

Defines
    class             name              what
    ----------------  ----------------  ----------------------------------------------------------------------
    ZH3               zh3               linear SH + zonal L2 on the luminance axis of the linear band (Sec. 3.1–3.2,
                                        Eq. 9–10), 15 floats (60 bytes)
    ZH3Solved         zh3_solved        linear band re-solved for the lowest Eq. 11 error (Sec. 3.3, App. C
                                        gradients, batched BFGS, luminance + 4 tetrahedral starts), 60 bytes
    ZH3Deringed       zh3_deringed      luminance-axis ZH3 made non-negative everywhere (App. B bound, exact
                                        minimum, windowing), 60 bytes
    ZH3Hallucinated   zh3_hallucinated  linear SH only; the zonal L2 term is predicted from the L1/L0 ratio at
                                        evaluation (Sec. 3.4, Eq. 21, Listing 1), 48 bytes

Parameters
    encoding          recipe key  type                                    meaning
    ----------------  ----------  --------------------------------------  -------------------------------------------
    zh3_hallucinated  curve       "paper" | "fit" | [float, float]        (c2, c1) of f2^0 = (c2 p² + c1 p) f0:
                                                                          "paper" = Eq. 21's (0.6, 0.08); "fit" =
                                                                          least squares over every probe of the store
                                                                          (method notes §2; the paper's curve when
                                                                          the store has < 12 usable samples),
                                                                          resolved by ``finalize``; a pair = that curve
    ZH3, ZH3Solved and ZH3Deringed have none (``Params = NoParams``). ``fit_samples`` and ``fitted`` are stored by
    ``finalize`` (samples the fit used, whether it replaced the paper's curve); they are not recipe keys.

All store *radiance* coefficients: ``radiance_sh`` (4, 3) bands 0–1 and ``zonal_l2`` (3,) f2^0 in the frame of the
luminance axis computed from the stored linear band (the reader recomputes the axis, so it is not stored).

References
    [ZH3] T. Roughton, P.-P. Sloan, A. Silvennoinen, M. Iwanicki, P. Shirley, "ZH3: Quadratic Zonal Harmonics",
          Proc. ACM Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001).
    [S08] P.-P. Sloan, "Stupid Spherical Harmonics (SH) Tricks", GDC 2008 (windowing, :mod:`bakery.irradiance.dering`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bakery.encodings.base import Encoding, EncodingParams, FieldSpec, NoParams, finalize_field
from bakery.encodings.registry import register
from bakery.encodings.sh import LINEAR_SH, SH2
from bakery.irradiance.dering import dering_zh3
from bakery.irradiance.zh3 import (
    PAPER_HALLUCINATION_CURVE,
    evaluate_zh3_irradiance,
    fit_hallucination_curve,
    fit_zh3_luminance,
    hallucinate_zonal_l2,
    solve_zh3_axis,
)
from bakery.probe import ProbeBatch

ZONAL_L2 = FieldSpec(
    "zonal_l2", (3,), "float32", "zonal L2 radiance coefficient f2^0 per RGB channel in the frame of the luminance "
    "axis of radiance_sh (ZH3 paper Eq. 10)"
)
#: Aux field of ``zh3_hallucinated`` with ``curve = "fit"``: what :meth:`ZH3Hallucinated.finalize` fits over.
RADIANCE_SH3 = FieldSpec("radiance_sh3", (9, 3), "float32",
                         "radiance SH bands 0-2 of the capture, index l*(l+1)+m, RGB last (hallucination curve fit)")


class _ZH3Stored(Encoding):
    """Shared layout and evaluation of the stored ZH3 encodings (linear band + zonal L2)."""

    kind = "irradiance"
    Params = NoParams
    max_band = 2
    radiance_sh_field = "radiance_sh"

    def field_specs(self):
        return (LINEAR_SH, ZONAL_L2)

    def evaluate_irradiance(self, fields, normals):
        return evaluate_zh3_irradiance(
            fields["radiance_sh"].astype(np.float64), fields["zonal_l2"].astype(np.float64), normals
        )

    @staticmethod
    def _fields(linear: np.ndarray, zonal: np.ndarray) -> dict[str, np.ndarray]:
        return {"radiance_sh": linear.astype(np.float32), "zonal_l2": zonal.astype(np.float32)}


class ZH3(_ZH3Stored):
    """ZH3 on the shared luminance axis ([ZH3] Sec. 3.1–3.2, Eq. 9–10): 15 floats per probe."""

    name = "zh3"
    description = "linear SH + zonal L2 on the luminance axis (ZH3 paper Sec. 3.2)"
    Params = NoParams

    def encode(self, batch: ProbeBatch):
        return self._fields(*fit_zh3_luminance(batch.radiance_sh(2)))


class ZH3Solved(_ZH3Stored):
    """ZH3 whose linear band is re-solved to minimise [ZH3] Eq. 11 (App. C gradients, batched BFGS)."""

    name = "zh3_solved"
    description = "ZH3 with the linear band solved for the lowest Eq. 11 error (ZH3 paper Sec. 3.3)"
    Params = NoParams

    def encode(self, batch: ProbeBatch):
        linear, zonal, _ = solve_zh3_axis(batch.radiance_sh(2))
        return self._fields(linear, zonal)


class ZH3Deringed(_ZH3Stored):
    """Luminance-axis ZH3 made non-negative everywhere ([ZH3] App. B clamp + [Sloan 2008/2017] windowing)."""

    name = "zh3_deringed"
    description = "ZH3 (luminance axis) deringed to non-negative irradiance (ZH3 paper App. B, windowing)"
    Params = NoParams

    def encode(self, batch: ProbeBatch):
        linear, zonal = fit_zh3_luminance(batch.radiance_sh(2))
        linear, zonal, _ = dering_zh3(linear, zonal)
        return self._fields(linear, zonal)


class ZH3Hallucinated(Encoding):
    """Linear SH only; the zonal L2 coefficient is hallucinated at evaluation ([ZH3] Listing 1, Eq. 21).

    With ``curve = "fit"``, :meth:`encode` also returns the aux field ``radiance_sh3`` and :meth:`finalize` fits the
    curve over every probe of the store; the curve used is stored in the settings, so evaluation needs nothing else.
    """

    @dataclass(frozen=True)
    class Params(EncodingParams):
        curve: Literal["paper", "fit"] | tuple[float, float] = "paper"
        fit_samples: int | None = finalize_field()
        fitted: bool | None = finalize_field()

        def validate(self) -> None:
            if self.fit_samples is not None and self.fit_samples < 0:
                raise ValueError(f"fit_samples must be >= 0, got {self.fit_samples}")

    name = "zh3_hallucinated"
    kind = "irradiance"
    description = "linear SH with the zonal L2 term hallucinated from the L1/L0 ratio (ZH3 paper Sec. 3.4)"
    max_band = 1
    radiance_sh_field = "radiance_sh"
    worse_than = ("hallucination_hurts", SH2)

    def field_specs(self):
        return (LINEAR_SH,)

    def aux_specs(self):
        return (RADIANCE_SH3,) if self.params.curve == "fit" else ()

    def curve(self) -> tuple[float, float]:
        """The (c2, c1) evaluation uses; ValueError while ``curve = "fit"`` has not been finalized."""
        curve = self.params.curve
        if curve == "paper":
            return PAPER_HALLUCINATION_CURVE
        if curve == "fit":
            raise ValueError(f"{self.name}: curve = 'fit' is not resolved: finalize() was not run over the store's "
                             "probes (aux field radiance_sh3)")
        return float(curve[0]), float(curve[1])

    def encode(self, batch: ProbeBatch):
        sh = batch.radiance_sh(2)
        fields = {"radiance_sh": sh[:, :4].astype(np.float32)}
        if self.params.curve == "fit":
            fields["radiance_sh3"] = sh[:, :9].astype(np.float32)
        return fields

    def finalize(self, fields, aux):
        if self.params.curve != "fit":
            return self.params
        if "radiance_sh3" not in aux:
            raise ValueError(f"{self.name}: finalize with curve = 'fit' needs the aux field radiance_sh3")
        curve, used, fitted = fit_hallucination_curve(np.asarray(aux["radiance_sh3"], dtype=np.float64))
        return self.params.replace(curve=curve, fit_samples=used, fitted=fitted)

    def evaluate_irradiance(self, fields, normals):
        linear = fields["radiance_sh"].astype(np.float64)
        return evaluate_zh3_irradiance(linear, hallucinate_zonal_l2(linear, self.curve()), normals)


register(ZH3, ZH3Solved, ZH3Deringed, ZH3Hallucinated)
