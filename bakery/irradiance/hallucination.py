"""Solved hallucination: linear SH, and a per-probe scale of the zonal term, chosen so that the paper's hallucinated
ZH3 ([ZH3] Eq. 21, Listing 1) best matches the probe's full irradiance.

References
    [ZH3]  T. Roughton, P.-P. Sloan, A. Silvennoinen, M. Iwanicki, P. Shirley, "ZH3: Quadratic Zonal Harmonics",
           Proc. ACM Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001): Sec. 3.3 (solving the linear band with
           BFGS), Sec. 3.4.3–3.4.4 (Eq. 21 on the luminance axis), Listing 1 (the shader), App. C (gradients).
    [ZH3S] The authors' reference solver, kayru/Probulator ``Source/External/zh3solver`` (MIT),
           ``ZH3HallucinateSharedLuminanceSolver``: the same idea, four tetrahedral starts, L-BFGS. Re-derived here
           (no code taken): bakery's objective is the irradiance error of every channel with equal weight (the
           bench's metric) and keeps the reader's luminance axis (Rec.709 weights, Listing 1) and its abs().
    [VP]   G. H. Golub, V. Pereyra, "The Differentiation of Pseudo-Inverses and Nonlinear Least Squares Problems
           Whose Variables Separate", SIAM J. Numer. Anal. 10(2), 1973 (eliminating the linear zonal scale).

The reader is Listing 1 applied to the stored (f0, f1) (:func:`bakery.irradiance.zh3.hallucinate_zonal_l2`), its
zonal term times the stored scale (1 for the paper's shader). Only the stored linear band and the scale differ
from the projected band and 1.

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
    the projected band with scale 0, which drops the zonal term at evaluation (plain SH2;
    :func:`hallucination_beats_sh2` decides, exactly against the capture by the same Parseval argument: SH2's
    error is the objective with z_c = 0, :func:`plain_sh2_sh_error`).

The zonal scale (``zh3_hallucinated_solved`` 1.2.0)
    Eq. 21 sizes the zonal term from the L1/L0 ratio alone, a curve fitted to production maps; on a given probe
    the capture's zonal coefficient is often larger or smaller (``studio``: the best scale is 2.7). One stored
    byte g multiplies Listing 1's zonal term, z_c = g h_c, with h_c the term above; the axis and each channel's
    share stay hallucinated from the band. The objective is the one above with z_c = g h_c: quadratic in g for a
    fixed band (:func:`optimal_zonal_scale`), so :func:`solve_scaled_hallucination` eliminates g (variable
    projection) and runs BFGS over the band alone. ∂E/∂v at fixed g is the gradient above with ∂z_c/∂d_c scaled
    by g.
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


#: ``zonal_scale`` codes per unit scale (``zh3_hallucinated_solved`` 1.2.0): scale = code / 64, so code 64 is
#: Listing 1 as published, 0 is plain SH2 and 255 the largest scale, 3.98 (schemas/store-v1.md).
ZONAL_SCALE_UNIT = 64
MAX_ZONAL_SCALE_CODE = 255


def _listing1_terms(vector: np.ndarray, radiance_sh: np.ndarray, curve: tuple[float, float]) -> dict:
    """Listing 1's pieces for linear band vectors ``vector`` (P, 3, C) and the capture's radiance SH3 (P, 9, C):
    axis a (P, 3), d_c = v_c·a, the unit-scale zonal term h_c = c2 d_c²/f0_c + c1 |d_c| and ∂h_c/∂d_c (P, C), the
    best zonal value s_c (P, C) and the pieces of the axis gradient (module derivation)."""
    c2, c1 = curve
    f0 = radiance_sh[:, 0]
    u = np.einsum("pjc,c->pj", vector, LUMINANCE_WEIGHTS)
    norm_u = np.linalg.norm(u, axis=-1)
    degenerate = ~(norm_u > 1e-30)  # the reader's fallback axis; no axis gradient there
    safe_norm = np.where(degenerate, 1.0, norm_u)
    a = np.where(degenerate[:, None], FALLBACK_AXIS[None, :], u / safe_norm[:, None])
    r2 = radiance_sh[:, 4:9]
    d = np.einsum("pj,pjc->pc", a, vector)
    positive = f0 > 0  # p = 0 where f0 <= 0 (schemas/store-v1.md)
    safe_f0 = np.where(positive, f0, 1.0)
    return {"a": a, "d": d, "r2": r2, "degenerate": degenerate, "safe_norm": safe_norm,
            "s": _K2 * np.einsum("pk,pkc->pc", band2_at(a), r2),
            "h": np.where(positive, c2 * d * d / safe_f0 + c1 * np.abs(d), 0.0),
            "dh_dd": np.where(positive, 2.0 * c2 * d / safe_f0 + c1 * np.sign(d), 0.0)}


def _hallucination_error(
    vector: np.ndarray, radiance_sh: np.ndarray, curve: tuple[float, float], scale: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Irradiance SH error (P,) of Listing 1 with linear band vectors ``vector`` (P, 3, C), DC r0 and its zonal
    term scaled by ``scale`` (P,) (None: 1, the paper's) against the capture's radiance SH3 ``radiance_sh``
    (P, 9, C), and its gradient (P, 3, C) with respect to ``vector`` (module derivation, z_c = scale · h_c)."""
    t = _listing1_terms(vector, radiance_sh, curve)
    a, d, r2, s = t["a"], t["d"], t["r2"], t["s"]
    g = np.ones(len(vector)) if scale is None else np.asarray(scale, dtype=np.float64)
    rho = linear_band_vector(radiance_sh)
    z = g[:, None] * t["h"]
    error = (_A1**2 * np.sum((vector - rho) ** 2, axis=(1, 2))
             + _A2**2 * np.sum((z - s) ** 2 + np.sum(r2**2, axis=1) - s**2, axis=1))
    de_dz = 2.0 * _A2**2 * (z - s)
    de_dd = de_dz * g[:, None] * t["dh_dd"]
    de_da = (np.einsum("pc,pjc->pj", de_dd, vector)
             - 2.0 * _A2**2 * _K2 * np.einsum("pc,pkj,pkc->pj", z, band2_jacobian(a), r2))
    safe_norm = t["safe_norm"]
    de_du = np.where(t["degenerate"][:, None], 0.0,
                     (de_da - a * np.sum(a * de_da, axis=-1, keepdims=True)) / safe_norm[:, None])
    grad = (2.0 * _A1**2 * (vector - rho) + a[:, :, None] * de_dd[:, None, :]
            + de_du[:, :, None] * LUMINANCE_WEIGHTS[None, None, :])
    return error, grad


