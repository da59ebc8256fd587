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


class ModelNumericalError(RuntimeError):
    """A model produced NaN or infinity; the message names the model and the step."""


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
