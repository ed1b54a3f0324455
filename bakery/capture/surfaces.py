"""Material parameters at ray hits: per-triangle constants, or textures looked up per hit (mip-mapped).

Each mesh has one :class:`bakery.capture.scene.Material`; its textured inputs (``Material.maps``) are evaluated at
the hit's texture coordinates (the mesh's ``uvs`` interpolated with the hit's barycentrics), as UsdUVTexture does:
``value = scale · texel + bias`` with ``wrapS``/``wrapT`` (repeat, mirror, clamp, black; the reader resolves
"useMetadata" to black); a gprim without texture coordinates is read at its primvar reader's fallback st (a
constant ``st_transform``, :func:`bakery.usd.materials.read_at_fallback_st`). An entry with a ``primvar`` reads a
colour per vertex instead (the mesh's ``colors`` at the hit's barycentrics); one with a ``tint_primvar`` multiplies
its texel by it
(``value = scale · texel · colour + bias``: a MaterialX ``multiply`` of an image graph by a ``geompropvalue``).

Explicit Fresnel (``Material.explicit_fresnel``: a MaterialX metal's weight, F82 tint or conductor edge, or a
dielectric F90 given as is)
    F0 and F90 are built share by share — the dielectric share (1 − m): F0(ior)·specular_tint and F90 =
    ``dielectric_f90``, else min(1, 50·F0(ior))·specular_edge_tint; the metallic share m, of reflectivity F0_m =
    clamp(diffuse, 0, 1): open_pbr's ``metal_bsdf`` m·w·F0_m and m·w (F90 = 1) with the F82 term b = m·w·a(F0_m,
    F82), or standard_surface's conductor of weight m and complex IOR ``artistic_ior``(F0_m, edge colour) — all
    times the coat's tint (:class:`bakery.capture.bsdf.Fresnel`). Per hit from the textured diffuse and metallic in
    both paths (:meth:`Surfaces._point`, :meth:`Surfaces._textured_soa`); materials without these fields keep
    F90 = min(1, 50·luminance(F0)) of the mixed F0, as before.

MaterialX layering (``Material.layering`` "materialx"; :mod:`bakery.capture.bsdf` "MaterialX layering")
    Per hit in both paths, what the BSDF's :class:`~bakery.capture.bsdf.Layering` needs beyond F0 and F90: the
    dielectric specular layer's share of the lobe's Schlick terms, coat·(1 − m)·F0(ior)·specular_tint and
    coat·(1 − m)·F90_d (F90_d = ``dielectric_f90``, else min(1, 50·F0(ior))·specular_edge_tint); that layer's own
    Schlick terms and weight — ``Material.specular_layer`` (u0, u90, w): F0(ior)·u0, min(1, 50·F0(ior))·u90 and w,
    else the share's own F0(ior)·specular_tint, F90_d and 1 —; and the metal share's weight coat·m·``metal_weight``
    (the specular workflow: the whole lobe is the layer's, of weight 1). Materials without it get zeros and no
    flag: their points shade as before.

Filtering
    Textures are mip-mapped (2×2 box pyramid, built once per texture) and looked up trilinearly. The level of detail
    comes from the ray's footprint: a ray of angular spread σ (the probe texel's angular size for primary rays,
    :data:`BOUNCE_SPREAD` for bounce rays) covers ≈ t·σ metres at distance t, i.e. t·σ·√(A_uv/A_world)·resolution
    texels of that triangle, so a probe texel averages the texture over its footprint instead of aliasing it.

Normal maps (UsdPreviewSurface ``normal``: a tangent-space normal in [−1, 1]³, i.e. the texture's scale/bias
already applied, as its specification asks)
    n = normalize(x·T + y·B + z·N) with N the unperturbed shading normal on the triangle's front (winding) side,
    T = dP/ds of the triangle orthogonalised against N, B = ±N × T with the sign of the triangle's (dP/ds, dP/dt,
    normal) handedness (right-handed tangent space: x along +s, y along +t, z out of the surface); a hit on the
    back side mirrors n with the surface. Where the mapped normal faces away from the viewer (or z ≤ 0) the
    unperturbed one is kept; as for authored normals, directions below the geometric surface get no BSDF value.
    A world-space map (entry ``space`` "world": MaterialX ``normalize`` of a decoded image, the surfaces' ``normal``
    being in world space) gives n in stage axes, turned into the bake frame (:func:`bakery.conventions.
    stage_to_bake_axes`); a back-side hit sees it mirrored, and it is kept only on the front side of the surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bakery.capture.bsdf import SHEEN_LAYERS, Fresnel, Layering, Sheen, artistic_ior, f82_coefficient
from bakery.capture.scene import CaptureScene, Material
from bakery.conventions import LUMINANCE_WEIGHTS, stage_to_bake_axes

#: Angular spread (radians) assumed for bounce rays (diffuse-like): textures seen after a bounce are blurred.
BOUNCE_SPREAD = 0.05
_INPUTS = ("diffuseColor", "emissiveColor", "roughness", "metallic", "specularColor", "opacity", "ior")


@dataclass(frozen=True)
class SurfacePoint:
    """Material parameters at M hits."""

    albedo: np.ndarray
    f0: np.ndarray
    roughness: np.ndarray
    emission: np.ndarray
    opacity: np.ndarray
    threshold: np.ndarray
    f90: np.ndarray | None = None
    #: the metal terms (M, 3) each, when some material has them (:class:`bakery.capture.bsdf.Fresnel`): the F82
    #: term's coefficient b, and the conductor's weight, η and κ; None otherwise
    f82: np.ndarray | None = None
    conductor: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    #: MaterialX's layering terms when some material has them (module docstring "MaterialX layering"): the
    #: dielectric share's Schlick F0 and F90, the layer's own F0 and F90 (M, 3) each, its weight (M,), the metal's
    #: weight (M, 3) and whether the hit is layered (M,) bool; None otherwise
    layering: tuple[np.ndarray, ...] | None = None


#: rows of a layering block (share F0, share F90, own F0, own F90, weight, metal weight, flag)
LAYER_ROWS = 17


def transformed_st(entry: dict, s: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A map entry's texture coordinates after its ``st_transform`` ((a, b, tx), (c, d, ty)): s' = a·s + b·t + tx,
    t' = c·s + d·t + ty (UsdTransform2d, MaterialX ``place2d`` and ``tiledimage`` tiling, composed at read time),
    and the factor √|ad − bc| by which it scales a footprint's size in texture space (the level of detail)."""
    transform = entry.get("st_transform")
    if transform is None:
        return s, t, 1.0
    (a, b, tx), (c, d, ty) = transform
    dtype = s.dtype.type
    return (dtype(a) * s + dtype(b) * t + dtype(tx), dtype(c) * s + dtype(d) * t + dtype(ty),
            float(np.sqrt(abs(a * d - b * c))))


