"""Reading a file a user names (a config, a recorded-data table, a wall map), safely.

A path in a config can name anything: a named pipe (``open`` blocks until a writer comes,
possibly forever), ``/dev/zero`` or ``/dev/urandom`` (reading never ends, until memory runs
out), a folder, a socket, or a file far larger than any config. :func:`read_user_file` reads
only a regular file (a symbolic link to one is fine) and at most a given number of bytes:

* the path is checked with ``os.stat`` before it is opened, so a pipe or device is refused
  without being touched;
* it is opened without blocking (``O_NONBLOCK``, which changes nothing for a regular file) and
  the open descriptor is checked again, so a path swapped for a pipe in between cannot hang
  the read;
* at most ``max_bytes + 1`` bytes are read, whatever size the file reports (``/proc`` files
  report 0, a file may grow while it is read), and one byte more than the limit refuses it.

Problems are :class:`UnreadableFile` with a reason in words; each caller turns it into its own
error (a :class:`~pfx.errors.ConfigError` naming the file and the key that gave the path).
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

_CHUNK_BYTES = 1024 * 1024


class UnreadableFile(Exception):
    """A file pfx will not read; ``reason`` says why, as a predicate ("is a named pipe ...").

    ``missing`` is True when there is nothing at the path (or a part of the path is not a
    folder): callers word that case themselves ("no such file").
    """

    def __init__(self, reason: str, *, missing: bool = False):
        super().__init__(reason)
        self.reason = reason
        self.missing = missing


def _kind_of_file(mode: int) -> str | None:
    """Why a file of this ``st_mode`` is refused, or None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "is a directory, not a file"
    if stat.S_ISFIFO(mode):
        return "is a named pipe (FIFO), not a regular file"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "is a device, not a regular file"
    if stat.S_ISSOCK(mode):
        return "is a socket, not a regular file"
    return "is not a regular file"


def _size_text(max_bytes: int) -> str:
    return f"{max_bytes / 2**20:g} MiB" if max_bytes >= 2**20 else f"{max_bytes} bytes"


def _refusal(error: OSError | ValueError) -> UnreadableFile:
    """OSError from the system; ValueError from Python for a path holding a NUL character."""
    if getattr(error, "errno", None) in (errno.ENOENT, errno.ENOTDIR):
        return UnreadableFile("does not exist", missing=True)
    return UnreadableFile(f"cannot be read ({getattr(error, 'strerror', None) or error})")


def read_user_file(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The bytes of the regular file at ``path``, if it holds at most ``max_bytes`` of them;
    else :class:`UnreadableFile` (see the module docstring)."""
    path = Path(path)
    try:
        refused = _kind_of_file(os.stat(path).st_mode)          # follows a symbolic link
    except (OSError, ValueError) as error:
        raise _refusal(error) from None
    if refused:
        raise UnreadableFile(refused)
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as error:
        raise _refusal(error) from None
    try:
        refused = _kind_of_file(os.fstat(descriptor).st_mode)   # the path may have changed since
        if refused:
            raise UnreadableFile(refused)
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(descriptor, min(_CHUNK_BYTES, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as error:
        raise _refusal(error) from None
    finally:
        os.close(descriptor)
    if size > max_bytes:
        raise UnreadableFile(f"is larger than {_size_text(max_bytes)}")
    return b"".join(chunks)
