"""Quantized SH: HDR DC + bound-remapped 8-bit ratios ([ZH3] App. A, A.1).

References
    [ZH3]  Roughton et al. 2024, App. A (coefficient bounds for positive functions) and A.1 (encoding).
    [WS22] T. Wiederien, P.-P. Sloan, "Tighter Spherical Harmonic Quantization Bound", I3D 2022 posters.

Bounds (radiance SH of a non-negative function, ratio x = f_lm / f0)
    band 1, every m:       |x| ≤ √3
    band 2, m = 0:         −√5/2 ≤ x ≤ √5
    band 2, m ≠ 0:         |x| ≤ √15/2
    (A delta function attains them; [ZH3] App. A.) A zonal f2^0 in any frame obeys the m = 0 bound.

Byte layouts (little-endian; all ratios coefficient-major, RGB inside each coefficient)
    DC       uint32 R11G11B10F: R = bits 0–10, G = bits 11–21, B = bits 22–31 (DXGI_FORMAT_R11G11B10_FLOAT: unsigned,
             5-bit exponent with bias 15, 6/6/5-bit mantissa, round to nearest even; values above the format's
             maximum 65024 (R, G) / 64512 (B) clamp to it and are counted and warned).
    ratio    int8 SNORM: s = q / 127 ∈ [−1, 1]. Remap t = x / hi for x ≥ 0 and x / |lo| for x < 0 (zero stays exact),
             optionally companded s = sign(t)·√|t| (App. A.1: "square root to encode the magnitude"), then
             q = round(127·s). Decoding inverts: t = s (or sign(s)·s²), x = t·hi or t·|lo|. The encoder never
             writes q = −128; a reader decodes it as −127 (s = max(q/127, −1), the GPU SNORM8 rule:
             D3D/Vulkan map both −128 and −127 to −1.0).
    DC codes with exponent 31 (float16's Inf/NaN) are never written (the encoder clamps to the largest finite
             value); :func:`decode_r11g11b10` refuses them (StoreFormatError): a corrupt store.
    ZH3 16 B  [0:4] DC, [4:7] f1,−1 RGB, [7:10] f1,0 RGB, [10:13] f1,1 RGB, [13:16] f2^0 RGB (luminance-axis frame).
    SH3 28 B  [0:4] DC, then coefficients k = 1..8 (f1,−1 … f2,2), 3 bytes (RGB) each.

Error bound (per ratio, ulp u = 1/127): linear |Δx| ≤ side·u/2; sqrt |Δx| ≤ side·(|s|·u + u²/4) ≤ side·(u + u²/4),
side = hi or |lo| for the sign of x. DC relative error ≤ 2⁻⁷ (R, G) or 2⁻⁶ (B) for normal values.
"""

from __future__ import annotations

from math import sqrt

import numpy as np

from bakery.errors import StoreFormatError

SQRT3 = sqrt(3.0)
#: (lower, upper) ratio bounds per SH index 1..8 ([ZH3] App. A).
RATIO_BOUNDS = np.array(
    [[-SQRT3, SQRT3]] * 3
    + [[-sqrt(15.0) / 2, sqrt(15.0) / 2]] * 2
    + [[-sqrt(5.0) / 2, sqrt(5.0)]]
    + [[-sqrt(15.0) / 2, sqrt(15.0) / 2]] * 2
)
ZONAL_BOUNDS = np.array([-sqrt(5.0) / 2, sqrt(5.0)])

_MANTISSA_BITS = (6, 6, 5)
_SHIFT = (0, 11, 22)


def _float_to_small(values: np.ndarray, mantissa_bits: int) -> tuple[np.ndarray, int]:
    """Unsigned small float (5-bit exponent, bias 15, ``mantissa_bits`` mantissa bits) with one correct rounding to
    nearest-even from float64; returns the codes and how many values exceeded the format's maximum (clamped)."""
    v = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=np.inf)
    v = np.maximum(v, 0.0)
    scale = float(1 << mantissa_bits)
    max_code = (30 << mantissa_bits) | ((1 << mantissa_bits) - 1)
    max_value = _small_to_float(np.array([max_code]), mantissa_bits)[0]
    overflow = v > max_value
    finite = np.where(overflow, 0.0, v)
    _, exponent = np.frexp(finite)  # finite = m·2^exponent, m ∈ [0.5, 1)
    biased = np.maximum(exponent - 1 + 15, 1)  # denormals share the smallest normal exponent's step
    step = np.ldexp(1.0, (biased - 15) - mantissa_bits)  # value of one mantissa unit
    units = np.rint(finite / step).astype(np.int64)  # rint: round half to even
    # units counts steps from 0: normal codes are (biased << m) + (units − 2^m); a carry to 2^(m+1) moves into the
    # next exponent naturally; denormals (biased = 1 and units < 2^m) are code = units.
    code = np.where(units >= scale, ((biased - 1) << mantissa_bits) + units, units)
    code = np.where(overflow, max_code, np.minimum(code, max_code))
    return code.astype(np.uint32), int(overflow.sum())


