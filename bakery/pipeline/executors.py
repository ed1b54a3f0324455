"""Executors: run batch tasks and yield outcomes as they finish.

- :class:`SerialExecutor` — in-process (``--jobs 1``); the reference for determinism.
- :class:`ProcessExecutor` — a spawn-context process pool of N workers (default: the number of cores). A worker
  that dies (killed, out of memory) breaks the pool; the pool is rebuilt and unfinished tasks are resubmitted, each
  at most ``retries`` times, after which the task is reported as failed. A pool that broke before it was given the
  tasks (a worker killed while the pool that :meth:`~ProcessExecutor.start` spawned during planning waits) is
  rebuilt without counting an attempt, at most ``retries`` times.
- :class:`DaskExecutor` — Dask distributed: an existing scheduler (``tcp://host:port``) or a ``LocalCluster``.
  Dask retries tasks whose worker died (``retries``).

All executors run the same tasks with the same batch composition, so the merged result — and the store bytes —
do not depend on the executor or the number of workers.

Workers die with the bake: pool workers get the parent-death signal (Linux ``PR_SET_PDEATHSIG``) and, like the
workers of a ``LocalCluster``, watch the parent's pid (:func:`bakery.pipeline.worker.watch_parent`), so killing
only the parent (even with SIGKILL) leaves no worker running. Ctrl-C reaches the whole process group: every worker
(also of a rebuilt pool) starts with SIGINT blocked and ignores it from its initializer on, and only the parent acts
on it (:func:`_workers_start_shielded`). A scheduler that cannot be reached is a
:class:`SchedulerError` (exit 2) after a short connect timeout, not a traceback.

Spawned workers import the ``__main__`` script again. A script that calls :func:`bakery.bake` with worker processes
at its top level, outside ``if __name__ == "__main__":``, would re-run the bake in every worker (which then fails on
the store's lock, and the bake on "worker process died"); the executors refuse it before any work, naming the
script's line (:func:`unguarded_main_line`).
"""

from __future__ import annotations

import ast
import importlib
import logging
import multiprocessing
import os
import signal
import socket
import sys
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Protocol

from bakery.errors import ConfigError, InputError
from bakery.pipeline.plan import BatchTask
from bakery.pipeline.worker import (
    PARENT_ENVIRONMENT,
    BatchOutcome,
    run_batch,
    watch_parent,
)

#: Seconds to wait for a Dask scheduler to answer (``BAKERY_SCHEDULER_TIMEOUT`` overrides).
SCHEDULER_TIMEOUT = 10.0


class SchedulerError(InputError):
    """The Dask scheduler given by ``--scheduler`` cannot be reached (or went away)."""


class Executor(Protocol):
    """Runs batch tasks and yields their outcomes as they finish (any order; the merge restores plan order)."""

    name: str
    workers: int

    def run(self, tasks: Iterable[BatchTask]) -> Iterator[BatchOutcome]: ...

    def close(self) -> None: ...


#: One BLAS/OpenMP thread per worker process: the pool provides the parallelism (N workers × N BLAS threads on N
#: cores oversubscribe them). BLAS reads these when numpy is imported, so they must be in a worker's environment when
#: it starts (:func:`_single_threaded_children`): setting them in the worker's initializer is too late.
WORKER_THREAD_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextmanager
def _single_threaded_children() -> Iterator[None]:
    """:data:`WORKER_THREAD_ENVIRONMENT` in this process's environment while worker processes are started (values the
    user set are kept), restored afterwards; this process's own BLAS is already initialised and unaffected."""
    saved = {k: os.environ.get(k) for k in WORKER_THREAD_ENVIRONMENT}
    for key, value in WORKER_THREAD_ENVIRONMENT.items():
        os.environ.setdefault(key, value)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


