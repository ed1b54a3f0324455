"""Conformance suite: every registered encoding, picked up from the registry (a new encoding is tested here
without editing this file)."""

from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.bake import BakeSettings, bake_probes
from bakery.encodings import ENCODINGS
from bakery.probe import PROBE_KINDS, Probe, ProbeBatch
from bakery.sphere.cubemap import cube_texel_directions
from bakery.sphere.fibonacci import fibonacci_directions

SPEC_FILES = sorted((Path(__file__).resolve().parents[1] / "schemas").glob("store*.md"))
FACE = 16


def _batch() -> ProbeBatch:
    d = cube_texel_directions(FACE)
    sun = np.array([0.3, 0.8, 0.52])
    sun /= np.linalg.norm(sun)
    lobe = np.exp(40.0 * (d @ sun - 1.0))[..., None] * np.array([50.0, 40.0, 30.0])
    sky = (0.5 + 0.5 * d[..., 1:2]) * np.array([0.2, 0.3, 0.6])
    constant = np.full_like(lobe, 0.7)
    return ProbeBatch(np.stack([lobe + sky, constant, sky]).astype(np.float32))


def _view_normal(count=64):
    normal = fibonacci_directions(count)
    view = np.roll(normal, 1, axis=0) + normal  # within 90° of n
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    return view, normal


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    probes = [Probe(f"/probe_{i}", PROBE_KINDS) for i in range(3)]
    path = tmp_path_factory.mktemp("conformance") / "store.h5"
    result = bake_probes(probes, _batch(), BakeSettings(face_size=FACE, encodings=tuple(ENCODINGS)), path)
    return result, bakery.open_store(path)


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_fields_match_declared_specs(name, baked):
    result, _ = baked
    encoding = result.encodings[name]
    for spec in encoding.field_specs():
        array = result.encoded[name][spec.name]
        assert array.shape == (3, *spec.shape) and array.dtype == np.dtype(spec.dtype)
        assert np.all(np.isfinite(array.astype(np.float64)))


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_memory_accounting_matches_stored_arrays(name, baked):
    result, store = baked
    fields = store.fields(name)
    stored = sum(fields[s.name].nbytes for s in result.encodings[name].field_specs()) // 3
    assert store.encodings[name].bytes_per_probe == stored == result.encodings[name].bytes_per_probe()


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_store_round_trip_evaluates_identically(name, baked):
    result, store = baked
    encoding = result.encodings[name]
    stored = store.fields(name)
    for key, array in result.encoded[name].items():
        assert stored[key].tobytes() == array.tobytes() and stored[key].dtype == array.dtype
    view, normal = _view_normal()
    if encoding.kind == "irradiance":
        direct = encoding.evaluate_irradiance(result.encoded[name], normal)
        np.testing.assert_allclose(store.evaluate_irradiance(name, normal), direct, rtol=1e-12, atol=1e-12)
    else:
        alpha, f0 = np.full(len(normal), 0.5), np.full(len(normal), 0.04)
        direct = encoding.evaluate_reflection(result.encoded[name], encoding.shared_tables(), view, normal, alpha, f0)
        np.testing.assert_allclose(store.evaluate_reflection(name, view, normal, alpha, f0), direct, rtol=1e-6)


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_constant_in_constant_out(name, baked):
    result, store = baked
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
    first = ENCODINGS[name]().encode(_batch())
    second = ENCODINGS[name]().encode(_batch())
    for key in first:
        assert first[key].tobytes() == second[key].tobytes()
