"""The fused SH-exp fit (:func:`bakery.reflection.shexp.fit_shexp`) against an independent, straightforward float64
evaluation of the same least squares: dense splat einsums, E0 = W·F, the guarded log, the luminance weights and a
per-probe lstsq — and against the step-by-step batched fit it replaces."""

from dataclasses import replace

import numpy as np
import pytest

from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.reflection import shexp as sx
from bakery.sphere.cubemap import cube_texel_directions, cube_texel_solid_angles

SMALL = sx.SHExpSettings(n_normals=24, n_views=24, n_alphas=4, fit_face_size=16)
FACE = 32


def captures(n=FACE):
    """Three probes: sky + 5e4 sun, sky alone, a dim sky with a weak sun and a black lower hemisphere."""
    d = cube_texel_directions(n)
    sky = np.where(d[..., 1:2] > 0, (0.4 + 0.6 * d[..., 1:2]) * np.array([0.3, 0.5, 1.0]), [0.2, 0.15, 0.1])
    sun_dir = np.array([0.4, 0.7, 0.59]) / np.linalg.norm([0.4, 0.7, 0.59])
    sun = np.unravel_index(np.argmax(d @ sun_dir), d.shape[:3])
    a, b, c = sky.copy(), sky.copy(), 0.3 * sky
    a[sun] = 5e4 * np.array([1.0, 0.9, 0.8])
    c[sun] = 10.0
    c[d[..., 1] < 0] = 0.0
    return np.stack([a, b, c]).astype(np.float32)


def straightforward_fit(cubes: np.ndarray, settings: sx.SHExpSettings) -> np.ndarray:
    """[p; q] = argmin Σ_m w_m (A_m x − log max(E0_m, floor) + log a_m)², everything in float64, one probe at a time."""
    ops = sx.build_operators(settings, cubes.shape[2])
    n = cubes.shape[2]
    omega = cube_texel_solid_angles(n)[0]
    flux = {}
    finest = max(b.face_size for b in ops.blocks)
    bf = sx.splat_matrix(n, finest).astype(np.float64)
    fine = np.einsum("ai,bj,ij,pfijc->pfabc", bf, bf, omega, cubes.astype(np.float64))  # Σ b_ct Ω_t L_t
    for g in {b.face_size for b in ops.blocks}:
        bc = sx.splat_matrix(finest, g).astype(np.float64)
        flux[g] = fine if g == finest else np.einsum("ai,bj,pfijc->pfabc", bc, bc, fine)
    out = []
    for p in range(cubes.shape[0]):
        e0 = np.concatenate([b.weights.astype(np.float64) @ flux[b.face_size][p].reshape(-1, 3) for b in ops.blocks])
        floor = max(sx.EPS_REL * e0.mean(), sx.EPS_ABS)
        target = np.log(np.maximum(e0, floor)) - ops.log_albedo.astype(np.float64)[:, None]
        design = ops.design.astype(np.float64)
        if settings.fit == "weighted":
            lum = e0 @ LUMINANCE_WEIGHTS
            root = np.sqrt(lum / max(lum.mean(), sx.EPS_ABS) + sx.WEIGHT_MIN)[:, None]
            design, target = design * root, target * root
        out.append(np.linalg.lstsq(design, target, rcond=None)[0])
    return np.stack(out)


@pytest.mark.parametrize("model", [SMALL, replace(SMALL, fit="log"), replace(SMALL, albedo_normalized=False)],
                         ids=["weighted", "log", "paper"])
def test_fused_fit_equals_a_straightforward_least_squares(model):
    """Same coefficients and E0 to float32 rounding (the 5e4 sun makes the weighted Gram ill-conditioned: ~1e-4
    relative on the coefficients; see tests/encodings/test_reflection_shexp.py)."""
    cubes = captures()
    fused = sx.fit_shexp(cubes, model)
    truth = straightforward_fit(cubes, model)
    assert fused.dtype == np.float32 and fused.shape == truth.shape
    np.testing.assert_allclose(fused, truth, rtol=1e-3, atol=1e-3)
    v, n, a = sx.fit_design(model)
    np.testing.assert_allclose(sx.evaluate_e0(fused, v, n, a, model), sx.evaluate_e0(truth, v, n, a, model),
                               rtol=2e-3, atol=1e-9)


