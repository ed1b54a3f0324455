"""Projection of radiance onto SH as one matrix product per batch of probes (method notes §4).

L_lm = Σ_t Y_lm(ω_t) Ω_t L(ω_t), i.e. coefficients = (Y ⊙ Ω)ᵀ · L for a fixed grid: the weighted basis is built
once per grid and band limit and reused for every probe.
"""

from __future__ import annotations

import numpy as np

from bakery.sh.basis import evaluate_sh_basis


class SHProjector:
    """Projects radiance sampled on one fixed grid onto SH bands 0..L.

    Args:
        directions: (T, 3) texel directions of the grid.
        solid_angles: (T,) texel solid angles.
        max_band: L.
    """

    def __init__(self, directions: np.ndarray, solid_angles: np.ndarray, max_band: int) -> None:
        self.max_band = max_band
        #: (T, K) basis weighted by solid angle.
        self.weighted_basis = evaluate_sh_basis(directions, max_band) * np.asarray(solid_angles)[:, None]

    def project(self, radiance: np.ndarray) -> np.ndarray:
        """Radiance (P, T, C) or (T, C) → radiance SH (P, K, C) or (K, C)."""
        r = np.asarray(radiance, dtype=np.float64)
        return np.einsum("tk,...tc->...kc", self.weighted_basis, r, optimize=True)


def project_radiance_sh(
    directions: np.ndarray, solid_angles: np.ndarray, radiance: np.ndarray, max_band: int
) -> np.ndarray:
    """One-off projection (see :class:`SHProjector`): radiance (..., T, C) → (..., (L+1)², C)."""
    return SHProjector(directions, solid_angles, max_band).project(radiance)
