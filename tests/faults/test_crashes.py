"""Issue 15 case 6 — what a killed bake leaves is cleaned up and never mixes outputs.

* Temporary files of a killed run (a staged store of MBs, a staged layer, a checkpoint being written) are removed
  by the next run.
* Killing only the parent (SIGKILL) takes its worker processes with it.
* The store and the layer are committed together: a kill between the two renames leaves a commit record that the
  next run completes, so a new store is never paired with an old layer for longer than until the next run.
* SIGKILL of the parent, and of a worker, at seeded random moments: the previous store and layer stay byte-identical
  (or the commit completes), and the rerun writes exactly what a clean bake writes.
* SIGTERM removes every temporary file on the way out."""

from __future__ import annotations

import json
import os
import signal
import time

import numpy as np
import pytest
from faultkit import (
    alive,
    children,
    cli,
    dead_pid,
    incli,
    pool_workers,
    popen,
    scene_text,
    temporaries,
    wait_for,
)

pytestmark = pytest.mark.faults

FLAGS = ["-e", "sh2", "-e", "zh3", "--face-size", "8", "--samples", "2", "--bounces", "1"]


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """A scene (24 probes, 6 batches), its previous version (another dome: every probe re-bakes) and a clean bake."""
    d = tmp_path_factory.mktemp("crash")
    recipe = d / "batches.toml"
    recipe.write_text('name = "batches"\n[targets]\nirradiance = ["sh2"]\n[pipeline]\nbatch_size = 4\n')
    FLAGS[:] = [*FLAGS[:10], "--recipe", str(recipe)]
    (d / "scene.usda").write_text(scene_text(24, spacing=0.5))
    (d / "old.usda").write_text(scene_text(24, spacing=0.5, dome=0.8))
    (d / "clean").mkdir()
    result = incli("bake", d / "scene.usda", "-o", d / "clean" / "s.h5", *FLAGS, "-j", "1")
    assert result.returncode == 0, result.output
    return d


def _workdir(d, name):
    work = d / name
    work.mkdir()
    result = incli("bake", d / "old.usda", "-o", work / "s.h5", *FLAGS, "-j", "1")
    assert result.returncode == 0, result.output
    # The previous pair, written from another scene file: make it look like this scene's previous bake.
    return work, {p: (work / p).read_bytes() for p in ("s.h5", "s.bake.usda")}


def _outputs(work):
    return {p: (work / p).read_bytes() for p in ("s.h5", "s.bake.usda")}


def _clean(d):
    return {p: (d / "clean" / p).read_bytes() for p in ("s.h5", "s.bake.usda")}


def _layer_matches_store(work, reference):
    """The layer on disk is the one committed with the store on disk (same pair as the reference or previous)."""
    return _outputs(work)["s.bake.usda"] == reference["s.bake.usda"]


def test_leftovers_of_a_killed_run_are_removed(scenes):
    work, _ = _workdir(scenes, "leftovers")
    pid = dead_pid()
    (work / f".s.h5.tmp-{pid}").write_bytes(np.random.default_rng(0).bytes(3 << 20))  # a staged store, 3 MB
    (work / f".s.bake.usda.tmp-{pid}.usda").write_text("#usda 1.0\n")
    (work / "s.h5.partial").mkdir()
    (work / "s.h5.partial" / f".0123.pkl.tmp-{pid}").write_bytes(b"half a pickle")
    (work / "s.h5.lock").write_text(json.dumps({"pid": pid, "host": "elsewhere"}))
    result = cli("bake", scenes / "scene.usda", "-o", work / "s.h5", *FLAGS, "-j", "1")
    assert result.returncode == 0, result.stderr
    assert "removed 3 temporary file(s)" in result.stderr and "took over the lock" in result.stderr
    assert not temporaries(work) and not (work / "s.h5.partial").exists()
    assert _outputs(work) == _clean(scenes)


@pytest.mark.parametrize("executor", [["-j", "2"], ["--dask-local", "-j", "2"]], ids=["processes", "dask"])
def test_workers_die_with_a_killed_parent(scenes, executor, tmp_path):
    process = popen("bake", scenes / "scene.usda", "-o", tmp_path / "s.h5", *FLAGS, *executor)
    workers: list[int] = []

    def started():
        workers[:] = children(process.pid)
        return len(workers) >= 2 or process.poll() is not None

    assert wait_for(started, timeout=60)
    time.sleep(0.3)
    workers[:] = children(process.pid)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert workers, "the bake started no worker processes"
    assert wait_for(lambda: not alive(workers), timeout=10), f"workers still running: {alive(workers)}"


def test_store_and_layer_are_committed_together(scenes):
    work, previous = _workdir(scenes, "commit")
    killed = cli("bake", scenes / "scene.usda", "-o", work / "s.h5", *FLAGS, "-j", "1",
                 env={"BAKERY_FAULT": "commit:1"})  # SIGKILL right after the store's rename
    assert killed.returncode == -signal.SIGKILL
    now = _outputs(work)
    assert now["s.h5"] == _clean(scenes)["s.h5"] and now["s.bake.usda"] == previous["s.bake.usda"]
    assert (work / ".s.h5.commit").exists()  # the half-committed pair is recorded …
    repaired = cli("inspect", work / "s.h5")  # (readers are not blocked)
    assert repaired.returncode == 0
    again = cli("bake", scenes / "scene.usda", "-o", work / "s.h5", *FLAGS, "-j", "1", "--json")
    assert again.returncode == 0, again.stderr
    assert "completed the interrupted commit" in again.stderr  # … and the next run completes it
    assert json.loads(again.stdout)["baked"] == 0
    assert _outputs(work)["s.bake.usda"] == _clean(scenes)["s.bake.usda"] and not temporaries(work)


