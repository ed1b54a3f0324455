"""The reflection bench end to end on one real environment (small grid, few pixels)."""

import json
import shutil

import pytest

from bakery.bench.reflection import run_reflection_bench


@pytest.mark.slow
def test_bench_writes_quality_table(shared_data, tmp_path):
    env = shared_data / "hdri" / "polyhaven_1k" / "city.hdr"
    if not env.is_file():
        pytest.skip("city.hdr not present")
    (tmp_path / "env").mkdir()
    shutil.copy(env, tmp_path / "env" / env.name)
    result = run_reflection_bench(tmp_path / "env", tmp_path / "out", face_size=32, sphere_resolution=6,
                                  plain_splitsum=False)
    summary = result["summary"]
    assert summary["cases"] == 1 * 2 * 2 * 6  # env × materials × views × α
    assert summary["bytes_per_probe"]["shexp"] == 396
    assert summary["memory_ratio"] > 100
    data = json.loads((tmp_path / "out" / "reflection.json").read_text())
    assert len(data["rows"]) == summary["cases"]
    assert all(r["mse_shexp"] >= 0 and r["mse_splitsum"] >= 0 for r in data["rows"])
    assert "| city |" in (tmp_path / "out" / "reflection.md").read_text()
