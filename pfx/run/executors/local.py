"""Executors on this machine: this process, or a pool of local worker processes."""

from __future__ import annotations

import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Callable, Optional, Sequence

from pfx.run.executors.base import Executor, Results, Task, ignore_interrupts


class InProcess(Executor):
    """Each task in turn, in this process."""

    def run(self, function: Callable, tasks: Sequence[Task]) -> Results:
        for index, arguments in enumerate(tasks):
            yield index, function(*arguments)

class ProcessPool(Executor):
    """A pool of local worker processes (``concurrent.futures``)."""

    def __init__(self, workers: int):
        self.slots = workers
        self._pool: Optional[ProcessPoolExecutor] = None

    def run(self, function: Callable, tasks: Sequence[Task]) -> Results:
        if self._pool is None:
            # JAX runs threads of its own, which a forked child would inherit locked: once the
            # jax backend has been loaded (a config's cells on jax), workers start from a fresh
            # server process instead (plain numpy runs fork, as they always did)
            context = multiprocessing.get_context("forkserver") if "jax" in sys.modules else None
            self._pool = ProcessPoolExecutor(max_workers=self.slots, initializer=ignore_interrupts, mp_context=context)
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
