"""Errors pfx reports to its user.

A :class:`ConfigError` is the user's mistake, not a bug: the command line prints it as one
line (file, key path, reason), exits with status 2 and writes nothing.
"""

from __future__ import annotations

import re

# A component's check locates its error below the component: ValueError("@sub.key: reason").
_LOCATED = re.compile(r"@([\w.\[\]]+): (.*)", re.S)


class ConfigError(Exception):
    """A problem with the user's input, located by file, key path and (for YAML) position."""

    def __init__(self, reason: str, *, file: str | None = None, key: str | None = None,
                 line: int | None = None, column: int | None = None):
        super().__init__(reason)
        self.reason = reason
        self.file = file
        self.key = key
        self.line = line
        self.column = column

    def located(self, *, file: str | None = None, key_prefix: str | None = None) -> "ConfigError":
        """The same error with the file filled in and/or a prefix added to the key path."""
        key = self.key
        if key_prefix:
            key = f"{key_prefix}.{key}" if key else key_prefix
        return ConfigError(self.reason, file=self.file or file, key=key,
                           line=self.line, column=self.column)

    def __str__(self) -> str:
        return " ".join(self._text().splitlines())       # always one line, whatever a key holds

    def _text(self) -> str:
        where = self.file or "<config>"
        if self.line is not None:
            where += f":{self.line}"
            if self.column is not None:
                where += f":{self.column}"
        if self.key:
            return f"{where}: {self.key}: {self.reason}"
        return f"{where}: {self.reason}"


def split_location(text: str) -> tuple[str, str]:
    """``"@sub.key: reason"`` -> ``("sub.key", "reason")``; any other text -> ``("", text)``.

    The one reader of the convention by which components (noises, laws, diffusions, filter
    kinds, model checks) say which key below them an error is about.
    """
    match = _LOCATED.match(text)
    return (match.group(1), match.group(2)) if match else ("", text)


def located_value_error(error: ValueError, *, prefix: str, file: str | None = None) -> ConfigError:
    """The ConfigError for a component check's ``ValueError("@sub.key: reason")`` under ``prefix``."""
    sub, reason = split_location(str(error))
    return ConfigError(reason, file=file, key=f"{prefix}.{sub}" if sub else prefix)


# An exception on its way out of a filter's or the truth's loop gets a note saying where:
# "at step 3 of the filter" (shown under a traceback, and in a plugin fault's one line).
STEP_NOTE_PREFIX = "at "


def note_step(error: BaseException, step: int, loop: str) -> None:
    """Add ``at step <step> of the <loop>`` to an exception leaving a filter's or the truth's
    loop, unless an inner loop said so already."""
    if not any(note.startswith(STEP_NOTE_PREFIX) for note in getattr(error, "__notes__", [])):
        error.add_note(f"{STEP_NOTE_PREFIX}step {step} of the {loop}")


class ModelNumericalError(RuntimeError):
    """A model produced NaN or infinity; the message names the model and the step."""


class ModelContractError(RuntimeError):
    """A model's method broke the contract while a run was under way (a result of the wrong
    shape for the run's batch, say, where the check on a tiny batch before the run passed);
    the message names the model, the method and the step."""


class PluginFault(RuntimeError):
    """An exception that came out of a plugin's code, or a contract a plugin's component broke,
    while a run was under way: one line naming the plugin file, the line in it, the component,
    the function and the exception (``walk.py:41: model hidden_walk: propagate raised
    RuntimeError: ... (step 3 of the filter)``).

    It crosses process boundaries (worker processes, Dask) as plain text: the original
    traceback, formatted where the exception was raised, travels in ``details`` for
    ``pfx --traceback``. The command line prints it in one line, exits with status 1 and keeps
    the finished cells, as for a model's NaN.
    """

    def __init__(self, line: str, details: str = ""):
        super().__init__(line)
        self.details = details

    def __reduce__(self):
        return (type(self), (str(self), self.details))


class UsageError(ConfigError):
    """A command-line request pfx cannot honour (an option, a missing optional extra, an
    unreachable scheduler): one line naming the option, exit status 2, nothing written."""

    def _text(self) -> str:
        return f"{self.key}: {self.reason}" if self.key else self.reason


class ExecutorError(RuntimeError):
    """The executor could not finish the run (a lost cluster, a task whose workers kept dying).

    Not the user's input and not a bug in a model: the command line prints one line, exits
    with status 1 and keeps the finished cells for a resume.
    """
