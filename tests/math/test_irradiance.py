"""ZH3 family, deringing, quantization and the exact reference: closed forms, properties, brute force."""

from math import pi, sqrt

import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st

from bakery.irradiance import quantize
from bakery.irradiance.dering import dering_zh3
from bakery.irradiance.reference import reference_irradiance
from bakery.irradiance.sh_irradiance import evaluate_sh_irradiance, minimum_sh_irradiance
from bakery.irradiance.zh3 import (
    axis_error,
    evaluate_zh3_irradiance,
    expand_zh3_to_sh3,
    fit_zh3_luminance,
    hallucinate_zonal_l2,
    luminance_axis,
    solve_zh3_axis,
)
from bakery.sh.convolution import cosine_lobe_band_factors, zonal_to_sh
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.sphere.grid import SphericalSamples
from tests.conftest import random_positive_radiance_sh

DENSE = fibonacci_directions(20000)
seeds = st.integers(0, 2**32 - 1)


def sphere_light_sh(sigma, axis, colour):
    """Radiance SH3 (1, 9, 3) of a constant cone light ([ZH3] Eq. 15)."""
    zonal = np.array([sqrt(pi) * (1 - np.cos(sigma)), sqrt(3 * pi) / 2 * np.sin(sigma) ** 2,
                      sqrt(5 * pi) / 2 * np.cos(sigma) * np.sin(sigma) ** 2])
    # zonal_to_sh takes SH-zonal coefficients z_l with f_lm = z_l √(4π/(2l+1)) Y_lm(a); Eq. 15 gives f_l^0 in the
    # axis frame, which equals z_l √(4π/(2l+1)) Y_l0(z) = z_l at z = 1, so z_l = f_l^0.
    sh = zonal_to_sh(zonal, axis[None])[0]
    return sh[None, :, None] * np.asarray(colour)[None, None, :]


@given(st.floats(0.05, 1.5), seeds)
def test_zh3_reproduces_a_zonal_sh3_signal_exactly(sigma, seed):
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    sh = sphere_light_sh(sigma, axis, rng.uniform(0.1, 3.0, size=3))
    linear, zonal = fit_zh3_luminance(sh)
    np.testing.assert_allclose(luminance_axis(linear)[0], axis, atol=1e-9)
    np.testing.assert_allclose(expand_zh3_to_sh3(linear, zonal, luminance_axis(linear)), sh, atol=1e-12)
    np.testing.assert_allclose(evaluate_zh3_irradiance(linear, zonal, DENSE[:500]),
                               evaluate_sh_irradiance(sh, DENSE[:500]), atol=1e-12)


@given(seeds, st.integers(1, 6))
def test_solved_axis_never_worse_than_luminance_start(seed, lights):
    sh = np.concatenate([random_positive_radiance_sh(np.random.default_rng(seed + i), lights) for i in range(4)])
    target = sh * cosine_lobe_band_factors(2)[[0, 1, 1, 1, 2, 2, 2, 2, 2]][None, :, None]
    start = target[:, 1:4]
    linear, _, _ = solve_zh3_axis(sh)
    solved = linear[:, 1:4] * cosine_lobe_band_factors(2)[1]
    # Eq. 11 is evaluated as ‖t2‖² − (4π/5)s², so rounding is relative to the target energy ‖t‖².
    tolerance = 1e-12 * np.sum(target**2, axis=(1, 2))
    assert np.all(axis_error(solved, target) <= axis_error(start, target) + tolerance)


def test_solved_axis_improves_a_case_with_weak_linear_band():
    # Two opposite lights (L1 cancels) plus a weak third: the L2 lobe is strong along ±z, L1 points along x.
    from bakery.sh.basis import evaluate_sh_basis

    d = np.array([[0, 0, 1.0], [0, 0, -1.0], [1, 0, 0]])
    sh = (evaluate_sh_basis(d, 2).T @ np.array([[1.0] * 3, [1.0] * 3, [0.05] * 3]))[None]
    target = sh * cosine_lobe_band_factors(2)[[0, 1, 1, 1, 2, 2, 2, 2, 2]][None, :, None]
    linear, _, stats = solve_zh3_axis(sh)
    solved = linear[:, 1:4] * cosine_lobe_band_factors(2)[1]
    assert stats["improved"] == 1
    assert axis_error(solved, target)[0] < 0.5 * axis_error(target[:, 1:4], target)[0]


