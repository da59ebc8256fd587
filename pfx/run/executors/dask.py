"""The Dask executor: a run's tasks on a Dask distributed cluster (``--executor dask|dask-local``).

The client (the ``pfx run`` process) submits every task, a :func:`pfx.run.batch.run_batch`
argument tuple, with :meth:`distributed.Client.submit` and takes the results back with
:func:`distributed.as_completed`; the runner writes each cell when its batches are back, so
the CSV files are written by the client alone, atomically and resumably as for local runs.

* What travels to a worker: the task's arguments, pickled (the resolved cell with its models,
  filter and metric settings; the root seed; the trial numbers; the trace count). The config
  file does not. What travels back: the batch's table rows.
* Workers need the same pfx version installed: checked when connecting, through
  :meth:`distributed.Client.get_versions`.
* Fault tolerance is Dask's: when a worker dies, the scheduler runs its tasks on other
  workers (a task whose workers die ``distributed.scheduler.allowed-failures`` times fails
  the run, which keeps its finished cells). Tasks are not retried on exceptions: a batch is a
  deterministic function of its arguments, so a retry would fail the same way.
* Task keys are ``pfx-batch-<run token>-<index>``: unique per run (two runs never share a
  result), readable on the Dask dashboard. Earlier tasks get higher priority, so cells
  finish, and are saved, roughly in order.

This module imports Dask; :mod:`pfx.run.executors` imports it only when a Dask executor is asked for.
"""

from __future__ import annotations

import logging
import uuid
from typing import Callable, Optional, Sequence

import dask.config
import distributed

import pfx
from pfx.errors import ExecutorError, UsageError
from pfx.run.executors.base import Executor, Results, Task, ignore_interrupts

# Dask settings for the workers of the clusters pfx starts (docs/dask.md: the same for your own).
# Dask's nannies set MALLOC_TRIM_THRESHOLD_ in their workers, which turns off glibc's adaptive
# mmap threshold: every particle-sized array then comes fresh from the kernel, and the filter
# spends about three times the CPU time (measured). The workers' statistical profiler (a
# stack sample every 10 ms, for the dashboard) costs another 10% or so of CPU time (measured).
WORKER_SETTINGS = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.worker.profile.enabled": False,
}


class IgnoreInterrupts(distributed.WorkerPlugin):
    """Worker plugin for the clusters pfx starts: Ctrl-C, which reaches the whole process
    group, is left to the ``pfx run`` process, which cancels the run and closes the cluster."""

    def setup(self, worker) -> None:
        ignore_interrupts()


