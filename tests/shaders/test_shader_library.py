"""The shader library (bakery/shaders/) against the Python API, on a real GPU pipeline.

The shipped examples (examples/indoor, examples/outdoor, examples/environments/city_512.hdr) are baked with every
registered encoding, plus a store of non-default settings (the paper's Fresnel-tail SH exponentials, a fitted
hallucination curve, quantized layouts without companding), two ``shexp_hybrid`` stores whose probes need only
part of the chain (first_level 2 of 5; the levels below are not uploaded) or none of it (first_level = L), three
with ``gap_level`` (6 levels: from level 0, from the gap level 1, and with the gap level skipped) and three with two
gap levels (7 levels: whole, and with one or both gap levels skipped). For
every (store, encoding) headless Chromium renders, with WebGL2 (SwiftShader where there is no GPU), the manifest's
GLSL entry point into an RGBA32F target at 64 normals (irradiance) or 96 (v, n, α, F0) rows (reflection; 18 of
them with n·v < 0, down to −0.999, which the shaders clamp to the horizon, and α from 0, below the SH exponentials'
fitted ``alpha_range``, through the hybrid's blends, to 1); ``readPixels`` must match ``evaluate_irradiance`` /
``evaluate_reflection`` of the same stored values at the same float32-rounded inputs:

    irradiance                |GPU − Python| ≤ 2⁻¹⁹ · peak                 (16 float32 ulps of the probe's peak)
    reflection, exact lookups |GPU − Python| ≤ 2⁻¹⁹ · peak + 2⁻¹⁶ · |E|      (exp() amplifies ulps of its argument)
    reflection, GPU filtering |GPU − Python| ≤ 2⁻⁸ · peak                  (hardware bilinear weights have ~8
                                                                            fractional bits; SwiftShader's are exact)

peak = the largest |value| of that probe over the rows and channels. "exact lookups" fetch texels and weight them in
float32 (``bakery_dfg_fetch``, ``bakery_cube_fetch_bilinear``); "GPU filtering" samples the same RGBA16F face
arrays / RG32F tables with LINEAR filtering, and the split-sum levels as cube textures (seamless; compared where no
bilinear tap crosses a face edge). All of it runs in one Chromium launch per test session.

The same GLSL is validated by ``glslangValidator`` (GLSL ES 3.00), and the HLSL (the same core through
``bakery.hlsl``) is compiled to SPIR-V by its HLSL front end; ``test_hlsl_execution.py`` runs that HLSL on the same
stores and rows (SPIR-V → GLSL ES 3.00 by spirv-cross → this WebGL2 page).
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.encodings import ENCODINGS
from bakery.shaders import SHADER_DIR, manifest
from shader_pipeline import (build_jobs, chromium_binary, glslang_binary, hlsl_include_dir, hlsl_test_entry,
                             reflection_inputs, run_jobs, tolerance, validate)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SOURCES = {
    "indoor": EXAMPLES / "indoor" / "indoor.usda",
    "outdoor": EXAMPLES / "outdoor" / "outdoor.usda",
    "city": EXAMPLES / "environments" / "city_512.hdr",
}
#: Non-default settings that change what the shaders evaluate (baked over the outdoor scene).
VARIANT_SETTINGS = {
    "shexp": {"albedo_normalized": False},
    "zh3_hallucinated": {"curve": "fit"},
    "zh3_quantized": {"sqrt_companding": False},
    "sh3_quantized": {"sqrt_companding": False},
}
#: shexp_hybrid stores whose probes need part of the chain (first_level 2 of 5: levels 0–1 are not uploaded) or none
#: (first_level = L: SH exponential + lights only), from the settings' material range (city map, no per-probe range);
#: and the chain with ``gap_level`` (6 levels, α = 0, 0.072, 0.144, …): whole (the α_1/2 level between the capture and
#: level 2), from the gap level up (α_min 0.1 → first_level 1: the capture is not uploaded), and with the gap level
#: skipped (a mirror and α ≥ 0.2 only: ``gap_skipped``, level 1 not uploaded, read as the chain without it); with
#: ``gap_levels`` = 2 (7 levels, α = 0, 0.036, 0.072, 0.144, …): whole, with the first gap level skipped (a mirror and
#: α ≥ 0.1 only: ``gap_skipped`` = 1, read from the capture to level 2) and with both skipped (α ≥ 0.2: 2); with
#: ``gap_levels`` = 3 (8 levels, α = 0, 0.018, 0.036, 0.072, …) and the first skipped (a mirror and α ≥ 0.05 only).
HYBRID_VARIANTS = {
    "hybrid_glossy": (16, {"alpha_min": 0.3}),
    "hybrid_rough": (8, {"alpha_min": 0.9}),
    "hybrid_gap": (16, {"gap_level": True}),
    "hybrid_gap_sharp": (16, {"gap_level": True, "alpha_min": 0.1}),
    "hybrid_gap_skipped": (16, {"gap_level": True, "alpha_min_nonzero": 0.2}),
    "hybrid_gap2": (16, {"gap_level": True, "gap_levels": 2}),
    "hybrid_gap2_skip1": (16, {"gap_level": True, "gap_levels": 2, "alpha_min_nonzero": 0.1}),
    "hybrid_gap2_skip2": (16, {"gap_level": True, "gap_levels": 2, "alpha_min_nonzero": 0.2}),
    "hybrid_gap3_skip1": (16, {"gap_level": True, "gap_levels": 3, "alpha_min_nonzero": 0.05}),
}
#: Budget of the browser part (page load, 100+ shader compiles, draws and read-backs).
BROWSER_SECONDS = 60.0


#: The baked stores, once per test session (shared with tests/shaders/test_hlsl_execution.py).
STORES_KEY = pytest.StashKey[dict]()


@pytest.fixture(scope="session")
def stores(request, tmp_path_factory):
    return example_stores(request.config, tmp_path_factory)


def example_stores(config: pytest.Config, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """label → :class:`bakery.api.ProbeStore` of :data:`SOURCES`, :data:`VARIANT_SETTINGS` and
    :data:`HYBRID_VARIANTS`, baked on the first call of a test session."""
    if STORES_KEY not in config.stash:
        config.stash[STORES_KEY] = _bake_stores(tmp_path_factory)
    return config.stash[STORES_KEY]


def _bake_stores(tmp_path_factory: pytest.TempPathFactory) -> dict:
    folder = tmp_path_factory.mktemp("shader_stores")
    everything = tuple(ENCODINGS)
    result = {}
    for label, source in SOURCES.items():
        bakery.bake(source, folder / f"{label}.h5", encodings=everything, face_size=8, samples=1)
        result[label] = bakery.open_store(folder / f"{label}.h5")
    settings = {k: v for k, v in VARIANT_SETTINGS.items() if k in ENCODINGS}
    bakery.bake(SOURCES["outdoor"], folder / "variants.h5", encodings=tuple(settings), face_size=8, samples=1,
                encoding_settings=settings)
    result["variants"] = bakery.open_store(folder / "variants.h5")
    for label, (face_size, hybrid) in HYBRID_VARIANTS.items():
        bakery.bake(SOURCES["city"], folder / f"{label}.h5", encodings=("shexp_hybrid",), face_size=face_size,
                    samples=1, encoding_settings={"shexp_hybrid": hybrid})
        result[label] = bakery.open_store(folder / f"{label}.h5")
    return result


@pytest.fixture(scope="session")
def pipeline(stores, tmp_path_factory):
    """Every job of every store, rendered in one headless Chromium launch."""
    if chromium_binary() is None:
        pytest.skip("headless Chromium is not installed (apt-get install -y chromium)")
    jobs, missing = [], {}
    for label, store in stores.items():
        store_jobs, store_missing = build_jobs(store, label)
        jobs += store_jobs
        for name in store_missing:
            missing.setdefault(name, []).append(label)
    run = run_jobs(jobs, tmp_path_factory.mktemp("webgl"))
    return jobs, missing, run


def _errors(job, gpu: np.ndarray) -> tuple[float, float, bool]:
    """(max |Δ|/peak, max |Δ|/|E| where |E| > 1e-3·peak, within the job's tolerance)."""
    ref = job.reference
    peak = np.max(np.abs(ref), axis=(1, 2), keepdims=True) + 1e-30
    delta = np.abs(gpu - ref)
    if job.mask is not None:
        delta = np.where(job.mask[..., None], delta, 0.0)
    bound = tolerance(ENCODINGS[job.encoding].kind, job.variant, ref)
    relative = np.where(np.abs(ref) > 1e-3 * peak, delta / np.maximum(np.abs(ref), 1e-30), 0.0)
    return float(np.max(delta / peak)), float(np.max(relative)), bool(np.all(delta <= bound))


#: Known gaps of the shader library, each an open item of issue 18 (strict xfail: a test that starts passing fails,
#: so the entry must then be removed). None left.
PENDING: dict[str, str] = {}


def _pending(name: str):
    if name in PENDING:
        return pytest.param(name, marks=pytest.mark.xfail(reason=PENDING[name], strict=True))
    return name


# ------------------------------------------------------------------------------------------------------ manifest
def test_every_registered_encoding_has_a_shader_entry_point():
    entries = manifest()["encodings"]
    missing = [name for name in ENCODINGS if name not in entries and name not in PENDING]
    assert not missing, f"no shader entry point in bakery/shaders/manifest.json for {missing}"
    assert set(entries) <= set(ENCODINGS), f"manifest entries for unregistered encodings: {set(entries) - set(ENCODINGS)}"
    sources = "\n".join((SHADER_DIR / f).read_text() for f in manifest()["sources"]["glsl"])
    for name, spec in entries.items():
        for entry in [spec, *spec.get("variants", ())]:
            assert f" {entry['entry']}(" in sources, f"{name}: {entry['entry']} is not defined in the GLSL library"


def test_every_registered_encoding_is_baked_into_the_example_stores(stores):
    baked = {name for store in stores.values() for name in store.encodings}
    assert baked == set(ENCODINGS)


def test_the_inputs_exercise_the_reflection_validity_rules(stores):
    """The rows reach every rule of store-reflection.md the shaders must reproduce: views below the horizon, α = 0
    and α below the SH exponentials' fitted range (clamped into ``alpha_range``), the hybrid's blend, and hybrid
    probes with the whole chain, part of it (levels below first_level not uploaded) and none, with and without
    ``gap_level``."""
    from bakery.reflection import hybrid as hy

    rows = reflection_inputs()
    n_dot_v = np.sum(rows["view"] * rows["normal"], axis=1)
    assert np.count_nonzero(n_dot_v < 0.0) >= 10 and n_dot_v.min() < -0.99
    assert np.count_nonzero(rows["alpha"] == 0.0) >= 1
    lowest = min(float(np.min(np.asarray(store.fields(name)["alpha_range"])[:, 0]))
                 for store in stores.values() for name in ("shexp", "shexp_lights") if name in store.encodings)
    assert np.count_nonzero(rows["alpha"] < lowest) >= 4
    first_levels, gap_first_levels = set(), set()
    for store in stores.values():
        if "shexp_hybrid" in store.encodings:
            settings = store.encodings["shexp_hybrid"].settings
            levels = len(settings["level_alphas"])
            first = np.asarray(store.fields("shexp_hybrid")["first_level"]).reshape(-1)
            first_levels |= {"all" if k == 0 else "none" if k == levels else "part" for k in first}
            if settings.get("gap_level"):  # rows read every gap level 1 … G, between its neighbours and around it
                gaps = settings.get("gap_levels", 1)
                skipped = np.asarray(store.fields("shexp_hybrid")["gap_skipped"]).reshape(-1)
                gap_first_levels |= {(gaps, int(k), int(g)) for k, g in zip(first, skipped, strict=True)}
                edges = settings["level_alphas"][: gaps + 2]
                assert np.count_nonzero((rows["alpha"] > 0) & (rows["alpha"] < edges[1])) >= 2
                for lo, hi in itertools.pairwise(edges[1:]):
                    assert np.count_nonzero((rows["alpha"] > lo) & (rows["alpha"] < hi)) >= 1, (lo, hi)
            w0 = hy.chain_weight(rows["alpha"], settings["crossover"], settings["blend_octaves"])
            w1 = hy.chain_weight(rows["alpha"], settings["tail_crossover"], settings["blend_octaves"])
            assert np.count_nonzero((w0 > 0) & (w0 < 1)) >= 5 and np.count_nonzero((w1 > 0) & (w1 < 1)) >= 5
            assert np.count_nonzero(w0 == 1.0) >= 5 and np.count_nonzero(w1 == 0.0) >= 5
    assert first_levels == {"all", "part", "none"}
    # (gap levels, first level, gap levels skipped): gap_level chains read from the capture, from the gap level up,
    # and from the capture without the gap level; with two gap levels, whole and without one or both; with three,
    # without the first
    assert gap_first_levels == {(1, 0, 0), (1, 1, 0), (1, 0, 1), (2, 0, 0), (2, 0, 1), (2, 0, 2), (3, 0, 1)}


# ------------------------------------------------------------------------------------------------------ WebGL2
def test_webgl2_pipeline_runs_in_one_launch_within_budget(pipeline):
    jobs, _, run = pipeline
    assert "EXT_color_buffer_float" in run.extensions  # float render targets (RGBA32F)
    assert not run.errors, "\n".join(f"{k}: {v}" for k, v in run.errors.items())
    assert len(run.results) == len(jobs)
    assert run.seconds < BROWSER_SECONDS, f"the browser part took {run.seconds:.1f} s"


@pytest.mark.parametrize("encoding", [_pending(name) for name in ENCODINGS])
def test_glsl_on_webgl2_matches_the_python_api(pipeline, encoding):
    jobs, missing, run = pipeline
    assert encoding not in missing, f"{encoding} has no shader entry point (stores {missing.get(encoding)})"
    mine = [job for job in jobs if job.encoding == encoding]
    assert mine, f"no WebGL2 job for {encoding}"
    report, failures = {}, []
    for job in mine:
        assert job.id in run.results, f"{job.id}: {run.errors.get(job.id)}"
        peak_error, relative_error, ok = _errors(job, run.results[job.id])
        report[job.id] = {"max_abs_over_peak": peak_error, "max_rel": relative_error}
        if not ok:
            failures.append(job.id)
    print(json.dumps({"renderer": run.renderer, **report}, indent=1))
    assert not failures, f"outside the float32 tolerance: {failures}: {json.dumps(report, indent=1)}"
    variants = {job.variant for job in mine}
    if ENCODINGS[encoding].kind == "reflection" and any("table" in a for a in manifest()["encodings"][encoding]
                                                        ["arguments"]):
        assert "sample" in variants  # the hardware-filtered lookups are exercised too


# ------------------------------------------------------------------------------------------------------ glslang
@pytest.fixture(scope="module")
def glslang():
    if glslang_binary() is None:
        pytest.skip("glslangValidator is not installed (apt-get install -y glslang-tools)")
    return glslang_binary()


def test_glsl_validates_with_glslang(glslang, stores):
    sources = {}
    for label, store in stores.items():
        for job in build_jobs(store, label)[0]:
            sources.setdefault(job.fragment, job.id)
    for source, job_id in sources.items():
        result = validate(source, ".frag")
        assert result.returncode == 0, f"{job_id}: glslangValidator (GLSL ES 3.00):\n{result.stdout}{result.stderr}"


def test_hlsl_compiles_to_spirv(glslang, tmp_path):
    source = hlsl_test_entry()
    for entry in {e["entry"] for spec in manifest()["encodings"].values() for e in [spec, *spec.get("variants", ())]}:
        assert f"{entry}(" in source
    result = validate(source, ".hlsl", ("-D", "-V", "-S", "frag", "-e", "main", f"-I{hlsl_include_dir()}",
                                        "-o", str(tmp_path / "bakery.spv")))
    assert result.returncode == 0, f"glslangValidator (HLSL → SPIR-V):\n{result.stdout}{result.stderr}"
    spirv = (tmp_path / "bakery.spv").read_bytes()
    assert spirv[:4] == bytes.fromhex("03022307")  # SPIR-V magic, little-endian
