"""Issue 15 case 5 — one writer per store: ``STORE.h5.lock`` (an fcntl lock with the holder's pid and host) is held
for the whole bake. A second bake (or ``migrate``) of the same store fails at once naming the holder, and the
first bake's store is what ends up on disk; a lock left by a process that died is taken over with a warning."""

from __future__ import annotations

import json
import os
import signal
import socket

import pytest
from faultkit import assert_fails_cleanly, cli, dead_pid, popen, wait_for, write_env

import bakery
from bakery.files import FileLock, OutputError

pytestmark = pytest.mark.faults


@pytest.fixture
def slow(tmp_path):
    """Inputs and a recipe for a bake of a few batches (one probe per batch, the solved ZH3)."""
    images = [write_env(tmp_path / f"big{i}.exr", i, size=(64, 128)) for i in range(6)]
    recipe = tmp_path / "slow.toml"
    recipe.write_text('name = "slow"\n[targets]\nirradiance = ["sh2", "zh3_solved"]\n[bake]\nface_size = 16\n'
                      '[pipeline]\nbatch_size = 1\n')
    return images, recipe


def test_second_bake_of_the_same_store_is_refused(tmp_path, slow):
    images, recipe = slow
    store = tmp_path / "s.h5"
    first = popen("bake", *images, "-o", store, "--recipe", recipe, "-j", "1")
    try:
        lock = tmp_path / "s.h5.lock"  # held and filled in (the holder writes its pid just after locking)
        assert wait_for(lambda: (lock.exists() and "pid" in lock.read_text()) or first.poll() is not None)
        first.send_signal(signal.SIGSTOP)  # frozen while it holds the lock: the race is decided, not timed
        assert first.poll() is None, "the first bake finished before it could be paused"
        second = cli("bake", images[0], "-o", store, "-e", "zh3", "--face-size", "4")
        migrate = cli("migrate", store)
    finally:
        first.send_signal(signal.SIGCONT)
        _, err = first.communicate(timeout=300)
    assert first.returncode == 0, err
    assert_fails_cleanly(second, 2, "s.h5", "another bake is writing this store", f"pid {first.pid}",
                         socket.gethostname())
    assert_fails_cleanly(migrate, 2, "s.h5", f"pid {first.pid}")
    contents = bakery.open_store(store)  # the first bake's store, not dropped by a later writer
    assert len(contents.probe_names) == 6 and set(contents.encodings) == {"sh2", "zh3_solved"}
    assert not (tmp_path / "s.h5.lock").exists()


def test_stale_lock_of_a_dead_process_is_taken_over(tmp_path):
    image = write_env(tmp_path / "sky.exr")
    store = tmp_path / "s.h5"
    pid = dead_pid()
    (tmp_path / "s.h5.lock").write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "since": "earlier"}))
    result = cli("bake", image, "-o", store, "-e", "sh2", "--face-size", "4")
    assert result.returncode == 0, result.stderr
    assert "took over the lock" in result.stderr and f"pid {pid}" in result.stderr
    assert not (tmp_path / "s.h5.lock").exists() and bakery.open_store(store).probe_names == ["/environment"]


def test_the_lock_is_per_store_and_per_process(tmp_path):
    store = tmp_path / "s.h5"
    with FileLock(store) as lock:
        info = json.loads((tmp_path / "s.h5.lock").read_text())
        assert info["pid"] == os.getpid() and info["host"] == socket.gethostname() and lock.stale is None
        with pytest.raises(OutputError, match="already writing"):
            FileLock(store).acquire()
        with FileLock(tmp_path / "other.h5"):  # another store: independent
            pass
    assert not (tmp_path / "s.h5.lock").exists()
    with FileLock(store):  # released: can be taken again
        pass
