"""Estimated cost of a plan: seconds per probe from its capture size, samples and encodings, calibrated by a bench.

Model (one bake process, one worker; ``calibration.json`` holds the constants, :mod:`bakery.farm.calibrate`
measures them)

    process  = process_seconds + per_probe_seconds · P                    start-up, stage read, snapshot, write
    capture  = capture_probe_seconds + seconds_per_ray · rays             rendered probes only
    rays     = 6 n² · samples · (lights + 2) · (1 + b)                    primary + one shadow ray per light (above 16
                                                                          lights: per distant light and 4 drawn) and the
                                                                          dome, again per bounce; b = min(bounces,
                                                                          the calibrated effective bounces of the
                                                                          default maximum: paths escape or end by
                                                                          Russian roulette)
    encode   = Σ_enc  setup_enc(N) + P_kind(enc) · probe_enc(N)           f(N) = f0 + f2 · N²  (N: the encoding's face
                                                                          size, the bake's unless it sets one)
    diagnose = P_irr · (E_irr · (d0 + d2 · N²) + r · N²) · Q/1024          evaluating each of the E_irr irradiance
                                                                          encodings at Q quality directions; r: the
                                                                          reference errors, when on

``n`` is the probe's capture face size (its ``resolution`` or the bake's). ``bakery plan`` replaces the modelled
capture with the scene's own (:func:`pilot_capture`): a pilot capture of up to :data:`PILOT_PROBES` probes per kind
at the face sizes :data:`PILOT_FACES`, one ray per texel, the bake's bounces, counts the rays the capture really
traces per camera ray ρ (an open scene's rays escape: ~1.5; a closed room's paths are long: ~15) and times them:
σ seconds per ray (the slope between its two face sizes) and f seconds per probe (the rest: validity rays, splats).
Then

    capture  = k · (f + σ · 6 n² · samples · ρ(kind)),    k = seconds_per_traced_ray / pilot_seconds_per_ray

where k, fitted on the calibration hall, converts pilot seconds into bake seconds (``seconds_per_traced_ray``: the
calibration bakes' seconds per traced ray; ``pilot_seconds_per_ray``: the pilot's σ on the same hall); a scene of
many lights, light shapes or a sunny dome pays more per ray than the hall, and its pilot shows it. The chunking of
a plan into farm tasks keeps the modelled rays (no pilot): it must be the same on every host of the farm and cost
nothing to compute. Setups are paid once per process that encodes with that encoding (operators are memory-mapped
from the shared cache, not rebuilt), so a task's estimate
is process + setups of the encodings in its batches + the per-probe costs of its probes, and the merge's is
process_seconds + Σ merge_probe_seconds[kind] over all probes of the store + merge_prim_squared_seconds ·
prims² (writing the USD layer grows faster than linearly with its prims, measured).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bakery.capture.light_tree import next_event_lights
from bakery.encodings import ENCODINGS
from bakery.errors import ConfigError
from bakery.pipeline.plan import BatchTask, Plan
from bakery.pipeline.settings import BakeRequest, encoding_params

DEFAULT_CALIBRATION = Path(__file__).with_name("calibration.json")
CALIBRATION_VERSION = 1


_SECONDS = {"type": "number", "minimum": 0}
_PAIR = {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2}  # a + b·N² (:func:`_poly`)
#: What the cost model reads from a calibration (JSON Schema); other keys (the bench's runs, the machine) are notes.
CALIBRATION_SCHEMA = {
    "type": "object",
    "required": ["version", "capture_probe_seconds", "seconds_per_ray", "loaded_probe_seconds", "encodings",
                 "unknown_encoding_seconds", "irradiance_diagnostics", "reference_seconds_per_texel",
                 "per_probe_seconds", "process_seconds"],
    "properties": {
        "version": {"type": "integer"},
        **{key: _SECONDS for key in ("capture_probe_seconds", "seconds_per_ray", "loaded_probe_seconds",
                                     "unknown_encoding_seconds", "reference_seconds_per_texel", "per_probe_seconds",
                                     "process_seconds", "merge_prim_squared_seconds", "pilot_seconds_per_ray",
                                     "seconds_per_traced_ray")},
        "irradiance_diagnostics": _PAIR,
        "encodings": {"type": "object", "additionalProperties": {
            "type": "object", "required": ["probe", "setup"], "properties": {"probe": _PAIR, "setup": _PAIR}}},
        "effective_bounces": {"type": "object", "properties": {"measured": {"type": ["number", "null"]}}},
        "merge_probe_seconds": {"type": "object", "additionalProperties": _SECONDS},
    },
    "dependentRequired": {"pilot_seconds_per_ray": ["seconds_per_traced_ray"]},
}


def load_calibration(path: str | os.PathLike[str] | None) -> dict[str, Any]:
    """The calibration at ``path``, else ``$BAKERY_CALIBRATION``, else the one shipped with bakery; ConfigError
    naming the file and the first bad key unless it has the shape :data:`CALIBRATION_SCHEMA` describes."""
    import jsonschema

    chosen = Path(path or os.environ.get("BAKERY_CALIBRATION") or DEFAULT_CALIBRATION)
    try:
        data = json.loads(chosen.read_text())
    except (OSError, ValueError) as error:
        raise ConfigError(f"{chosen}: cannot read the cost calibration: {error}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{chosen}: not a cost calibration (a JSON {type(data).__name__}, not an object); run "
                          "`bakery farm calibrate` to write one")
    if data.get("version") != CALIBRATION_VERSION:
        raise ConfigError(f"{chosen}: calibration version {data.get('version')} (this bakery reads "
                          f"{CALIBRATION_VERSION}); run `bakery farm calibrate` again")
    errors = sorted(jsonschema.Draft202012Validator(CALIBRATION_SCHEMA).iter_errors(data),
                    key=lambda e: list(map(str, e.absolute_path)))
    if errors:
        where = ".".join(map(str, errors[0].absolute_path)) or "<root>"
        raise ConfigError(f"{chosen}: not a valid cost calibration ({where}: {errors[0].message}"
                          f"{f'; {len(errors) - 1} more' if len(errors) > 1 else ''}); run `bakery farm calibrate` "
                          "again")
    data["path"] = str(chosen)
    return data


def _poly(coefficients: list[float], size: int) -> float:
    return float(coefficients[0]) + float(coefficients[1]) * size * size


def _encoding_size(name: str, request: BakeRequest) -> int:
    params = encoding_params(name, request.settings)
    size = getattr(params, "face_size", None)
    return int(size) if size else request.settings.face_size


@dataclass
class ProbeCost:
    capture: float
    encode: dict[str, float]
    diagnostics: float

    @property
    def total(self) -> float:
        return self.capture + sum(self.encode.values()) + self.diagnostics


#: The pilot capture: rendered probes per kind (evenly spaced in the plan's order) and its two face sizes.
PILOT_PROBES, PILOT_FACES = 16, (16, 32)


def _kind(task: Any) -> str:
    return "reflection" if "reflection" in task.probe.kinds else "irradiance"


@dataclass(frozen=True)
class Pilot:
    """What a pilot capture measured (:func:`pilot_capture`), on this machine.

    Attributes:
        rays_per_camera_ray: traced rays per camera ray ρ, by probe kind.
        seconds_per_ray: rendering seconds per traced ray σ (the slope between the pilot's two face sizes).
        seconds_per_probe: rendering seconds per probe that do not grow with its rays (validity rays, the sun's
            and small lights' splats, SH noise).
    """

    rays_per_camera_ray: dict[str, float]
    seconds_per_ray: float
    seconds_per_probe: float


def pilot_capture(request: BakeRequest, source: Any, plan: Plan) -> Pilot | None:
    """Render up to :data:`PILOT_PROBES` probes per kind of the plan (evenly spaced in its order) at the face sizes
    :data:`PILOT_FACES` with one ray per texel and the bake's bounces, in groups of 8 as the bake's workers do, and
    time them (rendering only, after an untimed warm-up, not building the scene); None for image sources or when no
    probe is rendered. The ray counts are deterministic (fixed seeds), the times are this machine's."""
    reading = getattr(source, "_reading", None)
    if reading is None or source.kind != "usd":
        return None
    from bakery.capture import ProbeRenderer

    specs: dict[str, list[Any]] = {}
    for task in plan.tasks:
        probe = getattr(task.capture, "probe", None)
        if probe is not None and not probe.image:
            specs.setdefault(_kind(task), []).append(probe)
    if not specs:
        return None
    renderer = ProbeRenderer(reading.scene, samples=1, bounces=request.capture.bounces, base_seed=request.capture.seed)
    chosen = {kind: [probes[i] for i in sorted({int(round(i)) for i in np.linspace(
        0, len(probes) - 1, min(PILOT_PROBES, len(probes)))})] for kind, probes in sorted(specs.items())}
    count = sum(len(probes) for probes in chosen.values())
    first = next(iter(chosen.values()))[0]
    renderer.render_many([np.asarray(first.position)], 4, [first.name], [first.relocate])  # warm-up, not timed
    rho: dict[str, float] = {}
    rays, seconds = [], []
    for face in PILOT_FACES:
        traced_all, elapsed = 0, 0.0
        for kind, probes in chosen.items():
            traced = 0
            for start in range(0, len(probes), 8):
                group = probes[start:start + 8]
                began = time.perf_counter()
                results = renderer.render_many([np.asarray(p.position) for p in group], face, [p.name for p in group],
                                               [p.relocate for p in group])
                elapsed += time.perf_counter() - began
                traced += sum(stats.rays for _cube, stats in results)
            rho[kind] = traced / (len(probes) * 6 * face * face)  # the largest face's stays
            traced_all += traced
        rays.append(traced_all)
        seconds.append(elapsed)
    slope = (seconds[-1] - seconds[0]) / (rays[-1] - rays[0]) if rays[-1] > rays[0] else 0.0
    if not slope > 0:  # too noisy to split: every second is the rays'
        slope = seconds[-1] / max(rays[-1], 1)
    return Pilot(rays_per_camera_ray=rho, seconds_per_ray=slope,
                 seconds_per_probe=max(seconds[-1] - slope * rays[-1], 0.0) / count)


class CostModel:
    """Per-probe and per-batch seconds of a plan (module docstring). ``pilot`` (:func:`pilot_capture`): the scene's
    own rays and their cost, used instead of the modelled rays when the calibration has the pilot's yardstick
    (``pilot_seconds_per_ray``)."""

    def __init__(self, request: BakeRequest, source: Any, plan: Plan, calibration: dict[str, Any],
                 pilot: Pilot | None = None) -> None:
        self.request, self.plan, self.calibration, self.source = request, plan, calibration, source
        self.pilot = pilot if pilot is not None and "pilot_seconds_per_ray" in calibration else None
        reading = getattr(source, "_reading", None)
        self.scene = reading.scene if reading is not None else None
        self.lights = len(self.scene.lights) if self.scene is not None else 0
        #: shadow rays per path vertex for the analytic lights (many lights are drawn, not all sampled)
        self.next_event_lights = next_event_lights([light.kind for light in self.scene.lights]) \
            if self.scene is not None else 0
        self.rendered = source.kind == "usd"
        self._size = {}

    @property
    def bake_per_pilot_second(self) -> float:
        """A bake's capture seconds per pilot second: the calibration bakes' seconds per traced ray over the pilot's
        on the same hall (workers render bigger batches, at other face sizes)."""
        hall = self.calibration.get("pilot_seconds_per_ray")
        return float(self.calibration["seconds_per_traced_ray"]) / float(hall) if hall else 1.0

    def encoding_size(self, name: str) -> int:
        if name not in self._size:
            self._size[name] = _encoding_size(name, self.request)
        return self._size[name]

    def capture_rays(self, task: Any) -> float:
        if not self.rendered:
            return 0.0
        probe = getattr(task.capture, "probe", None)  # a scene probe's spec (sources.usd_scene.SceneProbeCapture)
        if probe is not None and probe.image:
            return 0.0
        n = (probe.resolution if probe is not None and probe.resolution else 0) or self.request.settings.face_size
        capture = self.request.capture
        if self.pilot is not None:  # the rays this scene traces per camera ray, measured
            by_kind = self.pilot.rays_per_camera_ray
            rho = by_kind.get(_kind(task), float(np.mean(list(by_kind.values()))))
            return 6.0 * n * n * capture.samples * rho
        return 6.0 * n * n * capture.samples * (self.next_event_lights + 2) * (
            1 + self.effective_bounces(capture.bounces))

    def effective_bounces(self, bounces: int) -> float:
        """Bounces a path really takes on average: ``bounces`` up to the calibrated effective bounces of the default
        (paths escape or end by Russian roulette long before a large maximum)."""
        measured = self.calibration.get("effective_bounces", {}).get("measured")
        return float(bounces) if measured is None else min(float(bounces), float(measured))

    def probe(self, task: Any) -> ProbeCost:
        c = self.calibration
        rays = self.capture_rays(task)
        if self.pilot is not None:  # this scene's own costs, as its pilot measured them
            scale = self.bake_per_pilot_second
            per_probe, per_ray = scale * self.pilot.seconds_per_probe, scale * self.pilot.seconds_per_ray
        else:
            per_probe, per_ray = c["capture_probe_seconds"], c["seconds_per_ray"]
        capture = (per_probe + per_ray * rays) if rays else c["loaded_probe_seconds"]
        encode = {}
        for name in task.encodings:
            entry = c["encodings"].get(name)
            encode[name] = _poly(entry["probe"], self.encoding_size(name)) if entry else c["unknown_encoding_seconds"]
        diagnostics = 0.0
        if "irradiance" in task.probe.kinds:
            n = self.request.settings.face_size
            q = self.request.settings.quality_directions / 1024.0
            evaluated = sum(1 for e in task.encodings if ENCODINGS[e].kind == "irradiance")
            diagnostics = evaluated * _poly(c["irradiance_diagnostics"], n) * q
            if self.request.settings.reference_errors:
                diagnostics += c["reference_seconds_per_texel"] * n * n * q
        return ProbeCost(max(capture, 0.0), {k: max(v, 0.0) for k, v in encode.items()}, max(diagnostics, 0.0))

    def batch(self, batch: BatchTask) -> float:
        return sum(self.probe(t).total for t in batch.probes) + self.calibration["per_probe_seconds"] * len(batch.probes)

    def setup(self, encodings: set[str]) -> float:
        entries = self.calibration["encodings"]
        return sum(max(_poly(entries[n]["setup"], self.encoding_size(n)), 0.0) for n in encodings if n in entries)

    def merge(self, plan: Plan) -> float:
        """Seconds of ``bakery merge`` of the plan's shards: start-up, then reading, finalizing and writing every
        probe of the store and its layer (per probe kind: reflection probes are prims of their own)."""
        fallback = self.calibration["per_probe_seconds"]
        per_kind = self.calibration.get("merge_probe_seconds", {"irradiance": fallback, "reflection": fallback})
        prims = len(set(getattr(self.source, "_prim_of", {}).values()))  # the layer's prims (scene sources)
        return self.calibration["process_seconds"] + sum(
            max(per_kind.get(kind, 0.0) for kind in t.probe.kinds) for t in plan.tasks) \
            + self.calibration.get("merge_prim_squared_seconds", 0.0) * prims * prims

    def process(self, batches: list[BatchTask]) -> float:
        """Seconds of one bake process running ``batches`` serially (start-up, setups, probes)."""
        used = {n for b in batches for t in b.probes for n in t.encodings}
        return self.calibration["process_seconds"] + self.setup(used) + sum(self.batch(b) for b in batches)


def batch_costs(request: BakeRequest, source: Any, plan: Plan, calibration: dict[str, Any]) -> list[float]:
    model = CostModel(request, source, plan, calibration)
    return [model.batch(b) for b in plan.batches]
