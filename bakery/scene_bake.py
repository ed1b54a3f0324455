"""Baking a USD scene through the pipeline: plan in the parent, capture + encode in workers, single writer.

    plan, context = plan_scene_bake(scene, settings, previous)    # parent: read + check the scene (pxr), plan
    summary = context.execute(plan, settings, output, executor)   # workers: capture "scene" probes and encode;
                                                                  # parent: store, then the baked-results layer

Parent
    :func:`bakery.usd.scene.read_scene` reads and checks the scene. Errors (``bakery check`` severity "error") stop
    the bake with :class:`bakery.errors.SceneError` before anything is written; warnings are re-emitted as
    :class:`bakery.errors.BakeryWarning`. Every probe becomes a :class:`bakery.probe.Probe` (name = prim path,
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

import hashlib
import time
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from bakery.errors import BakeryWarning, ConfigError, SceneError
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


def _files_hash(paths: tuple[str, ...]) -> str:
    digest = hashlib.sha256()
    for path in sorted(set(paths)):
        digest.update(path.encode())
        try:
            with open(path, "rb") as handle:
                for chunk in iter(lambda: handle.read(1 << 20), b""):
                    digest.update(chunk)
        except OSError:
            digest.update(b"<unreadable>")
    return digest.hexdigest()


# ---------------------------------------------------------------------------------------------------------------
# Worker side
#: Rays and seconds of the captures run in this process (the serial executor's are the bake's).
CAPTURE_COUNTERS = {"rays": 0, "seconds": 0.0, "rendered": 0, "loaded": 0}


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
        CAPTURE_COUNTERS["loaded"] += 1
    else:
        cube, stats = renderer.render(np.asarray(probe_spec.position), n, probe_spec.name)
        CAPTURE_COUNTERS["rays"] += stats.rays
        CAPTURE_COUNTERS["seconds"] += stats.seconds
        CAPTURE_COUNTERS["rendered"] += 1
    return to_face_size(cube, face_size), None, None


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
        ``rays_per_second`` for captures run in this process (all of them with the serial executor).
        """
        from bakery.pipeline.run import execute_plan

        output = Path(output)
        self.layer_path = Path(layer) if layer is not None else default_layer_path(output)
        if str(self.layer_path.resolve()) in self.protected_layers:
            raise SceneError(f"{self.layer_path}: refusing to overwrite one of the scene's own layers; choose "
                             "another --layer")
        before = dict(CAPTURE_COUNTERS)
        summary = execute_plan(
            plan, settings, output, executor, previous, resume=resume, progress=progress,
            attributes={
                "source": str(self.scene_path), "source_kind": "usd", "scene_up_axis": self.up_axis,
                "scene_meters_per_unit": self.meters_per_unit, "capture_samples": self.params.samples,
                "capture_bounces": self.params.bounces, "capture_seed": self.params.seed,
            },
            layers=str(self.layer_path),
            on_written=lambda merged, attributes: self._write_layer(merged, attributes, output),
            band_energy_tolerance=band_energy_tolerance,
        )
        rays = CAPTURE_COUNTERS["rays"] - before["rays"]
        seconds = CAPTURE_COUNTERS["seconds"] - before["seconds"]
        summary.timings["capture_rays"] = float(rays)
        summary.timings["capture_seconds"] = float(seconds)
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
        warnings.warn(f"{scene_path}: {issue}", BakeryWarning, stacklevel=2)
    scene_hash = _files_hash(reading.layers + reading.assets)
    params = SceneCaptureParams(samples, bounces, seed)
    entries = []
    prim_of: dict[str, str] = {}
    for spec in reading.scene.probes:
        probe_settings = {"encodings": list(spec.encodings)} if spec.encodings else {}
        if spec.influence:
            probe_settings["influence"] = spec.influence
        probe = Probe(spec.name, (spec.kind,), spec.position, probe_settings)
        capture = CaptureSpec(
            "scene", str(scene_path.resolve()), (scene_hash,),
            (("capture", params), ("resolution", spec.resolution), ("image", spec.image),
             ("rotation", spec.rotation)),
        )
        entries.append((probe, capture))
        prim_of[spec.name] = spec.volume or spec.name
    plan = plan_tasks(entries, settings, previous, batch_size)
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
