"""Batched ray queries against the scene's triangles with Embree (``embreex``).

All triangles of all meshes go into one Embree scene; ``primID`` indexes the concatenated triangle arrays, so
per-triangle normals (and, in :mod:`bakery.capture.surfaces`, materials) are plain numpy gathers. Queries are
issued in chunks of :data:`CHUNK` rays (Embree's stream API is single-call per chunk; there is no per-ray Python loop)
as contiguous (M, 3) float32 arrays; shadow rays use occlusion queries (``query="OCCLUDED"``: any hit ends the
search), camera and bounce rays closest-hit queries. The renderer passes structure-of-arrays (3, M) rays
(``soa=True``), transposed here into Embree's layout.
"""

from __future__ import annotations

import numpy as np
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh

from bakery.capture.scene import FAR, CaptureScene

#: Rays per Embree call.
CHUNK = 1 << 18
__all__ = ["CHUNK", "FAR", "SceneTracer"]


class SceneTracer:
    """Closest-hit and occlusion queries, plus per-triangle shading data.

    Attributes:
        normals: (T, 3) unit geometric normals (right-hand rule on the triangle's vertex order).
        mesh_of: (T,) index of the mesh each triangle belongs to.
        epsilon: relative ray-origin offset; see :meth:`offset`.
        rays_cast: running count of rays traced (for rays/s reports).
    """

    def __init__(self, scene: CaptureScene) -> None:
        triangles = [m.triangles.reshape(-1, 3, 3) for m in scene.meshes if m.triangles.size]
        self.empty = not triangles
        tris = np.concatenate(triangles).astype(np.float64) if triangles else np.zeros((0, 3, 3))
        self.mesh_of = np.concatenate(
            [np.full(m.triangles.reshape(-1, 3, 3).shape[0], i, dtype=np.int64) for i, m in enumerate(scene.meshes)]
            or [np.zeros(0, dtype=np.int64)]
        )
        self.triangles = tris
        cross = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]) if len(tris) else np.zeros((0, 3))
        length = np.linalg.norm(cross, axis=-1, keepdims=True)
        self.normals = np.where(length > 0, cross / np.maximum(length, 1e-300), np.array([0.0, 1.0, 0.0]))
        #: the normals' x, y and z rows in float32 (structure-of-arrays gathers of the renderer)
        self.normals_soa = np.ascontiguousarray(self.normals.T, dtype=np.float32)
        #: authored shading normals of the triangles' corners (9, T) float32 (rows: corner-major x, y, z) and which
        #: triangles have them (T,) bool; None when no mesh has normals
        self.shading_soa, self.has_shading = None, None
        if any(m.normals is not None for m in scene.meshes if m.triangles.size):
            corners, flags, start = [], [], 0
            for m in scene.meshes:
                count = m.triangles.reshape(-1, 3, 3).shape[0]
                if count == 0:
                    continue
                if m.normals is None:
                    geometric = self.normals[start : start + count]
                    corners.append(np.repeat(geometric[:, None, :], 3, axis=1))
                else:
                    corners.append(np.asarray(m.normals, dtype=np.float64).reshape(-1, 3, 3))
                flags.append(np.full(count, m.normals is not None))
                start += count
            self.shading_soa = np.ascontiguousarray(np.concatenate(corners).reshape(-1, 9).T, dtype=np.float32)
            self.has_shading = np.concatenate(flags)
        if len(tris):
            lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
            diagonal = float(np.linalg.norm(hi - lo))
        else:
            diagonal = 1.0
        self.epsilon = 1e-5
        self.diagonal = diagonal
        self.rays_cast = 0
        self._scene = None
        if not self.empty:
            self._scene = rtcs.EmbreeScene(robust=True)  # watertight: no leaks along shared edges
            # Embree keeps a reference to the mesh buffer through the scene object.
            self._mesh = TriangleMesh(self._scene, tris.astype(np.float32))

    def shading_normals(self, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray, geometric: np.ndarray,
                        wo: np.ndarray) -> np.ndarray:
        """Shading normals (3, M) at hits: the authored corner normals interpolated with the barycentrics (u, v)
        and normalised, turned to the side of ``geometric`` (3, M) (the geometric normal facing the viewer ``wo``,
        two-sided surfaces); the geometric normal itself on triangles without normals and where the interpolated
        normal faces away from the viewer (n_s·wo ≤ 0: no shading frame exists there)."""
        smooth = np.flatnonzero(np.take(self.has_shading, prim))  # only hits on meshes with normals
        if smooth.size == 0:
            return geometric
        prim, bu, bv = np.take(prim, smooth), np.take(bu, smooth), np.take(bv, smooth)
        g, w = np.take(geometric, smooth, axis=1), np.take(wo, smooth, axis=1)
        c = [np.take(self.shading_soa[i], prim) for i in range(9)]
        w0 = 1 - bu - bv
        ns = np.stack([w0 * c[k] + bu * c[3 + k] + bv * c[6 + k] for k in range(3)])
        length = np.sqrt(ns[0] * ns[0] + ns[1] * ns[1] + ns[2] * ns[2])
        ns /= np.maximum(length, np.float32(1e-30))
        ns *= 1 - 2 * ((ns * g).sum(axis=0) < 0).astype(ns.dtype)
        fallback = ((ns * w).sum(axis=0) <= 0) | (length <= 0)
        out = geometric.copy()
        out[:, smooth] = np.where(fallback, g, ns)
        return out

    def offset(self, points: np.ndarray) -> np.ndarray:
        """Ray-origin offsets (M,) in metres: relative to the points' magnitude, as float32 hit points are
        accurate to about 1e-7·|p| (the 1e-5 factor leaves two orders of margin)."""
        return self.epsilon * (1e-2 + np.abs(points).max(axis=-1))

    def offset_soa(self, points: np.ndarray) -> np.ndarray:
        """:meth:`offset` of points (3, M)."""
        a = np.abs(points)
        return self.epsilon * (1e-2 + np.maximum(np.maximum(a[0], a[1]), a[2]))

    def intersect_uv(self, origins: np.ndarray, directions: np.ndarray, soa: bool = False
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest hit of rays (M, 3) (or (3, M) with ``soa``): triangle index (M,) int32 (−1 on miss), distance t
        (M,) float32 (FAR on miss) and the hit's barycentric coordinates u, v (M,) float32
        (p = (1−u−v)·v0 + u·v1 + v·v2)."""
        o = np.ascontiguousarray(origins.T if soa else origins, dtype=np.float32)
        d = np.ascontiguousarray(directions.T if soa else directions, dtype=np.float32)
        m = o.shape[0]
        self.rays_cast += m
        prim = np.full(m, -1, dtype=np.int32)
        t = np.full(m, FAR, dtype=np.float32)
        bu = np.zeros(m, dtype=np.float32)
        bv = np.zeros(m, dtype=np.float32)
        if self._scene is None or m == 0:
            return prim, t, bu, bv
        for start in range(0, m, CHUNK):
            stop = min(m, start + CHUNK)
            out = self._scene.run(o[start:stop], d[start:stop], output=1)
            hit = out["primID"] >= 0
            prim[start:stop] = out["primID"]
            t[start:stop] = np.where(hit, out["tfar"], FAR)
            bu[start:stop] = out["u"]
            bv[start:stop] = out["v"]
        return prim, t, bu, bv

    def intersect(self, origins: np.ndarray, directions: np.ndarray, soa: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Closest hit of rays: triangle index (M,) (−1 on miss) and distance t (M,) (FAR on miss)."""
        prim, t, _u, _v = self.intersect_uv(origins, directions, soa)
        return prim, t

    def occluded(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray,
                 soa: bool = False) -> np.ndarray:
        """Whether each segment origin + t·direction, 0 < t < distance, hits a triangle: bool (M,). An occlusion
        query (Embree stops at the first hit found, no closest-hit search)."""
        o = np.ascontiguousarray(origins.T if soa else origins, dtype=np.float32)
        d = np.ascontiguousarray(directions.T if soa else directions, dtype=np.float32)
        m = o.shape[0]
        self.rays_cast += m
        if self._scene is None or m == 0:
            return np.zeros(m, dtype=bool)
        dist = np.ascontiguousarray(np.minimum(distances, FAR), dtype=np.float32)
        result = np.zeros(m, dtype=bool)
        for start in range(0, m, CHUNK):
            stop = min(m, start + CHUNK)
            out = self._scene.run(o[start:stop], d[start:stop], dists=dist[start:stop], query="OCCLUDED")
            result[start:stop] = np.asarray(out) >= 0
        return result


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit-circumradius icosahedron: vertices (12, 3) and triangles (20, 3) (outward winding)."""
    g = (1.0 + 5.0**0.5) / 2.0
    v = np.array([[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0], [0, -1, g], [0, 1, g], [0, -1, -g], [0, 1, -g],
                  [g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]], dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


#: Circumradius over inradius of the icosahedron (1.2584).
_ICOSAHEDRON_RATIO = 1.0 / float(np.linalg.norm(np.mean(np.take(*_icosahedron(), axis=0)[0], axis=0)))


class SphereCuller:
    """Which segments may pass within any of K spheres, by one Embree occlusion query against icosahedra that
    enclose them (a conservative cull before the light shapes' exact tests, :class:`bakery.capture.lights.LightSet`).

    Each segment is queried from ``back`` before its origin, more than any icosahedron's diameter: a segment that
    meets a sphere then crosses the surface of the icosahedron around it (even one that starts inside it), which
    Embree's watertight test finds. So the flagged segments hold every segment that meets a sphere (and a few that
    pass near one, or near one just behind their origin). The icosahedra's inradius is the sphere's plus a float32
    margin. The queries are culling, not rendering rays: they are not counted in :attr:`SceneTracer.rays_cast`.
    """

    def __init__(self, centres: np.ndarray, radii: np.ndarray) -> None:
        centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
        radii = np.asarray(radii, dtype=np.float64).reshape(-1)
        vertices, faces = _icosahedron()
        scale = 1.0 + np.abs(centres).max(initial=0.0)
        inradius = radii * (1.0 + 1e-3) + 1e-6 * scale  # float32 rounding of vertices and ray arithmetic
        circumradius = inradius * _ICOSAHEDRON_RATIO
        corners = centres[:, None, None, :] + circumradius[:, None, None, None] * vertices[faces][None]  # (K,20,3,3)
        self.back = float(2.0 * circumradius.max(initial=0.0) * (1.0 + 1e-3) + 1e-5 * scale)
        self._faces = faces.shape[0]  # triangles per icosahedron, sphere by sphere in the mesh
        self._scene = rtcs.EmbreeScene(robust=True)
        self._mesh = TriangleMesh(self._scene, corners.reshape(-1, 3, 3).astype(np.float32))

    def _queries(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray,
                 origin_of: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Embree's rays for the segments (arguments as :meth:`flag`): origins ``back`` before theirs (S, 3),
        directions (S, 3) and lengths (S,), float32."""
        d = np.ascontiguousarray(directions.T, dtype=np.float32)
        o = np.asarray(origins, dtype=np.float32).T
        o = np.ascontiguousarray((o if origin_of is None else o[origin_of]) - np.float32(self.back) * d)  # new array
        dist = np.ascontiguousarray(np.minimum(np.asarray(distances, dtype=np.float64) + self.back, FAR),
                                    dtype=np.float32)
        return o, d, dist

    def flag(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray,
             origin_of: np.ndarray | None = None) -> np.ndarray:
        """Segments origin + t·direction, 0 < t < distance (directions (3, S) unit, distances (S,); origins (3, S),
        or (3, M) indexed by ``origin_of`` (S,)) that may meet a sphere: bool (S,)."""
        o, d, dist = self._queries(origins, directions, distances, origin_of)
        result = np.zeros(d.shape[0], dtype=bool)
        for start in range(0, d.shape[0], CHUNK):
            stop = min(d.shape[0], start + CHUNK)
            out = self._scene.run(o[start:stop], d[start:stop], dists=dist[start:stop], query="OCCLUDED")
            result[start:stop] = np.asarray(out) >= 0
        return result

    def first(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray,
              origin_of: np.ndarray | None = None) -> np.ndarray:
        """The sphere whose icosahedron each segment (arguments as :meth:`flag`, queried from ``back`` before its
        origin too) enters first, by one closest-hit query: index (S,) int64, −1 where :meth:`flag` is False."""
        o, d, dist = self._queries(origins, directions, distances, origin_of)
        result = np.full(d.shape[0], -1, dtype=np.int64)
        for start in range(0, d.shape[0], CHUNK):
            stop = min(d.shape[0], start + CHUNK)
            prim = np.asarray(self._scene.run(o[start:stop], d[start:stop], dists=dist[start:stop], output=1)["primID"])
            result[start:stop] = np.where(prim >= 0, prim // self._faces, -1)
        return result
