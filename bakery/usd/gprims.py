"""Triangles of the UsdGeom implicit surfaces (pure numpy; :mod:`bakery.usd.scene` reads their attributes).

Each function returns local-space triangles (T, 3, 3) float64 of the gprim as UsdGeom defines it: centred at the
origin, with its spine (Cylinder, Cone, Capsule) or normal (Plane) along ``axis`` ("X", "Y" or "Z"):

=============  ======================================================================================================
Sphere         radius r (UV sphere, ``rings`` × ``segments``)
Cube           edge ``size``
Cylinder       radius r (``Cylinder_1``: radiusBottom at −h/2, radiusTop at +h/2), height h, both caps closed
Cone           base radius r at −h/2, apex at +h/2 (UsdGeomCone: "the apex pointing in the direction of the positive
               axis"), base closed
Capsule        a cylinder of radius r and height h (the caps excluded, UsdGeomCapsule) with a hemisphere of radius
               r centred on each end (``Capsule_1`` with radiusBottom ≠ radiusTop: hemispheres of each radius joined by
               the frustum between their equators, which is the capsule's shape only when the radii are equal)
Plane          ``width`` × ``length`` rectangle: axis X → width along z, length along y; Y → x, z; Z → x, y
               (UsdGeomPlane's table); two triangles (the capture shades both sides of every triangle)
=============  ======================================================================================================

Round surfaces use :data:`SEGMENTS` (24) facets around the spine, as :func:`uv_sphere`: vertices on the surface,
enclosed volumes 1.1 % (inscribed 24-gon) to 1.8 % (capsule caps) below the closed forms. The surfaces of revolution
are watertight (every edge shared by exactly two triangles, the seam closing on the same vertices) and wound
counter-clockwise seen from outside; tests/usd/test_gprims.py checks both, and the extents against USD's own.
"""

from __future__ import annotations

import numpy as np

#: Facets around a round gprim's spine, and latitude rings of a sphere (a hemisphere gets half).
SEGMENTS = 24
RINGS = 12


def uv_sphere(radius: float, rings: int = RINGS, segments: int = SEGMENTS) -> np.ndarray:
    """Sphere of ``radius`` (poles on ±Y; the triangles at the poles are degenerate)."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    v = radius * np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1)
    a, b, c, d = v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])


def cube(size: float) -> np.ndarray:
    """Axis-aligned cube of edge ``size``."""
    h = 0.5 * size
    corners = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)], dtype=np.float64)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
    return corners[np.array(tris)]


def cylinder(radius_bottom: float, radius_top: float, height: float, axis: str = "Z",
             segments: int = SEGMENTS) -> np.ndarray:
    """Closed cylinder (or frustum) about ``axis``: profile (radius, height) from the bottom centre up."""
    h = 0.5 * height
    profile = np.array([[0.0, -h], [radius_bottom, -h], [radius_top, h], [0.0, h]])
    return _lathe(profile, segments, axis)


def cone(radius: float, height: float, axis: str = "Z", segments: int = SEGMENTS) -> np.ndarray:
    """Cone about ``axis``, base of ``radius`` at −height/2, apex at +height/2."""
    h = 0.5 * height
    return _lathe(np.array([[0.0, -h], [radius, -h], [0.0, h]]), segments, axis)


def capsule(radius_bottom: float, radius_top: float, height: float, axis: str = "Z", rings: int = RINGS,
            segments: int = SEGMENTS) -> np.ndarray:
    """Capsule about ``axis``: hemispheres centred at ∓height/2 joined by the side between their equators."""
    h = 0.5 * height
    bottom = _sphere_profile(radius_bottom, -h, np.pi, 0.5 * np.pi, rings // 2)  # south pole → equator
    top = _sphere_profile(radius_top, h, 0.5 * np.pi, 0.0, rings // 2)  # equator → north pole
    return _lathe(np.concatenate([bottom, top]), segments, axis)


def plane(width: float, length: float, axis: str = "Z") -> np.ndarray:
    """Rectangle ``width`` × ``length`` with its normal along ``axis`` (UsdGeomPlane's width/length axes)."""
    w, ln = 0.5 * width, 0.5 * length
    along = {"X": (2, 1), "Y": (0, 2), "Z": (0, 1)}[_checked(axis)]  # (width axis, length axis)
    corners = np.zeros((4, 3))
    corners[:, along[0]] = (-w, w, w, -w)
    corners[:, along[1]] = (-ln, -ln, ln, ln)
    return corners[np.array([(0, 1, 2), (0, 2, 3)])]


def _sphere_profile(radius: float, centre: float, polar_from: float, polar_to: float, steps: int) -> np.ndarray:
    """(steps + 1, 2) points (distance from the spine, height) of a meridian arc from polar angle ``polar_from``
    to ``polar_to`` (0 = +spine) of a sphere of ``radius`` centred at ``centre`` on the spine."""
    polar = np.linspace(polar_from, polar_to, steps + 1)
    sin, cos = np.sin(polar), np.cos(polar)
    sin[np.abs(sin) < 1e-12], cos[np.abs(cos) < 1e-12] = 0.0, 0.0  # poles exactly on the spine, equators level
    return np.stack([radius * sin, centre + radius * cos], axis=-1)


def _lathe(profile: np.ndarray, segments: int, axis: str) -> np.ndarray:
    """Surface of revolution of a profile (K, 2) = (distance from the spine ≥ 0, height along it) about ``axis``:
    one quad (two triangles) per profile edge and segment; degenerate triangles (on the spine) are dropped."""
    phi = 2.0 * np.pi * np.arange(segments) / segments
    radius, height = profile[:, 0:1], profile[:, 1:2]
    # spine along +Z, then a cyclic permutation (a rotation) onto the gprim's axis
    ring = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.broadcast_to(height, (len(profile), phi.size))],
                    axis=-1)
    ring = ring[:, np.r_[0:segments, 0]]  # (K, S + 1, 3): the seam closes on the same vertices (watertight)
    a, b, c, d = ring[:-1, :-1], ring[1:, :-1], ring[1:, 1:], ring[:-1, 1:]
    tris = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=-1)
    tris = tris[area2 > 1e-12 * max(1.0, float(np.abs(profile).max()) ** 2)]
    order = {"Z": (0, 1, 2), "X": (2, 0, 1), "Y": (1, 2, 0)}[_checked(axis)]  # (x, y, z) ← (…)
    return tris[:, ::-1][..., order]  # counter-clockwise seen from outside (USD's rightHanded orientation)


def _checked(axis: str) -> str:
    if axis not in ("X", "Y", "Z"):
        raise ValueError(f"axis must be X, Y or Z, got {axis!r}")
    return axis
