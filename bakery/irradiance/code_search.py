"""Choosing the 16 bytes of quantized ZH3 by a search over neighbouring codes ([ZH3] App. A.1 layout).

Rounding every coefficient to its nearest code and then re-deringing the *decoded* probe until it is
non-negative widens the window far beyond what the App. B bound needs (a decoded probe that is slightly negative
after rounding gets a window for the whole probe). Instead, the codes are chosen directly: starting from the
rounded codes of the deringed float ZH3, a greedy descent over single-code moves (one SNORM8 ratio or one
R11G11B10F DC field ±1) keeps the move with the lowest error that leaves the decoded probe non-negative, until no
move improves; every code stays within ``radius`` steps of its rounded value.

Objective (exact w.r.t. the capture's full irradiance)
    The decoded ZH3 is a band-≤2 SH s (P, 9, C) (:func:`~bakery.irradiance.zh3.expand_zh3_to_sh3` along the axis
    the reader computes from the decoded linear band). Its irradiance error against the full irradiance is
    ‖Σ A_l (s_lm − r_lm) Y_lm‖² + ‖E_>2‖² (Parseval; bands > 2 are orthogonal and do not depend on the codes), so
    the search minimises e = Σ_lm Σ_c A_l² (s_lm − r_lm)² with r the capture's radiance SH3.
Constraint (exact)
    min over the sphere of the decoded irradiance ≥ 0 per channel, by the exact trust-region minimum
    (:func:`~bakery.irradiance.sh_irradiance.minimum_on_sphere`). A move is tested exactly only when the cheap
    lower bound c − ‖b‖ − ‖M‖_F of E(n) = c + bᵀn + nᵀMn (|n| = 1, nᵀMn ≥ −‖M‖₂ ≥ −‖M‖_F) is negative.
    While a probe is negative (its rounded start already was), moves are ranked by the total negative part
    relative to each channel's mean irradiance, Σ_c max(0, −min_c) / Ē_c, first and by e second; a non-negative
    probe never accepts a negative move.
"""

from __future__ import annotations

from math import pi

import numpy as np

from bakery.irradiance import quantize
from bakery.irradiance.sh_irradiance import irradiance_quadratic_form, minimum_on_sphere
from bakery.irradiance.zh3 import expand_zh3_to_sh3, luminance_axis

_Y00 = 0.5 / np.sqrt(pi)
_IRRADIANCE_SCALE = np.array([pi] + [2.0 * pi / 3.0] * 3 + [pi / 4.0] * 5)[None, :, None]
#: (shift, width) of the R, G, B fields of the R11G11B10F DC word.
_DC_FIELDS = ((0, 11), (11, 11), (22, 10))


def _dc_max_code(width: int) -> int:
    """Largest finite code of an unsigned small float field (exponent 30, all mantissa bits set)."""
    mantissa = width - 5
    return (30 << mantissa) | ((1 << mantissa) - 1)


def dc_fields(packed: np.ndarray) -> np.ndarray:
    """R, G, B codes (..., 3) int64 of the DC words of packed layouts (..., ≥4) uint8."""
    word = np.ascontiguousarray(packed[..., :4]).view("<u4")[..., 0].astype(np.int64)
    return np.stack([(word >> shift) & ((1 << width) - 1) for shift, width in _DC_FIELDS], axis=-1)


def zh3_neighbours(packed: np.ndarray) -> np.ndarray:
    """All single-code moves of 16-byte ZH3 layouts (P, 16) → (P, 30, 16): the 12 SNORM8 codes ±1 (within
    [−127, 127]) and the three DC fields ±1 (within [0, largest finite code]); a clipped move repeats its start."""
    packed = np.ascontiguousarray(packed, dtype=np.uint8)
    p = packed.shape[0]
    moves = np.repeat(packed[:, None, :], 30, axis=1)
    codes = packed[:, 4:16].view(np.int8).astype(np.int16)  # (P, 12)
    step = np.array([1, -1], dtype=np.int16)
    moved = np.clip(codes[:, :, None] + step[None, None, :], -127, 127).astype(np.int8)  # (P, 12, 2)
    for j in range(12):  # the 12 code positions, each a batched move over every probe
        moves[:, 2 * j : 2 * j + 2, 4 + j] = moved[:, j].view(np.uint8)
    word = np.ascontiguousarray(packed[:, :4]).view("<u4")[:, 0].astype(np.int64)
    fields = dc_fields(packed)
    for k, (shift, width) in enumerate(_DC_FIELDS):
        for i, s in enumerate((1, -1)):
            code = np.clip(fields[:, k] + s, 0, _dc_max_code(width))
            new_word = (word & ~(((1 << width) - 1) << shift)) | (code << shift)
            moves[:, 24 + 2 * k + i, :4] = new_word.astype("<u4").view(np.uint8).reshape(p, 4)
    return moves


