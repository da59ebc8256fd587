"""Stopping a run on SIGTERM (and Ctrl-C) as reliably as on an error.

``pfx run`` turns SIGTERM into :class:`Interrupted`, a ``KeyboardInterrupt`` raised wherever the
program is, like Ctrl-C's. Python runs a signal handler between two bytecodes of the main
thread, and that can be inside a finaliser (``__del__``, a weakref callback), where an
exception is printed as "Exception ignored" and dropped: the run would then go on as if no
signal had come. So the handler also records the signal, and the runner checks the record
after every batch (:func:`raise_if_requested`): a stop asked for is never lost.
"""

from __future__ import annotations

import signal
from typing import Optional

_requested: Optional[int] = None          # the signal that asked the run to stop, if any


class Interrupted(KeyboardInterrupt):
    """SIGTERM (or another stop signal), raised where the program is, like Ctrl-C."""

    def __init__(self, signal_number: int):
        super().__init__(signal_number)
        self.signal_number = signal_number
        self.signal_name = signal.Signals(signal_number).name


def _stop(signal_number, frame):
    global _requested
    _requested = signal_number
    raise Interrupted(signal_number)


def stop_on_signals() -> None:
    """Make SIGTERM and SIGINT stop the run (the command line calls this once)."""
    global _requested
    _requested = None
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)


def raise_if_requested() -> None:
    """Raise :class:`Interrupted` if a stop signal came and its exception was swallowed."""
    if _requested is not None:
        raise Interrupted(_requested)
