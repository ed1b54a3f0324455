"""Conformance suite: every registered encoding, picked up from the registry (a new encoding is tested here without
editing this file), baked through the one bake path (``bakery.bake``) in-process and with two worker processes,
and through the CLI, then evaluated through the public API."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_limits
from harness import bake_cubes

import bakery
from bakery.encodings import ENCODINGS
from bakery.environment.io import write_exr
from bakery.probe import PROBE_KINDS, Probe, ProbeBatch
from bakery.sphere.cubemap import cube_texel_directions
from bakery.sphere.fibonacci import fibonacci_directions

SPEC_FILES = sorted((Path(__file__).resolve().parents[2] / "schemas").glob("store*.md"))
FACE = 16
SMALL = {"splitsum": {"min_face_size": 8}}  # keeps the chain small at FACE


def _cubes() -> np.ndarray:
    d = cube_texel_directions(FACE)
    sun = np.array([0.3, 0.8, 0.52])
    sun /= np.linalg.norm(sun)
    lobe = np.exp(40.0 * (d @ sun - 1.0))[..., None] * np.array([50.0, 40.0, 30.0])
    sky = (0.5 + 0.5 * d[..., 1:2]) * np.array([0.2, 0.3, 0.6])
    constant = np.full_like(lobe, 0.7)
    return np.stack([lobe + sky, constant, sky]).astype(np.float32)


def _view_normal(count=64):
    normal = fibonacci_directions(count)
    view = np.roll(normal, 1, axis=0) + normal  # within 90° of n
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    return view, normal


def _settings(name):
    return {k: v for k, v in SMALL.get(name, {}).items() if k in ENCODINGS[name].Params.__dataclass_fields__}


PROBES = [Probe(f"/probe_{i}", PROBE_KINDS) for i in range(3)]


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """The same captures baked in-process and by two worker processes (with the cubes snapshot workers map)."""
    folder = tmp_path_factory.mktemp("conformance")
    os.environ.setdefault("SOURCE_DATE_EPOCH", "1700000000")
    settings = {n: _settings(n) for n in ENCODINGS if _settings(n)}
    serial = bake_cubes(folder / "serial.h5", PROBES, _cubes(), encodings=tuple(ENCODINGS), jobs=1,
                        encoding_settings=settings)
    processes = bake_cubes(folder / "processes.h5", PROBES, _cubes(), encodings=tuple(ENCODINGS), jobs=2,
                           encoding_settings=settings)
    return serial, processes


def test_worker_count_does_not_change_the_store(baked):
    serial, processes = baked
    assert serial.summary.executor == "serial" and processes.summary.executor == "processes"
    assert serial.path.read_bytes() == processes.path.read_bytes()
    assert not Path(f"{processes.path}.partial").exists()


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_fields_match_declared_specs(name, baked):
    stored, _ = baked
    encoding = stored.encoding(name)
    fields = stored.fields(name)
    assert set(fields) == {s.name for s in encoding.field_specs()}
    for spec in encoding.field_specs():
        array = fields[spec.name]
        assert array.shape == (3, *spec.shape) and array.dtype == np.dtype(spec.dtype)
        assert np.all(np.isfinite(array.astype(np.float64)))


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_memory_accounting_matches_stored_arrays(name, baked):
    stored, _ = baked
    encoding = stored.encoding(name)
    fields = stored.fields(name)
    per_probe = sum(fields[s.name].nbytes for s in encoding.field_specs()) // 3
    assert stored.store.encodings[name].bytes_per_probe == per_probe == encoding.bytes_per_probe()


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_pipeline_stores_what_the_encoding_computes(name, baked):
    """The bake path adds nothing: the stored arrays are the encoding's own output for the same captures, and the
    API evaluates them exactly as the encoding built from the stored settings does."""
    stored, _ = baked
    encoding = stored.encoding(name)
    with threadpool_limits(limits=1):  # as every bake computes (BLAS may round differently with other thread counts)
        direct = encoding.encode(ProbeBatch(_cubes()))
    for key, array in stored.fields(name).items():
        assert array.tobytes() == direct[key].tobytes() and array.dtype == direct[key].dtype, key
    view, normal = _view_normal()
    if encoding.kind == "irradiance":
        np.testing.assert_allclose(stored.store.evaluate_irradiance(name, normal),
                                   encoding.evaluate_irradiance(direct, normal), rtol=1e-12, atol=1e-12)
    else:
        alpha, f0 = np.full(len(normal), 0.5), np.full(len(normal), 0.04)
        np.testing.assert_allclose(stored.store.evaluate_reflection(name, view, normal, alpha, f0),
                                   encoding.evaluate_reflection(direct, encoding.shared_tables(), view, normal, alpha,
                                                                f0), rtol=1e-6)


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_constant_in_constant_out(name, baked):
    stored, _ = baked
    store = stored.store
    c = 0.7
    view, normal = _view_normal()
    if store.encodings[name].kind == "irradiance":
        values = store.evaluate_irradiance(name, normal, probes=["/probe_1"])[0]
        # E = πc; quantized layouts add at most their DC rounding (R11G11B10F: 2⁻⁶ relative).
        np.testing.assert_allclose(values, np.pi * c, rtol=2.0**-6)
    else:
        alpha, f0 = np.full(len(normal), 0.6), np.ones(len(normal))
        values = store.evaluate_reflection(name, view, normal, alpha, f0, probes=["/probe_1"])[0]
        # Chrome (F0 = 1) under constant radiance: E = c · directional albedo ∈ (0, c]; uniform across directions.
        assert np.all(values > 0) and np.all(values <= c * 1.02)


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_encoding_is_documented_in_the_store_specification(name):
    text = "\n".join(p.read_text() for p in SPEC_FILES)
    assert f"`{name}`" in text, f"{name} is not specified in schemas/store*.md"


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_encoding_is_deterministic(name):
    first = ENCODINGS[name]().encode(ProbeBatch(_cubes()))
    second = ENCODINGS[name]().encode(ProbeBatch(_cubes()))
    for key in first:
        assert first[key].tobytes() == second[key].tobytes()


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_a_probes_encoding_depends_on_its_capture_alone(name):
    """Bit for bit the same fields for a probe whatever it is encoded with: 18 captures at once (more than one
    block of bakery.reflection.blocks.PROBE_BLOCK) and in pieces of 1, 7 and 10. Before, the reflection fits and SH-domain
    prefilters differed by 1e-6 relative (BLAS picks its kernels by the matrix shapes), so re-baking one probe, or
    another batch_size, changed the store's bits."""
    rng = np.random.default_rng(3)
    cubes = np.concatenate([_cubes()] * 6) * rng.uniform(0.5, 2.0, (18, 1, 1, 1, 3)).astype(np.float32)
    encoding = ENCODINGS[name](**_settings(name))
    whole = encoding.encode(ProbeBatch(cubes))
    pieces = [encoding.encode(ProbeBatch(cubes[a:b])) for a, b in ((0, 1), (1, 8), (8, 18))]
    for key in whole:
        assert np.concatenate([piece[key] for piece in pieces]).tobytes() == whole[key].tobytes(), key