def test_hallucination_matches_listing_1():
    # [ZH3] Listing 1 transcribed literally for one probe (radiance SH, sh[k] RGB).
    rng = np.random.default_rng(3)
    sh = random_positive_radiance_sh(rng, 3)[0, :4]
    lum = np.array([0.2126, 0.7152, 0.0722])
    axis = np.array([-sh[3] @ lum, -sh[1] @ lum, sh[2] @ lum])
    axis /= np.linalg.norm(axis)
    ratio = np.abs(np.stack([-sh[3], -sh[1], sh[2]], 0).T @ axis) / sh[0]
    zonal = sh[0] * (0.08 * ratio + 0.6 * ratio * ratio)
    n = DENSE[:50]
    fz = n @ axis
    zh_dir = sqrt(5 / (16 * pi)) * (3 * fz * fz - 1)
    c1 = sqrt(3 / (4 * pi))
    linear = pi * sh[0] / (2 * sqrt(pi)) + (2 * pi / 3) * c1 * (
        np.outer(-n[:, 1], sh[1]) + np.outer(n[:, 2], sh[2]) + np.outer(-n[:, 0], sh[3]))
    expected = linear + pi * 0.25 * np.outer(zh_dir, zonal)  # Listing 1 is for the normalised cosine (÷π)
    ours = evaluate_zh3_irradiance(sh[None], hallucinate_zonal_l2(sh[None]), n)[0]
    np.testing.assert_allclose(ours, expected, rtol=1e-12)


@given(seeds, st.integers(1, 6))
def test_deringed_irradiance_is_non_negative_on_a_dense_set(seed, lights):
    sh = np.concatenate([random_positive_radiance_sh(np.random.default_rng(seed + i), lights) for i in range(3)])
    linear, zonal = fit_zh3_luminance(sh)
    linear, zonal, _ = dering_zh3(linear, zonal)
    values = evaluate_zh3_irradiance(linear, zonal, DENSE)
    assert values.min() >= -1e-9 * sh[:, 0].max()


@given(seeds)
def test_exact_minimum_matches_dense_sampling(seed):
    rng = np.random.default_rng(seed)
    sh = rng.normal(size=(2, 9, 3))
    exact = minimum_sh_irradiance(sh)
    sampled = evaluate_sh_irradiance(sh, DENSE).min(axis=1)
    assert np.all(exact <= sampled + 1e-9)
    assert np.all(exact >= sampled - 1e-3 * np.abs(sh).max())


@given(seeds, st.integers(1, 6), st.booleans())
def test_quantization_round_trip_within_layout_bound(seed, lights, companding):
    sh = random_positive_radiance_sh(np.random.default_rng(seed), lights)
    sh[:, 0] = np.minimum(sh[:, 0], 6e4)  # keep the DC inside the R11G11B10F range for this bound
    packed, stats = quantize.pack_sh3(sh, companding)
    decoded = quantize.unpack_sh3(packed, companding)
    # The ratios are taken against the *decoded* DC: a lone light puts a ratio on its App. A bound, and the DC's
    # rounding can push it past (seed 35: −1.1177 → −1.126 < −√5/2). Those are clamped by design; not this bound.
    against_decoded = sh[0, 1:] / decoded[0, 0]
    lower, upper = quantize.RATIO_BOUNDS[:, 0, None], quantize.RATIO_BOUNDS[:, 1, None]
    assume(np.all((against_decoded >= lower - 1e-6) & (against_decoded <= upper + 1e-6)))
    assert packed.shape == (1, 28) and packed.dtype == np.uint8 and stats["ratios_clamped"] == 0
    f0 = sh[:, 0]
    np.testing.assert_allclose(decoded[:, 0], f0, rtol=2.0**-6)
    dc_error = np.abs(decoded[:, 0] - f0) / f0
    bound = quantize.ratio_error_bound(quantize.RATIO_BOUNDS[:, 0], quantize.RATIO_BOUNDS[:, 1], companding)
    ratio = sh[0, 1:] / f0
    side = np.where(ratio >= 0, bound[:, 1, None], bound[:, 0, None])
    # |Δ(x·f0)| ≤ |x|·|Δf0| + f0·Δx (+ second order); checked on ratios relative to the true DC.
    decoded_ratio = decoded[0, 1:] / f0
    assert np.all(np.abs(decoded_ratio - ratio) <= side + np.abs(ratio) * dc_error[0] * (1 + 1e-9) + 1e-12)


def test_zh3_quantized_layout_is_16_bytes_and_exact_for_representable_values():
    linear = np.array([[[2.0, 1.0, 0.5], [0.5, 0, 0], [0, 0, 0], [-0.25, 0, 0]]])
    zonal = np.array([[0.5, 0.0, 0.0]])
    packed, _ = quantize.pack_zh3(linear, zonal, sqrt_companding=False)
    assert packed.shape == (1, 16)
    dc = packed[0, :4].view("<u4")[0]
    # R11G11B10F of (2, 1, 0.5): exponent 16/15/14 with zero mantissa.
    assert dc & 0x7FF == 16 << 6 and (dc >> 11) & 0x7FF == 15 << 6 and dc >> 22 == 14 << 5
    # f1,-1 of R = 0.5 → ratio 0.25 → 0.25/√3·127 rounded.
    assert packed[0, 4].view(np.int8) == round(0.25 / sqrt(3) * 127)


