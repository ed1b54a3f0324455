"""The roughness range a reflection probe needs (issue 5: skip what a scene does not need).

An SH-exponential fit covers a design range of GGX α (paper: [0.2, 1]). A probe only ever shades the materials
inside its influence volume, so its fit can spend all its design samples on their range instead, and the hybrid
encoding (``shexp_hybrid``) stores only the sharp chain levels down to their smallest α: the
probe's range is [r_lo², r_hi²] where r are the perceptual roughnesses (UsdPreviewSurface ``roughness``) of the
materials whose geometry intersects the influence volume, bucketed outwards to steps of 0.1 in r (so a scene needs
few distinct fit operators, which are cached per range), widened to at least one step, in α ∈ [0, 1]. This is the
*true* range, down to α = 0 for a mirror: each encoding applies its own floor (SH-exp fits from its
``FIT_ALPHA_FLOOR`` = 0.05, :mod:`bakery.encodings.shexp`; the hybrid keeps chain levels down to α = 0). Geometry counts as inside when a triangle's bounding sphere meets the influence volume's
bounding sphere (radius for spheres, the box's |extent| for boxes: conservative — it may include more materials,
never fewer). A probe with no geometry in range keeps the encoding's default range.

Evaluation does not depend on the design range (the stored coefficients are evaluated at any α), so the stored
layout is unchanged; the range used is recorded per probe in ``diagnostics/fit_alpha_range``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STEP = 0.1


def influence_radius(influence: dict) -> float:
    if influence.get("shape") == "box":
        return float(np.linalg.norm(np.asarray(influence.get("extent_m", [0.0, 0.0, 0.0]), dtype=np.float64)))
    return float(influence.get("radius_m", 0.0))


@dataclass(frozen=True)
class TriangleBounds:
    """Bounding spheres of a scene's triangles, computed once for every probe's roughness query.

    Attributes:
        centres: (T, 3) float64 triangle centroids (bake frame, metres).
        spans: (T,) float64 largest centroid-to-vertex distance of each triangle.
        mesh: (T,) int index of the triangle's mesh.
        roughness: (M,) float64 perceptual roughness of each mesh's material.
    """

    centres: np.ndarray
    spans: np.ndarray
    mesh: np.ndarray
    roughness: np.ndarray

    @classmethod
    def of(cls, meshes) -> TriangleBounds:  # noqa: ANN001 - capture dataclasses
        centres, spans, owner = [], [], []
        for index, mesh in enumerate(meshes):
            triangles = np.asarray(mesh.triangles, dtype=np.float64).reshape(-1, 3, 3)
            mid = triangles.mean(axis=1)
            centres.append(mid)
            spans.append(np.linalg.norm(triangles - mid[:, None, :], axis=2).max(axis=1, initial=0.0))
            owner.append(np.full(len(mid), index, dtype=np.int64))
        roughness = np.array([float(mesh.material.roughness) for mesh in meshes], dtype=np.float64)
        if not centres:
            return cls(np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64), roughness)
        return cls(np.concatenate(centres), np.concatenate(spans), np.concatenate(owner), roughness)


def visible_roughness(position, influence: dict, meshes) -> list[float]:  # noqa: ANN001 - capture dataclasses
    """Perceptual roughness of every material (in mesh order) with a triangle inside the influence bound of a probe
    at ``position``. ``meshes``: the scene's meshes or their :class:`TriangleBounds` (once for many probes)."""
    bounds = meshes if isinstance(meshes, TriangleBounds) else TriangleBounds.of(meshes)
    radius = influence_radius(influence)
    p = np.asarray(position, dtype=np.float64)
    inside = np.linalg.norm(bounds.centres - p, axis=1) <= radius + bounds.spans
    return [float(bounds.roughness[m]) for m in np.unique(bounds.mesh[inside]).tolist()]


def fit_alpha_range(roughness: list[float]) -> tuple[float, float] | None:
    """Bucketed GGX α range [r_lo², r_hi²] ⊂ [0, 1] for the given perceptual roughnesses (module docstring), or
    None; r_lo may be 0 (a mirror in range)."""
    if not roughness:
        return None
    r = np.clip(np.asarray(roughness, dtype=np.float64), 0.0, 1.0)
    lo = _bucket_down(r.min())
    hi = np.ceil(r.max() / STEP - 1e-9) * STEP
    if hi - lo < STEP:
        lo, hi = (hi - STEP, hi) if hi >= STEP else (0.0, STEP)
    return float(round(lo * lo, 6)), float(round(hi * hi, 6))


#: Buckets per octave of α for :func:`smallest_nonzero_alpha` (2^(1/4): never more than 19 % below the true α).
NONZERO_ALPHA_BUCKETS_PER_OCTAVE = 4


def smallest_nonzero_alpha(roughness: list[float]) -> float | None:
    """GGX α of the smallest perceptual roughness above 0 among ``roughness``, bucketed down (never above the true
    α), or None when every material is a mirror (or none is given). With a mirror in range it tells the hybrid which
    of its gap levels (α_1/2, α_1/4, … : octaves) any material reads (``shexp_hybrid`` ``alpha_min_nonzero``), so the
    bucket is the finer of the range's (r rounded down to 0.1, squared: 0.04 for r = 0.25; 0 below r = 0.1) and a
    quarter octave of α (α = 0.0225 for r = 0.15 → 0.0221, where the range's bucket gives 0.01)."""
    r = np.clip(np.asarray(roughness, dtype=np.float64), 0.0, 1.0)
    r = r[r > 0.0]
    if r.size == 0:
        return None
    alpha = float(r.min()) ** 2
    by_roughness = round(_bucket_down(float(r.min())) ** 2, 6)  # the range's lower end
    if alpha < 1e-6:  # below the 6 decimals kept (r < 0.001)
        return by_roughness
    steps = np.floor(NONZERO_ALPHA_BUCKETS_PER_OCTAVE * np.log2(alpha) + 1e-9)
    by_octave = np.floor(min(2.0 ** (steps / NONZERO_ALPHA_BUCKETS_PER_OCTAVE), alpha) * 1e6) / 1e6  # rounded down
    return float(max(by_roughness, by_octave))


def _bucket_down(roughness: float) -> float:
    """The perceptual roughness rounded down to a multiple of :data:`STEP`."""
    return float(np.floor(roughness / STEP + 1e-9) * STEP)
