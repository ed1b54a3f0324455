"""Quantized irradiance encodings ([ZH3] App. A.1): R11G11B10F DC + SNORM8 ratios remapped by the App. A bounds.

Defines
    class          name           what
    -------------  -------------  -----------------------------------------------------------------------------
    ZH3Quantized   zh3_quantized  16-byte ZH3: R11G11B10F DC + 12 SNORM8 ratios (linear band + zonal L2): the
                                  rounded codes of the deringed ZH3, refined by a search over neighbouring codes
                                  for the lowest irradiance error with a non-negative decoded probe
    SH3Quantized   sh3_quantized  28-byte SH3: R11G11B10F DC + 24 SNORM8 ratios (the layout the paper compares with)

Parameters
    encoding       recipe key       type  meaning
    -------------  ---------------  ----  --------------------------------------------------------------------
    both           sqrt_companding  bool  store sqrt-companded ratios (App. A.1; default true)
    zh3_quantized  dering           bool  dering before packing and keep the decoded probe non-negative everywhere
                                          (the constraint of the code search; default true)

Layouts: :mod:`bakery.irradiance.quantize` and ``schemas/store-v1.md``. Neither stores float radiance SH
(``radiance_sh_field`` is None).

References
    [ZH3]  T. Roughton, P.-P. Sloan, A. Silvennoinen, M. Iwanicki, P. Shirley, "ZH3: Quadratic Zonal Harmonics",
           Proc. ACM Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001), App. A (bounds) and A.1 (encoding).
    [WS22] T. Wiederien, P.-P. Sloan, "Tighter Spherical Harmonic Quantization Bound", I3D 2022 posters.
    Code search: :mod:`bakery.irradiance.code_search` (objective and constraint derived there).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from bakery.encodings.base import Encoding, EncodingParams, FieldSpec
from bakery.encodings.registry import register
from bakery.errors import ClampWarning, warn_about_probes
from bakery.irradiance import quantize
from bakery.irradiance.code_search import decoded_zh3_sh3, negative_part, search_zh3_codes
from bakery.irradiance.dering import clamp_zonal_l2, dering_zh3
from bakery.irradiance.sh_irradiance import evaluate_sh_irradiance, minimum_sh_irradiance
from bakery.irradiance.zh3 import (
    evaluate_zh3_irradiance,
    expand_zh3_to_sh3,
    fit_zh3_luminance,
    luminance_axis,
    solve_zonal_l2,
)
from bakery.probe import ProbeBatch

#: Relative irradiance floor of the last-resort windowing (about one SNORM8 step of the ratios).
QUANTIZED_MARGIN = 1.0 / 127.0
#: Steps each code may move from its rounded value in the code search (``search_zh3_codes``); the wider radii
#: are searched (from the previous result) only for probes the narrower search left negative.
SEARCH_RADII = (1, 2, 4)
#: Steps a DC field may move in any search: one R11G11B10F step (1/64 relative, 1/32 in blue) keeps each probe's
#: mean irradiance within the format's precision (wider DC moves trade brightness for shape: +4…9 % measured).
DC_RADIUS = 1


def _warn_clamps(name: str, stats: dict) -> None:
    """Warn (counted in the store's ``warnings``) when packing clamped the DC or ratios to the layout's range."""
    if stats["dc_clamped"] or stats["ratios_clamped"]:
        warnings.warn(
            f"{name}: {stats['dc_clamped']} probes with a DC above the R11G11B10F maximum (65024) scaled down "
            f"to fit (colour and shape kept) and "
            f"{stats['ratios_clamped']} ratios outside the App. A bounds were clamped", ClampWarning, stacklevel=3,
        )


def _window_quantized(packed: np.ndarray, companding: bool, rounds: int = 12) -> np.ndarray:
    """Last resort for probes the code search left negative: re-dering the decoded values with a relative floor
    that starts at one SNORM8 step and doubles each round, and re-pack, until the exact minimum of every decoded
    probe is ≥ 0. A floor above π·Y00 ≈ 0.886 (relative to f0) leaves only DC, which is non-negative, so this
    terminates. (The previous default path; it widens the window far beyond the bound, hence only a fallback.)"""
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


class ZH3Quantized(Encoding):
    """16-byte ZH3 ([ZH3] App. A.1): R11G11B10F DC + 12 SNORM8 ratios (layout in :mod:`bakery.irradiance.quantize`).

    Built from the deringed ZH3 (``dering``, default on; App. B clamp + exact minimum + window). The zonal
    coefficient is re-projected onto the axis the reader will compute from the *decoded* linear band and
    re-clamped with the decoded DC; then the codes are chosen by a greedy search over neighbouring codes (each
    within :data:`SEARCH_RADII` of its rounded value) for the lowest irradiance error against the capture, subject
    to a non-negative decoded probe (:func:`bakery.irradiance.code_search.search_zh3_codes`). Probes the search
    cannot make non-negative fall back to the windowing of :func:`_window_quantized`, and the search runs again
    from the windowed (non-negative) codes.
    """

    @dataclass(frozen=True)
    class Params(EncodingParams):
        sqrt_companding: bool = True
        dering: bool = True

    name = "zh3_quantized"
    kind = "irradiance"
    description = "16-byte ZH3: R11G11B10F DC + SNORM8 ratios remapped by the App. A bounds (ZH3 paper App. A.1)"
    max_band = 2

    def field_specs(self):
        return (FieldSpec("packed", (16,), "uint8", "16-byte ZH3 layout, see schemas/store-v1.md"),)

    def encode(self, batch: ProbeBatch):
        companding, dering = self.params.sqrt_companding, self.params.dering
        radiance_sh, scaled = quantize.fit_to_dc_range(batch.radiance_sh(2))  # also the search's target
        linear, zonal = fit_zh3_luminance(radiance_sh)
        if dering:
            linear, zonal, _ = dering_zh3(linear, zonal)
        band2 = expand_zh3_to_sh3(linear, zonal, luminance_axis(linear))[:, 4:9]
        first, stats = quantize.pack_zh3(linear, zonal, companding)
        _warn_clamps(self.name, {**stats, "dc_clamped": scaled})
        decoded_linear, _ = quantize.unpack_zh3(first, companding)
        decoded_axis = luminance_axis(decoded_linear)
        zonal = solve_zonal_l2(band2, decoded_axis)
        if dering:
            zonal = clamp_zonal_l2(decoded_linear, zonal, decoded_axis)
        packed, _ = quantize.pack_zh3(decoded_linear, zonal, companding)
        # [ZH3] App. A.1 codes chosen by the lowest error with E ≥ 0 after decoding (App. B), not by re-windowing.
        rounded = packed
        packed, search = search_zh3_codes(rounded, radiance_sh, companding, non_negative=dering,
                                          radius=SEARCH_RADII[0], dc_radius=DC_RADIUS)
        if dering and search["negative"]:
            still = negative_part(decoded_zh3_sh3(packed, companding)) > 0
            for radius in SEARCH_RADII[1:]:  # from the last result, every code bounded around its rounded value
                packed[still], _ = search_zh3_codes(packed[still], radiance_sh[still], companding, radius=radius,
                                                    dc_radius=DC_RADIUS, origin=rounded[still])
                still[still] = negative_part(decoded_zh3_sh3(packed[still], companding)) > 0
                if not still.any():
                    break
            if still.any():  # window to a non-negative start, then search again from there (never negative)
                windowed = _window_quantized(packed[still], companding)
                origin = windowed.copy()
                origin[:, :4] = rounded[still, :4]  # the ratios around the window's, the DC around the rounded DC
                packed[still], _ = search_zh3_codes(windowed, radiance_sh[still], companding,
                                                    radius=SEARCH_RADII[-1], dc_radius=DC_RADIUS, origin=origin)
                warn_about_probes(f"{self.name}: {int(still.sum())} probes stayed negative after the code search "
                                  "and were windowed instead", ClampWarning, np.flatnonzero(still))
        return {"packed": packed}

    def evaluate_irradiance(self, fields, normals):
        linear, zonal = quantize.unpack_zh3(fields["packed"], self.params.sqrt_companding)
        return evaluate_zh3_irradiance(linear, zonal, normals)


class SH3Quantized(Encoding):
    """28-byte SH3 ([ZH3] App. A.1, Sec. 4): R11G11B10F DC + 24 SNORM8 ratios."""

    @dataclass(frozen=True)
    class Params(EncodingParams):
        sqrt_companding: bool = True

    name = "sh3_quantized"
    kind = "irradiance"
    description = "28-byte SH3: R11G11B10F DC + SNORM8 ratios remapped by the App. A bounds"
    max_band = 2

    def field_specs(self):
        return (FieldSpec("packed", (28,), "uint8", "28-byte SH3 layout, see schemas/store-v1.md"),)

    def encode(self, batch: ProbeBatch):
        packed, stats = quantize.pack_sh3(batch.radiance_sh(2), self.params.sqrt_companding)
        _warn_clamps(self.name, stats)
        return {"packed": packed}

    def evaluate_irradiance(self, fields, normals):
        return evaluate_sh_irradiance(quantize.unpack_sh3(fields["packed"], self.params.sqrt_companding), normals)


register(ZH3Quantized, SH3Quantized)
