"""Brightest texels as analytic lights: extraction conserves flux and finds the sun, the analytic light equals the
brute-force integral of its texels, and SH-exp + lights beats SH-exp alone on a sun sky (brute-force reference)."""

import numpy as np
import pytest

from bakery.encodings.shexp import SHExp, SHExpLights
from bakery.probe import ProbeBatch
from bakery.reflection import shexp as sx
from bakery.reflection.lights import evaluate_lights, extract_lights, remove_texels
from bakery.reflection.reference import integrate_reflection, reflected_radiance
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.sphere.grid import SphericalSamples

FACE = 32


def sky(sun_texels=((2, 5, 9),), sun_radiance=(2e4, 1.8e4, 1.5e4)):
    d = cube_texel_directions(FACE)
    cube = np.where(d[..., 1:2] > 0, (0.4 + 0.6 * d[..., 1:2]) * np.array([0.3, 0.5, 1.0]),
                    np.array([0.2, 0.15, 0.1])).astype(np.float32)
    for texel in sun_texels:
        cube[texel] = sun_radiance
    return cube


def flux(cube):
    return np.einsum("fij,fijc->c", cube_texel_solid_angles(cube.shape[1]), cube.astype(np.float64))


def test_extraction_finds_the_sun_and_conserves_flux():
    cube = sky()
    directions, light_flux, removed = extract_lights(cube[None], max_lights=4, threshold=10.0, radius_deg=3.0)
    remainder = remove_texels(cube[None], removed)
    omega = cube_texel_solid_angles(FACE)
    lit = np.flatnonzero(light_flux[0].max(axis=1) > 0)
    assert lit.tolist() == [0]  # one sun, nothing else above 10× the mean radiance
    np.testing.assert_allclose(directions[0, 0], cube_texel_directions(FACE)[2, 5, 9], atol=1e-6)
    np.testing.assert_allclose(light_flux[0, 0], omega[2, 5, 9] * np.array([2e4, 1.8e4, 1.5e4]), rtol=1e-6)
    assert np.all(remainder[0, 2, 5, 9] == 0)
    np.testing.assert_allclose(flux(remainder[0]) + light_flux[0].sum(axis=0), flux(cube), rtol=1e-5)


def test_extraction_clusters_neighbours_and_caps_the_count():
    # a 2×2-texel sun (one cluster, flux-weighted centre) and three distant lamps, max_lights = 3
    cube = sky(sun_texels=((2, 5, 9), (2, 5, 10), (2, 6, 9), (2, 6, 10)))
    for texel, value in (((0, 16, 16), 9e3), ((4, 16, 16), 8e3), ((5, 16, 16), 7e3)):
        cube[texel] = value
    # 32² faces: texels are ~2.8° apart, diagonal neighbours ~4° — a 5° radius takes the whole 2×2 sun
    directions, light_flux, removed = extract_lights(cube[None], max_lights=3, threshold=10.0, radius_deg=5.0)
    remainder = remove_texels(cube[None], removed)
    d = cube_texel_directions(FACE)
    omega = cube_texel_solid_angles(FACE)
    sun = [(2, 5, 9), (2, 5, 10), (2, 6, 9), (2, 6, 10)]
    centre = sum(omega[t] * d[t] for t in sun)
    np.testing.assert_allclose(directions[0, 0], centre / np.linalg.norm(centre), atol=1e-6)
    np.testing.assert_allclose(light_flux[0, 0], sum(omega[t] for t in sun) * np.array([2e4, 1.8e4, 1.5e4]),
                               rtol=1e-5)
    # brightest lamps next; the third lamp stays in the environment
    np.testing.assert_allclose(directions[0, 1:], [d[0, 16, 16], d[4, 16, 16]], atol=1e-6)
    assert remainder[0, 5, 16, 16, 0] == 7e3
    np.testing.assert_allclose(flux(remainder[0]) + light_flux[0].sum(axis=0), flux(cube), rtol=1e-5)