def test_sigkill_of_the_parent_at_random_moments(scenes):
    work, previous = _workdir(scenes, "random-parent")
    rng = np.random.default_rng(15)
    clean = _clean(scenes)
    for delay in rng.uniform(0.3, 3.0, size=3):
        process = popen("bake", scenes / "scene.usda", "-o", work / "s.h5", *FLAGS, "-j", "2")
        time.sleep(float(delay))
        workers = children(process.pid)
        process.send_signal(signal.SIGKILL)
        process.wait()
        outputs = _outputs(work)
        if (work / ".s.h5.commit").exists():  # killed inside the commit: the record names the pair
            assert outputs["s.h5"] == clean["s.h5"]
        else:
            assert outputs == previous or outputs == clean, delay
        assert wait_for(lambda w=workers: not alive(w), timeout=10)
    result = cli("bake", scenes / "scene.usda", "-o", work / "s.h5", *FLAGS, "-j", "2")
    assert result.returncode == 0, result.stderr
    assert _outputs(work) == clean and not temporaries(work) and not (work / "s.h5.partial").exists()


def test_sigkill_of_a_worker_at_random_moments(scenes):
    work, _ = _workdir(scenes, "random-worker")
    rng = np.random.default_rng(16)
    process = popen("bake", scenes / "scene.usda", "-o", work / "s.h5", *FLAGS, "-j", "2", "--json")
    killed = 0
    for delay in rng.uniform(0.0, 1.0, size=2):
        if not wait_for(lambda: pool_workers(process.pid) or process.poll() is not None, timeout=60):
            break
        time.sleep(float(delay))
        workers = pool_workers(process.pid)
        if process.poll() is not None or not workers:
            break
        try:
            os.kill(workers[int(rng.integers(len(workers)))], signal.SIGKILL)
            killed += 1
        except ProcessLookupError:
            pass
    out, err = process.communicate(timeout=300)
    assert process.returncode == 0, err
    assert killed >= 1
    assert json.loads(out)["failed"] == {}  # the dead worker's batch was run again
    assert _outputs(work) == _clean(scenes)


def test_sigterm_cleans_up(scenes):
    """SIGTERM while batches are still being baked (after the first checkpoint, so the work folder holds files):
    exit 143 with one line, the previous pair untouched, no temporary file left. (The bake is made seconds long so
    that the signal cannot arrive after it finished: a process killed after its outputs were committed exits −15.)"""
    flags = list(FLAGS)
    flags[flags.index("--samples") + 1] = "512"
    work, previous = _workdir(scenes, "sigterm")
    process = popen("bake", scenes / "scene.usda", "-o", work / "s.h5", *flags, "-j", "1")
    assert wait_for(lambda: any((work / "s.h5.partial").glob("*.pkl")) or process.poll() is not None, timeout=120)
    assert process.poll() is None, "the bake finished before it could be terminated"
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143, err
    assert "Traceback" not in err and "terminated:" in err
    assert _outputs(work) == previous
    assert not temporaries(work)


@pytest.mark.parametrize("executor", [["-j", "2"], ["--dask-local", "-j", "2"]], ids=["processes", "dask"])
def test_ctrl_c_stops_the_bake_and_its_workers_in_one_line_and_the_next_bake_resumes(scenes, executor):
    """Ctrl-C sends SIGINT to the terminal's whole process group, the workers included: the bake exits 130 with one
    line (no worker traceback), the previous outputs are untouched, no worker is left, and the next bake resumes
    from the kept checkpoints and writes what a clean bake writes."""
    flags = list(FLAGS)
    flags[flags.index("--samples") + 1] = "512"  # seconds of batches after the first checkpoint
    reference = scenes / "clean-ctrl-c"  # beside the others: the layer names the scene by a relative path
    if not reference.is_dir():
        reference.mkdir()
        clean = incli("bake", scenes / "scene.usda", "-o", reference / "s.h5", *flags, "-j", "1")
        assert clean.returncode == 0, clean.output
    work, previous = _workdir(scenes, f"ctrl-c-{executor[0].strip('-')}")
    process = popen("bake", scenes / "scene.usda", "-o", work / "s.h5", *flags, *executor,
                    start_new_session=True)  # its own process group, like a shell's foreground job
    workers: list[int] = []

    def checkpointed():
        workers[:] = children(process.pid) or workers
        return any((work / "s.h5.partial").glob("*.pkl")) or process.poll() is not None

    assert wait_for(checkpointed, timeout=120)
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "Traceback" not in err and "Process " not in err and "WARNING" not in err, err
    assert "interrupted:" in err and "the previous store and layer are unchanged" in err
    assert _outputs(work) == previous
    assert workers and wait_for(lambda: not alive(workers), timeout=10), f"workers still running: {alive(workers)}"
    again = cli("bake", scenes / "scene.usda", "-o", work / "s.h5", *flags, *executor)
    assert again.returncode == 0, again.stderr
    assert "batches resumed from checkpoints" in again.stderr
    assert _outputs(work) == _outputs(reference)