@contextmanager
def _children_ignore_interrupt() -> Iterator[None]:
    """SIGINT ignored while child processes are started (they inherit it through fork and exec, and Python and
    asyncio keep an ignored SIGINT ignored): Ctrl-C reaches the whole process group, and only this process should
    act on it. Restored afterwards; a no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextmanager
def _workers_start_shielded() -> Iterator[None]:
    """While pool workers are started (spawn: fork and exec of a new interpreter, which then imports bakery for
    ≈ 1 s): SIGINT is blocked in this thread, so that each worker starts with it blocked — the signal mask survives
    fork and exec — until :func:`_worker_init` ignores it (which discards one that arrived meanwhile) and unblocks
    it; and a Ctrl-C that reaches this process meanwhile is held and raised as ``KeyboardInterrupt`` once the workers
    have started, not lost. Ctrl-C reaches the whole process group: before, a worker still importing was killed by
    it with a traceback, the pool was rebuilt and the bake could go on. (Ignoring SIGINT, as for a ``LocalCluster``
    (:func:`_children_ignore_interrupt`), would also drop a Ctrl-C meant for this process.) A no-op outside the main
    thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from multiprocessing import resource_tracker

    # Started now if it is not running: it blocks and then unblocks SIGINT around its own start, which inside this
    # block would unblock it for the workers too.
    resource_tracker.ensure_running()
    held: list[int] = []
    previous = signal.getsignal(signal.SIGINT)
    hold = callable(previous)  # a Python handler (Ctrl-C → KeyboardInterrupt); SIG_IGN / SIG_DFL are left as they are
    if hold:
        signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a SIGINT pending meanwhile is handled here: held
        if hold:
            signal.signal(signal.SIGINT, previous)
            if held:
                previous(signal.SIGINT, None)  # the Ctrl-C, now that the workers are started (shielded)


def _worker_init(parent: int | None = None, modules: tuple[str, ...] = ()) -> None:
    # Ctrl-C reaches the whole process group: the parent stops the bake and its workers; a worker interrupted
    # mid-batch would only print a traceback of its own. The worker started with SIGINT blocked
    # (:func:`_workers_start_shielded`): ignoring it discards a Ctrl-C that arrived since, then it is unblocked.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    watch_parent(parent, death_signal=True)
    for module in modules:  # e.g. the source's (USD, Embree): imported before the first batch arrives
        try:
            importlib.import_module(module)
        except Exception:  # noqa: BLE001 - a warm-up only: a batch that needs the module reports its own error
            pass


def _started() -> None:
    """A task that only makes a pool start its workers."""


def parent_token() -> str:
    """``host:pid`` of this process, for workers that must die with it (:data:`PARENT_ENVIRONMENT`)."""
    return f"{socket.gethostname()}:{os.getpid()}"


def _failed(task: BatchTask, message: str) -> BatchOutcome:
    return BatchOutcome(task.key, None, {t.probe.name: message for t in task.probes})


class SerialExecutor:
    name = "serial"
    workers = 1

    def run(self, tasks: Iterable[BatchTask]) -> Iterator[BatchOutcome]:
        for task in tasks:
            yield run_batch(task)

    def close(self) -> None:
        pass


def _is_main_test(test: ast.expr) -> bool:
    """``__name__ == "__main__"`` (either way round)."""
    if not (isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.Eq)):
        return False
    sides = (test.left, test.comparators[0])
    return (any(isinstance(side, ast.Name) and side.id == "__name__" for side in sides)
            and any(isinstance(side, ast.Constant) and side.value == "__main__" for side in sides))


