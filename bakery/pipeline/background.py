"""One call run beside the parent's own work, in a forked child process where the platform has ``fork``.

The bake's tail writes the HDF5 store and the USD layer side by side. In two threads they share the GIL — h5py and
``Sdf.Layer.Export`` both hold it — so the store's write (0.6 s on a 11 000-probe hall) added to the layer's
(2 s). A forked child inherits the arguments (nothing is pickled), writes the store on the other core and exits::

    call = BackgroundCall(write_store_file, staged_store, contents)   # starts now
    ...                                                                # the parent's own work (the layer)
    call.result()        # waits; re-raises the call's exception; the return value is the call's
    call.stop()          # on every exit path: kills a child still running (nothing is left writing)

The child runs only the call (numpy and h5py, already imported) and leaves with ``os._exit``: no ``atexit``
handler, no buffered output of the parent flushed twice, no ``finally`` of the parent run again. It dies with the
parent (``PR_SET_PDEATHSIG``) and answers through a pipe: ``(True, value)`` or ``(False, exception)``, pickled. If
the child dies without answering (killed, out of memory), the call is run again in the parent, so the result never
depends on the child. Without ``fork`` (or if it fails), or with ``BAKERY_BACKGROUND=thread`` in the environment (a
host application that must not be forked, e.g. a DCC embedding bakery), the call runs in a thread, as before.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

#: Environment variable: ``thread`` runs background calls in a thread instead of a forked child.
BACKGROUND_ENVIRONMENT = "BAKERY_BACKGROUND"
#: Exit status of a child that answered (any other status: it died, and the call is run in the parent).
_ANSWERED = 0
#: Pids of the running children, and the lock held across a fork and its registration (:func:`children_known`).
_CHILDREN: set[int] = set()
_FORKING = threading.Lock()


@contextmanager
def children_known() -> Iterator[frozenset[int]]:
    """The pids of the background children now running; no new one is forked while the block runs, so a process
    listing taken inside it sees no child that is missing from the set (the scale bench tells the bake's workers
    from the store's writer this way: a forked child's resident size counts the parent's pages it shares)."""
    with _FORKING:
        yield frozenset(_CHILDREN)


class BackgroundCall:
    """``fn(*args)`` started at construction, in a forked child (Linux) or a thread (module docstring)."""

    def __init__(self, fn: Callable[..., Any], *args: Any) -> None:
        self._fn, self._args = fn, args
        self._pid: int | None = None
        self._read: int | None = None
        self._thread: threading.Thread | None = None
        self._outcome: tuple[bool, Any] | None = None
        forkable = sys.platform.startswith("linux") and hasattr(os, "fork")
        if forkable and os.environ.get(BACKGROUND_ENVIRONMENT, "").strip().lower() != "thread":
            try:
                self._fork()
                return
            except OSError:  # no process left (ulimit), no memory for the page tables: a thread instead
                self._pid = None
        self._thread = threading.Thread(target=self._run_here, name="bakery-background", daemon=True)
        self._thread.start()

    # -- child ------------------------------------------------------------------------------------------------------
    def _fork(self) -> None:
        read, write = os.pipe()
        with _FORKING, warnings.catch_warnings():  # Python ≥ 3.12 warns on fork with threads: the child only
            warnings.simplefilter("ignore", DeprecationWarning)  # runs the call
            try:
                pid = os.fork()
            except OSError:
                os.close(read)
                os.close(write)
                raise
            if pid == 0:  # the child: never returns
                os.close(read)
                self._child(write)
            _CHILDREN.add(pid)
        os.close(write)
        self._pid, self._read = pid, read

    def _child(self, write: int) -> None:
        try:
            for number in (signal.SIGTERM, signal.SIGINT):
                signal.signal(number, signal.SIG_DFL)
            from bakery.pipeline.worker import _set_death_signal

            _set_death_signal()  # a killed bake leaves no writer behind
            try:
                answer = (True, self._fn(*self._args))
            except BaseException as error:  # noqa: BLE001 - every error goes back to the parent
                answer = (False, error)
            try:
                data = pickle.dumps(answer)
            except Exception:  # noqa: BLE001 - an unpicklable value or exception: its text
                data = pickle.dumps((False, RuntimeError(f"{type(answer[1]).__name__}: {answer[1]}")))
            with os.fdopen(write, "wb") as pipe:
                pipe.write(data)
        finally:
            os._exit(_ANSWERED)

    # -- parent -----------------------------------------------------------------------------------------------------
    def _run_here(self) -> None:
        try:
            self._outcome = (True, self._fn(*self._args))
        except BaseException as error:  # noqa: BLE001 - re-raised by result()
            self._outcome = (False, error)

    def _wait(self) -> tuple[bool, Any]:
        if self._outcome is not None:
            return self._outcome
        if self._thread is not None:
            self._thread.join()
            assert self._outcome is not None
            return self._outcome
        assert self._pid is not None and self._read is not None
        with os.fdopen(self._read, "rb") as pipe:
            self._read = None
            data = pipe.read()
        _, status = os.waitpid(self._pid, 0)
        _CHILDREN.discard(self._pid)
        self._pid = None
        if data and os.WIFEXITED(status) and os.WEXITSTATUS(status) == _ANSWERED:
            self._outcome = pickle.loads(data)
        else:  # the child died before answering: the call, here
            self._run_here()
        return self._outcome

    def result(self) -> Any:
        """Wait for the call; return its value or raise its exception."""
        ok, value = self._wait()
        if not ok:
            raise value
        return value

    def exception(self) -> BaseException | None:
        """Wait for the call; its exception, or None."""
        ok, value = self._wait()
        return None if ok else value

    def stop(self) -> None:
        """Kill a child still running and reap it, or wait for the thread (idempotent): once it returns, nothing of
        the call is still writing."""
        if self._thread is not None:
            self._thread.join()
        if self._pid is not None:
            try:
                os.kill(self._pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.waitpid(self._pid, 0)
            _CHILDREN.discard(self._pid)
            self._pid = None
        if self._read is not None:
            os.close(self._read)
            self._read = None

