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

``n`` is the probe's capture face size (its ``resolution`` or the bake's). Setups are paid once per process that
encodes with that encoding (operators are memory-mapped from the shared cache, not rebuilt), so a task's estimate
is process + setups of the encodings in its batches + the per-probe costs of its probes, and the merge's is
process_seconds + Σ merge_probe_seconds[kind] over all probes of the store + merge_prim_squared_seconds ·
prims² (writing the USD layer grows faster than linearly with its prims, measured).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bakery.capture.light_tree import next_event_lights
from bakery.encodings import ENCODINGS
from bakery.errors import ConfigError
from bakery.pipeline.plan import BatchTask, Plan
from bakery.pipeline.settings import BakeRequest, encoding_params

DEFAULT_CALIBRATION = Path(__file__).with_name("calibration.json")
CALIBRATION_VERSION = 1


def load_calibration(path: str | os.PathLike[str] | None) -> dict[str, Any]:
    """The calibration at ``path``, else ``$BAKERY_CALIBRATION``, else the one shipped with bakery."""
    chosen = Path(path or os.environ.get("BAKERY_CALIBRATION") or DEFAULT_CALIBRATION)
    try:
        data = json.loads(chosen.read_text())
    except (OSError, ValueError) as error:
        raise ConfigError(f"{chosen}: cannot read the cost calibration: {error}") from None
    if data.get("version") != CALIBRATION_VERSION:
        raise ConfigError(f"{chosen}: calibration version {data.get('version')} (this bakery reads "
                          f"{CALIBRATION_VERSION}); run `bakery farm calibrate` again")
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


class CostModel:
    """Per-probe and per-batch seconds of a plan (module docstring)."""

    def __init__(self, request: BakeRequest, source: Any, plan: Plan, calibration: dict[str, Any]) -> None:
        self.request, self.plan, self.calibration, self.source = request, plan, calibration, source
        reading = getattr(source, "_reading", None)
        self.scene = reading.scene if reading is not None else None
        self.lights = len(self.scene.lights) if self.scene is not None else 0
        #: shadow rays per path vertex for the analytic lights (many lights are drawn, not all sampled)
        self.next_event_lights = next_event_lights([light.kind for light in self.scene.lights]) \
            if self.scene is not None else 0
        self.rendered = source.kind == "usd"
        self._size = {}

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
        capture = (c["capture_probe_seconds"] + c["seconds_per_ray"] * rays) if rays else c["loaded_probe_seconds"]
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