def unguarded_main_line() -> tuple[str, int] | None:
    """(script, line) of the top-level statement of the running ``__main__`` script that led to this call, when it
    is not inside an ``if __name__ == "__main__":`` block — what spawned workers would run again as they import the
    script; None when it is guarded, or there is no script (interactive, ``-c``, a notebook)."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if not path or not str(path).endswith(".py"):
        return None
    frame, line = sys._getframe(1), None
    while frame is not None:  # the outermost frame of the script's own top-level code
        if frame.f_globals is vars(main) and frame.f_code.co_name == "<module>":
            line = frame.f_lineno
        frame = frame.f_back
    if line is None:
        return None
    try:
        tree = ast.parse(Path(path).read_bytes())
    except (OSError, SyntaxError, ValueError):
        return None
    guarded = any(isinstance(node, ast.If) and _is_main_test(node.test)
                  and node.body[0].lineno <= line <= (node.body[-1].end_lineno or line)
                  for node in ast.walk(tree))
    return None if guarded else (str(path), line)


def refuse_unguarded_script(what: str) -> None:
    """ConfigError if the ``__main__`` script starts ``what`` (spawned worker processes) from unguarded top-level
    code (:func:`unguarded_main_line`)."""
    where = unguarded_main_line()
    if where is not None:
        raise ConfigError(f"{where[0]}:{where[1]}: this bake starts {what}, which import the script again and would "
                          "re-run its top-level code, this bake included; put the bake under "
                          "`if __name__ == \"__main__\":` (or bake with jobs=1)")


class ProcessExecutor:
    name = "processes"

    def __init__(self, workers: int | None = None, retries: int = 2) -> None:
        refuse_unguarded_script("worker processes")
        self.workers = workers or os.cpu_count() or 1
        self.retries = retries
        self._pool: ProcessPoolExecutor | None = None

    def _new_pool(self, modules: tuple[str, ...] = ()) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init, initargs=(os.getpid(), modules))

    def start(self, modules: tuple[str, ...] = ()) -> None:
        """Start the workers now — spawning one and importing bakery take ≈ 1 s — so that they start while the
        parent reads and plans the bake; ``modules`` are imported in each worker as it starts. The first
        :meth:`run` uses this pool."""
        if self._pool is None:
            try:
                # a spawn pool starts a worker per submit while none is idle
                with _workers_start_shielded(), _single_threaded_children():
                    self._pool = self._new_pool(modules)
                    for _ in range(self.workers):
                        self._pool.submit(_started)
            except BrokenProcessPool:  # a worker died at once: :meth:`run` starts a new pool
                self._drop_pool()

    def run(self, tasks: Iterable[BatchTask]) -> Iterator[BatchOutcome]:
        try:
            yield from self._run(list(tasks))
        finally:  # the caller stopped early (an error writing a checkpoint, SIGTERM): stop the workers now
            self.close()

    def _run(self, pending: list[BatchTask]) -> Iterator[BatchOutcome]:
        attempts = {t.key: 0 for t in pending}
        restarts = 0  # pools found broken before they were given the batches (a worker killed while starting)
        while pending:
            try:
                # a spawn pool starts its workers as the tasks are submitted (also a pool rebuilt after a worker died)
                with _workers_start_shielded(), _single_threaded_children():
                    self._pool = self._pool or self._new_pool()  # the pool :meth:`start` started, else a new one
                    futures: dict[Future, BatchTask] = {self._pool.submit(run_batch, t): t for t in pending}
            except BrokenProcessPool:  # no batch ran in it: a new pool, the batches not counted as attempted
                self._drop_pool()
                restarts += 1
                if restarts > self.retries:
                    for task in pending:
                        yield _failed(task, f"the worker processes died {restarts} times before this batch started")
                    return
                continue
            pending = []
            broken = False
            while futures:
                done, _ = wait(futures, return_when=FIRST_COMPLETED)
                for future in done:
                    task = futures.pop(future)
                    try:
                        yield future.result()
                    except BrokenProcessPool:
                        broken = True
                        attempts[task.key] += 1
                        if attempts[task.key] > self.retries:
                            yield _failed(task, f"worker process died {attempts[task.key]} times on this batch")
                        else:
                            pending.append(task)
                    except Exception as error:  # noqa: BLE001 - reported per probe, the bake goes on
                        yield _failed(task, f"{type(error).__name__}: {error}")
                if broken:
                    # Every other future of a broken pool fails too; requeue them without counting an attempt.
                    for future, task in futures.items():
                        if future.done() and not future.exception():
                            yield future.result()
                        else:
                            pending.append(task)
                    futures = {}
            self._drop_pool()

    def _drop_pool(self) -> None:
        """Shut down the current pool (done, or broken) and forget it: the next :meth:`run` starts a new one."""
        pool, self._pool = self._pool, None
        pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        """Stop a pool that is still running: terminate its workers (a running batch would otherwise finish first),
        then shut it down and join its manager thread, so that nothing of it is left for the interpreter's exit
        (CPython's exit hook otherwise races with the closed pool: "Bad file descriptor")."""
        if self._pool is not None:
            pool, self._pool = self._pool, None
            for process in list((getattr(pool, "_processes", None) or {}).values()):
                process.terminate()
            pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
    name = "dask"

    def __init__(self, scheduler: str | None = None, workers: int | None = None, retries: int = 2) -> None:
        from distributed import Client, LocalCluster

        self.retries = retries
        self._cluster = None
        if scheduler:
            timeout = float(os.environ.get("BAKERY_SCHEDULER_TIMEOUT", SCHEDULER_TIMEOUT))
            _reachable(scheduler, timeout)
            try:
                self._client = Client(scheduler, timeout=f"{timeout}s")
            except (OSError, TimeoutError) as error:
                raise SchedulerError(f"cannot connect to the Dask scheduler at {scheduler}: "
                                     f"{_reason(error)}") from None
        else:
            refuse_unguarded_script("a Dask LocalCluster's worker processes")
            with _children_ignore_interrupt():  # the nannies and their workers inherit SIGINT ignored (Ctrl-C)
                # silence_logs: what Dask logs about its own cluster (tasks lost or cancelled when a Ctrl-C or an
                # error drops the unfinished batches on purpose, a worker's heartbeat failing as the scheduler
                # closes, workers killed on the way out) says nothing to a bake's user; a batch that fails comes
                # back through its future and is reported by the bake itself.
                self._cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                             processes=True, dashboard_address=None, silence_logs=logging.CRITICAL,
                                             env={PARENT_ENVIRONMENT: parent_token()})
            self._client = Client(self._cluster)
        self.workers = len(self._client.scheduler_info().get("workers", {})) or (workers or 1)

    def run(self, tasks: Iterable[BatchTask]) -> Iterator[BatchOutcome]:
        from distributed import as_completed

        tasks = list(tasks)
        try:
            futures = [self._client.submit(run_batch, t, key=f"bakery-batch-{t.key}", retries=self.retries,
                                           pure=False) for t in tasks]
        except (OSError, TimeoutError) as error:
            raise SchedulerError(f"lost the Dask scheduler: {_reason(error)}") from None
        by_key = {f.key: t for f, t in zip(futures, tasks)}
        for future in as_completed(futures):
            task = by_key[future.key]
            try:
                yield future.result()
            except Exception as error:  # noqa: BLE001
                yield _failed(task, f"{type(error).__name__}: {error}")

    def close(self) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


def _reason(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


def _reachable(address: str, timeout: float) -> None:
    """Fail fast (connection refused, unknown host) for tcp/tls addresses before Dask's retry loop."""
    scheme, _, rest = address.partition("://") if "://" in address else ("tcp", "", address)
    if scheme not in ("tcp", "tls") or ":" not in rest:
        return
    host, _, port = rest.rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=min(timeout, 5.0)):
            pass
    except (OSError, ValueError) as error:
        reason = getattr(error, "strerror", None) or str(error) or type(error).__name__
        raise SchedulerError(f"cannot connect to the Dask scheduler at {address}: {reason}") from None


def make_executor(jobs: int | None = None, scheduler: str | None = None, dask_local: bool = False) -> Executor:
    """``--scheduler`` → Dask client; ``--dask-local`` → Dask LocalCluster; ``--jobs 1`` → serial; else processes."""
    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise ConfigError(f"--jobs must be an integer >= 1, got {jobs!r}")
    if scheduler or dask_local:
        return DaskExecutor(scheduler, jobs)
    if jobs == 1:
        return SerialExecutor()
    return ProcessExecutor(jobs)
