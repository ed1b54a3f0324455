"""Structure-of-arrays vector helpers of the capture's hot path.

The renderer keeps M vectors as one (3, M) array (x, y and z rows, each contiguous) in float32 (:data:`REAL`):
numpy's element-wise loops then run over M contiguous numbers. The (M, 3) layout makes every broadcast
``a[:, None] * v``, every ``v.max(axis=1)`` and every row mask run an inner loop of length 3, which on this code
cost 10–50× more per element.

Constants (light axes, centres) are used as Python floats so that float32 arrays stay float32 (NEP 50: a Python
scalar never widens an array; a ``np.float64`` scalar would). Dot products are written out component by component
rather than with ``@``/``einsum`` so every element is computed the same way wherever it sits in the array (BLAS
kernels may treat the ends of an array differently), which keeps captures bit-identical across batchings.
"""

from __future__ import annotations

import numpy as np

#: Float type of the renderer's per-ray arrays.
REAL = np.float32
#: Smallest positive guard used in divisions (representable in float32, unlike 1e-300).
TINY = 1e-30


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (3, ...) arrays."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def dotc(c: tuple[float, float, float], a: np.ndarray) -> np.ndarray:
    """Dot product of a constant vector (Python floats) with (3, ...) vectors."""
    return c[0] * a[0] + c[1] * a[1] + c[2] * a[2]


def const(v) -> tuple[float, float, float]:
    """A constant 3-vector as Python floats (see module docstring)."""
    return tuple(float(x) for x in np.asarray(v, dtype=np.float64).reshape(3))


def column(c: tuple[float, float, float], dtype=REAL) -> np.ndarray:
    """A constant vector as a (3, 1) array of ``dtype`` (broadcasts against (3, M))."""
    return np.asarray(c, dtype=dtype).reshape(3, 1)


def vmax(a: np.ndarray) -> np.ndarray:
    """Largest component of (3, ...) vectors."""
    return np.maximum(np.maximum(a[0], a[1]), a[2])


def luminance(a: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of (3, ...) colours (:data:`bakery.conventions.LUMINANCE_WEIGHTS`)."""
    return 0.2126 * a[0] + 0.7152 * a[1] + 0.0722 * a[2]


def normalize(a: np.ndarray) -> np.ndarray:
    return a / np.maximum(np.sqrt(dot(a, a)), TINY)


def frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent and bitangent (3, M) of unit normals (3, M): the branchless frame of Duff et al. 2017, as
    :func:`bakery.sphere.sampling.orthonormal_frame`."""
    x, y, z = n[0], n[1], n[2]
    s = (z >= 0).astype(n.dtype) * 2 - 1
    a = -1 / (s + z)
    b = x * y * a
    t = np.stack([1 + s * x * x * a, s * b, -s * x])
    bt = np.stack([b, s + y * y * a, -y])
    return t, bt


def cone(axis: np.ndarray, one_minus_cos_max: np.ndarray | float, u0: np.ndarray, u1: np.ndarray) -> np.ndarray:
    """Uniform directions (3, M) in cones around unit axes (3, M) with 1 − cos θmax; u0, u1 (M,) uniform."""
    omc = u0 * one_minus_cos_max
    cos_t = 1 - omc
    sin_t = np.sqrt(np.maximum(0, omc * (2 - omc)))
    phi = (2 * np.pi) * u1
    t, s = frame(axis)
    return (sin_t * np.cos(phi)) * t + (sin_t * np.sin(phi)) * s + cos_t * axis


def power(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Power-heuristic weight a²/(a² + b²) = 1/(1 + (b/a)²), as a ratio so float32 squares cannot overflow; 1 where
    b = 0 or a = ∞ (the other strategy cannot produce the sample), 0 where a = 0 < b."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        r = b / a
        w = 1 / (1 + r * r)
    return np.where(b > 0, w, 1).astype(a.dtype, copy=False)
