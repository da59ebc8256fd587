"""The lock of a result folder: one run writes a folder at a time.

A run makes its result folder if needed (:func:`make_folder`) and holds an exclusive ``flock``
on ``.pfx.lock`` inside it for as long as it writes (:func:`folder_lock`); a second run on the
same folder is refused in one line naming the pid of the first. The lock dies with its process,
so a killed run leaves no stale lock. Runs started together may interleave in any order:

* a run refused by another never removes anything;
* a run that kept nothing removes the folder only if it made it, it held nothing but the lock
  when locked, and it still holds the lock: a run that removed a folder without the lock could
  remove it under the run that holds it;
* a run that locks a lock file whose holder has just removed it (folder and all) notices, the
  path no longer naming the file it locked, and starts again from the mkdir.

What a run read of the folder before it held the lock, it reads again once it does
(:func:`pfx.folder_state.inspect_folder` with ``locked``).
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

from pfx.errors import ConfigError

LOCK_FILE = ".pfx.lock"


def make_folder(out: Path) -> bool:
    """Create the result folder (and its missing parents); True if this call created it.

    The fallback of :func:`check_writable`: a folder that cannot be made is one line naming it.
    """
    try:
        out.mkdir(parents=True)
        return True
    except FileExistsError:
        if out.is_dir():
            return False
        raise ConfigError("exists and is not a folder (the result folder must be one); choose another folder",
                          file=str(out)) from None
    except OSError as error:
        raise ConfigError(f"cannot create the result folder: {error.strerror or error}", file=str(out)) from None


LOCK_ATTEMPTS = 100           # a folder removed under a run this often is given up on
HOLDER_WAIT_S = 1.0           # how long a refused run waits for the holder's pid to be written


def held_error(out: Path, holder: str) -> ConfigError:
    return ConfigError(f"another pfx run (pid {holder}) is writing to this result folder; "
                       "wait for it or choose another --out", file=str(out))


def _written_pid(descriptor: int) -> str:
    return os.pread(descriptor, 32, 0).decode("ascii", "replace").strip()


def lock_holder(out: Path) -> Optional[str]:
    """The pid (as text) of the pfx run holding ``out``'s lock, "?" if it has not written it
    yet; None when no run holds it. (The probe holds a shared lock for an instant.)"""
    try:
        import fcntl
    except ImportError:
        return None
    try:
        descriptor = os.open(Path(out) / LOCK_FILE, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _written_pid(descriptor) or "?"
        return None
    finally:
        os.close(descriptor)             # releases the probe's shared lock


def _same_file(descriptor: int, path: Path) -> bool:
    """Whether ``path`` still names the file open as ``descriptor`` (not removed, not replaced)."""
    try:
        named = os.stat(path)
    except FileNotFoundError:
        return False
    held = os.fstat(descriptor)
    return (named.st_dev, named.st_ino) == (held.st_dev, held.st_ino)


def _unused(out: Path) -> bool:
    """The folder holds nothing but the lock (and empty folders)."""
    return not [path for path in out.iterdir()
                if path.name != LOCK_FILE and not (path.is_dir() and not any(path.iterdir()))]


def _remove_unused(out: Path) -> None:
    """Remove a folder that holds nothing but the lock and empty folders, lock file first (a
    run that opens the lock file afterwards makes a new one and keeps the folder, whose last
    removal then fails harmlessly)."""
    try:
        for path in out.iterdir():
            if path.is_dir():
                path.rmdir()
        (out / LOCK_FILE).unlink(missing_ok=True)
        out.rmdir()
    except OSError:
        pass


def _acquire(out: Path, fcntl) -> tuple[int, bool]:
    """Make the folder if needed and lock it: (the lock file's open descriptor, whether this
    call made the folder). Refuses, naming the holder, a folder another run holds."""
    for _ in range(LOCK_ATTEMPTS):
        created = make_folder(out)
        try:
            descriptor = os.open(out / LOCK_FILE, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)   # less the umask
        except FileNotFoundError:       # removed since the mkdir, by a run that kept nothing: again
            continue
        except OSError as error:        # what check_writable cannot see (root on a read-only file system)
            raise ConfigError(f"cannot create the lock file {LOCK_FILE}: {error.strerror or error}",
                              file=str(out)) from None
        try:
            _lock_or_refuse(out, descriptor, fcntl)
        except BaseException:
            os.close(descriptor)
            raise
        # Locked, but perhaps a file whose holder removed it (folder and all: its run kept
        # nothing) between our open and our lock; then start again with a new folder.
        if _same_file(descriptor, out / LOCK_FILE):
            return descriptor, created
        os.close(descriptor)
    raise ConfigError(f"the result folder was removed {LOCK_ATTEMPTS} times while this run tried to lock "
                      "it; choose another --out", file=str(out))


def _lock_or_refuse(out: Path, descriptor: int, fcntl) -> None:
    """Take the exclusive lock, or refuse naming the run that holds it. A holder that has not
    written its pid yet (it has just locked), or a probe (:func:`lock_holder`), is given a
    moment before the refusal."""
    deadline = time.monotonic() + HOLDER_WAIT_S
    while True:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except BlockingIOError:
            holder = _written_pid(descriptor)
        except OSError as error:        # a file system without locks
            raise ConfigError(f"cannot lock {LOCK_FILE}: {error.strerror or error}", file=str(out)) from None
        if holder or time.monotonic() > deadline:
            raise held_error(out, holder or "?")
        time.sleep(0.01)


@contextmanager
def folder_lock(out: Path, *, remove_if_unused: bool = False):
    """Make the result folder if needed and hold an exclusive lock on it for the block; a
    second run on it is refused, naming the first (see :func:`_lock_or_refuse`).

    The lock (``.pfx.lock``, flock) dies with its process, so a killed run leaves no stale lock.
    With ``remove_if_unused``, a folder this call made, and that still holds nothing but the
    lock at the end of the block (the run kept nothing), is removed, while the lock is still
    held: a run that removed a folder without the lock could remove it under the run that
    holds it. A run that had opened the removed lock file then notices and starts again.
    """
    out = Path(out)
    try:
        import fcntl
    except ImportError:          # no flock on this platform: run unlocked
        created = make_folder(out)
        try:
            yield
        finally:
            if remove_if_unused and created and _unused(out):
                _remove_unused(out)
        return
    descriptor, created = _acquire(out, fcntl)
    unused_when_locked = False
    try:
        unused_when_locked = created and _unused(out)
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, str(os.getpid()).encode(), 0)
        yield
    finally:
        try:
            if remove_if_unused and unused_when_locked and _unused(out):
                _remove_unused(out)
            else:
                os.ftruncate(descriptor, 0)      # an idle lock names no run
        finally:
            os.close(descriptor)                 # releases the lock
