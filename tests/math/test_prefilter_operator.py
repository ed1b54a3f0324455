"""The sparse prefilter operator (bakery.reflection.prefilter_operator): against the dense quadrature of the
normalised GGX kernel on a smooth and a sun environment, the constant-environment identity (rows sum to 1), the
α → 0 identity, batch independence (bit-identical), and the on-disk cache round trip with a damaged file rebuilt."""

import warnings

import numpy as np
import pytest

from bakery import operator_cache
from bakery.reflection import prefilter_operator as po
from bakery.reflection import splitsum as ss
from bakery.reflection.tables import OperatorCache
from bakery.sphere.cubemap import cube_texel_directions, direction_to_cube_texel

N = 32
SPLITSUM = po.OperatorSettings(tolerance=1.5, core=3.0)  # the split-sum chain's defaults


def _environments() -> dict[str, np.ndarray]:
    d = cube_texel_directions(N)
    rng = np.random.default_rng(0)
    w = rng.normal(size=(8, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    smooth = sum(np.exp(6.0 * (d @ w[i] - 1.0))[..., None] * rng.uniform(0.2, 1.0, 3) for i in range(8)) + 0.1
    sun = smooth.copy()
    direction = np.array([0.3, 0.8, 0.52]) / np.linalg.norm([0.3, 0.8, 0.52])
    face, row, col = (int(v) for v in direction_to_cube_texel(direction, N))
    sun[face, row, col] += 5000.0  # one texel ~ 10⁴ × the mean: a sun
    return {"smooth": smooth.astype(np.float32), "sun": sun.astype(np.float32)}


def _apply(matrix, cubes, out):
    return po.apply_prefilter_operator(matrix, po.stack_pyramid(cubes), cubes.shape[2], out, cubes.shape[-1])


def _rel_mse(x, exact):
    return float(np.mean((x - exact) ** 2) / np.mean(exact**2))


# The operator alone (no bright split): measured relative MSE (smooth, sun) with the split-sum τ, κ: ≤ 2.2e-6 /
# 2.4e-4; FIS (128 samples) 1.4e-4 / 1.2e-2 at α 0.04, 2.1e-4 / 1.7e-2 at α 0.1.
@pytest.mark.parametrize("alpha, out", [(0.04, 16), (0.04, 32), (0.1, 16)])
def test_operator_matches_the_dense_kernel_quadrature(alpha, out):
    matrix = po.build_prefilter_operator(alpha, out, N, SPLITSUM)
    for name, env in _environments().items():
        exact = ss._exact_prefilter_level(env, alpha, out)
        got = _apply(matrix, env[None], out)[0]
        fis = ss._prefilter_fis(ss.build_mips(env), alpha, out, 128)
        bound = 5e-6 if name == "smooth" else 1e-3
        assert _rel_mse(got, exact) < bound, (name, _rel_mse(got, exact))
        assert _rel_mse(got, exact) < 0.1 * _rel_mse(fis, exact), name  # at least 10× better than FIS


def test_rows_sum_to_one_and_a_constant_environment_is_returned():
    matrix = po.build_prefilter_operator(0.04, 16, N, SPLITSUM)
    assert matrix.shape == (16 * 16, po.pyramid_offsets(N)[-1]) and matrix.dtype == np.float32
    assert np.all(matrix.data > 0)
    np.testing.assert_allclose(np.asarray(matrix.astype(np.float64).sum(axis=1)).ravel(), 1.0, atol=1e-7)
    cubes = np.full((2, 6, N, N, 3), 0.7, np.float32) * np.array([1.0, 3.0], np.float32)[:, None, None, None, None]
    out = _apply(matrix, cubes, 16)
    np.testing.assert_allclose(out[0], 0.7, rtol=2e-6)  # float32 sums of 300 terms
    np.testing.assert_allclose(out[1], 2.1, rtol=2e-6)


def test_vanishing_roughness_is_the_identity():
    env = _environments()["smooth"]
    got = _apply(po.build_prefilter_operator(1e-3, N, N, SPLITSUM), env[None], N)[0]
    np.testing.assert_allclose(got, env, rtol=1e-4)


def test_batch_results_are_bit_identical_to_each_probe_alone():
    envs = _environments()
    cubes = np.stack([envs["smooth"], envs["sun"], envs["smooth"] * 2.0, envs["sun"][:, ::-1]]).astype(np.float32)
    matrix = po.build_prefilter_operator(0.04, 16, N, SPLITSUM)
    batch = _apply(matrix, cubes, 16)
    for i in range(cubes.shape[0]):
        np.testing.assert_array_equal(_apply(matrix, cubes[i : i + 1], 16)[0], batch[i])
    np.testing.assert_array_equal(_apply(matrix, cubes[[3, 1]], 16), batch[[3, 1]])


def test_alpha_zero_is_refused():
    with pytest.raises(ValueError, match="alpha"):
        po.build_prefilter_operator(0.0, 16, N)


def test_sparse_cache_round_trip_and_damaged_file_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("BAKERY_CACHE_DIR", str(tmp_path))
    matrix = po.build_prefilter_operator(0.04, 8, 16, SPLITSUM)
    stored = operator_cache.save_sparse("test-op", matrix)
    assert not stored.data.flags.writeable and not stored.indices.flags.writeable  # views of the read-only maps
    assert len(list(tmp_path.glob("*.npy"))) == 4
    loaded = operator_cache.load_sparse("test-op")
    assert loaded.shape == matrix.shape and (loaded != matrix).nnz == 0
    assert operator_cache.load_sparse("another-op") is None
    # damage the largest part (the weights): detected by its checksum, removed, and the matrix reported missing
    path = next(p for p in tmp_path.glob("*.npy") if np.load(p, mmap_mode="r").dtype == np.float32)
    array = np.load(path)
    array[3] += np.float32(0.25)
    with open(path, "r+b") as handle:
        np.save(handle, array)
    with pytest.warns(operator_cache.OperatorCacheWarning):
        assert operator_cache.load_sparse("test-op") is None
    assert not path.exists()


def test_cached_operator_is_rebuilt_after_damage(tmp_path, monkeypatch):
    monkeypatch.setenv("BAKERY_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(OperatorCache, "load", staticmethod(operator_cache.load))
    monkeypatch.setattr(OperatorCache, "save", staticmethod(operator_cache.save))
    po.cached_prefilter_operator.cache_clear()
    first = po.cached_prefilter_operator(0.05, 8, 16, SPLITSUM).copy()  # (the live one maps the files)
    files = sorted(p.name for p in tmp_path.glob("*.npy"))
    assert len(files) == 5  # the matrix's 4 parts and the row normalisers S(d)
    for path in tmp_path.glob("*.npy"):  # poison every part
        array = np.load(path)
        array.reshape(-1)[0] = array.reshape(-1)[0] + 1
        with open(path, "r+b") as handle:
            np.save(handle, array)
    po.cached_prefilter_operator.cache_clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = po.cached_prefilter_operator(0.05, 8, 16, SPLITSUM)
    assert any(issubclass(w.category, operator_cache.OperatorCacheWarning) for w in caught)
    assert (again != first).nnz == 0 and sorted(p.name for p in tmp_path.glob("*.npy")) == files
    po.cached_prefilter_operator.cache_clear()


def test_row_normalisers_match_the_dense_quadrature_normaliser():
    # S(d) = Σ_j w_j(d) over the leaves ≈ Σ_i K_α(d, c_i) Ω_i over every capture texel (what _exact divides by),
    # also when the lobe is narrower than a texel (where the sphere integral Z(α) is far off)
    from bakery.sphere.cubemap import cube_texel_solid_angles

    for alpha, out in ((0.011, 32), (0.05, 16)):
        norms = po.cached_row_norms(alpha, out, N, SPLITSUM)
        src = cube_texel_directions(N).reshape(-1, 3)
        dense = (ss._kernel_profile(cube_texel_directions(out).reshape(-1, 3) @ src.T, alpha)
                 * cube_texel_solid_angles(N).reshape(-1)).sum(axis=1)
        np.testing.assert_allclose(norms, dense, rtol=2e-4)


def test_bright_texels_split_off_are_exact_on_a_small_sunny_capture():
    # the chain's sharp path: operator on the remainder + the sun texel exactly, divided by S(d)
    import dataclasses

    env = _environments()["sun"]
    settings = dataclasses.replace(ss.SplitSumSettings(face_size=N))
    for alpha, out in ((0.011, 32), (0.05, 16)):
        exact = ss._exact_prefilter_level(env, alpha, out)
        got = ss._prefilter_sharp_batch(env[None], [alpha], [out], settings)[0][0]
        assert _rel_mse(got, exact) < 1e-6, (alpha, _rel_mse(got, exact))
