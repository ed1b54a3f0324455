"""The bake's fast reference irradiance (:mod:`bakery.irradiance.reference`) against the brute force it replaces:
the cube operator (same sum, one GEMM), the binned full-resolution quadrature (bound and measured error), and the
reported per-encoding errors on two environments."""

from pathlib import Path

import numpy as np
import pytest

from bakery.encodings import get_encoding
from bakery.environment import environment_samples, resample_to_cube
from bakery.environment.io import read_environment
from bakery.irradiance import reference as ref
from bakery.pipeline.encode import reference_irradiance_values, relative_rmse_per_probe
from bakery.probe import ProbeBatch
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.sphere.grid import SphericalSamples

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
ENVIRONMENTS = [EXAMPLES / "data" / "StinsonBeach_512.hdr", EXAMPLES / "environments" / "city_512.hdr"]
NORMALS = fibonacci_directions(1024)


def cube_samples(cube: np.ndarray) -> SphericalSamples:
    n = cube.shape[1]
    return SphericalSamples(cube_texel_directions(n).reshape(-1, 3), cube_texel_solid_angles(n).reshape(-1),
                            cube.reshape(-1, 3).astype(np.float64))


def test_cube_operator_is_the_brute_force_over_the_cube():
    rng = np.random.default_rng(3)
    cubes = rng.gamma(0.5, 1.0, size=(3, 6, 16, 16, 3)).astype(np.float32)
    cubes[1, 2, 3, 4] = 1e4  # a sun texel
    fast = ref.reference_irradiance_cubes(cubes, NORMALS)
    assert fast.shape == (3, 1024, 3) and fast.dtype == np.float32
    for p in range(3):
        np.testing.assert_allclose(fast[p], ref.reference_irradiance(cube_samples(cubes[p]), NORMALS), rtol=1e-5,
                                   atol=1e-6 * np.abs(fast[p]).max())
    np.testing.assert_allclose(reference_irradiance_values(ProbeBatch(cubes), NORMALS), fast)


def test_uncached_cube_operator_equals_the_cached_one(monkeypatch):
    rng = np.random.default_rng(4)
    cubes = rng.gamma(0.5, 1.0, size=(2, 6, 8, 8, 3)).astype(np.float32)
    cached = ref.reference_irradiance_cubes(cubes, NORMALS)
    monkeypatch.setattr(ref, "_MAX_CACHED_ELEMENTS", 8000)  # not cached: streamed one texel at a time
    np.testing.assert_allclose(ref.reference_irradiance_cubes(cubes, NORMALS), cached, rtol=1e-5, atol=1e-6)


def test_constant_radiance_gives_pi_c_in_both_formulations():
    """Closed form: L ≡ c → E ≡ πc, to the texel-centre quadrature's own error (2e-4 at 32²); the binned path stays
    within its a posteriori bound of the brute force over the same samples."""
    cube = np.full((1, 6, 32, 32, 3), 2.0, dtype=np.float32)
    np.testing.assert_allclose(ref.reference_irradiance_cubes(cube, NORMALS), 2.0 * np.pi, rtol=5e-4)
    fine = cube_samples(np.full((6, 96, 96, 3), 2.0))
    binned = ref.reference_irradiance_binned([fine], NORMALS, exact=0)[0]
    bound = ref.binned_error_bound(fine, NORMALS, exact=0)
    assert np.all(np.abs(binned - ref.reference_irradiance(fine, NORMALS)) <= bound + 1e-5)
    np.testing.assert_allclose(binned, 2.0 * np.pi, rtol=2e-3)


def test_binned_error_is_within_its_a_posteriori_bound_with_a_sun():
    rng = np.random.default_rng(5)
    n = 64
    radiance = rng.gamma(1.0, 0.3, size=(6, n, n, 3))
    radiance[4, 20, 40] = 5e4
    samples = cube_samples(radiance)
    truth = ref.reference_irradiance(samples, NORMALS)
    for exact in (0, 1024):
        binned = ref.reference_irradiance_binned([samples], NORMALS, exact=exact)[0]
        bound = ref.binned_error_bound(samples, NORMALS, exact=exact)
        assert np.all(np.abs(binned - truth) <= bound + 1e-5 * np.abs(truth).max())
    # the sun handled exactly: the bound (and the error) shrink to the sky's
    assert ref.binned_error_bound(samples, NORMALS, exact=1024).max() < 0.1 * ref.binned_error_bound(
        samples, NORMALS, exact=0).max()


def test_texel_chord():
    """The centre texel of a face is the largest: its diagonal is ≈ 2√2/N (chord ≈ arc at this size)."""
    assert ref.texel_chord(48) == pytest.approx(2 * np.sqrt(2) / 48, rel=0.01)


@pytest.mark.parametrize("path", ENVIRONMENTS, ids=lambda p: p.stem)
def test_reported_errors_equal_the_brute_force_ones(path):
    """Per encoding, the relative RMSE against the fast reference equals the one against the brute-force reference
    of the full-resolution image within the stated bound ρ(1 + err)/(1 − ρ) and 1e-3 relative (measured ≤ 4.7e-4,
    city); the references agree to ρ < 1e-4 (measured 3.1e-5 StinsonBeach, 7.3e-5 city)."""
    image = read_environment(path)[0]
    samples = environment_samples(image)
    cube = resample_to_cube(image, 64)[None]
    batch = ProbeBatch(cube, [samples])
    slow = ref.reference_irradiance(samples, NORMALS, dtype=np.float32)[None]
    fast = reference_irradiance_values(batch, NORMALS)
    rho = np.sqrt(np.sum((fast - slow) ** 2) / np.sum(slow**2))
    assert rho < 1e-4
    for name in ("sh2", "sh3", "zh3", "zh3_hallucinated"):
        encoding = get_encoding(name)()
        values = encoding.evaluate_irradiance(encoding.encode(batch), NORMALS)
        old, new = relative_rmse_per_probe(values, slow)[0], relative_rmse_per_probe(values, fast)[0]
        assert abs(new - old) <= rho * (1 + old) / (1 - rho) + 1e-6, name
        assert new == pytest.approx(old, rel=1e-3), name


