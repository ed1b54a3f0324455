"""The reflection bench end to end on one real environment (small grid, few pixels): every α band, view elevation
and reflection encoding is scored, the headline table is printed, and unmeasured figures are never shown."""

import json
import shutil

import pytest

from bakery.bench.reflection import (
    ALPHAS,
    ELEVATIONS,
    HYBRID,
    IDEAL,
    PLAIN,
    format_headline,
    run_reflection_bench,
)


@pytest.mark.slow
def test_bench_writes_and_prints_the_per_alpha_table(shared_data, tmp_path):
    env = shared_data / "hdri" / "polyhaven_1k" / "city.hdr"
    if not env.is_file():
        pytest.skip("city.hdr not present")
    (tmp_path / "env").mkdir()
    shutil.copy(env, tmp_path / "env" / env.name)
    printed = []
    result = run_reflection_bench(tmp_path / "env", tmp_path / "out", face_size=16, sphere_resolution=4,
                                  plain_splitsum=False, echo=printed.append)
    summary = result["summary"]
    assert summary["cases"] == 1 * 2 * len(ELEVATIONS) * len(ALPHAS)  # env × materials × views × α
    assert min(ALPHAS) == 0.0 and {0.04, 0.0625, 0.1, 0.16, 0.25, 1.0} <= set(ALPHAS)
    assert min(ELEVATIONS) == -30.0 and max(ELEVATIONS) == 85.0
    assert result["bytes_per_probe"]["shexp"] == 404
    assert PLAIN not in result["protocol"]["scored"] and HYBRID in result["protocol"]["scored"]
    for band in summary["by_band"].values():
        for key in result["protocol"]["scored"]:
            assert 0.0 <= band[key]["win_share"] <= 1.0 and band[key]["geomean_ratio_vs_splitsum"] > 0
    data = json.loads((tmp_path / "out" / "reflection.json").read_text())
    assert len(data["rows"]) == summary["cases"]
    assert all(r["mse_shexp_hybrid"] >= 0 and r[f"mse_{IDEAL}"] >= 0 for r in data["rows"])
    headline = printed[0]
    assert headline == format_headline(result) and "| α < 0.1 |" in headline and "splitsum_plain" not in headline
    assert "| city |" in (tmp_path / "out" / "reflection.md").read_text()
    # a second run reads the reference from the cache
    assert any((tmp_path / "out" / "reference-cache").iterdir())


def test_the_bench_and_the_report_share_the_converged_reference(tmp_path, monkeypatch):
    """One reference, one place: the bench's cached reference is the report's, at the mirror and at every α; its
    cache key carries the reference method's version (caches of the texel-centre reference are not reused)."""
    import numpy as np

    import bakery.bench.reflection as bench
    from bakery.environment.io import read_environment, write_exr
    from bakery.environment.reflection_reference import CubeTexels, cube_prefiltered
    from bakery.environment.resample import environment_samples
    from bakery.reflection.reference import REFERENCE_METHOD_VERSION
    from bakery.report.quality import CaptureReference, reference_reflection
    from bakery.sphere.cubemap import sample_cube_bilinear

    pixels = np.ones((16, 32, 3), np.float32)
    pixels[5, 11] = (900.0, 800.0, 700.0)
    write_exr(tmp_path / "sky.exr", pixels, half=False)
    image = read_environment(tmp_path / "sky.exr")[0]
    alphas = (0.0, 0.05, 0.5)
    view, normal, alpha, _ = bench.bench_rows(4, alphas=alphas, elevations=(0.0, 60.0))
    e0, e1 = bench.reference_e0_e1(tmp_path / "sky.exr", image, view, normal, alpha, tmp_path / "cache")
    (cached,) = (tmp_path / "cache").iterdir()
    assert cached.name.startswith(f"sky-v{REFERENCE_METHOD_VERSION}-")
    capture = CaptureReference(image, environment_samples(image))
    for a in alphas:
        rows = alpha == a
        r0, r1 = reference_reflection(capture, view[rows], normal[rows], a)
        np.testing.assert_allclose(e0[rows], r0, rtol=1e-12)
        np.testing.assert_allclose(e1[rows], r1, rtol=1e-12)

    def recomputed(*args, **kwargs):  # noqa: ANN002, ANN003
        raise AssertionError("the cached reference was not read")

    monkeypatch.setattr(bench, "environment_reflection", recomputed)
    again = bench.reference_e0_e1(tmp_path / "sky.exr", image, view, normal, alpha, tmp_path / "cache")
    np.testing.assert_array_equal(again[0], e0)
    # the idealised split-sum: the converged kernel at α > 0, bilinear in the capture at α = 0
    cube = np.random.default_rng(1).uniform(0.5, 2.0, (6, 8, 8, 3)).astype(np.float32)
    r = normal[:6]
    a = np.array([0.0, 0.0, 0.05, 0.05, 0.3, 0.3])
    ideal = bench.ideal_split_sum(cube, r, a)
    np.testing.assert_allclose(ideal[:2], sample_cube_bilinear(cube, r[:2]))
    for k in (2, 4):
        np.testing.assert_allclose(ideal[k : k + 2], cube_prefiltered(CubeTexels(cube), r[k : k + 2], a[k]))


