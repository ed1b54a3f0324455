"""Input rules shared by every reflection evaluation (``schemas/store-reflection.md`` "Evaluation inputs").

Arguments (:func:`check_reflection_inputs`, applied by every reflection encoding's ``evaluate_reflection`` through
:class:`bakery.encodings.base.Encoding`; every violation raises :class:`bakery.errors.EvaluationError`, a ValueError,
naming the argument)
    view, normal  (N, 3), or (3,) for one row; the same N; finite and of non-zero length; normalised here
                  (directions: a length other than 1 is ignored, as a shader's normalize() would; scaled by the
                  largest component first, so that no finite input overflows).
    alpha         one value (a scalar or shape (1,)) for every row, or (N,) one per row.
    f0            one value (a scalar or (1,)) for every row, (N,) one scalar F0 per row, (N, 3) one RGB F0 per row or
                  (1, 3) one RGB F0 for every row; finite and in [0, 1]. A 1-D f0 is always per-row scalar F0: an RGB
                  F0 is 2-D (a (3,) f0 is valid only for N = 3 rows, as three scalar F0).

α (GGX roughness, α = perceptual²)
    Must be finite and in [0, 1]; anything else raises ValueError naming the argument (``alpha``). Each encoding
    then maps α into the range it stores (its own documented rule: clamp, or hand over to the chain), it never
    extrapolates.

View below or on the horizon (n·v ≤ 0)
    Engines clamp n·v to 0 rather than shade a back-facing view; we do the same, explicitly and without NaN:
        t  = v − (n·v)·n, projected twice (in floating point the first pass leaves a component along n comparable
             to t near v = −n), or t(n) if |t| < 1e-9 |v| (v = −n; a fixed tangent, :func:`fixed_tangent`);
             n is normalised first (float32-unit normals have |n|² ≠ 1)
        v' = normalize(normalize(t) + ε·n),  ε = HORIZON_EPSILON = 1e-6            if n·v ≤ 0
    i.e. v turned onto the tangent plane, a hair above it so that every BRDF term takes its n·v → 0⁺ limit (the same
    value for a view that is already clamped). r = 2(n·v')n − v' lies on the horizon, n·r ≥ 0 and h_r =
    normalize(n + r) has |n + r| ≥ 1 (defined for every input, also n·v = −1). The DFG/Fresnel tables are read at
    n·v ≈ 0. E at n·v ≤ 0 therefore equals E at the horizon view v' (continuous at n·v = 0).

Notation: M rows (N in the argument rules and messages); view v (M, 3) points towards the viewer, normal n (M, 3) unit.
"""

from __future__ import annotations

import numpy as np

from bakery.errors import EvaluationError

#: Height above the horizon of a clamped view (module doc).
HORIZON_EPSILON = 1e-6


def _numbers(value: object, name: str) -> np.ndarray:
    """``value`` as a float64 array, or EvaluationError naming ``name`` (strings, ragged lists, None, …)."""
    try:
        if value is None:  # numpy would make it NaN
            raise TypeError
        if np.asarray(value).dtype.kind not in "iuf":  # complex (numpy drops the imaginary part), bool, object
            raise TypeError
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        shown = repr(value)
        shown = shown if len(shown) <= 60 else shown[:57] + "..."
        raise EvaluationError(f"{name} must be numbers, got {shown} ({type(value).__name__})") from None


def check_directions(value: object, name: str) -> np.ndarray:
    """(N, 3) float64 unit directions from (N, 3) or (3,) (one row): finite and of non-zero length, else
    EvaluationError naming ``name``; normalised (module doc)."""
    d = _numbers(value, name)
    if d.shape == (3,):
        d = d[None]
    elif d.ndim != 2 or d.shape[1] != 3:
        raise EvaluationError(f"{name} must have shape (N, 3) (or (3,) for one direction), got shape {d.shape}")
    finite = np.all(np.isfinite(d), axis=1)
    if not np.all(finite):
        row = int(np.flatnonzero(~finite)[0])
        raise EvaluationError(f"{name} must be finite, got {d[row].tolist()} in row {row} "
                              f"({int(np.count_nonzero(~finite))} of {len(d)} rows)")
    zero = ~np.any(d != 0.0, axis=1)
    if np.any(zero):
        row = int(np.flatnonzero(zero)[0])
        raise EvaluationError(f"{name} must have non-zero length, got {d[row].tolist()} in row {row} "
                              f"({int(np.count_nonzero(zero))} of {len(d)} rows)")
    d = d / np.max(np.abs(d), axis=1, keepdims=True)  # largest component ±1: |d|² cannot overflow or underflow
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def check_alpha(alpha: np.ndarray, name: str = "alpha") -> np.ndarray:
    """α as float64 (...), or ValueError (:class:`~bakery.errors.EvaluationError`) "<name> must be finite and in
    [0, 1] (GGX α) …" naming the first bad value."""
    a = _numbers(alpha, name)
    bad = ~(np.isfinite(a) & (a >= 0.0) & (a <= 1.0))
    if np.any(bad):
        first = float(a.reshape(-1)[int(np.flatnonzero(bad.reshape(-1))[0])])
        raise EvaluationError(f"{name} must be finite and in [0, 1] (GGX alpha), got {first!r} "
                              f"({int(np.count_nonzero(bad))} of {a.size} values out of range)")
    return a


