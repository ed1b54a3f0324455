"""Deringing ZH3 to non-negative irradiance ([ZH3] App. B) with windowing where the axes diverge [Sloan 2017].

References
    [ZH3]   Roughton et al. 2024, App. B (Eq. 22–26).
    [S08]   P.-P. Sloan, "Stupid Spherical Harmonics (SH) Tricks", GDC 2008: window w_l = 1 / (1 + λ l²(l+1)²).
    [S17]   P.-P. Sloan, "Deringing Spherical Harmonics", SIGGRAPH Asia 2017 Technical Briefs.

Derivation (bounds on f2^0, aligned axes)
    Eq. 23 with a = 2 f1^0/(√3 f0), b = √5 f2^0/(8 f0) and Eq. 25 ((a−1)/2 ≤ b ≤ √5/4) give
        (8/√15) f1^0 − (4/√5) f0 ≤ f2^0 ≤ 2 f0.
    (The printed Eq. 26 has 2√15/3 for the f1 coefficient; substituting a and b into Eq. 25 gives 8/√15 = 8√15/15.)
    The bound is exact only when the channel's linear axis equals the shared zonal axis and a ≤ √3. bakery
    therefore (1) clamps f2^0 per channel with f1^0 = v_c·a, then (2) checks the *exact* minimum of each channel's
    irradiance over the sphere (:func:`bakery.irradiance.sh_irradiance.minimum_on_sphere`) and, where it is still
    negative (diverging axes, a > √3), (3) applies the smallest uniform window to bands 1–2 that makes it
    non-negative ([S17] deringing by windowing; a uniform window keeps the ratio of L2 to L1, which measured closer
    to the reference than [S08]'s w_l = 1/(1 + λ l²(l+1)²) on sun-dominated maps: `park` relative RMSE 0.27 with
    [S08] against the figures in docs/irradiance.md). s → 0 leaves only DC, which is ≥ 0 for f0 ≥ 0.
"""

from __future__ import annotations

from math import pi, sqrt

import numpy as np

from bakery.irradiance.sh_irradiance import minimum_sh_irradiance
from bakery.irradiance.zh3 import expand_zh3_to_sh3, linear_band_vector, luminance_axis

#: Relative safety margin: the deringed minimum is ≥ MARGIN · f0 (absorbs float32 storage rounding).
MARGIN = 1e-5


def clamp_zonal_l2(linear_sh: np.ndarray, zonal_l2: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Clamp f2^0 (P, C) into the App. B interval computed with f1^0 = v_c·a (see module derivation)."""
    f0 = linear_sh[:, 0]
    f1_axis = np.einsum("pj,pjc->pc", axis, linear_band_vector(linear_sh))
    lower = (8.0 / sqrt(15.0)) * f1_axis - (4.0 / sqrt(5.0)) * f0
    upper = 2.0 * f0
    return np.where(lower <= upper, np.clip(zonal_l2, lower, upper), upper)


def dering_zh3(
    linear_sh: np.ndarray, zonal_l2: np.ndarray, margin: float = MARGIN
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Non-negative-irradiance ZH3 (linear SH (P, 4, C), f2^0 (P, C)) on the luminance axis.

    Steps (module derivation): App. B clamp of f2^0 per channel; then, for probes whose exact minimum is still
    below the floor, the smallest uniform window s ∈ [0, 1] on bands 1–2. Irradiance is affine in s,
    E_s(n) = c_DC + s·h(n), so s = min_c (c_DC,c − floor_c) / (−min_n h_c(n)) in closed form (exact minimum via the
    trust-region solution). One s per probe keeps the luminance axis, which readers recompute, unchanged.
    ``margin``: the minimum is made ≥ margin·f0 (relative floor). Returns the deringed ZH3 and counts {"clamped": channels changed by the clamp, "windowed": probes scaled}.
    """
    linear = np.asarray(linear_sh, dtype=np.float64).copy()
    axis = luminance_axis(linear)
    zonal = clamp_zonal_l2(linear, zonal_l2, axis)
    clamped = int(np.sum(zonal != zonal_l2))
    f0 = np.maximum(linear[:, 0], 0.0)
    floor = margin * f0
    dc_irradiance = pi * f0 / (2.0 * sqrt(pi))  # A_0 f0 Y00
    higher = expand_zh3_to_sh3(linear, zonal, axis)
    higher[:, 0] = 0.0
    min_higher = minimum_sh_irradiance(higher)  # (P, C): min_n h(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale_c = np.where(
            dc_irradiance + min_higher < floor, (dc_irradiance - floor) / np.maximum(-min_higher, 1e-300), 1.0
        )
    scale = np.clip(np.min(scale_c, axis=-1), 0.0, 1.0)
    # Guard against rounding: shrink by a further 1e-9 relative where a window was applied.
    windowed = scale < 1.0
    scale = np.where(windowed, scale * (1.0 - 1e-9), 1.0)
    linear[:, 1:4] *= scale[:, None, None]
    return linear, zonal * scale[:, None], {"clamped": clamped, "windowed": int(windowed.sum())}
