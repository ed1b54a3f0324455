"""Reading a USD stage into a :class:`bakery.capture.scene.CaptureScene` (bake frame, metres) plus per-prim issues.

Frames and units
    USD composes transforms with row vectors: p_world = p_local · M (Gf convention). bakery's bake frame is
    right-handed, +Y up, metres. A stage with ``upAxis = "Z"`` is rotated by −90° about X,
    (x, y, z) ↦ (x, z, −y), i.e. p_bake = mpu · p_world · A with A = [[1,0,0],[0,0,−1],[0,1,0]]; ``metersPerUnit``
    (mpu, fallback 0.01 as in UsdGeom) scales every length. Both captures and baked SH are in the bake frame.

DomeLight orientation
    UsdLuxDomeLight: the dome's top pole is its local +Y and its latlong texture follows OpenEXR (longitude 0 =
    local +Z, +π/2 = local +X) — bakery's equirect convention — so the dome-local → bake rotation is the dome's
    world rotation followed by A. A Z-up stage's dome therefore needs ``rotateX = 90`` to put its pole on +Z
    (as in OpenUSD's ``domeLightZup.usda``); with it, the Y-up and Z-up versions of a scene bake identically.
    ``DomeLight_1`` has ``poleAxis``: "Y" as above; "Z" (or "scene" on a Z-up stage) first turns the pole from
    local +Y to local +Z (rotateX 90°).

What is read
    Probes (bakery schema types), UsdLux Dome/Distant/Sphere/Rect/Disk lights (``inputs:*`` attributes, else the
    legacy un-namespaced ones), meshes (fan-triangulated), Sphere and Cube gprims (tessellated), point instancers
    and native instances (instance proxies), with payloads loaded; UsdPreviewSurface materials
    (:mod:`bakery.usd.materials`). Invisible prims and ``guide``/``proxy`` purposes are skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

from bakery.capture.scene import CaptureScene, Dome, Light, Mesh, ProbeSpec
from bakery.environment.io import is_8bit_image, read_environment
from bakery.errors import ImageError, SceneError
from bakery.usd.assets import local_asset_path
from bakery.usd.materials import MaterialReader, srgb_to_linear
from bakery.usd.plugin import FALLBACKS, PROBE_TYPES

_Z_UP_TO_BAKE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
_POLE_Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # row vectors: +Y ↦ +Z
#: Time at which the scene is read: authored defaults, else the first time sample.
_T = Usd.TimeCode.EarliestTime()


@dataclass(frozen=True)
class Issue:
    """A problem found in a scene: ``severity`` "error" (the bake cannot be trusted) or "warning"."""

    severity: str
    prim: str
    message: str

    def __str__(self) -> str:
        return f"{self.severity}: {self.prim}: {self.message}"


@dataclass(frozen=True)
class SceneReading:
    """A stage read for capture: the scene, its issues, and the stage facts recorded in outputs."""

    scene: CaptureScene
    issues: tuple[Issue, ...]
    path: str
    meters_per_unit: float
    up_axis: str
    layers: tuple[str, ...] = ()
    assets: tuple[str, ...] = ()

    @property
    def errors(self) -> tuple[Issue, ...]:
        return tuple(i for i in self.issues if i.severity == "error")


def open_stage(path: str | Path) -> Usd.Stage:
    """Open a stage with all payloads loaded. Raises SceneError if it cannot be opened."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: scene not found")
    try:
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Exception as exc:  # pxr raises Tf.ErrorException
        raise SceneError(f"{path}: USD cannot open it: {exc}") from exc
    if stage is None:
        raise SceneError(f"{path}: USD cannot open it")
    return stage


class _Frame:
    """Stage → bake conversion for world matrices (row-vector 4 × 4)."""

    def __init__(self, stage: Usd.Stage) -> None:
        self.mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
        self.up = str(UsdGeom.GetStageUpAxis(stage))
        self.axes = _Z_UP_TO_BAKE if self.up == "Z" else np.eye(3)

    def points(self, local: np.ndarray, matrix: np.ndarray) -> np.ndarray:
        """Bake-frame points (…, 3) in metres of local points and a world matrix."""
        world = local @ matrix[:3, :3] + matrix[3, :3]
        return self.mpu * (world @ self.axes)

    def vectors(self, local: np.ndarray, matrix: np.ndarray) -> np.ndarray:
        """Bake-frame vectors (metres) of local vectors (rows)."""
        return self.mpu * (np.asarray(local) @ matrix[:3, :3] @ self.axes)

    def rotation(self, matrix: np.ndarray, pre: np.ndarray | None = None) -> np.ndarray:
        """Local → bake rotation (columns = local axes in the bake frame) of a world matrix, scale removed."""
        m3 = _orthonormalize(matrix[:3, :3])
        if pre is not None:
            m3 = pre @ m3
        return (m3 @ self.axes).T


