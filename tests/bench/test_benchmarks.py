"""pytest-benchmark suite: wall time of bakes through the one bake path (``bakery.bake``), per encoding and per
example scene, with the bytes and peak allocation each one costs.

    python -m pytest tests/bench --benchmark-enable                     # median, IQR, rounds; ratios to the best
    python -m pytest tests/bench --benchmark-enable --benchmark-autosave  # then --benchmark-compare to diff runs

Every benchmark bakes a fresh store (``resume=False``): capture or resample, encode, diagnostics, store and layer
writes, as ``bakery bake`` does. Operators that do not depend on the environment come from the operator cache, as on
a farm after the first bake; a warm-up round builds them, and is not timed. Groups hold what is comparable side by
side: one group per probe kind (the same captures for every encoding of the kind), one for the example scenes.

In the default test run (``--benchmark-disable``, see ``pyproject.toml``) each benchmark runs once at a small size,
so that the suite stays runnable; nothing is timed then and nothing is asserted about speed anywhere. The sizes of
an enabled run are those of the console recipe (face 64), 64 probes per encoding bake (one worker batch).
"""

from __future__ import annotations

import os
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.encodings import ENCODINGS
from bakery.probe import Probe
from bakery.sources import CubeSource
from bakery.sphere.cubemap import cube_texel_directions
from bakery.sphere.fibonacci import fibonacci_directions

pytestmark = pytest.mark.bench

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SCENES = {"indoor": EXAMPLES / "indoor" / "indoor.usda", "outdoor": EXAMPLES / "outdoor" / "outdoor.usda",
          "plaza": EXAMPLES / "plaza" / "plaza.usda"}


def _enabled(benchmark) -> bool:  # noqa: ANN001
    return not benchmark.disabled


def sun_and_sky_cubes(probe_count: int, face_size: int) -> np.ndarray:
    """(P, 6, N, N, 3) float32 captures: a sky gradient and a 0.5°-ish sun (peak 1e4) whose direction differs per
    probe (Fibonacci), so that every probe has its own dominant direction, as probes across a scene do."""
    directions = cube_texel_directions(face_size)
    suns = fibonacci_directions(probe_count)
    sky = (0.5 + 0.5 * directions[..., 1:2]) * np.array([0.2, 0.3, 0.6])
    cubes = [sky + np.exp(2000.0 * (directions @ sun - 1.0))[..., None] * np.array([1.0e4, 0.9e4, 0.8e4])
             for sun in suns]
    return np.stack(cubes).astype(np.float32)


def _peak_allocation_mb(call) -> float:  # noqa: ANN001
    """Peak of the allocations traced during ``call()`` (numpy arrays included), MB; in this process only."""
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def _run(benchmark, measured, bake, extra: dict, rounds: int) -> None:  # noqa: ANN001
    """Time ``rounds`` calls of ``bake()`` after an untimed warm-up; record its traced peak allocation and ``extra``
    (in the JSON's ``extra_info`` and in the suite's summary)."""
    if not _enabled(benchmark):
        benchmark(bake)
        return
    benchmark.extra_info.update(extra)
    benchmark.extra_info["peak_alloc_mb"] = round(_peak_allocation_mb(bake), 1)
    benchmark.pedantic(bake, rounds=rounds, warmup_rounds=1)
    measured.append({"name": benchmark.name, "group": benchmark.group, "median_s": benchmark.stats.stats.median,
                     **benchmark.extra_info})


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_bake_one_encoding(benchmark, measured, name, tmp_path):
    """One encoding baked from in-memory captures: 64 sun-and-sky probes at 64², one batch (smoke: 2 at 16²)."""
    kind = ENCODINGS[name].kind
    probe_count, face_size = (64, 64) if _enabled(benchmark) else (2, 16)
    probes = [Probe(f"/probe_{i}", (kind,)) for i in range(probe_count)]
    cubes = sun_and_sky_cubes(probe_count, face_size)
    settings = {}
    if "face_size" in ENCODINGS[name]().settings:
        settings[name] = {"face_size": face_size}
        if "min_face_size" in ENCODINGS[name]().settings:
            settings[name]["min_face_size"] = min(ENCODINGS[name]().settings["min_face_size"], face_size // 2)
    output = tmp_path / "bench.h5"
    benchmark.group = f"bake: {kind} encodings, {probe_count} probes at {face_size}²"

    def bake():
        return bakery.bake(CubeSource(probes, cubes), output, encodings=(name,), encoding_settings=settings,
                           resume=False, jobs=1)

    summary = bake()
    store = bakery.open_store(output)
    assert store.encodings[name].probe_count == probe_count and not summary.failed
    _run(benchmark, measured, bake, {"probes": probe_count, "face_size": face_size,
                           "bytes_per_probe": store.encodings[name].bytes_per_probe,
                           "store_bytes": os.path.getsize(output)}, rounds=5)


@pytest.mark.parametrize("scene", list(SCENES))
def test_bake_example_scene(benchmark, measured, scene, tmp_path):
    """An example scene baked as the README does (its own probes and encodings, capture included), one process;
    the smoke run captures with 1 sample per texel at face 8."""
    output = tmp_path / f"{scene}.h5"
    options = {} if _enabled(benchmark) else {"face_size": 8, "samples": 1}
    benchmark.group = "bake: example scenes (capture + every encoding the probes need)"

    def bake():
        return bakery.bake(SCENES[scene], output, resume=False, jobs=1, **options)

    summary = bake()
    store = bakery.open_store(output)
    assert store.probe_names and not summary.failed
    _run(benchmark, measured, bake, {"probes": len(store.probe_names), "store_bytes": os.path.getsize(output),
                           "encodings": sorted(store.encodings)}, rounds=3)
