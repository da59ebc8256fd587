"""Executors: where the tasks of a run are computed.

A run is a list of tasks; a task is the argument tuple of one call of
:func:`pfx.runner.run_batch` (one cell, the root seed, a batch of its trials, ...). An
executor computes the tasks and hands back ``(index, result)`` pairs as they finish, in any
order; the runner writes each cell as soon as all its batches are back. Every trial draws
from its own random streams (:mod:`pfx.seeding`), so which executor computes a task, on which
machine and in which order, changes nothing in the results.

==============  ====================================================================
``local``       this process (``--workers 1``) or a pool of K local processes
``dask``        an existing Dask distributed cluster (``--scheduler ADDRESS``)
``dask-local``  a Dask cluster of K single-threaded worker processes, started on
                loopback for the run and stopped after it
==============  ====================================================================

The Dask executors live in :mod:`pfx.dask_cluster` (what travels to the workers, fault
tolerance); Dask (``dask[distributed]``) is an optional extra, imported only when one of them
is asked for. Without it, asking for one is a one-line error naming the extra.
"""

from __future__ import annotations

import os
import signal
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, Callable, Iterator, Optional, Sequence

from pfx.errors import UsageError
from pfx.registry import Registry, closest_name

Task = tuple                    # the positional arguments of one call of the task function
Results = Iterator[tuple[int, Any]]

EXTRA_HINT = "pip install 'pfx[dask]'"


class Executor:
    """Computes tasks, yielding ``(index, result)`` as they finish; a context manager.

    ``slots`` is how many tasks run at once (the memory budget is shared among them), and
    ``counts`` what the progress bar counts: ``"trials"`` or ``"tasks"``.
    """

    slots: int = 1
    counts: str = "trials"

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, kind, error, traceback) -> None:
        self.close(abandon=kind is not None)

    def describe(self) -> Optional[str]:
        """A line saying where the work runs (None when it is just here)."""
        return None

    def run(self, function: Callable, tasks: Sequence[Task]) -> Results:
        raise NotImplementedError

    def close(self, abandon: bool = False) -> None:
        """Release the workers; ``abandon``: at once, dropping the tasks still in flight."""


class InProcess(Executor):
    """Each task in turn, in this process."""

    def run(self, function: Callable, tasks: Sequence[Task]) -> Results:
        for index, arguments in enumerate(tasks):
            yield index, function(*arguments)


def ignore_interrupts() -> None:
    """Worker initialiser: the parent process alone reacts to Ctrl-C and SIGTERM.

    Ctrl-C reaches every process of the terminal's process group; the parent stops the workers.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


class ProcessPool(Executor):
    """A pool of local worker processes (``concurrent.futures``)."""

    def __init__(self, workers: int):
        self.slots = workers
        self._pool: Optional[ProcessPoolExecutor] = None

    def run(self, function: Callable, tasks: Sequence[Task]) -> Results:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=self.slots, initializer=ignore_interrupts)
        index_of = {self._pool.submit(function, *arguments): index for index, arguments in enumerate(tasks)}
        try:
            for future in as_completed(index_of):
                yield index_of.pop(future), future.result()
        except BaseException:          # an interrupt, a failed task, or the runner giving up
            self._abort()
            raise

    def _abort(self) -> None:
        """Stop at once, the batches still running included."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        in_flight = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for process in in_flight:
            process.terminate()

    def close(self, abandon: bool = False) -> None:
        if abandon:
            self._abort()
        elif self._pool is not None:
            self._pool.shutdown()
            self._pool = None


def _dask_cluster(**options) -> Executor:
    try:
        import distributed  # noqa: F401  (the optional extra; pfx.dask_cluster imports it too)
    except ImportError:
        raise UsageError(f"the Dask executor needs the optional extra: {EXTRA_HINT}") from None
    from pfx.dask_cluster import DaskCluster

    return DaskCluster(**options)


EXECUTORS: Registry[Callable[..., Executor]] = Registry("executor")


@EXECUTORS.register("local")
def local_executor(workers: Optional[int], scheduler: Optional[str]) -> Executor:
    """This process, or --workers K local processes (the default)."""
    if scheduler is not None:
        raise UsageError("only --executor dask connects to a scheduler", key="--scheduler")
    return ProcessPool(workers) if workers and workers > 1 else InProcess()


@EXECUTORS.register("dask")
def dask_executor(workers: Optional[int], scheduler: Optional[str]) -> Executor:
    """An existing Dask distributed cluster, at --scheduler ADDRESS."""
    if workers is not None:
        raise UsageError("a Dask cluster has its own workers; --workers is for --executor local or "
                         "dask-local", key="--workers")
    if not scheduler:
        raise UsageError("--executor dask needs --scheduler ADDRESS (e.g. tcp://host:8786); "
                         "--executor dask-local starts a cluster here")
    return _dask_cluster(scheduler=scheduler)


@EXECUTORS.register("dask-local")
def dask_local_executor(workers: Optional[int], scheduler: Optional[str]) -> Executor:
    """A Dask cluster of --workers K processes on this machine (default: one per CPU)."""
    if scheduler is not None:
        raise UsageError("dask-local starts its own scheduler; use --executor dask to connect to one",
                         key="--scheduler")
    return _dask_cluster(workers=workers or os.cpu_count() or 1)


def make_executor(name: str, workers: Optional[int] = None, scheduler: Optional[str] = None) -> Executor:
    """The executor called ``name`` (one of :data:`EXECUTORS`); nothing is started yet."""
    if name not in EXECUTORS:
        hint = closest_name(name, EXECUTORS)
        raise UsageError(f"unknown executor {name!r}" + (f" (did you mean {hint!r}?)" if hint else "")
                         + f"; choose from {', '.join(EXECUTORS)}", key="--executor")
    return EXECUTORS[name](workers, scheduler)
