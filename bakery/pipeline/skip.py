"""Skipping what a scene does not need: SH bands with no energy (seed 003 §5.1, seed 002 §4.4).

Required band (frequency-space order selection, [RH01b] Ramamoorthi & Hanrahan 2002, seed 003 §5.1)
    The irradiance of probe p has SH energy e_l = Σ_m Σ_rgb (A_l f_lm)² per band (Parseval: ∫E² dω = Σ_l e_l).
    An order-L expansion keeps 1 − ε of the energy when Σ_{l>L} e_l ≤ ε Σ_l e_l; the required band is the smallest
    such L (0, 1 or 2 for the bands bakery stores). ε is the recipe's ``band_energy_tolerance``.

Neighbour refinement (seed 002, Sec. 4.4 "Refining the ROIs")
    A probe that needs band L makes its spatial neighbours need at least L too (one breadth-first ring; neighbours
    are probes within 1.5× the median nearest-neighbour spacing), so that a band does not switch on and off
    between adjacent probes and interpolated lighting does not pop.

Encoding skips
    An irradiance encoding whose stored information reaches band 2 (``Encoding.max_band == 2``,
    :func:`band2_encodings`) is skipped when no probe requires band 2: linear SH then carries all but ε of every
    probe's irradiance energy.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from bakery.encodings import ENCODINGS
from bakery.sh.convolution import cosine_lobe_band_factors


def band2_encodings() -> tuple[str, ...]:
    """Irradiance encodings whose stored content beyond linear SH is band 2 (skipped when no probe needs it)."""
    return tuple(n for n, e in ENCODINGS.items() if e.kind == "irradiance" and e.max_band == 2)


def irradiance_band_energy(radiance_sh: np.ndarray) -> np.ndarray:
    """Per-band irradiance energy (P, 3) of radiance SH (P, 9, C): e_l = Σ_m Σ_c (A_l f_lm)²."""
    a = cosine_lobe_band_factors(2)
    energy = np.stack([np.sum((a[l] * radiance_sh[:, l * l : (l + 1) ** 2]) ** 2, axis=(1, 2)) for l in range(3)],
                      axis=-1)
    return energy


def required_bands(band_energy: np.ndarray, tolerance: float) -> np.ndarray:
    """Smallest L (P,) with Σ_{l>L} e_l ≤ tolerance · Σ_l e_l (black probes need band 0)."""
    total = band_energy.sum(axis=1)
    residual = total[:, None] - np.cumsum(band_energy, axis=1)  # energy above band L, L = 0, 1, 2
    ok = residual <= tolerance * total[:, None]
    return np.argmax(ok, axis=1).astype(np.int32)


def dilate_over_neighbours(required: np.ndarray, positions: np.ndarray, spacing_factor: float = 1.5) -> np.ndarray:
    """One ring of neighbour refinement: each probe takes the maximum requirement of itself and its neighbours."""
    positions = np.asarray(positions, dtype=np.float64)
    if len(required) < 2:
        return required.copy()
    tree = cKDTree(positions)
    distances, _ = tree.query(positions, k=2)
    nearest = distances[:, 1]
    positive = nearest[nearest > 0]
    if positive.size == 0:  # all probes coincide: they are one another's neighbours
        return np.full_like(required, required.max())
    radius = spacing_factor * float(np.median(positive))
    out = required.copy()
    for i, neighbours in enumerate(tree.query_ball_point(positions, r=radius)):
        out[i] = max(out[i], int(required[neighbours].max()))
    return out


def band_skip_decisions(
    band_energy: np.ndarray, positions: np.ndarray, tolerance: float, encodings: list[str]
) -> tuple[np.ndarray, list[dict[str, str]]]:
    """(required band per probe after refinement, skipped encodings with their reasons)."""
    required = dilate_over_neighbours(required_bands(band_energy, tolerance), positions)
    skipped = []
    if len(required) and int(required.max()) < 2:
        band2 = band2_encodings()
        for name in encodings:
            if name in band2:
                skipped.append({"encoding": name, "reason": f"band 2 carries less than {tolerance:g} of the irradiance "
                                                            f"energy of every probe (seed 003 §5.1); linear SH suffices"})
    return required, skipped
