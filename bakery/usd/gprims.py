"""Triangles of the UsdGeom implicit surfaces (pure numpy; :mod:`bakery.usd.scene` reads their attributes).

Each function returns a :class:`Tessellation` — local-space triangles (T, 3, 3) float64 and, for the curved
surfaces, their exact unit normals at every corner (the capture interpolates them: a sphere is shaded smooth, as
Hydra draws it) — of the gprim as UsdGeom defines it: centred at the origin, with its spine (Cylinder, Cone,
Capsule) or normal (Plane) along ``axis`` ("X", "Y" or "Z"):

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
               (UsdGeomPlane's table); two triangles wound towards +axis (the capture shades both sides of every
               triangle; UsdGeomPlane is ``doubleSided`` by default)
=============  ======================================================================================================

Round surfaces use :data:`SEGMENTS` (24) facets around the spine, as :func:`uv_sphere`: vertices on the surface,
enclosed volumes 1.1 % (inscribed 24-gon) to 1.8 % (capsule caps) below the closed forms. The surfaces of revolution
are watertight (every edge shared by exactly two triangles, the seam closing on the same vertices) and, as the
sphere and the cube, wound counter-clockwise seen from outside (the winding tells a probe inside a gprim:
``Mesh.front``); tests/usd/test_gprims.py checks both, and the extents against USD's own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Facets around a round gprim's spine, and latitude rings of a sphere (a hemisphere gets half).
SEGMENTS = 24
RINGS = 12


@dataclass(frozen=True)
class Tessellation:
    """Triangles (T, 3, 3) float64 and unit shading normals per corner (T, 3, 3) float64, or None (flat faces)."""

    triangles: np.ndarray
    normals: np.ndarray | None = None


def uv_sphere(radius: float, rings: int = RINGS, segments: int = SEGMENTS) -> Tessellation:
    """Sphere of ``radius`` (poles on ±Y; the triangles at the poles are degenerate); normals p/r."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1)

    def corners(v: np.ndarray) -> np.ndarray:  # counter-clockwise seen from outside (a → d is +φ, a → b +θ)
        a, b, c, d = v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]
        return np.concatenate([np.stack([a, c, b], -2).reshape(-1, 3, 3), np.stack([a, d, c], -2).reshape(-1, 3, 3)])

    return Tessellation(corners(radius * unit), corners(unit) if radius > 0 else None)


def cube(size: float) -> Tessellation:
    """Axis-aligned cube of edge ``size`` (flat faces)."""
    h = 0.5 * size
    corners = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)], dtype=np.float64)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
    return Tessellation(corners[np.array(tris)])


def cylinder(radius_bottom: float, radius_top: float, height: float, axis: str = "Z",
             segments: int = SEGMENTS) -> Tessellation:
    """Closed cylinder (or frustum) about ``axis``: profile (radius, height) from the bottom centre up."""
    h = 0.5 * height
    return _lathe(np.array([[0.0, -h], [radius_bottom, -h], [radius_top, h], [0.0, h]]), None, segments, axis)


def cone(radius: float, height: float, axis: str = "Z", segments: int = SEGMENTS) -> Tessellation:
    """Cone about ``axis``, base of ``radius`` at −height/2, apex at +height/2."""
    h = 0.5 * height
    return _lathe(np.array([[0.0, -h], [radius, -h], [0.0, h]]), None, segments, axis)


