"""`bakery bench scale --repeats`: alternating repetitions, each worker count reported by its median trial."""

from bakery.bench.scale import _median_run, run_scale_bench


def test_median_run_is_the_middle_trial_and_keeps_every_wall():
    trials = [{"wall_seconds": w, "tag": t} for w, t in ((3.0, "a"), (1.0, "b"), (2.0, "c"), (5.0, "d"))]
    run = _median_run(trials)
    assert run["tag"] == "c"  # sorted 1, 2, 3, 5: the lower middle of an even count
    assert run["wall_seconds_runs"] == [3.0, 1.0, 2.0, 5.0]  # in the order they ran
    assert _median_run(trials[:3])["tag"] == "c"  # 1, 2, 3
    assert _median_run(trials[:1])["tag"] == "a"


def test_repeated_scale_bench_reports_the_median_of_its_trials(tmp_path):
    result = run_scale_bench(tmp_path, volume_counts=(2, 1, 1), reflection=1, recipe="mobile", face_size=4,
                             jobs=(1,), repeats=3)
    run = result["runs"]["1"]
    walls = run["wall_seconds_runs"]
    assert len(walls) == 3 and run["wall_seconds"] == sorted(walls)[1]
    assert result["probes"] == 3 and "speedup_1_to_2" not in result
    assert (tmp_path / "hall-j1.h5").is_file()


def test_two_worker_counts_report_both_ratios_and_the_store_writer_is_no_worker(tmp_path):
    """The ratio of the median walls and the median of the per-repetition ratios, recomputed from the trials' walls;
    the in-process bake has no worker, whatever the store's forked writer weighs (``peak_store_writer_uss_mb``)."""
    import numpy as np

    result = run_scale_bench(tmp_path, volume_counts=(2, 1, 1), reflection=1, recipe="mobile", face_size=4,
                             jobs=(1, 2), repeats=2)
    one, two = result["runs"]["1"], result["runs"]["2"]
    assert result["speedup_1_to_2"] == one["wall_seconds"] / two["wall_seconds"]
    pairs = [a / b for a, b in zip(one["wall_seconds_runs"], two["wall_seconds_runs"])]
    assert result["speedup_1_to_2_runs"] == pairs
    assert result["speedup_1_to_2_median_of_runs"] == float(np.median(pairs))
    assert one["peak_worker_mb"] == 0 and two["peak_worker_mb"] > 0
    assert one["peak_store_writer_uss_mb"] >= 0 and two["peak_store_writer_uss_mb"] >= 0
