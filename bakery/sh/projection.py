"""Projection of radiance onto SH as one fixed matrix product per probe (method notes §4).

L_lm = Σ_t Y_lm(ω_t) Ω_t L(ω_t), i.e. coefficients = (Y ⊙ Ω)ᵀ · L for a fixed grid: the weighted basis is built
once per grid and band limit and reused for every probe.
"""

from __future__ import annotations

import numpy as np

from bakery.sh.basis import evaluate_sh_basis
from bakery.sphere.cubemap import direction_to_cube_texel


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
        self._basis_t = np.ascontiguousarray(self.weighted_basis.T)  # (K, T)

    def project(self, radiance: np.ndarray) -> np.ndarray:
        """Radiance (P, T, C) or (T, C) → radiance SH (P, K, C) or (K, C).

        One (K, T)·(T, C) product per probe, not one for the batch: a batch-wide GEMM's blocking depends on the
        number of probes, and with it the last bits of every coefficient, which a nonlinear encoding (the ZH3 axis
        solve) can carry into its float32 output — a probe's SH must not depend on what it is batched with."""
        r = np.asarray(radiance, dtype=np.float64)
        if r.ndim == 2:
            return self._basis_t @ r
        lead = r.shape[:-2]
        flat = r.reshape((-1,) + r.shape[-2:])
        out = np.empty((flat.shape[0], self._basis_t.shape[0], flat.shape[-1]))
        for i, probe in enumerate(flat):
            np.matmul(self._basis_t, probe, out=out[i])
        return out.reshape(lead + out.shape[1:])


def project_radiance_sh(
    directions: np.ndarray, solid_angles: np.ndarray, radiance: np.ndarray, max_band: int
) -> np.ndarray:
    """One-off projection (see :class:`SHProjector`): radiance (..., T, C) → (..., (L+1)², C)."""
    return SHProjector(directions, solid_angles, max_band).project(radiance)


# ---------------------------------------------------------------------------------------------------------------
# Cube maps: the projection through the cube's reflection symmetry (exact)
#
# The texel grid of a cube with an even face size is invariant under the eight axis reflections
# R_s: (x, y, z) → (±x, ±y, ±z), with equal solid angles, and every real SH has a definite parity under each axis
# reflection, Y_lm(R_s ω) = χ_lm(s) Y_lm(ω), χ_lm(s) = ±1. Grouping the texels into orbits of eight,
#     L_lm = Σ_t Y_lm(ω_t) Ω_t L(ω_t) = Σ_o Y_lm(ω_o) Ω_o Σ_s χ_lm(s) L(R_s ω_o),
# so the cube is first folded into eight parity classes (a Hadamard transform over each orbit) and each class is
# projected onto its SH with the basis at the T/8 representatives (x, y, z > 0): the same sums, 1/8 of the
# weighted basis (98304 × 841 float32 = 331 MB → 41 MB for a 128² cube at band 28) and 1/8 of its multiply-adds.

#: The eight axis reflections (8, 3), s = b_x + 2 b_y + 4 b_z with b = 1 where the axis flips.
AXIS_REFLECTIONS = np.array([[-1.0 if s & 1 else 1.0, -1.0 if s & 2 else 1.0, -1.0 if s & 4 else 1.0]
                             for s in range(8)])


def sh_reflection_parity(max_band: int) -> np.ndarray:
    """χ_lm(s) (8, (L+1)²) ±1: the sign of each real SH under each axis reflection (:data:`AXIS_REFLECTIONS`),
    read off the basis at generic directions (for each SH the one where it is largest; |Y(R_s ω)| = |Y(ω)| is
    checked to 1e-9 of it)."""
    rng = np.random.default_rng(12345)  # fixed generic directions, away from the symmetry planes
    directions = np.abs(rng.normal(size=(16, 3))) + 0.05
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    at = evaluate_sh_basis(directions, max_band)  # (16, K)
    best = np.argmax(np.abs(at), axis=0)  # (K,)
    reflected = evaluate_sh_basis((directions[best][None] * AXIS_REFLECTIONS[:, None, :]).reshape(-1, 3),
                                  max_band).reshape(8, best.size, -1)[:, np.arange(best.size), np.arange(best.size)]
    value = at[best, np.arange(best.size)]  # (K,)
    parity = np.sign(reflected * value[None])
    if not np.allclose(reflected, parity * value[None], rtol=0, atol=1e-9 * np.abs(value).min()):
        raise AssertionError("an SH basis function without a definite axis parity")
    return parity


