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


# ------------------------------------------------------------------------------------------------ points and curves
#: Sides of the prism a curve is swept into, and samples per cubic span
CURVE_SIDES = 6
CURVE_SPAN_SAMPLES = 4
#: Circumradius / radius of the icosahedron standing for a point's sphere and of the prism for a curve's tube, so
#: that their mean projected area — a convex body's is a quarter of its surface (Cauchy) — is the round shape's:
#: a point's shadow and silhouette are as large on average as its sphere's, a curve's as its tube's
ICOSAHEDRON_SCALE = float(np.sqrt(np.pi / (5.0 * np.sqrt(3.0) * (1.0 / np.sin(2.0 * np.pi / 5.0)) ** 2 / 4.0)))
PRISM_SCALE = float(np.pi / CURVE_SIDES / np.sin(np.pi / CURVE_SIDES))


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit-circumradius icosahedron: vertices (12, 3), triangles (20, 3) counter-clockwise seen from outside."""
    g = (1.0 + np.sqrt(5.0)) / 2.0
    v = np.array([[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0], [0, -1, g], [0, 1, g], [0, -1, -g], [0, 1, -g],
                  [g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]], dtype=np.float64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    return v, f


def point_spheres(positions: np.ndarray, widths: np.ndarray) -> Tessellation:
    """UsdGeomPoints: a sphere of diameter ``widths`` (N,) at each of ``positions`` (N, 3), as an icosahedron of
    circumradius :data:`ICOSAHEDRON_SCALE` × the radius (20 triangles a point), shaded smooth (sphere normals)."""
    v, f = _icosahedron()
    unit = v[f]  # (20, 3, 3)
    radius = 0.5 * np.asarray(widths, dtype=np.float64).reshape(-1, 1, 1, 1) * ICOSAHEDRON_SCALE
    tris = np.asarray(positions, dtype=np.float64)[:, None, None, :] + radius * unit[None]
    normals = np.broadcast_to(unit[None], tris.shape)
    keep = radius.reshape(-1) > 0
    return Tessellation(tris[keep].reshape(-1, 3, 3), np.ascontiguousarray(normals[keep]).reshape(-1, 3, 3))


#: Cubic bases of UsdGeomBasisCurves (rows: the weights of the span's 4 control points as cubics in t, as
#: coefficient vectors (1, t, t², t³)) and each basis' vstep
CUBIC_BASES = {
    "bezier": (np.array([[1, -3, 3, -1], [0, 3, -6, 3], [0, 0, 3, -3], [0, 0, 0, 1]], dtype=np.float64), 3),
    "bspline": (np.array([[1, -3, 3, -1], [4, 0, -6, 3], [1, 3, 3, -3], [0, 0, 0, 1]], dtype=np.float64) / 6.0, 1),
    "catmullRom": (np.array([[0, -1, 2, -1], [2, 0, -5, 3], [0, 1, 4, -3], [0, 0, -1, 1]], dtype=np.float64) / 2.0,
                   1),
}


def curve_samples(points: np.ndarray, kind: str, basis: str, wrap: str,
                  samples: int = CURVE_SPAN_SAMPLES) -> np.ndarray:
    """Points (K, C) along one curve of control points (n, C) (C: positions and the widths carried along), by
    UsdGeomBasisCurves' rules: ``linear`` the control polygon (closed when ``periodic``); ``cubic`` spans of 4
    control points every vstep (bezier 3, bspline and catmullRom 1), ``periodic`` wrapping round, ``pinned``
    bspline/catmullRom with the phantom points 2·P₀ − P₁ and 2·P_{n−1} − P_{n−2} at the ends (so the curve reaches
    them), each span sampled ``samples`` times."""
    p = np.asarray(points, dtype=np.float64)
    if kind == "linear" or len(p) < 4:
        return np.concatenate([p, p[:1]]) if wrap == "periodic" and len(p) > 2 else p
    weights, step = CUBIC_BASES[basis]
    if wrap == "periodic":
        p = np.concatenate([p, p[: 4 - step if basis == "bezier" else 3]])
    elif wrap == "pinned" and basis != "bezier":
        p = np.concatenate([2 * p[:1] - p[1:2], p, 2 * p[-1:] - p[-2:-1]])
    spans = (len(p) - 4) // step + 1
    t = np.linspace(0.0, 1.0, samples + 1)
    powers = np.stack([np.ones_like(t), t, t * t, t * t * t], axis=1)  # (S + 1, 4)
    blend = powers @ weights.T  # (S + 1, 4): each control point's weight at t
    out = [blend @ p[k * step : k * step + 4] for k in range(spans)]
    return np.concatenate([out[0]] + [o[1:] for o in out[1:]])


def curve_tubes(curves: list[np.ndarray], radii: list[np.ndarray], sides: int = CURVE_SIDES) -> Tessellation:
    """Tubes along sampled curves (each (K, 3)) of radii (K,): prisms of ``sides`` sides, circumradius
    :data:`PRISM_SCALE` × the radius, swept with frames transported along the curve (no twist), shaded smooth
    (radial normals), open at the ends."""
    tris, norms = [], []
    angles = 2.0 * np.pi * np.arange(sides + 1) / sides
    for points, radius in zip(curves, radii, strict=True):
        if len(points) < 2:
            continue
        tangent = np.gradient(points, axis=0)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
        axis = np.eye(3)[int(np.argmin(np.abs(tangent[0])))]
        normal = np.cross(tangent[0], axis)
        normal /= np.linalg.norm(normal)
        frames = []
        for k in range(len(points)):  # parallel transport: the previous normal projected off the new tangent
            if k:
                normal = normal - tangent[k] * float(normal @ tangent[k])
                length = np.linalg.norm(normal)
                normal = normal / length if length > 1e-12 else frames[-1][0]
            frames.append((normal, np.cross(tangent[k], normal)))
        n = np.array([f[0] for f in frames])
        b = np.array([f[1] for f in frames])
        ring = np.cos(angles)[None, :, None] * n[:, None, :] + np.sin(angles)[None, :, None] * b[:, None, :]
        rim = points[:, None, :] + (PRISM_SCALE * np.asarray(radius, dtype=np.float64))[:, None, None] * ring
        a, c = rim[:-1, :-1], rim[1:, 1:]
        bb, d = rim[1:, :-1], rim[:-1, 1:]
        na, nc, nb, nd = ring[:-1, :-1], ring[1:, 1:], ring[1:, :-1], ring[:-1, 1:]
        tris.append(np.concatenate([np.stack([a, c, bb], -2).reshape(-1, 3, 3),  # counter-clockwise from outside
                                    np.stack([a, d, c], -2).reshape(-1, 3, 3)]))
        norms.append(np.concatenate([np.stack([na, nc, nb], -2).reshape(-1, 3, 3),
                                     np.stack([na, nd, nc], -2).reshape(-1, 3, 3)]))
    if not tris:
        return Tessellation(np.zeros((0, 3, 3)), None)
    return Tessellation(np.concatenate(tris), np.concatenate(norms))
