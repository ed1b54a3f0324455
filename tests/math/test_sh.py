"""SH core: closed forms, then properties."""

from math import pi, sqrt

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.spatial.transform import Rotation
from scipy.special import eval_legendre

from bakery.probe import cube_projector
from bakery.sh import (
    cosine_lobe_band_factors,
    evaluate_sh,
    evaluate_sh_basis,
    irradiance_sh_from_radiance_sh,
    rotate_sh,
    sh_index,
    zonal_to_sh,
)
from bakery.sh.basis import normalization
from bakery.sphere.cubemap import cube_texel_directions
from bakery.sphere.fibonacci import fibonacci_directions
from tests.conftest import random_positive_radiance_sh

GRID = 96
DIRECTIONS = cube_texel_directions(GRID).reshape(-1, 3)


def project(values):
    return cube_projector(GRID, 6).project(values)


def test_basis_matches_zh3_paper_equations_4_and_5():
    d = fibonacci_directions(50)
    x, y, z = d.T
    y_basis = evaluate_sh_basis(d, 2)
    c1, c2 = sqrt(3 / (4 * pi)), sqrt(15 / (4 * pi))
    expected = np.stack([np.full_like(x, 1 / (2 * sqrt(pi))), -c1 * y, c1 * z, -c1 * x, c2 * x * y, -c2 * y * z,
                         sqrt(5 / (16 * pi)) * (3 * z * z - 1), -c2 * x * z, sqrt(15 / (16 * pi)) * (x * x - y * y)], 1)
    np.testing.assert_allclose(y_basis, expected, atol=1e-13)


def test_zonal_basis_is_legendre():
    d = fibonacci_directions(40)
    basis = evaluate_sh_basis(d, 8)
    for l in range(9):  # noqa: E741
        np.testing.assert_allclose(basis[:, sh_index(l, 0)], normalization(l, 0) * eval_legendre(l, d[:, 2]),
                                   atol=1e-12)


def test_orthonormality_on_a_fine_cube_grid():
    gram = cube_projector(GRID, 6).weighted_basis.T @ evaluate_sh_basis(DIRECTIONS, 6)
    np.testing.assert_allclose(gram, np.eye(49), atol=2e-4)


def test_constant_radiance_gives_l00_and_irradiance_pi_c():
    c = np.array([0.5, 2.0, 7.0])
    sh = project(np.broadcast_to(c, (DIRECTIONS.shape[0], 3)))
    np.testing.assert_allclose(sh[0], 2 * sqrt(pi) * c, rtol=1e-10)
    np.testing.assert_allclose(sh[1:16], 0, atol=1e-10)  # bands 1–3 vanish by the cube's symmetry
    np.testing.assert_allclose(sh[16:], 0, atol=2e-3)  # band 4+ holds the cube quadrature's cubic invariant
    irr = evaluate_sh(irradiance_sh_from_radiance_sh(sh[None, :9]), fibonacci_directions(100))[0]
    np.testing.assert_allclose(irr, np.broadcast_to(pi * c, irr.shape), rtol=1e-10)


@pytest.mark.parametrize("l", range(7))
def test_cosine_lobe_band_factors_by_funk_hecke(l):  # noqa: E741
    # Funk–Hecke: the convolution eigenvalue of max(0, t) is 2π ∫_0^1 t P_l(t) dt.
    expected, _ = quad(lambda t: 2 * pi * t * eval_legendre(l, t), 0.0, 1.0)
    assert cosine_lobe_band_factors(6)[l] == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("k", [0, 1, 3, 6, 8, 15, 24, 40])
def test_single_basis_function_projects_to_its_unit_vector(k):
    values = evaluate_sh_basis(DIRECTIONS, 6)[:, k : k + 1]
    sh = project(values)[:, 0]
    expected = np.zeros(49)
    expected[k] = 1
    np.testing.assert_allclose(sh, expected, atol=3e-4)


