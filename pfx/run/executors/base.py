"""The executor interface: computes tasks and yields ``(index, result)`` as they finish."""

from __future__ import annotations

import signal
from typing import Any, Callable, Iterator, Optional, Sequence

Task = tuple                    # the positional arguments of one call of the task function
Results = Iterator[tuple[int, Any]]


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

def ignore_interrupts() -> None:
    """Worker initialiser: the parent process alone reacts to Ctrl-C and SIGTERM.

    Ctrl-C reaches every process of the terminal's process group; the parent stops the workers.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