class MipTexture:
    """A texture as a mip pyramid of (H, W, 4) float64 levels with wrap modes, looked up trilinearly."""

    def __init__(self, pixels: np.ndarray) -> None:
        level = np.asarray(pixels, dtype=np.float64)
        if level.ndim == 2:
            level = level[..., None]
        c = level.shape[2]
        if c < 4:
            rgb = level[..., :3] if c >= 3 else np.repeat(level[..., :1], 3, axis=2)
            alpha = level[..., 1:2] if c == 2 else np.ones(level.shape[:2] + (1,))
            level = np.concatenate([rgb, alpha], axis=2)
        self.levels = [level]
        while max(level.shape[:2]) > 1:
            h, w = level.shape[:2]
            if h > 1:
                level = 0.5 * (level[0 : h - h % 2 : 2] + level[1 : h - h % 2 + 1 : 2]) if h % 2 == 0 else \
                    _shrink(level, 0)
            if w > 1:
                level = 0.5 * (level[:, 0 : w - w % 2 : 2] + level[:, 1 : w - w % 2 + 1 : 2]) if w % 2 == 0 else \
                    _shrink(level, 1)
            self.levels.append(level)
        self.height, self.width = self.levels[0].shape[:2]
        # all levels as one channel-major float32 table (4, Σ h·w) with per-level offsets and sizes, for
        # :meth:`lookup_soa`
        sizes = [lvl.shape[:2] for lvl in self.levels]
        self._flat = np.ascontiguousarray(np.concatenate([lvl.reshape(-1, 4) for lvl in self.levels]).T,
                                          dtype=np.float32)
        self._offset = np.cumsum([0] + [h * w for h, w in sizes[:-1]]).astype(np.int64)
        self._h = np.array([h for h, _ in sizes], dtype=np.int64)
        self._w = np.array([w for _, w in sizes], dtype=np.int64)

    def lookup_soa(self, s: np.ndarray, t: np.ndarray, lod: np.ndarray, wrap: tuple[str, str],
                   channels: tuple[int, ...]) -> list[np.ndarray]:
        """:meth:`lookup` for float32 coordinates s, t and level of detail (M,), returning the ``channels`` (0–3)
        as a list of (M,) arrays; every level is looked up in one pass (per-element level sizes)."""
        top = len(self.levels) - 1
        lod = np.clip(lod, 0, top)
        l0 = lod.astype(np.int64)  # floor (lod ≥ 0)
        frac = lod - l0
        a = self._bilinear_soa(l0, s, t, wrap, channels)
        blend = np.flatnonzero(frac > 0)  # footprints under a texel (lod 0) need no second level
        if blend.size == 0:
            return a
        fb = frac[blend]
        b = self._bilinear_soa(np.minimum(l0[blend] + 1, top), s[blend], t[blend], wrap, channels)
        for x, y in zip(a, b):
            x[blend] = x[blend] * (1 - fb) + y * fb
        return a

    def _bilinear_soa(self, level: np.ndarray, s: np.ndarray, t: np.ndarray, wrap: tuple[str, str],
                      channels: tuple[int, ...]) -> list[np.ndarray]:
        h, w = np.take(self._h, level), np.take(self._w, level)
        offset = np.take(self._offset, level)
        x = s * w.astype(s.dtype) - 0.5
        y = (1 - t) * h.astype(t.dtype) - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = x - x0, y - y0
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        out = [np.zeros(s.shape, dtype=s.dtype) for _ in channels]
        for dx, dy, weight in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy),
                               (1, 1, fx * fy)):
            cx, vx = _wrap(x0 + dx, w, wrap[0])
            cy, vy = _wrap(y0 + dy, h, wrap[1])
            index = offset + cy * w + cx
            if wrap[0] == "black" or wrap[1] == "black":
                weight = weight * (vx & vy)
            for acc, c in zip(out, channels):
                acc += weight * np.take(self._flat[c], index)
        return out

    def lookup(self, st: np.ndarray, lod: np.ndarray, wrap: tuple[str, str]) -> np.ndarray:
        """RGBA (M, 4) at texture coordinates st (M, 2) (s right, t up: t = 1 is row 0) and level of detail (M,)."""
        lod = np.clip(lod, 0.0, len(self.levels) - 1.0)
        l0 = np.floor(lod).astype(np.int64)
        frac = (lod - l0)[:, None]
        result = np.zeros((st.shape[0], 4))
        for level in np.unique(l0):
            sel = np.flatnonzero(l0 == level)
            a = self._bilinear(int(level), st[sel], wrap)
            if level + 1 < len(self.levels):
                b = self._bilinear(int(level) + 1, st[sel], wrap)
                result[sel] = a * (1.0 - frac[sel]) + b * frac[sel]
            else:
                result[sel] = a
        return result

    def _bilinear(self, level: int, st: np.ndarray, wrap: tuple[str, str]) -> np.ndarray:
        image = self.levels[level]
        h, w = image.shape[:2]
        x = st[:, 0] * w - 0.5
        y = (1.0 - st[:, 1]) * h - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        out = np.zeros((st.shape[0], 4))
        for dx, dy, weight in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy),
                               (1, 1, fx * fy)):
            cx, vx = _wrap(x0 + dx, w, wrap[0])
            cy, vy = _wrap(y0 + dy, h, wrap[1])
            out += weight * np.where((vx & vy)[:, None], image[cy, cx], 0.0)
        return out


