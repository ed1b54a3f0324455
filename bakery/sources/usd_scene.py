"""USD scenes: every bakery probe prim of a stage, rendered with Embree, plus a layer of baked attributes.

Parent (the only place that touches ``pxr``, through :mod:`bakery.usd`)
    :meth:`UsdSceneSource.plan` reads and checks the stage once (:func:`bakery.usd.scene.read_scene`). Errors
    (``bakery check`` severity "error") stop the bake with :class:`~bakery.errors.SceneError` before anything is
    written; warnings are re-emitted as :class:`~bakery.errors.SceneWarning`. Every probe becomes a
    :class:`~bakery.probe.Probe` (name = prim path; volume members ``<volume>[i,j,k]``) whose inputs are the hash of
    everything every probe can see plus, for image probes, the image bytes (:mod:`bakery.pipeline.dependencies`).
    A reflection probe's SH-exponential fit range follows the materials in its influence volume
    (:mod:`bakery.pipeline.roughness`). :meth:`prepare` writes the capture scene, without its probes, once as a
    snapshot (:mod:`bakery.capture.snapshot`) in the bake's work folder; each probe's :class:`ProbeSpec` travels
    with its batch in its :class:`SceneProbeCapture`.

Workers
    :meth:`UsdSceneSource.capture` memory-maps the snapshot (cached per process), builds the Embree scene once and
    renders (or loads the captured image of) one probe; :meth:`UsdSceneSource.capture_many` renders a worker
    batch's probes in groups of up to :data:`GROUP_PROBES` traced together (one Embree query per bounce for the
    group). Seeds come from the probe's name (:func:`bakery.capture.probe_seed`) and each probe draws from its own
    generator, so captures do not depend on grouping, batching or the number of workers. Workers never import
    ``pxr`` and never re-read the stage.

After the store
    :meth:`after_write` writes the baked-results layer (:func:`bakery.usd.layer.write_bake_layer`) with an
    ``over`` per probe prim; a probe volume's arrays are written only if all of its probes were baked.
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bakery.capture.light_tree import light_sampling
from bakery.encodings import ENCODINGS
from bakery.environment.resample import RESAMPLE_MODEL_VERSION
from bakery.errors import SceneError, SceneWarning
from bakery.pipeline.dilate import DILATION_SETTING, NEIGHBOURS_KEY, DilationSettings
from bakery.pipeline.settings import CaptureSettings
from bakery.probe import Probe
from bakery.sources.base import (
    Capture,
    PlannedProbe,
    Source,
    SourceHandle,
    SourcePlan,
    capture_each,
    register_source,
)

if TYPE_CHECKING:  # pragma: no cover
    from bakery.capture import CaptureStats, ProbeRenderer, ProbeSpec

SCENE_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
#: Largest number of probes rendered together by :meth:`UsdSceneSource.capture_many` (one renderer call)
GROUP_PROBES = 8


def default_layer_path(output: Path) -> Path:
    """``<store stem>.bake.usda`` beside the store (never the scene's own file, whatever the store is called)."""
    output = Path(output)
    return output.with_name(f"{output.stem}.bake.usda")


@dataclass(frozen=True)
class SceneProbeCapture:
    """Capture spec of one scene probe: the probe as the scene defines it (placement, capture resolution, captured
    image and its orientation, relocation) and how to render it. It travels with its batch — the workers' snapshot
    holds the scene, not its probes — and enters the probe's content hash (:mod:`bakery.pipeline.plan`; the fields
    :class:`ProbeSpec` marks ``content_hash: False`` are hashed otherwise or not at all), so a changed capture
    resolution or image orientation re-bakes the probe."""

    probe: ProbeSpec = field(hash=False)
    settings: CaptureSettings

    @property
    def name(self) -> str:
        return self.probe.name


def _json_attribute(value: Any) -> Any:
    return value if isinstance(value, (str, int, float, bool)) else json.dumps(value, sort_keys=True)


@lru_cache(maxsize=2)
def _renderer(location: str, digest: str, settings: CaptureSettings):  # noqa: ANN202, ARG001 - digest: cache key
    from bakery.capture import ProbeRenderer
    from bakery.capture.snapshot import read_capture_scene

    scene = read_capture_scene(Path(location))
    return scene, ProbeRenderer(scene, samples=settings.samples, bounces=settings.bounces, base_seed=settings.seed,
                                target_noise=settings.target_noise, max_samples=settings.max_samples or None)


class UsdSceneSource(Source):
    """A USD stage with bakery probe prims (schemas in ``schemas/usd``)."""

    kind = "usd"
    default_face_size = 32
    default_batch_size = 64

    def __init__(self, path: Path, capture: CaptureSettings | None = None) -> None:
        self.path = Path(path)
        self.capture_settings = capture or CaptureSettings()
        self._reading = None
        self._prim_of: dict[str, str] = {}
        self._positions: dict[str, tuple[float, float, float]] = {}
        self._lights: list[dict] = []
        self._protected: tuple[str, ...] = ()

    # -- parent ---------------------------------------------------------------------------------------------------
    def plan(self, settings, previous) -> SourcePlan:  # noqa: ANN001, ARG002
        from bakery.pipeline.dependencies import environment_hash, light_table
        from bakery.pipeline.roughness import (
            TriangleBounds,
            fit_alpha_range,
            smallest_nonzero_alpha,
            visible_roughness,
        )
        from bakery.pipeline.settings import encoding_params
        from bakery.usd.scene import read_scene

        reading = read_scene(self.path, time=self.capture_settings.time,
                             subdivision=self.capture_settings.subdivision)
        if reading.errors:  # each as `bakery check` prints it: the file that defines the prim (a sublayer, an asset)
            listing = "\n".join(f"  {issue.layer or self.path}: {issue}" for issue in reading.errors)
            raise SceneError(f"{self.path}: {len(reading.errors)} error(s); the bake cannot be trusted:\n{listing}")
        for issue in reading.issues:
            warnings.warn(f"{issue.layer or self.path}: {issue.prim}: {issue.message}", SceneWarning,
                          stacklevel=2)  # all warnings
        self._reading = reading
        self._protected = tuple(str(Path(p).resolve()) for p in reading.layers)
        scene_hash = environment_hash(reading.scene, tuple(reading.assets))
        self._lights = light_table(reading.scene)
        ranged = [name for name, cls in ENCODINGS.items() if cls.accepts_alpha_range]
        planned: list[PlannedProbe] = []
        roughness_notes: list[dict[str, str]] = []
        from bakery.files import sha256_file

        bounds = None  # the triangles' bounding spheres, once for every reflection probe's roughness range
        for spec in reading.scene.probes:
            probe_settings: dict[str, Any] = {"encodings": list(spec.encodings)} if spec.encodings else {}
            if spec.influence:
                probe_settings["influence"] = spec.influence
            if spec.relocate > 0:  # where it is captured depends on the search radius
                probe_settings["relocate"] = spec.relocate
            if spec.dilation > 0:  # applied in the parent (bakery.pipeline.dilate); only "on" enters the hash
                probe_settings[DILATION_SETTING] = DilationSettings(spec.volume, spec.dilation,
                                                                    spec.dilation_passes).as_setting()
            if spec.kind == "reflection" and ranged:
                if bounds is None:
                    bounds = TriangleBounds.of(reading.scene.meshes)
                    ranged_params = {name: encoding_params(name, settings) for name in ranged}
                roughness = visible_roughness(spec.position, spec.influence or {}, bounds)
                alpha_range = fit_alpha_range(roughness)
                if alpha_range is not None:
                    nonzero = smallest_nonzero_alpha(roughness)
                    probe_settings["encoding_settings"] = {
                        name: ENCODINGS[name].probe_alpha_overrides(ranged_params[name], alpha_range, nonzero)
                        for name in ranged}
                    roughness_notes.append({"probe": spec.name, "reason": (
                        f"{', '.join(ranged)} fitted over α ∈ [{alpha_range[0]:g}, {alpha_range[1]:g}] (materials in "
                        f"its influence volume) instead of the default range")})
            probe = Probe(spec.name, (spec.kind,), spec.position, probe_settings)
            image_hash = (sha256_file(spec.image) if Path(spec.image).is_file() else "<missing>") if spec.image else None
            # a captured image is resampled to the bake grid: a changed resampling re-bakes its probe, and so does a
            # changed orientation of the image (ProbeSpec leaves the image's path and rotation to these inputs)
            inputs = (scene_hash, image_hash, RESAMPLE_MODEL_VERSION, spec.rotation) if spec.image else (scene_hash,)
            capture = SceneProbeCapture(spec, self.capture_settings)
            planned.append(PlannedProbe(probe, capture, inputs))
            self._prim_of[spec.name] = spec.volume or spec.name
            self._positions[spec.name] = spec.position
        attributes: dict[str, Any] = {
            "source": str(self.path), "source_kind": self.kind, "sources": json.dumps([str(self.path)]),
            "scene_up_axis": reading.up_axis, "scene_meters_per_unit": reading.meters_per_unit,
            "capture_samples": self.capture_settings.samples, "capture_bounces": self.capture_settings.bounces,
            "capture_seed": self.capture_settings.seed, "scene_lights": _json_attribute(self._lights),
            "capture_target_noise": self.capture_settings.target_noise,
            "capture_max_samples": self.capture_settings.max_samples,
            "capture_subdivision": self.capture_settings.subdivision,
            "capture_time": "default" if reading.scene.time_code is None else float(reading.scene.time_code),
            "capture_working_space": reading.scene.working_space,
            "capture_texture_color_spaces": _json_attribute(sorted({t.color_space for t in reading.scene.textures})),
            "capture_light_sampling": _json_attribute(light_sampling([light.kind for light in reading.scene.lights])),
        }
        if roughness_notes:
            attributes["roughness_ranges"] = _json_attribute(roughness_notes)
        return SourcePlan(planned, attributes, layers=_json_attribute(list(self._protected)),
                          issues=[str(i) for i in reading.issues])

    def layer_path(self, request) -> Path:  # noqa: ANN001
        return Path(request.layer) if request.layer is not None else default_layer_path(request.output)

    def validate_outputs(self, request) -> None:  # noqa: ANN001
        protected = set(self._protected) | {str(self.path.resolve())}
        if str(self.layer_path(request).resolve()) in protected:
            raise SceneError(f"{self.layer_path(request)}: refusing to overwrite one of the scene's own layers; "
                             "choose another --layer")
        if str(Path(request.output).resolve()) in protected:
            raise SceneError(f"{request.output}: refusing to overwrite one of the scene's own layers with the store; "
                             "choose another -o")

    def rebake(self, previous, reused: list[str]) -> tuple[set[str], dict[str, Any]]:  # noqa: ANN001
        """Reused probes that a changed local light can affect (:mod:`bakery.pipeline.dependencies`)."""
        from bakery.pipeline.dependencies import mean_irradiance_from_store, probes_affected_by_light_changes

        if not reused:
            return set(), {}
        old_table = json.loads(str(previous.attributes.get("scene_lights", "[]")))
        positions = np.array([self._positions[n] for n in reused], dtype=np.float64)
        affected, changed = probes_affected_by_light_changes(
            old_table, self._lights, reused, positions, mean_irradiance_from_store(previous, reused))
        return affected, ({"changed_lights": _json_attribute(changed)} if affected else {})

    def prepare(self, work_dir: Path) -> SourceHandle:
        from bakery.capture.snapshot import write_capture_scene

        if self._reading is None:
            raise RuntimeError("UsdSceneSource.prepare before plan")
        folder = Path(work_dir) / "scene"
        # The scene without its probes: each batch carries its own (SceneProbeCapture.probe). Encoding and decoding
        # thousands of probe records was most of the snapshot's time (a 11 000-probe hall: 0.66 s to write, 0.28 s
        # to read in every worker).
        digest = write_capture_scene(dataclasses.replace(self._reading.scene, probes=()), folder)
        return SourceHandle(self.kind, str(folder), digest)

    def after_write(self, merged, contents, request) -> dict[str, Any]:  # noqa: ANN001
        from bakery.usd.layer import BakedPrim, attribute_name, write_bake_layer

        layer_path = self.layer_path(request)
        rows_of_prim: dict[str, list[int]] = {}
        for row, probe in enumerate(merged.probes):
            rows_of_prim.setdefault(self._prim_of.get(probe.name, probe.name), []).append(row)
        expected: dict[str, int] = {}
        for prim in self._prim_of.values():
            expected[prim] = expected.get(prim, 0) + 1
        baked: list[BakedPrim] = []
        # store row -> encoding row (-1: the probe lacks the encoding), once per encoding, not per prim (a scene
        # has thousands of reflection prims)
        index_of: dict[str, np.ndarray] = {}
        for encoding in merged.encoded:
            index = np.full(len(merged.probes), -1, dtype=np.int64)
            index[np.asarray(merged.rows[encoding], dtype=np.int64)] = np.arange(len(merged.rows[encoding]))
            index_of[encoding] = index
        encoded = {encoding: {k: np.asarray(v) for k, v in values.items()}
                   for encoding, values in merged.encoded.items()}
        for prim, rows in rows_of_prim.items():
            if len(rows) != expected.get(prim, len(rows)):
                continue  # part of a volume failed: its arrays would be incomplete
            fields: dict[str, np.ndarray] = {}
            names: list[str] = []
            for encoding, values in encoded.items():
                index = index_of[encoding][rows]
                if np.any(index < 0):
                    continue
                kind = ENCODINGS[encoding].kind
                prim_values = {k: v[index] for k, v in values.items()}
                for field_name, array in ENCODINGS[encoding].layer_fields(prim_values).items():
                    fields[attribute_name(kind, encoding, field_name)] = array
                names.append(encoding)
            fraction = merged.diagnostics.get("capture/backface_fraction")
            sources = merged.diagnostics.get(NEIGHBOURS_KEY)
            sources = None if sources is None else np.asarray(sources, dtype=np.float64)[rows]
            baked.append(BakedPrim(prim, len(rows), tuple(names), fields,
                                   None if fraction is None else np.asarray(fraction, dtype=np.float32)[rows],
                                   None if sources is None or not np.all(np.isfinite(sources)) else sources))
        write_bake_layer(
            layer_path, baked, request.output, str(contents.attributes.get("settings_hash", "")), self.path,
            up_axis=self._reading.up_axis, meters_per_unit=self._reading.meters_per_unit, protected=self._protected,
            encoding_settings={name: json.loads(group["attributes"]["settings"])
                               for name, group in contents.encodings.items() if "settings" in group["attributes"]},
            instances=self._reading.instances,
        )
        return {"layer": str(layer_path)}

    # -- worker ---------------------------------------------------------------------------------------------------
    @classmethod
    def capture(cls, handle: SourceHandle, spec: SceneProbeCapture, face_size: int) -> Capture:
        probe, renderer = _probe(handle, spec)
        if probe.image:
            return _loaded(probe, face_size)
        n = probe.resolution or face_size
        return _rendered(*renderer.render(np.asarray(probe.position), n, probe.name, probe.relocate), face_size)

    @classmethod
    def capture_many(cls, handle: SourceHandle, specs: Sequence[SceneProbeCapture], face_size: int
                     ) -> list[Capture | Exception]:
        """:meth:`capture` of every spec, the rendered probes in groups of one renderer call
        (:meth:`bakery.capture.ProbeRenderer.render_many`, :func:`render_groups`). Captures are those of
        :meth:`capture` (seeds per probe name); ``capture_seconds`` is the group's time split in proportion to
        rays. If a group's render raises, its probes are rendered one by one, so the error is that probe's."""
        results: list[Capture | Exception | None] = [None] * len(specs)
        pending: dict[tuple[CaptureSettings, int], list[int]] = {}
        for i, spec in enumerate(specs):
            try:
                probe = _probe(handle, spec)[0]
                if probe.image:
                    results[i] = _loaded(probe, face_size)
                else:
                    pending.setdefault((spec.settings, probe.resolution or face_size), []).append(i)
            except Exception as error:  # noqa: BLE001 - reported for this probe by the caller
                results[i] = error
        for (settings, n), members in pending.items():
            for group in render_groups(members, 6 * n * n * settings.samples):
                try:
                    probes, renderer = zip(*(_probe(handle, specs[i]) for i in group))
                    rendered = renderer[0].render_many([np.asarray(p.position) for p in probes], n,
                                                       [p.name for p in probes], [p.relocate for p in probes])
                    for i, (cube, stats) in zip(group, rendered):
                        results[i] = _rendered(cube, stats, face_size)
                except Exception:  # noqa: BLE001 - find the probe that fails: one by one
                    for i, result in zip(group, capture_each(cls, handle, [specs[i] for i in group], face_size)):
                        results[i] = result
        return results


def render_groups(members: list[int], camera_rays: int) -> list[list[int]]:
    """``members`` in groups of at most :data:`GROUP_PROBES` probes whose passes (``camera_rays`` each) fit one
    path-tracer call (:data:`bakery.capture.render.CALL_RAYS`; a larger probe is a group of its own: its chunks
    would share no call with the others', and the group would only hold their passes in memory — measured +73 MB
    per worker at 128² with groups of 5), as few groups as that allows, of nearly equal sizes (a small last group
    would amortise less)."""
    from bakery.capture.render import CALL_RAYS

    size = max(1, min(GROUP_PROBES, CALL_RAYS // max(camera_rays, 1)))
    count = -(-len(members) // size)
    return [members[len(members) * k // count:len(members) * (k + 1) // count] for k in range(count)]


def _probe(handle: SourceHandle, spec: SceneProbeCapture) -> tuple[ProbeSpec, ProbeRenderer]:
    """The probe of ``spec`` and the process's renderer of the snapshot with its settings."""
    return spec.probe, _renderer(handle.location, handle.digest, spec.settings)[1]


def _loaded(probe: ProbeSpec, face_size: int) -> Capture:
    """The capture of a probe with a captured image, on the bake grid."""
    from bakery.capture import load_captured_cube

    cube = load_captured_cube(probe.image, np.asarray(probe.rotation), probe.resolution or face_size)
    return _on_grid(cube, face_size, {"capture_loaded": 1.0}, {})


def _rendered(cube: np.ndarray, render_stats: CaptureStats, face_size: int) -> Capture:
    """The capture of a rendered probe (its cube (6, n, n, 3) at its own resolution n): stats and per-probe
    diagnostics (achieved SH noise, rays per texel, share of camera rays that see back faces)."""
    stats = {"capture_rays": float(render_stats.rays), "capture_seconds": float(render_stats.seconds),
             "capture_rendered": 1.0}
    diagnostics = {"capture/sh_noise": np.asarray(render_stats.sh_noise, dtype=np.float32),
                   "capture/samples": np.asarray(render_stats.samples, dtype=np.float32),
                   "capture/backface_fraction": np.asarray(render_stats.backface_fraction, dtype=np.float32),
                   "capture/offset": np.asarray(render_stats.offset, dtype=np.float32)}
    return _on_grid(cube, face_size, stats, diagnostics)


def _on_grid(cube: np.ndarray, face_size: int, stats: dict[str, float], diagnostics: dict[str, np.ndarray]
             ) -> Capture:
    """A :class:`Capture` of a cube (6, n, n, 3), resampled (flux-preserving) to the bake grid's face size."""
    from bakery.sphere.cubemap import resample_cube

    if cube.shape[1] != face_size:
        cube = resample_cube(cube, face_size)
    return Capture(np.asarray(cube, dtype=np.float32), stats=stats, diagnostics=diagnostics)


register_source(UsdSceneSource)
