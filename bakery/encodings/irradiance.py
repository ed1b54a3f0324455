"""Irradiance encodings (seed 001): SH2, SH3, ZH3 (luminance axis, solved axis, hallucinated, deringed) and the
quantized 16-byte ZH3 / 28-byte SH3 layouts. Each is declared once here and picked up by store, API and the
conformance tests. All store *radiance* coefficients (conventions); irradiance is reconstructed at evaluation.
"""

from __future__ import annotations

import warnings

import numpy as np

from bakery.encodings.registry import Encoding, FieldSpec, register
from bakery.irradiance import quantize
from bakery.errors import ClampWarning
from bakery.irradiance.dering import clamp_zonal_l2, dering_zh3
from bakery.irradiance.sh_irradiance import evaluate_sh_irradiance, minimum_sh_irradiance
from bakery.irradiance.zh3 import (
    PAPER_HALLUCINATION_CURVE,
    evaluate_zh3_irradiance,
    expand_zh3_to_sh3,
    fit_hallucination_curve,
    fit_zh3_luminance,
    hallucinate_zonal_l2,
    luminance_axis,
    solve_zh3_axis,
    solve_zonal_l2,
)
from bakery.probe import ProbeBatch

#: Relative irradiance floor used when re-deringing decoded quantized ZH3 (about one SNORM8 step of the ratios).
QUANTIZED_MARGIN = 1.0 / 127.0

_LINEAR = FieldSpec("radiance_sh", (4, 3), "float32", "radiance SH bands 0-1, index l*(l+1)+m, RGB last")
_ZONAL = FieldSpec(
    "zonal_l2", (3,), "float32", "zonal L2 radiance coefficient f2^0 per RGB channel in the frame of the luminance "
    "axis of radiance_sh (ZH3 paper Eq. 10)"
)


def _warn_clamps(name: str, stats: dict) -> None:
    """Warn (counted in the store's ``warnings``) when packing clamped the DC or ratios to the layout's range."""
    if stats["dc_clamped"] or stats["ratios_clamped"]:
        warnings.warn(
            f"{name}: {stats['dc_clamped']} DC values above the R11G11B10F maximum (65024) and "
            f"{stats['ratios_clamped']} ratios outside the App. A bounds were clamped", ClampWarning, stacklevel=3,
        )


def _dering_quantized(packed: np.ndarray, companding: bool, rounds: int = 12) -> np.ndarray:
    """Make decoded quantized ZH3 non-negative: re-dering the decoded values with a relative floor that starts at
    one SNORM8 step and doubles each round, and re-pack, until the exact minimum of every decoded probe is ≥ 0.
    A floor above π·Y00 ≈ 0.886 (relative to f0) leaves only DC, which is non-negative, so this terminates."""
    margin = QUANTIZED_MARGIN
    for _ in range(rounds):
        decoded_linear, decoded_zonal = quantize.unpack_zh3(packed, companding)
        minimum = minimum_sh_irradiance(expand_zh3_to_sh3(decoded_linear, decoded_zonal,
                                                          luminance_axis(decoded_linear)))
        negative = np.any(minimum < 0.0, axis=-1)
        if not negative.any():
            break
        fixed_linear, fixed_zonal, _ = dering_zh3(decoded_linear[negative], decoded_zonal[negative], margin=margin)
        repacked, _ = quantize.pack_zh3(fixed_linear, fixed_zonal, companding)
        packed = packed.copy()
        packed[negative] = repacked
        margin *= 2.0
    return packed


class IrradianceEncoding(Encoding):
    kind = "irradiance"


@register
class SH2(IrradianceEncoding):
    """Linear SH: 4 radiance coefficients per channel (48 bytes as float32)."""

    name = "sh2"
    description = "linear SH (bands 0-1) of radiance"

    def field_specs(self):
        return (_LINEAR,)

    def encode(self, batch: ProbeBatch):
        return {"radiance_sh": batch.radiance_sh(2)[:, :4].astype(np.float32)}

    def evaluate_irradiance(self, fields, normals):
        return evaluate_sh_irradiance(fields["radiance_sh"].astype(np.float64), normals)