def test_a_damaged_reference_cache_file_is_recomputed_not_used(tmp_path, monkeypatch):
    """Verify before reuse: a cache file whose values were altered (header intact), one cut short, and one without
    the recorded checksum are each recomputed and replaced; the verified file is then read without recomputing."""
    import numpy as np

    import bakery.bench.reflection as bench
    from bakery.environment.io import read_environment, write_exr

    pixels = np.ones((8, 16, 3), np.float32)
    pixels[2, 5] = (50.0, 40.0, 30.0)
    write_exr(tmp_path / "sky.exr", pixels, half=False)
    image = read_environment(tmp_path / "sky.exr")[0]
    view, normal, alpha, _ = bench.bench_rows(3, alphas=(0.0, 0.3), elevations=(30.0,))
    calls = []
    real = bench.environment_reflection

    def counted(*args):  # noqa: ANN002
        calls.append(1)
        return real(*args)

    monkeypatch.setattr(bench, "environment_reflection", counted)
    e0, e1 = bench.reference_e0_e1(tmp_path / "sky.exr", image, view, normal, alpha, tmp_path / "cache")
    (cached,) = (tmp_path / "cache").iterdir()
    good = cached.read_bytes()

    def altered(path):
        with np.load(path) as z:
            np.savez(path, e0=z["e0"] * 1.01, e1=z["e1"], sha256=z["sha256"])

    def truncated(path):
        path.write_bytes(good[: len(good) // 2])

    def unrecorded(path):
        np.savez(path, e0=e0, e1=e1)

    for damage in (altered, truncated, unrecorded):
        cached.write_bytes(good)
        damage(cached)
        before = len(calls)
        again = bench.reference_e0_e1(tmp_path / "sky.exr", image, view, normal, alpha, tmp_path / "cache")
        assert len(calls) == before + 1, damage.__name__
        np.testing.assert_array_equal(again[0], e0)
        np.testing.assert_array_equal(again[1], e1)
        replaced = bench._verified_reference(cached, len(view))  # replaced by the recomputed, verified file
        assert replaced is not None, damage.__name__
        np.testing.assert_array_equal(replaced[0], e0)
    before = len(calls)
    bench.reference_e0_e1(tmp_path / "sky.exr", image, view, normal, alpha, tmp_path / "cache")
    assert len(calls) == before and [p.name for p in (tmp_path / "cache").iterdir()] == [cached.name]


def test_the_bench_scores_the_hybrid_with_the_gap_levels_asked_for():
    """``bakery bench reflection --gap-level --gap-levels G`` scores ``shexp_hybrid`` with G gap levels (recorded in
    ``reflection.json``'s settings); without ``--gap-level``, with the encoding's defaults."""
    from bakery.bench.reflection import _encoders

    default, two = _encoders(16)[HYBRID], _encoders(16, hybrid_gap_levels=2)[HYBRID]
    assert not default.params.gap_level
    assert two.params.gap_level and two.params.gap_levels == 2
    assert two.settings["level_alphas"][1] == pytest.approx(default.settings["level_alphas"][1] / 4, rel=1e-4)
