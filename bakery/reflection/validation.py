"""Input rules shared by every reflection evaluation (``schemas/store-reflection.md`` "Evaluation inputs").

α (GGX roughness, α = perceptual²)
    Must be finite and in [0, 1]; anything else raises ValueError naming the argument (``alpha``). Each encoding
    then maps α into the range it stores (its own documented rule: clamp, or hand over to the chain), it never
    extrapolates.

View below the horizon (n·v < 0)
    Engines clamp n·v to 0 rather than shade a back-facing view; we do the same, explicitly and without NaN:
        t  = v − (n·v)·n, projected twice (in floating point the first pass leaves a component along n comparable
             to t near v = −n), or t(n) if |t| < 1e-9 |v| (v = −n; a fixed tangent, :func:`fixed_tangent`);
             n is normalised first (float32-unit normals have |n|² ≠ 1)
        v' = normalize(normalize(t) + ε·n),  ε = HORIZON_EPSILON = 1e-6            if n·v < 0
    i.e. v turned onto the tangent plane, a hair above it so that every BRDF term takes its n·v → 0⁺ limit (the same
    value for a view that is already clamped). r = 2(n·v')n − v' lies on the horizon, n·r ≥ 0 and h_r =
    normalize(n + r) has |n + r| ≥ 1 (defined for every input, also n·v = −1). The DFG/Fresnel tables are read at
    n·v ≈ 0. E at n·v < 0 therefore equals E at the horizon view v' (continuous at n·v = 0).

Notation: M rows; view v (M, 3) points towards the viewer, normal n (M, 3) unit.
"""

from __future__ import annotations

import numpy as np

#: Height above the horizon of a clamped view (module doc).
HORIZON_EPSILON = 1e-6


def check_alpha(alpha: np.ndarray, name: str = "alpha") -> np.ndarray:
    """α as float64 (...), or ValueError "<name> must be finite and in [0, 1] (GGX α) …" naming the first bad value."""
    a = np.asarray(alpha, dtype=np.float64)
    bad = ~(np.isfinite(a) & (a >= 0.0) & (a <= 1.0))
    if np.any(bad):
        first = float(a.reshape(-1)[int(np.flatnonzero(bad.reshape(-1))[0])])
        raise ValueError(f"{name} must be finite and in [0, 1] (GGX alpha), got {first!r} "
                         f"({int(np.count_nonzero(bad))} of {a.size} values out of range)")
    return a


def check_rows(view: np.ndarray, normal: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(v (M, 3), n (M, 3), α (M,)) float64 with α checked (:func:`check_alpha`) and broadcast to the rows; view and
    normal must be finite (ValueError naming ``view``/``normal``)."""
    v = np.asarray(view, dtype=np.float64).reshape(-1, 3)
    n = np.asarray(normal, dtype=np.float64).reshape(-1, 3)
    if v.shape != n.shape:
        raise ValueError(f"view {v.shape} and normal {n.shape} must both be (M, 3)")
    for label, x in (("view", v), ("normal", n)):
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{label} must be finite")
    a = check_alpha(alpha)
    if a.size not in (1, v.shape[0]):
        raise ValueError(f"alpha must have one value or one per row ({v.shape[0]}), got {a.size}")
    return v, n, np.broadcast_to(a.reshape(-1), (v.shape[0],)).copy()


def fixed_tangent(normal: np.ndarray) -> np.ndarray:
    """A unit tangent (M, 3) of each unit normal (M, 3): normalize(e × n) with e = +X, or +Z where |n_x| > 0.9."""
    n = np.asarray(normal, dtype=np.float64)
    e = np.where(np.abs(n[:, :1]) > 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    t = np.cross(e, n)
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def clamp_view_to_horizon(view: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Views (M, 3) with n·v < 0 turned onto the horizon (module doc); others unchanged."""
    v = np.asarray(view, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)  # float32-unit normals: |n|² ≠ 1
    nv = np.sum(v * n, axis=1, keepdims=True)
    below = nv[:, 0] < 0.0
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
