"""ZH3: linear SH plus one zonal quadratic coefficient per channel on a shared axis (seed 001).

References
    [ZH3] T. Roughton, P.-P. Sloan, A. Silvennoinen, M. Iwanicki, P. Shirley. "ZH3: Quadratic Zonal Harmonics".
          Proc. ACM Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001).

Notation
    f0, f1   DC (P, C) and linear band (P, 3, C) of radiance SH, m = −1, 0, 1 (index order of the conventions)
    v        linear band as a Cartesian vector (−f1,1, −f1,−1, f1,0): f1·Y1(ω) = √(3/4π) v·ω
    a        unit zonal axis (P, 3) shared by the channels: the optimal linear direction of the luminance SH
    q        Y2(a) (P, 5), the band-2 basis at the axis
    f2^0     zonal L2 *radiance* coefficient per channel in the frame of a (P, C)  ([ZH3] Eq. 10)

Stored ZH3 = (f0, f1, f2^0); the axis is recomputed from f1 by the reader (luminance weights of the conventions).
Irradiance: E(n) = π f0 Y00 + (2π/3) f1·Y1(n) + (π/4) f2^0 Y20(a·n)   ([ZH3] Listing 1, unnormalised cosine).
"""

from __future__ import annotations

import warnings
from math import pi, sqrt

import numpy as np

from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.errors import DegenerateInputWarning
from bakery.sh.basis import evaluate_sh_basis
from bakery.sh.convolution import cosine_lobe_band_factors

#: [ZH3] Eq. 21: curve-fit hallucination f2^0 = (0.6 p² + 0.08 p) f0, p = |f1^0| / f0.
PAPER_HALLUCINATION_CURVE = (0.6, 0.08)

#: Axis used when the luminance linear band vanishes (constant or perfectly balanced lighting).
FALLBACK_AXIS = np.array([0.0, 0.0, 1.0])

_C20 = sqrt(5.0 / (16.0 * pi))
_C2 = sqrt(15.0 / (4.0 * pi))


def linear_band_vector(linear_sh: np.ndarray) -> np.ndarray:
    """v = (−f1,1, −f1,−1, f1,0) per channel: (P, ≥4, C) → (P, 3, C)."""
    return np.stack([-linear_sh[:, 3], -linear_sh[:, 1], linear_sh[:, 2]], axis=1)