@register
class SH3(IrradianceEncoding):
    """Quadratic SH: 9 radiance coefficients per channel (108 bytes as float32)."""

    name = "sh3"
    description = "quadratic SH (bands 0-2) of radiance"

    def field_specs(self):
        return (FieldSpec("radiance_sh", (9, 3), "float32", "radiance SH bands 0-2, index l*(l+1)+m, RGB last"),)

    def encode(self, batch: ProbeBatch):
        return {"radiance_sh": batch.radiance_sh(2).astype(np.float32)}

    def evaluate_irradiance(self, fields, normals):
        return evaluate_sh_irradiance(fields["radiance_sh"].astype(np.float64), normals)


class _ZH3Base(IrradianceEncoding):
    def field_specs(self):
        return (_LINEAR, _ZONAL)

    def evaluate_irradiance(self, fields, normals):
        return evaluate_zh3_irradiance(
            fields["radiance_sh"].astype(np.float64), fields["zonal_l2"].astype(np.float64), normals
        )


@register
class ZH3(_ZH3Base):
    """ZH3 on the shared luminance axis ([ZH3] Sec. 3.1–3.2, Eq. 9–10): 15 floats per probe."""

    name = "zh3"
    description = "linear SH + zonal L2 on the luminance axis (ZH3 paper Sec. 3.2)"

    def encode(self, batch):
        linear, zonal = fit_zh3_luminance(batch.radiance_sh(2))
        return {"radiance_sh": linear.astype(np.float32), "zonal_l2": zonal.astype(np.float32)}


@register
class ZH3Solved(_ZH3Base):
    """ZH3 whose linear band is re-solved to minimise [ZH3] Eq. 11 (App. C gradients, L-BFGS)."""

    name = "zh3_solved"
    description = "ZH3 with the linear band solved for the lowest Eq. 11 error (ZH3 paper Sec. 3.3)"

    def encode(self, batch):
        linear, zonal, _ = solve_zh3_axis(batch.radiance_sh(2), **self.settings)
        return {"radiance_sh": linear.astype(np.float32), "zonal_l2": zonal.astype(np.float32)}


@register
class ZH3Deringed(_ZH3Base):
    """Luminance-axis ZH3 made non-negative everywhere ([ZH3] App. B clamp + [Sloan 2008/2017] windowing)."""

    name = "zh3_deringed"
    description = "ZH3 (luminance axis) deringed to non-negative irradiance (ZH3 paper App. B, windowing)"

    def encode(self, batch):
        linear, zonal = fit_zh3_luminance(batch.radiance_sh(2))
        linear, zonal, _ = dering_zh3(linear, zonal)
        return {"radiance_sh": linear.astype(np.float32), "zonal_l2": zonal.astype(np.float32)}


@register
class ZH3Hallucinated(IrradianceEncoding):
    """Linear SH only; the zonal L2 coefficient is hallucinated at evaluation ([ZH3] Listing 1, Eq. 21).

    Settings: ``curve`` = (c2, c1) of f2^0 = (c2 p² + c1 p) f0; ``"paper"`` uses Eq. 21's (0.6, 0.08) and
    ``"fit"`` fits the curve to the probes of the bake (method notes §2), falling back to the paper's when the bake
    has too few probes. The curve used is stored in the settings attribute, so evaluation needs nothing else.
    """

    name = "zh3_hallucinated"
    description = "linear SH with the zonal L2 term hallucinated from the L1/L0 ratio (ZH3 paper Sec. 3.4)"

    def __init__(self, curve="paper", **settings):
        super().__init__(curve=curve, **settings)

    def field_specs(self):
        return (_LINEAR,)

    def curve(self) -> tuple[float, float]:
        curve = self.settings["curve"]
        if curve == "paper":
            return PAPER_HALLUCINATION_CURVE
        if curve == "fit":
            raise ValueError("zh3_hallucinated: the 'fit' curve is resolved at encode time")
        return float(curve[0]), float(curve[1])

    def encode(self, batch):
        sh = batch.radiance_sh(2)
        if self.settings["curve"] == "fit":
            curve, used, fitted = fit_hallucination_curve(sh)
            self.settings.update(curve=list(curve), fit_samples=used, fitted=fitted)
        return {"radiance_sh": sh[:, :4].astype(np.float32)}

    def evaluate_irradiance(self, fields, normals):
        linear = fields["radiance_sh"].astype(np.float64)
        return evaluate_zh3_irradiance(linear, hallucinate_zonal_l2(linear, self.curve()), normals)