class DaskCluster(Executor):
    """Tasks submitted to a Dask distributed cluster through a :class:`distributed.Client`.

    With ``scheduler`` it connects to that scheduler (``tcp://host:8786``); otherwise it
    starts a :class:`distributed.LocalCluster` of ``workers`` single-threaded worker
    processes on loopback, owned by this executor and closed with it.
    """

    counts = "tasks"

    def __init__(self, scheduler: Optional[str] = None, workers: Optional[int] = None):
        self.scheduler = scheduler
        self.workers = workers
        self.client: Optional[distributed.Client] = None
        self.cluster: Optional[distributed.LocalCluster] = None
        self._pending: dict = {}           # key -> (index, future) of the tasks not yet returned
        self._settings = None              # WORKER_SETTINGS in force, for a cluster of our own
        self._log_levels: dict = {}        # client-side loggers quietened while the client lives

    def __enter__(self) -> "DaskCluster":
        self._quiet_client_logs()
        try:
            if self.scheduler is None:
                self._start_local_cluster()
            else:
                self._connect()
                self._check_versions()
        except BaseException:
            self.close(abandon=True)
            raise
        self.slots = max(1, sum(self.client.nthreads().values()))
        return self

    def _start_local_cluster(self) -> None:
        # The settings hold while the cluster lives: its nannies read them again when they
        # restart a worker. Loopback only; the dashboard on a free port (a fixed one would
        # clash with another run's). The workers' own logs stay quiet (their shutdown races log
        # tracebacks); what matters comes back through the client: a task's exception, a
        # worker's death.
        self._settings = dask.config.set(WORKER_SETTINGS)
        self.cluster = distributed.LocalCluster(
            n_workers=self.workers, threads_per_worker=1, processes=True, host="127.0.0.1",
            dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL)
        self.client = distributed.Client(self.cluster, set_as_default=False)
        self.client.register_plugin(IgnoreInterrupts(), name="pfx-ignore-interrupts")

    def _connect(self) -> None:
        try:
            self.client = distributed.Client(self.scheduler, set_as_default=False)
        except (OSError, ValueError, TypeError) as error:     # refused, timed out, malformed
            reason = " ".join(str(error).split()) or type(error).__name__
            raise UsageError(f"cannot connect to the Dask scheduler at {self.scheduler}: {reason}",
                             key="--scheduler") from None

    def _check_versions(self) -> None:
        """Refuse workers without this pfx: they would fail, or compute with other code."""
        versions = self.client.get_versions(packages=["pfx"])
        # Both sides are read the same way (installed package metadata), so they compare.
        ours = (versions.get("client", {}).get("packages") or {}).get("pfx") or pfx.__version__
        for address, info in sorted(versions.get("workers", {}).items()):
            theirs = (info.get("packages") or {}).get("pfx")
            if theirs != ours:
                found = f"pfx {theirs}" if theirs else "no pfx"
                raise UsageError(f"the Dask worker {address} has {found}, this client pfx {ours}; "
                                 "workers need the same pfx version installed", key="--scheduler")

    def describe(self) -> str:
        where = (f"a local Dask cluster at {self.cluster.scheduler_address}" if self.cluster is not None
                 else f"the Dask cluster at {self.scheduler}")
        return f"{where}: {len(self.client.nthreads())} worker(s), {self.slots} thread(s)"

    def run(self, function: Callable, tasks: Sequence[Task]) -> Results:
        token = uuid.uuid4().hex[:12]
        pending = self._pending = {}
        for index, arguments in enumerate(tasks):
            future = self.client.submit(function, *arguments, key=f"pfx-batch-{token}-{index}",
                                        priority=len(tasks) - index, pure=False)
            pending[future.key] = (index, future)
        # Results are fetched in the background as tasks finish (with_results), not one
        # round trip per task; a task's exception is raised here, as the local executors do.
        finished = distributed.as_completed([future for _, future in pending.values()],
                                            loop=self.client.loop, with_results=True)
        try:
            for future, result in self._translated(finished):
                index, _ = pending.pop(future.key)
                future.release()           # the cluster may now forget the result
                yield index, result
        except BaseException:
            self._cancel()
            raise

    def _translated(self, finished):
        """Dask's failures of the cluster itself, as one-line :class:`ExecutorError` s."""
        try:
            yield from finished
        except distributed.KilledWorker as error:
            raise ExecutorError("Dask workers kept dying while running a batch: "
                                + " ".join(str(error).split())) from None
        except distributed.CancelledError:
            raise ExecutorError(f"the Dask scheduler at {self._address()} dropped the run's tasks "
                                "(lost or restarted?)") from None

    def _cancel(self) -> None:
        """Drop the tasks not yet returned, so that the cluster stops working for this run."""
        futures, self._pending = [future for _, future in self._pending.values()], {}
        if futures and self.client is not None:
            try:
                self.client.cancel(futures)
            except Exception:          # the cluster is gone already: nothing left to stop
                pass

    def _address(self) -> str:
        return self.scheduler or (self.cluster.scheduler_address if self.cluster is not None else "?")

    def close(self, abandon: bool = False) -> None:
        if abandon:
            self._cancel()
        client, self.client = self.client, None
        cluster, self.cluster = self.cluster, None
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        settings, self._settings = self._settings, None
        if settings is not None:
            settings.__exit__(None, None, None)
        for name, level in self._log_levels.items():
            logging.getLogger(name).setLevel(level)
        self._log_levels = {}

    def _quiet_client_logs(self) -> None:
        """While pfx holds the client, a lost worker or connection is reported by pfx itself, in
        one line (:meth:`_translated`); the same failure must not also reach the user as
        the traceback tornado's event loop logs when one of the client's own callbacks meets the
        closed connection (``tornado.application``: "Exception in callback ...")."""
        for name in ("tornado.application", "distributed.client"):
            self._log_levels[name] = logging.getLogger(name).level
            logging.getLogger(name).setLevel(logging.CRITICAL)
