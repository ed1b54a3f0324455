"""Executors: run batch tasks and yield outcomes as they finish.

- :class:`SerialExecutor` — in-process (``--jobs 1``); the reference for determinism.
- :class:`ProcessExecutor` — a spawn-context process pool of N workers (default: the number of cores). A worker
  that dies (killed, out of memory) breaks the pool; the pool is rebuilt and unfinished tasks are resubmitted, each
  at most ``retries`` times, after which the task is reported as failed.
- :class:`DaskExecutor` — Dask distributed: an existing scheduler (``tcp://host:port``) or a ``LocalCluster``.
  Dask retries tasks whose worker died (``retries``).

All executors run the same tasks with the same batch composition, so the merged result — and the store bytes —
do not depend on the executor or the number of workers.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Protocol

from bakery.pipeline.plan import BatchTask
from bakery.pipeline.worker import BatchOutcome, run_batch


class Executor(Protocol):
    """Runs batch tasks and yields their outcomes as they finish (any order; the merge restores plan order)."""

    name: str
    workers: int

    def run(self, tasks: Iterable[BatchTask]) -> Iterator[BatchOutcome]: ...

    def close(self) -> None: ...


def _worker_init() -> None:
    # One BLAS thread per worker process: the pool provides the parallelism.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")


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


class ProcessExecutor:
    name = "processes"

    def __init__(self, workers: int | None = None, retries: int = 2) -> None:
        self.workers = workers or os.cpu_count() or 1
        self.retries = retries
        self._pool: ProcessPoolExecutor | None = None

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init)

    def run(self, tasks: Iterable[BatchTask]) -> Iterator[BatchOutcome]:
        pending = list(tasks)
        attempts = {t.key: 0 for t in pending}
        while pending:
            self._pool = self._new_pool()
            futures: dict[Future, BatchTask] = {self._pool.submit(run_batch, t): t for t in pending}
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
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)


class DaskExecutor:
    name = "dask"

    def __init__(self, scheduler: str | None = None, workers: int | None = None, retries: int = 2) -> None:
        from distributed import Client, LocalCluster

        self.retries = retries
        self._cluster = None
        if scheduler:
            self._client = Client(scheduler)
        else:
            self._cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                         processes=True, dashboard_address=None)
            self._client = Client(self._cluster)
        self.workers = len(self._client.scheduler_info().get("workers", {})) or (workers or 1)

    def run(self, tasks: Iterable[BatchTask]) -> Iterator[BatchOutcome]:
        from distributed import as_completed

        tasks = list(tasks)
        futures = [self._client.submit(run_batch, t, key=f"bakery-batch-{t.key}", retries=self.retries, pure=False)
                   for t in tasks]
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


def make_executor(jobs: int | None = None, scheduler: str | None = None, dask_local: bool = False) -> Executor:
    """``--scheduler`` → Dask client; ``--dask-local`` → Dask LocalCluster; ``--jobs 1`` → serial; else processes."""
    if jobs is not None and jobs < 1:
        from bakery.errors import ConfigError

        raise ConfigError(f"--jobs must be >= 1, got {jobs}")
    if scheduler or dask_local:
        return DaskExecutor(scheduler, jobs)
    if jobs == 1:
        return SerialExecutor()
    return ProcessExecutor(jobs)
