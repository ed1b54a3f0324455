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


def _hold_and_free(megabytes: int, ready, done) -> None:  # noqa: ANN001 - a spawned child of the sampler's test
    import numpy as np

    block = np.ones(megabytes * 2**20 // 8)  # touched: resident
    del block  # freed at once: only the kernel's high-water mark still knows
    ready.set()
    done.wait(30)


def test_memory_sampler_peaks_are_high_water_marks_not_samples():
    """A 300 MB block that lives for a few milliseconds, between two of the sampler's looks, in this process and in
    a child, is in both peaks: they are the kernel's marks (VmHWM), not what the looks happened to see."""
    import multiprocessing
    import sys
    import time

    import numpy as np
    import pytest

    from bakery.bench.scale import _MemorySampler

    if not sys.platform.startswith("linux"):
        pytest.skip("the high-water marks are read from /proc")
    context = multiprocessing.get_context("spawn")
    ready, done = context.Event(), context.Event()
    with _MemorySampler() as memory:
        block = np.ones(300 * 2**20 // 8)
        del block
        child = context.Process(target=_hold_and_free, args=(300, ready, done))
        child.start()
        assert ready.wait(60)
        time.sleep(0.6)  # at least one look while the child lives (it freed its block before)
        done.set()
        child.join(30)
    peaks = memory.as_dict()
    assert peaks["peak_parent_mb"] >= 300 and peaks["peak_worker_mb"] >= 300


def test_an_exports_peak_memory_is_measured(tmp_path):
    """The export's ``peak_mb`` is this process's high-water mark over the export, read once the sampler stops
    (read inside its block it was 0 with the kernel's marks); at least the size of the export's result in memory."""
    result = run_scale_bench(tmp_path, volume_counts=(1, 1, 1), reflection=1, recipe="console", face_size=8,
                             jobs=(1,), exports=("ktx2",))
    ktx2 = result["exports"]["ktx2"]
    assert ktx2["files"] == 1 and ktx2["peak_mb"] > 10  # an interpreter with numpy, USD and h5py loaded