def _small_to_float(code: np.ndarray, mantissa_bits: int) -> np.ndarray:
    drop = 10 - mantissa_bits
    return (np.asarray(code, dtype=np.uint32) << drop).astype(np.uint16).view(np.float16).astype(np.float64)


def encode_r11g11b10(rgb: np.ndarray) -> tuple[np.ndarray, int]:
    """Pack non-negative RGB (P, 3) into uint32 (P,) R11G11B10F; returns the codes and how many values clamped."""
    packed = np.zeros(rgb.shape[0], dtype=np.uint32)
    clamped = 0
    for channel in range(3):
        code, n = _float_to_small(rgb[:, channel], _MANTISSA_BITS[channel])
        packed |= code << np.uint32(_SHIFT[channel])
        clamped += n
    return packed, clamped


def decode_r11g11b10(packed: np.ndarray) -> np.ndarray:
    """Unpack uint32 (P,) R11G11B10F into float64 RGB (P, 3).

    Raises StoreFormatError for a field with exponent 31 (Inf/NaN in the format): no bakery writer produces one
    (schemas/store-v1.md), so the store is corrupt."""
    packed = np.asarray(packed, dtype=np.uint32)
    channels = []
    for channel in range(3):
        width = 5 + _MANTISSA_BITS[channel]
        code = (packed >> np.uint32(_SHIFT[channel])) & np.uint32((1 << width) - 1)
        if np.any((code >> np.uint32(_MANTISSA_BITS[channel])) == 31):
            raise StoreFormatError(f"R11G11B10F DC with exponent 31 (Inf/NaN) in channel {'RGB'[channel]}: "
                                   "bakery never writes one; the store is corrupt")
        channels.append(_small_to_float(code, _MANTISSA_BITS[channel]))
    return np.stack(channels, axis=-1)


def encode_ratio(ratio: np.ndarray, lower: np.ndarray, upper: np.ndarray, sqrt_companding: bool) -> np.ndarray:
    """Ratios x (...) with bounds (broadcastable) → int8 SNORM codes (module doc)."""
    side = np.where(ratio >= 0, upper, -lower)
    t = np.clip(ratio / side, -1.0, 1.0)
    if sqrt_companding:
        t = np.sign(t) * np.sqrt(np.abs(t))
    return np.round(t * 127.0).astype(np.int8)


def decode_ratio(code: np.ndarray, lower: np.ndarray, upper: np.ndarray, sqrt_companding: bool) -> np.ndarray:
    """Inverse of :func:`encode_ratio` → ratios (...) float64; the code −128 (never written) decodes as −127."""
    s = np.maximum(np.asarray(code, dtype=np.float64) / 127.0, -1.0)
    t = np.sign(s) * s * s if sqrt_companding else s
    return t * np.where(t >= 0, upper, -lower)


def ratio_error_bound(lower: np.ndarray, upper: np.ndarray, sqrt_companding: bool) -> np.ndarray:
    """Largest |decoded − x| over x within bounds, per side: (..., 2) for (negative side, positive side)."""
    u = 1.0 / 127.0
    per_unit = (u + u * u / 4.0) if sqrt_companding else u / 2.0
    return np.stack([np.abs(lower) * per_unit, np.abs(upper) * per_unit], axis=-1)


#: Largest finite R, G, B values of R11G11B10F (exponent 30, all mantissa bits set): 65024, 65024, 64512.
_DC_LARGEST = np.array([_small_to_float(np.array([(30 << m) | ((1 << m) - 1)]), m)[0] for m in _MANTISSA_BITS])


def fit_to_dc_range(radiance_sh: np.ndarray) -> tuple[np.ndarray, int]:
    """Radiance SH (P, K, 3) with every probe whose DC exceeds the format's largest value in some channel (65024 in
    R and G, 64512 in B) scaled as a whole, every coefficient of every channel by the same factor, until it fits;
    and how many probes were scaled. Their colour and shape are kept, only their brightness is capped (clamping the
    DC alone and dividing by it inflated the ratios: E(up)/E(down) of a 2:1 sky became 3.35)."""
    f0 = np.maximum(radiance_sh[:, 0], 0.0)
    largest = _DC_LARGEST
    over = f0 > largest
    fit = np.min(np.where(over, largest / np.where(over, f0, 1.0), 1.0), axis=-1)  # (P,); no division by ~0
    if np.all(fit == 1.0):
        return radiance_sh, 0
    return radiance_sh * fit[:, None, None], int(np.count_nonzero(fit < 1.0))


