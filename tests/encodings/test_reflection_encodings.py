"""Reflection encodings: registration, declared layout = encoded arrays, memory accounting, reconstruction."""

import json

import numpy as np
import pytest

from bakery.encodings.registry import ENCODINGS
from bakery.encodings.shexp import SHExp
from bakery.encodings.splitsum import SplitSum
from bakery.probe import ProbeBatch
from bakery.reflection.reference import integrate_reflection, reflected_radiance
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.sphere.grid import SphericalSamples

FACE = 16


def _batch():
    d = cube_texel_directions(FACE)
    sun = np.array([0.3, 0.8, 0.52]) / np.linalg.norm([0.3, 0.8, 0.52])
    lobe = np.exp(40.0 * (d @ sun - 1.0))[..., None] * np.array([50.0, 40.0, 30.0])
    sky = (0.5 + 0.5 * d[..., 1:2]) * np.array([0.2, 0.3, 0.6])
    return ProbeBatch(np.stack([lobe + sky, np.full_like(lobe, 0.7), sky]).astype(np.float32))


ENCODERS = {
    "splitsum": lambda: SplitSum(face_size=FACE, n_levels=4, min_face_size=4),
    "shexp": lambda: SHExp(n_normals=16, n_views=16, fit_face_size=8),
    "shexp_paper": lambda: SHExp(n_normals=16, n_views=16, fit_face_size=8, albedo_normalized=False, fit="log"),
}


@pytest.fixture(scope="module")
def encoded():
    batch = _batch()
    out = {}
    for key, make in ENCODERS.items():
        enc = make()
        out[key] = (enc, enc.encode(batch))
    return out


def test_registered_as_reflection_encodings():
    assert ENCODINGS["splitsum"] is SplitSum and ENCODINGS["shexp"] is SHExp
    assert SplitSum.kind == SHExp.kind == "reflection"


@pytest.mark.parametrize("key", list(ENCODERS))
def test_fields_match_specs_and_memory_accounting(key, encoded):
    enc, fields = encoded[key]
    assert set(fields) == {s.name for s in enc.field_specs()}
    total = 0
    for spec in enc.field_specs():
        array = fields[spec.name]
        assert array.shape == (3, *spec.shape) and array.dtype == np.dtype(spec.dtype)
        assert np.all(np.isfinite(array.astype(np.float64)))
        total += array[0].nbytes
    assert enc.bytes_per_probe() == total
    json.loads(enc.settings_json())


def test_shexp_default_memory_is_33_coefficients_per_channel():
    enc = SHExp()
    assert enc.bytes_per_probe() == 33 * 3 * 4 + 2 * 4  # + the fitted α range
    assert [s.shape for s in enc.field_specs()] == [(25, 3), (8, 3), (2,)]
    levels = SplitSum(face_size=128).field_specs()
    assert [s.shape[1] for s in levels] == [128, 64, 32, 32, 32, 32]
    assert SplitSum(face_size=128).bytes_per_probe() == 6 * 3 * 2 * (128**2 + 64**2 + 4 * 32**2)


@pytest.mark.parametrize("key", list(ENCODERS))
def test_rebuilt_from_settings_evaluates_identically(key, encoded):
    enc, fields = encoded[key]
    again = type(enc).from_settings(json.loads(enc.settings_json()))
    n = fibonacci_directions(32)
    v = n + np.roll(n, 3, axis=0)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    a, f0 = np.full(32, 0.5), np.full(32, 0.04)
    out = enc.evaluate_reflection(fields, enc.shared_tables(), v, n, a, f0)
    assert out.shape == (3, 32, 3) and np.all(out >= 0)
    np.testing.assert_allclose(again.evaluate_reflection(fields, again.shared_tables(), v, n, a, f0), out)
    np.testing.assert_allclose(enc.evaluate_reflection(fields, {}, v, n, a, f0), out)


@pytest.mark.parametrize("key", ["splitsum", "shexp"])
def test_constant_radiance_reflects_c_times_albedo(key, encoded):
    """Probe 1 is constant 0.7: both reconstruct the brute-force E (chrome and glass) within a few percent."""
    enc, fields = encoded[key]
    n = fibonacci_directions(48)
    v = n + 0.5 * np.roll(n, 5, axis=0)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    a = np.linspace(0.25, 1.0, 48)
    d = cube_texel_directions(48).reshape(-1, 3)
    samples = SphericalSamples(d, cube_texel_solid_angles(48).reshape(-1), np.full((len(d), 3), 0.7))
    e0, e1 = integrate_reflection(samples, v, n, a)
    for f0 in (1.0, 0.04):
        out = enc.evaluate_reflection({k: x[1:2] for k, x in fields.items()}, enc.shared_tables(), v, n, a,
                                      np.full(48, f0))[0]
        np.testing.assert_allclose(out, reflected_radiance(e0, e1, np.full(48, f0)), rtol=3e-2)


def test_bad_settings_are_rejected():
    with pytest.raises(ValueError):
        SHExp(fit="magic")