def optimal_linear_direction(vector: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """normalize(v) (P, 3) and a mask (P,) of probes whose v vanished and got :data:`FALLBACK_AXIS`.

    [ZH3] Sec. 2.2 / Eq. 32: the optimal linear direction is normalize(−f1,1, −f1,−1, f1,0).
    """
    norm = np.linalg.norm(vector, axis=-1)
    degenerate = ~(norm > 1e-30)
    axis = np.where(degenerate[:, None], FALLBACK_AXIS[None, :], vector / np.where(degenerate, 1.0, norm)[:, None])
    return axis, degenerate


def luminance_axis(linear_sh: np.ndarray) -> np.ndarray:
    """Shared zonal axis (P, 3): optimal linear direction of the luminance SH ([ZH3] Sec. 3.2, Eq. 29–32)."""
    axis, _ = optimal_linear_direction(linear_band_vector(linear_sh) @ LUMINANCE_WEIGHTS)
    return axis


def band2_at(axis: np.ndarray) -> np.ndarray:
    """q = Y2(axis) (P, 5): band-2 basis (indices 4..8) at the axis."""
    return evaluate_sh_basis(axis, 2)[:, 4:9]


def solve_zonal_l2(band2: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Least-squares zonal L2 radiance coefficient f2^0 (P, C) of band-2 SH (P, 5, C) along ``axis`` (P, 3).

    [ZH3] Eq. 9–10: k2 = (4π/5) q·f2 and l2^0 = K_2^0 k2 = √(4π/5) q·f2.
    """
    return sqrt(4.0 * pi / 5.0) * np.einsum("pk,pkc->pc", band2_at(axis), band2)


def expand_zh3_to_sh3(linear_sh: np.ndarray, zonal_l2: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Radiance SH3 (P, 9, C) equal to the ZH3 (linear SH (P, 4, C), f2^0 (P, C), axis (P, 3)).

    The band-2 part of a zonal lobe is f2^0 √(4π/5) Y2(a) ([ZH3] Sec. 2.1, Eq. 2).
    """
    band2 = sqrt(4.0 * pi / 5.0) * band2_at(axis)[:, :, None] * zonal_l2[:, None, :]
    return np.concatenate([linear_sh[:, :4], band2], axis=1)


def evaluate_zh3_irradiance(
    linear_sh: np.ndarray, zonal_l2: np.ndarray, normals: np.ndarray, axis: np.ndarray | None = None
) -> np.ndarray:
    """Irradiance (P, N, C) at unit normals (N, 3), as a shader would ([ZH3] Listing 1 with A_l = π, 2π/3, π/4)."""
    if axis is None:
        axis = luminance_axis(linear_sh)
    a = cosine_lobe_band_factors(2)
    basis = evaluate_sh_basis(normals, 1)  # (N, 4)
    linear = np.einsum("nk,pkc->pnc", basis * a[[0, 1, 1, 1]], linear_sh[:, :4])
    t = normals @ axis.T  # (N, P)
    zonal = _C20 * (3.0 * t.T**2 - 1.0)  # (P, N)
    return linear + a[2] * zonal[:, :, None] * zonal_l2[:, None, :]


# -----------------------------------------------------------------------------------------------------------------
# ZH3 on the luminance axis ([ZH3] Sec. 3.1–3.2)
def fit_zh3_luminance(radiance_sh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(linear SH (P, 4, C), f2^0 (P, C)) of radiance SH3 (P, 9, C) with the shared luminance axis."""
    linear = radiance_sh[:, :4].copy()
    axis = luminance_axis(linear)
    return linear, solve_zonal_l2(radiance_sh[:, 4:9], axis)


# -----------------------------------------------------------------------------------------------------------------
# ZH3 with a solved axis ([ZH3] Sec. 3.3, Eq. 11, App. C)
def axis_error(linear_irr: np.ndarray, target_irr: np.ndarray) -> np.ndarray:
    """[ZH3] Eq. 11 per probe: ‖f − t1‖² + Σ_c ‖k_c q − t2_c‖² with k_c = (4π/5) q·t2_c (irradiance SH).

    Args:
        linear_irr: (P, 3, C) candidate linear band f (irradiance SH, m = −1, 0, 1).
        target_irr: (P, 9, C) target irradiance SH t.
    Returns:
        (P,) error. Uses ‖k q − t2‖² = ‖t2‖² − (4π/5)(q·t2)² since ‖q‖² = 5/4π.
    """
    error, _ = _axis_error_and_gradient(linear_irr, target_irr)
    return error


def band2_jacobian(axis: np.ndarray) -> np.ndarray:
    """J_Y2 (P, 5, 3) at unit axes (P, 3): rows are the five band-2 functions (indices 4..8), columns d/dx, d/dy,
    d/dz ([ZH3] Eq. 28; row 5: ∇[√(15/16π)(x² − y²)] = √(15/4π)(x, −y, 0))."""
    x, y, z = axis[:, 0], axis[:, 1], axis[:, 2]
    zero = np.zeros_like(x)
    return np.stack(
        [
            np.stack([_C2 * y, _C2 * x, zero], -1),
            np.stack([zero, -_C2 * z, -_C2 * y], -1),
            np.stack([zero, zero, 6.0 * _C20 * z], -1),
            np.stack([-_C2 * z, zero, -_C2 * x], -1),
            np.stack([_C2 * x, -_C2 * y, zero], -1),
        ],
        axis=1,
    )


def _axis_error_and_gradient(f: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 11 and its gradient with respect to f (P, 3, C). Derivation (our own, equivalent to [ZH3] App. C):

    E = Σ_c ‖f_c − t1_c‖² + Σ_c (‖t2_c‖² − (4π/5) s_c²),  s_c = Y2(a)·t2_c,  a = normalize(u),
    u = (−ℓ_1, −ℓ_−1, ℓ_0), ℓ = Σ_c w_c f_c (luminance, Eq. 29–30, 32).
    ∂E/∂a = −(8π/5) Σ_c s_c J_Y2(a)ᵀ t2_c (J_Y2 of Eq. 28);  ∂E/∂u = (I − a aᵀ)/‖u‖ · ∂E/∂a (Eq. 36);
    ∂E/∂ℓ = (−∂E/∂u_y, ∂E/∂u_z, −∂E/∂u_x);  ∂E/∂f_c = 2(f_c − t1_c) + w_c ∂E/∂ℓ (Eq. 34).
    """
    t1, t2 = t[:, 1:4], t[:, 4:9]
    ell = f @ LUMINANCE_WEIGHTS  # (P, 3) in m order (−1, 0, 1)
    u = np.stack([-ell[:, 2], -ell[:, 0], ell[:, 1]], axis=-1)
    norm_u = np.maximum(np.linalg.norm(u, axis=-1), 1e-30)
    a = u / norm_u[:, None]
    q = band2_at(a)  # (P, 5)
    s = np.einsum("pk,pkc->pc", q, t2)
    error = np.sum((f - t1) ** 2, axis=(1, 2)) + np.sum(t2**2, axis=(1, 2)) - (4.0 * pi / 5.0) * np.sum(s**2, axis=1)
    de_da = -(8.0 * pi / 5.0) * np.einsum("pc,pkj,pkc->pj", s, band2_jacobian(a), t2)
    de_du = (de_da - a * np.sum(a * de_da, axis=-1, keepdims=True)) / norm_u[:, None]
    de_dell = np.stack([-de_du[:, 1], de_du[:, 2], -de_du[:, 0]], axis=-1)  # back to m order (−1, 0, 1)
    grad = 2.0 * (f - t1) + de_dell[:, :, None] * LUMINANCE_WEIGHTS[None, None, :]
    return error, grad


def batched_bfgs(
    objective, x0: np.ndarray, iterations: int = 60, gradient_tolerance: float = 1e-7
) -> tuple[np.ndarray, int]:
    """Minimise P independent smooth problems at once: BFGS with a per-problem Armijo backtracking line search.

    ``objective(x (A, n), rows (A,)) -> (f (A,), g (A, n))`` evaluates the problems ``rows`` (indices into the P
    problems) at ``x``; only problems still running are evaluated, so converged ones cost nothing. f should be
    scaled to O(1) (the gradient tolerance is absolute). A problem stops when its gradient is below the tolerance,
    its predicted decrease is at rounding level, or its line search fails. Every problem keeps its own
    inverse-Hessian estimate (P, n, n); all arithmetic is vectorised over the running problems (Nocedal & Wright,
    Algorithm 6.1 with backtracking, Alg. 3.1). Returns the minimisers (P, n) and the number of iterations run.
    """
    x = np.array(x0, dtype=np.float64)
    p, n = x.shape
    f, g = objective(x, np.arange(p))
    f, g = np.array(f, dtype=np.float64), np.array(g, dtype=np.float64)
    inverse_hessian = np.broadcast_to(np.eye(n), (p, n, n)).copy()
    active = np.ones(p, dtype=bool)
    eye = np.eye(n)[None]
    iteration = 0
    for iteration in range(1, iterations + 1):
        active &= np.sum(g * g, axis=1) > gradient_tolerance**2
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        g_a, h_a, f_a, x_a = g[rows], inverse_hessian[rows], f[rows], x[rows]
        direction = -np.einsum("pij,pj->pi", h_a, g_a)
        slope = np.sum(g_a * direction, axis=1)
        uphill = slope >= 0  # a non-descent direction: restart with steepest descent
        direction[uphill] = -g_a[uphill]
        h_a[uphill] = np.eye(n)
        slope = np.sum(g_a * direction, axis=1)
        # A predicted decrease at rounding level of f means the problem has converged.
        going = -slope > 1e-14 * np.maximum(np.abs(f_a), 1e-300)
        active[rows[~going]] = False
        if not going.any():
            break
        rows, g_a, h_a, f_a, x_a = rows[going], g_a[going], h_a[going], f_a[going], x_a[going]
        direction, slope = direction[going], slope[going]
        step = np.ones(rows.size)
        f_new, g_new = objective(x_a + direction, rows)
        f_new, g_new = np.array(f_new, dtype=np.float64), np.array(g_new, dtype=np.float64)
        for _ in range(12):  # Armijo backtracking, per problem
            bad = np.flatnonzero(~(f_new <= f_a + 1e-4 * step * slope))
            if bad.size == 0:
                break
            step[bad] *= 0.5
            f_new[bad], g_new[bad] = objective(x_a[bad] + step[bad, None] * direction[bad], rows[bad])
        accepted = f_new <= f_a + 1e-4 * step * slope
        s = np.where(accepted[:, None], step[:, None] * direction, 0.0)
        y = np.where(accepted[:, None], g_new - g_a, 0.0)
        x[rows] = x_a + s
        f[rows] = np.where(accepted, f_new, f_a)
        g[rows] = np.where(accepted[:, None], g_new, g_a)
        active[rows[~accepted]] = False
        sy = np.sum(s * y, axis=1)
        update = accepted & (sy > 1e-12 * np.sqrt(np.sum(s * s, axis=1) * np.sum(y * y, axis=1)))
        if update.any():
            rho = np.where(update, 1.0 / np.where(update, sy, 1.0), 0.0)
            left = eye - rho[:, None, None] * s[:, :, None] * y[:, None, :]
            right = eye - rho[:, None, None] * y[:, :, None] * s[:, None, :]
            updated = left @ h_a @ right + rho[:, None, None] * s[:, :, None] * s[:, None, :]
            h_a = np.where(update[:, None, None], updated, h_a)
        inverse_hessian[rows] = h_a
    return x, iteration


#: Unit vertices of a regular tetrahedron: the four starting axes of the reference ZH3 solver
#: (kayru/Probulator ``Source/External/zh3solver``, the authors' solver for [ZH3] Sec. 3.3).
TETRAHEDRON_AXES = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]]) / sqrt(3.0)


