"""The hybrid reflection encoding (``shexp_hybrid``) and its bandwidth chain: levels from the kernel's bandwidth, the
sharp prefilter against exact quadrature, the constant-environment identity against brute force, convergence to the
exact prefiltered environment below the crossover, no seam at the crossover (stated bound), first_level and the
clamp rules, memory accounting, and the α / n·v input rules of every reflection encoding."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bakery.encodings.hybrid import SHExpHybrid
from bakery.encodings.registry import ENCODINGS
from bakery.encodings.shexp import SHExp, SHExpLights
from bakery.encodings.splitsum import SplitSum
from bakery.probe import ProbeBatch
from bakery.reflection import hybrid as hy
from bakery.reflection import splitsum as ss
from bakery.reflection.reference import integrate_reflection, reflected_radiance
from bakery.reflection.validation import clamp_view_to_horizon
from bakery.sh.convolution import cosine_lobe_band_factors
from bakery.sphere.cubemap import (
    cube_texel_directions,
    cube_texel_solid_angles,
    sample_cube_bilinear,
)
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.sphere.grid import SphericalSamples

FACE = 16
FAST = {"n_normals": 16, "n_views": 16, "fit_face_size": 8}


def _cubes():
    d = cube_texel_directions(FACE)
    sun = np.array([0.3, 0.8, 0.52]) / np.linalg.norm([0.3, 0.8, 0.52])
    lobe = np.exp(40.0 * (d @ sun - 1.0))[..., None] * np.array([50.0, 40.0, 30.0])
    sky = (0.5 + 0.5 * d[..., 1:2]) * np.array([0.2, 0.3, 0.6])
    return np.stack([lobe + sky, np.full_like(lobe, 0.7)]).astype(np.float32)


@pytest.fixture(scope="module")
def hybrid():
    enc = SHExpHybrid(face_size=FACE, **FAST)
    return enc, enc.encode(ProbeBatch(_cubes()))


def _rows(count=48, seed=0):
    n = fibonacci_directions(count)
    rng = np.random.default_rng(seed)
    v = n + 0.6 * rng.normal(size=n.shape)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    flip = np.sum(v * n, axis=1) < 0.05
    v[flip] = n[flip]
    return v, n


# ------------------------------------------------------------------------------------------------ the chain
def test_high_band_factors_match_the_split_sum_quadrature_and_the_cosine_closed_form():
    for alpha in (0.16, 0.36):
        np.testing.assert_allclose(ss._band_factors_high(alpha)[:33], ss.kernel_band_factors(alpha, 32), atol=2e-4)
    # α = 1: K ∝ ⟨n, l⟩₊ exactly, λ_l = A_l / π (closed form, an independent reference)
    np.testing.assert_allclose(ss._band_factors_high(1.0)[:9], cosine_lobe_band_factors(8) / np.pi, atol=1e-5)


def test_chain_levels_come_from_the_kernel_bandwidth():
    chain = ss.BandwidthChainSettings(face_size=128, alpha_top=0.84)
    alphas, sizes = chain.level_alphas(), chain.level_sizes()
    assert alphas[0] == 0 and sizes[:3] == (128, 128, 64) and np.all(np.diff(alphas) > 0) and alphas[-1] >= 0.84
    for a, size in zip(alphas[1:], sizes[1:], strict=True):
        if size > 4:  # the face follows the order: oversampling · F_ε(α_k) = N_k
            assert chain.oversampling * ss.kernel_order(a) == pytest.approx(size, rel=2e-3)
    # scale invariance for sharp α: one level per halving of the face doubles α
    assert alphas[2] / alphas[1] == pytest.approx(2.0, rel=0.03)
    # the runtime coordinate hits every level and is monotone and continuous in α
    np.testing.assert_allclose(chain.level_coordinate(alphas[1:]), np.arange(1, len(alphas)), atol=1e-9)
    sweep = np.linspace(0.0, 1.0, 4001)
    x = chain.level_coordinate(sweep)
    assert x[0] == 0 and np.all(np.diff(x) >= -1e-12) and np.max(np.abs(np.diff(x))) < 0.1


@pytest.mark.parametrize("formulation, bound", [("operator", 0.01), ("fis", 0.02)])  # measured 5.1e-3, 7.9e-3
def test_sharp_level_prefilter_matches_exact_quadrature(formulation, bound):
    cube = _cubes()[0]
    # force the angular path (operator or FIS on the remainder + exact bright texels) at α = 0.144 on a 16² capture
    settings = ss.BandwidthChainSettings(face_size=FACE, max_sh_band=4, formulation=formulation)
    exact = ss._exact_prefilter_level(cube, 0.144, FACE)
    for s in (settings, ss.BandwidthChainSettings(face_size=FACE)):  # angular and SH-domain formulations
        level = ss.prefilter_level(cube, 0.144, FACE, s)
        assert np.sqrt(np.mean((level - exact) ** 2)) / exact.mean() < bound


def test_bandwidth_batch_is_bit_identical_to_each_probe_alone():
    settings = ss.BandwidthChainSettings(face_size=FACE, max_sh_band=4)  # several operator levels
    cubes = np.stack([*_cubes(), _cubes()[0] * 0.5]).astype(np.float32)
    cubes[1, 2, 3, 5] = 1e4  # a sun (bright texel, exact part) in one probe only
    batch = ss.prefilter_bandwidth_batch(cubes, settings, first_level=1)
    assert batch[0] is None
    for i in range(cubes.shape[0]):
        alone = ss.prefilter_bandwidth_chain(cubes[i], settings, first_level=1)
        for k in range(1, settings.n_levels):
            np.testing.assert_array_equal(alone[k], batch[k][i])


# ------------------------------------------------------------------------------------------------ the encoding
def test_layout_memory_and_first_level(hybrid):
    enc, fields = hybrid
    assert set(fields) == {s.name for s in enc.field_specs()}
    for spec in enc.field_specs():
        assert fields[spec.name].shape == (2, *spec.shape) and fields[spec.name].dtype == np.dtype(spec.dtype)
    assert enc.bytes_per_probe() == sum(fields[s.name][0].nbytes for s in enc.field_specs())
    assert np.all(fields["first_level"] == 0) and np.all(enc.upload_bytes(fields) == enc.bytes_per_probe())
    # a probe that sees only α ≥ 0.2 keeps the levels from the one at or below 0.2; only rough materials: none
    glossy = SHExpHybrid(face_size=FACE, alpha_min=0.2, **FAST)
    k0 = glossy.first_level
    assert glossy.chain.level_alphas()[k0] <= 0.2 < glossy.chain.level_alphas()[k0 + 1]
    rough = SHExpHybrid(face_size=FACE, alpha_min=0.9, **FAST)
    assert rough.first_level == rough.chain.n_levels and rough.model.alpha_min == 0.9
    encoded = rough.encode(ProbeBatch(_cubes()))
    # level 0 keeps the capture for exports (keep_capture, the default); every other level is zero, and none is
    # uploaded
    np.testing.assert_array_equal(encoded["level0"], _cubes().astype(np.float16))
    assert all(not np.any(encoded[f"level{k}"]) for k in range(1, rough.chain.n_levels))
    assert rough.upload_bytes(encoded)[0] == SHExpLights().bytes_per_probe() + 4
    unkept = SHExpHybrid(face_size=FACE, alpha_min=0.9, keep_capture=False, **FAST).encode(ProbeBatch(_cubes()))
    assert all(not np.any(unkept[f"level{k}"]) for k in range(rough.chain.n_levels))


def test_rough_only_probe_is_the_sh_exponential_with_lights():
    rough = SHExpHybrid(face_size=FACE, alpha_min=0.9, **FAST)
    fields = rough.encode(ProbeBatch(_cubes()))
    lights = SHExpLights(alpha_min=0.9, **FAST)
    v, n = _rows()
    a, f0 = np.full(len(v), 0.95), np.full(len(v), 0.04)
    np.testing.assert_allclose(rough.evaluate_reflection(fields, {}, v, n, a, f0),
                               lights.evaluate_reflection(lights.encode(ProbeBatch(_cubes())), {}, v, n, a, f0),
                               rtol=1e-6)


def test_constant_environment_identity_against_brute_force(hybrid):
    enc, fields = hybrid
    v, n = _rows()
    d = cube_texel_directions(48).reshape(-1, 3)
    samples = SphericalSamples(d, cube_texel_solid_angles(48).reshape(-1), np.full((len(d), 3), 0.7))
    for alpha in (0.0, 0.05, 0.144, 0.3, 0.6, 1.0):
        a = np.full(len(v), alpha)
        for f0 in (1.0, 0.04):
            out = enc.evaluate_reflection({k: x[1:2] for k, x in fields.items()}, {}, v, n, a, np.full(len(v), f0))[0]
            if alpha == 0.0:  # mirror: E = F(n·v) · c
                nv = np.sum(v * n, axis=1)[:, None]
                expected = 0.7 * (f0 + (1 - f0) * (1 - nv) ** 5)
                np.testing.assert_allclose(out, np.broadcast_to(expected, out.shape), rtol=0.03, atol=2e-3)
                continue
            e0, e1 = integrate_reflection(samples, v, n, a)
            np.testing.assert_allclose(out, reflected_radiance(e0, e1, np.full(len(v), f0)), rtol=3e-2)


def test_below_the_crossover_the_hybrid_is_the_exact_prefiltered_environment(hybrid):
    """α below both blends: E = c·(F0 A + B) with c the exactly prefiltered environment (v = n, any F0); α → 0:
    the capture itself."""
    enc, fields = hybrid
    cube = _cubes()[0]
    d = fibonacci_directions(200)
    level_alpha = float(enc.chain.level_alphas()[1])
    assert level_alpha < enc.blends[0][0] and level_alpha < enc.blends[1][0]
    parts = enc.evaluate_parts({k: x[:1] for k, x in fields.items()}, {}, d, d, np.full(len(d), level_alpha),
                               np.ones(len(d)))
    assert np.all(parts["w0"] == 1) and np.all(parts["w1"] == 1)
    exact = sample_cube_bilinear(ss._exact_prefilter_level(cube, level_alpha, FACE).astype(np.float32), d)
    from bakery.reflection.tables import lookup_table

    albedo = lookup_table(enc.shared_tables()["dfg"], np.ones(len(d)), np.full(len(d), level_alpha)).sum(axis=1)
    np.testing.assert_allclose(parts["E"][0], exact * albedo[:, None], rtol=0.02, atol=2e-3 * exact.mean())
    mirror = enc.evaluate_reflection({k: x[:1] for k, x in fields.items()}, {}, d, d, np.zeros(len(d)),
                                     np.ones(len(d)))[0]
    np.testing.assert_allclose(mirror, sample_cube_bilinear(cube.astype(np.float16).astype(np.float32), d),
                               rtol=2e-3)


def test_no_seam_at_the_crossover(hybrid):
    """E is continuous in α across both blends, within the stated bound
    |ΔE| ≤ |Δ chain| + |Δ sh| + 1.5 |Δ log2 α| / width · |chain − sh|."""
    enc, fields = hybrid
    v, n = _rows(24)
    alphas = np.geomspace(0.1, 1.0, 161)
    rows_v, rows_n = np.repeat(v, len(alphas), 0), np.repeat(n, len(alphas), 0)
    a = np.tile(alphas, len(v))
    for f0 in (1.0, 0.04):
        p = enc.evaluate_parts(fields, {}, rows_v, rows_n, a, np.full(len(a), f0))
        e, chain, sh = (p[k].reshape(2, len(v), len(alphas), 3) for k in ("E", "chain", "sh"))
        step = np.abs(np.diff(e, axis=2))
        dlog = np.diff(np.log2(alphas))[None, None, :, None]
        gap = np.maximum(np.abs(chain - sh)[:, :, 1:], np.abs(chain - sh)[:, :, :-1])
        bound = (np.abs(np.diff(chain, axis=2)) + np.abs(np.diff(sh, axis=2))
                 + 1.5 * dlog / enc.params.blend_octaves * gap)
        assert np.all(step <= bound + 1e-9)
        assert step.max() < 0.05 * np.abs(e).max()  # no visible jump at this step (Δ log2 α = 0.02)


def test_evaluation_below_the_stored_range_clamps():
    cubes = _cubes()
    glossy = SHExpHybrid(face_size=FACE, alpha_min=0.2, **FAST)
    fields = glossy.encode(ProbeBatch(cubes))
    k0 = glossy.first_level
    # level 0 holds the capture (kept for exports), but below first_level nothing is read: engines never upload it
    assert np.all(fields["first_level"] == k0) and k0 > 0 and np.any(fields["level0"])
    d = fibonacci_directions(64)
    sharp = glossy.evaluate_parts(fields, {}, d, d, np.zeros(len(d)), np.ones(len(d)))["chain"]
    at_level = glossy.evaluate_parts(fields, {}, d, d, np.full(len(d), glossy.chain.level_alphas()[k0]),
                                     np.ones(len(d)))["chain"]
    from bakery.reflection.tables import lookup_table

    dfg = glossy.shared_tables()["dfg"]
    ratio = (lookup_table(dfg, np.ones(1), np.zeros(1)).sum() /
             lookup_table(dfg, np.ones(1), np.full(1, glossy.chain.level_alphas()[k0])).sum())
    np.testing.assert_allclose(sharp, at_level * ratio, rtol=1e-6)  # the sharpest uploaded level, not level 0


def test_shexp_is_never_evaluated_outside_its_fitted_range():
    from bakery.reflection.shexp import clamped_pq, evaluate_pq

    enc = SHExp(alpha_min=0.3, **FAST)
    fields = enc.encode(ProbeBatch(_cubes()))
    np.testing.assert_allclose(fields["alpha_range"], [[0.3, 1.0]] * 2)
    v, n = _rows(16)
    coeffs = np.concatenate([fields["p"], fields["q"]], axis=1)
    np.testing.assert_allclose(clamped_pq(coeffs, v, n, np.zeros(16), enc.model, fields["alpha_range"]),
                               evaluate_pq(coeffs, v, n, np.full(16, 0.3), enc.model))
    assert np.all(np.isfinite(enc.evaluate_reflection(fields, {}, v, n, np.zeros(16), np.ones(16))))


def test_shexp_fit_floor_moved_from_the_pipeline_into_the_encoding():
    params = SHExp.Params(alpha_min=0.0, alpha_max=0.01)  # what pipeline/roughness.py passes for a mirror
    assert (params.alpha_min, params.alpha_max) == (0.05, 0.06)
    assert SHExp.Params(alpha_min=0.3).alpha_min == 0.3
    with pytest.raises(ValueError, match="alpha_min"):
        SHExp.Params(alpha_min=-0.1)
    assert SHExpHybrid.Params(alpha_min=0.0).alpha_min == 0.0  # the hybrid keeps the true minimum
    with pytest.raises(ValueError, match="tail_crossover"):
        SHExpHybrid.Params(crossover=0.5, tail_crossover=0.3)


# ------------------------------------------------------------------------------------------------ input rules
REFLECTION = [n for n, cls in ENCODINGS.items() if cls.kind == "reflection"]


def _small(name):
    cls = ENCODINGS[name]
    extra = {"face_size": FACE} if "face_size" in cls.Params.__dataclass_fields__ else {}
    extra.update({k: v for k, v in FAST.items() if k in cls.Params.__dataclass_fields__})
    if name == "splitsum":
        extra.update(n_levels=4, min_face_size=4)
    return cls(**extra)


@pytest.fixture(scope="module")
def every_reflection_encoding():
    return {name: (enc, enc.encode(ProbeBatch(_cubes()))) for name in REFLECTION for enc in [_small(name)]}


@pytest.mark.parametrize("name", REFLECTION)
@pytest.mark.parametrize("bad", [-0.1, 1.5, np.nan, np.inf])
def test_alpha_outside_zero_one_raises_naming_alpha(name, bad, every_reflection_encoding):
    enc, fields = every_reflection_encoding[name]
    v, n = _rows(4)
    with pytest.raises(ValueError, match="alpha"):
        enc.evaluate_reflection(fields, {}, v, n, np.array([0.5, bad, 0.5, 0.5]), np.ones(4))


@pytest.mark.parametrize("name", REFLECTION)
def test_views_below_the_horizon_are_clamped_to_it(name, every_reflection_encoding):
    enc, fields = every_reflection_encoding[name]
    n = fibonacci_directions(16)
    rng = np.random.default_rng(2)
    v = rng.normal(size=n.shape)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(np.sum(v * n, axis=1, keepdims=True) > 0, -v, v)  # all below the horizon
    v[0] = -n[0]  # n·v = −1: h_r was undefined before
    a, f0 = np.full(16, 0.4), np.full(16, 0.04)
    below = enc.evaluate_reflection(fields, {}, v, n, a, f0)
    assert np.all(np.isfinite(below)) and np.all(below >= 0)
    horizon = clamp_view_to_horizon(v, n)
    np.testing.assert_allclose(np.sum(horizon * n, axis=1), 1e-6, atol=1e-9)
    np.testing.assert_allclose(below, enc.evaluate_reflection(fields, {}, horizon, n, a, f0), rtol=1e-12)


def test_splitsum_accepts_the_whole_range_and_keeps_its_layout():
    enc = SplitSum(face_size=FACE, n_levels=4, min_face_size=4)
    fields = enc.encode(ProbeBatch(_cubes()))
    v, n = _rows(8)
    out = enc.evaluate_reflection(fields, {}, v, n, np.linspace(0, 1, 8), np.ones(8))
    assert np.all(np.isfinite(out))
    assert hy.chain_weight(np.array([0.0]), 0.3, 1.5)[0] == 1.0


# ------------------------------------------------------------------------------------------------ gap level
def _errors_against_the_exact_prefilter(encoders: dict, alpha: float) -> dict[str, float]:
    """Relative RMS error of each encoder's E at v = n, F0 = 1 and ``alpha`` (200 directions, the first test cube)
    against the capture prefiltered exactly at ``alpha`` × the DFG albedo (A + B)(1, α)."""
    from bakery.reflection.tables import lookup_table

    cube = _cubes()[0]
    d = fibonacci_directions(200)
    exact = sample_cube_bilinear(ss._exact_prefilter_level(cube, alpha, FACE).astype(np.float32), d)
    dfg = next(iter(encoders.values())).shared_tables()["dfg"]
    expected = exact * lookup_table(dfg, np.ones(len(d)), np.full(len(d), alpha)).sum(axis=1)[:, None]
    errors = {}
    for name, enc in encoders.items():
        got = enc.evaluate_reflection(enc.encode(ProbeBatch(cube[None])), {}, d, d, np.full(len(d), alpha),
                                      np.ones(len(d)))[0]
        errors[name] = float(np.sqrt(np.mean((got - expected) ** 2)) / np.sqrt(np.mean(expected**2)))
    return errors


def test_the_gap_level_halves_the_first_blend_and_is_the_exact_prefiltered_environment():
    """``gap_level``: one more level at α_1/2 at the capture's face, every other level unchanged; the runtime
    coordinate hits it (x = 1), stays monotone and continuous; at α = α_1/2 the hybrid is the environment
    prefiltered exactly at that α (× the DFG albedo), which the default chain only approximates by blending the
    capture with level 1."""
    plain = SHExpHybrid(face_size=FACE, **FAST)
    gap = SHExpHybrid(face_size=FACE, gap_level=True, **FAST)
    levels, with_gap = plain.chain.levels(), gap.chain.levels()
    assert with_gap == (levels[0], (round(levels[1][0] / 2, 6), FACE), *levels[1:])
    alphas = gap.chain.level_alphas()
    np.testing.assert_allclose(gap.chain.level_coordinate(alphas[1:]), np.arange(1, len(alphas)), atol=1e-9)
    x = gap.chain.level_coordinate(np.linspace(0.0, 1.0, 4001))
    assert x[0] == 0 and np.all(np.diff(x) >= -1e-12) and np.max(np.abs(np.diff(x))) < 0.1
    assert gap.bytes_per_probe() - plain.bytes_per_probe() == 6 * FACE * FACE * 3 * 2 + 4  # + gap_skipped

    errors = _errors_against_the_exact_prefilter({"plain": plain, "gap": gap}, float(alphas[1]))
    assert errors["gap"] < 2e-3, errors  # measured 2.5e-4 relative RMS (float16 levels, bilinear)
    assert errors["plain"] > 0.03, errors  # measured 9.4 %: the capture blended with level 1


def test_a_parameter_added_at_its_former_behaviour_keeps_earlier_hashes():
    """``gap_level`` false reproduces the chain from before the parameter existed, so the probes' content hash
    (``stable_hash`` of the resolved Params) must not change with it: a dataclass that gains such a field
    (``metadata={"hashed_at_default": False}``) hashes, at the field's default, as the same dataclass without it, and
    differently away from the default. Otherwise the next bake of a store baked before 2026-12-07 would re-bake
    every hybrid probe. (Checked by hand as well: the default Params hash the same at a0513f1 and here.)"""
    import dataclasses

    from bakery.files import stable_hash

    def params(with_field: bool):
        fields = [("face_size", int, dataclasses.field(default=64))]
        if with_field:
            fields.append(("gap_level", bool, dataclasses.field(default=False,
                                                                metadata={"hashed_at_default": False})))
        return dataclasses.make_dataclass("Params", fields, frozen=True)

    before, after = params(False), params(True)
    assert stable_hash(after()) == stable_hash(before())
    assert stable_hash(after(gap_level=True)) != stable_hash(before())
    default, on = SHExpHybrid.Params(), SHExpHybrid.Params(gap_level=True)
    assert stable_hash(default) != stable_hash(on)
    assert {f.name: f.metadata for f in dataclasses.fields(SHExpHybrid.Params)}["gap_level"] == {
        "hashed_at_default": False}


def test_a_skipped_gap_level_reads_as_the_chain_without_it():
    """A ``gap_level`` probe whose materials are a mirror and α ≥ α_2 only never reads level 1 (x(α) ∈ (0, 2) only for
    0 < α < α_2): it is skipped (``gap_skipped``, zero, not uploaded, not in the layer) and the probe evaluates
    exactly as the chain without ``gap_level`` at every α — the same stored levels, read at the same coordinates.
    A smallest non-zero α below α_2 keeps it."""
    plain = SHExpHybrid(face_size=FACE, **FAST)
    alpha_2 = float(SHExpHybrid(face_size=FACE, gap_level=True, **FAST).chain.level_alphas()[2])
    skipping = SHExpHybrid(face_size=FACE, gap_level=True, alpha_min_nonzero=alpha_2, **FAST)
    keeping = SHExpHybrid(face_size=FACE, gap_level=True, alpha_min_nonzero=0.99 * alpha_2, **FAST)
    assert skipping.gap_skipped and not keeping.gap_skipped
    assert not SHExpHybrid(face_size=FACE, gap_level=True, **FAST).gap_skipped  # unset: materials anywhere
    assert hy.gap_levels_skipped(skipping.chain.level_alphas(), 1, 0.0) == 0  # a material at α ≈ 0⁺ reads it
    cubes = _cubes()
    fields = {name: enc.encode(ProbeBatch(cubes)) for name, enc in
              (("plain", plain), ("skipping", skipping), ("keeping", keeping))}
    assert fields["skipping"]["gap_skipped"].tolist() == [[1], [1]]
    assert fields["keeping"]["gap_skipped"].tolist() == [[0], [0]] and "gap_skipped" not in fields["plain"]
    assert not np.any(fields["skipping"]["level1"])
    level_bytes = 6 * FACE * FACE * 3 * 2
    np.testing.assert_array_equal(skipping.upload_bytes(fields["skipping"]),
                                  keeping.upload_bytes(fields["keeping"]) - level_bytes)
    np.testing.assert_array_equal(skipping.upload_bytes(fields["skipping"]),
                                  plain.upload_bytes(fields["plain"]) + 4)  # + the gap_skipped word
    assert "level1" not in SHExpHybrid.layer_fields({k: v[:1] for k, v in fields["skipping"].items()})
    assert "level1" in SHExpHybrid.layer_fields({k: v[:1] for k, v in fields["keeping"].items()})

    v, n = _rows(64)
    alpha = np.concatenate([[0.0, 1e-4, 0.5 * alpha_2, 0.99 * alpha_2, alpha_2], np.linspace(0.0, 1.0, 59)])
    v, n = v[: len(alpha)], n[: len(alpha)]
    f0 = np.full(len(alpha), 0.04)
    e_plain = plain.evaluate_reflection(fields["plain"], plain.shared_tables(), v, n, alpha, f0)
    e_skip = skipping.evaluate_reflection(fields["skipping"], skipping.shared_tables(), v, n, alpha, f0)
    np.testing.assert_array_equal(e_skip, e_plain)
    e_keep = keeping.evaluate_reflection(fields["keeping"], keeping.shared_tables(), v, n, alpha, f0)
    reads_gap = (alpha > 0) & (alpha < alpha_2)
    np.testing.assert_allclose(e_keep[:, ~reads_gap], e_skip[:, ~reads_gap], rtol=1e-12)  # the same levels
    assert not np.allclose(e_keep[:, reads_gap], e_skip[:, reads_gap])


def test_two_gap_levels_add_alpha_1_over_4_and_skip_as_the_chains_with_fewer():
    """``gap_levels`` = 2: levels 1, 2 at α_1/4, α_1/2 (at the capture's face), every other level unchanged. At α_1/4
    the hybrid is the environment prefiltered exactly at that α (× the DFG albedo), which one gap level only
    approximates by blending the capture with α_1/2. A mirror probe whose other materials have α ≥ α_2 (= α_1/2)
    skips level 1 and evaluates bit for bit as the one-gap-level chain; with α ≥ α_3 (= α_1) it skips both and
    evaluates as the chain without gap levels (the same stored levels read at the same coordinates)."""
    plain = SHExpHybrid(face_size=FACE, **FAST)
    one = SHExpHybrid(face_size=FACE, gap_level=True, **FAST)
    two = SHExpHybrid(face_size=FACE, gap_level=True, gap_levels=2, **FAST)
    levels, alphas = plain.chain.levels(), two.chain.level_alphas()
    assert two.chain.levels() == (levels[0], (round(levels[1][0] / 4, 6), FACE), (round(levels[1][0] / 2, 6), FACE),
                                  *levels[1:])
    np.testing.assert_allclose(two.chain.level_coordinate(alphas[1:]), np.arange(1, len(alphas)), atol=1e-9)
    level_bytes = 6 * FACE * FACE * 3 * 2
    assert two.bytes_per_probe() - one.bytes_per_probe() == level_bytes

    errors = _errors_against_the_exact_prefilter({"one": one, "two": two}, float(alphas[1]))
    assert errors["two"] < 2e-3, errors  # float16 levels, bilinear
    assert errors["one"] > 5 * errors["two"], errors  # measured 1.7e-4 and 3.1 % relative RMS

    skip_one = SHExpHybrid(face_size=FACE, gap_level=True, gap_levels=2, alpha_min_nonzero=float(alphas[2]), **FAST)
    skip_two = SHExpHybrid(face_size=FACE, gap_level=True, gap_levels=2, alpha_min_nonzero=float(alphas[3]), **FAST)
    keep = SHExpHybrid(face_size=FACE, gap_level=True, gap_levels=2, alpha_min_nonzero=0.99 * float(alphas[2]),
                       **FAST)
    assert (keep.gap_skipped, skip_one.gap_skipped, skip_two.gap_skipped) == (0, 1, 2)
    cubes = _cubes()
    encoders = {"plain": plain, "one": one, "skip_one": skip_one, "skip_two": skip_two}
    fields = {name: enc.encode(ProbeBatch(cubes)) for name, enc in encoders.items()}
    assert fields["skip_one"]["gap_skipped"].tolist() == [[1], [1]]
    assert fields["skip_two"]["gap_skipped"].tolist() == [[2], [2]]
    assert not np.any(fields["skip_one"]["level1"]) and np.any(fields["skip_one"]["level2"])
    assert not np.any(fields["skip_two"]["level1"]) and not np.any(fields["skip_two"]["level2"])
    upload = {name: enc.upload_bytes(fields[name]) for name, enc in encoders.items()}
    np.testing.assert_array_equal(upload["skip_one"], upload["one"])
    np.testing.assert_array_equal(upload["skip_two"], upload["plain"] + 4)  # + the gap_skipped word
    assert {"level1", "level2"} & set(SHExpHybrid.layer_fields({k: v[:1] for k, v in fields["skip_two"].items()})) \
        == set()
    assert "level2" in SHExpHybrid.layer_fields({k: v[:1] for k, v in fields["skip_one"].items()})

    v, n = _rows(64)
    alpha = np.concatenate([[0.0, 1e-4, *alphas[1:4], 0.5 * alphas[2]], np.linspace(0.0, 1.0, 58)])
    v, n, f0 = v[: len(alpha)], n[: len(alpha)], np.full(len(alpha), 0.04)
    e = {name: enc.evaluate_reflection(fields[name], enc.shared_tables(), v, n, alpha, f0)
         for name, enc in encoders.items()}
    np.testing.assert_array_equal(e["skip_one"], e["one"])
    np.testing.assert_array_equal(e["skip_two"], e["plain"])


def test_skipping_s_of_three_gap_levels_evaluates_as_three_minus_s():
    """``gap_levels`` = 3: levels 1–3 at α_1/8, α_1/4, α_1/2. A mirror probe whose other materials all have
    α ≥ α_{s+1} skips gap levels 1 … s and evaluates bit for bit as the chain with 3 − s gap levels (3 − s = 0:
    without gap levels), uploading the same bytes (+ the ``gap_skipped`` word against the chain without any)."""
    three = SHExpHybrid(face_size=FACE, gap_level=True, gap_levels=3, **FAST)
    alphas = three.chain.level_alphas()
    first = SHExpHybrid(face_size=FACE, **FAST).chain.level_alphas()[1]
    np.testing.assert_allclose(alphas[1:4], [first / 8, first / 4, first / 2], rtol=1e-4)  # stored to 6 digits
    cubes = _cubes()
    v, n = _rows(64)
    alpha = np.concatenate([[0.0, 1e-4, *alphas[1:5], 0.5 * alphas[1]], np.linspace(0.0, 1.0, 57)])
    v, n, f0 = v[: len(alpha)], n[: len(alpha)], np.full(len(alpha), 1.0)
    for skipped in (1, 2, 3):
        skipping = SHExpHybrid(face_size=FACE, gap_level=True, gap_levels=3,
                               alpha_min_nonzero=float(alphas[skipped + 1]), **FAST)
        fewer = (SHExpHybrid(face_size=FACE, gap_level=True, gap_levels=3 - skipped, **FAST) if skipped < 3
                 else SHExpHybrid(face_size=FACE, **FAST))
        assert skipping.gap_skipped == skipped
        fields = {"skipping": skipping.encode(ProbeBatch(cubes)), "fewer": fewer.encode(ProbeBatch(cubes))}
        e_skipping = skipping.evaluate_reflection(fields["skipping"], skipping.shared_tables(), v, n, alpha, f0)
        e_fewer = fewer.evaluate_reflection(fields["fewer"], fewer.shared_tables(), v, n, alpha, f0)
        np.testing.assert_array_equal(e_skipping, e_fewer)
        np.testing.assert_array_equal(skipping.upload_bytes(fields["skipping"]),
                                      fewer.upload_bytes(fields["fewer"]) + (4 if skipped == 3 else 0))


@pytest.mark.parametrize("value", [0, 5, True, 1.5])
def test_gap_levels_outside_one_to_four_is_refused(value):
    from bakery.encodings.base import ParamsError

    with pytest.raises(ParamsError, match="gap_levels"):
        SHExpHybrid.Params(gap_level=True, gap_levels=value)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=6))
def test_the_smallest_non_zero_alpha_is_never_above_the_true_one_and_at_most_a_quarter_octave_below(roughness):
    """Bucketed down: a probe may keep a gap level none of its materials reads, never skip one that one reads
    (6 decimals: within 1e-6)."""
    from bakery.pipeline.roughness import smallest_nonzero_alpha

    got = smallest_nonzero_alpha(roughness)
    nonzero = [r for r in roughness if r > 0.0]
    if not nonzero:
        assert got is None
        return
    alpha = min(nonzero) ** 2
    assert got <= alpha + 5e-7
    assert got >= alpha * 2.0**-0.25 - 1e-6


def test_the_pipeline_tells_the_hybrid_the_smallest_non_zero_alpha_only_where_it_matters():
    """``probe_alpha_overrides``: the range for every ranged encoding; ``alpha_min_nonzero`` for the hybrid only with
    ``gap_level`` and a mirror in range (elsewhere it would change the probes' hash and nothing else);
    ``smallest_nonzero_alpha`` buckets down (never above the true α; property test below)."""
    from bakery.pipeline.roughness import smallest_nonzero_alpha

    assert smallest_nonzero_alpha([0.0, 0.25, 0.7]) == 0.0625  # α = 2^−4: on a quarter-octave bucket
    assert smallest_nonzero_alpha([0.0, 0.3, 0.7]) == 0.09  # the range's bucket (r = 0.3) is finer here
    assert smallest_nonzero_alpha([0.0, 0.15]) == pytest.approx(2.0**-5.5, abs=1e-6)  # α 0.0225; range bucket: 0.01
    assert smallest_nonzero_alpha([0.0]) is None and smallest_nonzero_alpha([]) is None
    on, off = SHExpHybrid.Params(gap_level=True), SHExpHybrid.Params()
    assert SHExpHybrid.probe_alpha_overrides(on, (0.0, 1.0), 0.04) == {
        "alpha_min": 0.0, "alpha_max": 1.0, "alpha_min_nonzero": 0.04}
    assert SHExpHybrid.probe_alpha_overrides(off, (0.0, 1.0), 0.04) == {"alpha_min": 0.0, "alpha_max": 1.0}
    assert SHExpHybrid.probe_alpha_overrides(on, (0.04, 1.0), 0.04) == {"alpha_min": 0.04, "alpha_max": 1.0}
    assert SHExp.probe_alpha_overrides(SHExp.Params(), (0.0, 1.0), 0.04) == {"alpha_min": 0.0, "alpha_max": 1.0}
    from bakery.encodings.base import ParamsError

    with pytest.raises(ParamsError, match="alpha_min_nonzero"):
        SHExpHybrid.Params(alpha_min=0.1, alpha_min_nonzero=0.05)
