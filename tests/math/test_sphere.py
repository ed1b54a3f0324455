"""Spherical grids: closed forms for solid angles and mapping round trips."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bakery.environment.layouts import (
    direction_to_equirect,
    equirect_directions,
    equirect_texel_solid_angles,
)
from bakery.sphere.cubemap import (
    cube_face_uv_to_direction,
    cube_mean_texel_solid_angle,
    cube_texel_density,
    cube_texel_directions,
    cube_texel_solid_angles,
    direction_to_cube_face_uv,
    direction_to_cube_texel,
    resample_cube,
)
from bakery.sphere.fibonacci import fibonacci_directions


@pytest.mark.parametrize("n", [1, 2, 7, 64])
def test_cube_texel_solid_angles_sum_to_4pi(n):
    assert cube_texel_solid_angles(n).sum() == pytest.approx(4 * np.pi, rel=1e-12)


def test_cube_texel_solid_angle_matches_numerical_integral():
    # Independent: integrate dΩ = (1+u²+v²)^(-3/2) du dv over the corner texel of a 4×4 face with a fine grid.
    n, fine = 4, 2000
    t = (np.arange(fine) + 0.5) / fine * (2.0 / n) - 1.0
    u, v = np.meshgrid(t, t)
    numeric = np.sum((1 + u * u + v * v) ** -1.5) * (2.0 / n / fine) ** 2
    assert cube_texel_solid_angles(n)[0, 0, 0] == pytest.approx(numeric, rel=1e-6)


@pytest.mark.parametrize("h,w", [(4, 8), (256, 512)])
def test_equirect_solid_angles_sum_to_4pi(h, w):
    assert equirect_texel_solid_angles(h, w).sum() == pytest.approx(4 * np.pi, rel=1e-12)


def test_cube_face_order_and_orientation_follow_the_convention_table():
    d = cube_texel_directions(1)[:, 0, 0]
    np.testing.assert_allclose(d, [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], atol=1e-12)
    # +Z face: u grows towards +x, v (rows, downwards) towards -y.
    np.testing.assert_allclose(cube_face_uv_to_direction(np.array(4), np.array(1.0), np.array(0.0)),
                               np.array([1, 0, 1]) / np.sqrt(2))
    np.testing.assert_allclose(cube_face_uv_to_direction(np.array(4), np.array(0.0), np.array(1.0)),
                               np.array([0, -1, 1]) / np.sqrt(2))


unit_vectors = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3)


@given(unit_vectors)
def test_cube_mapping_round_trip(v):
    d = np.array(v) / np.linalg.norm(v)
    face, u, w = direction_to_cube_face_uv(d[None])
    np.testing.assert_allclose(cube_face_uv_to_direction(face, u, w)[0], d, atol=1e-12)


@given(st.integers(1, 40), st.integers(0, 2**32 - 1))
def test_cube_mapping_by_chunks_is_the_whole_array_mapping(chunk, seed):
    # Large arrays go through the mapping in chunks (cache-sized); every chunking gives the same bits as one pass,
    # for any leading shape, including exact ties between axes and the zero vector.
    import bakery.sphere.cubemap as cubemap

    rng = np.random.default_rng(seed)
    d = rng.normal(size=(4, 25, 3))
    d[0, :10] = np.round(d[0, :10])  # ties between |x|, |y|, |z| and zero components
    d[1, 0] = 0.0
    whole = (*direction_to_cube_face_uv(d), *direction_to_cube_texel(d, 7))
    saved = cubemap._DIRECTION_CHUNK
    cubemap._DIRECTION_CHUNK = chunk
    try:
        chunked = (*direction_to_cube_face_uv(d), *direction_to_cube_texel(d, 7))
    finally:
        cubemap._DIRECTION_CHUNK = saved
    for a, b in zip(whole, chunked, strict=True):
        assert a.shape == b.shape == (4, 25) and a.dtype == b.dtype
        assert np.array_equal(a, b)


@given(unit_vectors)
def test_equirect_mapping_round_trip(v):
    d = np.array(v) / np.linalg.norm(v)
    rows, cols = direction_to_equirect(d[None], 64, 128)
    # the latitude goes through acos(y): within ~1e-8 rad of a pole, y = cos θ rounds to 1 (error ~ √ε ≈ 1.5e-8)
    np.testing.assert_allclose(equirect_directions(rows, cols, 64, 128)[0], d, atol=1e-7)


def test_equirect_orientation_matches_openexr():
    # OpenEXR LatLongMap: row 0 is +Y, the image centre looks down +Z, column 0 is longitude +π (so left of
    # centre is +X).
    np.testing.assert_allclose(equirect_directions(np.array(0.0), np.array(32.0), 32, 64), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(equirect_directions(np.array(16.0), np.array(32.0), 32, 64), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(equirect_directions(np.array(16.0), np.array(16.0), 32, 64), [1, 0, 0], atol=1e-12)


def test_fibonacci_directions_are_unit_and_balanced():
    d = fibonacci_directions(4096)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.abs(d.mean(axis=0)).max() < 1e-3


def cube_flux(cube):
    return np.einsum("fijc,fij->c", cube.astype(np.float64), cube_texel_solid_angles(cube.shape[1]))


def test_cube_texel_density_integrates_to_the_texel_solid_angles():
    n, fine = 4, 512
    t = (np.arange(n * fine) + 0.5) / (n * fine) * 2.0 - 1.0
    v, u = np.meshgrid(t, t, indexing="ij")
    omega = cube_texel_density(u, v, n * fine).reshape(n, fine, n, fine).sum(axis=(1, 3))
    np.testing.assert_allclose(omega, cube_texel_solid_angles(n)[0], rtol=1e-5)
    assert cube_mean_texel_solid_angle(n) == pytest.approx(cube_texel_solid_angles(n).mean(), rel=1e-12)


@pytest.mark.parametrize("m,n", [(32, 16), (32, 8), (48, 32), (16, 40), (20, 7), (8, 32), (5, 5)])
def test_resample_cube_preserves_flux(m, n):
    cube = np.random.default_rng(m * 100 + n).lognormal(size=(6, m, m, 3)).astype(np.float32)
    out = resample_cube(cube, n)
    assert out.shape == (6, n, n, 3) and out.dtype == np.float32
    np.testing.assert_allclose(cube_flux(out), cube_flux(cube), rtol=1e-6)


@pytest.mark.parametrize("m,n", [(32, 16), (48, 32), (16, 40), (8, 32)])
def test_resample_cube_keeps_a_constant(m, n):
    out = resample_cube(np.full((6, m, m, 2), 1.75, dtype=np.float32), n)
    np.testing.assert_allclose(out, 1.75, rtol=1e-6)


def test_solid_angle_weighting_matters():
    # A plain 2x2 mean loses flux because texel solid angles differ (more near face centres).
    cube = np.random.default_rng(1).lognormal(size=(6, 16, 16, 1))
    plain = cube.reshape(6, 8, 2, 8, 2, 1).mean(axis=(2, 4))
    assert abs(cube_flux(plain)[0] / cube_flux(cube)[0] - 1) > 1e-4
    np.testing.assert_allclose(cube_flux(resample_cube(cube, 8)), cube_flux(cube), rtol=1e-6)


@pytest.mark.parametrize("m,k", [(8, 2), (8, 4), (6, 3)])
def test_downsampling_an_upsampled_cube_returns_it(m, k):
    cube = np.random.default_rng(m + k).lognormal(size=(6, m, m, 3)).astype(np.float32)
    up = resample_cube(cube, k * m)
    np.testing.assert_allclose(resample_cube(up, m), cube, rtol=1e-5)