def test_zonal_lobe_projects_by_the_zonal_harmonic_formula():
    axis = np.array([0.3, -0.5, 0.81])
    axis /= np.linalg.norm(axis)
    kappa = 3.0
    g = lambda t: np.exp(kappa * (t - 1))  # noqa: E731
    values = g(DIRECTIONS @ axis)[:, None]
    # Zonal coefficient in the axis frame: z_l = 2π ∫ g(t) K_l^0 P_l(t) dt; then f_lm = z_l √(4π/(2l+1)) Y_lm(a).
    z = np.array([quad(lambda t: 2 * pi * g(t) * normalization(l, 0) * eval_legendre(l, t), -1, 1)[0]
                  for l in range(7)])
    np.testing.assert_allclose(project(values)[:, 0], zonal_to_sh(z, axis[None])[0], atol=2e-4)


def test_cone_light_matches_zh3_equation_15():
    sigma = 0.6
    values = (DIRECTIONS[:, 2] >= np.cos(sigma)).astype(float)[:, None]
    sh = cube_projector(512, 2).project(np.broadcast_to(
        (cube_texel_directions(512).reshape(-1, 3)[:, 2] >= np.cos(sigma)).astype(float)[:, None], (6 * 512 * 512, 1)))
    expected = [sqrt(pi) * (1 - np.cos(sigma)), sqrt(3 * pi) / 2 * np.sin(sigma) ** 2,
                sqrt(5 * pi) / 2 * np.cos(sigma) * np.sin(sigma) ** 2]
    np.testing.assert_allclose(sh[[0, 2, 6], 0], expected, rtol=2e-3)
    del values


coefficients = st.lists(st.floats(-2, 2, allow_nan=False), min_size=25, max_size=25)
quaternions = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1)


@given(coefficients, coefficients, st.floats(-3, 3), st.floats(-3, 3))
def test_projection_is_linear(a, b, s, t):
    basis = evaluate_sh_basis(DIRECTIONS, 4)
    fa, fb = basis @ np.array(a), basis @ np.array(b)
    lhs = project((s * fa + t * fb)[:, None])
    rhs = s * project(fa[:, None]) + t * project(fb[:, None])
    np.testing.assert_allclose(lhs, rhs, atol=1e-9)


@given(coefficients, quaternions)
def test_rotation_is_equivariant(c, q):
    rotation = Rotation.from_quat(q).as_matrix()
    f = np.array(c)[None, :, None]
    d = fibonacci_directions(64)
    rotated = rotate_sh(f, rotation)
    # f'(ω) = f(R⁻¹ω)
    np.testing.assert_allclose(evaluate_sh(rotated, d), evaluate_sh(f, d @ rotation), atol=1e-9)


@given(st.integers(0, 2**32 - 1), st.integers(1, 8))
def test_positive_function_coefficient_bounds(seed, lights):
    # [ZH3] App. A: |f_l| / f0 ≤ √(2l+1); per basis function L1 ≤ √3, L2 zonal ∈ [−√5/2, √5], others ≤ √15/2.
    sh = random_positive_radiance_sh(np.random.default_rng(seed), lights, max_band=4)[0]
    f0 = sh[0]
    for l in range(5):  # noqa: E741
        norm = np.linalg.norm(sh[l * l : (l + 1) ** 2], axis=0)
        assert np.all(norm <= sqrt(2 * l + 1) * f0 * (1 + 1e-9))
    ratios = sh[1:9] / f0
    assert np.all(np.abs(ratios[:3]) <= sqrt(3) * (1 + 1e-9))
    assert np.all(ratios[5] <= sqrt(5) * (1 + 1e-9)) and np.all(ratios[5] >= -sqrt(5) / 2 * (1 + 1e-9))
    assert np.all(np.abs(ratios[[3, 4, 6, 7]]) <= sqrt(15) / 2 * (1 + 1e-9))


# --------------------------------------------------------------------------- reflection-symmetric cube projection


