"""Smoke test of the SH-exp fit bench (bakery.bench.shexp_fit) on a tiny batch: the result's layout, that the fused
and step-by-step fits agree, and that the bake configuration runs its workers (no timing asserted)."""

from bakery.bench.shexp_fit import run_shexp_fit_bench


def test_bench_reports_both_formulations_pieces_and_the_bake_configuration():
    lines = []
    result = run_shexp_fit_bench(batch_size=2, face_size=16, repeats=5, echo=lines.append, processes=2)
    for entry in result["variants"].values():
        assert entry["fused_ms_per_probe"] > 0 and entry["fused_cpu_ms_per_probe"] > 0
        assert entry["rel_rms_e0_difference"] < 1e-4  # same least squares, float32 rounding
    assert set(result["fused_breakdown_ms_per_probe"]) == {"splat", "W_times_F_tiles", "W_times_F_dense", "rest"}
    bake = result["bake_configuration"]
    assert bake["processes"] == 2 and bake["ms_per_probe"] >= bake["min_ms_per_probe"] > 0
    assert bake["cpu_ms_per_probe_per_worker"] > 0
    assert "bake configuration, 2 single-threaded processes" in lines[0]