class CubeSHProjector:
    """Projects cube maps (6, N, N, C), N even, onto SH bands 0..L through the reflection symmetry (comment
    above): ``project(cube) == (Y ⊙ Ω)ᵀ · cube`` over all 6N² texels, to float32 rounding.

    Attributes:
        orbits: (8, T/8) flat texel index of R_s ω_o, column o per representative (x, y, z > 0).
        hadamard: (8, 8) χ_k(s) of the eight parity classes k (k's bits: which reflections flip the sign).
        classes: per class k, the flat SH indices of that parity (ascending) and their weighted basis at the
            representatives, Y ⊙ Ω (T/8, K_k) float32.
    """

    def __init__(self, directions: np.ndarray, solid_angles: np.ndarray, max_band: int) -> None:
        directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        solid_angles = np.asarray(solid_angles, dtype=np.float64).reshape(-1)
        representatives = np.flatnonzero((directions > 0).all(axis=1))
        if representatives.size * 8 != directions.shape[0]:
            raise ValueError("the reflection-symmetric projection needs a cube with an even face size")
        reflected = directions[representatives][None] * AXIS_REFLECTIONS[:, None, :]  # (8, T/8, 3)
        n = int(round(np.sqrt(directions.shape[0] / 6)))
        face, row, col = direction_to_cube_texel(reflected, n)
        self.orbits = (face * n + row) * n + col  # (8, T/8) flat [face, row, column] index
        if not np.allclose(directions[self.orbits], reflected, atol=1e-9):
            raise ValueError("directions must be the texel centres of a cube (cube_texel_directions), in its order")
        # equal up to the rounding of their closed form (≤ 1e-9 relative, far below float32's)
        if not np.allclose(solid_angles[self.orbits], solid_angles[representatives][None], rtol=1e-9, atol=0):
            raise ValueError("texel solid angles are not reflection-symmetric")
        flips = (np.arange(8)[:, None] >> np.arange(3)) & 1  # (8, 3): the axes R_s flips (and the classes' odd axes)
        self.hadamard = (-1.0) ** (flips @ flips.T)  # χ_k(s) = (−1)^(number of axes flipped by s on which k is odd)
        parity = sh_reflection_parity(max_band)  # (8, K)
        class_of = (parity[[1, 2, 4]] < 0).astype(np.int64).T @ np.array([1, 2, 4])  # (K,) odd under x, y, z flips
        self.max_band = max_band
        self.classes = [(np.flatnonzero(class_of == k),
                         np.empty((representatives.size, int(np.sum(class_of == k))), dtype=np.float32))
                        for k in range(8)]
        for start in range(0, representatives.size, 2048):  # float64 basis in chunks: the peak is the float32 result
            rows = representatives[start : start + 2048]
            weighted = evaluate_sh_basis(directions[rows], max_band) * solid_angles[rows, None]
            for idx, basis in self.classes:
                basis[start : start + rows.size] = weighted[:, idx]
        for _, basis in self.classes:
            basis.setflags(write=False)

    def project(self, cube: np.ndarray) -> np.ndarray:
        """Cube (6, N, N, C) → radiance SH (K, C) float32."""
        flat = np.asarray(cube, dtype=np.float32).reshape(-1, np.shape(cube)[-1])
        gathered = flat[self.orbits]  # (8, T/8, C)
        folded = (self.hadamard.astype(np.float32) @ gathered.reshape(8, -1)).reshape(gathered.shape)  # per class
        out = np.empty((sum(idx.size for idx, _ in self.classes), flat.shape[1]), dtype=np.float32)
        for k, (idx, basis) in enumerate(self.classes):
            if idx.size:
                out[idx] = basis.T @ folded[k]
        return out

