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
    local +Y to local +Z (rotateX 90°, UsdImaging's ``domeOffset``, before the prim's transform). A mirroring
    transform (negative scale) mirrors the sky, as in HdEmbree and Storm, which look the texture up through the
    inverse world matrix; a non-uniform scale is reported and only its rotation and mirror applied.

What is read (``docs/capture.md``)
    Probes (bakery schema types); every UsdLux light through its class in :mod:`bakery.capture.lights`
    (Sphere, Disk, Rect with texture, Cylinder, Distant; ShapingAPI; color temperature; ``inputs:*`` attributes,
    else the legacy un-namespaced ones), Dome/DomeLight_1, GeometryLight (emission on its meshes), PortalLight (a
    dome sampling guide); meshes (fan-triangulated, catmullClark refined ``subdivision`` levels; authored normals
    of polygonal meshes), Sphere, Cube, Cylinder(_1), Cone, Capsule(_1) and Plane gprims (tessellated with their
    exact normals, :mod:`bakery.usd.gprims`), point instancers and native instances (instance proxies), with
    payloads loaded; texture coordinates for textured materials; UsdPreviewSurface and MaterialX materials
    (:mod:`bakery.usd.materials`, :mod:`bakery.usd.mtlx`). Invisible prims and ``guide``/``proxy`` purposes are
    skipped. Composition errors (unparsable sublayers, missing references and payloads) are errors. The stage is
    read at ``time`` (default: each attribute's earliest time sample, else its authored default).

Attribute types
    USD returns an opinion of another type than the schema declares as authored (``string bakery:volume:relocate =
    "no"`` would read as a truthy "no"); every attribute is read with the type its schema declares — bakery's probe
    schema (``bakery/usd/schema/generatedSchema.usda``), UsdLux, UsdGeom; xformOps by their operation — and another
    type is an error on the prim naming the attribute, its authored and its expected type (:func:`typed_value`).
    Floating-point precision and roles aside: a ``double`` authored for a ``float`` reads the same.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade, UsdSkel

from bakery.capture.ies import IesError, IesShaping, parse_ies
from bakery.capture.lights import LIGHT_MODELS, Placement
from bakery.capture.scene import CaptureScene, Dome, Light, Material, Mesh, ProbeSpec
from bakery.conventions import MAX_FACE_SIZE, stage_to_bake_axes
from bakery.environment.io import is_8bit_image, read_environment
from bakery.errors import ImageError, SceneError
from bakery.usd import gprims
from bakery.usd.assets import local_asset_path
from bakery.usd.color import WORKING_SPACE, ColorSpaceError, to_working_space
from bakery.usd.materials import MaterialReader, read_at_fallback_st, srgb_to_linear, without_st_fallbacks
from bakery.usd.plugin import FALLBACKS, PLUGIN_DIR, PROBE_TYPES
from bakery.usd.values import typed_value, value_kind

_POLE_Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # row vectors: +Y ↦ +Z
#: Time at which the scene is read without ``--time``: each attribute's earliest time sample, else its authored
#: default (USD's EarliestTime: a time sample wins over a default).
_T = Usd.TimeCode.EarliestTime()
#: Largest ``bakery:capture:resolution``: the largest bake face size
MAX_CAPTURE_RESOLUTION = MAX_FACE_SIZE
#: UsdLuxShadowAPI inputs the capture does not apply (reported per light)


#: A world matrix with NaN or infinite entries (an xformOp value of the prim or of an ancestor)
_NOT_FINITE_WORLD = "world transform is not finite (a NaN or infinite xformOp value on the prim or an ancestor)"

#: :meth:`_SceneReader._shadow` of a light without ShadowAPI opinions
_NO_SHADOW_API = {"shadow": True, "shadow_color": (0.0, 0.0, 0.0)}
#: Largest emission the float32 capture represents (np.finfo(np.float32).max)
_FLOAT32_LIMIT = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class Issue:
    """A problem found in a scene: ``severity`` "error" (the bake cannot be trusted) or "warning"; ``layer``: the
    file that defines the prim when it is not the scene's root layer (a sublayer, a referenced asset: the file to
    open to fix it; set by :meth:`SceneReader.read` with :func:`defining_layer`), else ""."""

    severity: str
    prim: str
    message: str
    layer: str = ""

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
    #: native instances (``instanceable`` prims with a composition arc) above probe prims, nested ones included:
    #: USD ignores opinions on prims inside an instance, so the baked layer de-instances them
    #: (:func:`bakery.usd.layer.write_bake_layer`)
    instances: tuple[str, ...] = ()

    @property
    def errors(self) -> tuple[Issue, ...]:
        return tuple(i for i in self.issues if i.severity == "error")


def open_stage(path: str | Path) -> Usd.Stage:
    """Open a stage with all payloads loaded. Raises SceneError if it cannot be opened."""
    path = Path(path)
    if path.is_dir():
        raise SceneError(f"{path}: is a directory, not a USD scene file")
    if not path.is_file():
        raise SceneError(f"{path}: scene not found")
    try:
        # usd-core prints each composition error as a warning while it opens the stage; SceneReader reports every
        # one of them as an issue naming its prim (``_composition_issues``), so those prints are dropped here —
        # every other diagnostic still reaches stderr
        trap_type = getattr(Tf, "DiagnosticTrap", None)  # usd-core ≥ 25.x; older versions print them
        with trap_type() if trap_type is not None else contextlib.nullcontext() as trap:
            stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
            if trap is not None:
                trap.EraseMatching(lambda diagnostic: diagnostic.sourceFunction.endswith("UsdStage::_ReportErrors"))
    except Exception as exc:  # pxr raises Tf.ErrorException
        raise SceneError(f"{path}: USD cannot open it: {tf_error_message(exc)}") from exc
    if stage is None:
        raise SceneError(f"{path}: USD cannot open it")
    return stage


_TF_ERROR = re.compile(r"Error in '[^']*' at line \d+ in file \S+ : '(.*)'\s*$", re.DOTALL)


def tf_error_message(error: Exception) -> str:
    """One line from a ``Tf.ErrorException``: the message of its first error without pxr's function, source file
    and line (``Error in 'pxrInternal…::Sdf_TextFileFormatParser…' at line 48 in file …/textParserHelpers.h :
    'scene.usda:9:44: Expected ) at …'`` → ``scene.usda:9:44: Expected ) at …``), whitespace collapsed."""
    messages = []
    for arg in error.args or (str(error),):
        match = _TF_ERROR.search(str(arg).strip())
        messages.append(match.group(1) if match else str(arg))
    text = " ".join(messages[0].split()) if messages else ""
    return text if len(text) <= 300 else text[:297] + "..."


#: Token attributes whose value decides what the capture sees, checked against their schema's allowedTokens
_CHECKED_TOKENS = ("visibility", "purpose")


def _token_problem(prim: Usd.Prim, time: Usd.TimeCode) -> str | None:
    """Why ``prim``'s authored visibility or purpose is not one of the tokens its schema allows (USD computes an
    unknown ``visibility = "hidden"`` as visible), or None."""
    for name in _CHECKED_TOKENS:
        attr = prim.GetAttribute(name)
        if not attr or not attr.HasAuthoredValue():
            continue
        try:
            value = typed_value(attr, time)
        except SceneError as error:
            return str(error)
        allowed = [str(t) for t in (attr.GetMetadata("allowedTokens") or [])]
        if allowed and str(value) not in allowed:
            return f"{name} is {str(value)!r}, expected one of {', '.join(allowed)}"
    return None


@functools.cache
def _probe_schema_types() -> dict[str, dict[str, Sdf.ValueTypeName]]:
    """{probe type: {attribute: declared type}} of bakery's schema (its ``generatedSchema.usda``), so that probe
    attributes are checked whether or not OpenUSD's schema registry saw the plugin (:mod:`bakery.usd.plugin`)."""
    layer = Sdf.Layer.FindOrOpen(str(PLUGIN_DIR / "generatedSchema.usda"))
    if layer is None:
        return {}
    return {spec.name: {a.name: a.typeName for a in spec.attributes} for spec in layer.rootPrims
            if spec.name in PROBE_TYPES}


@functools.cache
def _light_api_definitions() -> tuple:
    """The prim definitions of the UsdLux API schemas whose ``inputs:*`` the capture reads on a light whether or not
    the API is applied (ShapingAPI, ShadowAPI)."""
    registry = Usd.SchemaRegistry()
    return tuple(d for d in (registry.FindAppliedAPIPrimDefinition(api) for api in ("ShapingAPI", "ShadowAPI")) if d)


def _xform_op_problem(prim: Usd.Prim) -> str | None:
    """Why USD cannot compute the world transform of ``prim``: the first xformOp of the prim or of an ancestor
    (named) whose authored type does not fit its operation (``string xformOp:translate``), or None."""
    rotations = {f"rotate{axis}" for axis in "XYZ"}
    owner = prim
    while owner and not owner.IsPseudoRoot():
        xformable = UsdGeom.Xformable(owner)
        for op in xformable.GetOrderedXformOps() if xformable else ():
            operation = str(UsdGeom.XformOp.GetOpTypeToken(op.GetOpType()))
            if operation in rotations:
                expected = ("double", "float", "half")
            elif operation == "orient":
                expected = ("quatd", "quatf", "quath")
            elif operation == "transform":
                expected = ("matrix4d",)
            else:  # translate, scale, rotateXYZ…, pivots
                expected = ("double3", "float3", "half3")
            type_name = op.GetAttr().GetTypeName()  # not declared by a schema: the authored type
            if not type_name or value_kind(type_name) != value_kind(Sdf.ValueTypeNames.Find(expected[0])):
                where = "" if owner == prim else f" of {owner.GetPath()}"
                allowed = expected[0] if len(expected) == 1 else f"{', '.join(expected[:-1])} or {expected[-1]}"
                return (f"{op.GetAttr().GetName()}{where} is authored as {type_name or 'an unknown type'}, "
                        f"expected {allowed}")
        owner = owner.GetParent()
    return None


def _exception_text(error: Exception) -> str:
    """One line of an exception raised while a prim was read (``Tf.ErrorException``: :func:`tf_error_message`)."""
    if isinstance(error, Tf.ErrorException):
        return tf_error_message(error)
    text = " ".join(str(error).split()) or type(error).__name__
    return text if len(text) <= 300 else text[:297] + "..."


class _Frame:
    """Stage → bake conversion for world matrices (row-vector 4 × 4)."""

    def __init__(self, stage: Usd.Stage) -> None:
        self.mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
        self.up = str(UsdGeom.GetStageUpAxis(stage))
        self.axes = stage_to_bake_axes(self.up)

    def points(self, local: np.ndarray, matrix: np.ndarray) -> np.ndarray:
        """Bake-frame points (…, 3) in metres of local points and a world matrix."""
        world = local @ matrix[:3, :3] + matrix[3, :3]
        return self.mpu * (world @ self.axes)

    def vectors(self, local: np.ndarray, matrix: np.ndarray) -> np.ndarray:
        """Bake-frame vectors (metres) of local vectors (rows)."""
        return self.mpu * (np.asarray(local) @ matrix[:3, :3] @ self.axes)

    def rotation(self, matrix: np.ndarray, pre: np.ndarray | None = None) -> np.ndarray:
        """Local → bake orthogonal matrix (columns = local axes in the bake frame) of a world matrix, scale removed:
        a rotation, or a reflection for a mirroring transform (:func:`_orthonormalize`)."""
        m3 = _orthonormalize(matrix[:3, :3])
        if pre is not None:
            m3 = pre @ m3
        return (m3 @ self.axes).T


#: UsdLux ``inputs:colorTemperature``: "The valid range is from 1000 to 10000" (UsdLuxBlackbodyTemperatureAsRgb
#: clamps to it)
COLOR_TEMPERATURE_RANGE = (1000.0, 10000.0)


def blackbody_rgb(kelvin: float) -> np.ndarray:
    """Linear Rec.709 colour of a blackbody at ``kelvin`` with luminance 1 (Gf's Planckian locus, normalised to the
    Rec.709 luminance of (1, 1, 1) as HdEmbree's ``_BlackbodyTemperatureAsRgb``), the temperature clamped to UsdLux's
    valid range 1000–10000 K and negative components (the blue of the locus below ~1900 K lies outside Rec.709)
    clamped to 0 after the normalisation, both as ``UsdLuxBlackbodyTemperatureAsRgb``. ValueError if not finite
    (Gf crashes on NaN)."""
    kelvin = float(kelvin)
    if not np.isfinite(kelvin):
        raise ValueError(f"colorTemperature {kelvin} is not finite")
    kelvin = min(max(kelvin, COLOR_TEMPERATURE_RANGE[0]), COLOR_TEMPERATURE_RANGE[1])
    color = Gf.Color(Gf.ColorSpace(Gf.ColorSpaceNames.LinearRec709))
    color.SetFromPlanckianLocus(kelvin, 1.0)
    rgb = np.asarray(color.GetRGB(), dtype=np.float64)
    return np.maximum(rgb / float(rgb @ np.array([0.2126, 0.7152, 0.0722])), 0.0)


def _orthonormalize(m3: np.ndarray) -> np.ndarray:
    """The orthogonal factor of the polar decomposition of a probe's world matrix (scale removed): a rotation, or a
    **reflection** (det −1) for a mirroring transform, so that a captured image follows the probe's local frame
    (``bakery:capture:image``) as a mirrored dome's sky does (:meth:`SceneReader._dome_orientation`). Until 2026-12 a
    mirror was turned into a rotation by negating the axis of the smallest singular value — arbitrary: ``scale =
    (-2, 1, 1)`` turned the image upside down (its zenith to −Y) while ``(1, -0.5, 1)`` left it unmirrored."""
    u, _s, vt = np.linalg.svd(m3)
    return u @ vt


def _matrix(gf: Gf.Matrix4d) -> np.ndarray:
    return np.array(gf, dtype=np.float64).reshape(4, 4)


class SceneReader:
    """Reads one stage; collects issues instead of failing on the first problem."""

    def __init__(self, stage: Usd.Stage, load_textures: bool = True, time: float | None = None,
                 subdivision: int = 0) -> None:
        self.stage = stage
        self.subdivision = int(subdivision)
        self.time_code = time
        self.time = Usd.TimeCode(time) if time is not None else _T
        self.frame = _Frame(stage)
        self.xforms = UsdGeom.XformCache(self.time)
        self.materials = MaterialReader(time=self.time, load_textures=load_textures)
        self.load_textures = load_textures
        self.issues: list[Issue] = []
        #: native instances above probe prims (:attr:`SceneReading.instances`)
        self._instances: set[str] = set()
        self.meshes: list[Mesh] = []
        self.lights: list[Light] = []
        self.domes: list[Dome] = []
        self.probes: list[ProbeSpec] = []
        self.portals: list[Light] = []
        #: (name, targets, emission, normalize[, materialSyncMode of a MeshLightAPI])
        self.geometry_lights: list[tuple] = []
        self._linked: list[tuple[str, int, Usd.Prim]] = []  # ("light" | "dome", index, prim): light linking
        self._cage_faces: dict[str, np.ndarray] = {}  # refined meshes: the control-cage face of each triangle
        #: UsdSkel: skinned points (or None: rigid) and placement per skinned prim (:meth:`_read_skel_root`)
        self._skinned: dict[str, tuple[np.ndarray | None, np.ndarray]] = {}

    def issue(self, severity: str, prim: Usd.Prim | str, message: str) -> None:
        path = prim if isinstance(prim, str) else str(prim.GetPath())
        self.issues.append(Issue(severity, path, message))

    def world(self, prim: Usd.Prim) -> np.ndarray:
        """The world matrix of ``prim``; SceneError if USD cannot compute it (a wrongly typed xformOp)."""
        try:
            return _matrix(self.xforms.GetLocalToWorldTransform(prim))
        except Tf.ErrorException as error:
            self.xforms = UsdGeom.XformCache(self.time)  # it may hold the failed ancestor: its descendants fail too
            raise SceneError(_xform_op_problem(prim) or f"its world transform cannot be computed: "
                             f"{tf_error_message(error)}") from error

    def value(self, attr: Usd.Attribute, expected: Sdf.ValueTypeName | None = None):
        """``attr``'s value at the reader's time, of its declared type (:func:`typed_value`)."""
        return typed_value(attr, self.time, expected)

    def _read_skel_root(self, root_prim: Usd.Prim) -> None:
        """UsdSkel, at the reader's time (met in the traversal before the prims it skins): into ``_skinned``, per
        skinned prim path, its points (N, 3) skinned into skeleton space — or None for a rigidly deformed prim — and
        the world matrix that places them: the skeleton's, times the rigid skinning transform. Computed by
        ``UsdSkelSkinningQuery`` (linear blend or dual-quaternion skinning, as ``skel:skinningMethod`` says); as
        UsdSkel specifies and Hydra draws it, a skinned prim's own transform does not place it (its
        ``geomBindTransform`` does, inside the skinning). Blend shapes are not applied (reported)."""
        predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        cache = UsdSkel.Cache()
        root = UsdSkel.Root(root_prim)
        cache.Populate(root, predicate)
        for binding in cache.ComputeSkelBindings(root, predicate):
            skeleton = binding.GetSkeleton().GetPrim()
            query = cache.GetSkelQuery(binding.GetSkeleton())
            if not query or not query.HasBindPose():  # pxr would skin with identity bind transforms
                self.issue("warning", skeleton, "its bindTransforms are missing or do not match its joints; the prims "
                           "it skins are baked in their bind pose")
                continue
            transforms = query.ComputeSkinningTransforms(self.time)
            if transforms is None:
                self.issue("warning", skeleton, "its skinning transforms cannot be computed; the prims it skins are "
                           "baked in their bind pose")
                continue
            skeleton_world = self.world(skeleton)
            for target in binding.GetSkinningTargets():
                prim = target.GetPrim()
                if target.HasBlendShapes():
                    self.issue("warning", prim, "blend shapes are not applied by the capture (skinning is)")
                if target.IsRigidlyDeformed():
                    rigid = target.ComputeSkinnedTransform(transforms, self.time)
                    if rigid is not None:
                        self._skinned[str(prim.GetPath())] = (None, _matrix(rigid) @ skeleton_world)
                    continue
                if not prim.IsA(UsdGeom.PointBased):
                    continue
                points = UsdGeom.PointBased(prim).GetPointsAttr().Get(self.time)
                if points is not None and target.ComputeSkinnedPoints(transforms, points, self.time):
                    self._skinned[str(prim.GetPath())] = (np.asarray(points, dtype=np.float64).reshape(-1, 3),
                                                          skeleton_world)
                else:
                    self.issue("warning", prim, "its skinned points cannot be computed; baked in its bind pose")

    def _gprim_world(self, prim: Usd.Prim) -> np.ndarray:
        """The world matrix of a gprim: its own, or for a skinned prim its skeleton's (:meth:`_read_skel_root`)."""
        skinned = self._skinned.get(str(prim.GetPath()))
        return self.world(prim) if skinned is None else skinned[1]

    # ------------------------------------------------------------------------------------------------------------
    def _composition_issues(self) -> None:
        """Composition errors are errors (a sublayer that fails to parse, a missing reference or payload silently
        drops its contents from the bake), except ``.mtlx`` references, which are read with the MaterialX package."""
        for error in self.stage.GetCompositionErrors():
            text = str(error).splitlines()[0] if str(error) else type(error).__name__
            site = getattr(error, "rootSite", None)
            path = str(getattr(site, "path", "")) if site is not None else ""
            prim = path if path.startswith("/") else "/"
            if ".mtlx" in text:
                self.issue("warning", prim, "composition: a .mtlx reference cannot be composed by usd-core; its "
                           "materials are read with the MaterialX package")
                continue
            self.issue("error", prim, f"composition: {text.strip()}")

    def read(self) -> SceneReading:
        self._composition_issues()
        if not UsdGeom.StageHasAuthoredMetersPerUnit(self.stage):
            self.issue("warning", "/", f"metersPerUnit is not authored; using UsdGeom's fallback {self.frame.mpu}")
        predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        iterator = iter(Usd.PrimRange(self.stage.GetPseudoRoot(), predicate))
        for prim in iterator:
            if prim.IsPseudoRoot():
                continue
            imageable = UsdGeom.Imageable(prim)
            problem = _token_problem(prim, self.time)
            if problem:  # USD reads an unknown token as visible / default: a typo would show hidden geometry
                self.issue("error", prim, problem)
            if imageable and imageable.ComputeVisibility(self.time) == UsdGeom.Tokens.invisible:
                iterator.PruneChildren()
                continue
            purpose = imageable.ComputePurpose() if imageable else UsdGeom.Tokens.default_
            if purpose in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                iterator.PruneChildren()
                continue
            type_name = str(prim.GetTypeName())
            try:
                if prim.IsA(UsdSkel.Root):  # before the prims it skins
                    self._read_skel_root(prim)
                if type_name in PROBE_TYPES:
                    self._read_probe(prim, type_name)
                elif "probe" in type_name.lower():
                    self.issue("error", prim, f"unknown probe type {type_name!r}; known: {', '.join(PROBE_TYPES)}")
                elif prim.HasAPI(UsdLux.MeshLightAPI) and (prim.IsA(UsdGeom.Mesh) or is_surface_gprim(prim)):
                    self._read_mesh(prim) if prim.IsA(UsdGeom.Mesh) else self._read_gprim(prim)
                    self._read_mesh_light(prim)  # the geometry is read as any mesh, then emits
                elif prim.HasAPI(UsdLux.LightAPI) or prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
                    self._read_light(prim)
                elif prim.IsA(UsdGeom.PointInstancer):
                    iterator.PruneChildren()  # its prototypes are drawn only as its instances, also when it fails
                    self._read_point_instancer(prim)
                elif prim.IsA(UsdGeom.Mesh):
                    self._read_mesh(prim)
                elif is_surface_gprim(prim) or prim.IsA(UsdGeom.Points) or prim.IsA(UsdGeom.BasisCurves):
                    self._read_gprim(prim)
                elif prim.IsA(UsdGeom.Gprim):
                    self.issue("warning", prim, f"{type_name} gprims are not supported by the capture; skipped")
            except SceneError as exc:
                self.issue("error", prim, str(exc))
            except (TypeError, ValueError, IndexError, Tf.ErrorException) as exc:  # a bad value not named above
                self.issue("error", prim, f"cannot be read: {_exception_text(exc)}")
        self._apply_geometry_lights()
        self._apply_light_links()
        self._check_encodings()
        for severity, path, message in self.materials.issues:
            self.issue(severity, path, message)
        if not self.probes:
            self.issue("error", "/", "the scene has no probes (BakeryIrradianceProbe, BakeryReflectionProbe or "
                       "BakeryIrradianceProbeVolume prims)")
        if not self.lights and not self.domes and not any(mesh.material.emits for mesh in self.meshes):
            self.issue("warning", "/", "nothing in the scene emits light (no UsdLux light, no dome light, no emissive "
                       "material): every probe will be black")
        if len(self.domes) > 1:
            self.issue("warning", self.domes[1].name, f"{len(self.domes)} dome lights; only {self.domes[0].name} "
                       "is used")
        names = [p.name for p in self.probes]
        textures = self._used_textures()
        scene = CaptureScene(
            meshes=tuple(self.meshes),
            lights=tuple(self.lights),
            dome=self.domes[0] if self.domes else None,
            probes=tuple(self.probes),
            meters_per_unit=self.frame.mpu,
            up_axis=self.frame.up,
            textures=textures,
            portals=tuple(self.portals),
            working_space=WORKING_SPACE,
            time_code=self.time_code,
        )
        assert len(set(names)) == len(names)
        return SceneReading(
            scene=scene,
            issues=tuple(replace(issue, layer=defining_layer(self.stage, issue.prim)) for issue in self.issues),
            path=str(self.stage.GetRootLayer().realPath or self.stage.GetRootLayer().identifier),
            meters_per_unit=self.frame.mpu,
            up_axis=self.frame.up,
            layers=tuple(sorted({layer.realPath for layer in self.stage.GetUsedLayers() if layer.realPath})),
            assets=tuple(sorted(self._assets())),
            instances=tuple(sorted(self._instances)),
        )

    def _used_textures(self) -> tuple:
        """The textures some mesh map or light uses (others, e.g. of meshes without texture coordinates, are dropped
        from the snapshot), with the indices in materials and lights renumbered."""
        used = sorted({int(e["texture"]) for m in self.meshes for e in m.material.maps if "texture" in e}
                      | {int(i) for m in self.meshes for e in m.material.maps for _tile, i in e.get("udim", ())}
                      | {light.texture for light in self.lights if light.texture >= 0})
        index = {old: new for new, old in enumerate(used)}

        def renumbered(entry: dict) -> dict:
            if "texture" not in entry:  # a colour read per vertex
                return entry
            entry = dict(entry, texture=index[int(entry["texture"])])
            if entry.get("udim"):
                entry["udim"] = tuple((tile, index[int(i)]) for tile, i in entry["udim"])
            return entry

        for i, mesh in enumerate(self.meshes):
            if mesh.material.maps:
                maps = tuple(renumbered(e) for e in mesh.material.maps)
                self.meshes[i] = dataclasses.replace(mesh, material=dataclasses.replace(mesh.material, maps=maps))
        self.lights = [dataclasses.replace(light, texture=index[light.texture]) if light.texture >= 0 else light
                       for light in self.lights]
        return tuple(self.materials.textures[k] for k in used)

    def _assets(self) -> set[str]:
        """Files other than layers that every probe's capture can read: dome texture, material and light textures,
        MaterialX documents. Not a probe's captured image (``bakery:capture:image``): only that probe reads it, and
        its bytes are in that probe's own hash (:mod:`bakery.pipeline.dependencies`)."""
        files = {d.source for d in self.domes if d.source}
        files |= set(self.materials.files)
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
        """A probe attribute of the type bakery's schema declares (SceneError otherwise), else its fallback."""
        attr = prim.GetAttribute(name)
        expected = _probe_schema_types().get(str(prim.GetTypeName()), {}).get(name)
        value = self.value(attr, expected) if attr else None
        return FALLBACKS.get(name) if value is None else value

    def _probe_placement(self, prim: Usd.Prim) -> np.ndarray | None:
        matrix = self.world(prim)
        if not np.all(np.isfinite(matrix)):  # before the determinant (NaN: a numpy warning naming nothing)
            self.issue("error", prim, f"{_NOT_FINITE_WORLD}; probe skipped")
            return None
        det = np.linalg.det(matrix[:3, :3])
        if abs(det) < 1e-12:
            self.issue("error", prim, f"non-invertible world transform (det = {det:.3g}); probe skipped")
            return None
        return matrix

    def _read_probe(self, prim: Usd.Prim, type_name: str) -> None:
        matrix = self._probe_placement(prim)
        if matrix is None:
            return
        resolution = int(self._attr(prim, "bakery:capture:resolution") or 0)
        if not 0 <= resolution <= MAX_CAPTURE_RESOLUTION:
            self.issue("error", prim, f"bakery:capture:resolution must be >= 0 (0: the bake's face size) and <= "
                       f"{MAX_CAPTURE_RESOLUTION} (the largest face size), got {resolution}")
            return
        encodings = tuple(str(e) for e in (self._attr(prim, "bakery:encodings") or ()))
        rotation = tuple(map(tuple, self.frame.rotation(matrix).tolist()))
        path = str(prim.GetPath())
        ancestor = prim.GetParent()  # met as an instance proxy: the instances above it
        while ancestor and not ancestor.IsPseudoRoot():
            if ancestor.IsInstance():
                self._instances.add(str(ancestor.GetPath()))
            ancestor = ancestor.GetParent()
        if type_name == "BakeryIrradianceProbeVolume":
            self._read_volume(prim, matrix, resolution, encodings)
            return
        image = ""
        asset = self._attr(prim, "bakery:capture:image")
        if isinstance(asset, Sdf.AssetPath) and asset.path:
            image = local_asset_path(asset) or ""
            if not image:
                self.issue("error", prim, f"bakery:capture:image {asset.path!r} not found")
                return
        kind = "irradiance" if type_name == "BakeryIrradianceProbe" else "reflection"
        scale = float(np.cbrt(abs(np.linalg.det(matrix[:3, :3])))) * self.frame.mpu
        sizes = {"bakery:influence:radius": [float(self._attr(prim, "bakery:influence:radius"))]}
        if kind == "reflection":
            sizes["bakery:influence:extent"] = [float(x) for x in self._attr(prim, "bakery:influence:extent")]
            sizes["bakery:influence:blendDistance"] = [float(self._attr(prim, "bakery:influence:blendDistance"))]
        for name, values in sizes.items():  # a negative or NaN size would silently select no material
            if not all(np.isfinite(v) and v >= 0.0 for v in values):
                shown = values[0] if len(values) == 1 else values
                self.issue("error", prim, f"{name} must be finite and >= 0, got {shown}")
                return
        influence: dict = {"radius_m": sizes["bakery:influence:radius"][0] * scale}
        if kind == "reflection":
            influence["shape"] = str(self._attr(prim, "bakery:influence:shape"))
            influence["extent_m"] = [x * scale for x in sizes["bakery:influence:extent"]]
            influence["blend_distance_m"] = sizes["bakery:influence:blendDistance"][0] * scale
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
        if not np.all(np.isfinite(extent)) or (extent < 0).any():
            self.issue("error", prim, f"bakery:volume:extent must be finite and >= 0, got {extent.tolist()}")
            return
        path = str(prim.GetPath())
        rotation = tuple(map(tuple, self.frame.rotation(matrix).tolist()))
        # flat index i + nx·(j + ny·k): i fastest
        k, j, i = np.meshgrid(*(np.arange(c) for c in counts[::-1]), indexing="ij")
        ijk = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=-1)
        fraction = np.where(counts > 1, ijk / np.maximum(counts - 1, 1), 0.5)
        local = -extent + 2.0 * extent * fraction
        positions = self.frame.points(local, matrix)
        relocate = 0.0
        if bool(self._attr(prim, "bakery:volume:relocate")):  # half the smallest spacing (bake frame, metres)
            steps = [self.frame.vectors(np.eye(3)[a] * 2.0 * extent[a] / (counts[a] - 1), matrix)
                     for a in range(3) if counts[a] > 1]
            spacings = [float(np.linalg.norm(step)) for step in steps if np.linalg.norm(step) > 0]
            relocate = 0.5 * min(spacings) if spacings else 0.0
            if relocate == 0.0:
                self.issue("warning", prim, "bakery:volume:relocate needs two probes or more along an axis of "
                           "non-zero extent (the search radius is half the spacing); the probes are not relocated")
        dilation, passes = self._volume_dilation(prim, extent, counts, matrix)
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
                    relocate=relocate,
                    dilation=dilation,
                    dilation_passes=passes,
                )
            )

    def _volume_dilation(self, prim: Usd.Prim, extent: np.ndarray, counts: np.ndarray,
                         matrix: np.ndarray) -> tuple[float, int]:
        """(search radius in bake-frame metres, passes) of a volume's ``bakery:volume:dilate``; (0, 1) when off."""
        if not bool(self._attr(prim, "bakery:volume:dilate")):
            return 0.0, 1
        distance = float(self._attr(prim, "bakery:volume:dilationDistance"))
        passes = int(self._attr(prim, "bakery:volume:dilationIterations"))
        if not np.isfinite(distance) or distance < 0:
            self.issue("error", prim, f"bakery:volume:dilationDistance must be a finite number >= 0, got {distance}")
            return 0.0, 1
        if passes < 1:
            self.issue("error", prim, f"bakery:volume:dilationIterations must be >= 1, got {passes}")
            return 0.0, 1
        if distance > 0:  # stage units → bake-frame metres
            return distance * self.frame.mpu, passes
        cell = np.zeros(3)  # the cell diagonal: every axis with two probes or more contributes its spacing
        for a in range(3):
            if counts[a] > 1:
                cell += np.eye(3)[a] * 2.0 * extent[a] / (counts[a] - 1)
        radius = float(np.linalg.norm(self.frame.vectors(cell, matrix)))
        if radius == 0.0:
            self.issue("warning", prim, "bakery:volume:dilate needs two probes or more along an axis of non-zero "
                       "extent (or a bakery:volume:dilationDistance); the probes are not dilated")
            return 0.0, 1
        return radius * (1.0 + 1e-6), passes  # the diagonal neighbours themselves are within reach

    # ------------------------------------------------------------------------------------------------------------
    # Lights
    def _input(self, prim: Usd.Prim, name: str, fallback):
        """``inputs:<name>`` if authored, else the legacy ``<name>`` if authored, else the schema fallback; of the
        type the light's schemas declare for ``inputs:<name>`` (SceneError otherwise)."""
        expected = self._input_type(prim, f"inputs:{name}")
        for attr_name in (f"inputs:{name}", name):
            attr = prim.GetAttribute(attr_name)
            if attr and attr.HasAuthoredValue():
                return self.value(attr, expected)
        attr = prim.GetAttribute(f"inputs:{name}")
        value = self.value(attr, expected) if attr else None
        return fallback if value is None else value

    @staticmethod
    def _input_type(prim: Usd.Prim, name: str) -> Sdf.ValueTypeName | None:
        """The type of light input ``name`` in the prim's definition, else in UsdLux's ShapingAPI or ShadowAPI
        (read whether or not applied), or None."""
        for definition in (prim.GetPrimDefinition(), *_light_api_definitions()):
            attribute = definition.GetAttributeDefinition(name) if definition else None
            if attribute:
                return attribute.GetTypeName()
        return None

    def _emission_scale(self, prim: Usd.Prim) -> np.ndarray:
        intensity = float(self._input(prim, "intensity", 1.0))
        exposure = float(self._input(prim, "exposure", 0.0))
        color = np.asarray(self._input(prim, "color", (1.0, 1.0, 1.0)), dtype=np.float64)
        if not np.isfinite(exposure) or abs(exposure) > 1e4:  # 2**exposure itself overflows a float (OverflowError)
            raise SceneError(f"light exposure {exposure} is out of range (|exposure| ≤ 10000)")
        scale = intensity * 2.0**exposure * color
        if bool(self._input(prim, "enableColorTemperature", False)):
            kelvin = float(self._input(prim, "colorTemperature", 6500.0))
            if not np.isfinite(kelvin):
                raise SceneError(f"colorTemperature {kelvin} is not finite")
            low, high = COLOR_TEMPERATURE_RANGE
            if not low <= kelvin <= high:
                self.issue("warning", prim, f"colorTemperature {kelvin} K is outside UsdLux's valid range "
                                            f"{low:g}–{high:g} K; clamped")
            scale = scale * blackbody_rgb(kelvin)
        if not np.all(np.isfinite(scale)) or (scale < 0).any():
            raise SceneError(f"light emission {scale.tolist()} is negative or not finite")
        if float(np.max(scale, initial=0.0)) > _FLOAT32_LIMIT:
            raise SceneError(f"light emission {scale.tolist()} (intensity × 2^exposure × color) exceeds what the "
                             "capture can represent (float32, ~3.4e38)")
        return scale

    def _response(self, prim: Usd.Prim) -> dict[str, float]:
        """UsdLux's ``diffuse`` and ``specular`` multipliers (non-negative, finite)."""
        values = {name: float(self._input(prim, name, 1.0)) for name in ("diffuse", "specular")}
        bad = {k: v for k, v in values.items() if not np.isfinite(v) or v < 0}
        if bad:
            raise SceneError(f"light {', '.join(f'{k} {v}' for k, v in bad.items())} must be finite and ≥ 0")
        return values

    def _shadow(self, prim: Usd.Prim) -> dict[str, object]:
        """UsdLuxShadowAPI: ``shadow:enable``, ``shadow:color`` and, when authored, ``shadow:distance``,
        ``shadow:falloff`` (stage units → metres; the falloff zone never exceeds the distance) and
        ``shadow:falloffGamma`` (:attr:`bakery.capture.scene.Light.shadow_distance`)."""
        color = tuple(float(c) for c in self._input(prim, "shadow:color", (0.0, 0.0, 0.0)))
        if not all(np.isfinite(color)) or min(color) < 0:
            raise SceneError(f"shadow:color {color} must be finite and ≥ 0")
        out: dict[str, object] = {"shadow": bool(self._input(prim, "shadow:enable", True)), "shadow_color": color}
        distance = float(self._input(prim, "shadow:distance", -1.0))
        falloff = float(self._input(prim, "shadow:falloff", -1.0))
        gamma = float(self._input(prim, "shadow:falloffGamma", 1.0))
        if not all(np.isfinite([distance, falloff, gamma])) or gamma <= 0:
            raise SceneError(f"shadow:distance {distance}, shadow:falloff {falloff} and shadow:falloffGamma {gamma} "
                             "must be finite, the gamma > 0")
        if distance > 0:  # ≤ 0 (the fallback −1): no limit
            out["shadow_distance"] = distance * self.frame.mpu
            if falloff > 0:  # ≤ 0: no falloff zone
                out["shadow_falloff"] = min(falloff, distance) * self.frame.mpu
                out["shadow_falloff_gamma"] = gamma
        return out

    def _shaping(self, prim: Usd.Prim) -> tuple[float, ...]:
        """UsdLuxShapingAPI inputs as (cone angle°, softness, focus, tint r, g, b), or () if not shaped."""
        names = ("shaping:cone:angle", "shaping:cone:softness", "shaping:focus", "shaping:focusTint")
        applied = prim.HasAPI(UsdLux.ShapingAPI)
        authored = any((prim.GetAttribute(f"inputs:{n}") and prim.GetAttribute(f"inputs:{n}").HasAuthoredValue())
                       or (prim.GetAttribute(n) and prim.GetAttribute(n).HasAuthoredValue()) for n in names)
        if not (applied or authored):
            return ()
        cone = float(self._input(prim, "shaping:cone:angle", 90.0))
        # UsdLux: "Values outside of the [0, 1] range are clamped to the range"
        softness = min(max(float(self._input(prim, "shaping:cone:softness", 0.0)), 0.0), 1.0)
        focus = float(self._input(prim, "shaping:focus", 0.0))
        tint = tuple(float(c) for c in self._input(prim, "shaping:focusTint", (0.0, 0.0, 0.0)))
        return (cone, softness, focus, *tint)

    def _placement(self, matrix: np.ndarray) -> Placement:
        x, y, z = (self.frame.vectors(np.eye(3)[i], matrix) for i in range(3))
        lengths = tuple(float(np.linalg.norm(v)) for v in (x, y, z))
        axes = tuple(tuple(float(c) for c in v / max(n, 1e-300)) for v, n in zip((x, y, z), lengths))
        position = tuple(float(c) for c in self.frame.points(np.zeros(3), matrix))
        return Placement(position, axes, lengths, self.frame.mpu)

    def _read_light(self, prim: Usd.Prim, matrix: np.ndarray | None = None, name: str | None = None) -> None:
        """A UsdLux light at its world transform, or — one instance of a point instancer's prototype — at
        ``matrix`` under ``name`` ("<path>#n")."""
        matrix = self.world(prim) if matrix is None else matrix
        if not np.all(np.isfinite(matrix)):
            self.issue("error", prim, f"{_NOT_FINITE_WORLD}; light skipped")
            return
        if abs(np.linalg.det(matrix[:3, :3])) < 1e-12:
            self.issue("error", prim, "non-invertible world transform; light skipped")
            return
        name = str(prim.GetPath()) if name is None else name
        if prim.IsA(UsdLux.PortalLight):
            width = float(self._input(prim, "width", 1.0))
            height = float(self._input(prim, "height", 1.0))
            placement = self._placement(matrix)
            self.portals.append(Light("rect", name, position=placement.position, axes=placement.axes,
                                      size=(width * placement.lengths[0], height * placement.lengths[1])))
            return
        scale = self._emission_scale(prim)
        normalize = bool(self._input(prim, "normalize", False))
        if prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
            self._read_dome(prim, matrix, scale)
            if self.domes and self.domes[-1].name == str(prim.GetPath()):
                self._linked.append(("dome", len(self.domes) - 1, prim))
            return
        if prim.IsA(UsdLux.GeometryLight):
            if self._response(prim) != {"diffuse": 1.0, "specular": 1.0} or self._shadow(prim) != _NO_SHADOW_API:
                self.issue("warning", prim, "diffuse/specular multipliers and ShadowAPI of a GeometryLight are "
                                            "not applied (its meshes emit as surfaces)")
            targets = [str(t) for t in UsdLux.GeometryLight(prim).GetGeometryRel().GetTargets()]
            if not targets:
                self.issue("warning", prim, "GeometryLight has no geometry targets; skipped")
            self.geometry_lights.append((name, targets, scale, normalize))
            return
        cls = next((c for c in LIGHT_MODELS.values()
                    if any(prim.IsA(getattr(UsdLux, t)) for t in c.usd_types if hasattr(UsdLux, t))), None)
        if cls is None:
            self.issue("warning", prim, f"{prim.GetTypeName()} lights are not supported by the capture; skipped")
            return
        inputs = {key: self._input(prim, key, fallback) for key, fallback in cls.usd_inputs.items()}
        light, notes = cls.from_usd(name, inputs, self._placement(matrix), scale, normalize)
        for note in notes:
            self.issue("warning", prim, note)
        emitted = np.asarray(light.illuminance if cls.kind == "distant" else light.radiance, dtype=np.float64)
        if not np.all(np.isfinite(emitted)) or float(np.max(emitted, initial=0.0)) > _FLOAT32_LIMIT:
            raise SceneError(f"light {'illuminance' if cls.kind == 'distant' else 'radiance'} {emitted.tolist()} "
                             "(after normalize) exceeds what the capture can represent (float32, ~3.4e38)")
        shaping = self._shaping(prim) if cls.kind != "distant" else ()
        ies = self._ies(prim) if cls.kind != "distant" else None
        if cls.kind == "distant" and (self._shaping(prim) or self._input(prim, "shaping:ies:file", None)):
            self.issue("warning", prim, "ShapingAPI on a DistantLight has no effect")
        texture = -1
        tex = self._input(prim, "texture:file", None)
        if isinstance(tex, Sdf.AssetPath) and tex.path:
            if cls.kind != "rect":
                self.issue("warning", prim, f"texture:file on a {prim.GetTypeName()} is not applied")
            else:
                texture = self._light_texture(prim, tex)
        self.lights.append(dataclasses.replace(light, shaping=shaping, texture=texture, ies=ies,
                                               **self._response(prim), **self._shadow(prim)))
        self._linked.append(("light", len(self.lights) - 1, prim))

    def _ies(self, prim: Usd.Prim) -> IesShaping | None:
        """UsdLuxShapingAPI's IES profile (``shaping:ies:file``, ``:angleScale``, ``:normalize``), or None."""
        asset = self._input(prim, "shaping:ies:file", None)
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:
            return None
        resolved = local_asset_path(asset)
        if resolved is None:
            self.issue("warning", prim, f"IES profile {asset.path!r} not found; the light is not shaped by it")
            return None
        try:  # LM-63 files are ASCII; latin-1 reads any byte (a stray ° in a keyword line)
            profile = parse_ies(Path(resolved).read_text(encoding="latin-1"), asset.path)
        except OSError as error:
            self.issue("error", prim, f"IES profile {asset.path!r} cannot be read: {error.strerror or error}")
            return None
        except IesError as error:
            self.issue("error", prim, f"IES profile {error}")
            return None
        angle_scale = float(self._input(prim, "shaping:ies:angleScale", 0.0))
        if not np.isfinite(angle_scale):
            self.issue("error", prim, f"shaping:ies:angleScale {angle_scale} is not finite")
            return None
        return IesShaping(profile, angle_scale, bool(self._input(prim, "shaping:ies:normalize", False)))

    def _light_texture(self, prim: Usd.Prim, asset: Sdf.AssetPath) -> int:
        resolved = local_asset_path(asset)
        if resolved is None:
            self.issue("warning", prim, f"light texture {asset.path!r} not found; uniform emission used")
            return -1
        if not self.load_textures:
            return -1
        index = self.materials.texture_index(resolved, "auto", str(prim.GetPath()))
        return -1 if index is None else index

    def _apply_light_links(self) -> None:
        """UsdLux light and shadow linking: a light (or the dome) whose ``collection:lightLink`` leaves out some of
        the meshes read illuminates only the others (:attr:`Light.links`); one whose ``collection:shadowLink`` leaves
        some out is shadowed by the others alone (:attr:`Light.shadow_links`). Light filters are reported."""
        for kind, index, prim in self._linked:
            api = UsdLux.LightAPI(prim)
            emitters = self.lights if kind == "light" else self.domes
            for collection, field in ((api.GetLightLinkCollectionAPI(), "links"),
                                      (api.GetShadowLinkCollectionAPI(), "shadow_links")):
                members = self._members(collection)
                if members is not None:
                    emitters[index] = dataclasses.replace(emitters[index], **{field: members})
            if api.GetFiltersRel().GetTargets():
                self.issue("warning", prim, "light filters are not applied by the capture")

    def _members(self, collection: Usd.CollectionAPI) -> tuple[int, ...] | None:
        """Indices of the meshes read that ``collection`` includes, or None if it includes them all."""
        include_root = collection.GetIncludeRootAttr().Get()
        expression = collection.GetMembershipExpressionAttr() if hasattr(collection, "GetMembershipExpressionAttr") \
            else None
        if include_root and not collection.GetExcludesRel().GetTargets() and not (
                expression and expression.HasAuthoredValue()):
            return None  # the fallback: everything (no query per mesh)
        query = collection.ComputeMembershipQuery()
        included = [query.IsPathIncluded(Sdf.Path(mesh.name.split("#", 1)[0])) for mesh in self.meshes]
        return None if all(included) else tuple(i for i, inside in enumerate(included) if inside)

    def _read_mesh_light(self, prim: Usd.Prim) -> None:
        """UsdLuxMeshLightAPI on a mesh or gprim: recorded, and applied to its meshes by
        :meth:`_apply_geometry_lights`."""
        scale = self._emission_scale(prim)
        if self._response(prim) != {"diffuse": 1.0, "specular": 1.0} or self._shadow(prim) != _NO_SHADOW_API:
            self.issue("warning", prim, "diffuse/specular multipliers and ShadowAPI of a mesh light are not "
                                        "applied (it emits as a surface)")
        attr = prim.GetAttribute("light:materialSyncMode")
        mode = str(attr.Get()) if attr and attr.Get() else str(UsdLux.Tokens.materialGlowTintsLight)
        self.geometry_lights.append((str(prim.GetPath()), [str(prim.GetPath())], scale,
                                     bool(self._input(prim, "normalize", False)), mode))

    def _apply_geometry_lights(self) -> None:
        """GeometryLight and MeshLightAPI: the light's emission L = intensity·2^exposure·color (÷ area in stage units²
        when normalized) on the meshes under the GeometryLight's targets, or of the MeshLightAPI prim. A
        GeometryLight adds L to the material's emission. A mesh light's surface emits (the capture has one emission
        per surface: what rays see and what lights the scene) by its ``light:materialSyncMode``:
        ``materialGlowTintsLight`` L ⊙ the material's emissive colour (or L where the material does not emit),
        ``independent`` L, ``noMaterialResponse`` L with no diffuse or specular response."""
        for name, targets, scale, normalize, *mode in self.geometry_lights:
            found = False
            for i, mesh in enumerate(self.meshes):
                base = mesh.name.split("#", 1)[0]
                if not any(base == t or base.startswith(t + "/") for t in targets):
                    continue
                found = True
                tris = np.asarray(mesh.triangles, dtype=np.float64)
                area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=-1).sum()
                area_su = area / self.frame.mpu**2
                radiance = scale / area_su if normalize and area_su > 0 else scale
                material = mesh.material
                if not mode:  # GeometryLight
                    emission = tuple(float(a + b) for a, b in zip(material.emission, radiance))
                    material = dataclasses.replace(material, emission=emission)
                else:
                    material = self._mesh_light_material(name, material, radiance, mode[0])
                self.meshes[i] = dataclasses.replace(mesh, material=material)
            if not found and targets:
                self.issue("warning", name, f"GeometryLight targets {targets} hold no meshes the capture reads")

    def _mesh_light_material(self, name: str, material: Material, radiance: np.ndarray, mode: str) -> Material:
        """The material of a MeshLightAPI surface emitting ``radiance`` (:meth:`_apply_geometry_lights`)."""
        light = tuple(float(c) for c in radiance)
        if mode == "noMaterialResponse":
            keep = tuple(m for m in material.maps if m.get("input") == "opacity")
            return dataclasses.replace(material, diffuse=(0.0, 0.0, 0.0), specular=(0.0, 0.0, 0.0),
                                       use_specular_workflow=True, emission=light, maps=keep)
        maps = tuple(m for m in material.maps if m.get("input") != "emissiveColor")
        if mode == "materialGlowTintsLight" and material.emits:
            tint = [dict(m, scale=tuple(float(x) * c for x, c in zip(m.get("scale", (1.0,) * 4), (*light, 1.0))),
                         bias=tuple(float(x) * c for x, c in zip(m.get("bias", (0.0,) * 4), (*light, 1.0))))
                    for m in material.maps if m.get("input") == "emissiveColor"]
            emission = tuple(a * b for a, b in zip(material.emission, light))
            return dataclasses.replace(material, emission=emission, maps=tuple(sorted(
                (*maps, *tint), key=lambda m: m["input"])))
        if mode not in ("materialGlowTintsLight", "independent"):
            self.issue("warning", name, f"light:materialSyncMode {mode!r} is unknown; read as 'independent'")
        if material.emits and mode == "independent":
            self.issue("warning", name, "materialSyncMode 'independent': the surface emits the light's colour; the "
                                        "material's own glow is not added (the capture has one emission per surface)")
        return dataclasses.replace(material, emission=light, maps=maps)

    def _dome_orientation(self, prim: Usd.Prim, matrix: np.ndarray, pre: np.ndarray | None) -> np.ndarray:
        """Dome-local → bake orthogonal matrix (columns: the dome's local axes in the bake frame) of its world matrix,
        after the DomeLight_1 pole turn ``pre``: the orthogonal factor of the polar decomposition, a **reflection**
        (det −1) for a mirroring transform. Hydra looks the dome up through the inverse of its full world matrix
        (HdEmbree ``_SampleDomeLight``: ``xformWorldToLight.TransformDir``; Storm ``worldToLightTransform``), so a
        negative scale mirrors the sky; until 2026-12 bakery turned it into a rotation (``scale = (-1, 1, 1)``
        showed the sky turned 180° about Y instead of mirrored in X). A non-uniform scale, which Hydra applies to
        the directions before normalising them (a squashed sky), is not modelled: reported, its rotation (and
        mirror) kept."""
        m3 = np.asarray(matrix, dtype=np.float64)[:3, :3]
        u, sigma, vt = np.linalg.svd(m3)
        if sigma[0] > 0 and sigma[-1] < sigma[0] * (1.0 - 1e-5):
            self.issue("warning", prim, "dome light with a non-uniform scale (singular values "
                       f"{', '.join(f'{x:.6g}' for x in sigma)}): Hydra stretches the sky by it; bakery applies only "
                       "the rotation (and any mirroring) of the transform")
        q = u @ vt  # nearest orthogonal matrix; keeps the sign of det(m3)
        if pre is not None:
            q = pre @ q
        return (q @ self.frame.axes).T

    def _read_dome(self, prim: Usd.Prim, matrix: np.ndarray, scale: np.ndarray) -> None:
        pre = None
        if prim.IsA(UsdLux.DomeLight_1):
            pole = str(self._input(prim, "poleAxis", "scene") or "scene")
            attr = prim.GetAttribute("poleAxis")
            pole = str(attr.Get(self.time)) if attr and attr.Get(self.time) else pole
            if pole == "Z" or (pole == "scene" and self.frame.up == "Z"):
                pre = _POLE_Y_TO_Z
        rotation = tuple(map(tuple, self._dome_orientation(prim, matrix, pre).tolist()))
        name = str(prim.GetPath())
        response = self._response(prim)
        response = {**response, **self._shadow(prim)}  # ShadowAPI on the dome (Dome.shadow, Dome.shadow_color)
        texture = self._input(prim, "texture:file", None)
        fmt = str(self._input(prim, "texture:format", "automatic") or "automatic")
        if not isinstance(texture, Sdf.AssetPath) or not texture.path:
            self.domes.append(Dome(name, scale=tuple(scale), rotation=rotation, **response))
            return
        resolved = local_asset_path(texture)
        if resolved is None:
            self.issue("error", prim, f"dome texture {texture.path!r} not found")
            return
        layouts = {"automatic": None, "latlong": "equirect", "angular": "angular", "mirroredBall": "mirrored_ball",
                   "cubeMapVerticalCross": "vertical_cross"}
        if fmt not in layouts:
            self.issue("error", prim, f"dome texture format {fmt!r} is not a UsdLux format ({', '.join(layouts)})")
            return
        if not self.load_textures:
            self.domes.append(Dome(name, scale=tuple(scale), rotation=rotation, source=resolved, **response))
            return
        try:
            image, report = read_environment(resolved, layouts[fmt], decode="raw")  # colour managed below
        except ImageError as exc:
            self.issue("error", prim, str(exc))
            return
        pixels = image.pixels
        attr = prim.GetAttribute("inputs:texture:file") or prim.GetAttribute("texture:file")
        color_space = attr.GetColorSpace() if attr else ""
        if is_8bit_image(resolved):  # 8-bit textures are sRGB-encoded (sourceColorSpace "auto", as in Hydra)
            pixels = srgb_to_linear(pixels).astype(np.float32)
        elif color_space:
            try:
                pixels = to_working_space(pixels, color_space).astype(np.float32)
            except ColorSpaceError as error:
                self.issue("warning", prim, f"dome texture: {error}; read as linear Rec.709")
        replaced = report.nan + report.positive_inf + report.negative_inf + report.negative
        if replaced:
            self.issue("warning", prim, f"dome texture: {replaced} non-finite or negative texels replaced")
        self.domes.append(
            Dome(name, scale=tuple(scale), rotation=rotation, pixels=pixels, layout=image.layout, source=resolved,
                 **response)
        )

    # ------------------------------------------------------------------------------------------------------------
    # Geometry
    def _triangulate(self, prim: Usd.Prim, points: np.ndarray, counts: np.ndarray, indices: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fan triangulation, as Hydra's ``HdMeshUtil::ComputeTriangleIndices`` (also of concave faces): point
        indices (T, 3), face-vertex positions (T, 3) and face index (T,) per triangle. Faces of fewer than 3 vertices
        are skipped (reported), as Hydra skips them ("degenerated face found") while drawing the rest of the mesh;
        UsdGeomMesh::ValidateTopology's violations — counts not summing to the indices, indices outside the points —
        are errors."""
        if counts.size == 0:
            return np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
        if (counts < 0).any() or counts.sum() != indices.size:
            raise SceneError(f"faceVertexCounts (sum {counts.sum()}) do not match {indices.size} faceVertexIndices "
                             "or a count is negative")
        if indices.size and (indices.min() < 0 or indices.max() >= len(points)):
            raise SceneError(f"faceVertexIndices reference points outside 0..{len(points) - 1}")
        degenerate = np.flatnonzero(counts < 3)
        if degenerate.size:
            self.issue("warning", prim, f"{degenerate.size} face(s) of fewer than 3 vertices (faces "
                       f"{degenerate[:5].tolist()}{'…' if degenerate.size > 5 else ''}) skipped, as Hydra skips them")
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        per_face = np.maximum(counts - 2, 0)
        face_of_tri = np.repeat(np.arange(counts.size), per_face)
        j = np.arange(per_face.sum()) - np.repeat(np.cumsum(per_face) - per_face, per_face)
        s = starts[face_of_tri]
        corners = np.stack([s, s + j + 1, s + j + 2], axis=-1)
        return indices[corners], corners, face_of_tri

    def _mesh_geometry(self, prim: Usd.Prim) -> tuple[np.ndarray | gprims.Tessellation, tuple | None]:
        """Local-space triangles (T, 3, 3) of a Mesh or implicit-surface prim, and for meshes the triangulation
        (point indices, face-vertex positions, face indices) for primvar interpolation."""
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            skinned = self._skinned.get(str(prim.GetPath()), (None, None))[0]
            points = skinned if skinned is not None else np.asarray(
                self.value(mesh.GetPointsAttr()) or [], dtype=np.float64).reshape(-1, 3)
            counts = np.asarray(self.value(mesh.GetFaceVertexCountsAttr()) or [], dtype=np.int64)
            indices = np.asarray(self.value(mesh.GetFaceVertexIndicesAttr()) or [], dtype=np.int64)
            scheme_attr = mesh.GetSubdivisionSchemeAttr()
            scheme = str(self.value(scheme_attr)) if scheme_attr and scheme_attr.HasAuthoredValue() else "none"
            if scheme not in ("none", "bilinear"):
                levels = self.subdivision
                refine = {"catmullClark": catmull_clark, "loop": loop_subdivide}.get(scheme)
                if scheme == "loop" and counts.size and bool(np.any(counts != 3)):
                    refine = None  # Loop subdivides triangles (OpenSubdiv: non-triangles are an error)
                    self.issue("warning", prim, "subdivisionScheme 'loop' on faces that are not triangles: baked as "
                               "its control cage")
                elif levels > 0 and refine is not None:
                    holes = self._hole_faces(mesh, counts.size)
                    points, counts, indices, cage = refine(points, counts, indices, levels, with_faces=True)
                    self.issue("warning", prim, f"{scheme} subdivision refined {levels} level(s) (creases and "
                               "boundary rules simplified; primvars are read on the control cage)")
                    tris, corners, faces = self._triangulate(prim, points, counts, indices)
                    keep = ~np.isin(cage[faces], holes)  # the refined faces of hole faces are holes (OpenSubdiv)
                    self._cage_faces[str(prim.GetPath())] = cage[faces][keep]  # for GeomSubsets
                    return points[tris[keep]], None
                else:
                    self.issue("warning", prim, f"subdivisionScheme {scheme!r}: baked as its control cage "
                               + ("(set the recipe's capture.subdivision to refine)" if refine is not None else
                                  "(only catmullClark and loop can be refined)"))
            tris, corners, faces = self._triangulate(prim, points, counts, indices)
            holes = self._hole_faces(mesh, counts.size)
            if holes.size:  # hole faces are not surfaces (UsdGeomMesh holeIndices); primvars keep their face indices
                keep = ~np.isin(faces, holes)
                tris, corners, faces = tris[keep], corners[keep], faces[keep]
            return points[tris], (tris, corners, faces, counts.size)
        return self._implicit_surface(prim), None

    def _hole_faces(self, mesh: UsdGeom.Mesh, faces: int) -> np.ndarray:
        """The mesh's ``holeIndices`` (faces that are holes), those outside 0..faces − 1 dropped (reported)."""
        holes = np.asarray(self.value(mesh.GetHoleIndicesAttr()) or [], dtype=np.int64)
        valid = (holes >= 0) & (holes < faces)
        if not valid.all():
            self.issue("warning", mesh.GetPrim(), f"holeIndices {holes[~valid][:5].tolist()} are not faces of the mesh "
                       f"(0..{faces - 1}); ignored")
        return holes[valid]

    def _implicit_surface(self, prim: Usd.Prim) -> gprims.Tessellation:
        """Local triangles and normals of a Sphere, Cube, Cylinder(_1), Cone, Capsule(_1) or Plane
        (:mod:`bakery.usd.gprims`)."""
        if prim.IsA(UsdGeom.Points) or prim.IsA(UsdGeom.BasisCurves):
            return self._points_or_curves(prim)

        def value(name: str) -> object:
            return self.value(prim.GetAttribute(name))

        def length(name: str) -> float:
            number = float(value(name))
            if not np.isfinite(number) or number < 0:
                raise SceneError(f"{name} = {number} is negative or not finite")
            return number

        if prim.IsA(UsdGeom.Sphere):
            return gprims.uv_sphere(length("radius"))
        if prim.IsA(UsdGeom.Cube):
            return gprims.cube(length("size"))
        axis = str(value("axis"))
        if prim.IsA(UsdGeom.Plane):
            return gprims.plane(length("width"), length("length"), axis)
        if prim.IsA(UsdGeom.Cone):
            return gprims.cone(length("radius"), length("height"), axis)
        if prim.IsA(UsdGeom.Cylinder) or prim.IsA(UsdGeom.Capsule):
            radii = (length("radius"),) * 2
        else:  # Cylinder_1, Capsule_1
            radii = (length("radiusBottom"), length("radiusTop"))
        if prim.IsA(UsdGeom.Cylinder) or prim.IsA(UsdGeom.Cylinder_1):
            return gprims.cylinder(*radii, length("height"), axis)
        return gprims.capsule(*radii, length("height"), axis)

    def _points_or_curves(self, prim: Usd.Prim) -> gprims.Tessellation:
        """UsdGeomPoints as spheres and UsdGeomBasisCurves as tubes of their ``widths`` (:mod:`bakery.usd.gprims`:
        icosahedra and hexagonal prisms of the round shapes' mean projected area); widths per point or control
        point, per curve or constant; not authored: 1 stage unit (reported)."""
        points = np.asarray(self.value(UsdGeom.PointBased(prim).GetPointsAttr()) or [],
                            dtype=np.float64).reshape(-1, 3)
        schema = UsdGeom.Points(prim) if prim.IsA(UsdGeom.Points) else UsdGeom.Curves(prim)
        widths = np.asarray(self.value(schema.GetWidthsAttr()) or [], dtype=np.float64).reshape(-1)
        if widths.size == 0:
            self.issue("warning", prim, "widths not authored: read as 1 stage unit")
            widths = np.ones(1)
        if not np.all(np.isfinite(points)) or not np.all(np.isfinite(widths)) or (widths < 0).any():
            raise SceneError("points and widths must be finite, widths ≥ 0")
        if prim.IsA(UsdGeom.Points):
            if widths.size not in (1, len(points)):
                raise SceneError(f"{widths.size} widths for {len(points)} points: author one width per point, or "
                                 "one for all")
            return gprims.point_spheres(points, np.broadcast_to(widths, len(points)))
        curves = UsdGeom.BasisCurves(prim)
        counts = np.asarray(self.value(curves.GetCurveVertexCountsAttr()) or [], dtype=np.int64)
        if counts.sum() != len(points) or (counts < 1).any():
            raise SceneError(f"curveVertexCounts sum to {int(counts.sum())} for {len(points)} points: they must be "
                             "≥ 1 and sum to the number of points")
        kind = str(curves.GetTypeAttr().Get(self.time) or "cubic")
        basis = str(curves.GetBasisAttr().Get(self.time) or "bezier")
        wrap = str(curves.GetWrapAttr().Get(self.time) or "nonperiodic")
        if kind == "cubic" and basis not in gprims.CUBIC_BASES:
            self.issue("warning", prim, f"basis {basis!r} is not bezier, bspline or catmullRom: read as linear")
            kind = "linear"
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        if widths.size == len(points):
            per_vertex = widths
        elif widths.size == counts.size:
            per_vertex = np.repeat(widths, counts)
        else:
            if widths.size != 1:
                self.issue("warning", prim, f"{widths.size} widths for {counts.size} curves of {len(points)} "
                           "points: their mean is used")
            per_vertex = np.full(len(points), float(widths.mean()))
        sampled = [gprims.curve_samples(np.column_stack([points[a : a + c], per_vertex[a : a + c]]), kind, basis, wrap)
                   for a, c in zip(starts, counts)]
        return gprims.curve_tubes([x[:, :3] for x in sampled], [0.5 * np.maximum(x[:, 3], 0.0) for x in sampled])

    def _read_mesh(self, prim: Usd.Prim) -> None:
        local, topology = self._mesh_geometry(prim)
        self._add_mesh(prim, local, self._gprim_world(prim), str(prim.GetPath()), topology)

    _read_gprim = _read_mesh

    def _corner_primvar(self, prim: Usd.Prim, name: str, topology, components: int = 2,  # noqa: ANN001
                        fallback: str = "") -> np.ndarray | None:
        """A float2 (texture coordinates) or float3 (``components`` = 3: colours) primvar at every triangle corner
        (T, 3, components), or None (reported, ending with ``fallback``: what is used instead) if it cannot be
        read."""
        what = "textures read" if components == 2 else "colour inputs read"
        fallback = fallback or ("the textures are read at the primvar reader's fallback st" if components == 2
                                else "their fallback values are used")
        primvar = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance(name)  # an ancestor's constant primvar too
        if not primvar or not primvar.HasValue():
            self.issue("warning", prim, f"{what} primvar {name!r}, which the mesh does not have; {fallback}")
            return None
        values = np.asarray(primvar.ComputeFlattened(self.time), dtype=np.float64)
        if values.ndim != 2 or values.shape[1] < components or not np.all(np.isfinite(values)):
            self.issue("warning", prim, f"primvar {name!r} is not float{components} or not finite; {fallback}")
            return None
        interpolation = primvar.GetInterpolation()
        at_corners = _at_corners(values[:, :components], interpolation, topology)
        if at_corners is None:
            self.issue("warning", prim, f"primvar {name!r} has too few values for its {interpolation} "
                       f"interpolation; {fallback}")
        return at_corners

    def _corner_normals(self, prim: Usd.Prim, topology) -> np.ndarray | None:  # noqa: ANN001
        """A polygonal Mesh's authored shading normals (``primvars:normals``, else ``normals``) at every triangle
        corner, local (T, 3, 3), or None (not authored, subdivided — subdivision defines its own normals — or
        unusable, reported)."""
        mesh = UsdGeom.Mesh(prim)
        scheme = mesh.GetSubdivisionSchemeAttr()
        if scheme and scheme.HasAuthoredValue() and str(scheme.Get()) != "none":
            return None
        primvar = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance("normals")  # as Hydra's _GetInheritedPrimvar
        if self._skinned.get(str(prim.GetPath()), (None, None))[0] is not None:  # bind-pose normals
            if (primvar and primvar.HasValue()) or mesh.GetNormalsAttr().HasAuthoredValue():
                self.issue("warning", prim, "skinned: its authored normals are not skinned; the geometric normals "
                           "of the skinned points are used")
            return None
        if primvar and primvar.HasValue():
            values, interpolation = primvar.ComputeFlattened(self.time), primvar.GetInterpolation()
        elif mesh.GetNormalsAttr().HasAuthoredValue():
            values, interpolation = self.value(mesh.GetNormalsAttr()), mesh.GetNormalsInterpolation()
        else:
            return None
        values = np.asarray(values if values is not None else [], dtype=np.float64)
        local = _at_corners(values.reshape(-1, 3), interpolation, topology) if values.size else None
        if local is None or not np.all(np.isfinite(local)):
            self.issue("warning", prim, f"normals ({interpolation}) do not match the mesh or are not finite; the "
                       "geometric normals are used")
            return None
        return local

    def _bake_normals(self, prim: Usd.Prim, local: np.ndarray, matrix: np.ndarray) -> np.ndarray | None:
        """Local corner normals (T, 3, 3) → bake-frame unit normals float32, or None (reported) if one vanishes."""
        # normals transform by the inverse transpose of the world matrix (row vectors: n · M⁻ᵀ), then rotate
        world = local.reshape(-1, 3) @ np.linalg.inv(matrix[:3, :3]).T @ self.frame.axes
        length = np.linalg.norm(world, axis=-1, keepdims=True)
        if not np.all(length > 0):
            self.issue("warning", prim, "normals include zero vectors; the geometric normals are used")
            return None
        return (world / length).reshape(-1, 3, 3).astype(np.float32)

    def _add_mesh(self, prim: Usd.Prim, local: np.ndarray | gprims.Tessellation, matrix: np.ndarray, name: str,
                  topology=None) -> None:  # noqa: ANN001
        """Add a mesh from local triangles (a Mesh's, with its triangulation ``topology``) or a gprim's
        tessellation, placed by the world ``matrix``."""
        local_normals = None
        if isinstance(local, gprims.Tessellation):
            local, local_normals = local.triangles, local.normals
        elif topology is not None:
            local_normals = self._corner_normals(prim, topology)
        if local.size == 0:
            return
        if not np.all(np.isfinite(local)):
            raise SceneError("mesh points are not finite")
        if not np.all(np.isfinite(matrix)):
            raise SceneError(_NOT_FINITE_WORLD)
        tris = self.frame.points(local.reshape(-1, 3), matrix).reshape(-1, 3, 3).astype(np.float32)
        normals = None if local_normals is None else self._bake_normals(prim, local_normals, matrix)
        for part, material, primvar, label in self._material_parts(prim, topology, tris.shape[0]):
            uvs = None
            textured = any("primvar" not in entry for entry in material.maps)  # textures read at st
            if primvar is not None and textured:
                # where the gprim has no such primvar the reader's fallback st is read (UsdPreviewSurface
                # specification: "fallback value to be returned if geometry fetch failed"): a constant lookup
                at_fallback, reading = read_at_fallback_st(material)
                if topology is None:
                    self.issue("warning", prim, f"{prim.GetTypeName()} gprims have no texture coordinates; {reading}")
                else:
                    corner = self._corner_primvar(prim, primvar, topology, fallback=reading)
                    uvs = None if corner is None else corner.astype(np.float32)
                if uvs is None:  # every corner at st (0, 0); each entry's constant st_transform moves it
                    material = at_fallback
                    uvs = np.zeros((tris.shape[0], 3, 2), dtype=np.float32)
                else:
                    material = without_st_fallbacks(material)
            elif textured:  # no primvar named (cannot happen for the readers' materials): as before, untextured
                material = dataclasses.replace(material, maps=tuple(e for e in material.maps if "primvar" in e))
            colors, material = self._vertex_colors(prim, material, topology)

            def take(array: np.ndarray | None) -> np.ndarray | None:
                return array if array is None or part is None else array[part]

            self.meshes.append(Mesh(name if label is None else f"{name}#{label}", take(tris), material, take(uvs),
                                    take(normals), front=_front_side(prim, matrix, self.time), colors=take(colors)))

    def _vertex_colors(self, prim: Usd.Prim, material: Material, topology) -> tuple[np.ndarray | None, Material]:  # noqa: ANN001
        """The corner colours (T, 3, 3) float32 of the colour primvar the material's per-hit colour entries read
        (``displayColor`` of Hydra's fallback surface, a ``UsdPrimvarReader_float3``'s ``varname``, a MaterialX
        ``geompropvalue``, also one tinting a texture), and the material — without those entries (their fallback
        values stand; tinted textures untinted) where the primvar cannot be read."""
        names = list(dict.fromkeys(entry.get("primvar") or entry["tint_primvar"] for entry in material.maps
                                   if "primvar" in entry or "tint_primvar" in entry))
        if not names:
            return None, material
        if len(names) > 1:
            self.issue("warning", prim, f"colour inputs read different primvars ({', '.join(names)}); {names[0]} is "
                       "read for all")
        corner = None
        if topology is None:
            self.issue("warning", prim, f"{prim.GetTypeName()} gprims have no per-vertex primvars; the colour "
                       f"primvar {names[0]!r} is read as its fallback")
        else:
            corner = self._corner_primvar(prim, names[0], topology, components=3)
        if corner is None:  # colour entries keep their fallback, tinted textures lose the tint
            return None, dataclasses.replace(material, maps=tuple(
                {k: v for k, v in e.items() if k != "tint_primvar"} for e in material.maps if "primvar" not in e))
        return corner.astype(np.float32), material

    def _material_parts(self, prim: Usd.Prim, topology, triangles: int):  # noqa: ANN001, ANN202
        """(triangle indices or None for all, material, primvar, subset label or None) per material of the mesh:
        UsdGeomSubsets of the ``materialBind`` family bind their own materials to their faces (UsdShade), the
        rest keeps the mesh's binding."""
        subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets() if prim.IsA(UsdGeom.Mesh) else []
        material, primvar = self.materials.material_for(prim)
        if not subsets:
            return [(None, material, primvar, None)]
        faces = topology[2] if topology is not None else self._cage_faces.get(str(prim.GetPath()))
        if faces is None or faces.size != triangles:
            self.issue("warning", prim, "GeomSubset materials cannot be mapped to this mesh's triangles; the mesh's "
                                        "binding is used")
            return [(None, material, primvar, None)]
        face_count = int(faces.max()) + 1 if faces.size else 0
        owner = np.full(face_count, -1, dtype=np.int64)  # the subset binding each face (−1: the mesh's)
        for k, subset in enumerate(subsets):
            if str(subset.GetElementTypeAttr().Get()) != "face":
                continue
            index = np.asarray(self.value(subset.GetIndicesAttr()) or [], dtype=np.int64)
            index = index[(index >= 0) & (index < face_count)]
            owner[index[owner[index] < 0]] = k  # a face in two subsets keeps the first (the schema forbids it)
        parts = []
        per_triangle = owner[faces]
        for k in range(-1, len(subsets)):
            part = np.flatnonzero(per_triangle == k)
            if part.size == 0:
                continue
            if k < 0:
                parts.append((part, material, primvar, None))
            else:
                # the subset's binding (inherited from the mesh when it has none, as UsdShade resolves it and
                # Hydra binds HdGeomSubsets); the fallback surface reads the mesh's displayColor/displayOpacity
                sub_material, sub_primvar = self.materials.material_for(subsets[k].GetPrim(), display_prim=prim)
                parts.append((part, sub_material, sub_primvar, subsets[k].GetPrim().GetName()))
        return parts

    def _read_point_instancer(self, prim: Usd.Prim, instancer_world: np.ndarray | None = None,
                              suffix: str = "") -> None:
        """Every instance of every prototype: its meshes, gprims, points and curves (named "<path>#n"), its UsdLux
        lights (one light per instance, "<path>#n"; a GeometryLight once, for all instances' meshes) and nested
        point instancers (names "<path>#n#m"), skipping guide/proxy prims as the stage traversal does and prims
        invisible from the prototype root down (Hydra), and the instances masked by ``invisibleIds``/``inactiveIds``.
        Instance transforms in UsdGeomPointInstancer's order: the prototype root's local transform (once), scales,
        orientations, positions, the instancer's. ``instancer_world``: the instancer's world matrix when it is itself
        an instance of a prototype."""
        instancer = UsdGeom.PointInstancer(prim)
        for attr in (instancer.GetPositionsAttr(), instancer.GetOrientationsAttr(), instancer.GetScalesAttr()):
            self.value(attr)  # their types (USD computes the transforms from them)
        time = self._instancer_time(instancer)
        # the prototype root's own transform is applied below, with the rest of the prototype's (IncludeProtoXform
        # would apply it twice); masked instances (inactiveIds, invisibleIds) are dropped by the mask below
        transforms = instancer.ComputeInstanceTransformsAtTime(time, time, UsdGeom.PointInstancer.ExcludeProtoXform,
                                                               UsdGeom.PointInstancer.IgnoreMask)
        proto_indices = np.asarray(typed_value(instancer.GetProtoIndicesAttr(), time) or [], dtype=np.int64)
        prototypes = instancer.GetPrototypesRel().GetTargets()
        if transforms is None or len(proto_indices) == 0 or not prototypes:
            return
        if len(transforms) != len(proto_indices):  # USD computes none when an array's length does not match
            raise SceneError(f"the transforms of its {len(proto_indices)} instances cannot be computed: positions "
                             "(and orientations, scales when authored) need one value per protoIndices entry")
        mask = np.asarray(instancer.ComputeMaskAtTime(time) or [True] * len(proto_indices), dtype=bool)
        if mask.size != proto_indices.size:
            mask = np.ones(proto_indices.size, dtype=bool)
        instancer_world = self.world(prim) if instancer_world is None else instancer_world
        stage = prim.GetStage()
        for p_index, proto_path in enumerate(prototypes):
            proto = stage.GetPrimAtPath(proto_path)
            if not proto:
                self.issue("warning", prim, f"prototype {proto_path} does not exist")
                continue
            chosen = np.flatnonzero((proto_indices == p_index) & mask)
            if chosen.size == 0:
                continue
            instances = [(f"{suffix}#{n}", _matrix(transforms[int(n)]) @ instancer_world) for n in chosen]
            iterator = iter(Usd.PrimRange(proto, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
            for sub in iterator:
                imageable = UsdGeom.Imageable(sub)
                # visibility from the prototype root down, as Hydra's point instancer computes it
                # (UsdImagingPointInstancerAdapter::_ComputeProtoVisibility): the prototype's namespace ancestors —
                # an invisible "Prototypes" scope — do not hide its instances; an invisible prim prunes its subtree
                if imageable and (typed_value(imageable.GetVisibilityAttr(), self.time) == UsdGeom.Tokens.invisible
                                  or imageable.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)):
                    iterator.PruneChildren()
                    continue
                if str(sub.GetTypeName()) in PROBE_TYPES:  # a probe has one place: not one per instance
                    self.issue("warning", sub, "probe inside a PointInstancer prototype: not baked (probes are "
                                               "placed prims, not instanced; place it outside the prototypes)")
                    continue
                to_proto = self._to_prototype_parent(sub, proto)  # prim → prototype-parent space (row vectors)
                path = str(sub.GetPath())
                try:
                    if sub.IsA(UsdGeom.PointInstancer):
                        for tag, instance in instances:
                            self._read_point_instancer(sub, to_proto @ instance, tag)
                        iterator.PruneChildren()
                    elif sub.IsA(UsdLux.GeometryLight):
                        self._read_light(sub)
                    elif sub.IsA(UsdLux.DomeLight) or sub.IsA(UsdLux.DomeLight_1):
                        self.issue("warning", sub, "a dome light in a point instancer's prototype is not applied")
                    elif sub.HasAPI(UsdLux.LightAPI) and not sub.HasAPI(UsdLux.MeshLightAPI):
                        for tag, instance in instances:
                            self._read_light(sub, to_proto @ instance, f"{path}{tag}")
                    elif (sub.IsA(UsdGeom.Mesh) or is_surface_gprim(sub) or sub.IsA(UsdGeom.Points)
                          or sub.IsA(UsdGeom.BasisCurves)):
                        local, topology = self._mesh_geometry(sub)
                        if sub.HasAPI(UsdLux.MeshLightAPI):  # every instance emits (names "<path>#n")
                            self._read_mesh_light(sub)
                        for tag, instance in instances:
                            self._add_mesh(sub, local, to_proto @ instance, f"{path}{tag}", topology)
                    elif sub.IsA(UsdGeom.Gprim):
                        self.issue("warning", sub, f"{sub.GetTypeName()} gprims are not supported by the capture; "
                                   "skipped")
                except SceneError as exc:
                    self.issue("error", sub, str(exc))
                except (TypeError, ValueError, IndexError, Tf.ErrorException) as exc:  # as in :meth:`read`
                    self.issue("error", sub, f"cannot be read: {_exception_text(exc)}")

    def _instancer_time(self, instancer: UsdGeom.PointInstancer) -> Usd.TimeCode:
        """The time at which a point instancer's instances are computed: the reader's, or without ``--time`` the
        earliest time sample of its per-instance attributes (Default when none is sampled). Evaluated at a sample
        with itself as the base time, velocities and angular velocities move nothing (USD's
        ComputeInstanceTransformsAtTime at EarliestTime extrapolates positions by velocities to −∞)."""
        if self.time != _T:
            return self.time
        firsts = []
        for attr in (instancer.GetPositionsAttr(), instancer.GetOrientationsAttr(), instancer.GetOrientationsfAttr(),
                     instancer.GetScalesAttr(), instancer.GetProtoIndicesAttr(), instancer.GetVelocitiesAttr(),
                     instancer.GetAngularVelocitiesAttr(), instancer.GetAccelerationsAttr(),
                     instancer.GetInvisibleIdsAttr(), instancer.GetIdsAttr()):
            samples = attr.GetTimeSamples() if attr else []
            if samples:
                firsts.append(samples[0])
        return Usd.TimeCode(min(firsts)) if firsts else Usd.TimeCode.Default()

    def _to_prototype_parent(self, prim: Usd.Prim, proto: Usd.Prim) -> np.ndarray:
        """The transform of ``prim`` (the prototype root or one of its descendants) into the space of the prototype
        root's parent: the local transforms from ``prim`` up to the root, the root's own included (UsdGeomPointInstancer
        step 1, "the authored local to parent transformation for prototypes[protoIndices[i]]"); an empty-scaled
        ancestor above the root does not matter."""
        matrix = np.eye(4)
        current = prim
        while True:
            local, resets = self.xforms.GetLocalTransformation(current)
            matrix = matrix @ _matrix(local)
            if current == proto or resets or not current.GetParent():
                return matrix
            current = current.GetParent()


def catmull_clark(points: np.ndarray, counts: np.ndarray, indices: np.ndarray, levels: int,
                  with_faces: bool = False) -> tuple[np.ndarray, ...]:
    """``levels`` steps of Catmull-Clark refinement of a polygon mesh (points (P, 3), faceVertexCounts,
    faceVertexIndices) → a quad mesh. Boundary edges and their vertices follow the cubic B-spline boundary rules
    (edge midpoints, ¾ + ⅛ + ⅛ vertices: UsdGeom's "edgeAndCorner" boundaries without creases). ``with_faces``:
    also the control-cage face (Q,) each quad comes from (for GeomSubsets)."""
    parent = np.arange(np.asarray(counts).size)
    for _ in range(levels):
        counts = np.asarray(counts, dtype=np.int64)
        indices = np.asarray(indices, dtype=np.int64)
        n_pts, n_faces = len(points), counts.size
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        face_of = np.repeat(np.arange(n_faces), counts)
        nxt = np.arange(indices.size) + 1
        nxt[np.cumsum(counts) - 1] = starts
        a, b = indices, indices[nxt]
        face_points = np.zeros((n_faces, 3))
        np.add.at(face_points, face_of, points[a])
        face_points /= counts[:, None]
        key = np.minimum(a, b) * n_pts + np.maximum(a, b)
        edges, edge_of = np.unique(key, return_inverse=True)
        e0, e1 = edges // n_pts, edges % n_pts
        edge_faces = np.bincount(edge_of, minlength=edges.size)
        fp_sum = np.zeros((edges.size, 3))
        np.add.at(fp_sum, edge_of, face_points[face_of])
        boundary = edge_faces == 1
        edge_points = np.where(boundary[:, None], 0.5 * (points[e0] + points[e1]),
                               (points[e0] + points[e1] + fp_sum) / np.maximum(edge_faces + 2, 1)[:, None])
        # vertex points
        valence = np.bincount(np.concatenate([e0, e1]), minlength=n_pts).astype(np.float64)
        f_sum = np.zeros((n_pts, 3))
        f_cnt = np.bincount(a, minlength=n_pts).astype(np.float64)
        np.add.at(f_sum, a, face_points[face_of])
        mid = 0.5 * (points[e0] + points[e1])
        r_sum = np.zeros((n_pts, 3))
        np.add.at(r_sum, e0, mid)
        np.add.at(r_sum, e1, mid)
        nval = np.maximum(valence, 1.0)[:, None]
        new_vertices = (f_sum / np.maximum(f_cnt, 1.0)[:, None] + 2.0 * r_sum / nval + (nval - 3.0) * points) / nval
        new_vertices = _boundary_vertices(points, e0[boundary], e1[boundary], new_vertices)
        # quads: (vertex, edge to next, face point, edge from previous)
        prev = np.arange(indices.size) - 1
        prev[starts] = np.cumsum(counts) - 1
        vi = a
        e_next = n_pts + edge_of
        e_prev = n_pts + edge_of[prev]
        fi = n_pts + edges.size + face_of
        points = np.concatenate([new_vertices, edge_points, face_points])
        indices = np.stack([vi, e_next, fi, e_prev], axis=-1).reshape(-1)
        counts = np.full(indices.size // 4, 4, dtype=np.int64)
        parent = parent[face_of]  # one quad per face-vertex of the previous level
    return (points, counts, indices, parent) if with_faces else (points, counts, indices)


def _boundary_vertices(points: np.ndarray, a: np.ndarray, b: np.ndarray, interior: np.ndarray) -> np.ndarray:
    """The vertex points (P, 3) of a refinement step: the boundary rule ¾·v + ⅛·(its two boundary neighbours) on the
    vertices of the boundary edges (a, b) (E,) each, ``interior`` elsewhere (Catmull-Clark and Loop alike)."""
    on_boundary = np.zeros(len(points), dtype=bool)
    on_boundary[a] = True
    on_boundary[b] = True
    neighbours = np.zeros((len(points), 3))
    np.add.at(neighbours, a, points[b])
    np.add.at(neighbours, b, points[a])
    return np.where(on_boundary[:, None], 0.75 * points + 0.125 * neighbours, interior)


def loop_subdivide(points: np.ndarray, counts: np.ndarray, indices: np.ndarray, levels: int,
                   with_faces: bool = False) -> tuple[np.ndarray, ...]:
    """``levels`` steps of Loop subdivision of a triangle mesh (points (P, 3), faceVertexCounts all 3,
    faceVertexIndices) → a triangle mesh, each triangle split in four (C. Loop, "Smooth Subdivision Surfaces Based
    on Triangles", 1987; the weights OpenSubdiv uses):

        edge point      3/8·(a + b) + 1/8·(c + d)        (c, d opposite the edge; a boundary edge: its midpoint)
        vertex point    (1 − n·β)·v + β·Σ neighbours,   β = (5/8 − (3/8 + ¼·cos(2π/n))²)/n
                        (a boundary vertex: ¾·v + ⅛·(its two boundary neighbours))

    ``with_faces``: also the control-cage triangle (T,) each triangle comes from (for GeomSubsets)."""
    parent = np.arange(np.asarray(counts).size)
    tri = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    for _ in range(levels):
        n_pts = len(points)
        a, b = tri.reshape(-1), np.roll(tri, -1, axis=1).reshape(-1)  # the directed edges a → b of every triangle
        opposite = np.roll(tri, -2, axis=1).reshape(-1)  # the third corner of each edge's triangle
        key = np.minimum(a, b) * n_pts + np.maximum(a, b)
        edges, edge_of = np.unique(key, return_inverse=True)
        e0, e1 = edges // n_pts, edges % n_pts
        edge_faces = np.bincount(edge_of, minlength=edges.size)
        boundary = edge_faces == 1
        opposite_sum = np.zeros((edges.size, 3))
        np.add.at(opposite_sum, edge_of, points[opposite])
        edge_points = np.where(boundary[:, None], 0.5 * (points[e0] + points[e1]),
                               0.375 * (points[e0] + points[e1]) + 0.125 * opposite_sum)
        valence = np.bincount(np.concatenate([e0, e1]), minlength=n_pts).astype(np.float64)
        ring = np.zeros((n_pts, 3))
        np.add.at(ring, e0, points[e1])
        np.add.at(ring, e1, points[e0])
        n = np.maximum(valence, 1.0)
        beta = (0.625 - (0.375 + 0.25 * np.cos(2.0 * np.pi / n)) ** 2) / n
        new_vertices = (1.0 - n * beta)[:, None] * points + beta[:, None] * ring
        new_vertices = _boundary_vertices(points, e0[boundary], e1[boundary], new_vertices)
        mid = (n_pts + edge_of).reshape(-1, 3)  # edge points of (v0→v1, v1→v2, v2→v0), in each triangle's winding
        v = tri
        tri = np.concatenate([np.stack([v[:, 0], mid[:, 0], mid[:, 2]], axis=1),
                              np.stack([mid[:, 0], v[:, 1], mid[:, 1]], axis=1),
                              np.stack([mid[:, 2], mid[:, 1], v[:, 2]], axis=1),
                              np.stack([mid[:, 0], mid[:, 1], mid[:, 2]], axis=1)])
        parent = np.tile(parent, 4)
        points = np.concatenate([new_vertices, edge_points])
    counts = np.full(len(tri), 3, dtype=np.int64)
    out = (points, counts, tri.reshape(-1))
    return (*out, parent) if with_faces else out


def _front_side(prim: Usd.Prim, matrix: np.ndarray, time: Usd.TimeCode = _T) -> int:
    """:attr:`Mesh.front` of a gprim placed by the world ``matrix``: 0 when ``doubleSided``, else +1 for a Mesh of
    right-handed ``orientation`` (USD's fallback), −1 for a left-handed one, the sign flipped by a mirroring world
    transform (det < 0) as Hydra flips the winding; the bake frame is a rotation. The tessellated implicit surfaces,
    points and curves are wound outward and keep +1 whatever their ``orientation``: UsdGeom applies the winding rule
    "for all non-implicit surface and solid types" (usdGeom/overview.dox, UsdGeom_WindingOrder), and Hydra's
    generated meshes for them are always rightHanded (geomUtil/*MeshGenerator.cpp)."""
    gprim = UsdGeom.Gprim(prim)
    double_sided = typed_value(gprim.GetDoubleSidedAttr(), time)
    if double_sided:
        return 0
    side = 1
    if prim.IsA(UsdGeom.Mesh) and typed_value(gprim.GetOrientationAttr(), time) == UsdGeom.Tokens.leftHanded:
        side = -1
    return side if np.linalg.det(np.asarray(matrix, dtype=np.float64)[:3, :3]) >= 0 else -side


def _at_corners(values: np.ndarray, interpolation: str, topology) -> np.ndarray | None:  # noqa: ANN001
    """Primvar values (N, C) at every triangle corner (T, 3, C) by their interpolation, from a mesh's
    triangulation (point indices, face-vertex indices, face index per triangle, face count); None if too few."""
    tris, corners, faces, _face_count = topology
    try:
        if interpolation == UsdGeom.Tokens.faceVarying:
            return values[corners]
        if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
            return values[tris]
        if interpolation == UsdGeom.Tokens.uniform:
            return np.repeat(values[faces][:, None, :], 3, axis=1)
        return np.broadcast_to(values[0], tris.shape + values.shape[1:]).copy()
    except IndexError:
        return None


#: The implicit surfaces the capture tessellates (:mod:`bakery.usd.gprims`).
IMPLICIT_SURFACES = (UsdGeom.Sphere, UsdGeom.Cube, UsdGeom.Cylinder, UsdGeom.Cylinder_1, UsdGeom.Cone,
                     UsdGeom.Capsule, UsdGeom.Capsule_1, UsdGeom.Plane)


def is_surface_gprim(prim: Usd.Prim) -> bool:
    """Whether ``prim`` is one of :data:`IMPLICIT_SURFACES`."""
    return any(prim.IsA(kind) for kind in IMPLICIT_SURFACES)


def defining_layer(stage: Usd.Stage, prim_path: str) -> str:
    """The file of the strongest ``def`` of the prim at ``prim_path`` (or of the prim owning that property path), if
    that is not the stage's root layer — the sublayer or referenced asset to open to fix it — else ""."""
    if not Sdf.Path.IsValidPathString(prim_path) or prim_path == "/":
        return ""
    prim = stage.GetPrimAtPath(Sdf.Path(prim_path).GetPrimPath())
    if not prim:
        return ""
    for spec in prim.GetPrimStack():
        if spec.specifier == Sdf.SpecifierDef:
            layer = spec.layer
            if layer == stage.GetRootLayer() or layer.anonymous:
                return ""
            return layer.realPath or layer.identifier
    return ""


def read_scene(path: str | Path, load_textures: bool = True, time: float | None = None,
               subdivision: int = 0) -> SceneReading:
    """Read a USD scene for capture at USD time ``time`` (None: each attribute's earliest time sample, else its
    authored default), refining catmullClark meshes ``subdivision`` levels. Raises SceneError only if the stage cannot
    be opened; everything else is reported in ``SceneReading.issues``."""
    stage = open_stage(path)
    return SceneReader(stage, load_textures=load_textures, time=time, subdivision=subdivision).read()