def tetrahedral_starts(vector: np.ndarray) -> list[np.ndarray]:
    """Four starts (P, 3, C) for the axis solves: every channel's linear band vector v_c (P, 3, C) replaced by its
    projection (t·v_c) t onto a tetrahedron vertex t (:data:`TETRAHEDRON_AXES`), so that the shared axis starts
    on t whatever the target's own axis is (the reference solver's starts, re-derived)."""
    return [t[None, :, None] * np.einsum("j,pjc->pc", t, vector)[:, None, :] for t in TETRAHEDRON_AXES]


def _vector_to_linear(vector: np.ndarray) -> np.ndarray:
    """Inverse of :func:`linear_band_vector`: (P, 3, C) Cartesian → (P, 3, C) in m order (−1, 0, 1)."""
    return np.stack([-vector[:, 1], vector[:, 2], -vector[:, 0]], axis=1)


#: Starts of the Eq. 11 solve (:func:`axis_starts`): what ``zh3_solved`` uses.
AXIS_STARTS = ("luminance", "tetrahedral")


def axis_starts(target_irr: np.ndarray, names: tuple[str, ...] = AXIS_STARTS) -> list[np.ndarray]:
    """Starting linear bands (P, 3, C) (irradiance SH, m order) of the Eq. 11 solves, by name:
    ``"luminance"`` the target's own band (the luminance-axis ZH3), ``"tetrahedral"`` the four starts of
    :func:`tetrahedral_starts`, ``"l2_favoured"`` the luminance vector turned onto the dominant axis of the L2
    band (:func:`_l2_favoured_start`; bakery's earlier second start, kept for the measurement in the bench)."""
    starts: list[np.ndarray] = []
    for name in names:
        if name == "luminance":
            starts.append(target_irr[:, 1:4].copy())
        elif name == "tetrahedral":
            starts += [_vector_to_linear(v) for v in tetrahedral_starts(linear_band_vector(target_irr))]
        elif name == "l2_favoured":
            starts.append(_l2_favoured_start(target_irr))
        else:
            raise ValueError(f"unknown axis start {name!r}; known: luminance, tetrahedral, l2_favoured")
    return starts