def check_f0(f0: object, rows: int) -> np.ndarray:
    """F0 as float64 (rows,) (scalar F0 per row) or (rows, 3) (RGB F0 per row), from a scalar, (1,), (rows,),
    (1, 3) or (rows, 3); finite and in [0, 1]. Anything else raises EvaluationError naming ``f0``."""
    f = _numbers(f0, "f0")
    if f.ndim == 0 or f.shape == (1,):
        f = np.broadcast_to(f.reshape(1), (rows,))
    elif f.ndim == 2 and f.shape[1] == 3 and f.shape[0] in (1, rows):
        f = np.broadcast_to(f, (rows, 3))
    elif f.shape != (rows,):
        hint = "; a 1-D f0 is one scalar F0 per row: give one RGB F0 as shape (1, 3)" if f.shape == (3,) else ""
        raise EvaluationError(f"f0 must be one value (a scalar or (1,)), (N,) scalar F0 per row, (N, 3) RGB F0 per "
                              f"row or (1, 3) one RGB F0, with N = {rows} rows; got shape {f.shape}{hint}")
    bad = ~(np.isfinite(f) & (f >= 0.0) & (f <= 1.0))
    if np.any(bad):
        first = float(f.reshape(-1)[int(np.flatnonzero(bad.reshape(-1))[0])])
        raise EvaluationError(f"f0 must be finite and in [0, 1] (reflectance at normal incidence), got {first!r} "
                              f"({int(np.count_nonzero(bad))} of {f.size} values out of range)")
    return np.array(f)


def check_rows(view: np.ndarray, normal: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(v (M, 3), n (M, 3), α (M,)) float64: view and normal (M, 3) or (3,), the same M, finite, of non-zero length
    (:func:`check_directions`); α checked (:func:`check_alpha`), one value or one per row, broadcast to the rows.
    EvaluationError (a ValueError) naming the argument otherwise."""
    v = check_directions(view, "view")
    n = check_directions(normal, "normal")
    if v.shape != n.shape:
        raise EvaluationError(f"view and normal must have the same number of rows, got view {v.shape} and "
                              f"normal {n.shape}")
    a = check_alpha(alpha)
    if a.ndim > 1 or a.size not in (1, v.shape[0]):
        raise EvaluationError(f"alpha must be one value or one per row ({v.shape[0]},), got shape {a.shape}")
    return v, n, np.broadcast_to(a.reshape(-1), (v.shape[0],)).copy()


def check_reflection_inputs(view: object, normal: object, alpha: object, f0: object,
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every argument of a reflection evaluation checked (module doc, "Arguments") and brought to its row form:
    (v (N, 3), n (N, 3), α (N,), F0 (N,) or (N, 3)) float64. EvaluationError naming the argument otherwise."""
    v, n, a = check_rows(view, normal, alpha)
    return v, n, a, check_f0(f0, v.shape[0])


def fixed_tangent(normal: np.ndarray) -> np.ndarray:
    """A unit tangent (M, 3) of each unit normal (M, 3): normalize(e × n) with e = +X, or +Z where |n_x| > 0.9."""
    n = np.asarray(normal, dtype=np.float64)
    e = np.where(np.abs(n[:, :1]) > 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    t = np.cross(e, n)
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def clamp_view_to_horizon(view: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Views (M, 3) with n·v ≤ 0 turned onto the horizon (module doc); others unchanged."""
    v = np.asarray(view, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)  # float32-unit normals: |n|² ≠ 1
    nv = np.sum(v * n, axis=1, keepdims=True)
    below = nv[:, 0] <= 0.0  # n·v = 0 too: on the horizon the lights' visibility is 0, their limit is not
    if not np.any(below):
        return v
    out = v.copy()
    tangent = v[below] - nv[below] * n[below]
    # Project twice: near v = −n the first pass leaves a component along n comparable to the (tiny) tangent.
    tangent -= np.sum(tangent * n[below], axis=1, keepdims=True) * n[below]
    length = np.linalg.norm(tangent, axis=1, keepdims=True)
    degenerate = length[:, 0] < 1e-9 * np.linalg.norm(v[below], axis=1)  # v = −n up to rounding: no tangent
    safe = np.where(degenerate[:, None], fixed_tangent(n[below]), tangent / np.maximum(length, 1e-300))
    safe = safe + HORIZON_EPSILON * n[below]
    out[below] = safe / np.linalg.norm(safe, axis=1, keepdims=True)
    return out