@pytest.mark.parametrize("model", [SMALL, replace(SMALL, fit="log")], ids=["weighted", "log"])
def test_fused_fit_equals_the_stepwise_fit_and_is_no_further_from_float64(model):
    """The fused fit reorders float32 sums only: it matches the step-by-step batched fit to float32 rounding of the
    ill-conditioned weighted Gram (measured 5e-4 with the 5e4 sun, 1e-5 unweighted), and is at least as close to
    the float64 least squares (measured 2e-4 vs 4e-4)."""
    cubes = captures()
    fused, stepwise = sx.fit_shexp(cubes, model), sx.fit_shexp_stepwise(cubes, model)
    np.testing.assert_allclose(fused, stepwise, rtol=1e-3, atol=1e-3)
    truth = straightforward_fit(cubes, model)
    assert np.abs(fused - truth).max() <= 1.05 * np.abs(stepwise - truth).max() + 1e-6


def test_fused_fit_chunking_does_not_change_the_result(monkeypatch):
    """Row chunks of 64 (many chunks, a partial last one) give the same coefficients as one chunk per block, to the
    float32 rounding of the summation order (1e-3 with the 5e4 sun's ill-conditioned Gram, 1e-4 without)."""
    cubes = captures()
    whole = sx.fit_shexp(cubes, SMALL)
    monkeypatch.setattr(sx, "_CHUNK_FLOATS", 64 * 3 * cubes.shape[0] + 5)
    chunked = sx.fit_shexp(cubes, SMALL)
    np.testing.assert_allclose(chunked, whole, rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(chunked[1:], whole[1:], rtol=1e-4, atol=1e-4)


def test_fused_fit_with_removed_texels_equals_fitting_the_blacked_out_capture():
    cubes = captures()
    probe, texel = np.array([0, 0, 2]), np.array([5, 6 * FACE * FACE - 1, 100])
    black = cubes.copy().reshape(3, -1, 3)
    black[probe, texel] = 0.0
    np.testing.assert_allclose(sx.fit_shexp(cubes, SMALL, (probe, texel)),
                               sx.fit_shexp(black.reshape(cubes.shape), SMALL), rtol=1e-4, atol=1e-4)


def test_weight_tiles_partition_the_design_and_drop_only_zeros():
    """The normal-cluster tiles of the fused W·F cover every design row once, hold W's entries exactly, and every
    node they leave out of a row is an exact zero of W (the lower hemisphere of its normal, ⟨l, n⟩ ≤ 0)."""
    ops = sx.build_operators(sx.SHExpSettings(), 128)
    rows = np.concatenate([t.rows for t in ops.tiles] + [s.rows for s in ops.low_rank])
    assert np.array_equal(np.sort(rows), np.arange(ops.design.shape[0]))  # with the low-rank slabs: every row once
    v, n, _ = sx.fit_design(sx.SHExpSettings())
    for tile in ops.tiles:
        block = next(b for b in ops.blocks if b.start <= tile.rows[0] < b.stop)
        dense = block.weights[tile.rows - block.start]
        assert np.array_equal(dense[:, tile.nodes], tile.weights)
        left_out = np.setdiff1d(np.arange(dense.shape[1]), tile.nodes)
        assert not dense[:, left_out].any()
        nodes = cube_texel_directions(tile.face_size).reshape(-1, 3)[left_out]
        assert (n[tile.rows] @ nodes.T).max(initial=-1.0) <= 1e-6  # only below every row's horizon
        np.testing.assert_array_equal(tile.design_t, ops.design_t[:, tile.rows])
    dense_macs = sum(b.weights.size for b in ops.blocks)
    tiled = {int(r) for t in ops.tiles for r in t.rows}
    assert sum(t.weights.size for t in ops.tiles) < 0.65 * sum(b.weights[0].size for b in ops.blocks
                                                             for r in range(b.start, b.stop) if r in tiled)
    assert sum(t.weights.size for t in ops.tiles) < 0.65 * dense_macs


def test_low_rank_slab_is_the_alpha_one_kernel_to_its_tolerance():
    """At α = 1, D = 1/π and Smith's V = ½/(n·l + n·v): W = ⟨n, l⟩₊ / (2π (n·l + n·v)) per steradian (closed
    form).
    The default design factors exactly that slab, per normal to ‖ΔW_k‖_F ≤ 1e-7 ‖W_k‖_F (plus the float32
    rounding of the factors), at a fraction of its tiles' multiply-adds; the α < 1 slabs stay in the tiles."""
    settings = sx.SHExpSettings()
    ops = sx.build_operators(settings, 128)
    v, n, a = sx.fit_design(settings)
    (slab,) = ops.low_rank
    assert np.all(a[slab.rows] == 1.0) and slab.rows.size == settings.n_normals * settings.n_views
    nodes = cube_texel_directions(slab.face_size).reshape(-1, 3)
    nl = np.maximum(n[slab.rows] @ nodes.T, 0.0)
    nv = np.sum(n[slab.rows] * v[slab.rows], axis=1)[:, None]
    closed = nl / (2.0 * np.pi * (nl + nv))  # (R, 6g²)
    factored = np.matmul(slab.left.astype(np.float64),
                         slab.right.astype(np.float64).reshape(settings.n_normals, slab.rank, -1)).reshape(closed.shape)
    for k in range(settings.n_normals):
        rows = slice(k * settings.n_views, (k + 1) * settings.n_views)
        assert np.linalg.norm(factored[rows] - closed[rows]) <= 5e-7 * np.linalg.norm(closed[rows])
    assert slab.rank <= 16
    tile_macs = slab.rows.size * nodes.shape[0] / 2  # a normal's hemisphere
    assert slab.left.size + slab.right.size < 0.5 * tile_macs


def test_fused_fit_with_a_low_rank_slab_equals_a_straightforward_least_squares():
    """The default design (its α = 1 slab factored) against the float64 least squares on the exact W."""
    settings = sx.SHExpSettings()
    assert sx.build_operators(settings, FACE).low_rank
    cubes = captures()
    fused, truth = sx.fit_shexp(cubes, settings), straightforward_fit(cubes, settings)
    np.testing.assert_allclose(fused, truth, rtol=1e-3, atol=1e-3)
    v, n, a = sx.fit_design(settings)
    np.testing.assert_allclose(sx.evaluate_e0(fused, v, n, a, settings), sx.evaluate_e0(truth, v, n, a, settings),
                               rtol=2e-3, atol=1e-9)


def test_weight_tiles_are_shared_through_the_operator_cache(tmp_path, monkeypatch):
    """A bake's workers map one copy of the tiles' W from the on-disk operator cache: the first build writes it,
    the next loads the same entries, and a different tile layout is its own entry."""
    from bakery import operator_cache
    from bakery.reflection.tables import OperatorCache

    ops = sx.build_operators(SMALL, FACE)
    monkeypatch.setenv("BAKERY_CACHE_DIR", str(tmp_path))  # an empty cache from here on
    monkeypatch.setattr(OperatorCache, "load", staticmethod(operator_cache.load))
    monkeypatch.setattr(OperatorCache, "save", staticmethod(operator_cache.save))
    first = sx.weight_tiles(SMALL, ops.blocks, ops.design_t, ops.pinv)
    files = sorted(tmp_path.glob("*.npy"))
    assert len(files) == 1
    again = sx.weight_tiles(SMALL, ops.blocks, ops.design_t, ops.pinv)
    assert sorted(tmp_path.glob("*.npy")) == files
    for a, b, reference in zip(first, again, ops.tiles, strict=True):
        assert np.array_equal(a.weights, b.weights) and np.array_equal(a.weights, reference.weights)
        assert np.array_equal(a.nodes, reference.nodes) and np.array_equal(a.rows, reference.rows)
    monkeypatch.setattr(sx, "NORMALS_PER_TILE", 3)
    other = sx.weight_tiles(SMALL, ops.blocks, ops.design_t, ops.pinv)
    assert len(list(tmp_path.glob("*.npy"))) == 2 and len(other) != len(first)


def test_low_rank_decisions_and_factors_are_shared_through_the_operator_cache(tmp_path, monkeypatch):
    """One cache entry per α slab — the factors, or the decision to keep the slab in the tiles — written by the
    first build and loaded by the next."""
    from bakery import operator_cache
    from bakery.reflection.tables import OperatorCache

    settings = replace(SMALL, n_views=64, n_normals=16)
    ops = sx.build_operators(settings, FACE)
    monkeypatch.setenv("BAKERY_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(OperatorCache, "load", staticmethod(operator_cache.load))
    monkeypatch.setattr(OperatorCache, "save", staticmethod(operator_cache.save))
    first = sx.low_rank_slabs(settings, ops.blocks, ops.design_t, ops.pinv)
    files = sorted(tmp_path.glob("*.npy"))
    assert len(files) == settings.n_alphas
    again = sx.low_rank_slabs(settings, ops.blocks, ops.design_t, ops.pinv)
    assert sorted(tmp_path.glob("*.npy")) == files
    assert [s.rows[0] for s in first] == [s.rows[0] for s in again] == [s.rows[0] for s in ops.low_rank]
    for a, b in zip(first, again, strict=True):
        assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
