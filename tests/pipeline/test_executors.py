"""Executors: worker processes start with one BLAS thread each (N workers on N cores must not oversubscribe them),
and the parent's environment is left as it was; batches run longest-first without changing the store."""

import os

from bakery.pipeline.executors import WORKER_THREAD_ENVIRONMENT, ProcessExecutor, _single_threaded_children


def _environment_of_worker() -> dict[str, str | None]:
    import numpy as np  # noqa: F401 - BLAS is initialised at import, from this environment

    return {k: os.environ.get(k) for k in WORKER_THREAD_ENVIRONMENT}


def test_workers_start_single_threaded_and_the_parent_environment_is_restored(monkeypatch):
    for key in WORKER_THREAD_ENVIRONMENT:
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")  # a user's own choice is kept
    executor = ProcessExecutor(1)
    pool = executor._new_pool()
    try:
        with _single_threaded_children():
            future = pool.submit(_environment_of_worker)
        seen = future.result(timeout=120)
    finally:
        pool.shutdown()
    assert seen == {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "3"}
    assert os.environ.get("OPENBLAS_NUM_THREADS") is None and os.environ.get("OMP_NUM_THREADS") is None
    assert os.environ["MKL_NUM_THREADS"] == "3"



def _interrupt_handler_of_worker() -> str:
    import signal

    return repr(signal.getsignal(signal.SIGINT))


def test_workers_ignore_ctrl_c_the_parent_stops_them():
    """Ctrl-C reaches the whole process group; a worker must not die of it mid-batch with a traceback of its own —
    the parent stops the bake and its workers (tests/faults: ``test_ctrl_c_stops_the_bake…``)."""
    import signal

    executor = ProcessExecutor(1)
    pool = executor._new_pool()
    try:
        handler = pool.submit(_interrupt_handler_of_worker).result(timeout=120)
    finally:
        pool.shutdown()
    assert handler == repr(signal.SIG_IGN)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the parent's own is untouched

def test_longest_first_order_does_not_change_the_store(tmp_path, monkeypatch):
    """A scene with cheap irradiance and expensive reflection probes: the reflection batches are submitted first,
    and the store is byte-identical to the serial bake's."""
    import bakery
    from usd_scenes import header, material, plane_mesh, probe, write

    text = (header() + material("Grey", diffuse=(0.5, 0.5, 0.5)) + plane_mesh("Floor", 5.0, "/Grey")
            + '\ndef DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'
            + "".join(probe(f"I{i}", (0.5 * i, 1.0, 0.0)) for i in range(3))
            + "".join(probe(f"R{i}", (0.5 * i, 2.0, 0.0), "BakeryReflectionProbe") for i in range(2)))
    scene = write(tmp_path / "mixed.usda", text)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")  # the stores' timestamps
    kw = dict(encodings=("sh3", "shexp"), face_size=8, samples=1, bounces=0, resume=False, batch_size=1)
    bakery.bake(scene, tmp_path / "serial.h5", jobs=1, layer=tmp_path / "serial.bake.usda", **kw)
    bakery.bake(scene, tmp_path / "pool.h5", jobs=2, layer=tmp_path / "pool.bake.usda", **kw)
    assert (tmp_path / "serial.h5").read_bytes() == (tmp_path / "pool.h5").read_bytes()



def _imported(module: str) -> bool:
    import sys

    return module in sys.modules


def test_started_workers_import_the_modules_they_are_given_and_run_with_one_blas_thread():
    """``start`` spawns the pool early (while the parent plans) with the source's module imported in every worker;
    the tasks then run in that pool, single-threaded as any worker; ``close`` ends it."""
    executor = ProcessExecutor(2)
    executor.start(("bakery.sources.usd_scene",))
    pool = executor._pool
    try:
        assert pool is not None
        assert all(pool.submit(_imported, "bakery.sources.usd_scene").result(timeout=120) for _ in range(4))
        seen = pool.submit(_environment_of_worker).result(timeout=120)
        assert seen["OPENBLAS_NUM_THREADS"] == "1" and seen["OMP_NUM_THREADS"] == "1"
        processes = list(pool._processes.values())
        assert len(processes) == 2
    finally:
        executor.close()
    assert executor._pool is None
    for process in processes:
        process.join(timeout=30)
        assert not process.is_alive()