def optimal_zonal_scale(vector: np.ndarray, radiance_sh: np.ndarray,
                       curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE) -> np.ndarray:
    """The scale g (P,) that minimises the error of Listing 1's zonal term g·h_c for fixed linear band vectors
    ``vector`` (P, 3, C): the error is A2² Σ_c (g h_c − s_c)² + const in g, so g = Σ_c h_c s_c / Σ_c h_c²,
    clipped to [0, the largest stored scale] (1 where h = 0: the scale does not matter)."""
    t = _listing1_terms(vector, radiance_sh, curve)
    hh = np.sum(t["h"] ** 2, axis=1)
    g = np.sum(t["h"] * t["s"], axis=1) / np.where(hh > 0, hh, 1.0)
    return np.where(hh > 0, np.clip(g, 0.0, MAX_ZONAL_SCALE_CODE / ZONAL_SCALE_UNIT), 1.0)


def hallucination_sh_error(
    linear_sh: np.ndarray, radiance_sh: np.ndarray, curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE,
    scale: np.ndarray | None = None,
) -> np.ndarray:
    """‖E_h − E_≤2‖² (P,): irradiance SH error of Listing 1 on ``linear_sh`` (P, 4, C) (its DC replaced by the
    capture's), its zonal term times ``scale`` (P,) (None: 1), against the capture's radiance SH3 (P, 9, C);
    equals the squared L2 error against the full irradiance minus a constant per probe (module derivation)."""
    sh = np.array(radiance_sh[:, :9], dtype=np.float64)
    error, _ = _hallucination_error(linear_band_vector(np.asarray(linear_sh, dtype=np.float64)), sh, curve, scale)
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
    min_gain: float = 0.01, scale: np.ndarray | None = None,
) -> np.ndarray:
    """(P,) bool: Listing 1 on ``linear_sh`` (P, 4, C), its zonal term times ``scale`` (P,) (None: 1), has a
    band-≤2 irradiance error against the capture at least ``min_gain`` (relative) below plain ``sh2`` on the
    capture's projected band — where it has not, ``zh3_hallucinated_solved`` stores ``zonal_scale`` = 0. Both
    are the L2 error against the capture's full irradiance minus the same constant ‖E_>2‖² (Parseval), so the
    order is exact; ``min_gain`` keeps near-ties (which the capture's resampling can flip against the true
    environment) on the plain reconstruction."""
    sh = np.array(radiance_sh[:, :9], dtype=np.float64)
    hallucinated = hallucination_sh_error(linear_sh, sh, curve, scale)
    plain = plain_sh2_sh_error(sh[:, :4], sh)
    return np.isfinite(hallucinated) & (hallucinated < (1.0 - min_gain) * plain)


