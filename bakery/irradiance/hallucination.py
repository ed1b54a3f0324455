"""Solved hallucination: linear SH chosen so that the paper's hallucinated ZH3 ([ZH3] Eq. 21, Listing 1) best
matches the probe's full irradiance.

References
    [ZH3]  T. Roughton, P.-P. Sloan, A. Silvennoinen, M. Iwanicki, P. Shirley, "ZH3: Quadratic Zonal Harmonics",
           Proc. ACM Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001): Sec. 3.3 (solving the linear band with
           BFGS), Sec. 3.4.3–3.4.4 (Eq. 21 on the luminance axis), Listing 1 (the shader), App. C (gradients).
    [ZH3S] The authors' reference solver, kayru/Probulator ``Source/External/zh3solver`` (MIT),
           ``ZH3HallucinateSharedLuminanceSolver``: the same idea, four tetrahedral starts, L-BFGS. Re-derived here
           (no code taken): bakery's objective is the irradiance error of every channel with equal weight (the
           bench's metric) and keeps the reader's luminance axis (Rec.709 weights, Listing 1) and its abs().

The reader is unchanged: Listing 1 applied to the stored (f0, f1) (:func:`bakery.irradiance.zh3.
hallucinate_zonal_l2`). Only the stored linear band differs from the projected one.

Objective (derivation)
    The hallucinated irradiance is a band-≤2 polynomial, E_h = Σ_{l≤2} A_l h_lm Y_lm with h_0 = f0, h_1 = f1 and
    h_2 = z √(4π/5) Y2(a) per channel ([ZH3] Eq. 2: a zonal coefficient z along a as SH). The probe's full
    irradiance is E = E_≤2 + E_>2 with E_≤2 = Σ A_l r_lm Y_lm (r = the capture's radiance SH, Funk–Hecke) and E_>2
    orthogonal to every band ≤ 2. So ‖E_h − E‖² = ‖E_h − E_≤2‖² + ‖E_>2‖², and the last term does not depend on
    the stored values: minimising the irradiance SH error below is *exactly* minimising the L2 error against the
    full irradiance of the capture. With ‖√(4π/5) Y2(a)‖² = 1 (q·q = 5/4π, [ZH3] Eq. 8):

        E(f1) = Σ_c A1² ‖v_c − ρ_c‖² + A2² [(z_c − s_c)² + ‖r2_c‖² − s_c²]        (f0 = r0 fixed, as Eq. 11)
        v_c = linear band vector of f1 (:func:`~bakery.irradiance.zh3.linear_band_vector`), ρ_c the capture's,
        a = normalize(Σ_c w_c v_c) (luminance axis, Eq. 29–32), d_c = v_c·a, z_c = c2 d_c²/f0_c + c1 |d_c|
        (Eq. 21: (c2 p² + c1 p) f0 with p = |d_c|/f0), s_c = √(4π/5) Y2(a)·r2_c (Eq. 10: the best zonal value).

    Gradient (chain rule, as App. C for Eq. 11):
        ∂E/∂z_c = 2A2²(z_c − s_c);  ∂z_c/∂d_c = 2c2 d_c/f0_c + c1 sign(d_c)
        ∂E/∂a = Σ_c ∂E/∂z_c ∂z_c/∂d_c v_c − 2A2² Σ_c z_c √(4π/5) J_Y2(a)ᵀ r2_c     (J_Y2: [ZH3] Eq. 28)
        ∂E/∂u = (I − a aᵀ)/‖u‖ ∂E/∂a  (Eq. 36),  u = Σ_c w_c v_c
        ∂E/∂v_c = 2A1²(v_c − ρ_c) + ∂E/∂z_c ∂z_c/∂d_c a + w_c ∂E/∂u.

Why the projected band is not always kept, and why SH2 can still win
    Listing 1 always adds a zonal term z_c ≥ 0 along the luminance axis. Moving the stored L1 trades L1 error for
    a better zonal term, which the solve does. But Σ_c w_c d_c = ‖u‖ > 0, so no stored band switches the zonal
    term off: where the capture's L2 band is not a positive zonal lobe about the light (interiors lit by a ring
    of lamps), *every* 48-byte input to Listing 1 is worse than plain SH2 (``docs/irradiance.md``: 2048 random
    starts per map on ``lobby`` and ``night``, ``bakery bench irradiance``). For those probes the encoding stores
    the projected band with its per-probe flag ``hallucinate`` = 0, which drops the zonal term at evaluation
    (plain SH2; :func:`hallucination_beats_sh2` decides, exactly against the capture by the same Parseval
    argument: SH2's error is the objective with z_c = 0, :func:`plain_sh2_sh_error`).
"""