def test_sh_reflection_parity_holds_everywhere():
    """Y_lm(R_s ω) = χ_lm(s) Y_lm(ω) at random directions, for every axis reflection; and the closed form of the
    z flip, (−1)^(l+m) for the real SH of this basis (P_l^|m|(−z) = (−1)^(l+|m|) P_l^|m|(z))."""
    from bakery.sh.projection import AXIS_REFLECTIONS, sh_reflection_parity

    band = 12
    parity = sh_reflection_parity(band)
    rng = np.random.default_rng(3)
    omega = rng.normal(size=(50, 3))
    omega /= np.linalg.norm(omega, axis=1, keepdims=True)
    at = evaluate_sh_basis(omega, band)
    for s, reflection in enumerate(AXIS_REFLECTIONS):
        np.testing.assert_allclose(evaluate_sh_basis(omega * reflection, band), at * parity[s], atol=1e-10)
    l = np.array([l for l in range(band + 1) for _ in range(2 * l + 1)])  # noqa: E741
    m = np.array([m for l in range(band + 1) for m in range(-l, l + 1)])
    np.testing.assert_array_equal(parity[4], (-1.0) ** (l + np.abs(m)))


@given(half=st.integers(1, 12), band=st.integers(0, 14), channels=st.integers(1, 4), seed=st.integers(0, 2**31))
def test_cube_projection_through_reflections_equals_the_direct_sum(half, band, channels, seed):
    """The folded projection is the brute-force sum Σ_t Y(ω_t) Ω_t L_t over every texel (float64), to float32."""
    from bakery.sh.projection import CubeSHProjector
    from bakery.sphere.cubemap import cube_texel_solid_angles

    n = 2 * half
    directions = cube_texel_directions(n).reshape(-1, 3)
    omega = cube_texel_solid_angles(n).reshape(-1)
    cube = np.random.default_rng(seed).gamma(0.5, size=(6, n, n, channels)).astype(np.float32)
    direct = (evaluate_sh_basis(directions, band) * omega[:, None]).T @ cube.reshape(-1, channels).astype(np.float64)
    folded = CubeSHProjector(directions, omega, band).project(cube)
    assert folded.dtype == np.float32 and folded.shape == direct.shape
    np.testing.assert_allclose(folded, direct, rtol=0, atol=2e-6 * np.abs(direct).max() + 1e-12)


def test_cube_projection_through_reflections_needs_an_even_face():
    from bakery.sh.projection import CubeSHProjector
    from bakery.sphere.cubemap import cube_texel_solid_angles

    with pytest.raises(ValueError, match="even face size"):
        CubeSHProjector(cube_texel_directions(5).reshape(-1, 3), cube_texel_solid_angles(5).reshape(-1), 4)


@given(seed=st.integers(0, 2**31 - 1), count=st.integers(2, 9), face=st.sampled_from([4, 8, 16]))
def test_a_probe_projects_to_the_same_bits_whatever_it_is_batched_with(seed, count, face):
    """The projection of a batch is each probe's own projection, bit for bit (no batch-wide GEMM whose blocking
    depends on the batch): a nonlinear encoding downstream (the ZH3 axis solve) cannot then store different bits
    for a probe baked in another batch (pipeline batch size, dilation's re-encoded batches)."""
    from bakery.irradiance.zh3 import solve_zh3_axis

    rng = np.random.default_rng(seed)
    cubes = rng.lognormal(0.0, 1.0, (count, 6 * face * face, 3)).astype(np.float32)
    projector = cube_projector(face, 2)
    together = projector.project(cubes)
    for i in range(count):
        np.testing.assert_array_equal(together[i], projector.project(cubes[i]))
        np.testing.assert_array_equal(together[i], projector.project(cubes[i : i + 1])[0])
    linear, zonal, _ = solve_zh3_axis(together)
    alone = [solve_zh3_axis(together[i : i + 1]) for i in (0, count - 1)]
    np.testing.assert_array_equal(linear[[0, count - 1]], np.concatenate([a[0] for a in alone]))
    np.testing.assert_array_equal(zonal[[0, count - 1]], np.concatenate([a[1] for a in alone]))