#: Steps t of the negative guard's backtracking from the solution (t = 1) towards the projected band (t = 0).
GUARD_STEPS = np.linspace(1.0, 0.0, 17)


def hallucinated_minimum(linear_sh: np.ndarray, curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE,
                         scale: np.ndarray | None = None) -> np.ndarray:
    """Exact minimum over the sphere (P, C) of the Listing-1 irradiance of linear SH (P, 4, C), its zonal term
    times ``scale`` (P,) (None: 1) (the zonal term as band-2 SH, :func:`~bakery.irradiance.zh3.expand_zh3_to_sh3`;
    trust-region minimum of :func:`~bakery.irradiance.sh_irradiance.minimum_sh_irradiance`)."""
    axis = luminance_axis(linear_sh)
    zonal = hallucinate_zonal_l2(linear_sh, curve)
    if scale is not None:
        zonal = np.asarray(scale, dtype=np.float64)[:, None] * zonal
    return minimum_sh_irradiance(expand_zh3_to_sh3(linear_sh, zonal, axis))


def _guard_negative(solved: np.ndarray, projected: np.ndarray, curve: tuple[float, float],
                    code: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Move each solved band (P, 4, C) and its ``zonal_scale`` code (P,) (None: the paper's, 64) back along the
    segment towards the projected band with the paper's code (t ∈ :data:`GUARD_STEPS`, the largest t that passes;
    codes rounded along the way) until no channel's minimum irradiance is below min(0, its minimum under the
    paper's hallucination): the solve then never adds negative lobes the paper's hallucination does not have
    (t = 0, the paper's, always passes). Returns the bands and codes."""
    unit = float(ZONAL_SCALE_UNIT)
    code = np.full(len(solved), ZONAL_SCALE_UNIT) if code is None else np.asarray(code)
    floor = np.minimum(hallucinated_minimum(projected, curve), 0.0)  # (P, C)
    allowance = 1e-12 * np.abs(projected[:, 0]).max(axis=-1)[:, None]  # rounding, relative to the DC
    out, out_code = solved.copy(), code.copy()
    # Most solutions pass at t = 1; only the others are backtracked over the whole grid.
    failing = np.flatnonzero(~np.all(hallucinated_minimum(solved, curve, code / unit) >= floor - allowance, axis=-1))
    if failing.size:
        start, end = projected[failing], solved[failing]
        steps = GUARD_STEPS
        trial = start[:, None] + steps[None, :, None, None] * (end - start)[:, None]  # (F, T, 4, C)
        trial_code = np.rint(unit + steps[None, :] * (code[failing, None] - unit))  # (F, T)
        minima = hallucinated_minimum(trial.reshape(-1, *solved.shape[1:]), curve,
                                      trial_code.reshape(-1) / unit).reshape(failing.size, len(steps), -1)
        passes = np.all(minima >= floor[failing, None, :] - allowance[failing, None, :], axis=-1)
        passes[:, -1] = True  # t = 0 is the projected band itself
        first = np.argmax(passes, axis=1)  # steps run from t = 1 down: the first pass is the largest t
        out[failing] = trial[np.arange(failing.size), first]
        out_code[failing] = trial_code[np.arange(failing.size), first]
    return out, out_code.astype(code.dtype)


def _irradiance_energy(radiance_sh: np.ndarray) -> np.ndarray:
    """‖t‖² (P,): the squared norm of the capture's band-≤2 irradiance SH (P, 9, C), floored away from 0."""
    return np.maximum(np.sum((radiance_sh * _IRRADIANCE_SCALE[None, :, None]) ** 2, axis=(1, 2)), 1e-300)


def _bfgs_objective(radiance_sh: np.ndarray, curve: tuple[float, float], scale=None):
    """The ``objective(flat (A, 3C), rows (A,))`` of :func:`~bakery.irradiance.zh3.batched_bfgs` over linear band
    vectors: :func:`_hallucination_error` of probes ``rows`` divided by their ‖t‖², so one tolerance fits all.
    ``scale``: None (1, the paper's), an array (P,) of fixed scales, or a callable (vector, rows) → (A,) (the
    variable-projection scale of :func:`solve_scaled_hallucination`)."""
    weight = 1.0 / _irradiance_energy(radiance_sh)
    ch = radiance_sh.shape[-1]

    def objective(flat: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        vector = flat.reshape(rows.size, 3, ch)
        g = scale(vector, rows) if callable(scale) else None if scale is None else scale[rows]
        e, grad = _hallucination_error(vector, radiance_sh[rows], curve, g)
        return e * weight[rows], (grad * weight[rows, None, None]).reshape(rows.size, -1)

    return objective


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
    objective = _bfgs_objective(sh, curve)
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
        moved, _ = _guard_negative(as_linear, sh[:, :4], curve)
        guarded = np.any(moved != as_linear, axis=(1, 2))
        vector = linear_band_vector(moved).astype(np.float32).astype(np.float64)
    error = _hallucination_error(vector, sh, curve)[0]
    error = np.where(np.isfinite(error), error, np.inf)
    kept = error < errors[0]  # strictly better than the projected band, else the fallback
    vector = np.where(kept[:, None, None], vector, projected)
    linear = np.concatenate([sh[:, :1], _vector_to_linear(vector)], axis=1)
    return linear, {"solved": int(kept.sum()), "fallback": int((~kept).sum()), "guarded": int(guarded.sum()),
                    "iterations": iterations}


def solve_scaled_hallucination(
    radiance_sh: np.ndarray, curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE, max_iterations: int = 60,
    negative_guard: bool = True,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Linear SH (P, 4, C) and ``zonal_scale`` codes (P,) whose Listing-1 reconstruction, its zonal term times
    code / :data:`ZONAL_SCALE_UNIT`, best matches the capture's irradiance (module derivation with z_c = g·h_c),
    batched over probes.

    Variable projection ([VP]): for a fixed band the error is quadratic in the scale g, minimised by
    :func:`optimal_zonal_scale`, so BFGS (:func:`~bakery.irradiance.zh3.batched_bfgs`) runs over the nine band
    parameters of E(v, g*(v)), whose gradient is ∂E/∂v at g = g*(v) (∂E/∂g = 0 there, or g* is at a bound). Five
    starts, as :func:`solve_hallucinated_linear`; per probe the best is kept, its scale rounded to a code and the
    band re-solved at that scale, then (``negative_guard``) moved back towards the paper's hallucination until it
    adds no negative lobe (:func:`_guard_negative`). Per probe the lower of {that, the paper's hallucination
    (projected band, code 64)} is returned, so the result is never worse than ``zh3_hallucinated`` against the
    capture; code 64 with a solved band is :func:`solve_hallucinated_linear`'s answer space.

    Args:
        radiance_sh: (P, 9, C) radiance SH3 of the capture.
    Returns:
        linear SH (P, 4, C) float64 (float32-representable), codes (P,) uint8, and {"solved": probes that differ
        from the paper's, "guarded": probes the guard moved, "iterations": the most BFGS iterations used}.
    """
    sh = np.array(radiance_sh[:, :9], dtype=np.float64)
    p, _, ch = sh.shape
    everything = np.arange(p)
    projected = linear_band_vector(sh)
    reduced = _bfgs_objective(sh, curve, lambda vector, rows: optimal_zonal_scale(vector, sh[rows], curve))
    iterations, solutions, errors = 0, [], []
    for start in [projected, *tetrahedral_starts(projected)]:
        solved, used = batched_bfgs(reduced, start.reshape(p, -1), max_iterations)
        iterations = max(iterations, used)
        solutions.append(solved)
        errors.append(np.where(np.isfinite(e := reduced(solved, everything)[0]), e, np.inf))
    best = np.stack(solutions)[np.argmin(np.stack(errors), axis=0), everything].reshape(p, 3, ch)
    code = np.clip(np.rint(optimal_zonal_scale(best, sh, curve) * ZONAL_SCALE_UNIT), 0, MAX_ZONAL_SCALE_CODE)
    solved, used = batched_bfgs(_bfgs_objective(sh, curve, code / ZONAL_SCALE_UNIT), best.reshape(p, -1),
                                max_iterations)
    iterations = max(iterations, used)
    vector = solved.reshape(p, 3, ch).astype(np.float32).astype(np.float64)  # compared as stored
    guarded = np.zeros(p, dtype=bool)
    if negative_guard:
        as_linear = np.concatenate([sh[:, :1], _vector_to_linear(vector)], axis=1)
        moved, moved_code = _guard_negative(as_linear, sh[:, :4], curve, code)
        guarded = np.any(moved != as_linear, axis=(1, 2)) | (moved_code != code)
        vector, code = linear_band_vector(moved).astype(np.float32).astype(np.float64), moved_code
    error = _hallucination_error(vector, sh, curve, code / ZONAL_SCALE_UNIT)[0]
    paper = _hallucination_error(projected, sh, curve)[0]
    kept = np.where(np.isfinite(error), error, np.inf) < paper  # strictly better than the paper's, else it
    vector = np.where(kept[:, None, None], vector, projected)
    code = np.where(kept, code, ZONAL_SCALE_UNIT).astype(np.uint8)
    linear = np.concatenate([sh[:, :1], _vector_to_linear(vector)], axis=1)
    return linear, code, {"solved": int(kept.sum()), "guarded": int(guarded.sum()), "iterations": iterations}


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
    repeated = np.repeat(sh, starts + 1, axis=0)
    x0 = rng.normal(size=(p, starts + 1, 3, ch)) * (scale[:, None] * rng.uniform(0, 1.5, (p, starts + 1)))[
        :, :, None, None]
    x0[:, 0] = projected
    objective = _bfgs_objective(repeated, curve)
    solved, _ = batched_bfgs(objective, x0.reshape(p * (starts + 1), -1), max_iterations, 1e-10)
    error = objective(solved, np.arange(p * (starts + 1)))[0].reshape(p, starts + 1)
    return np.sqrt(np.maximum(np.min(error, axis=1), 0.0))