@pytest.mark.parametrize("name", [n for n, cls in ENCODINGS.items() if cls.kind == "irradiance"])
def test_irradiance_encodings_are_functions_of_the_band_0_to_2_radiance_sh(name):
    """What the dilation of probes inside geometry relies on (bakery.pipeline.dilate): an irradiance encoding of
    probes known by their radiance SH alone is, bit for bit, the encoding of the captures it was projected from."""
    from bakery.probe import RadianceSHBatch

    for params in ({}, STORED_VARIANTS.get(name, {})):
        encoding = ENCODINGS[name](ENCODINGS[name].Params(**params))
        batch = ProbeBatch(_cubes())
        from_cubes = encoding.encode(batch)
        from_sh = encoding.encode(RadianceSHBatch(batch.radiance_sh(2)))
        assert set(from_sh) == set(from_cubes)
        for key in from_cubes:
            assert from_sh[key].dtype == from_cubes[key].dtype and from_sh[key].tobytes() == from_cubes[key].tobytes()


def test_reflection_encodings_refuse_probes_known_by_sh_alone():
    from bakery.probe import RadianceSHBatch

    batch = RadianceSHBatch(ProbeBatch(_cubes()).radiance_sh(2))
    for name in [n for n, cls in ENCODINGS.items() if cls.kind == "reflection"]:
        with pytest.raises(ValueError, match="radiance SH bands 0-2 alone"):
            ENCODINGS[name](ENCODINGS[name].Params(**_settings(name))).encode(batch)


# ----------------------------------------------------------------------------------------- stores the CLI writes
#: Parameters that change what is stored, each baked by the CLI from a recipe and evaluated through the API.
STORED_VARIANTS = {
    "zh3_hallucinated": {"curve": "fit"},
    "zh3_quantized": {"sqrt_companding": False},
    "sh3_quantized": {"sqrt_companding": False},
    "splitsum": {"n_levels": 4, "min_face_size": 4},
    "shexp": {"p_band": 3, "albedo_normalized": False},
    "shexp_lights": {"max_lights": 2},
}