def _dc_and_ratios(radiance_sh: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """DC codes (P,), decoded DC (P, C), how many probes were scaled to fit (:func:`fit_to_dc_range`), ratios
    (P, K−1, C) relative to the decoded DC."""
    radiance_sh, clamped = fit_to_dc_range(radiance_sh)
    f0 = np.maximum(radiance_sh[:, 0], 0.0)
    dc_code, _ = encode_r11g11b10(f0)
    f0_decoded = decode_r11g11b10(dc_code)
    safe = np.where(f0_decoded > 0, f0_decoded, 1.0)
    ratios = np.where(f0_decoded[:, None, :] > 0, radiance_sh[:, 1:] / safe[:, None, :], 0.0)
    return dc_code, f0_decoded, clamped, ratios


def pack_zh3(linear_sh: np.ndarray, zonal_l2: np.ndarray, sqrt_companding: bool) -> tuple[np.ndarray, dict]:
    """16-byte ZH3 (P, 16) uint8 from linear SH (P, 4, 3) and f2^0 (P, 3) (layout in module doc)."""
    coefficients = np.concatenate([linear_sh[:, :4], zonal_l2[:, None, :]], axis=1)  # (P, 5, 3)
    dc_code, _, clamped, ratios = _dc_and_ratios(coefficients)
    lower = np.concatenate([RATIO_BOUNDS[:3, 0], ZONAL_BOUNDS[:1]])[None, :, None]
    upper = np.concatenate([RATIO_BOUNDS[:3, 1], ZONAL_BOUNDS[1:]])[None, :, None]
    out_of_bounds = int(np.sum((ratios < lower - 1e-6) | (ratios > upper + 1e-6)))
    codes = encode_ratio(ratios, lower, upper, sqrt_companding)  # (P, 4, 3)
    packed = np.concatenate([dc_code.view(np.uint8).reshape(-1, 4), codes.view(np.uint8).reshape(-1, 12)], axis=1)
    return packed, {"dc_clamped": clamped, "ratios_clamped": out_of_bounds}


def unpack_zh3(packed: np.ndarray, sqrt_companding: bool) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack_zh3`: linear SH (P, 4, 3) and f2^0 (P, 3)."""
    packed = np.ascontiguousarray(packed, dtype=np.uint8)
    f0 = decode_r11g11b10(packed[:, :4].copy().view("<u4")[:, 0])
    codes = packed[:, 4:16].copy().view(np.int8).reshape(-1, 4, 3)
    lower = np.concatenate([RATIO_BOUNDS[:3, 0], ZONAL_BOUNDS[:1]])[None, :, None]
    upper = np.concatenate([RATIO_BOUNDS[:3, 1], ZONAL_BOUNDS[1:]])[None, :, None]
    coefficients = decode_ratio(codes, lower, upper, sqrt_companding) * f0[:, None, :]
    linear = np.concatenate([f0[:, None, :], coefficients[:, :3]], axis=1)
    return linear, coefficients[:, 3]


def pack_sh3(radiance_sh: np.ndarray, sqrt_companding: bool) -> tuple[np.ndarray, dict]:
    """28-byte SH3 (P, 28) uint8 from radiance SH3 (P, 9, 3) (layout in module doc)."""
    dc_code, _, clamped, ratios = _dc_and_ratios(radiance_sh[:, :9])
    lower, upper = RATIO_BOUNDS[None, :, 0, None], RATIO_BOUNDS[None, :, 1, None]
    out_of_bounds = int(np.sum((ratios < lower - 1e-6) | (ratios > upper + 1e-6)))
    codes = encode_ratio(ratios, lower, upper, sqrt_companding)  # (P, 8, 3)
    packed = np.concatenate([dc_code.view(np.uint8).reshape(-1, 4), codes.view(np.uint8).reshape(-1, 24)], axis=1)
    return packed, {"dc_clamped": clamped, "ratios_clamped": out_of_bounds}


def unpack_sh3(packed: np.ndarray, sqrt_companding: bool) -> np.ndarray:
    """Inverse of :func:`pack_sh3`: radiance SH3 (P, 9, 3)."""
    packed = np.ascontiguousarray(packed, dtype=np.uint8)
    f0 = decode_r11g11b10(packed[:, :4].copy().view("<u4")[:, 0])
    codes = packed[:, 4:28].copy().view(np.int8).reshape(-1, 8, 3)
    ratios = decode_ratio(codes, RATIO_BOUNDS[None, :, 0, None], RATIO_BOUNDS[None, :, 1, None], sqrt_companding)
    return np.concatenate([f0[:, None, :], ratios * f0[:, None, :]], axis=1)
