"""Skip decisions on constructed probes: required bands by energy (closed forms) and neighbour refinement."""

from math import pi, sqrt

import numpy as np

from bakery.pipeline.skip import band_skip_decisions, dilate_over_neighbours, irradiance_band_energy, required_bands
from bakery.sh.basis import evaluate_sh_basis


def test_constant_light_needs_only_band_0():
    sh = np.zeros((1, 9, 3))
    sh[0, 0] = 2 * sqrt(pi)
    assert required_bands(irradiance_band_energy(sh), 1e-6).tolist() == [0]


def test_directional_light_band_fractions_match_the_closed_form():
    # A delta light: f_lm = Y_lm(d); irradiance energy per band e_l = A_l² (2l+1)/(4π), so band 2 holds
    # (π/4)²·5 / (π² + (2π/3)²·3 + (π/4)²·5) of the energy.
    sh = evaluate_sh_basis(np.array([[0.0, 1.0, 0.0]]), 2)[:, :, None].repeat(3, axis=2)
    energy = irradiance_band_energy(sh)[0]
    e = np.array([pi**2 * 1, (2 * pi / 3) ** 2 * 3, (pi / 4) ** 2 * 5]) / (4 * pi) * 3
    np.testing.assert_allclose(energy, e)
    fraction2 = e[2] / e.sum()
    assert required_bands(energy[None], fraction2 * 1.01).tolist() == [1]
    assert required_bands(energy[None], fraction2 * 0.99).tolist() == [2]


def test_neighbour_refinement_spreads_one_ring_on_a_grid():
    x, y = np.meshgrid(np.arange(5.0), np.arange(5.0))
    positions = np.stack([x.ravel(), y.ravel(), np.zeros(25)], axis=1)
    required = np.zeros(25, dtype=np.int32)
    required[12] = 2  # the centre probe
    out = dilate_over_neighbours(required, positions).reshape(5, 5)
    expected = np.zeros((5, 5), dtype=np.int32)
    expected[1:4, 1:4] = 2  # 1.5 × spacing reaches the 8-neighbourhood (diagonals at √2)
    np.testing.assert_array_equal(out, expected)


def test_band2_encodings_are_skipped_only_when_no_probe_needs_band_2():
    positions = np.array([[0, 0, 0], [1, 0, 0.0]])
    flat = np.array([[1.0, 0.1, 0.0], [1.0, 0.2, 0.0]])
    _, skipped = band_skip_decisions(flat, positions, 1e-6, ["sh2", "zh3", "sh3"])
    assert [s["encoding"] for s in skipped] == ["zh3", "sh3"]
    bumpy = flat.copy()
    bumpy[1, 2] = 0.5
    required, skipped = band_skip_decisions(bumpy, positions, 1e-6, ["sh2", "zh3", "sh3"])
    assert skipped == [] and required.tolist() == [2, 2]
