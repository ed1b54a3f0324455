"""The HLSL shader library (``bakery.hlsl``: the shared core through its HLSL macros + ``bakery_textures.hlsl``)
executed, against the Python API, on the inputs and with the tolerances of the GLSL tests.

``test_shader_library.py`` renders the GLSL library on WebGL2 and only compiles the HLSL. Here every job of both GLSL
tests (the example stores at the generic rows of ``test_shader_library.py``, with exact lookups, GPU filtering and
cube textures; the synthetic probes at the edge rows of ``test_shader_edges.py``, exact lookups and GPU filtering) is
written as an HLSL pixel shader over ``bakery.hlsl`` (``Job.hlsl``: the same inputs and field textures, read with
``Load``; the settings in a ``cbuffer``; ``SamplerState`` for the filtered lookups) and run for real:

    HLSL ──glslangValidator -D -V -S frag -e main──▶ SPIR-V ──spirv-cross --es --version 300──▶ GLSL ES 3.00
         ──▶ WebGL2 in headless Chromium (the page of the GLSL tests; one launch for every job)

The GLSL is spirv-cross's transcription of the SPIR-V the HLSL front end produced (the library already inlined into
``main``): ``bakery_core.glsl`` enters only as ``bakery.hlsl`` includes it, through the HLSL macros, and
``bakery_glsl.glsl`` / ``bakery_textures.glsl`` not at all. ``readPixels`` must match ``evaluate_irradiance`` /
``evaluate_reflection`` within the GLSL tests' bounds (``shader_pipeline.tolerance``; docs/engine-integration.md §4).
Skips, with a reason, where Chromium, glslangValidator or spirv-cross is missing (.ci/run installs them).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import test_shader_edges as edges
import test_shader_library as library
from bakery.encodings import ENCODINGS
from shader_pipeline import (build_jobs, chromium_binary, glslang_binary, hlsl_jobs, run_jobs, spirv_cross_binary,
                             tolerance)

#: Store labels of test_shader_edges.edge_stores() (the edge rows); the others are the example stores.
EDGE_STORES = ("edge", "paper", "levels", "linear")
#: Budget of the browser part (page load, ~90 shader compiles, draws and read-backs).
BROWSER_SECONDS = 60.0


@pytest.fixture(scope="module")
def hlsl_run(request, tmp_path_factory):
    """Every GLSL-test job as HLSL, translated and rendered in one headless Chromium launch."""
    for tool, missing in ((chromium_binary, "headless Chromium is not installed (apt-get install -y chromium)"),
                          (glslang_binary, "glslangValidator is not installed (apt-get install -y glslang-tools)"),
                          (spirv_cross_binary, "spirv-cross is not installed (apt-get install -y spirv-cross)")):
        if tool() is None:
            pytest.skip(missing)
    jobs = []
    for label, store in library.example_stores(request.config, tmp_path_factory).items():
        jobs += build_jobs(store, label)[0]
    with edges.edge_inputs():
        for label, store in edges.edge_stores().items():
            jobs += build_jobs(store, label, variants=("fetch", "sample"))[0]
    assert {job.store for job in jobs} >= set(EDGE_STORES)
    translated, errors = hlsl_jobs(jobs, tmp_path_factory.mktemp("hlsl"))
    run = run_jobs(translated, tmp_path_factory.mktemp("webgl_hlsl"))
    return translated, errors, run


def _failures(job, gpu: np.ndarray) -> list[str]:
    """Rows of ``job`` outside its tolerance (NaN fails), labelled as the GLSL tests label them."""
    kind = ENCODINGS[job.encoding].kind
    ref = job.reference
    bad = ~(np.abs(gpu - ref) <= tolerance(kind, job.variant, ref))
    if job.mask is not None:
        bad &= job.mask[..., None]
    labels = (edges._row_labels(kind) if job.store in EDGE_STORES
              else np.array([f"row {i}" for i in range(ref.shape[1])]))
    return [f"{job.id} probe {p} {labels[m]}: HLSL {gpu[p, m].tolist()} API {ref[p, m].tolist()}"
            for p, m in zip(*np.nonzero(np.any(bad, axis=-1)), strict=True)]


def test_the_hlsl_translates_and_runs_in_one_launch_within_budget(hlsl_run):
    jobs, errors, run = hlsl_run
    assert not errors, "\n".join(f"{k}: {v}" for k, v in errors.items())
    assert not run.errors, "\n".join(f"{k}: {v}" for k, v in run.errors.items())
    assert len(run.results) == len(jobs)
    assert {job.variant for job in jobs} == {"fetch", "sample", "cube"}
    for job in jobs:  # what ran is spirv-cross output (SPIR-V from the HLSL), not bakery's GLSL
        assert "SPIRV_Cross_Combined" in job.fragment and "#define BK_" not in job.fragment, job.id
    assert run.seconds < BROWSER_SECONDS, f"the browser part took {run.seconds:.1f} s"


@pytest.mark.parametrize("encoding", list(ENCODINGS))
def test_hlsl_matches_the_python_api(hlsl_run, encoding):
    """Every job of the encoding (example stores at the generic rows, synthetic probes at the edge rows) within the
    float32 tolerance of the GLSL tests."""
    jobs, errors, run = hlsl_run
    mine = [job for job in jobs if job.encoding == encoding]
    assert {job.store in EDGE_STORES for job in mine} == {True, False}, f"{encoding}: not in both input sets"
    report, failures = {}, []
    for job in mine:
        assert job.id in run.results, f"{job.id}: {errors.get(job.id) or run.errors.get(job.id)}"
        gpu, ref = run.results[job.id], job.reference
        peak = np.max(np.abs(ref), axis=(1, 2), keepdims=True) + 1e-30
        delta = np.abs(gpu - ref) if job.mask is None else np.where(job.mask[..., None], np.abs(gpu - ref), 0.0)
        report[job.id] = float(np.max(delta / peak))
        failures += _failures(job, gpu)
    print(json.dumps({"renderer": run.renderer, "max_abs_over_peak": report}, indent=1))
    assert not failures, f"{len(failures)} rows outside the float32 tolerance:\n" + "\n".join(failures[:20])


def test_hlsl_closed_forms_at_the_edges(hlsl_run):
    """As test_shader_edges.py for the GLSL: black probes give 0 (exactly 0 for the linear encodings and the chains),
    and quantized DC codes at the R11G11B10F maximum give E = f0·√π/2 with zero ratios."""
    jobs, _, run = hlsl_run
    expected = np.array([65024.0, 65024.0, 64512.0]) * np.sqrt(np.pi) / 2.0
    for job in jobs:
        if job.store not in ("edge", "paper", "linear"):
            continue
        gpu = run.results[job.id]
        probe = 5 if job.encoding in ("zh3_quantized", "sh3_quantized") else 1
        assert np.all(np.abs(gpu[probe]) <= 1e-9), f"{job.id}: black probe gives {np.abs(gpu[probe]).max()}"
        if job.encoding in ("sh2", "sh3", "zh3", "zh3_quantized", "sh3_quantized", "splitsum"):
            assert np.all(gpu[probe] == 0.0), job.id
        if job.encoding in ("zh3_quantized", "sh3_quantized"):
            np.testing.assert_allclose(gpu[0], np.broadcast_to(expected, gpu[0].shape), rtol=2.0**-19)
