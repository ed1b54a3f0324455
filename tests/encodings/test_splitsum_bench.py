"""Smoke test of the split-sum prefilter bench (bakery.bench.splitsum) on a tiny grid: the result's layout and that
the operator formulation is at least as accurate as FIS on a real environment with a sun (no timing asserted)."""

from pathlib import Path

from bakery.bench.splitsum import run_splitsum_bench

STINSON = Path(__file__).resolve().parents[2] / "examples" / "data" / "StinsonBeach_512.hdr"


def test_bench_reports_speed_operators_and_errors_for_both_formulations():
    lines = []
    result = run_splitsum_bench(face_size=16, env_paths=[STINSON], batch_sizes=(1, 2), repeats=1, error_texels=64,
                                chains=("split_sum_chain",), echo=lines.append)
    entry = result["chains"]["split_sum_chain"]
    assert set(entry["speed"]) == {"operator", "fis"} and set(entry["speed"]["operator"]) == {"1", "2"}
    (op,) = entry["operators"]
    assert op["rows_all_faces"] == 6 * 16 * 16 and op["nnz"] > 0 and op["build_cold_s"] >= 0
    errors = entry["errors"]
    assert errors["operator"]["level1"]["StinsonBeach_512"] < errors["fis"]["level1"]["StinsonBeach_512"]
    assert "rel. MSE" in lines[0] and result["cmft"]["note"]
