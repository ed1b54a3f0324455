"""Dask on a real (loopback) cluster: a `dask scheduler` and two `dask worker` processes started from their own
command lines; a bake through `--scheduler tcp://127.0.0.1:PORT` survives one worker being killed mid-bake (Dask
reschedules its batches) and writes the same bytes as a serial bake; an unreachable scheduler is a clear error
within the timeout the user sets (BAKERY_SCHEDULER_TIMEOUT)."""

import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from farm_helpers import BAKERY, ENV, INDOOR, cli

DASK = [sys.executable, "-m", "dask"]


def _stop(process):  # noqa: ANN001
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGTERM)
            process.wait(timeout=10)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.wait(timeout=10)


def _wait_for(predicate, timeout, what):  # noqa: ANN001
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def hall(tmp_path):
    from bakery.bench.scale import generate_scene

    scene = generate_scene(tmp_path / "hall", (4, 2, 4), 4)  # 32 irradiance + 4 reflection probes
    recipe = tmp_path / "small.toml"
    recipe.write_text('name = "dask-test"\n[targets]\nirradiance = ["zh3", "zh3_quantized"]\nreflection = ["shexp"]\n'
                      '[bake]\nface_size = 8\nreference_errors = false\n[pipeline]\nbatch_size = 2\n')
    return scene, recipe


def test_a_bake_survives_a_killed_worker_on_a_real_cluster(tmp_path, hall):
    scene, recipe = hall
    env = {**ENV, "BAKERY_CACHE_DIR": str(tmp_path / "cache"), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "5"}
    serial = tmp_path / "serial" / "hall.h5"
    serial.parent.mkdir()
    cli("bake", scene, "-o", serial, "--recipe", recipe, "--samples", "8", "-j", "1", env=env)
    built = {p.name: (p.stat().st_ino, p.stat().st_size) for p in (tmp_path / "cache").glob("*.npy")}
    assert built  # the operators, built once in the shared cache folder
    scheduler_file = tmp_path / "scheduler.json"
    processes = []
    try:
        processes.append(subprocess.Popen([*DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                           "--scheduler-file", str(scheduler_file)], env=env, start_new_session=True,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        _wait_for(lambda: scheduler_file.is_file() and scheduler_file.stat().st_size > 0, 60, "the scheduler file")
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        workers = []
        for name in ("a", "b"):
            workers.append(subprocess.Popen(
                [*DASK, "worker", "--scheduler-file", str(scheduler_file), "--nthreads", "1", "--nworkers", "1",
                 "--no-dashboard", "--host", "127.0.0.1", "--name", name, "--local-directory", str(tmp_path / name)],
                env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            processes.append(workers[-1])
        store = tmp_path / "dask" / "hall.h5"
        store.parent.mkdir()
        bake = subprocess.Popen([*BAKERY, "bake", str(scene), "-o", str(store), "--recipe", str(recipe), "--samples",
                                 "8", "--scheduler", address, "--json"], env=env, start_new_session=True,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        processes.append(bake)
        journal = tmp_path / "dask" / "hall.h5.partial"
        _wait_for(lambda: bake.poll() is not None or len(list(journal.glob("*.pkl"))) >= 3, 240, "three batches")
        assert bake.poll() is None, "the bake finished before a worker could be killed"
        os.killpg(workers[0].pid, signal.SIGKILL)  # the nanny and its worker: this worker is gone for good
        workers[0].wait(timeout=10)
        stdout, stderr = bake.communicate(timeout=300)
        assert bake.returncode == 0, stderr[-3000:]
        summary = json.loads(stdout)
        assert summary["executor"] == "dask" and summary["baked"] == 36 and summary["failed"] == {}
        assert store.read_bytes() == serial.read_bytes()
        # The workers memory-mapped the shared operators; none was rebuilt.
        assert {p.name: (p.stat().st_ino, p.stat().st_size) for p in (tmp_path / "cache").glob("*.npy")} == built
    finally:
        for process in reversed(processes):
            _stop(process)
    assert all(p.poll() is not None for p in processes)


def test_an_unreachable_scheduler_is_a_clear_error_within_the_timeout(tmp_path):
    with socket.socket() as probe:  # a loopback port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    start = time.monotonic()
    result = cli("bake", INDOOR, "-e", "sh2", "--face-size", "4", "-o", tmp_path / "x.h5", "--scheduler",
                 f"tcp://127.0.0.1:{port}", check=False, env={**ENV, "BAKERY_SCHEDULER_TIMEOUT": "3"})
    assert time.monotonic() - start < 30
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert f"cannot connect to the Dask scheduler at tcp://127.0.0.1:{port}" in result.stderr
    assert not (tmp_path / "x.h5").exists()