from __future__ import annotations

from math import pi, sqrt

import numpy as np

from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.irradiance.sh_irradiance import minimum_sh_irradiance
from bakery.irradiance.zh3 import (
    FALLBACK_AXIS,
    PAPER_HALLUCINATION_CURVE,
    _vector_to_linear,
    band2_at,
    band2_jacobian,
    batched_bfgs,
    expand_zh3_to_sh3,
    hallucinate_zonal_l2,
    linear_band_vector,
    luminance_axis,
    tetrahedral_starts,
)

_A1 = 2.0 * pi / 3.0
_A2 = pi / 4.0
_K2 = sqrt(4.0 * pi / 5.0)
_IRRADIANCE_SCALE = np.array([pi] + [_A1] * 3 + [_A2] * 5)


def _hallucination_error(
    vector: np.ndarray, radiance_sh: np.ndarray, curve: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Irradiance SH error (P,) of Listing 1 with linear band vectors ``vector`` (P, 3, C) and DC r0 against the
    capture's radiance SH3 ``radiance_sh`` (P, 9, C), and its gradient (P, 3, C) (module derivation)."""
    c2, c1 = curve
    f0 = radiance_sh[:, 0]
    rho = linear_band_vector(radiance_sh)
    r2 = radiance_sh[:, 4:9]
    u = np.einsum("pjc,c->pj", vector, LUMINANCE_WEIGHTS)
    norm_u = np.linalg.norm(u, axis=-1)
    degenerate = ~(norm_u > 1e-30)  # the reader's fallback axis; no axis gradient there
    safe_norm = np.where(degenerate, 1.0, norm_u)
    a = np.where(degenerate[:, None], FALLBACK_AXIS[None, :], u / safe_norm[:, None])
    s = _K2 * np.einsum("pk,pkc->pc", band2_at(a), r2)
    d = np.einsum("pj,pjc->pc", a, vector)
    positive = f0 > 0  # p = 0 where f0 <= 0 (schemas/store-v1.md)
    safe_f0 = np.where(positive, f0, 1.0)
    z = np.where(positive, c2 * d * d / safe_f0 + c1 * np.abs(d), 0.0)
    error = (_A1**2 * np.sum((vector - rho) ** 2, axis=(1, 2))
             + _A2**2 * np.sum((z - s) ** 2 + np.sum(r2**2, axis=1) - s**2, axis=1))
    de_dz = 2.0 * _A2**2 * (z - s)
    de_dd = de_dz * np.where(positive, 2.0 * c2 * d / safe_f0 + c1 * np.sign(d), 0.0)
    de_da = (np.einsum("pc,pjc->pj", de_dd, vector)
             - 2.0 * _A2**2 * _K2 * np.einsum("pc,pkj,pkc->pj", z, band2_jacobian(a), r2))
    de_du = np.where(degenerate[:, None], 0.0,
                     (de_da - a * np.sum(a * de_da, axis=-1, keepdims=True)) / safe_norm[:, None])
    grad = (2.0 * _A1**2 * (vector - rho) + a[:, :, None] * de_dd[:, None, :]
            + de_du[:, :, None] * LUMINANCE_WEIGHTS[None, None, :])
    return error, grad


def hallucination_sh_error(
    linear_sh: np.ndarray, radiance_sh: np.ndarray, curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE
) -> np.ndarray:
    """‖E_h − E_≤2‖² (P,): irradiance SH error of Listing 1 on ``linear_sh`` (P, 4, C) (its DC replaced by the
    capture's) against the capture's radiance SH3 (P, 9, C); equals the squared L2 error against the full
    irradiance minus a constant per probe (module derivation)."""
    sh = np.array(radiance_sh[:, :9], dtype=np.float64)
    error, _ = _hallucination_error(linear_band_vector(np.asarray(linear_sh, dtype=np.float64)), sh, curve)
    return error


def plain_sh2_sh_error(linear_sh: np.ndarray, radiance_sh: np.ndarray) -> np.ndarray:
    """‖E_sh2 − E_≤2‖² (P,): irradiance SH error of ``linear_sh`` (P, 4, C) evaluated *without* the zonal term
    (plain ``sh2``; DC replaced by the capture's) against the capture's radiance SH3 (P, 9, C), on the scale of
    :func:`hallucination_sh_error`: Σ_c A1²‖v_c − ρ_c‖² + A2²‖r2_c‖² (Parseval, module derivation with z_c = 0)."""
    sh = np.array(radiance_sh[:, :9], dtype=np.float64)
    vector = linear_band_vector(np.asarray(linear_sh, dtype=np.float64))
    return (_A1**2 * np.sum((vector - linear_band_vector(sh)) ** 2, axis=(1, 2))
            + _A2**2 * np.sum(sh[:, 4:9] ** 2, axis=(1, 2)))


def hallucination_beats_sh2(
    linear_sh: np.ndarray, radiance_sh: np.ndarray, curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE,
    min_gain: float = 0.01,
) -> np.ndarray:
    """(P,) bool: Listing 1 on ``linear_sh`` (P, 4, C) has a band-≤2 irradiance error against the capture at least
    ``min_gain`` (relative) below plain ``sh2`` on the capture's projected band — the per-probe choice of
    ``zh3_hallucinated_solved``'s ``hallucinate`` flag. Both are the L2 error against the capture's full
    irradiance minus the same constant ‖E_>2‖² (Parseval), so the order is exact; ``min_gain`` keeps near-ties
    (which the capture's resampling can flip against the true environment) on the plain reconstruction."""
    sh = np.array(radiance_sh[:, :9], dtype=np.float64)
    hallucinated = hallucination_sh_error(linear_sh, sh, curve)
    plain = plain_sh2_sh_error(sh[:, :4], sh)
    return np.isfinite(hallucinated) & (hallucinated < (1.0 - min_gain) * plain)


#: Steps t of the negative guard's backtracking from the solution (t = 1) towards the projected band (t = 0).
GUARD_STEPS = np.linspace(1.0, 0.0, 17)


def hallucinated_minimum(linear_sh: np.ndarray, curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE) -> np.ndarray:
    """Exact minimum over the sphere (P, C) of the Listing-1 irradiance of linear SH (P, 4, C) (the zonal term as
    band-2 SH, :func:`~bakery.irradiance.zh3.expand_zh3_to_sh3`; trust-region minimum of
    :func:`~bakery.irradiance.sh_irradiance.minimum_sh_irradiance`)."""
    axis = luminance_axis(linear_sh)
    return minimum_sh_irradiance(expand_zh3_to_sh3(linear_sh, hallucinate_zonal_l2(linear_sh, curve), axis))


def _guard_negative(solved: np.ndarray, projected: np.ndarray, curve: tuple[float, float]) -> np.ndarray:
    """Move each solved band (P, 4, C) back along the segment towards the projected band (t ∈ :data:`GUARD_STEPS`,
    the largest t that passes) until no channel's minimum irradiance is below min(0, its minimum with the projected
    band): the solve then never adds negative lobes the paper's hallucination does not have (t = 0 always passes)."""
    floor = np.minimum(hallucinated_minimum(projected, curve), 0.0)  # (P, C)
    allowance = 1e-12 * np.abs(projected[:, 0]).max(axis=-1)[:, None]  # rounding, relative to the DC
    out = solved.copy()
    # Most solutions pass at t = 1; only the others are backtracked over the whole grid.
    failing = np.flatnonzero(~np.all(hallucinated_minimum(solved, curve) >= floor - allowance, axis=-1))
    if failing.size:
        start, end = projected[failing], solved[failing]
        steps = GUARD_STEPS
        trial = start[:, None] + steps[None, :, None, None] * (end - start)[:, None]  # (F, T, 4, C)
        minima = hallucinated_minimum(trial.reshape(-1, *solved.shape[1:]), curve).reshape(failing.size, len(steps), -1)
        passes = np.all(minima >= floor[failing, None, :] - allowance[failing, None, :], axis=-1)
        passes[:, -1] = True  # t = 0 is the projected band itself
        first = np.argmax(passes, axis=1)  # steps run from t = 1 down: the first pass is the largest t
        out[failing] = trial[np.arange(failing.size), first]
    return out


def solve_hallucinated_linear(
    radiance_sh: np.ndarray, curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE, max_iterations: int = 60,
    negative_guard: bool = True,
) -> tuple[np.ndarray, dict]:
    """Linear SH (P, 4, C) whose Listing-1 reconstruction best matches the capture's irradiance ([ZH3S], module
    derivation), batched over probes.

    Every probe is a 9-parameter problem (RGB linear band; the DC stays the capture's, as Eq. 11's f0 = t0),
    solved with :func:`~bakery.irradiance.zh3.batched_bfgs` from five starts: the projected band and the four
    tetrahedral starts of [ZH3S] (:func:`~bakery.irradiance.zh3.tetrahedral_starts`). The error is divided by the
    probe's irradiance energy so one tolerance fits all. Per probe the lowest of {projected band (the fallback:
    the paper's hallucination), every solution} is kept, so the result is never worse than ``zh3_hallucinated``
    against the capture.

    ``negative_guard`` (default): the error alone happily trades negative lobes for accuracy (measured: ``park``
    18 % of directions negative instead of the paper's 3.9 %), so each solution is first moved back towards the
    projected band until no channel's exact minimum is below min(0, the paper's) (:func:`_guard_negative`); the
    fallback comparison then uses the guarded band.

    Args:
        radiance_sh: (P, 9, C) radiance SH3 of the capture.
    Returns:
        linear SH (P, 4, C) float64 and {"solved": probes whose band changed, "fallback": probes that kept the
        projected band, "guarded": probes the guard moved, "iterations": the most BFGS iterations used}.
    """
    sh = np.array(radiance_sh[:, :9], dtype=np.float64)
    p, _, ch = sh.shape
    projected = linear_band_vector(sh)
    weight = 1.0 / np.maximum(np.sum((sh * _IRRADIANCE_SCALE[None, :, None]) ** 2, axis=(1, 2)), 1e-300)

    def objective(flat: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, g = _hallucination_error(flat.reshape(rows.size, 3, ch), sh[rows], curve)
        return e * weight[rows], (g * weight[rows, None, None]).reshape(rows.size, -1)

    candidates = [projected]
    iterations = 0
    for start in [projected, *tetrahedral_starts(projected)]:
        solved, used = batched_bfgs(objective, start.reshape(p, -1), max_iterations)
        iterations = max(iterations, used)
        # compared as stored (float32), so the fallback decision holds for the stored values
        candidates.append(solved.reshape(p, 3, ch).astype(np.float32).astype(np.float64))
    errors = np.stack([_hallucination_error(c, sh, curve)[0] for c in candidates])  # (starts, P)
    errors = np.where(np.isfinite(errors), errors, np.inf)
    best = np.argmin(errors, axis=0)
    vector = np.stack(candidates)[best, np.arange(p)]
    guarded = np.zeros(p, dtype=bool)
    if negative_guard:
        as_linear = np.concatenate([sh[:, :1], _vector_to_linear(vector)], axis=1)
        moved = _guard_negative(as_linear, sh[:, :4], curve)
        guarded = np.any(moved != as_linear, axis=(1, 2))
        vector = linear_band_vector(moved).astype(np.float32).astype(np.float64)
    error = _hallucination_error(vector, sh, curve)[0]
    error = np.where(np.isfinite(error), error, np.inf)
    kept = error < errors[0]  # strictly better than the projected band, else the fallback
    vector = np.where(kept[:, None, None], vector, projected)
    linear = np.concatenate([sh[:, :1], _vector_to_linear(vector)], axis=1)
    return linear, {"solved": int(kept.sum()), "fallback": int((~kept).sum()), "guarded": int(guarded.sum()),
                    "iterations": iterations}


def random_start_bound(radiance_sh: np.ndarray, starts: int = 512, seed: int = 0,
                       curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE, max_iterations: int = 200) -> np.ndarray:
    """Lowest relative error √(E/‖t‖²) (P,) of Listing 1 found from ``starts`` random linear bands per probe (plus
    the projected band): an empirical bound on what any 48 bytes (with the capture's DC) can do for the paper's
    shader, for the bench's "is SH2 reachable" question. Random bands: Gaussian vectors per channel, scaled by the
    projected band's norm times U(0, 1.5). Batched over probes × starts."""
    sh = np.array(radiance_sh[:, :9], dtype=np.float64)
    p, _, ch = sh.shape
    rng = np.random.default_rng(seed)
    projected = linear_band_vector(sh)
    scale = np.linalg.norm(projected, axis=(1, 2))
    energy = np.maximum(np.sum((sh * _IRRADIANCE_SCALE[None, :, None]) ** 2, axis=(1, 2)), 1e-300)
    repeated = np.repeat(sh, starts + 1, axis=0)
    x0 = rng.normal(size=(p, starts + 1, 3, ch)) * (scale[:, None] * rng.uniform(0, 1.5, (p, starts + 1)))[
        :, :, None, None]
    x0[:, 0] = projected
    weight = np.repeat(1.0 / energy, starts + 1)

    def objective(flat: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, g = _hallucination_error(flat.reshape(rows.size, 3, ch), repeated[rows], curve)
        return e * weight[rows], (g * weight[rows, None, None]).reshape(rows.size, -1)

    solved, _ = batched_bfgs(objective, x0.reshape(p * (starts + 1), -1), max_iterations, 1e-10)
    error = objective(solved, np.arange(p * (starts + 1)))[0].reshape(p, starts + 1)
    return np.sqrt(np.maximum(np.min(error, axis=1), 0.0))
