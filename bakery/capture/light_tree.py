"""Many lights: a bounding-volume hierarchy and a grid over the analytic lights, for ray culling and light selection
(no ``pxr``).

A scene with hundreds of lights (street lamps, bulbs, practicals) cannot test every light shape on every ray, nor
send a shadow ray to every light from every path vertex: both cost O(lights × rays) time and memory. One binary BVH
over the lights' bounding spheres serves both:

Ray culling (:meth:`LightBVH.candidates`)
    The (segment, light) pairs whose segment passes a light's box, found by descending the tree for all segments
    at once (a frontier of (segment, node) pairs, one slab test per pair and level). The boxes enclose the bounding
    spheres the renderer culls with, so the exact tests that follow see the same rays (conservative culling).

Light selection (:meth:`LightBVH.sample`, :meth:`LightBVH.pmf`; pbrt-v4 §12.6.3 "BVH Light Sampling")
    At every interior node a point picks a child with probability proportional to the child's importance
        I(p) = Φ · cos θ' / max(d², (|diag| / 2)²),   θ' = max(0, θ_w − θ_o − θ_b)   (0 when θ' ≥ θ_e)
    (Φ power bound, d distance to the box centre, θ_w the angle between the node's emission axis and the direction
    to p, θ_o, θ_e its normal and emission cone angles, θ_b the half-angle the box subtends from p; pbrt-v4's
    ``LightBounds::Importance`` without the surface-normal factor, so that transmission is never culled), reusing
    one uniform number down the tree. The probability of the light reached is the product of the choices; a light
    whose importance is > 0 wherever it can contribute is never missed, so next-event estimation stays unbiased.

Build: top-down, splitting a node's lights at the median of the largest extent of their centres (ties by index):
deterministic, O(L log L), depth ≤ ⌈log₂ L⌉ + 1.

Light selection by region (:class:`LightGrid`, what the renderer draws from)
    Descending the BVH costs two importance evaluations per level and draw, in numpy for every path vertex. The
    grid evaluates the same leaf importance once per (surface cell, light) when it is built and draws with one
    table lookup (a guide table and ~2 steps): O(1) per draw, and a lower variance than the BVH's clustered upper
    levels (measured on ``examples/plaza`` and on 100–10 000 random lamps, ``docs/capture.md`` "Many lights").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Above this many (non-distant) lights the renderer draws LIGHT_SAMPLES next-event lights per path vertex from the
#: BVH; at or below, it samples every light (lower variance). Measured on 128 probes of a 10-box scene (face 32,
#: 4 rays per texel, one process): 16 lights 3.1 s drawn, 3.3 s enumerated; 100 lights 7.5 s drawn, 75 s
#: enumerated; 1000 lights 12 s drawn (enumerated: > 10 min and 7.5 GB).
ENUMERATED_LIGHTS = 16

#: Lights selected per path vertex from the BVH (independent draws, each weighted 1/K).
LIGHT_SAMPLES = 4

#: Above this many light shapes the renderer finds the (ray, shape) pairs to test with the BVH; at or below, it
#: culls every ray against every shape's bounding sphere (cheaper for few shapes; capture seconds, one process:
#: 32 shapes (examples/plaza) 23 s enumerated, 31 s by the BVH; 100 shapes 6.3 s enumerated, 5.6 s by the BVH —
#: measured before the Embree culler, :data:`bakery.capture.lights.PROXY_CULLED_SHAPES`, ran in front of both).
CULLED_SHAPES = 64


def next_event_lights(kinds: list[str]) -> int:
    """Next-event samples (shadow rays) per path vertex for analytic lights of these kinds: every light at or below
    ENUMERATED_LIGHTS non-distant ones; above, the distant ones and LIGHT_SAMPLES draws."""
    drawn = sum(kind != "distant" for kind in kinds)
    return len(kinds) - drawn + (drawn if drawn <= ENUMERATED_LIGHTS else LIGHT_SAMPLES)


def light_sampling(kinds: list[str]) -> dict:
    """How next-event estimation samples analytic lights of these kinds (recorded with a scene bake): the lights,
    the non-distant ones, whether those are drawn, the draws per vertex and, when drawn, from what ("grid": the
    :class:`LightGrid`, the BVH outside it)."""
    local = sum(kind != "distant" for kind in kinds)
    drawn = local > ENUMERATED_LIGHTS
    return {"lights": len(kinds), "non_distant": local, "drawn": drawn, "draws_per_vertex": LIGHT_SAMPLES if drawn
            else 0, "enumerated_up_to": ENUMERATED_LIGHTS, "next_event_samples_per_vertex": next_event_lights(kinds),
            **({"selection": "grid"} if drawn else {})}


@dataclass(frozen=True)
class LightBound:
    """What the tree knows of one light: the box (3,) ``lower``/``upper`` (metres) enclosing its surface, its power
    bound ``power`` (> 0: luminance of the radiance × emitting area, any consistent scale), the axis ``axis`` (3,)
    of its emission-normal cone with the cosines of the normal cone's half-angle ``cos_normal`` (−1: every
    direction) and of the emission spread about it ``cos_emission`` (0: a hemisphere, Lambertian)."""

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]
    power: float
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    cos_normal: float = -1.0
    cos_emission: float = 0.0


def _cone_union(w_a: np.ndarray, cos_a: float, w_b: np.ndarray, cos_b: float) -> tuple[np.ndarray, float]:
    """The smallest cone holding two direction cones (pbrt-v4 ``Union(DirectionCone, DirectionCone)``)."""
    if cos_a <= -1.0 or cos_b <= -1.0:
        return np.array([0.0, 0.0, 1.0]), -1.0
    theta_a, theta_b = math.acos(min(1.0, cos_a)), math.acos(min(1.0, cos_b))
    theta_d = math.acos(float(np.clip(np.dot(w_a, w_b), -1.0, 1.0)))
    if min(theta_d + theta_b, math.pi) <= theta_a:
        return w_a, cos_a
    if min(theta_d + theta_a, math.pi) <= theta_b:
        return w_b, cos_b
    theta_o = 0.5 * (theta_a + theta_d + theta_b)
    if theta_o >= math.pi:
        return np.array([0.0, 0.0, 1.0]), -1.0
    axis = np.cross(w_a, w_b)
    norm = float(np.linalg.norm(axis))
    if norm < 1e-12:
        return np.array([0.0, 0.0, 1.0]), -1.0
    k, angle = axis / norm, theta_o - theta_a  # Rodrigues: w_a turned towards w_b by theta_o − theta_a
    w = w_a * math.cos(angle) + np.cross(k, w_a) * math.sin(angle) + k * np.dot(k, w_a) * (1 - math.cos(angle))
    return w / np.linalg.norm(w), math.cos(theta_o)


def _cos_sub_clamped(sin_a: np.ndarray, cos_a: np.ndarray, sin_b: np.ndarray, cos_b: np.ndarray) -> np.ndarray:
    """cos(max(0, a − b)) from the sines and cosines of a, b ∈ [0, π]."""
    return np.where(cos_a > cos_b, 1.0, cos_a * cos_b + sin_a * sin_b)


class LightBVH:
    """Binary BVH over L lights (module docstring). Nodes in depth-first order, the root first. Arrays: ``lower``,
    ``upper`` (N, 3) boxes; ``children`` (N, 2) (−1 at leaves); ``light`` (N,) the light of a leaf (−1 inside);
    ``power`` (N,), ``axis`` (N, 3), ``cos_normal``, ``cos_emission`` (N,) the summed bounds; ``path`` (L, D) the
    nodes from the root to each light's leaf's parent and ``side`` (L, D) the child taken there (−1 past the end)."""

    def __init__(self, bounds: list[LightBound]) -> None:
        if not bounds:
            raise ValueError("a light BVH needs at least one light")
        centres = np.array([[0.5 * (lo + hi) for lo, hi in zip(b.lower, b.upper)] for b in bounds])
        nodes: list[dict] = []

        def build(members: np.ndarray) -> int:
            index = len(nodes)
            nodes.append({})
            if members.size == 1:
                b = bounds[int(members[0])]
                nodes[index] = {"lower": np.array(b.lower, float), "upper": np.array(b.upper, float),
                                "children": (-1, -1), "light": int(members[0]), "power": float(b.power),
                                "axis": np.array(b.axis, float) / max(np.linalg.norm(b.axis), 1e-30),
                                "cos_normal": float(b.cos_normal), "cos_emission": float(b.cos_emission)}
                return index
            extent = centres[members].max(axis=0) - centres[members].min(axis=0)
            axis = int(np.argmax(extent))
            order = members[np.lexsort((members, centres[members, axis]))]  # by centre, ties by light index
            left, right = build(order[: order.size // 2]), build(order[order.size // 2 :])
            a, b = nodes[left], nodes[right]
            w, cos_o = _cone_union(a["axis"], a["cos_normal"], b["axis"], b["cos_normal"])
            nodes[index] = {"lower": np.minimum(a["lower"], b["lower"]), "upper": np.maximum(a["upper"], b["upper"]),
                            "children": (left, right), "light": -1, "power": a["power"] + b["power"], "axis": w,
                            "cos_normal": cos_o, "cos_emission": min(a["cos_emission"], b["cos_emission"])}
            return index

        build(np.arange(len(bounds)))
        self.lower = np.array([n["lower"] for n in nodes])
        self.upper = np.array([n["upper"] for n in nodes])
        self.children = np.array([n["children"] for n in nodes], dtype=np.int64)
        self.light = np.array([n["light"] for n in nodes], dtype=np.int64)
        self.power = np.array([n["power"] for n in nodes])
        self.axis = np.array([n["axis"] for n in nodes])
        self.cos_normal = np.array([n["cos_normal"] for n in nodes])
        self.cos_emission = np.array([n["cos_emission"] for n in nodes])
        self.centre = 0.5 * (self.lower + self.upper)
        self.half_diagonal2 = 0.25 * np.sum((self.upper - self.lower) ** 2, axis=1)
        self.sin_normal = np.sqrt(np.maximum(0.0, 1.0 - self.cos_normal**2))
        self._omni = self.cos_normal <= -1.0  # emits in every direction: no orientation term
        # per node, the importance's constants in float32 rows: the distance term's, and the emission cone's
        self._packed = np.ascontiguousarray(np.column_stack([self.centre, self.power, self.half_diagonal2]),
                                            dtype=np.float32)
        self._packed_cone = np.ascontiguousarray(np.column_stack([
            self.axis, self.sin_normal, self.cos_normal, self.cos_emission]), dtype=np.float32)
        parents: dict[int, tuple[int, int]] = {}
        for index, (left, right) in enumerate(self.children):
            if left >= 0:
                parents[int(left)], parents[int(right)] = (index, 0), (index, 1)
        leaf_of = {int(self.light[i]): i for i in range(len(nodes)) if self.light[i] >= 0}
        chains = []
        for light in range(len(bounds)):
            chain, node = [], leaf_of[light]
            while node in parents:
                node, side = parents[node]
                chain.append((node, side))
            chains.append(chain[::-1])
        depth = max(1, max(len(c) for c in chains))
        self.path = np.full((len(bounds), depth), -1, dtype=np.int64)
        self.side = np.full((len(bounds), depth), -1, dtype=np.int64)
        for light, chain in enumerate(chains):
            for level, (node, side) in enumerate(chain):
                self.path[light, level], self.side[light, level] = node, side

    @property
    def size(self) -> int:
        return int(self.path.shape[0])

    # -- light selection ------------------------------------------------------------------------------------------
    def importance(self, points: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """pbrt-v4's importance (module docstring) float32 of ``nodes`` (any shape) for points (3, ...) that broadcast
        against them (float32 arithmetic; nodes that emit in every direction, θ_o = π, reduce to
        Φ / max(d², (|diag|/2)²))."""
        p = np.asarray(points, dtype=np.float32)
        node = np.moveaxis(self._packed[nodes], -1, 0)  # (5, ...): one gather of the distance term's constants
        cx, cy, cz, power, half_diagonal2 = node[0], node[1], node[2], node[3], node[4]
        tx, ty, tz = p[0] - cx, p[1] - cy, p[2] - cz  # box centre → point
        d2 = tx * tx + ty * ty + tz * tz
        value = power / np.maximum(d2, half_diagonal2)
        omni = self._omni.take(nodes)
        if omni.all():
            return value
        # the orientation term only where a node has an emission cone (a node holding an omni light has none)
        shape = omni.shape
        cone = np.flatnonzero(~omni.reshape(-1))
        pick = lambda x: np.broadcast_to(x, shape).reshape(-1)[cone]  # noqa: E731
        axis = self._packed_cone[np.broadcast_to(nodes, shape).reshape(-1)[cone]].T  # (6, C)
        flat = np.broadcast_to(value, shape).reshape(-1).copy()
        flat[cone] = self._oriented(flat[cone], pick(tx), pick(ty), pick(tz), pick(d2), pick(half_diagonal2), *axis)
        return flat.reshape(shape)

    @staticmethod
    def _oriented(value: np.ndarray, tx: np.ndarray, ty: np.ndarray, tz: np.ndarray, d2: np.ndarray,
                  half_diagonal2: np.ndarray, ax: np.ndarray, ay: np.ndarray, az: np.ndarray, sin_o: np.ndarray,
                  cos_o: np.ndarray, cos_e: np.ndarray) -> np.ndarray:
        """:meth:`importance` of nodes with an emission cone (θ_o < π): ``value`` times the cosine of the angle the
        cone misses the point by, 0 outside the emission spread (float32, elementwise)."""
        inv_d = 1.0 / np.sqrt(np.maximum(d2, np.float32(1e-30)))
        cos_w = np.clip((tx * ax + ty * ay + tz * az) * inv_d, -1, 1)
        sin_w = np.sqrt(np.maximum(0, 1 - cos_w * cos_w))
        r2 = half_diagonal2  # the box's bounding sphere, for the subtended cone θ_b
        inside = d2 <= r2
        sin2_b = np.where(inside, 1, r2 / np.maximum(d2, np.float32(1e-30)))
        cos_b = np.where(inside, -1, np.sqrt(np.maximum(0, 1 - sin2_b)))
        sin_b = np.where(inside, 0, np.sqrt(np.minimum(1, sin2_b)))
        cos_x = _cos_sub_clamped(sin_w, cos_w, sin_o, cos_o)
        sin_x = np.sqrt(np.maximum(0, 1 - cos_x * cos_x))
        cos_p = np.where(inside, 1, _cos_sub_clamped(sin_x, cos_x, sin_b, cos_b))
        return np.where(cos_p > cos_e, value * np.maximum(cos_p, 0), 0).astype(np.float32, copy=False)

    def _child_probabilities(self, points: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The probabilities (float64, (K,) each) of descending from interior ``nodes`` (K,) to their left and right
        child at points (3, K): the children's importances over their sum (both 0 where neither can reach)."""
        both = self.importance(points[:, None, :], self.children[nodes].T).astype(np.float64)  # (2, K)
        total = both[0] + both[1]
        scale = np.where(total > 0, 1.0 / np.where(total > 0, total, 1.0), 0.0)
        return both[0] * scale, both[1] * scale

    def sample(self, points: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One light per point (3, M) from uniform numbers u (M,) float64: light indices (M,) (−1 where no light
        can reach the point) and their selection probabilities (M,) float64 (0 there), the same bits as
        :meth:`pmf` gives for them."""
        m = points.shape[1]
        points = np.asarray(points, dtype=np.float32)
        node = np.zeros(m, dtype=np.int64)
        pmf = np.ones(m)
        u = np.asarray(u, dtype=np.float64).copy()
        below_one = np.nextafter(1.0, 0.0)
        active = None if self.children[0, 0] >= 0 else np.zeros(0, dtype=np.int64)  # None: every point
        while active is None or active.size:
            at = node if active is None else node[active]
            p_left, p_right = self._child_probabilities(points if active is None else points[:, active], at)
            ua = u if active is None else u[active]
            go_left = ua < p_left
            ua = np.where(go_left, ua / np.maximum(p_left, 1e-300), (ua - p_left) / np.maximum(p_right, 1e-300))
            chosen = np.where(go_left, p_left, p_right)  # 0 where neither child can reach the point
            at = np.where(go_left, self.children[at, 0], self.children[at, 1])
            if active is None:
                u, node = np.minimum(ua, below_one), at
                pmf *= chosen
                inner = self.children[node, 0] >= 0
                active = None if inner.all() else np.flatnonzero(inner)
            else:
                u[active], node[active] = np.minimum(ua, below_one), at
                pmf[active] *= chosen
                active = active[self.children[at, 0] >= 0]
        light = self.light[node]
        return np.where(pmf > 0, light, -1), pmf

    def pmf(self, points: np.ndarray, lights: np.ndarray) -> np.ndarray:
        """The probability (M,) float64 that :meth:`sample` picks ``lights`` (M,) at points (3, M)."""
        lights = np.asarray(lights, dtype=np.int64)
        points = np.asarray(points, dtype=np.float32)
        out = np.ones(lights.size)
        for level in range(self.path.shape[1]):
            node, side = self.path[lights, level], self.side[lights, level]
            rows = np.flatnonzero(node >= 0)
            if rows.size == 0:
                break
            p_left, p_right = self._child_probabilities(points[:, rows], node[rows])
            out[rows] *= np.where(side[rows] == 0, p_left, p_right)
        return out

    # -- ray culling ----------------------------------------------------------------------------------------------
    def candidates(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray | float,
                   origin_of: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(segment, light) index pairs (both (C,), by segment then light) whose segment origin + t·direction,
        0 < t < distance, meets the light's box: directions (3, S), distances (S,) or a scalar, origins (3, S) or,
        with ``origin_of`` (S,), (3, M) indexed by it."""
        d = np.asarray(directions, dtype=np.float64)
        s = d.shape[1]
        o = np.asarray(origins, dtype=np.float64)
        tmax = np.broadcast_to(np.asarray(distances, dtype=np.float64), (s,))
        with np.errstate(divide="ignore"):  # ±1e300 for axis-parallel directions: (box − o)·inv stays finite
            inv = np.where(d == 0, np.copysign(1e300, d), 1.0 / np.where(d == 0, 1.0, d))
        seg = np.arange(s)
        node = np.zeros(s, dtype=np.int64)
        found_seg, found_light = [], []
        while seg.size:
            rows = seg if origin_of is None else origin_of[seg]
            near = np.zeros(seg.size)  # the segments start at t = 0
            far = tmax[seg].copy()
            for axis in range(3):
                oa, ia = o[axis].take(rows), inv[axis].take(seg)
                t0 = (self.lower[:, axis].take(node) - oa) * ia
                t1 = (self.upper[:, axis].take(node) - oa) * ia
                np.maximum(near, np.minimum(t0, t1), out=near)
                np.minimum(far, np.maximum(t0, t1), out=far)
            hit = near <= far
            seg, node = seg[hit], node[hit]
            leaf = self.children[:, 0].take(node) < 0
            found_seg.append(seg[leaf])
            found_light.append(self.light.take(node[leaf]))
            inner = ~leaf
            seg = np.repeat(seg[inner], 2)
            node = self.children[node[inner]].reshape(-1)
        if not found_seg:  # no segments
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        seg_all, light_all = np.concatenate(found_seg), np.concatenate(found_light)
        order = np.lexsort((light_all, seg_all))
        return seg_all[order], light_all[order]


# -- light selection by region --------------------------------------------------------------------------------------
#: Largest number of (cell, light) entries of a :class:`LightGrid`'s tables (float64 pmf and CDF, int32 guide: 20
#: bytes each, 42 MB per process at the limit). The cell size is the smallest that keeps the occupied cells within it.
GRID_ENTRIES = 1 << 21

#: Largest number of cells of a :class:`LightGrid`'s dense cell → row map (int32: 8 MB at the limit).
GRID_CELLS = 1 << 21


class LightGrid:
    """Light selection in O(1) per draw: one distribution per cell of a uniform grid, for the points inside it.

    Drawing from :class:`LightBVH` costs one importance evaluation of two children per level and draw — ten levels
    for 272 lights, most of a many-lights capture's time in numpy. Here every occupied cell c (one that a scene
    triangle's box reaches: path vertices lie on triangles) holds the distribution

        P(ℓ | c) ∝ I(c, ℓ) = Φ_ℓ · cos θ'_c / max(d², (R_ℓ + h)²)          (pbrt-v4 ``LightBounds::Importance``)

    the BVH leaf's importance of light ℓ (power Φ, bounding sphere of radius R about the box centre) seen from the
    cell's centre, with the light's sphere grown by the cell's bounding radius h: the cone θ_b it subtends is the one
    every direction between a point of the light and a point of the cell lies in, so I(c, ℓ) > 0 wherever ℓ can
    light a point of c (next-event estimation stays unbiased), and the distance term is flattened within a cell's
    reach of the light. A draw inverts the cell's CDF with a guide table (Chen & Asau 1974; Devroye 1986
    §III.2.4: per bucket i of [0, 1) in L buckets, the first light whose CDF exceeds i/L, then steps forward
    while CDF ≤ u — fewer than two on average); the probability of a light is a table entry. Points in no
    occupied cell (outside the grid, or a hit rounded across a cell's face) draw from the BVH, so every point has
    one well-defined distribution.

    The grid spans the scene's triangles within the lights' box grown by half its largest extent on every side
    (beyond it every light is far from every point and the BVH's clustering is accurate); its cubic cells are the
    smallest whose occupied count times the lights stays within :data:`GRID_ENTRIES`.
    """

    def __init__(self, tree: LightBVH, lower: np.ndarray, upper: np.ndarray) -> None:
        """``tree``: the BVH over the lights (its leaves give their bounds, and it serves the points outside the
        grid); ``lower``, ``upper`` (T, 3): the boxes of every triangle a path vertex can lie on."""
        self.tree = tree
        lights = tree.size
        leaf = np.full(lights, -1, dtype=np.int64)
        leaf[tree.light[tree.light >= 0]] = np.flatnonzero(tree.light >= 0)
        self._leaf = leaf
        self.rows, self.shape, self._cell_row = 0, (0, 0, 0), None
        t_lo, t_hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
        if lights > GRID_ENTRIES or not t_lo.size:
            return
        l_lo, l_hi = tree.lower[0], tree.upper[0]  # the root's box: every light
        grow = 0.5 * float(np.max(l_hi - l_lo)) + 1e-3
        lo = np.maximum(t_lo.min(axis=0), l_lo - grow)
        hi = np.minimum(t_hi.max(axis=0), l_hi + grow)
        keep = np.all((t_hi >= lo) & (t_lo <= hi), axis=1)  # triangles whose box meets the grid's
        t_lo, t_hi = np.maximum(t_lo[keep], lo), np.minimum(t_hi[keep], hi)
        if not t_lo.size:
            return
        extent = np.maximum(hi - lo, 1e-6)

        def occupancy(size: float) -> tuple[np.ndarray, np.ndarray] | None:
            shape = np.maximum(1, np.ceil(extent / size).astype(np.int64))
            if np.prod(shape) > GRID_CELLS:
                return None
            occupied = self._occupancy(lo, size, shape, t_lo, t_hi)
            return (shape, occupied) if occupied.sum() * lights <= GRID_ENTRIES else None

        step = 2.0 ** (1.0 / 3.0)  # cells halve in volume per step
        size = float(np.prod(extent) / min(GRID_CELLS, GRID_ENTRIES // lights)) ** (1.0 / 3.0)
        found = occupancy(size)
        while found is None:  # ceil() may overshoot the dense budget: coarser until it fits
            size *= step
            found = occupancy(size)
        for _ in range(15):  # then finer while the occupied cells fit (surfaces fill a fraction of the box)
            finer = occupancy(size / step)
            if finer is None:
                break
            size, found = size / step, finer
        shape, occupied = found
        self.lo, self.size, self.shape = lo, size, tuple(int(s) for s in shape)
        cells = np.flatnonzero(occupied.reshape(-1))
        self.rows = int(cells.size)
        self._cell_row = np.full(occupied.size, -1, dtype=np.int32)
        self._cell_row[cells] = np.arange(cells.size, dtype=np.int32)
        ijk = np.stack(np.unravel_index(cells, shape), axis=0).astype(np.float64)  # (3, C)
        centres = lo[:, None] + (ijk + 0.5) * size
        h = 0.5 * math.sqrt(3.0) * size * (1.0 + 1e-4) + 1e-6  # the cell's bounding radius, padded
        self._pmf = self._distributions(centres, h)  # (C, L) float64, rows summing to 1 (or all 0)
        cdf = np.cumsum(self._pmf, axis=1)
        reached = cdf[:, -1] > 0
        cdf[reached] /= cdf[reached, -1:]
        cdf[reached, -1] = 1.0
        # guide table (Chen & Asau 1974; Devroye 1986 §III.2.4): per row and bucket i of [0, 1) in L buckets, the
        # first light with CDF > i/L; a draw starts there and steps forward while CDF ≤ u (≤ 2 steps expected)
        buckets = np.arange(lights) / lights
        self._guide = np.stack([np.searchsorted(row, buckets, side="right") for row in cdf]).astype(np.int32)
        np.minimum(self._guide, lights - 1, out=self._guide)  # rows no light reaches: CDF 0 everywhere
        self._guide = self._guide.reshape(-1)
        cdf[~reached] = 2.0  # no step beyond a row no light reaches: its draws get pmf 0 (light −1)
        self._cdf = cdf.reshape(-1)
        self._pmf = self._pmf.reshape(-1)

    @staticmethod
    def _occupancy(lo: np.ndarray, size: float, shape: np.ndarray, t_lo: np.ndarray, t_hi: np.ndarray) -> np.ndarray:
        """bool (shape) of the cells that the triangle boxes (T, 3) meet."""
        occupied = np.zeros(tuple(int(s) for s in shape), dtype=bool)
        c_lo = np.clip(np.floor((t_lo - lo) / size).astype(np.int64), 0, shape - 1)
        c_hi = np.clip(np.floor((t_hi - lo) / size).astype(np.int64), 0, shape - 1)
        single = np.all(c_lo == c_hi, axis=1)
        occupied[tuple(c_lo[single].T)] = True
        for a, b in np.unique(np.hstack([c_lo[~single], c_hi[~single]]), axis=0).reshape(-1, 2, 3):
            occupied[a[0]:b[0] + 1, a[1]:b[1] + 1, a[2]:b[2] + 1] = True
        return occupied

    def _distributions(self, centres: np.ndarray, h: float) -> np.ndarray:
        """P(ℓ | c) (C, L) float64 of cells with centres (3, C) and bounding radius h (class docstring), in row
        chunks of at most 2¹⁸ entries (the temporaries stay small; each row is computed alone)."""
        out = np.empty((centres.shape[1], self.tree.size))
        step = max(1, (1 << 18) // self.tree.size)
        for r0 in range(0, centres.shape[1], step):
            out[r0 : r0 + step] = self._distribution_rows(centres[:, r0 : r0 + step], h)
        return out

    def _distribution_rows(self, centres: np.ndarray, h: float) -> np.ndarray:
        """:meth:`_distributions` of the cells with centres (3, C)."""
        tree, leaf = self.tree, self._leaf
        c = centres[:, :, None]  # (3, C, 1) against the lights (L,)
        t = c - tree.centre[leaf].T[:, None, :]  # light centre → cell centre
        d2 = np.sum(t * t, axis=0)
        reach2 = (np.sqrt(tree.half_diagonal2[leaf]) + h) ** 2  # (L,): the light's sphere grown by the cell's
        value = tree.power[leaf] / np.maximum(d2, reach2)
        cone = ~tree._omni[leaf]
        if cone.any():
            j = np.flatnonzero(cone)
            a = tree._packed_cone[leaf[j]].T.astype(np.float64)  # (6, J): axis, sin/cos θ_o, cos θ_e
            value[:, j] = LightBVH._oriented(value[:, j], t[0][:, j], t[1][:, j], t[2][:, j], d2[:, j],
                                             np.broadcast_to(reach2[j], d2[:, j].shape), *a[:, None, :])
        total = value.sum(axis=1, keepdims=True)
        return np.where(total > 0, value / np.where(total > 0, total, 1.0), 0.0)

    def _rows_of(self, points: np.ndarray) -> np.ndarray:
        """The table row (M,) of points (3, M): their occupied cell's, or −1 (outside the grid or unoccupied)."""
        if self._cell_row is None:
            return np.full(points.shape[1], -1, dtype=np.int64)
        p = (np.asarray(points, dtype=np.float64) - self.lo[:, None]) / self.size
        ijk = np.floor(p).astype(np.int64)
        shape = np.array(self.shape)[:, None]
        inside = np.all((ijk >= 0) & (ijk < shape), axis=0)
        flat = np.ravel_multi_index(tuple(np.where(inside, ijk, 0)), self.shape)
        return np.where(inside, self._cell_row[flat], -1).astype(np.int64)

    def sample(self, points: np.ndarray, u: np.ndarray, draws: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """``draws`` lights per point (3, M) from uniform numbers u (draws·M,) float64 in [0, 1) (draw-major):
        light indices (draws·M,) (−1 where no light can reach the point) and their selection probabilities
        (draws·M,) float64 (0 there), the same bits as :meth:`pmf` gives for them."""
        points = np.asarray(points)
        rows = np.tile(self._rows_of(points), draws)
        if draws > 1:
            points = np.tile(points, (1, draws))
        light = np.full(rows.size, -1, dtype=np.int64)
        pmf = np.zeros(rows.size)
        inside = np.flatnonzero(rows >= 0)
        if inside.size:
            lights = self.tree.size
            base = rows[inside] * lights
            ui = np.asarray(u, dtype=np.float64)[inside]
            j = self._guide[base + (ui * lights).astype(np.int64)].astype(np.int64)  # u < 1: bucket < L
            step = np.flatnonzero(self._cdf[base + j] <= ui)  # the first light with CDF > u (the row's last: 1)
            while step.size:
                j[step] += 1
                step = step[self._cdf[base[step] + j[step]] <= ui[step]]
            p = self._pmf[base + j]
            light[inside], pmf[inside] = np.where(p > 0, j, -1), p
        outside = np.flatnonzero(rows < 0)
        if outside.size:
            light[outside], pmf[outside] = self.tree.sample(np.asarray(points)[:, outside],
                                                            np.asarray(u)[outside])
        return light, pmf

    def pmf(self, points: np.ndarray, lights: np.ndarray) -> np.ndarray:
        """The probability (M,) float64 that :meth:`sample` picks ``lights`` (M,) at points (3, M)."""
        lights = np.asarray(lights, dtype=np.int64)
        rows = self._rows_of(points)
        out = np.zeros(rows.size)
        inside = np.flatnonzero(rows >= 0)
        if inside.size:
            out[inside] = self._pmf[rows[inside] * self.tree.size + lights[inside]]
        outside = np.flatnonzero(rows < 0)
        if outside.size:
            out[outside] = self.tree.pmf(np.asarray(points)[:, outside], lights[outside])
        return out