@register
class ZH3Quantized(IrradianceEncoding):
    """16-byte ZH3 ([ZH3] App. A.1): R11G11B10F DC + 12 SNORM8 ratios (layout in :mod:`bakery.irradiance.quantize`).

    Built from the deringed ZH3 (setting ``dering``, default on). The zonal coefficient is re-projected onto the
    axis the reader will compute from the *decoded* linear band and re-clamped with the decoded DC, so that the
    quantized probe is self-consistent.
    """

    name = "zh3_quantized"
    description = "16-byte ZH3: R11G11B10F DC + SNORM8 ratios remapped by the App. A bounds (ZH3 paper App. A.1)"

    def __init__(self, sqrt_companding=True, dering=True, **settings):
        super().__init__(sqrt_companding=bool(sqrt_companding), dering=bool(dering), **settings)

    def field_specs(self):
        return (FieldSpec("packed", (16,), "uint8", "16-byte ZH3 layout, see schemas/store-v1.md"),)

    def encode(self, batch):
        companding = self.settings["sqrt_companding"]
        linear, zonal = fit_zh3_luminance(batch.radiance_sh(2))
        if self.settings["dering"]:
            linear, zonal, _ = dering_zh3(linear, zonal)
        band2 = expand_zh3_to_sh3(linear, zonal, luminance_axis(linear))[:, 4:9]
        first, stats = quantize.pack_zh3(linear, zonal, companding)
        _warn_clamps(self.name, stats)
        decoded_linear, _ = quantize.unpack_zh3(first, companding)
        decoded_axis = luminance_axis(decoded_linear)
        zonal = solve_zonal_l2(band2, decoded_axis)
        if self.settings["dering"]:
            zonal = clamp_zonal_l2(decoded_linear, zonal, decoded_axis)
        packed, _ = quantize.pack_zh3(decoded_linear, zonal, companding)
        if self.settings["dering"]:
            packed = _dering_quantized(packed, companding)
        return {"packed": packed}

    def evaluate_irradiance(self, fields, normals):
        linear, zonal = quantize.unpack_zh3(fields["packed"], self.settings["sqrt_companding"])
        return evaluate_zh3_irradiance(linear, zonal, normals)


@register
class SH3Quantized(IrradianceEncoding):
    """28-byte SH3 ([ZH3] App. A.1, Sec. 4): R11G11B10F DC + 24 SNORM8 ratios."""

    name = "sh3_quantized"
    description = "28-byte SH3: R11G11B10F DC + SNORM8 ratios remapped by the App. A bounds"

    def __init__(self, sqrt_companding=True, **settings):
        super().__init__(sqrt_companding=bool(sqrt_companding), **settings)

    def field_specs(self):
        return (FieldSpec("packed", (28,), "uint8", "28-byte SH3 layout, see schemas/store-v1.md"),)

    def encode(self, batch):
        packed, stats = quantize.pack_sh3(batch.radiance_sh(2), self.settings["sqrt_companding"])
        _warn_clamps(self.name, stats)
        return {"packed": packed}

    def evaluate_irradiance(self, fields, normals):
        return evaluate_sh_irradiance(quantize.unpack_sh3(fields["packed"], self.settings["sqrt_companding"]), normals)