def capsule(radius_bottom: float, radius_top: float, height: float, axis: str = "Z", rings: int = RINGS,
            segments: int = SEGMENTS) -> Tessellation:
    """Capsule about ``axis``: hemispheres centred at ∓height/2 joined by the side between their equators."""
    h = 0.5 * height
    bottom, n_bottom = _sphere_profile(radius_bottom, -h, np.pi, 0.5 * np.pi, rings // 2)  # south pole → equator
    top, n_top = _sphere_profile(radius_top, h, 0.5 * np.pi, 0.0, rings // 2)  # equator → north pole
    normals = np.concatenate([_vertex_normals(n_bottom), [_edge_normal(bottom[-1], top[0])] * 2,
                              _vertex_normals(n_top)]).reshape(-1, 2, 2)
    return _lathe(np.concatenate([bottom, top]), normals, segments, axis)


def plane(width: float, length: float, axis: str = "Z") -> Tessellation:
    """Rectangle ``width`` × ``length`` with its normal along ``axis`` (UsdGeomPlane's width/length axes)."""
    w, ln = 0.5 * width, 0.5 * length
    along = {"X": (2, 1), "Y": (0, 2), "Z": (0, 1)}[_checked(axis)]  # (width axis, length axis)
    corners = np.zeros((4, 3))
    corners[:, along[0]] = (-w, w, w, -w)
    corners[:, along[1]] = (-ln, -ln, ln, ln)
    order = [(0, 1, 2), (0, 2, 3)] if axis == "Z" else [(0, 2, 1), (0, 3, 2)]  # wound towards +axis
    return Tessellation(corners[np.array(order)])


def _sphere_profile(radius: float, centre: float, polar_from: float, polar_to: float, steps: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Points (steps + 1, 2) (distance from the spine, height) of a meridian arc from polar angle ``polar_from``
    to ``polar_to`` (0 = +spine) of a sphere of ``radius`` centred at ``centre`` on the spine, and their unit
    normals (steps + 1, 2) in the same (radial, axial) components."""
    polar = np.linspace(polar_from, polar_to, steps + 1)
    sin, cos = np.sin(polar), np.cos(polar)
    sin[np.abs(sin) < 1e-12], cos[np.abs(cos) < 1e-12] = 0.0, 0.0  # poles exactly on the spine, equators level
    return np.stack([radius * sin, centre + radius * cos], axis=-1), np.stack([sin, cos], axis=-1)


def _vertex_normals(normals: np.ndarray) -> np.ndarray:
    """Per-edge (start, end) normals (K − 1, 2, 2) of a smooth profile from its vertex normals (K, 2)."""
    return np.stack([normals[:-1], normals[1:]], axis=1).reshape(-1, 2)


def _edge_normal(p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Outward unit normal (2,) of the profile edge p0 → p1 (profiles run from the −spine end to the +spine end)."""
    dr, dz = p1[0] - p0[0], p1[1] - p0[1]
    length = np.hypot(dr, dz)
    return np.array([dz, -dr]) / length if length > 0 else np.array([0.0, 0.0])


def _lathe(profile: np.ndarray, edge_normals: np.ndarray | None, segments: int, axis: str) -> Tessellation:
    """Surface of revolution of a profile (K, 2) = (distance from the spine ≥ 0, height along it) about ``axis``:
    one quad (two triangles) per profile edge and segment; degenerate triangles (on the spine) are dropped.
    ``edge_normals`` (K − 1, 2, 2): each edge's (radial, axial) normal at its start and end (smooth arcs); None:
    every edge is flat (its own normal at both ends)."""
    if edge_normals is None:
        edge_normals = np.array([[_edge_normal(p0, p1)] * 2 for p0, p1 in zip(profile[:-1], profile[1:])])
    phi = 2.0 * np.pi * np.arange(segments) / segments
    seam = np.r_[0:segments, 0]  # the seam closes on the same vertices (watertight)
    cos, sin = np.cos(phi)[seam], np.sin(phi)[seam]

    def revolve(radial: np.ndarray, axial: np.ndarray) -> np.ndarray:  # (…,) → (…, S + 1, 3), spine along +Z
        return np.stack([radial[..., None] * cos, radial[..., None] * sin,
                         np.broadcast_to(axial[..., None], radial.shape + cos.shape)], axis=-1)

    ring = revolve(profile[:, 0], profile[:, 1])  # (K, S + 1, 3)
    normal = revolve(edge_normals[..., 0], edge_normals[..., 1])  # (K − 1, 2, S + 1, 3): edge, end, segment
    a, b, c, d = ring[:-1, :-1], ring[1:, :-1], ring[1:, 1:], ring[:-1, 1:]
    na, nb, nc, nd = normal[:, 0, :-1], normal[:, 1, :-1], normal[:, 1, 1:], normal[:, 0, 1:]

    def triangles(p: np.ndarray, q: np.ndarray, r: np.ndarray, s: np.ndarray) -> np.ndarray:
        return np.concatenate([np.stack([p, q, r], -2).reshape(-1, 3, 3), np.stack([p, r, s], -2).reshape(-1, 3, 3)])

    tris, normals = triangles(a, b, c, d), triangles(na, nb, nc, nd)
    area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=-1)
    keep = area2 > 1e-12 * max(1.0, float(np.abs(profile).max()) ** 2)
    order = {"Z": (0, 1, 2), "X": (2, 0, 1), "Y": (1, 2, 0)}[_checked(axis)]  # a rotation (x, y, z) ← (…)
    # counter-clockwise seen from outside (USD's rightHanded orientation)
    return Tessellation(tris[keep][:, ::-1][..., order], normals[keep][:, ::-1][..., order])


def _checked(axis: str) -> str:
    if axis not in ("X", "Y", "Z"):
        raise ValueError(f"axis must be X, Y or Z, got {axis!r}")
    return axis
