"""Opening the files a user names on the command line (``--log``, ``--lateness``, ``--trace-up``, ``--trace-down``)
only when they are regular files: a FIFO blocks its opener until another process opens its other end, a device
reads or takes bytes without end, so either would hang the proxy before it serves."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import IO, Any

from gicore.error_policy import UserError

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a plain file")


def refuse_irregular(path: Path, option: str, fix: str) -> None:
    """Raise one :class:`UserError` line naming ``option`` when ``path`` exists and is no regular file (a
    missing path or one that cannot be inspected is left to the open, which says why)."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return
    if not stat.S_ISREG(mode):
        raise UserError(f"{option} {path} is {_kind(mode)}, not a regular file", fix)


def open_regular(path: Path, option: str, fix: str, mode: str, newline: str | None = None) -> IO[Any]:
    """``path`` opened with ``mode`` (``r``, ``rb``: to read; ``w``, ``wb``: created or emptied, to write) if it is
    a regular file; otherwise one :class:`UserError` line naming ``option``. The open does not wait on a FIFO
    (``O_NONBLOCK``) and what it got is checked again, so a FIFO put there after :func:`refuse_irregular` is
    refused too. Other failures are the caller's :class:`OSError`."""
    refuse_irregular(path, option, fix)
    access = os.O_WRONLY | os.O_CREAT | os.O_TRUNC if mode.startswith("w") else os.O_RDONLY
    fd = os.open(path, access | os.O_NONBLOCK | os.O_CLOEXEC, 0o666)
    try:
        mode_bits = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode_bits):
            raise UserError(f"{option} {path} is {_kind(mode_bits)}, not a regular file", fix)
        os.set_blocking(fd, True)
        return os.fdopen(fd, mode, newline=newline)
    except BaseException:
        os.close(fd)
        raise
