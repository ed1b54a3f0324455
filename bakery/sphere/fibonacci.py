"""Spherical Fibonacci point sets: near-uniform direction sets with equal weights 4π/N."""

from __future__ import annotations

import numpy as np

GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def fibonacci_directions(count: int) -> np.ndarray:
    """``count`` near-uniform unit directions (count, 3) (Marques et al. 2013, spherical Fibonacci points).

    Deterministic; each point stands for a solid angle of 4π/count.
    """
    if count < 1:
        raise ValueError(f"fibonacci_directions needs count >= 1, got {count}")
    k = np.arange(count, dtype=np.float64)
    z = 1.0 - (2.0 * k + 1.0) / count
    radius = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = GOLDEN_ANGLE * k
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), z], axis=-1)