def test_merge_releases_each_batch_field_once_merged_with_the_same_result():
    """``release_inputs`` frees the batches' fields as they are merged (the parent's peak), and the merge is the same
    arrays, in the requested order, as without it (closed form: each probe's row is its own values)."""
    import numpy as np

    from bakery.pipeline.encode import EncodedBatch
    from bakery.pipeline.merge import merge_batches
    from bakery.probe import Probe

    def batch(names, kinds):
        probes = [Probe(n, kinds) for n in names]
        value = np.array([[float(n[1:])] * 4 for n in names], np.float32)
        encoded = {"sh2": {"coefficients": value.copy(), "extra": value[:, :2] * 2}}
        rows = {"sh2": np.arange(len(names))}
        return EncodedBatch(probes, encoded, rows, {"error": value[:, 0]})

    def batches():
        return [batch(["p3", "p1"], ("irradiance",)), batch(["p0", "p2"], ("irradiance",))]

    order = ["p0", "p1", "p2", "p3"]
    kept = merge_batches(batches(), order)
    inputs = batches()
    released = merge_batches(inputs, order, release_inputs=True)
    assert all(b.encoded["sh2"] == {} for b in inputs)
    for field in ("coefficients", "extra"):
        np.testing.assert_array_equal(released.encoded["sh2"][field], kept.encoded["sh2"][field])
    np.testing.assert_array_equal(released.encoded["sh2"]["coefficients"][:, 0], [0.0, 1.0, 2.0, 3.0])
    assert [p.name for p in released.probes] == order


def test_a_module_that_cannot_be_imported_does_not_break_a_started_pool():
    executor = ProcessExecutor(1)
    executor.start(("bakery.no_such_module",))
    try:
        assert executor._pool.submit(_imported, "bakery.pipeline.worker").result(timeout=120)
    finally:
        executor.close()


def test_a_pool_broken_before_the_batches_are_given_is_rebuilt(tmp_path, monkeypatch):
    """A worker of the pool that :meth:`start` spawned during planning is killed before any batch is submitted (the
    pool is broken at submit time): the bake rebuilds the pool and writes the serial bake's bytes."""
    import signal
    import time

    import bakery
    from usd_scenes import header, material, plane_mesh, probe, write

    text = (header() + material("Grey", diffuse=(0.5, 0.5, 0.5)) + plane_mesh("Floor", 5.0, "/Grey")
            + "".join(probe(f"I{i}", (0.5 * i, 1.0, 0.0)) for i in range(3)))
    scene = write(tmp_path / "s.usda", text)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    kw = dict(encodings=("sh3",), face_size=4, samples=1, bounces=0, resume=False, batch_size=1)
    bakery.bake(scene, tmp_path / "serial.h5", jobs=1, layer=tmp_path / "serial.bake.usda", **kw)
    executor = ProcessExecutor(2)
    try:
        executor.start(("bakery.sources.usd_scene",))
        pool = executor._pool
        assert pool.submit(_imported, "bakery.sources.usd_scene").result(timeout=120)
        os.kill(next(iter(pool._processes.values())).pid, signal.SIGKILL)
        deadline = time.monotonic() + 60
        while not pool._broken and time.monotonic() < deadline:
            time.sleep(0.05)
        assert pool._broken
        summary = bakery.bake(scene, tmp_path / "pool.h5", executor=executor, layer=tmp_path / "pool.bake.usda", **kw)
    finally:
        executor.close()
    assert not summary.failed
    assert (tmp_path / "serial.h5").read_bytes() == (tmp_path / "pool.h5").read_bytes()


def _run_script(path, text):  # noqa: ANN001, ANN202
    import subprocess
    import sys

    path.write_text(text)
    return subprocess.run([sys.executable, str(path)], capture_output=True, text=True, timeout=300, cwd=path.parent,
                          check=False)


def test_a_script_baking_with_workers_at_its_top_level_is_refused_before_any_work(tmp_path):
    """Spawned workers import the __main__ script again: unguarded, each re-ran the bake, failed on the store's lock,
    and the bake ended in "worker process died 3 times" with worker tracebacks. Now the bake refuses at once, naming
    the script's line — for the process pool and a Dask LocalCluster —, and writes nothing."""
    image = tmp_path / "sky.hdr"
    import numpy as np
    import OpenImageIO as oiio

    oiio.ImageBuf(np.ones((4, 8, 3), np.float32)).write(str(image))
    for executor in ("jobs=2", "executor=make_executor(2, dask_local=True)"):
        script = tmp_path / "bake_it.py"
        result = _run_script(script, "import bakery\nfrom bakery.pipeline.executors import make_executor\n\n"
                                     f"bakery.bake({str(image)!r}, 'out.h5', encodings=('sh2',), {executor})\n")
        assert result.returncode != 0
        last = result.stderr.strip().splitlines()[-1]
        assert f"{script}:4: this bake starts" in last and '__name__ == "__main__"' in last, result.stderr
        assert not (tmp_path / "out.h5").exists() and "worker process died" not in result.stderr


