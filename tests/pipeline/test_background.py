"""BackgroundCall: the bake's store is written in a forked child beside the layer. The call's value and exception
reach the parent; a child that dies unanswered is replaced by the call in the parent; stop() leaves nothing
running."""

import errno
import os
import signal
import sys
import time

import pytest

from bakery.pipeline.background import BackgroundCall

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the child is forked on Linux only")


def _pid_and(value):
    return os.getpid(), value


def _fail(path):
    raise OSError(errno.ENOSPC, "No space left on device", str(path))


def _kill_self_unless(parent):
    if os.getpid() != parent:  # in the child: die without answering
        os.kill(os.getpid(), signal.SIGKILL)
    return os.getpid()


def _slow_write(path):
    time.sleep(0.5)
    path.write_text("late")


@linux
def test_the_call_runs_in_a_child_and_returns_its_value():
    pid, value = BackgroundCall(_pid_and, {"rows": [1, 2, 3]}).result()
    assert pid != os.getpid() and value == {"rows": [1, 2, 3]}


def test_the_calls_exception_is_raised_in_the_parent(tmp_path):
    call = BackgroundCall(_fail, tmp_path / "store.h5")
    error = call.exception()
    assert isinstance(error, OSError) and error.errno == errno.ENOSPC and error.filename == str(tmp_path / "store.h5")
    with pytest.raises(OSError, match="No space left"):
        call.result()


@linux
def test_a_child_that_dies_unanswered_is_replaced_by_the_call_in_the_parent():
    assert BackgroundCall(_kill_self_unless, os.getpid()).result() == os.getpid()


@linux
def test_stop_leaves_nothing_writing(tmp_path):
    target = tmp_path / "late.txt"
    call = BackgroundCall(_slow_write, target)
    pid = call._pid
    call.stop()
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # reaped
    time.sleep(0.7)
    assert not target.exists()
    call.stop()  # idempotent


def test_the_thread_fallback_gives_the_same_answers(tmp_path, monkeypatch):
    monkeypatch.setenv("BAKERY_BACKGROUND", "thread")
    pid, value = BackgroundCall(_pid_and, (1.5, "x")).result()
    assert pid == os.getpid() and value == (1.5, "x")
    assert isinstance(BackgroundCall(_fail, tmp_path / "s.h5").exception(), OSError)
