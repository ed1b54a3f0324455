"""Exact reference irradiance: brute-force cosine convolution of a full-resolution quadrature.

E(n) = Σ_t L(ω_t) max(0, n·ω_t) Ω_t, evaluated as chunked matrix products (N × T cosine kernel times T × C
radiance·Ω). Independent of SH: it is the ground truth every irradiance encoding is measured against.
"""

from __future__ import annotations

import numpy as np

from bakery.sphere.grid import SphericalSamples


def reference_irradiance(
    samples: SphericalSamples, normals: np.ndarray, chunk_elements: int = 1 << 24, dtype: type = np.float64
) -> np.ndarray:
    """Irradiance (N, C) at unit normals (N, 3) by brute-force integration over ``samples``.

    ``dtype=np.float32`` halves the time for diagnostics (relative rounding ~√T·2⁻²⁴); tests use float64.
    """
    weighted = (samples.radiance * samples.solid_angles[:, None]).astype(dtype)  # (T, C) = L·Ω
    directions = samples.directions.T.astype(dtype)  # (3, T)
    normals = np.asarray(normals, dtype=dtype)
    out = np.zeros((normals.shape[0], weighted.shape[1]), dtype=np.float64)
    rows = max(1, chunk_elements // max(1, directions.shape[1]))
    for start in range(0, normals.shape[0], rows):
        cosine = normals[start : start + rows] @ directions
        np.maximum(cosine, 0.0, out=cosine)
        out[start : start + rows] = cosine @ weighted
    return out


def relative_rmse(estimate: np.ndarray, reference: np.ndarray) -> float:
    """√(Σ (E − E_ref)²) / √(Σ E_ref²) over all directions and channels (uniformly weighted directions)."""
    denominator = np.sqrt(np.sum(reference**2))
    return float(np.sqrt(np.sum((estimate - reference) ** 2)) / denominator) if denominator > 0 else 0.0