def test_a_guarded_script_is_not_refused(tmp_path):
    """Under `if __name__ == "__main__":` (either way round), also through a function, or with no script at all
    (-c), nothing is refused."""
    probe = ("from bakery.pipeline.executors import unguarded_main_line\n\n"
             "def main():\n    print('where', unguarded_main_line())\n\n")
    for guard in ('if __name__ == "__main__":\n    main()\n', 'if "__main__" == __name__:\n    main()\n'):
        result = _run_script(tmp_path / "guarded.py", probe + guard)
        assert result.returncode == 0 and "where None" in result.stdout, result.stderr
    result = _run_script(tmp_path / "unguarded.py", probe + "main()\n")
    assert f"where ('{tmp_path / 'unguarded.py'}', 6)" in result.stdout, result.stdout + result.stderr


def test_spilled_fields_give_the_same_store_bytes_and_leave_no_file(tmp_path, monkeypatch):
    """With every field spilled (the size threshold lowered to one byte, where a production bake's chains spill at
    4 MiB): the parent keeps the batches' and the merge's fields as sparse files in the work folder, the store is
    byte-identical to the one baked with the fields in memory, and no spilled file is left afterwards (nor after a
    bake that fails once the batches have run)."""
    import numpy as np
    import pytest

    import bakery
    import bakery.pipeline.merge as merge
    import bakery.pipeline.run as run
    import bakery.zero_pages as zero_pages
    from usd_scenes import header, material, plane_mesh, probe, write

    text = (header() + material("Grey", diffuse=(0.5, 0.5, 0.5)) + plane_mesh("Floor", 5.0, "/Grey")
            + '\ndef DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'
            + "".join(probe(f"I{i}", (0.5 * i, 1.0, 0.0)) for i in range(3))
            + "".join(probe(f"R{i}", (0.5 * i, 2.0, 0.0), "BakeryReflectionProbe") for i in range(3)))
    scene = write(tmp_path / "mixed.usda", text)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    kw = dict(encodings=("sh3", "shexp_hybrid"), face_size=8, samples=1, bounces=0, resume=False, batch_size=2,
              jobs=1)
    bakery.bake(scene, tmp_path / "memory.h5", layer=tmp_path / "memory.bake.usda", **kw)
    spilled = []
    original = zero_pages.spilled

    def recording(array, path):  # noqa: ANN001, ANN202
        out = original(array, path)
        if isinstance(out, np.memmap):
            spilled.append(path)
        return out

    merged = []
    sparse_rows = merge.SparseRows

    def recording_merge(shape, dtype, path):  # noqa: ANN001, ANN202
        merged.append(path)
        return sparse_rows(shape, dtype, path)

    monkeypatch.setattr(zero_pages, "MIN_BYTES", 1)
    monkeypatch.setattr(merge, "MIN_BYTES", 1)
    monkeypatch.setattr(run, "spilled", recording)
    monkeypatch.setattr(merge, "SparseRows", recording_merge)
    bakery.bake(scene, tmp_path / "spilled.h5", layer=tmp_path / "spilled.bake.usda", **kw)
    folder = tmp_path / "spilled.h5.partial" / "fields"
    assert spilled and merged and all(p.parent == folder for p in spilled + merged)
    assert any(p.name == "merged.shexp_hybrid.level0" for p in merged)
    assert (tmp_path / "spilled.h5").read_bytes() == (tmp_path / "memory.h5").read_bytes()
    assert not (tmp_path / "spilled.h5.partial").exists()

    def failing(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(run, "commit_outputs", failing)
    with pytest.raises(Exception, match="No space left"):
        bakery.bake(scene, tmp_path / "failed.h5", **kw)
    assert not (tmp_path / "failed.h5.partial" / "fields").exists() and not (tmp_path / "failed.h5").exists()