def solve_zh3_axis(
    radiance_sh: np.ndarray, max_iterations: int = 60, starts: tuple[str, ...] = AXIS_STARTS
) -> tuple[np.ndarray, np.ndarray, dict]:
    """ZH3 with the linear band re-solved to minimise [ZH3] Eq. 11 (irradiance SH error).

    Every probe is its own 9-parameter problem (the RGB linear band), solved with a batched BFGS
    (:func:`batched_bfgs`, [ZH3] Sec. 3.3 uses BFGS) and the analytic gradient of App. C; each probe's error is
    divided by its target energy ‖t‖² so one tolerance fits all. Default starts (:data:`AXIS_STARTS`, five runs):
    the target's linear band (the luminance-axis ZH3; it can sit on a saddle of Eq. 11 where the gradient vanishes
    by symmetry) and the reference solver's four tetrahedral starts (:func:`tetrahedral_starts`). Each probe keeps
    the best of {target band, all solutions}, so the result is never worse than the luminance-axis ZH3.

    Measured (``docs/irradiance.md``, ``bakery bench irradiance``): the tetrahedral starts lower Eq. 11 on 2 of the
    23 shared maps (``WavyLinesLatLong`` 0.0159 → 0.0047 RMSE) and on 10 of 600 random positive probes, and make
    the previous second start (``"l2_favoured"``) redundant there; the reference solver's
    per-channel axes blended towards the luminance axis (``axisLuminanceLerp`` < 1) *raise* the mean Eq. 11 error
    (:func:`axis_error_blended`), so the shared luminance axis the readers compute is kept.

    Returns:
        linear SH (P, 4, C) (radiance; DC unchanged, Eq. 11's f0 = t0), f2^0 (P, C) along the solved axis, and
        statistics {"improved": probes improved, "iterations": the most BFGS iterations used}.
    """
    a = cosine_lobe_band_factors(2)
    scale = a[[0, 1, 1, 1, 2, 2, 2, 2, 2]][None, :, None]
    target = radiance_sh[:, :9] * scale
    p, _, ch = target.shape
    weight = 1.0 / np.maximum(np.sum(target**2, axis=(1, 2)), 1e-300)

    def objective(flat: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, g = _axis_error_and_gradient(flat.reshape(rows.size, 3, ch), target[rows])
        return e * weight[rows], (g * weight[rows, None, None]).reshape(rows.size, -1)

    candidates = [target[:, 1:4].copy()]
    iterations = 0
    for f_init in axis_starts(target, starts):  # [ZH3] Sec. 3.3: BFGS over the linear band, from each start
        solved, used = batched_bfgs(objective, f_init.reshape(p, -1), max_iterations)
        iterations = max(iterations, used)
        candidates.append(solved.reshape(p, 3, ch))
    errors = np.stack([axis_error(c, target) for c in candidates])  # (starts, P)
    best = np.argmin(errors, axis=0)
    f_final = np.stack(candidates)[best, np.arange(p)]
    linear_out = radiance_sh[:, :4].copy()
    linear_out[:, 1:4] = f_final / a[1]
    axis = luminance_axis(linear_out)
    improved = int(np.sum(errors[best, np.arange(p)] < errors[0]))
    return linear_out, solve_zonal_l2(radiance_sh[:, 4:9], axis), {"improved": improved, "iterations": iterations}


def axis_error_blended(linear_irr: np.ndarray, target_irr: np.ndarray, luminance_lerp: float) -> tuple[
        np.ndarray, np.ndarray]:
    """Eq. 11 with per-channel axes blended towards the luminance axis, and its gradient (measurement only).

    The reference solver's ``axisLuminanceLerp`` λ: channel c's zonal axis is a_c = normalize(u_c),
    u_c = Σ_c' ((1 − λ) δ_cc' + λ w_c') v_c' (v = :func:`linear_band_vector`), so λ = 1 is the shared luminance
    axis of [ZH3] Sec. 3.2 (what bakery's readers compute) and λ = 0 one axis per channel (Sec. 3.1).
    E = Σ_c ‖f_c − t1_c‖² + ‖t2_c‖² − (4π/5) s_c², s_c = Y2(a_c)·t2_c; ∂E/∂u_c = (I − a_c a_cᵀ)/‖u_c‖ ·
    (−(8π/5) s_c J_Y2(a_c)ᵀ t2_c), ∂E/∂v_c' = Σ_c ((1 − λ) δ_cc' + λ w_c') ∂E/∂u_c.

    Args:
        linear_irr: (P, 3, C) linear band f (irradiance SH, m order). target_irr: (P, 9, C).
    Returns:
        E (P,) and ∂E/∂f (P, 3, C).
    """
    ch = linear_irr.shape[-1]
    mix = (1.0 - luminance_lerp) * np.eye(ch) + luminance_lerp * np.broadcast_to(LUMINANCE_WEIGHTS, (ch, ch))
    v = linear_band_vector(np.concatenate([target_irr[:, :1], linear_irr], axis=1))
    t2 = target_irr[:, 4:9]
    u = np.einsum("cd,pjd->pjc", mix, v)
    norm_u = np.maximum(np.linalg.norm(u, axis=1), 1e-30)  # (P, C)
    a = u / norm_u[:, None, :]
    error = np.sum((linear_irr - target_irr[:, 1:4]) ** 2, axis=(1, 2)) + np.sum(t2**2, axis=(1, 2))
    de_du = np.empty_like(u)
    for c in range(ch):  # channels, not samples
        q = band2_at(a[:, :, c])
        s = np.einsum("pk,pk->p", q, t2[:, :, c])
        error = error - (4.0 * pi / 5.0) * s**2
        de_da = -(8.0 * pi / 5.0) * np.einsum("p,pkj,pk->pj", s, band2_jacobian(a[:, :, c]), t2[:, :, c])
        de_du[:, :, c] = (de_da - a[:, :, c] * np.sum(a[:, :, c] * de_da, -1, keepdims=True)) / norm_u[:, c, None]
    de_dv = np.einsum("cd,pjc->pjd", mix, de_du)
    grad = 2.0 * (linear_irr - target_irr[:, 1:4]) + _vector_to_linear(de_dv)
    return error, grad


def solve_zh3_axis_blended(
    radiance_sh: np.ndarray, luminance_lerp: float, max_iterations: int = 60, starts: tuple[str, ...] = AXIS_STARTS
) -> np.ndarray:
    """Lowest :func:`axis_error_blended` (P,) over the unsolved band and the solutions from ``starts``
    (:func:`axis_starts`), relative to the target energy ‖t‖² (measurement of the reference solver's
    ``axisLuminanceLerp``; λ = 1 gives :func:`solve_zh3_axis`'s error)."""
    a = cosine_lobe_band_factors(2)
    target = radiance_sh[:, :9] * a[[0, 1, 1, 1, 2, 2, 2, 2, 2]][None, :, None]
    p, _, ch = target.shape
    weight = 1.0 / np.maximum(np.sum(target**2, axis=(1, 2)), 1e-300)

    def objective(flat: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, g = axis_error_blended(flat.reshape(rows.size, 3, ch), target[rows], luminance_lerp)
        return e * weight[rows], (g * weight[rows, None, None]).reshape(rows.size, -1)

    best = objective(target[:, 1:4].reshape(p, -1), np.arange(p))[0]
    for f_init in axis_starts(target, starts):
        solved, _ = batched_bfgs(objective, f_init.reshape(p, -1), max_iterations)
        best = np.minimum(best, objective(solved, np.arange(p))[0])
    return best


def _l2_favoured_start(target_irr: np.ndarray) -> np.ndarray:
    """Linear band (P, 3, C) whose luminance vector has the same length but points along the eigenvector of the
    luminance L2 quadratic form with the largest |eigenvalue| (sign kept towards the original vector)."""
    from bakery.irradiance.sh_irradiance import irradiance_quadratic_form

    luminance_l2 = np.zeros((target_irr.shape[0], 9, 1))
    luminance_l2[:, 4:9, 0] = target_irr[:, 4:9] @ LUMINANCE_WEIGHTS
    _, _, m = irradiance_quadratic_form(luminance_l2)
    lam, vectors = np.linalg.eigh(m[:, 0])
    pick = np.argmax(np.abs(lam), axis=-1)
    e = vectors[np.arange(len(pick)), :, pick]  # (P, 3) Cartesian
    ell = target_irr[:, 1:4] @ LUMINANCE_WEIGHTS  # (P, 3) m order
    u = np.stack([-ell[:, 2], -ell[:, 0], ell[:, 1]], axis=-1)
    sign = np.where(np.sum(u * e, axis=-1) < 0, -1.0, 1.0)
    length = np.maximum(np.linalg.norm(u, axis=-1), 1e-3 * np.abs(target_irr[:, 0] @ LUMINANCE_WEIGHTS))
    u_new = e * (sign * length)[:, None]
    delta_u = u_new - u
    delta_ell = np.stack([-delta_u[:, 1], delta_u[:, 2], -delta_u[:, 0]], axis=-1)  # back to m order
    # Shifting every channel by the same δ moves the luminance vector by δ (weights sum to 1).
    return target_irr[:, 1:4] + delta_ell[:, :, None]


# -----------------------------------------------------------------------------------------------------------------
# Hallucinated ZH3 ([ZH3] Sec. 3.4.3–3.4.4, Listing 1)
def hallucination_ratio(linear_sh: np.ndarray, axis: np.ndarray | None = None) -> np.ndarray:
    """p = |v_c·a| / f0_c per channel (P, C) on the luminance axis ([ZH3] Listing 1); 0 where f0 ≤ 0."""
    if axis is None:
        axis = luminance_axis(linear_sh)
    projected = np.abs(np.einsum("pj,pjc->pc", axis, linear_band_vector(linear_sh)))
    f0 = linear_sh[:, 0]
    return np.where(f0 > 0, projected / np.where(f0 > 0, f0, 1.0), 0.0)


def hallucinate_zonal_l2(linear_sh: np.ndarray, curve: tuple[float, float] = PAPER_HALLUCINATION_CURVE) -> np.ndarray:
    """Hallucinated f2^0 (P, C) = (c2 p² + c1 p) f0 ([ZH3] Eq. 21 with curve = (c2, c1))."""
    p = hallucination_ratio(linear_sh)
    return (curve[0] * p * p + curve[1] * p) * linear_sh[:, 0]


def fit_hallucination_curve(
    radiance_sh: np.ndarray, minimum_samples: int = 12
) -> tuple[tuple[float, float], int, bool]:
    """Fit (c2, c1) of f2^0 ≈ (c2 p² + c1 p) f0 to a scene's own probes by linear least squares.

    The target is the luminance-axis f2^0 solved from each probe's SH3 ([ZH3] Eq. 10); samples are (probe, channel)
    pairs with f0 > 0. With fewer than ``minimum_samples`` usable samples the paper's curve (Eq. 21) is returned.

    Returns:
        (curve, samples used, fitted?)
    """
    linear = radiance_sh[:, :4]
    axis = luminance_axis(linear)
    target = solve_zonal_l2(radiance_sh[:, 4:9], axis).reshape(-1)
    p = hallucination_ratio(linear, axis).reshape(-1)
    f0 = linear[:, 0].reshape(-1)
    usable = f0 > 0
    if usable.sum() < minimum_samples or np.ptp(p[usable]) < 1e-6:
        return PAPER_HALLUCINATION_CURVE, int(usable.sum()), False
    design = np.stack([p * p * f0, p * f0], axis=-1)[usable]
    # Each sample weighted by 1/f0 so that the fit is on the ratio f2/f0 (scale-free across probes).
    w = 1.0 / f0[usable]
    coefficients, *_ = np.linalg.lstsq(design * w[:, None], target[usable] * w, rcond=None)
    if not np.all(np.isfinite(coefficients)):
        warnings.warn("hallucination curve fit was not finite; using the paper's curve", DegenerateInputWarning,
                      stacklevel=2)
        return PAPER_HALLUCINATION_CURVE, int(usable.sum()), False
    return (float(coefficients[0]), float(coefficients[1])), int(usable.sum()), True
