"""The progress bar of a long run, on stderr: how far it is, how fast it goes, the time left.

Every long run shows one, drawn by rich: a filter run counts its trials (or its executor's
tasks) over all cells (:mod:`pfx.run.runner`); PMMH and IF2 count their iterations over all
cells, as the method reports them (on jax, a compiled block's when it returns), and the pilot
of ``particles: auto`` its rungs, weighed by their particle counts (:mod:`pfx.run.estimation`,
:mod:`pfx.run.particle_count_pilot`). rich shows one live display at a time, so work inside a
bar's (the pilot again after PMMH's warm-up) says so in that bar's description. The bar goes
to stderr, so stdout keeps its tables, and it is transient: it is erased when the work ends,
leaving the lines the run printed (rich prints them above the bar while it shows).

Whether a run shows it is decided once, by :func:`show_progress`: never with ``--quiet``; else
where stderr is a terminal, except in CI (``CI`` set: a log, not a screen). rich's own
``TTY_COMPATIBLE`` overrides both ways: ``1`` says the output is a terminal (a bar is shown,
in CI too), ``0`` that it is not. A run that shows nothing gets :data:`NO_BAR`, whose methods do
nothing: its cost is one empty call per iteration, and nothing of rich is imported.

The bar never changes what a run computes or writes: it only counts what the run reports.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from functools import cache
from typing import Iterator


def show_progress(quiet: bool) -> bool:
    """Whether a run shows its progress bar (module docstring)."""
    terminal = os.environ.get("TTY_COMPATIBLE", "")
    if quiet or terminal == "0":
        return False
    if terminal == "1":
        return True
    return sys.stderr.isatty() and not os.environ.get("CI")


class Bar:
    """One task of a live rich display: :meth:`advance` as work is done, :meth:`describe` to
    say what it is doing now, :meth:`resize` when the work left turns out other than thought."""

    def __init__(self, display, task):
        self.display, self.task = display, task

    def advance(self, amount: float = 1) -> None:
        self.display.advance(self.task, amount)

    def describe(self, text: str) -> None:
        self.display.update(self.task, description=text, refresh=True)     # seldom, and worth showing at once

    def resize(self, total: float) -> None:
        self.display.update(self.task, total=total)


class _NoBar:
    """What a run that shows nothing counts with: every method does nothing."""

    def advance(self, amount: float = 1) -> None:
        pass

    def describe(self, text: str) -> None:
        pass

    def resize(self, total: float) -> None:
        pass


NO_BAR = _NoBar()


@contextmanager
def progress_bar(enabled: bool, total: float, name: str, counts: str = "trials", *,
                 counted: bool = True) -> Iterator[Bar | _NoBar]:
    """A bar on stderr for ``total`` units of work while the block runs (:data:`NO_BAR` when not
    ``enabled`` or there is no work). ``name`` starts the line (:meth:`Bar.describe` changes
    it); ``counts`` names the units (``"trials"``, ``"iterations"``). ``counted``: the units are
    the user's (shown as "12/2000 iterations" with their rate); else they only weigh the work (a
    pilot's rungs, whose cost grows with N), and the bar shows a percentage."""
    if not enabled or total <= 0:
        yield NO_BAR
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TaskProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    amount = (MofNCompleteColumn(), TextColumn(counts), _rate_class()()) if counted else (TaskProgressColumn(),)
    display = Progress(TextColumn("{task.description}", markup=False), BarColumn(bar_width=24), *amount,
                       TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), transient=True,
                       console=Console(stderr=True))
    with display:
        yield Bar(display, display.add_task(name, total=total))


@cache
def _rate_class():
    """The rate column's class, made on first use (rich is imported only when a bar shows)."""
    from rich.progress import ProgressColumn
    from rich.text import Text

    class Rate(ProgressColumn):
        """The units per second ("12.5/s"), or the seconds per unit where one takes longer ("3.2 s each")."""

        def render(self, task) -> Text:
            speed = task.finished_speed or task.speed
            if not speed:
                return Text("")
            return Text(f"{speed:.3g}/s" if speed >= 1 else f"{1 / speed:.3g} s each", style="progress.data.speed",
                        no_wrap=True)

    return Rate