def decoded_zh3_sh3(packed: np.ndarray, sqrt_companding: bool) -> np.ndarray:
    """Radiance SH3 (P, 9, 3) a reader reconstructs from 16-byte layouts (P, 16) (axis from the decoded band)."""
    linear, zonal = quantize.unpack_zh3(packed, sqrt_companding)
    return expand_zh3_to_sh3(linear, zonal, luminance_axis(linear))


def _error(sh3: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Irradiance SH squared error (P,) of radiance SH3 (P, 9, C) against the target (P, 9, C)."""
    return np.sum(((sh3 - target) * _IRRADIANCE_SCALE) ** 2, axis=(1, 2))


def negative_part(sh3: np.ndarray, exact_only_below_bound: bool = True) -> np.ndarray:
    """Σ_c max(0, −min_n E_c(n)) / Ē_c (P,) of radiance SH3 (P, 9, C), Ē_c = π·Y00·f0_c the channel's mean
    irradiance: 0 iff the irradiance is non-negative everywhere.

    Relative to the mean because scaling a channel (its DC code, with the ratios that multiply it) scales its
    minimum too: an absolute measure made the search of a probe it could not make non-negative walk every DC field
    down its whole radius, 6–15 % of the probe's irradiance, without changing a sign. The exact minimum is
    computed only where the lower bound c − ‖b‖ − ‖M‖_F is negative (module doc)."""
    c, b, m = irradiance_quadratic_form(sh3)  # (P, C), (P, C, 3), (P, C, 3, 3)
    bound = c - np.linalg.norm(b, axis=-1) - np.linalg.norm(m, axis=(-2, -1))
    minimum = bound.copy()
    check = bound < 0 if exact_only_below_bound else np.ones_like(bound, dtype=bool)
    if check.any():
        # 56 bisection halvings shrink the multiplier's bracket (width ‖β‖/2) below double precision already.
        minimum[check] = minimum_on_sphere(c[check], b[check], m[check], iterations=56)
    mean = np.maximum(pi * _Y00 * sh3[:, 0], np.finfo(np.float64).tiny)  # (P, C)
    return np.sum(np.maximum(-minimum, 0.0) / mean, axis=-1)


def _pick_non_negative(
    move_error: np.ndarray, move_sh3: np.ndarray, error: np.ndarray, negative: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per probe the move to take (A,) and its negative part (A,), from move errors (A, M) (inf = outside the
    radius), decoded moves (A, M, 9, C), and the current error and negative part (A,).

    A non-negative probe takes its lowest-error non-negative move: moves are tested in order of error, one batch per
    rank, so only as many exact minima are computed as it takes to find one (a move that does not lower the error
    is never needed). A negative probe ranks every move by (negative part, error)."""
    a, m = move_error.shape
    pick = np.argmin(move_error, axis=1)
    pick_negative = np.full(a, np.inf)
    feasible = negative <= 0
    # Negative probes: every move within the radius, lexicographic (negative part, error).
    bad = np.flatnonzero(~feasible)
    if bad.size:
        values = np.full((bad.size, m), np.inf)
        inside = np.isfinite(move_error[bad])
        values[inside] = negative_part(move_sh3[bad][inside])
        least = values.min(axis=1)
        pick[bad] = np.argmin(np.where(values <= least[:, None], move_error[bad], np.inf), axis=1)
        pick_negative[bad] = values[np.arange(bad.size), pick[bad]]
    # Non-negative probes: improving moves in order of error until one is non-negative.
    good = np.flatnonzero(feasible)
    order = np.argsort(move_error[good], axis=1, kind="stable")
    undecided = np.ones(good.size, dtype=bool)
    for rank in range(m):
        candidate = order[:, rank]
        improving = move_error[good, candidate] < error[good]
        undecided &= improving  # a probe whose next move does not improve keeps its codes (pick stays infinite)
        rows = np.flatnonzero(undecided)
        if rows.size == 0:
            break
        values = negative_part(move_sh3[good[rows], candidate[rows]])
        found = values <= 0
        pick[good[rows[found]]] = candidate[rows[found]]
        pick_negative[good[rows[found]]] = 0.0
        undecided[rows[found]] = False
    return pick, pick_negative


def search_zh3_codes(
    packed: np.ndarray, radiance_sh: np.ndarray, sqrt_companding: bool, non_negative: bool = True,
    radius: int = 1, max_rounds: int = 32, dc_radius: int | None = None, origin: np.ndarray | None = None,
) -> tuple[np.ndarray, dict]:
    """Greedy search over neighbouring codes (module doc) of 16-byte ZH3 layouts (P, 16) for the lowest irradiance
    error against the capture's radiance SH3 ``radiance_sh`` (P, 9, 3), subject (``non_negative``) to a
    non-negative decoded probe. Every code stays within ``radius`` steps of its value in ``origin`` (P, 16)
    (default ``packed``: a search started from an earlier search's result is still bounded around the rounded
    codes when given them), the DC fields within ``dc_radius`` (default ``radius``).

    Returns:
        the chosen layouts (P, 16) uint8 and {"rounds": rounds run, "moved": probes whose codes changed,
        "negative": probes still negative somewhere (only if their start was and no move within the radius
        fixed it)}.
    """
    start = np.ascontiguousarray(packed, dtype=np.uint8).copy()
    target = np.asarray(radiance_sh[:, :9], dtype=np.float64)
    p = start.shape[0]
    anchor = start if origin is None else np.ascontiguousarray(origin, dtype=np.uint8)
    start_codes = anchor[:, 4:16].view(np.int8).astype(np.int16)
    start_dc = dc_fields(anchor)
    current = start.copy()
    sh3 = decoded_zh3_sh3(current, sqrt_companding)
    error = _error(sh3, target)
    negative = negative_part(sh3) if non_negative else np.zeros(p)
    active = np.ones(p, dtype=bool)
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        moves = zh3_neighbours(current[rows])  # (A, M, 16)
        a, m, _ = moves.shape
        within = np.all(np.abs(moves[:, :, 4:16].view(np.int8).astype(np.int16) - start_codes[rows, None]) <= radius,
                        axis=-1)
        dc_steps = radius if dc_radius is None else dc_radius
        within &= np.all(np.abs(dc_fields(moves) - start_dc[rows, None]) <= dc_steps, axis=-1)
        flat_sh3 = decoded_zh3_sh3(moves.reshape(-1, 16), sqrt_companding)
        move_error = _error(flat_sh3, np.repeat(target[rows], m, axis=0)).reshape(a, m)
        move_error = np.where(within, move_error, np.inf)
        pick = np.argmin(move_error, axis=1)
        pick_negative = np.zeros(a)
        if non_negative:
            pick, pick_negative = _pick_non_negative(move_error, flat_sh3.reshape(a, m, 9, -1), error[rows],
                                                     negative[rows])
        pick_error = move_error[np.arange(a), pick]
        better = (pick_negative < negative[rows]) | ((pick_negative == negative[rows]) & (pick_error < error[rows]))
        better &= np.isfinite(pick_error)
        chosen = rows[better]
        current[chosen] = moves[np.arange(a), pick][better]
        error[chosen] = pick_error[better]
        negative[chosen] = pick_negative[better]
        active[rows[~better]] = False
    moved = int(np.sum(np.any(current != start, axis=1)))
    return current, {"rounds": rounds, "moved": moved, "negative": int(np.sum(negative > 0))}
