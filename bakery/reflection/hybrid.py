"""The hybrid reflection model (issue 12): a bandwidth split-sum chain for sharp α, SH exponentials (+ lights) for
rough α, blended in log α so that E is continuous in α (layout and HLSL in ``schemas/store-reflection.md``).

Why two crossovers
    E = F0·E0 + (1 − F0)·E1 ([SHExp] Eq. 5). Below α ≈ 0.25 an order-4 SH exponential cannot hold the lobe ([SHExp]
    Sec. 5.4; measured: 344× split-sum's MSE at α = 0.0625), so E0 comes from the chain there. The Fresnel tail E1
    is worse off: Eq. 15 approximates E1 ≈ E0·τ, which loses to split-sum's E1 = prefiltered(r)·B even with the
    exact E0 at α = 0.25–0.36 (docs/reflection.md), so E1 hands over to the SH exponential at a larger α than E0.
    The chain's E1 is the split-sum factorisation of the tail, E1 ≈ c(r, α)·B(n·v, α) — the "F0·A + B" form with
    the same coefficients an engine already has.

Blend ([SHExp] Eq. 5 with two partitions of unity)
    w(α; α_c, width) = 1 − smoothstep(0, 1, ½ + log2(α/α_c)/width)      chain weight, 1 below α_c·2^(−width/2),
                                                                        0 above α_c·2^(+width/2), C¹ in α
    E0 = w0·c·(A + B) + (1 − w0)·(PQ·(A + B) + L0),   w0 = w(α; crossover, width)
    E1 = w1·c·B       + (1 − w1)·(PQ·B + L1),         w1 = w(α; tail_crossover, width)
    c = chain(r, x(α)) (trilinear, :func:`bakery.reflection.splitsum.level_coordinate`), PQ at α clamped into the
    fitted range, (A, B) the DFG table at the material's α, L0/L1 the analytic lights' base and tail terms.
    A probe without chain levels (first_level = L: its materials are all above the tail blend) has w0 = w1 = 0.
    Below the probe's sharpest stored level α_{first_level} the chain is read at that level (clamp, never an
    unstored level). A ``gap_level`` chain's gap levels 1 … s that a probe never reads are skipped
    (:func:`gap_levels_skipped`); its chain is then read as the chain without them.

Continuity bound (tested): both parts are continuous in α and w is C¹ with |dw/dlog2 α| ≤ 1.5/width, so
    |E(α₂) − E(α₁)| ≤ |ΔE_parts| + 1.5 |log2(α₂/α₁)|/width · |E_chain − E_sh|.

Notation: P probes, M rows (v, n, α, F0), C = 3 channels, L chain levels.
"""

from __future__ import annotations

import numpy as np


def smoothstep(t: np.ndarray) -> np.ndarray:
    """3t² − 2t³ on t clamped to [0, 1]."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def chain_weight(alpha: np.ndarray, crossover: float, width: float) -> np.ndarray:
    """w(α) (module doc) (M,): 1 − smoothstep(½ + log2(α/α_c)/width); α = 0 gives 1."""
    a = np.maximum(np.asarray(alpha, dtype=np.float64), 1e-30)
    return 1.0 - smoothstep(0.5 + np.log2(a / crossover) / width)


def blend_range(crossover: float, width: float) -> tuple[float, float]:
    """[α_c·2^(−width/2), α_c·2^(width/2)]: where w falls from 1 to 0."""
    return crossover * 2.0 ** (-0.5 * width), min(1.0, crossover * 2.0 ** (0.5 * width))


def first_chain_level(level_alphas: np.ndarray, alpha_min: float, alpha_top: float) -> int:
    """The sharpest level a probe whose materials have α ≥ ``alpha_min`` needs: the largest k with α_k ≤ α_min, or
    L (no chain) when α_min ≥ ``alpha_top`` (the top of the tail blend)."""
    la = np.asarray(level_alphas, dtype=np.float64)
    if alpha_min >= alpha_top:
        return int(la.size)
    return int(np.flatnonzero(la <= alpha_min + 1e-12)[-1])


def gap_levels_skipped(level_alphas: np.ndarray, gap_levels: int, alpha_min_nonzero: float) -> int:
    """How many of the G = ``gap_levels`` gap levels (indices 1 … G of a chain with level α's (L,): 0, α_1·2^(−G),
    …, α_1/2, α_1, …) a probe never reads whose materials are mirrors (α = 0, read at x = 0 exactly) and
    α ≥ ``alpha_min_nonzero``: level k is read only for α_{k−1} < α < α_{k+1}, so levels 1 … s are never read,
    s = #{k ≤ G : α_{k+1} ≤ alpha_min_nonzero}. Without them the chain is read exactly as a chain whose gap levels
    are s + 1 … G (:func:`bakery.reflection.splitsum.level_coordinate` of the remaining α's)."""
    la = np.asarray(level_alphas, dtype=np.float64)
    return int(np.count_nonzero(la[2 : int(gap_levels) + 2] <= alpha_min_nonzero))  # α_{k+1}, k = 1 … G


def combine(chain: np.ndarray, pq: np.ndarray, lights0: np.ndarray, lights1: np.ndarray, ab: np.ndarray,
            f0: np.ndarray, w0: np.ndarray, w1: np.ndarray) -> np.ndarray:
    """E (P, M, C) from the chain radiance c (P, M, C), P·Q (P, M, C), the lights' E0/E1 (P, M, C), the DFG (A, B)
    (M, 2), F0 (M, C) and the chain weights w0, w1 (P, M) (module doc "Blend")."""
    a, b = ab[None, :, 0:1], ab[None, :, 1:2]
    w0, w1 = w0[..., None], w1[..., None]
    e0 = w0 * chain * (a + b) + (1.0 - w0) * (pq * (a + b) + lights0)
    e1 = w1 * chain * b + (1.0 - w1) * (pq * b + lights1)
    return f0[None] * e0 + (1.0 - f0[None]) * e1
