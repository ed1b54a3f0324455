"""Baking a USD scene through the pipeline: plan in the parent, capture + encode in workers, single writer.

    plan, context = plan_scene_bake(scene, settings, previous)    # parent: read + check the scene (pxr), plan
    summary = context.execute(plan, settings, output, executor)   # workers: capture "scene" probes and encode;
                                                                  # parent: store, then the baked-results layer

Parent
    :func:`bakery.usd.scene.read_scene` reads and checks the scene. Errors (``bakery check`` severity "error") stop
    the bake with :class:`bakery.errors.SceneError` before anything is written; warnings are re-emitted as
    :class:`bakery.errors.SceneWarning`. Every probe becomes a :class:`bakery.probe.Probe` (name = prim path,
    members of a volume ``<volume>[i,j,k]``) and a ``"scene"`` :class:`~bakery.pipeline.plan.CaptureSpec` whose
    ``inputs`` hold the SHA-256 of every layer and asset the scene reads (so an unchanged scene reuses the stored
    probes and any edit re-bakes them) and whose ``params`` hold the capture settings.

Workers
    :func:`capture_scene_probe` (registered as capture kind ``"scene"``) reads the scene once per process (cached by
    path and content hash), builds the Embree scene once, and renders (or loads the captured image of) one probe.
    Probe seeds come from the prim path (:func:`bakery.capture.probe_seed`), so results do not depend on batching
    or the number of workers. Unpickling a scene task imports this module (its params hold a
    :class:`SceneCaptureParams`), which registers the capture kind in spawned workers.

Writer
    After the store is written, the layer (:func:`bakery.usd.layer.write_bake_layer`) gets an ``over`` per probe
    prim; a probe volume's arrays are written only if all its probes were baked.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from bakery.errors import ConfigError, SceneError, SceneWarning
from bakery.pipeline.capture import register_capture
from bakery.probe import Probe

SCENE_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")

#: Default rays per cube texel for rendered captures.
DEFAULT_SAMPLES = 4


@dataclass(frozen=True)
class SceneCaptureParams:
    """Capture settings of a scene bake (part of every probe's content hash)."""

    samples: int = DEFAULT_SAMPLES
    bounces: int = 1
    seed: int = 0


def default_layer_path(output: Path) -> Path:
    """``<store stem>.bake.usda`` beside the store (never the scene's own file, whatever the store is called)."""
    output = Path(output)
    return output.with_name(f"{output.stem}.bake.usda")


def _json_attribute(value):  # noqa: ANN001, ANN202
    import json as _json

    return value if isinstance(value, (str, int, float, bool)) else _json.dumps(value, sort_keys=True)


# ---------------------------------------------------------------------------------------------------------------
# Worker side


@lru_cache(maxsize=2)
def _scene_state(scene_path: str, scene_hash: str, params: SceneCaptureParams):  # noqa: ARG001 - cache key
    from bakery.capture import ProbeRenderer
    from bakery.usd.scene import read_scene

    reading = read_scene(scene_path)
    specs = {spec.name: spec for spec in reading.scene.probes}
    renderer = ProbeRenderer(reading.scene, samples=params.samples, bounces=params.bounces, base_seed=params.seed)
    return specs, renderer


@register_capture("scene")
def capture_scene_probe(spec, face_size: int, probe: Probe):  # noqa: ANN001 - CaptureSpec
    """Radiance cube (6, N, N, 3) of one scene probe; no reference quadrature, no sanitize report."""
    from bakery.capture import load_captured_cube, to_face_size

    params = spec.param("capture", SceneCaptureParams())
    specs, renderer = _scene_state(spec.source, spec.inputs[0] if spec.inputs else "", params)
    if probe.name not in specs:
        raise SceneError(f"{probe.name}: not a probe of {spec.source} (the scene changed since planning?)")
    probe_spec = specs[probe.name]
    n = probe_spec.resolution or face_size
    if probe_spec.image:
        cube = load_captured_cube(probe_spec.image, np.asarray(probe_spec.rotation), n)
        stats = {"capture_loaded": 1.0}
    else:
        cube, render_stats = renderer.render(np.asarray(probe_spec.position), n, probe_spec.name)
        stats = {"capture_rays": float(render_stats.rays), "capture_seconds": float(render_stats.seconds),
                 "capture_rendered": 1.0}
    # The 4th element is summed into the batch timings by the worker, whatever process it runs in.
    return to_face_size(cube, face_size), None, None, stats


# ---------------------------------------------------------------------------------------------------------------
# Parent side
@dataclass
class SceneBakeContext:
    """What the parent keeps between planning and writing: the scene's facts, issues and probe → prim mapping."""

    scene_path: Path
    up_axis: str
    meters_per_unit: float
    protected_layers: tuple[str, ...]
    prim_of: dict[str, str]
    issues: list[str] = field(default_factory=list)
    params: SceneCaptureParams = field(default_factory=SceneCaptureParams)
    layer_path: Path | None = None

    def execute(self, plan, settings, output, executor, previous=None, resume: bool = True, progress=None,
                layer: Path | None = None, band_energy_tolerance: float | None = None):  # noqa: ANN001
        """Run the plan (:func:`bakery.pipeline.run.execute_plan`), then write the baked-results layer.

        ``band_energy_tolerance`` is passed to the pipeline (None: no band skipping, every requested encoding is
        written to the store and the layer).

        Returns the pipeline's ``BakeSummary``; its ``timings`` gain ``capture_rays``, ``capture_seconds`` and
        ``rays_per_second`` summed over every worker's captures.
        """
        from bakery.pipeline.run import execute_plan

        output = Path(output)
        self.layer_path = Path(layer) if layer is not None else default_layer_path(output)
        if str(self.layer_path.resolve()) in self.protected_layers:
            raise SceneError(f"{self.layer_path}: refusing to overwrite one of the scene's own layers; choose "
                             "another --layer")
        summary = execute_plan(
            plan, settings, output, executor, previous, resume=resume, progress=progress,
            attributes={
                **{k: _json_attribute(v) for k, v in plan.attributes.items()},
                "source": str(self.scene_path), "source_kind": "usd", "scene_up_axis": self.up_axis,
                "scene_meters_per_unit": self.meters_per_unit, "capture_samples": self.params.samples,
                "capture_bounces": self.params.bounces, "capture_seed": self.params.seed,
            },
            layers=_json_attribute(list(self.protected_layers)),  # the scene's layer identifiers
            on_written=lambda merged, attributes: self._write_layer(merged, attributes, output),
            band_energy_tolerance=band_energy_tolerance,
        )
        rays = summary.timings.get("capture_rays", 0.0)
        seconds = summary.timings.get("capture_seconds", 0.0)
        summary.timings["rays_per_second"] = rays / seconds if seconds > 0 else 0.0
        return summary

    def _write_layer(self, merged, attributes: dict[str, Any], output: Path) -> None:  # noqa: ANN001
        from bakery.encodings import get_encoding
        from bakery.usd.layer import BakedPrim, attribute_name, write_bake_layer

        rows_of_prim: dict[str, list[int]] = {}
        for row, probe in enumerate(merged.probes):
            rows_of_prim.setdefault(self.prim_of.get(probe.name, probe.name), []).append(row)
        expected = {}
        for name, prim in self.prim_of.items():
            expected[prim] = expected.get(prim, 0) + 1
        baked: list[BakedPrim] = []
        for prim, rows in rows_of_prim.items():
            if len(rows) != expected.get(prim, len(rows)):
                continue  # part of a volume failed: its arrays would be incomplete
            fields: dict[str, np.ndarray] = {}
            names: list[str] = []
            for encoding, values in merged.encoded.items():
                index = {int(r): k for k, r in enumerate(merged.rows[encoding])}
                if not all(r in index for r in rows):
                    continue
                kind = get_encoding(encoding).kind
                for field_name, array in values.items():
                    fields[attribute_name(kind, encoding, field_name)] = np.asarray(array)[[index[r] for r in rows]]
                names.append(encoding)
            baked.append(BakedPrim(prim, len(rows), tuple(names), fields))
        write_bake_layer(
            self.layer_path, baked, output, str(attributes.get("settings_hash", "")), self.scene_path,
            up_axis=self.up_axis, meters_per_unit=self.meters_per_unit, protected=self.protected_layers,
        )


def _apply_light_changes(plan, entries, settings, previous, lights, batch_size):  # noqa: ANN001
    """Re-plan: reused probes that a changed local light can affect are baked again (see dependencies)."""
    import json as _json

    from bakery.pipeline.dependencies import mean_irradiance_from_store, probes_affected_by_light_changes
    from bakery.pipeline.plan import make_batches

    old_table = _json.loads(str(previous.attributes.get("scene_lights", "[]")))
    names = list(plan.reused)
    position = {p.name: p.position for p, _ in entries}
    affected, changed = probes_affected_by_light_changes(
        old_table, lights, names, np.array([position[n] for n in names]), mean_irradiance_from_store(previous, names)
    )
    if not affected:
        return plan
    plan.reused = [n for n in plan.reused if n not in affected]
    todo = [t for t in plan.tasks if t.probe.name not in set(plan.reused)]
    plan.batches = make_batches(todo, batch_size, settings.as_json())
    plan.attributes["changed_lights"] = changed
    return plan


def plan_scene_bake(
    scene_path: Path, settings, previous=None, batch_size: int = 64,  # noqa: ANN001 - pipeline types
    samples: int = DEFAULT_SAMPLES, bounces: int = 1, seed: int = 0,
):
    """Read and check the scene, and plan one ``"scene"`` capture per probe. Returns (Plan, SceneBakeContext).

    Raises:
        SceneError: the scene cannot be opened or has errors (nothing is written).
        ConfigError: invalid capture settings.
    """
    from bakery.pipeline.plan import CaptureSpec
    from bakery.pipeline.run import plan_tasks
    from bakery.usd.scene import read_scene

    if samples < 1 or bounces < 0:
        raise ConfigError(f"samples must be >= 1 and bounces >= 0, got {samples} and {bounces}")
    scene_path = Path(scene_path)
    reading = read_scene(scene_path)
    if reading.errors:
        listing = "\n".join(f"  {issue}" for issue in reading.errors)
        raise SceneError(f"{scene_path}: {len(reading.errors)} error(s); the bake cannot be trusted:\n{listing}")
    for issue in reading.issues:
        warnings.warn(f"{scene_path}: {issue}", SceneWarning, stacklevel=2)
    # Dependencies (bakery.pipeline.dependencies): one hash for what every probe sees; the probe's own data and
    # captured image; local lights tracked one by one in the light table.
    from bakery.pipeline.dependencies import environment_hash, file_digest, light_table

    scene_hash = environment_hash(reading.scene, tuple(reading.assets))
    lights = light_table(reading.scene)
    params = SceneCaptureParams(samples, bounces, seed)
    from bakery.pipeline.roughness import fit_alpha_range, visible_roughness

    entries = []
    roughness_notes: list[dict[str, str]] = []
    prim_of: dict[str, str] = {}
    for spec in reading.scene.probes:
        probe_settings = {"encodings": list(spec.encodings)} if spec.encodings else {}
        if spec.influence:
            probe_settings["influence"] = spec.influence
        if spec.kind == "reflection":
            alpha_range = fit_alpha_range(visible_roughness(spec.position, spec.influence or {}, reading.scene.meshes))
            if alpha_range is not None:
                fit_range = {"alpha_min": alpha_range[0], "alpha_max": alpha_range[1]}
                probe_settings["encoding_settings"] = {"shexp": fit_range, "shexp_lights": dict(fit_range)}
                roughness_notes.append({"probe": spec.name, "reason": (
                    f"shexp, shexp_lights fitted over α ∈ [{alpha_range[0]:g}, {alpha_range[1]:g}] (materials in its "
                    f"influence volume) instead of the default range")})
        probe = Probe(spec.name, (spec.kind,), spec.position, probe_settings)
        inputs = (scene_hash, file_digest(spec.image)) if spec.image else (scene_hash,)
        capture = CaptureSpec(
            "scene", str(scene_path.resolve()), inputs,
            (("capture", params), ("resolution", spec.resolution), ("image", spec.image),
             ("rotation", spec.rotation)),
        )
        entries.append((probe, capture))
        prim_of[spec.name] = spec.volume or spec.name
    plan = plan_tasks(entries, settings, previous, batch_size)
    if previous is not None and plan.reused:
        plan = _apply_light_changes(plan, entries, settings, previous, lights, batch_size)
    plan.attributes["scene_lights"] = lights
    if roughness_notes:
        plan.attributes["roughness_ranges"] = roughness_notes
    context = SceneBakeContext(
        scene_path=scene_path,
        up_axis=reading.up_axis,
        meters_per_unit=reading.meters_per_unit,
        protected_layers=tuple(str(Path(p).resolve()) for p in reading.layers),
        prim_of=prim_of,
        issues=[str(i) for i in reading.issues],
        params=params,
    )
    return plan, context


def bake_scene(
    scene_path: Path,
    output: Path,
    layer_path: Path | None = None,
    face_size: int = 64,
    encodings: list[str] | None = None,
    samples: int = DEFAULT_SAMPLES,
    bounces: int = 1,
    seed: int = 0,
    executor=None,  # noqa: ANN001
) -> dict:
    """Bake every probe of a USD scene into the store ``output`` and the layer ``layer_path`` (library entry point;
    the CLI uses :func:`plan_scene_bake` + :meth:`SceneBakeContext.execute` with its executor and resume logic).

    Args:
        scene_path: .usd/.usda/.usdc/.usdz scene with bakery probe prims.
        output: HDF5 store to write.
        layer_path: baked-results layer (.usda); default :func:`default_layer_path`. Never one of the scene's
            own layers.
        face_size: bake-grid cube face size N.
        encodings: encodings to bake (default: every registered encoding of the probes' kinds); a probe's own
            ``bakery:encodings`` replaces the list for that probe (restricted to its kind).
        samples: rays per cube texel of rendered captures; bounces: diffuse bounces; seed: base of the per-probe
            seeds (each probe's seed also hashes its prim path).
        executor: a pipeline executor (default: in-process serial).

    Returns:
        A JSON-able summary: the pipeline's summary plus ``probes``, ``layer``, ``rays``, ``rays_per_second``,
        ``encodings``, ``settings_hash`` and the scene's ``issues``.

    Raises:
        SceneError: the scene cannot be opened or has errors (see ``bakery check``); nothing is written.
        ConfigError: invalid settings.
    """
    from bakery.bake import BakeSettings
    from bakery.pipeline.executors import SerialExecutor

    start = time.perf_counter()
    settings = BakeSettings(face_size=face_size, encodings=tuple(encodings or ()))
    plan, context = plan_scene_bake(scene_path, settings, None, samples=samples, bounces=bounces, seed=seed)
    summary = context.execute(plan, settings, output, executor or SerialExecutor(), None, resume=False,
                              layer=layer_path)
    result = summary.as_dict()
    result.update(
        scene=str(scene_path),
        layer=str(context.layer_path),
        probes=summary.baked + summary.reused,
        rays=int(summary.timings.get("capture_rays", 0)),
        rays_per_second=summary.timings.get("rays_per_second", 0.0),
        encodings=sorted(summary.bytes_per_probe),
        settings_hash=settings.hash(),
        issues=context.issues,
        total_seconds=time.perf_counter() - start,
    )
    return result