def test_r11g11b10_clamps_and_counts_overflow():
    codes, clamped = quantize.encode_r11g11b10(np.array([[1e6, 70000.0, 1.0]]))
    assert clamped == 2
    np.testing.assert_allclose(quantize.decode_r11g11b10(codes)[0], [65024.0, 65024.0, 1.0])


def test_reference_irradiance_of_a_constant_and_a_linear_environment():
    n = 128
    samples_dir = cube_texel_directions(n).reshape(-1, 3)
    omega = cube_texel_solid_angles(n).reshape(-1)
    # L(ω) = 1 + ω_z: E(n) = π + (2π/3) n_z (closed form of the clamped-cosine convolution).
    radiance = (1.0 + samples_dir[:, 2])[:, None]
    samples = SphericalSamples(samples_dir, omega, radiance)
    normals = fibonacci_directions(64)
    expected = np.pi + (2 * np.pi / 3) * normals[:, 2]
    np.testing.assert_allclose(reference_irradiance(samples, normals)[:, 0], expected, rtol=2e-4)


def test_batched_bfgs_finds_the_minimisers_of_independent_quadratics():
    """P quadratics ½(x − m)ᵀH(x − m) with known minimisers m and very different conditioning (so they finish at
    different iterations and the running set shrinks): every problem reaches its own m."""
    from bakery.irradiance.zh3 import batched_bfgs

    rng = np.random.default_rng(0)
    p, n = 12, 5
    q, _ = np.linalg.qr(rng.normal(size=(p, n, n)))
    eigenvalues = 10.0 ** (np.linspace(0.0, 1.0, n)[None, :] * np.arange(p)[:, None] / 3.0)  # condition 1 … 10^3.7
    h = (q * eigenvalues[:, None, :]) @ np.swapaxes(q, 1, 2)
    m = rng.normal(size=(p, n))
    calls = []

    def objective(x, rows):
        calls.append(len(rows))
        d = x - m[rows]
        g = np.einsum("pij,pj->pi", h[rows], d)
        return 0.5 * np.sum(d * g, axis=1), g

    x, _ = batched_bfgs(objective, np.zeros((p, n)), iterations=200, gradient_tolerance=1e-10)
    np.testing.assert_allclose(x, m, atol=1e-7)
    assert min(calls) < p  # converged problems are no longer evaluated


def test_blended_axis_error_is_eq11_at_lambda_1_and_its_gradient_matches_finite_differences():
    from bakery.irradiance.zh3 import axis_error_blended

    sh = np.concatenate([random_positive_radiance_sh(np.random.default_rng(s), 3) for s in range(4)])
    target = sh * cosine_lobe_band_factors(2)[[0, 1, 1, 1, 2, 2, 2, 2, 2]][None, :, None]
    rng = np.random.default_rng(1)
    f = target[:, 1:4] + 0.2 * rng.normal(size=target[:, 1:4].shape) * np.abs(target[:, :1])
    scale = np.sum(target**2, axis=(1, 2))
    np.testing.assert_allclose(axis_error_blended(f, target, 1.0)[0], axis_error(f, target), atol=1e-12 * scale.max())
    for lam in (0.0, 0.5):
        _, grad = axis_error_blended(f, target, lam)
        direction = rng.normal(size=f.shape)
        h = 1e-6 * np.abs(f).max()
        numeric = (axis_error_blended(f + h * direction, target, lam)[0]
                   - axis_error_blended(f - h * direction, target, lam)[0]) / (2 * h)
        np.testing.assert_allclose(np.einsum("pjc,pjc->p", grad, direction), numeric, rtol=1e-5, atol=1e-9 * scale.max())


def test_tetrahedral_starts_put_the_luminance_axis_on_each_vertex():
    from bakery.irradiance.zh3 import TETRAHEDRON_AXES, linear_band_vector, tetrahedral_starts

    sh = random_positive_radiance_sh(np.random.default_rng(2), 3)
    starts = tetrahedral_starts(linear_band_vector(sh))
    lum = np.array([0.2126, 0.7152, 0.0722])
    for vertex, start in zip(TETRAHEDRON_AXES, starts, strict=True):
        u = start[0] @ lum  # the luminance vector of the start
        np.testing.assert_allclose(np.abs(u @ vertex), np.linalg.norm(u), rtol=1e-12)
        np.testing.assert_allclose(start[0].T @ vertex, linear_band_vector(sh)[0].T @ vertex, rtol=1e-12)
