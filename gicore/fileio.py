"""Writing files so that nothing half-written is ever seen, and one run per output folder.

``atomic_write`` writes to a uniquely named temporary file beside the target, fsyncs it and renames it
over the target, so a reader (or a resumed run) sees either the old file or the whole new one, and two
processes writing into one folder never share a temporary name. ``exclusive_run`` holds an advisory
lock on a folder for the life of a run and refuses a second run with a one-line error; the lock file
names its holder's PID, so a lock that a killed run left behind is taken over with a note saying so.
"""

from __future__ import annotations

import fcntl
import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO

from gicore.error_policy import UserError, writable_dir

#: Temporary files carry this marker so that a sweep can remove those a killed writer left behind.
TMP_MARKER = ".tmp-"

_UMASK = os.umask(0o022)  # read the process umask (set it back at once)
os.umask(_UMASK)


def atomic_write(path: Path, write: Callable[[IO[bytes]], object], *, fsync: bool = True) -> Path:
    """Write ``path`` through ``write(file)`` atomically (temp file in the same folder, fsync, rename)."""
    path = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f"{path.name}{TMP_MARKER}", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)  # mkstemp makes 0600; the result is an ordinary file, as open() makes it
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            if fsync:
                handle.flush()
                os.fsync(handle.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return path


def atomic_write_bytes(path: Path, data: bytes, *, fsync: bool = True) -> Path:
    return atomic_write(path, lambda handle: handle.write(data), fsync=fsync)


def sweep_temporaries(folder: Path) -> list[Path]:
    """Remove temporary files that a killed writer left in ``folder`` (not recursive); returns them."""
    removed = [p for p in Path(folder).glob(f"*{TMP_MARKER}*") if p.is_file()]
    for p in removed:
        p.unlink(missing_ok=True)
    return removed


class FolderHeld(UserError):
    """:func:`exclusive_run` refused: another live run holds ``folder``; ``holder`` is its PID (None
    when it has not written it yet). A command may catch it to say which run, in its own words."""

    def __init__(self, folder: Path, holder: int | None) -> None:
        who = "" if holder is None else f" (process {holder})"
        super().__init__(f"another run holds {folder}{who}", "wait for it to finish or choose another --out")
        self.folder = folder
        self.holder = holder

    def __reduce__(self) -> tuple:
        return type(self), (self.folder, self.holder)


def _holder(handle: IO[bytes]) -> int | None:
    """The PID written in an open lock file, or None (empty: a holder that has not written it yet, or a
    lock file older than PIDs in it)."""
    handle.seek(0)
    text = handle.read(32).decode("ascii", "replace").strip()
    return int(text) if text.isdigit() else None


@contextmanager
def made_folder(folder: Path, *, name: str = "--out") -> Iterator[Path]:
    """``folder``, created as :func:`writable_dir` creates it (with parents; UserError naming ``name`` if it is a
    file or not writable); on exit it and the parents made here are removed where they are left empty, so a run
    refused before it wrote anything leaves no trace."""
    folder = Path(folder)
    created = [p for p in (folder, *folder.parents) if not p.exists()]  # deepest first
    writable_dir(folder, name=name)
    try:
        yield folder
    finally:
        with suppress(OSError):
            for made in created:
                made.rmdir()  # only if empty: the first that is not stops the walk up


@contextmanager
def exclusive_run(folder: Path) -> Iterator[None]:
    """Hold ``folder/.lock`` for the duration of a run; a second run into the same folder is refused.

    ``folder`` is created if need be (:func:`made_folder`: removed again with the parents made for it where the
    run left them empty); a folder another run holds is refused with :class:`FolderHeld`. The lock is an flock
    (the kernel drops it when its holder dies, however it dies) on a file that holds the holder's PID.
    The lock file is removed when the run ends. A lock file that a killed run (kill -9, a lost
    machine) left behind is no longer locked: it is taken over, with one line on stderr naming the folder
    and the dead holder's PID. Removing a lock file races with a process that opened it just before: a
    run that locks a file no longer at ``folder/.lock`` therefore tries again.
    """
    with made_folder(folder) as folder:
        lock = folder / ".lock"
        handle = _take_lock(folder, lock)
        try:
            stale = _holder(handle)
            if stale is not None:  # its holder wrote it and never removed it: it ended without clean-up
                print(f"note: taking over the lock of {folder} left by process {stale}, which is gone", file=sys.stderr)
            handle.seek(0)
            handle.truncate()
            handle.write(f"{os.getpid()}\n".encode())
            handle.flush()
            yield
        finally:
            lock.unlink(missing_ok=True)  # while still holding it, so a waiting opener sees the inode change
            handle.close()


def _take_lock(folder: Path, lock: Path) -> IO[bytes]:
    """The open, flocked file at ``lock`` (FolderHeld if another run holds it)."""
    while True:
        handle = open(lock, "a+b")  # closed by the caller after the run
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError as exc:
            holder = _holder(handle)
            handle.close()
            raise FolderHeld(folder, holder) from exc
        try:
            if os.fstat(handle.fileno()).st_ino == os.stat(lock).st_ino:
                return handle
        except FileNotFoundError:
            pass
        handle.close()  # the previous holder removed this file after we opened it: lock the new one