@pytest.mark.parametrize("face_size", [1, 5, 48])
def test_row_runs_classify_every_texel_as_its_four_corner_signs_do(face_size):
    """The binned reference's O(D·N) row runs (``_row_intervals``) against the D × 6N² classification by the signs
    of n at every texel's four corners (``_texel_sides``, float32): the same positive and straddling texels, for
    Fibonacci normals and for the axes and face diagonals, where corners lie exactly on the terminator."""
    special = np.array([(1, 0, 0), (0, -1, 0), (0, 0, 1), (1, 1, 0), (1, -1, 1), (0.3, 0, -1)], dtype=np.float64)
    normals = np.concatenate([NORMALS, special / np.linalg.norm(special, axis=1, keepdims=True)])
    p0, p1, s0, s1 = ref._row_intervals(normals, face_size)
    columns = np.arange(face_size)
    positive = ((columns >= p0[..., None]) & (columns < p1[..., None])).reshape(len(normals), -1)
    straddle = ((columns >= s0[..., None]) & (columns < s1[..., None])).reshape(len(normals), -1)
    want_positive, want_straddle = ref._texel_sides(normals, face_size)
    # a corner on the terminator (within rounding) may go either way (module doc: it errs by ≤ 1e-7 Φ_t)
    corners = ref._corner_grid(face_size)
    dots = np.abs(normals @ corners.reshape(-1, 3).T).reshape(-1, 6, face_size + 1, face_size + 1)
    near = np.minimum.reduce([dots[..., :-1, :-1], dots[..., 1:, :-1], dots[..., :-1, 1:], dots[..., 1:, 1:]])
    decided = near.reshape(len(normals), -1) > 1e-6
    np.testing.assert_array_equal(positive[decided], want_positive[decided])
    np.testing.assert_array_equal(straddle[decided], want_straddle[decided])
    assert not (positive & straddle).any() and decided.mean() > 0.97


def test_the_binned_operators_give_the_dense_formulation(tmp_path):
    """E from the sparse prefix-sum and straddle operators against the same sums with dense corner-sign masks
    (P · m · n + S · Φ, written out here), on a 1k-like quadrature with a sun: to float32 rounding."""
    samples = environment_samples(read_environment(ENVIRONMENTS[0])[0])
    normals = NORMALS
    fast = ref.reference_irradiance_binned([samples], normals, exact=0)[0]
    phi, moment = ref.bin_samples(samples, ref.REFERENCE_FACE_SIZE)
    positive, straddle = ref._texel_sides(normals, ref.REFERENCE_FACE_SIZE)
    centres = cube_texel_directions(ref.REFERENCE_FACE_SIZE).reshape(-1, 3)
    s = np.maximum(normals @ centres.T, 0.0) * straddle
    dense = np.einsum("dcj,dj->dc", np.einsum("dt,tcj->dcj", positive.astype(np.float64), moment), normals) + s @ phi
    np.testing.assert_allclose(fast, dense, rtol=2e-5, atol=2e-6 * np.abs(dense).max())


@pytest.mark.parametrize("band_texels", [1, 5000])
def test_the_bakes_binned_reference_built_in_bands_is_the_binned_quadrature(monkeypatch, band_texels):
    """What an image probe's capture holds (:func:`bakery.environment.resample.environment_reference`, built band by
    band so that an 8K image never has its 1.9 GB of samples in memory) is the binned quadrature of its samples: the
    same brightest samples, bins equal up to summation order, flux ∫L dω, and irradiance within the brute force's
    a-posteriori bound (module doc)."""
    from bakery.environment import resample as resample_module
    from bakery.environment.layouts import EnvironmentImage

    rng = np.random.default_rng(5)
    pixels = rng.gamma(0.7, 1.0, size=(48, 96, 3)).astype(np.float32)
    pixels[5, 40] = 4e4  # a sun
    image = EnvironmentImage(pixels, "equirect")
    samples = environment_samples(image)
    monkeypatch.setattr(resample_module, "_SAMPLE_BAND_TEXELS", band_texels)
    banded = resample_module.environment_reference(image)
    whole = ref.binned_quadrature(samples)
    key = lambda q: np.lexsort(q.bright.directions.T)  # noqa: E731 - the same set, in any order
    np.testing.assert_array_equal(banded.bright.directions[key(banded)], whole.bright.directions[key(whole)])
    np.testing.assert_array_equal(banded.bright.radiance[key(banded)], whole.bright.radiance[key(whole)])
    np.testing.assert_allclose(banded.phi, whole.phi, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(banded.moment, whole.moment, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(banded.flux(), samples.flux(), rtol=1e-12)
    brute = ref.reference_irradiance(samples, NORMALS)
    fast = ref.reference_irradiance_binned([banded], NORMALS)[0]
    bound = ref.binned_error_bound(samples, NORMALS)
    assert np.all(np.abs(fast - brute) <= bound + 1e-5 * np.abs(brute).max())