class UdimTexture:
    """UDIM tiles (``<UDIM>`` in a UsdUVTexture file): tile 1001 + ⌊s⌋ + 10·⌊t⌋ (0 ≤ ⌊s⌋ < 10) is looked up at
    (s − ⌊s⌋, t − ⌊t⌋) with clamped edges; coordinates on a missing tile read black, as Hydra does. The same
    interface as :class:`MipTexture`."""

    def __init__(self, tiles: dict[int, MipTexture]) -> None:
        self.tiles = tiles
        self.width = max(t.width for t in tiles.values())
        self.height = max(t.height for t in tiles.values())

    def _split(self, s: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u, v = np.floor(s), np.floor(t)
        tile = np.where((u >= 0) & (u < 10) & (v >= 0), 1001 + u + 10 * v, -1).astype(np.int64)
        return tile, s - u, t - v

    def lookup_soa(self, s: np.ndarray, t: np.ndarray, lod: np.ndarray, wrap: tuple[str, str],
                   channels: tuple[int, ...]) -> list[np.ndarray]:
        tile, ls, lt = self._split(s, t)
        out = [np.zeros(s.shape, dtype=s.dtype) for _ in channels]
        for number, texture in self.tiles.items():
            sel = np.flatnonzero(tile == number)
            if sel.size:
                values = texture.lookup_soa(ls[sel], lt[sel], lod[sel], ("clamp", "clamp"), channels)
                for acc, value in zip(out, values):
                    acc[sel] = value
        return out

    def lookup(self, st: np.ndarray, lod: np.ndarray, wrap: tuple[str, str]) -> np.ndarray:
        tile, ls, lt = self._split(st[:, 0], st[:, 1])
        out = np.zeros((st.shape[0], 4))
        for number, texture in self.tiles.items():
            sel = np.flatnonzero(tile == number)
            if sel.size:
                out[sel] = texture.lookup(np.stack([ls[sel], lt[sel]], axis=1), lod[sel], ("clamp", "clamp"))
        return out


def _tangent_frames(triangles: np.ndarray, uvs: np.ndarray) -> np.ndarray:
    """Per-triangle tangent frames (4, T) float32: dP/ds (rows 0–2, unit; the edge direction where the texture
    coordinates are degenerate) and the handedness ±1 (row 3) of (dP/ds, dP/dt, winding normal), from the
    triangle's positions (T, 3, 3) and texture coordinates (T, 3, 2) — [dP/ds dP/dt] = [e1 e2]·[Δuv1 Δuv2]⁻¹."""
    tris = np.asarray(triangles, dtype=np.float64)
    uv = np.asarray(uvs, dtype=np.float64)
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-20
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    dp_ds = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv
    dp_dt = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv
    normal = np.cross(e1, e2)
    dp_ds = np.where(ok[:, None], dp_ds, e1)
    length = np.linalg.norm(dp_ds, axis=1, keepdims=True)
    dp_ds = dp_ds / np.maximum(length, 1e-300)
    handed = np.where(np.einsum("ij,ij->i", np.cross(normal, dp_ds), dp_dt) < 0, -1.0, 1.0)
    return np.ascontiguousarray(np.concatenate([dp_ds.T, handed[None]]), dtype=np.float32)


def _shrink(level: np.ndarray, axis: int) -> np.ndarray:
    """Halve an odd-sized axis by averaging overlapping pairs (keeps the mean close)."""
    n = level.shape[axis]
    m = max(1, n // 2)
    edges = np.linspace(0, n, m + 1)
    parts = []
    for i in range(m):
        lo, hi = int(math.floor(edges[i])), int(math.ceil(edges[i + 1]))
        parts.append(np.take(level, np.arange(lo, hi), axis=axis).mean(axis=axis, keepdims=True))
    return np.concatenate(parts, axis=axis)


def _wrap(index: np.ndarray, size: int, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """Wrapped integer texel indices and whether the texel exists (``black`` outside)."""
    i = index.astype(np.int64)
    if mode == "clamp":
        return np.clip(i, 0, size - 1), np.ones(i.shape, dtype=bool)
    if mode == "black":
        inside = (i >= 0) & (i < size)
        return np.clip(i, 0, size - 1), inside
    if mode == "mirror":
        period = np.mod(i, 2 * size)
        return np.where(period < size, period, 2 * size - 1 - period), np.ones(i.shape, dtype=bool)
    return np.mod(i, size), np.ones(i.shape, dtype=bool)


def _channels(rgba: np.ndarray, channels: str) -> np.ndarray:
    index = {"r": 0, "g": 1, "b": 2, "a": 3}
    if channels in index:
        return rgba[:, index[channels]]
    return rgba[:, :3]


def _explicit_fresnel(metallic, reflectivity, dielectric, spec, edge, coat, weight, f82,  # noqa: ANN001
                      f90_given, has_f90, conductor, edge_color) -> tuple[np.ndarray, ...]:
    """F0, F90, the F82 term's b, and the conductor's weight, η, κ, channel-major (3, M) each, of the module
    docstring's "Explicit Fresnel": per hit metallic m (M,), reflectivity F0_m = clamp(diffuse, 0, 1) (3, M) and the
    dielectric F0(ior) (M,); per material (3, M) or (3, 1) the specular tint, edge tint, coat tint, F82 tint, F90
    given and edge colour, the metal weight (M,) or scalar, whether F90 is given and whether the metal is a
    conductor ((M,) bool or scalar)."""
    share = 1 - metallic
    f90_d = np.where(has_f90, f90_given, np.minimum(1, 50 * dielectric) * edge)
    schlick = metallic * weight  # open_pbr metal_bsdf: Schlick(F0_m, 1)·w on the metallic share
    metal = np.where(conductor, 0, schlick)
    f0 = np.clip(coat * (share * dielectric * spec + metal * reflectivity), 0, 1)
    f90 = coat * (share * f90_d + metal)
    b = coat * (metal * f82_coefficient(reflectivity, f82))
    eta, kappa = artistic_ior(reflectivity, edge_color)
    cw = coat * np.where(conductor, metallic, 0)
    return f0, f90, b, cw, eta, kappa


def _layer_terms(metallic, dielectric, spec, edge, coat, f90_given, has_f90, metal_weight, given,  # noqa: ANN001
                 layer) -> tuple[np.ndarray, ...]:
    """The module docstring's "MaterialX layering" terms, channel-major: the dielectric share's Schlick F0 and F90,
    the layer's own F0 and F90 (3, M) each, its weight (M,) and the metal's weight (3, M), from per hit metallic m
    and the dielectric F0(ior) (M,), per material (3, M) or (3, 1) the specular, edge and coat tints and the F90
    given, the layer's (u0, u90, w) (3 rows of (M,) or scalars), and (M,) or scalar whether F90 is given, the
    metal weight and whether the layer's own terms are given (``Material.specular_layer``)."""
    share = 1 - metallic
    rule = np.minimum(1, 50 * dielectric)
    f90_d = np.where(has_f90, f90_given, rule * edge)
    u0, u90, w = layer
    own0 = np.where(given, dielectric * u0, dielectric * spec)
    own90 = np.where(given, rule * u90, f90_d)
    return (coat * (share * dielectric * spec), coat * (share * f90_d), own0, own90,
            np.where(given, w, 1) * np.ones_like(share), coat * (metallic * metal_weight))


class Surfaces:
    """Per-hit material parameters of a scene (see module docstring)."""

    def __init__(self, scene: CaptureScene, tracer) -> None:  # noqa: ANN001 - SceneTracer
        self.materials: list[Material] = [mesh.material for mesh in scene.meshes]
        self.mesh_of = tracer.mesh_of
        mats = self.materials or [Material()]
        self.base = {
            "diffuseColor": np.array([m.diffuse for m in mats], dtype=np.float64).reshape(-1, 3),
            "emissiveColor": np.array([m.emission for m in mats], dtype=np.float64).reshape(-1, 3),
            "roughness": np.array([m.roughness for m in mats], dtype=np.float64),
            "metallic": np.array([m.metallic for m in mats], dtype=np.float64),
            "specularColor": np.array([m.specular for m in mats], dtype=np.float64).reshape(-1, 3),
            "opacity": np.array([m.opacity for m in mats], dtype=np.float64),
            "ior": np.array([m.ior for m in mats], dtype=np.float64),
        }
        self.specular_workflow = np.array([m.use_specular_workflow for m in mats], dtype=bool)
        #: (N, 3) each material's dielectric specular tint and coat tint (Material), or None when none is tinted:
        #: the BSDF then derives F90 from F0 alone, exactly as without them
        self.specular_tint = self.coat_tint = self.edge_tint = None
        #: (N,) bool: the metallic share's F90 is the albedo (Material.metal_edge_albedo, UsdPreviewSurface's
        #: metallic workflow), where some material's F90 then differs from the one derived from F0
        self.metal_edge = np.array([m.metal_edge_albedo and not m.use_specular_workflow for m in mats], dtype=bool)
        metal_edge = any(edge and (m.metallic > 0 or any(entry.get("input") == "metallic" for entry in m.maps))
                         for edge, m in zip(self.metal_edge, mats))
        #: (N,) bool: the material's F0 and F90 are built share by share (module docstring "Explicit Fresnel")
        self.explicit = np.array([m.explicit_fresnel for m in mats], dtype=bool)
        #: per-material explicit Fresnel inputs (metal weight (N,), F82 tint (N, 3), F90 given (N, 3) and whether
        #: (N,), conductor (N,) and its edge colour (N, 3)), or None when no material's Fresnel is explicit
        self.explicit_inputs = None
        #: whether some material has a metal's F82 or conductor term: params_soa's F90 is then a Fresnel
        self.metal_terms = False
        if self.explicit.any():
            white = (1.0, 1.0, 1.0)
            self.explicit_inputs = (
                np.array([m.metal_weight for m in mats], dtype=np.float64),
                np.array([white if m.metal_f82 is None else m.metal_f82 for m in mats], dtype=np.float64),
                np.array([white if m.dielectric_f90 is None else m.dielectric_f90 for m in mats], dtype=np.float64),
                np.array([m.dielectric_f90 is not None for m in mats], dtype=bool),
                np.array([m.metal_edge_color is not None for m in mats], dtype=bool),
                np.array([white if m.metal_edge_color is None else m.metal_edge_color for m in mats],
                         dtype=np.float64))
            self.metal_terms = any(x and (m.metal_f82 is not None or m.metal_edge_color is not None)
                                   for x, m in zip(self.explicit, mats))
        if metal_edge or self.explicit.any() or any(
                tuple(m.specular_tint) != (1.0, 1.0, 1.0) or tuple(m.coat_tint) != (1.0, 1.0, 1.0)
                or m.specular_edge_tint is not None for m in mats):
            self.specular_tint = np.array([m.specular_tint for m in mats], dtype=np.float64).reshape(-1, 3)
            self.coat_tint = np.array([m.coat_tint for m in mats], dtype=np.float64).reshape(-1, 3)
            self.edge_tint = np.array([m.specular_tint if m.specular_edge_tint is None else m.specular_edge_tint
                                       for m in mats], dtype=np.float64).reshape(-1, 3)
        #: (N,) bool: the material shades with MaterialX's layering (module docstring "MaterialX layering")
        self.layered = np.array([m.layering == "materialx" for m in mats], dtype=bool)
        #: per-material layering inputs (the specular layer's (u0, u90, w) (N, 3) and whether given (N,), the metal
        #: weight (N,), the dielectric F90 given (N, 3) and whether (N,)), or None when no material is layered
        self.layer_inputs = None
        if self.layered.any():
            white = (1.0, 1.0, 1.0)
            self.layer_inputs = (
                np.array([white if m.specular_layer is None else m.specular_layer for m in mats], dtype=np.float64),
                np.array([m.specular_layer is not None for m in mats], dtype=bool),
                np.array([m.metal_weight for m in mats], dtype=np.float64),
                np.array([white if m.dielectric_f90 is None else m.dielectric_f90 for m in mats], dtype=np.float64),
                np.array([m.dielectric_f90 is not None for m in mats], dtype=bool))
        self.threshold = np.array([m.opacity_threshold for m in mats], dtype=np.float64)
        self.textured = [i for i, m in enumerate(self.materials) if m.maps]
        #: materials of partial presence: opacity < 1 (or textured) without an opacityThreshold — a hit passes
        #: through with probability 1 − opacity (stochastic presence)
        self.partial = np.array([m.opacity_threshold <= 0 and (m.opacity < 1 or any(
            entry.get("input") == "opacity" for entry in m.maps)) for m in mats], dtype=bool)
        self.stochastic = bool(self.partial.any())
        self.cutout = bool(np.any(self.threshold > 0)) or self.stochastic
        #: (3, materials) float32 ``transmission_tint`` of each material (what light passing through its absent part
        #: is multiplied by), or None when no material that can be passed through tints
        self.tint_soa = None
        if self.cutout and any(tuple(m.transmission_tint) != (1.0, 1.0, 1.0) for m in self.materials):
            self.tint_soa = np.ascontiguousarray(np.array([m.transmission_tint for m in mats], dtype=np.float32).T)
        self._textures: dict = {}  # MipTexture per texture index, UdimTexture per tile set
        self.scene = scene
        self.triangles = tracer.triangles
        self.uvs = None
        self.uv_density = None
        self._uvs_soa = None
        if self.textured:
            uvs = [np.asarray(m.uvs, dtype=np.float64).reshape(-1, 3, 2) if m.uvs is not None
                   else np.zeros((m.triangles.reshape(-1, 3, 3).shape[0], 3, 2)) for m in scene.meshes]
            self.uvs = np.concatenate(uvs) if uvs else np.zeros((0, 3, 2))
            tris = self.triangles
            area_w = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=-1)
            e1, e2 = self.uvs[:, 1] - self.uvs[:, 0], self.uvs[:, 2] - self.uvs[:, 0]
            area_uv = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
            self.uv_density = np.sqrt(area_uv / np.maximum(area_w, 1e-300))  # uv units per metre
        #: per-corner colours (T, 3, 3) of every triangle (zeros on meshes without them) for the colour inputs read
        #: per vertex (``Material.maps`` entries with a ``primvar``), and as float32 (9, T) rows, or None
        self.colors = self._colors_soa = None
        if any("primvar" in entry or "tint_primvar" in entry for m in self.materials for entry in m.maps):
            self.colors = np.concatenate([np.asarray(m.colors, dtype=np.float64).reshape(-1, 3, 3)
                                          if m.colors is not None else
                                          np.zeros((np.asarray(m.triangles).reshape(-1, 3, 3).shape[0], 3, 3))
                                          for m in scene.meshes])
            self._colors_soa = np.ascontiguousarray(self.colors.reshape(-1, 9).T, dtype=np.float32)

        # per-material BSDF parameters (rows: albedo rgb, F0 rgb, roughness, emission rgb, and F90 rgb with tints)
        # for the renderer's structure-of-arrays gathers; textured materials are re-evaluated per hit on top
        point = self._point({name: array.copy() for name, array in self.base.items()}, np.arange(len(mats)))
        self.table = np.ascontiguousarray(np.concatenate(
            [point.albedo.T, point.f0.T, point.roughness[None], point.emission.T]
            + ([] if point.f90 is None else [point.f90.T])
            + ([] if point.f82 is None else [point.f82.T, *(a.T for a in point.conductor)])
            + ([] if point.layering is None else [np.atleast_2d(np.asarray(a, dtype=np.float64).T)
                                                  for a in point.layering])), dtype=np.float32)
        #: the table's first layering row (module docstring "MaterialX layering"), or None
        self.layer_row = None if point.layering is None else 10 + 3 * self.tinted + 12 * self.metal_terms
        self.emissive = any(m.emits for m in self.materials)
        self.mesh_of_soa = np.ascontiguousarray(self.mesh_of, dtype=np.int32)
        #: (2, materials) float32 clearcoat amount and roughness — and a third row, the coat's F0, when some coat's
        #: is not 0.04 — or None when no material has a coat
        self.coat_table = None
        if any(m.clearcoat > 0 for m in self.materials):
            rows = [[m.clearcoat for m in mats], [m.clearcoat_roughness for m in mats]]
            if any(m.clearcoat > 0 and m.clearcoat_f0 != 0.04 for m in self.materials):
                rows.append([m.clearcoat_f0 for m in mats])
            self.coat_table = np.array(rows, dtype=np.float32)
        #: (2, materials) float32 Oren–Nayar roughness and energy compensation (1/0), or None when every diffuse
        #: lobe is Lambertian
        self.rough_table = None
        if any(m.diffuse_roughness > 0 for m in self.materials):
            self.rough_table = np.array([[m.diffuse_roughness for m in mats],
                                         [float(m.diffuse_energy_compensation) for m in mats]], dtype=np.float32)
        #: (7, materials) float32 sheen weight (× 1 − metallic over the dielectric's diffuse lobe alone), colour
        #: (× the coat's tint, unless the sheen lies over the coat), roughness, layer (SHEEN_LAYERS index) and mode
        #: (1: zeltner), or None when no material has sheen
        self.sheen_table = None
        if any(m.sheen > 0 for m in self.materials):
            def over_dielectric(m: Material) -> float:
                return 1.0 - min(max(m.metallic, 0.0), 1.0) if m.sheen_layer == "diffuse" else 1.0

            def under_coat(m: Material, c: int) -> float:
                return 1.0 if m.sheen_layer == "coat" else m.coat_tint[c]

            self.sheen_table = np.array(
                [[m.sheen * over_dielectric(m) for m in mats]]
                + [[m.sheen_color[c] * under_coat(m, c) for m in mats] for c in range(3)]
                + [[m.sheen_roughness for m in mats]]
                + [[SHEEN_LAYERS.index(m.sheen_layer) for m in mats]]
                + [[float(m.sheen_mode == "zeltner") for m in mats]], dtype=np.float32)
        #: materials with a UsdPreviewSurface ``normal`` map, and each one's map entry
        self.normal_maps = {k: next(e for e in m.maps if e.get("input") == "normal")
                            for k, m in enumerate(self.materials) if any(e.get("input") == "normal" for e in m.maps)}
        self._tangents = None
        self._stage_axes = stage_to_bake_axes(getattr(scene, "up_axis", "Y")).astype(np.float32)
        if self.normal_maps:  # and which triangles have texture coordinates (no tangent frame without them)
            self._tangents = _tangent_frames(self.triangles, self.uvs)
            for k, entry in self.normal_maps.items():  # a transformed map's frame: that of its coordinates
                if entry.get("st_transform") is not None:
                    rows = np.flatnonzero(np.asarray(self.mesh_of) == k)
                    (a, b, tx), (c, d, ty) = entry["st_transform"]
                    uv = self.uvs[rows]
                    moved = np.stack([a * uv[..., 0] + b * uv[..., 1] + tx, c * uv[..., 0] + d * uv[..., 1] + ty],
                                     axis=-1)
                    self._tangents[:, rows] = _tangent_frames(self.triangles[rows], moved)
            self._has_uv = np.concatenate([np.full(np.asarray(m.triangles).reshape(-1, 3, 3).shape[0],
                                                   m.uvs is not None) for m in scene.meshes])

    def coat_soa(self, prim: np.ndarray) -> tuple[np.ndarray, ...] | None:
        """Clearcoat amount and roughness (M,) at hits (and its F0 (M,) when some coat's is not 0.04), or None when
        no material has a coat."""
        if self.coat_table is None:
            return None
        mi = np.take(self.mesh_of_soa, prim)
        return tuple(np.take(row, mi) for row in self.coat_table)

    def rough_diffuse_soa(self, prim: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Oren–Nayar roughness (M,) and energy compensation (M,) bool at hits, or None (all Lambertian)."""
        if self.rough_table is None:
            return None
        mi = np.take(self.mesh_of_soa, prim)
        return np.take(self.rough_table[0], mi), np.take(self.rough_table[1], mi) > 0

    def sheen_soa(self, prim: np.ndarray) -> Sheen | None:
        """The sheen layer at hits (:class:`~bakery.capture.bsdf.Sheen`), or None when no material has sheen;
        its layer and mode are None where every material's are the defaults (over the diffuse lobe, Imageworks)."""
        if self.sheen_table is None:
            return None
        rows = [np.take(row, np.take(self.mesh_of_soa, prim)) for row in self.sheen_table]
        layer = rows[5].astype(np.int8) if bool(np.any(self.sheen_table[5] > 0)) else None
        zeltner = rows[6] > 0 if bool(np.any(self.sheen_table[6] > 0)) else None
        return Sheen(rows[0], np.stack(rows[1:4]), rows[4], layer, zeltner)

    def mapped_normals(self, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray, t: np.ndarray, spread: float,
                       shading: np.ndarray, back: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """Shading normals (3, M) perturbed by normal maps (module docstring "Normal maps"): ``shading`` (3, M) the
        unperturbed shading normals facing the viewer, ``back`` (M,) whether the hit is on the triangle's back
        (the side opposite its winding normal), ``wo`` (3, M) towards the viewer. Hits on other materials, and
        where the mapped normal faces away from the viewer, keep ``shading``."""
        mi = np.take(self.mesh_of_soa, prim)
        out = shading
        for k, entry in self.normal_maps.items():
            sel = np.flatnonzero((mi == k) & np.take(self._has_uv, prim))
            if sel.size == 0:
                continue
            p, u, v = np.take(prim, sel), np.take(bu, sel), np.take(bv, sel)
            n = np.take(shading, sel, axis=1)
            side = 1 - 2 * np.take(back, sel).astype(n.dtype)  # +1 front, −1 back
            front = n * side  # the shading normal on the front side (the tangent frame's side)
            texture = self.entry_texture(entry)
            uv = [np.take(self._uvs_soa_f32()[i], p) for i in range(6)]
            w0 = 1 - u - v
            s_, t_, stretch = transformed_st(entry, w0 * uv[0] + u * uv[2] + v * uv[4],
                                             w0 * uv[1] + u * uv[3] + v * uv[5])
            density = np.take(self._uv_density32, p) * (np.take(t, sel) * (spread * stretch))
            lod = np.log2(np.maximum(density * max(texture.width, texture.height), 1))
            texels = texture.lookup_soa(s_, t_, lod, tuple(entry.get("wrap", ("repeat", "repeat"))), (0, 1, 2))
            scale, bias = entry.get("scale", (1.0,) * 4), entry.get("bias", (0.0,) * 4)
            x, y, z = (texels[c] * np.float32(scale[c]) + np.float32(bias[c]) for c in range(3))
            if entry.get("space") == "world":  # stage axes → bake frame (row vectors: bake = stage @ axes)
                world = (np.stack([x, y, z]).T @ self._stage_axes).T
                z = (world * front).sum(axis=0)  # its height over the front side: ≤ 0 keeps the unmapped normal
                mapped = world * side
            else:
                mapped = self._tangent_space(p, front, x, y, z) * side  # back to the viewer's side
            length = np.sqrt((mapped * mapped).sum(axis=0))
            mapped /= np.maximum(length, np.float32(1e-30))
            keep = ((mapped * np.take(wo, sel, axis=1)).sum(axis=0) <= 0) | (length <= 0) | (z <= 0)
            if out is shading:
                out = shading.copy()
            out[:, sel] = np.where(keep, n, mapped)
        return out

    def _tangent_space(self, p: np.ndarray, front: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray
                       ) -> np.ndarray:
        """x·T + y·B + z·N (3, M) on the triangles ``p`` with N = ``front`` (module docstring "Normal maps")."""
        tangent = np.stack([np.take(self._tangents[c], p) for c in range(3)])
        handed = np.take(self._tangents[3], p)
        tangent = tangent - front * (tangent * front).sum(axis=0)  # Gram–Schmidt against the shading normal
        tangent /= np.maximum(np.sqrt((tangent * tangent).sum(axis=0)), np.float32(1e-30))
        bitangent = handed * np.stack([front[1] * tangent[2] - front[2] * tangent[1],
                                       front[2] * tangent[0] - front[0] * tangent[2],
                                       front[0] * tangent[1] - front[1] * tangent[0]])
        return x * tangent + y * bitangent + z * front

    def _uvs_soa_f32(self) -> np.ndarray:
        if self._uvs_soa is None:
            self._uvs_soa = np.ascontiguousarray(self.uvs.reshape(-1, 6).T, dtype=np.float32)
            self._uv_density32 = np.ascontiguousarray(self.uv_density, dtype=np.float32)
        return self._uvs_soa

    def params_soa(self, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray, t: np.ndarray, spread: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """BSDF parameters at hits as float32 structure-of-arrays: albedo (3, M), F0 (3, M), roughness (M,),
        emission (3, M) (None when no material emits) and F90 (3, M) (None when no material's specular is tinted:
        the BSDF derives it from F0) — a :class:`~bakery.capture.bsdf.Fresnel` holding it and the metal terms when
        some material has them (:attr:`metal_terms`)."""
        mi = np.take(self.mesh_of_soa, prim) if len(self.materials) else np.zeros(prim.shape, dtype=np.int32)
        first = self.layer_row
        rows = [*range(7), *(range(7, 10) if self.emissive else ()), *(range(10, 13) if self.tinted else ()),
                *(range(13, 25) if self.metal_terms else ()),
                *(() if first is None else range(first, first + LAYER_ROWS))]
        cols = {c: np.take(self.table[c], mi) for c in rows}
        albedo, f0, rough = np.stack([cols[c] for c in (0, 1, 2)]), np.stack([cols[c] for c in (3, 4, 5)]), cols[6]
        emission = np.stack([cols[c] for c in (7, 8, 9)]) if self.emissive else None
        f90 = np.stack([cols[c] for c in (10, 11, 12)]) if self.tinted else None
        metal = np.stack([cols[c] for c in range(13, 25)]) if self.metal_terms else None
        layer = None if first is None else np.stack([cols[c] for c in range(first, first + LAYER_ROWS)])
        for k in self.textured:
            sel = np.flatnonzero(mi == k)
            if sel.size:
                a, f, r, e, f9 = self._textured_soa(k, np.take(prim, sel), np.take(bu, sel), np.take(bv, sel),
                                                    np.take(t, sel), spread)
                albedo[:, sel] = a
                f0[:, sel] = f
                rough[sel] = r
                if emission is not None:
                    emission[:, sel] = e
                terms = None
                if isinstance(f9, Fresnel):
                    if metal is not None:
                        metal[:, sel] = 0 if f9.f82 is None else np.concatenate([f9.f82, *f9.conductor])
                    terms = f9.layering
                    f9 = f9.f90
                elif metal is not None:
                    metal[:, sel] = 0
                if layer is not None:
                    layer[:, sel] = 0 if terms is None else np.concatenate(
                        [terms.share0, terms.share90, terms.own0, terms.own90, terms.weight[None], terms.metal,
                         np.ones((1, sel.size), dtype=layer.dtype)])
                if f90 is not None:
                    f90[:, sel] = f9
        if metal is not None:
            f90 = Fresnel(f90, metal[0:3], (metal[3:6], metal[6:9], metal[9:12]))
        if layer is not None:  # module docstring "MaterialX layering"; hits on other materials as they were
            flag = layer[16] > 0
            if flag.any():
                layering = Layering(None if flag.all() else flag, layer[0:3], layer[3:6], layer[6:9], layer[9:12],
                                    layer[12], layer[13:16])
                f90 = (Fresnel(f90.f90, f90.f82, f90.conductor, layering) if isinstance(f90, Fresnel)
                       else Fresnel(f90, layering=layering))
        return albedo, f0, rough, emission, f90

    @property
    def tinted(self) -> bool:
        """Whether some material's specular lobe is tinted (:attr:`specular_tint`, :attr:`coat_tint`)."""
        return self.specular_tint is not None

    def _textured_soa(self, k: int, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray, t: np.ndarray, spread: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """:meth:`at` (textures, then :meth:`_point`) for hits on material ``k``, float32 (3, M) / (M,); F90 (3, M)
        when some material is tinted, a :class:`~bakery.capture.bsdf.Fresnel` when material ``k``'s metal has
        terms beyond Schlick (module docstring "Explicit Fresnel")."""
        m = prim.shape[0]
        dtype = t.dtype
        uv = [np.take(self._uvs_soa_f32()[i], prim) for i in range(6)]
        w0 = 1 - bu - bv
        s = w0 * uv[0] + bu * uv[2] + bv * uv[4]
        tt = w0 * uv[1] + bu * uv[3] + bv * uv[5]
        density = np.take(self._uv_density32, prim) * (t * spread)
        values: dict[str, np.ndarray] = {}
        for entry in self.materials[k].maps:
            name = entry["input"]
            if name not in self.base:
                continue
            if "primvar" in entry:  # a colour read per vertex: the corners' colours at the hit's barycentrics
                index = (0, 1, 2)
                texels = [self._vertex_colour_soa(c, prim, w0, bu, bv) for c in index]
            else:
                texture = self.entry_texture(entry)
                s_, t_, stretch = transformed_st(entry, s, tt)
                lod = np.log2(np.maximum(density * (stretch * max(texture.width, texture.height)), 1))
                channels = entry.get("channels", "rgb")
                index = {"r": (0,), "g": (1,), "b": (2,), "a": (3,)}.get(channels, (0, 1, 2))
                texels = texture.lookup_soa(s_, t_, lod, tuple(entry.get("wrap", ("repeat", "repeat"))), index)
                if "tint_primvar" in entry:  # times a colour read per vertex (a MaterialX multiply by a primvar)
                    texels = [x * self._vertex_colour_soa(c, prim, w0, bu, bv) for x, c in zip(texels, index)]
            scale = entry.get("scale", (1.0, 1.0, 1.0, 1.0))
            bias = entry.get("bias", (0.0, 0.0, 0.0, 0.0))
            texels = [x * float(scale[c]) + float(bias[c]) for x, c in zip(texels, index)]
            if self.base[name].ndim == 2:  # colour input
                values[name] = np.stack(texels if len(texels) == 3 else texels * 3)
            else:
                values[name] = texels[0] if len(texels) == 1 else (
                    0.2126 * texels[0] + 0.7152 * texels[1] + 0.0722 * texels[2])

        def get(name: str) -> np.ndarray:
            if name in values:
                return values[name]
            base = self.base[name][k]
            return np.asarray(base, dtype=dtype).reshape(3, 1) if np.ndim(base) else np.asarray(base, dtype=dtype)

        diffuse = np.maximum(get("diffuseColor"), 0)
        metallic = np.clip(get("metallic"), 0, 1)
        if self.specular_workflow[k]:
            f0 = np.clip(get("specularColor"), 0, 1)
            albedo = diffuse
        else:
            ior = get("ior")
            dielectric = np.where(ior > 0, ((ior - 1) / (ior + 1)) ** 2, 0)
            f0 = np.clip((1 - metallic) * dielectric + metallic * diffuse, 0, 1)
            albedo = diffuse * (1 - metallic)
        shape = (3, m)
        f90 = None
        if self.tinted:  # the tinted lobe: Material.specular_tint on the dielectric share, coat_tint on the base
            spec = self.specular_tint[k].astype(dtype).reshape(3, 1)
            edge = self.edge_tint[k].astype(dtype).reshape(3, 1)
            coat = self.coat_tint[k].astype(dtype).reshape(3, 1)
            if self.metal_edge[k]:  # UsdPreviewSurface: F90 = mix(F90 of the dielectric, albedo, metallic)
                f90 = coat * ((1 - metallic) * (np.minimum(1, 50 * dielectric) * edge)
                              + metallic * np.minimum(diffuse, 1))
            else:
                f90 = (np.minimum(1, 50 * np.tensordot(LUMINANCE_WEIGHTS.astype(dtype), np.asarray(f0), axes=1))
                       * (coat * (1 if self.specular_workflow[k] else (1 - metallic) * edge + metallic)))
            if not self.specular_workflow[k]:
                f0 = (1 - metallic) * dielectric * spec + metallic * diffuse
            f0, albedo = np.clip(coat * f0, 0, 1), albedo * coat
            f90 = np.broadcast_to(f90, shape)
            if self.explicit[k]:  # the shares' own F0 and F90 (module docstring "Explicit Fresnel")
                weight, f82, given, has_f90, conductor, edge_colour = self.explicit_inputs

                def column(a: np.ndarray) -> np.ndarray:
                    return a[k].astype(dtype).reshape(3, 1)

                f0, f90, b, cw, eta, kappa = (np.broadcast_to(x, shape) for x in _explicit_fresnel(
                    metallic, np.clip(diffuse, 0, 1), dielectric, spec, edge, coat, dtype.type(weight[k]),
                    column(f82), column(given), bool(has_f90[k]), bool(conductor[k]), column(edge_colour)))
                if self.metal_terms and (self.materials[k].metal_f82 is not None or conductor[k]):
                    f90 = Fresnel(f90, b, (cw, eta, kappa))
        if self.layered[k]:  # module docstring "MaterialX layering"
            u, given, metal_weight, f90_given, has_f90 = (a[k] for a in self.layer_inputs)
            one = np.ones((3, 1), dtype=dtype)
            if self.specular_workflow[k]:  # the whole lobe is the layer's
                lobe90 = (np.minimum(1, 50 * np.tensordot(LUMINANCE_WEIGHTS.astype(dtype), np.asarray(f0), axes=1))
                          if f90 is None else (f90.f90 if isinstance(f90, Fresnel) else f90))
                terms = (f0, lobe90, f0, lobe90, np.ones(m, dtype=dtype), np.zeros(shape, dtype=dtype))
            else:
                tints = (one, one, one) if not self.tinted else tuple(
                    t[k].astype(dtype).reshape(3, 1) for t in (self.specular_tint, self.edge_tint, self.coat_tint))
                terms = _layer_terms(metallic, dielectric, *tints, f90_given.astype(dtype).reshape(3, 1),
                                     bool(has_f90), dtype.type(metal_weight), bool(given), u.astype(dtype))
            layering = Layering(None, *(np.broadcast_to(t, shape if i != 4 else (m,)).astype(dtype, copy=False)
                                        for i, t in enumerate(terms)))
            f90 = (Fresnel(f90.f90, f90.f82, f90.conductor, layering) if isinstance(f90, Fresnel)
                   else Fresnel(f90, layering=layering))
        return (np.broadcast_to(np.clip(albedo, 0, 1), shape), np.broadcast_to(f0, shape),
                np.broadcast_to(np.clip(get("roughness"), 0, 1), (m,)),
                np.broadcast_to(np.maximum(get("emissiveColor"), 0), shape), f90)

    def entry_texture(self, entry: dict) -> MipTexture | UdimTexture:
        """The texture a map entry reads: its image, or its UDIM tiles (``entry["udim"]``)."""
        tiles = entry.get("udim")
        if not tiles:
            return self.texture(int(entry["texture"]))
        key = ("udim", tuple(tiles))
        if key not in self._textures:
            self._textures[key] = UdimTexture({int(tile): self.texture(int(index)) for tile, index in tiles})
        return self._textures[key]

    def texture(self, index: int) -> MipTexture:
        if index not in self._textures:
            self._textures[index] = MipTexture(self.scene.textures[index].pixels)
        return self._textures[index]

    def at(self, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray, t: np.ndarray | None = None,
           spread: float | np.ndarray = BOUNCE_SPREAD) -> SurfacePoint:
        """Material parameters at hits (triangle ``prim``, barycentrics bu, bv, ray distance t, ray spread)."""
        mi = self.mesh_of[prim] if len(self.materials) else np.zeros(prim.shape, dtype=np.int64)
        values = {name: array[mi] for name, array in self.base.items()}
        if self.textured:
            for k in self.textured:
                sel = np.flatnonzero(mi == k)
                if sel.size:
                    self._apply_maps(k, sel, prim[sel], bu[sel], bv[sel], None if t is None else t[sel],
                                     spread if np.isscalar(spread) else np.asarray(spread)[sel], values)
        return self._point(values, mi)

    def cut(self, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Whether hits are passed through: opacity below the material's opacityThreshold (> 0: a cut-out), or,
        on materials of partial presence (:attr:`partial`), u ≥ opacity for the uniform numbers ``u`` (M,) (one per
        hit; required when :attr:`stochastic`)."""
        mi = self.mesh_of[prim]
        result = np.zeros(prim.shape, dtype=bool)
        sel = np.flatnonzero(self.threshold[mi] > 0)
        if sel.size:
            point = self.at(prim[sel], bu[sel], bv[sel])
            result[sel] = point.opacity < point.threshold
        if self.stochastic:
            sel = np.flatnonzero(self.partial[mi])
            if sel.size:
                result[sel] = u[sel] >= self.at(prim[sel], bu[sel], bv[sel]).opacity
        return result

    def presence(self, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray) -> np.ndarray:
        """The expected presence (M,) float32 of surface points, what :meth:`cut` keeps on average: 0 or 1 on
        cut-out materials (opacity against opacityThreshold), the opacity on materials of partial presence, else
        1 (the emissive triangles' next-event estimate, :mod:`bakery.capture.emitters`)."""
        result = np.ones(prim.shape, dtype=np.float32)
        if not self.cutout:
            return result
        mi = self.mesh_of[prim]
        sel = np.flatnonzero((self.threshold[mi] > 0) | (self.partial[mi] if self.stochastic else False))
        if sel.size:
            point = self.at(prim[sel], bu[sel], bv[sel])
            opacity = np.clip(np.asarray(point.opacity, dtype=np.float64), 0.0, 1.0)
            threshold = np.asarray(point.threshold, dtype=np.float64)
            result[sel] = np.where(threshold > 0, (opacity >= threshold).astype(np.float64), opacity)
        return result

    def _vertex_colour_soa(self, c: int, prim: np.ndarray, w0: np.ndarray, bu: np.ndarray, bv: np.ndarray
                           ) -> np.ndarray:
        """Channel ``c`` (M,) float32 of the per-vertex colour at hits on triangles ``prim`` with barycentrics
        (w0, bu, bv): the corners' colours interpolated."""
        rows = self._colors_soa
        return w0 * np.take(rows[c], prim) + bu * np.take(rows[3 + c], prim) + bv * np.take(rows[6 + c], prim)

    def _vertex_colour_rgba(self, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray) -> np.ndarray:
        """The per-vertex colour (M, 4) float64 at hits (alpha 1): the corners' colours interpolated."""
        corners = self.colors[prim]
        rgb = (1.0 - bu - bv)[:, None] * corners[:, 0] + bu[:, None] * corners[:, 1] + bv[:, None] * corners[:, 2]
        return np.concatenate([rgb, np.ones((rgb.shape[0], 1))], axis=1)

    def _apply_maps(self, k: int, sel: np.ndarray, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray,
                    t: np.ndarray | None, spread, values: dict[str, np.ndarray]) -> None:  # noqa: ANN001
        uv = self.uvs[prim]
        st = (1.0 - bu - bv)[:, None] * uv[:, 0] + bu[:, None] * uv[:, 1] + bv[:, None] * uv[:, 2]
        for entry in self.materials[k].maps:
            name = entry["input"]
            if name not in values:
                continue
            if "primvar" in entry:  # a colour read per vertex (RGB, alpha 1)
                rgba = self._vertex_colour_rgba(prim, bu, bv)
            else:
                texture = self.entry_texture(entry)
                s_, t_, stretch = transformed_st(entry, st[:, 0], st[:, 1])
                size = max(texture.width, texture.height) * stretch
                if t is None:
                    lod = np.zeros(sel.size)
                else:
                    footprint = np.maximum(t * spread * self.uv_density[prim] * size, 1e-12)
                    lod = np.log2(np.maximum(footprint, 1.0))
                rgba = texture.lookup(np.stack([s_, t_], axis=-1), lod, tuple(entry.get("wrap", ("repeat", "repeat"))))
                if "tint_primvar" in entry:  # times a colour read per vertex (RGB; alpha unchanged)
                    rgba = rgba * self._vertex_colour_rgba(prim, bu, bv)
            rgba = rgba * np.asarray(entry.get("scale", (1.0, 1.0, 1.0, 1.0))) + np.asarray(
                entry.get("bias", (0.0, 0.0, 0.0, 0.0)))
            value = _channels(rgba, entry.get("channels", "rgb"))
            target = values[name]
            if target.ndim == 2:
                target[sel] = value[:, None] if value.ndim == 1 else value
            else:
                target[sel] = value if value.ndim == 1 else value @ np.array([0.2126, 0.7152, 0.0722])

    def _point(self, v: dict[str, np.ndarray], mi: np.ndarray) -> SurfacePoint:
        diffuse = np.clip(v["diffuseColor"], 0.0, None)
        metallic = np.clip(v["metallic"], 0.0, 1.0)
        spec_wf = self.specular_workflow[mi]
        ior = v["ior"]
        dielectric = np.where(ior > 0, ((ior - 1.0) / (ior + 1.0)) ** 2, 0.0)
        f0_metal = (1.0 - metallic)[:, None] * dielectric[:, None] + metallic[:, None] * diffuse
        f0 = np.where(spec_wf[:, None], np.clip(v["specularColor"], 0.0, 1.0), np.clip(f0_metal, 0.0, 1.0))
        albedo = np.where(spec_wf[:, None], diffuse, diffuse * (1.0 - metallic)[:, None])
        f90 = None
        if self.tinted:  # Material.specular_tint scales the dielectric share of F0 and F90, coat_tint the whole base
            spec, edge, coat = self.specular_tint[mi], self.edge_tint[mi], self.coat_tint[mi]
            share = np.where(spec_wf[:, None], 1.0, (1.0 - metallic)[:, None] * edge + metallic[:, None])
            f90 = np.minimum(1.0, 50.0 * (f0 @ LUMINANCE_WEIGHTS))[:, None] * share * coat
            metal_edge = self.metal_edge[mi] & ~spec_wf
            if metal_edge.any():  # UsdPreviewSurface: F90 = mix(F90 of the dielectric, albedo, metallic)
                edged = ((1.0 - metallic) * np.minimum(1.0, 50.0 * dielectric))[:, None] * edge \
                    + metallic[:, None] * np.minimum(diffuse, 1.0)
                f90 = np.where(metal_edge[:, None], edged * coat, f90)
            tinted = (1.0 - metallic)[:, None] * dielectric[:, None] * spec + metallic[:, None] * diffuse
            f0 = np.clip(coat * np.where(spec_wf[:, None], f0, tinted), 0.0, 1.0)
            albedo = albedo * coat
        f82 = conductor = None
        explicit = self.explicit[mi] & ~spec_wf if self.explicit_inputs is not None else None
        if explicit is not None and explicit.any():  # the shares' own F0 and F90 (module docstring)
            weight, tint82, given, has_f90, metal_conductor, edge_colour = self.explicit_inputs
            f0_x, f90_x, b, cw, eta, kappa = _explicit_fresnel(
                metallic, np.clip(diffuse, 0.0, 1.0).T, dielectric, spec.T, edge.T, coat.T, weight[mi],
                tint82[mi].T, given[mi].T, has_f90[mi], metal_conductor[mi], edge_colour[mi].T)
            f0 = np.where(explicit[:, None], f0_x.T, f0)
            f90 = np.where(explicit[:, None], f90_x.T, f90)
            if self.metal_terms:
                zero = np.zeros_like(f0)
                f82 = np.where(explicit[:, None], b.T, zero)
                conductor = tuple(np.where(explicit[:, None], x.T, zero) for x in (cw, eta, kappa))
        elif self.metal_terms:
            zero = np.zeros((mi.shape[0], 3))
            f82, conductor = zero, (zero, zero, zero)
        layering = None
        if self.layer_inputs is not None:  # module docstring "MaterialX layering"
            layered = self.layered[mi]
            u, given, metal_weight, f90_given, has_f90 = (a[mi] for a in self.layer_inputs)
            one = np.ones((3, 1))
            spec_t, edge_t, coat_t = (one, one, one) if not self.tinted else (spec.T, edge.T, coat.T)
            terms = _layer_terms(metallic, dielectric, spec_t, edge_t, coat_t, f90_given.T, has_f90, metal_weight,
                                 given, u.T)
            if spec_wf.any():  # the specular workflow: the whole lobe is the layer's
                edge90 = np.minimum(1.0, 50.0 * (f0 @ LUMINANCE_WEIGHTS))[:, None] * np.ones(3) if f90 is None else f90
                whole = (f0.T, edge90.T, f0.T, edge90.T, np.ones(mi.shape), np.zeros((3, mi.shape[0])))
                terms = tuple(np.where(spec_wf, w, t) for w, t in zip(whole, terms))
            layering = tuple(np.where(layered, t, 0.0).T for t in terms) + (layered,)
        return SurfacePoint(
            albedo=np.clip(albedo, 0.0, 1.0), f0=f0, roughness=np.clip(v["roughness"], 0.0, 1.0),
            emission=np.maximum(v["emissiveColor"], 0.0), opacity=np.clip(v["opacity"], 0.0, 1.0),
            threshold=self.threshold[mi], f90=f90, f82=f82, conductor=conductor, layering=layering,
        )
