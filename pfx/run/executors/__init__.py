"""Executors: where the tasks of a run are computed.

A run is a list of tasks; a task is the argument tuple of one call of
:func:`pfx.run.batch.run_batch` (one cell, the root seed, a batch of its trials, ...). An
executor computes the tasks and hands back ``(index, result)`` pairs as they finish, in any
order; the runner writes each cell as soon as all its batches are back. Every trial draws
from its own random streams (:mod:`pfx.numerics.seeding`), so which executor computes a task, on which
machine and in which order, changes nothing in the results.

==============  ====================================================================
``local``       this process (``--workers 1``) or a pool of K local processes
``dask``        an existing Dask distributed cluster (``--scheduler ADDRESS``)
``dask-local``  a Dask cluster of K single-threaded worker processes, started on
                loopback for the run and stopped after it
==============  ====================================================================

The Dask executors live in :mod:`pfx.run.executors.dask` (what travels to the workers, fault
tolerance); Dask (``dask[distributed]``) is an optional extra, imported only when one of them
is asked for. Without it, asking for one is a one-line error naming the extra.
"""

from __future__ import annotations

import os
from typing import Callable, Optional

from pfx.errors import UsageError
from pfx.registry import Registry, closest_name
from pfx.run.executors.base import Executor
from pfx.run.executors.local import InProcess, ProcessPool

EXTRA_HINT = "pip install 'pfx[dask]'"

def _dask_cluster(**options) -> Executor:
    try:
        import distributed  # noqa: F401  (the optional extra; pfx.run.executors.dask imports it too)
    except ImportError:
        raise UsageError(f"the Dask executor needs the optional extra: {EXTRA_HINT}") from None
    from pfx.run.executors.dask import DaskCluster

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
