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