def _write_environments(folder: Path, count: int = 5) -> list[Path]:
    rng = np.random.default_rng(7)
    paths = []
    for i in range(count):
        h = 16
        rows = (np.arange(h) + 0.5) / h
        sky = np.broadcast_to((np.array([0.2, 0.3, 0.6]) * (1.5 - rows)[:, None])[:, None, :], (h, 2 * h, 3)).copy()
        sky[rng.integers(0, h // 2), rng.integers(0, 2 * h)] = rng.uniform(20, 200, size=3)  # a sun
        paths.append(folder / f"env{i}.exr")
        write_exr(paths[-1], sky.astype(np.float32), half=False)
    return paths


def _toml_value(value):
    return json.dumps(value) if not isinstance(value, bool) else str(value).lower()


@pytest.fixture(scope="module")
def cli_store(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    envs = _write_environments(folder)
    recipe = folder / "variants.toml"
    lines = ['name = "variants"', "[targets]",
             "irradiance = " + json.dumps([n for n, e in ENCODINGS.items() if e.kind == "irradiance"]),
             "reflection = " + json.dumps([n for n, e in ENCODINGS.items() if e.kind == "reflection"]),
             "[bake]", "face_size = 16"]
    for name, values in STORED_VARIANTS.items():
        if name in ENCODINGS:
            lines.append(f"[encoding_settings.{name}]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in values.items()]
    recipe.write_text("\n".join(lines) + "\n")
    store = folder / "variants.h5"
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "bake", *envs, "-o", store, "--recipe", recipe,
                             "--jobs", "2", "--json"], capture_output=True, text=True,
                            env={**os.environ, "SOURCE_DATE_EPOCH": "1700000000"})
    assert result.returncode == 0, result.stderr
    return bakery.open_store(store), json.loads(result.stdout)


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_every_encoding_of_a_cli_store_evaluates_through_the_api(name, cli_store):
    store, summary = cli_store
    if name not in store.encodings:
        skipped = {s.get("encoding"): s["reason"] for s in summary["skipped"]}
        assert name in skipped, f"{name} neither stored nor reported as skipped"
        pytest.skip(f"{name} skipped by the bake: {skipped[name]}")
    stored = store.encodings[name].settings
    for key, value in STORED_VARIANTS.get(name, {}).items():
        if key == "curve":
            continue  # resolved by finalize (next test)
        assert stored[key] == value, (key, stored[key])
    view, normal = _view_normal()
    if store.encodings[name].kind == "irradiance":
        values = store.evaluate_irradiance(name, normal)
    else:
        values = store.evaluate_reflection(name, view, normal, np.full(len(normal), 0.4), np.full(len(normal), 0.04))
    assert values.shape == (5, len(normal), 3) and np.all(np.isfinite(values))


def test_fitted_hallucination_curve_is_stored_and_evaluates(cli_store):
    """``curve = "fit"`` is fitted once over every probe of the bake (finalize) and stored as numbers: a reader of
    the spec evaluates Listing 1 with the stored (c2, c1)."""
    from bakery.irradiance.sh_irradiance import evaluate_sh_irradiance
    from bakery.irradiance.zh3 import evaluate_zh3_irradiance, fit_hallucination_curve, hallucinate_zonal_l2

    store, _ = cli_store
    curve = store.encodings["zh3_hallucinated"].settings["curve"]
    assert isinstance(curve, list) and len(curve) == 2 and all(isinstance(c, float) for c in curve)
    # Independent of bakery's encoder: the curve fitted to the probes' full radiance SH (the sh3 encoding's field).
    expected, used, fitted = fit_hallucination_curve(store.fields("sh3")["radiance_sh"].astype(np.float64))
    assert fitted and used == 15
    np.testing.assert_allclose(curve, expected, rtol=1e-5)
    # Listing 1 (hallucinate_zonal_l2) with the stored curve on the stored linear SH is what the API evaluates.
    linear = store.fields("zh3_hallucinated")["radiance_sh"].astype(np.float64)
    normal = fibonacci_directions(32)
    values = store.evaluate_irradiance("zh3_hallucinated", normal)
    np.testing.assert_allclose(values, evaluate_zh3_irradiance(linear, hallucinate_zonal_l2(linear, tuple(curve)),
                                                               normal), rtol=1e-12)
    assert not np.allclose(values, evaluate_sh_irradiance(linear, normal))  # the zonal term is applied
