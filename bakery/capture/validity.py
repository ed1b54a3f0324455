"""Probe validity and relocation: probes inside geometry.

A probe inside a wall, a pillar or under the ground sees the inside of the geometry, which engines then
interpolate into the room. DDGI (Majercik, Marrs, Spjut, McGuire, "Scaling Probe-Based Real-Time Dynamic Global
Illumination for Production", JCGT 10(2), 2021) classifies a probe as inside geometry when more than 25 % of its
rays hit back faces (Sec. 4, "backface fraction") and relocates it (Sec. 5); Unity's Adaptive Probe Volumes do
the same ("probe validity", "virtual offset"). Here:

- **backface fraction** of a set of rays: the share whose first hit is the back of a single-sided surface —
  ``Mesh.front`` · (winding normal · ray direction) > 0 (:func:`back_facing`); escaping rays count as front;
- **relocation** (opt-in per probe volume, ``bakery:volume:relocate``): a probe whose fraction over
  :data:`SEARCH_DIRECTIONS` Fibonacci rays is ≥ :data:`INSIDE_BACKFACE_FRACTION` is captured instead at
  q = p + d·(t + margin) for the back-face hits (d, t) within the search radius R, nearest first, margin =
  :data:`RELOCATION_MARGIN`·R past the face it crosses — the first q whose own fraction is below the threshold (at
  most :data:`MAX_CANDIDATES` tried); none: the probe stays (and is reported). The probe keeps its position in the
  store and the layer (engines interpolate the grid); the capture offset q − p is recorded.

Relocation trusts the winding: a room shell wound outwards and seen from inside looks like the inside of a solid,
and its probes would be moved out of the room — which is why it is opt-in. Pure numpy on the Embree tracer; the
same rays for a probe whatever it is captured with (deterministic).
"""

from __future__ import annotations

import numpy as np

from bakery.capture.vec import REAL, dot
from bakery.conventions import INSIDE_BACKFACE_FRACTION
from bakery.sphere.fibonacci import fibonacci_directions
#: Rays a relocation search casts from the probe and from each candidate position.
SEARCH_DIRECTIONS = 256
#: How far past the back face it crosses a relocated probe is placed, as a fraction of the search radius.
RELOCATION_MARGIN = 0.1
#: Candidate positions tried per probe, nearest crossing first.
MAX_CANDIDATES = 16


def triangle_fronts(scene, tracer) -> np.ndarray:  # noqa: ANN001 - CaptureScene, SceneTracer
    """Per triangle of the scene's tracer (T,) float32: +1 / −1 the side of its winding normal that is its front,
    0 double-sided (``Mesh.front`` of its mesh)."""
    fronts = np.array([mesh.front for mesh in scene.meshes] or [1], dtype=REAL)
    return np.take(fronts, np.asarray(tracer.mesh_of, dtype=np.int64))


def back_facing(normals_soa: np.ndarray, front_soa: np.ndarray, prim: np.ndarray, directions: np.ndarray
                ) -> np.ndarray:
    """Whether hits on triangles ``prim`` (K,) of rays ``directions`` (3, K) see the triangles' backs: bool (K,).
    ``normals_soa`` (3, T) winding normals, ``front_soa`` (T,) +1 / −1 / 0 (``Mesh.front`` per triangle)."""
    facing = dot(np.take(normals_soa, prim, axis=1), directions)
    return np.take(front_soa, prim) * facing > 0


class Relocator:
    """Relocation searches in one scene (module docstring). ``tracer``: the scene's
    :class:`~bakery.capture.tracer.SceneTracer`; ``front_soa`` (T,) the front side of every triangle."""

    def __init__(self, tracer, front_soa: np.ndarray) -> None:  # noqa: ANN001 - SceneTracer
        self.tracer = tracer
        self.front_soa = front_soa
        self.directions = np.ascontiguousarray(fibonacci_directions(SEARCH_DIRECTIONS).T, dtype=REAL)  # (3, D)

    @classmethod
    def of_scene(cls, scene) -> Relocator:  # noqa: ANN001 - CaptureScene
        """A relocator over a scene's own Embree scene (no renderer: for ``bakery check``)."""
        from bakery.capture.tracer import SceneTracer

        tracer = SceneTracer(scene)
        return cls(tracer, triangle_fronts(scene, tracer))

    def _cast(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Back-face flags (D,) and hit distances (D,) of the search rays from ``position`` (3,)."""
        origins = np.repeat(np.asarray(position, dtype=REAL).reshape(3, 1), SEARCH_DIRECTIONS, axis=1)
        prim, t, _u, _v = self.tracer.intersect_uv(origins, self.directions, soa=True)
        back = np.zeros(SEARCH_DIRECTIONS, dtype=bool)
        hit = np.flatnonzero(prim >= 0)
        if hit.size:
            back[hit] = back_facing(self.tracer.normals_soa, self.front_soa, prim[hit], self.directions[:, hit])
        return back, t

    def backface_fraction(self, position: np.ndarray) -> float:
        """Share of the :data:`SEARCH_DIRECTIONS` rays from ``position`` (3,) that see back faces."""
        return float(self._cast(position)[0].mean())

    def capture_position(self, position: np.ndarray, radius: float) -> tuple[np.ndarray, int]:
        """Where to capture a probe at ``position`` (3,) float64 with search radius ``radius`` (metres; ≤ 0: no
        search) — itself if it is not inside geometry, else the relocated position (module docstring) — and the
        number of rays the search cast."""
        position = np.asarray(position, dtype=np.float64).reshape(3)
        if radius <= 0 or self.tracer.triangles.shape[0] == 0:
            return position, 0
        back, t = self._cast(position)
        cast = SEARCH_DIRECTIONS
        if back.mean() < INSIDE_BACKFACE_FRACTION:
            return position, cast
        crossings = np.flatnonzero(back & (t < radius))
        crossings = crossings[np.argsort(t[crossings], kind="stable")][:MAX_CANDIDATES]
        margin = RELOCATION_MARGIN * radius
        for k in crossings:
            candidate = position + self.directions[:, k].astype(np.float64) * (float(t[k]) + margin)
            cast += SEARCH_DIRECTIONS
            if self.backface_fraction(candidate) < INSIDE_BACKFACE_FRACTION:
                return candidate, cast
        return position, cast