def test_fitting_without_the_removed_texels_equals_fitting_the_remainder():
    """The fit subtracts the removed texels' splatted flux instead of copying the capture: same coefficients as
    fitting the zeroed remainder (two probes, one with lights)."""
    cubes = np.stack([sky(), sky(sun_texels=((0, 3, 3), (4, 20, 20)))])
    _, _, removed = extract_lights(cubes, max_lights=8, threshold=10.0, radius_deg=3.0)
    model = sx.SHExpSettings(n_normals=16, n_views=16)
    np.testing.assert_allclose(sx.fit_shexp(cubes, model, removed), sx.fit_shexp(remove_texels(cubes, removed), model),
                               rtol=1e-4, atol=1e-4)


def test_no_lights_in_a_smooth_environment_and_encoding_equals_shexp():
    cube = sky(sun_texels=())
    batch = ProbeBatch(cube[None])
    small = {"n_normals": 16, "n_views": 16, "fit_face_size": 8}
    fields = SHExpLights(**small).encode(batch)
    assert np.all(fields["light_flux"] == 0)
    plain = SHExp(**small).encode(batch)
    np.testing.assert_array_equal(fields["p"], plain["p"])
    np.testing.assert_array_equal(fields["q"], plain["q"])


def test_analytic_light_equals_the_brute_force_integral_of_its_texel():
    """A light at a texel centre with flux Ω·L is exactly that texel in Eq. 1's quadrature (E0 and E1)."""
    cube = np.zeros((6, FACE, FACE, 3))
    cube[2, 5, 9] = [3.0, 2.0, 1.0]
    d = cube_texel_directions(FACE).reshape(-1, 3)
    samples = SphericalSamples(d, cube_texel_solid_angles(FACE).reshape(-1), cube.reshape(-1, 3))
    rng = np.random.default_rng(3)
    n = fibonacci_directions(64)
    v = n + 0.5 * rng.normal(size=n.shape)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[np.sum(v * n, 1) < 0.05] = n[np.sum(v * n, 1) < 0.05]
    a = rng.uniform(0.1, 1.0, 64)
    f0 = rng.uniform(0.0, 1.0, 64)
    e0, e1 = integrate_reflection(samples, v, n, a, dtype=np.float64)
    truth = reflected_radiance(e0, e1, f0)
    light = evaluate_lights(cube_texel_directions(FACE)[2, 5, 9][None, None],
                            (cube_texel_solid_angles(FACE)[2, 5, 9] * cube[2, 5, 9])[None, None], v, n, a, f0)[0]
    np.testing.assert_allclose(light, truth, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("alpha", [0.25, 0.5])
def test_lights_beat_plain_shexp_on_a_sun_sky(alpha):
    """Against the brute-force reference over the capture: SH-exp of the remainder + the sun as a light has a
    lower MSE than SH-exp of the whole capture (the sun's peak is what 33 log-space coefficients cannot hold)."""
    cube = sky()
    batch = ProbeBatch(cube[None])
    small = {"n_normals": 24, "n_views": 24}
    n = fibonacci_directions(400)
    v = np.broadcast_to([0.0, 0.0, 1.0], n.shape)
    keep = np.sum(v * n, 1) > 0.05
    n, v = n[keep], np.ascontiguousarray(v[keep])
    a = np.full(len(n), alpha)
    f0 = np.ones(len(n))
    d = cube_texel_directions(FACE).reshape(-1, 3)
    samples = SphericalSamples(d, cube_texel_solid_angles(FACE).reshape(-1), cube.reshape(-1, 3).astype(np.float64))
    truth = reflected_radiance(*integrate_reflection(samples, v, n, a, dtype=np.float64), f0)
    mse = {}
    for enc in (SHExp(**small), SHExpLights(**small)):
        est = enc.evaluate_reflection(enc.encode(batch), enc.shared_tables(), v, n, a, f0)[0]
        mse[enc.name] = np.mean((est - truth) ** 2)
    assert mse["shexp_lights"] < 0.5 * mse["shexp"], mse


def test_bad_light_settings_are_rejected():
    for bad in ({"max_lights": -1}, {"light_threshold": 0.0}, {"light_radius_deg": 95.0}):
        with pytest.raises(ValueError, match="shexp_lights"):
            SHExpLights(**bad)