def _orthonormalize(m3: np.ndarray) -> np.ndarray:
    u, _s, vt = np.linalg.svd(m3)
    r = u @ vt
    if np.linalg.det(r) < 0:  # mirrored transforms: keep a rotation
        u[:, -1] *= -1
        r = u @ vt
    return r


def _matrix(gf: Gf.Matrix4d) -> np.ndarray:
    return np.array(gf, dtype=np.float64).reshape(4, 4)


class SceneReader:
    """Reads one stage; collects issues instead of failing on the first problem."""

    def __init__(self, stage: Usd.Stage, load_textures: bool = True) -> None:
        self.stage = stage
        self.frame = _Frame(stage)
        self.xforms = UsdGeom.XformCache(_T)
        self.materials = MaterialReader()
        self.load_textures = load_textures
        self.issues: list[Issue] = []
        self.meshes: list[Mesh] = []
        self.lights: list[Light] = []
        self.domes: list[Dome] = []
        self.probes: list[ProbeSpec] = []

    def issue(self, severity: str, prim: Usd.Prim | str, message: str) -> None:
        path = prim if isinstance(prim, str) else str(prim.GetPath())
        self.issues.append(Issue(severity, path, message))

    def world(self, prim: Usd.Prim) -> np.ndarray:
        return _matrix(self.xforms.GetLocalToWorldTransform(prim))

    # ------------------------------------------------------------------------------------------------------------
    def read(self) -> SceneReading:
        if not UsdGeom.StageHasAuthoredMetersPerUnit(self.stage):
            self.issue("warning", "/", f"metersPerUnit is not authored; using UsdGeom's fallback {self.frame.mpu}")
        predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        iterator = iter(Usd.PrimRange(self.stage.GetPseudoRoot(), predicate))
        for prim in iterator:
            if prim.IsPseudoRoot():
                continue
            imageable = UsdGeom.Imageable(prim)
            if imageable and imageable.ComputeVisibility() == UsdGeom.Tokens.invisible:
                iterator.PruneChildren()
                continue
            purpose = imageable.ComputePurpose() if imageable else UsdGeom.Tokens.default_
            if purpose in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                iterator.PruneChildren()
                continue
            type_name = str(prim.GetTypeName())
            try:
                if type_name in PROBE_TYPES:
                    self._read_probe(prim, type_name)
                elif "probe" in type_name.lower():
                    self.issue("error", prim, f"unknown probe type {type_name!r}; known: {', '.join(PROBE_TYPES)}")
                elif prim.HasAPI(UsdLux.LightAPI) or prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
                    self._read_light(prim)
                elif prim.IsA(UsdGeom.PointInstancer):
                    self._read_point_instancer(prim)
                    iterator.PruneChildren()
                elif prim.IsA(UsdGeom.Mesh):
                    self._read_mesh(prim)
                elif prim.IsA(UsdGeom.Sphere) or prim.IsA(UsdGeom.Cube):
                    self._read_gprim(prim)
                elif prim.IsA(UsdGeom.Gprim):
                    self.issue("warning", prim, f"{type_name} gprims are not supported by the capture; skipped")
            except SceneError as exc:
                self.issue("error", prim, str(exc))
        self._check_encodings()
        for severity, path, message in self.materials.issues:
            self.issue(severity, path, message)
        if not self.probes:
            self.issue("error", "/", "the scene has no probes (BakeryIrradianceProbe, BakeryReflectionProbe or "
                       "BakeryIrradianceProbeVolume prims)")
        if not self.meshes and not self.lights and not self.domes:
            self.issue("warning", "/", "the scene has no geometry and no lights: every probe will be black")
        if len(self.domes) > 1:
            self.issue("warning", self.domes[1].name, f"{len(self.domes)} dome lights; only {self.domes[0].name} "
                       "is used")
        names = [p.name for p in self.probes]
        scene = CaptureScene(
            meshes=tuple(self.meshes),
            lights=tuple(self.lights),
            dome=self.domes[0] if self.domes else None,
            probes=tuple(self.probes),
            meters_per_unit=self.frame.mpu,
            up_axis=self.frame.up,
        )
        assert len(set(names)) == len(names)
        return SceneReading(
            scene=scene,
            issues=tuple(self.issues),
            path=str(self.stage.GetRootLayer().realPath or self.stage.GetRootLayer().identifier),
            meters_per_unit=self.frame.mpu,
            up_axis=self.frame.up,
            layers=tuple(sorted({layer.realPath for layer in self.stage.GetUsedLayers() if layer.realPath})),
            assets=tuple(sorted(self._assets())),
        )

    def _assets(self) -> set[str]:
        """Files other than layers that the capture reads: dome texture, captured images, material textures."""
        files = {d.source for d in self.domes if d.source}
        files |= {p.image for p in self.probes if p.image}
        files |= {key.split("|", 1)[0] for key in self.materials._textures}
        return files

    def _check_encodings(self) -> None:
        """Per-probe ``bakery:encodings`` must name registered encodings (of the probe's kind, else a warning)."""
        from bakery.encodings import ENCODINGS, get_encoding

        seen: set[tuple[str, str]] = set()
        for spec in self.probes:
            prim = spec.volume or spec.name
            for name in spec.encodings:
                if (prim, name) in seen:
                    continue
                seen.add((prim, name))
                try:
                    cls = get_encoding(name)
                except KeyError:
                    self.issue("error", prim, f"unknown encoding {name!r} in bakery:encodings; known: "
                               f"{', '.join(ENCODINGS)}")
                    continue
                if cls.kind != spec.kind:
                    self.issue("warning", prim, f"encoding {name!r} is a {cls.kind} encoding on a {spec.kind} probe")

    # ------------------------------------------------------------------------------------------------------------
    # Probes
    def _attr(self, prim: Usd.Prim, name: str):
        attr = prim.GetAttribute(name)
        value = attr.Get(_T) if attr else None
        return FALLBACKS.get(name) if value is None else value

    def _probe_placement(self, prim: Usd.Prim) -> np.ndarray | None:
        matrix = self.world(prim)
        det = np.linalg.det(matrix[:3, :3])
        if not np.all(np.isfinite(matrix)) or abs(det) < 1e-12:
            self.issue("error", prim, f"non-invertible world transform (det = {det:.3g}); probe skipped")
            return None
        return matrix

    def _read_probe(self, prim: Usd.Prim, type_name: str) -> None:
        matrix = self._probe_placement(prim)
        if matrix is None:
            return
        resolution = int(self._attr(prim, "bakery:capture:resolution") or 0)
        if resolution < 0:
            self.issue("error", prim, f"bakery:capture:resolution must be >= 0, got {resolution}")
            return
        encodings_attr = prim.GetAttribute("bakery:encodings")
        encodings = tuple(str(e) for e in (encodings_attr.Get(_T) or ())) if encodings_attr else ()
        rotation = tuple(map(tuple, self.frame.rotation(matrix)))
        path = str(prim.GetPath())
        if type_name == "BakeryIrradianceProbeVolume":
            self._read_volume(prim, matrix, resolution, encodings)
            return
        image = ""
        image_attr = prim.GetAttribute("bakery:capture:image")
        asset = image_attr.Get(_T) if image_attr else None
        if isinstance(asset, Sdf.AssetPath) and asset.path:
            image = local_asset_path(asset) or ""
            if not image:
                self.issue("error", prim, f"bakery:capture:image {asset.path!r} not found")
                return
        kind = "irradiance" if type_name == "BakeryIrradianceProbe" else "reflection"
        scale = float(np.cbrt(abs(np.linalg.det(matrix[:3, :3])))) * self.frame.mpu
        influence: dict = {"radius_m": float(self._attr(prim, "bakery:influence:radius")) * scale}
        if kind == "reflection":
            influence["shape"] = str(self._attr(prim, "bakery:influence:shape"))
            influence["extent_m"] = [float(x) * scale for x in self._attr(prim, "bakery:influence:extent")]
            influence["blend_distance_m"] = float(self._attr(prim, "bakery:influence:blendDistance")) * scale
            if influence["shape"] not in ("sphere", "box"):
                self.issue("error", prim, f"bakery:influence:shape {influence['shape']!r} is not sphere or box")
                return
        position = self.frame.points(np.zeros(3), matrix)
        self.probes.append(
            ProbeSpec(
                name=path,
                kind=kind,
                position=tuple(float(x) for x in position),
                rotation=rotation,
                resolution=resolution,
                image=image,
                encodings=encodings,
                influence=influence,
            )
        )

    def _read_volume(self, prim: Usd.Prim, matrix: np.ndarray, resolution: int, encodings: tuple[str, ...]) -> None:
        extent = np.asarray(self._attr(prim, "bakery:volume:extent"), dtype=np.float64)
        counts = np.asarray(self._attr(prim, "bakery:volume:counts"), dtype=np.int64)
        if counts.shape != (3,) or (counts < 1).any():
            self.issue("error", prim, f"bakery:volume:counts must be three integers >= 1, got {counts.tolist()}")
            return
        if counts.prod() > 100_000:
            self.issue("error", prim, f"bakery:volume:counts {counts.tolist()} gives more than 100000 probes")
            return
        if (extent < 0).any():
            self.issue("error", prim, f"bakery:volume:extent must be >= 0, got {extent.tolist()}")
            return
        path = str(prim.GetPath())
        rotation = tuple(map(tuple, self.frame.rotation(matrix)))
        # flat index i + nx·(j + ny·k): i fastest
        k, j, i = np.meshgrid(*(np.arange(c) for c in counts[::-1]), indexing="ij")
        ijk = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=-1)
        fraction = np.where(counts > 1, ijk / np.maximum(counts - 1, 1), 0.5)
        local = -extent + 2.0 * extent * fraction
        positions = self.frame.points(local, matrix)
        for (a, b, c), position in zip(ijk.tolist(), positions):
            self.probes.append(
                ProbeSpec(
                    name=f"{path}[{a},{b},{c}]",
                    kind="irradiance",
                    position=tuple(float(x) for x in position),
                    rotation=rotation,
                    resolution=resolution,
                    encodings=encodings,
                    volume=path,
                    volume_index=(a, b, c),
                )
            )

    # ------------------------------------------------------------------------------------------------------------
    # Lights
    def _input(self, prim: Usd.Prim, name: str, fallback):
        """``inputs:<name>`` if authored, else the legacy ``<name>`` if authored, else the schema fallback."""
        for attr_name in (f"inputs:{name}", name):
            attr = prim.GetAttribute(attr_name)
            if attr and attr.HasAuthoredValue():
                return attr.Get(_T)
        attr = prim.GetAttribute(f"inputs:{name}")
        value = attr.Get(_T) if attr else None
        return fallback if value is None else value

    def _emission_scale(self, prim: Usd.Prim) -> np.ndarray:
        intensity = float(self._input(prim, "intensity", 1.0))
        exposure = float(self._input(prim, "exposure", 0.0))
        color = np.asarray(self._input(prim, "color", (1.0, 1.0, 1.0)), dtype=np.float64)
        if bool(self._input(prim, "enableColorTemperature", False)):
            self.issue("warning", prim, "enableColorTemperature is not applied (color temperature ignored)")
        unapplied = sorted(
            a.GetName() for a in prim.GetAuthoredAttributes()
            if a.GetName().startswith(("inputs:shaping:", "shaping:", "inputs:shadow:", "shadow:"))
            or a.GetName() in ("inputs:diffuse", "diffuse")
        )
        if unapplied:
            self.issue("warning", prim, f"not applied by the capture: {', '.join(unapplied)}")
        scale = intensity * 2.0**exposure * color
        if not np.all(np.isfinite(scale)) or (scale < 0).any():
            raise SceneError(f"light emission {scale.tolist()} is negative or not finite")
        return scale

    def _read_light(self, prim: Usd.Prim) -> None:
        matrix = self.world(prim)
        if abs(np.linalg.det(matrix[:3, :3])) < 1e-12:
            self.issue("error", prim, "non-invertible world transform; light skipped")
            return
        name = str(prim.GetPath())
        scale = self._emission_scale(prim)
        normalize = bool(self._input(prim, "normalize", False))
        if prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
            self._read_dome(prim, matrix, scale)
            return
        x, y, z = (self.frame.vectors(np.eye(3)[i], matrix) for i in range(3))
        lengths = [float(np.linalg.norm(v)) for v in (x, y, z)]
        axes = tuple(tuple(float(c) for c in v / max(n, 1e-300)) for v, n in zip((x, y, z), lengths))
        position = tuple(float(c) for c in self.frame.points(np.zeros(3), matrix))
        if prim.IsA(UsdLux.DistantLight):
            angle = float(self._input(prim, "angle", 0.53))
            alpha = math.radians(0.5 * angle)
            illuminance = scale if normalize else scale * math.pi * math.sin(alpha) ** 2
            if not normalize and angle <= 0:
                self.issue("warning", prim, "DistantLight with angle 0 and normalize off emits nothing (its "
                           "illuminance is radiance × the disc's solid angle); set inputs:normalize = 1")
            self.lights.append(Light("distant", name, illuminance=tuple(illuminance), axes=axes, angle=angle))
            return
        if prim.IsA(UsdLux.SphereLight):
            radius = float(self._input(prim, "radius", 0.5)) * float(np.mean(lengths))
            light = Light("sphere", name, position=position, axes=axes, size=(radius, 0.0))
            if bool(self._input(prim, "treatAsPoint", False)) or radius <= 0:
                # a point of the same radiant intensity I = L·πr² as the sphere, drawn as a tiny sphere
                tiny = 1e-4
                base = scale / light.area if normalize and light.area > 0 else scale
                factor = (radius / tiny) ** 2 if radius > 0 else 1.0 / (math.pi * tiny**2)
                self.lights.append(
                    Light("sphere", name, radiance=tuple(base * factor), position=position, axes=axes,
                          size=(tiny, 0.0), visible=False)
                )
                return
        elif prim.IsA(UsdLux.RectLight):
            width = float(self._input(prim, "width", 1.0)) * lengths[0]
            height = float(self._input(prim, "height", 1.0)) * lengths[1]
            light = Light("rect", name, position=position, axes=axes, size=(width, height))
            tex = self._input(prim, "texture:file", None)
            if isinstance(tex, Sdf.AssetPath) and tex.path:
                self.issue("warning", prim, "RectLight textures are not applied (uniform emission used)")
        elif prim.IsA(UsdLux.DiskLight):
            radius = float(self._input(prim, "radius", 0.5)) * 0.5 * (lengths[0] + lengths[1])
            light = Light("disk", name, position=position, axes=axes, size=(radius, 0.0))
        else:
            self.issue("warning", prim, f"{prim.GetTypeName()} lights are not supported by the capture; skipped")
            return
        radiance = scale / light.area if normalize and light.area > 0 else scale
        self.lights.append(
            Light(light.kind, name, radiance=tuple(float(c) for c in radiance), position=position, axes=axes,
                  size=light.size)
        )

    def _read_dome(self, prim: Usd.Prim, matrix: np.ndarray, scale: np.ndarray) -> None:
        pre = None
        if prim.IsA(UsdLux.DomeLight_1):
            pole = str(self._input(prim, "poleAxis", "scene") or "scene")
            attr = prim.GetAttribute("poleAxis")
            pole = str(attr.Get(_T)) if attr and attr.Get(_T) else pole
            if pole == "Z" or (pole == "scene" and self.frame.up == "Z"):
                pre = _POLE_Y_TO_Z
        rotation = tuple(map(tuple, self.frame.rotation(matrix, pre)))
        name = str(prim.GetPath())
        texture = self._input(prim, "texture:file", None)
        fmt = str(self._input(prim, "texture:format", "automatic") or "automatic")
        if not isinstance(texture, Sdf.AssetPath) or not texture.path:
            self.domes.append(Dome(name, scale=tuple(scale), rotation=rotation))
            return
        resolved = local_asset_path(texture)
        if resolved is None:
            self.issue("error", prim, f"dome texture {texture.path!r} not found")
            return
        layouts = {"automatic": None, "latlong": "equirect", "angular": "angular"}
        if fmt not in layouts:
            self.issue("error", prim, f"dome texture format {fmt!r} is not supported (latlong, angular, automatic)")
            return
        if not self.load_textures:
            self.domes.append(Dome(name, scale=tuple(scale), rotation=rotation, source=resolved))
            return
        try:
            image, report = read_environment(resolved, layouts[fmt])
        except ImageError as exc:
            self.issue("error", prim, str(exc))
            return
        pixels = image.pixels
        if is_8bit_image(resolved):  # 8-bit textures are sRGB-encoded (sourceColorSpace "auto", as in Hydra)
            pixels = srgb_to_linear(pixels).astype(np.float32)
        replaced = report.nan + report.positive_inf + report.negative_inf + report.negative
        if replaced:
            self.issue("warning", prim, f"dome texture: {replaced} non-finite or negative texels replaced")
        self.domes.append(
            Dome(name, scale=tuple(scale), rotation=rotation, pixels=pixels, layout=image.layout, source=resolved)
        )

    # ------------------------------------------------------------------------------------------------------------
    # Geometry
    def _triangulate(self, prim: Usd.Prim, points: np.ndarray, counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
        if counts.size == 0:
            return np.zeros((0, 3), dtype=np.int64)
        if (counts < 3).any() or counts.sum() != indices.size:
            raise SceneError(f"faceVertexCounts (sum {counts.sum()}) do not match {indices.size} faceVertexIndices "
                             "or a face has fewer than 3 vertices")
        if indices.size and (indices.min() < 0 or indices.max() >= len(points)):
            raise SceneError(f"faceVertexIndices reference points outside 0..{len(points) - 1}")
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        per_face = counts - 2
        face_of_tri = np.repeat(np.arange(counts.size), per_face)
        j = np.arange(per_face.sum()) - np.repeat(np.cumsum(per_face) - per_face, per_face)
        s = starts[face_of_tri]
        return np.stack([indices[s], indices[s + j + 1], indices[s + j + 2]], axis=-1)

    def _mesh_triangles(self, prim: Usd.Prim) -> np.ndarray:
        """Local-space triangles (T, 3, 3) of a Mesh, Sphere or Cube prim."""
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            points = np.asarray(mesh.GetPointsAttr().Get(_T) or [], dtype=np.float64).reshape(-1, 3)
            counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(_T) or [], dtype=np.int64)
            indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(_T) or [], dtype=np.int64)
            tris = self._triangulate(prim, points, counts, indices)
            return points[tris]
        if prim.IsA(UsdGeom.Sphere):
            return _uv_sphere(float(UsdGeom.Sphere(prim).GetRadiusAttr().Get(_T)))
        return _cube(float(UsdGeom.Cube(prim).GetSizeAttr().Get(_T)))

    def _read_mesh(self, prim: Usd.Prim) -> None:
        self._add_mesh(prim, self._mesh_triangles(prim), self.world(prim), str(prim.GetPath()))

    _read_gprim = _read_mesh

    def _add_mesh(self, prim: Usd.Prim, local: np.ndarray, matrix: np.ndarray, name: str) -> None:
        if local.size == 0:
            return
        if not np.all(np.isfinite(local)):
            raise SceneError("mesh points are not finite")
        tris = self.frame.points(local.reshape(-1, 3), matrix).reshape(-1, 3, 3).astype(np.float32)
        self.meshes.append(Mesh(name, tris, self.materials.material_for(prim)))

    def _read_point_instancer(self, prim: Usd.Prim) -> None:
        instancer = UsdGeom.PointInstancer(prim)
        transforms = instancer.ComputeInstanceTransformsAtTime(_T, _T)
        proto_indices = np.asarray(instancer.GetProtoIndicesAttr().Get(_T) or [], dtype=np.int64)
        prototypes = instancer.GetPrototypesRel().GetTargets()
        if transforms is None or len(proto_indices) == 0:
            return
        instancer_world = self.world(prim)
        stage = prim.GetStage()
        for p_index, proto_path in enumerate(prototypes):
            proto = stage.GetPrimAtPath(proto_path)
            if not proto:
                self.issue("warning", prim, f"prototype {proto_path} does not exist")
                continue
            parent_inv = np.linalg.inv(self.world(proto.GetParent()))
            chosen = np.flatnonzero(proto_indices == p_index)
            for sub in Usd.PrimRange(proto, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
                if not (sub.IsA(UsdGeom.Mesh) or sub.IsA(UsdGeom.Sphere) or sub.IsA(UsdGeom.Cube)):
                    continue
                local = self._mesh_triangles(sub)
                to_proto = self.world(sub) @ parent_inv  # mesh → prototype-parent space (row vectors)
                for n in chosen:
                    instance = _matrix(transforms[int(n)])
                    self._add_mesh(sub, local, to_proto @ instance @ instancer_world, f"{sub.GetPath()}#{n}")


def _uv_sphere(radius: float, rings: int = 12, segments: int = 24) -> np.ndarray:
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    v = radius * np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1)
    a, b, c, d = v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])


def _cube(size: float) -> np.ndarray:
    h = 0.5 * size
    corners = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
    return corners[np.array(tris)]


def read_scene(path: str | Path, load_textures: bool = True) -> SceneReading:
    """Read a USD scene for capture. Raises SceneError only if the stage cannot be opened; everything else is
    reported in ``SceneReading.issues``."""
    stage = open_stage(path)
    return SceneReader(stage, load_textures=load_textures).read()
