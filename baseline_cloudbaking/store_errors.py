"""What the GI tree raises (:mod:`baseline_cloudbaking.store`): a scene under another spec, a closed tree, a
lookup that would block, and a write the storage refused (full, read-only, failing), named in one line.
"""

from __future__ import annotations

import errno
import sqlite3
from pathlib import Path

from gicore.error_policy import UserError


class StoreConflict(ValueError):
    """The store already holds a scene under another spec or light-cell size."""


class StoreClosed(RuntimeError):
    """A call on a :class:`GITree` after :meth:`GITree.close`: the tree does not reopen itself."""


class WouldBlock(Exception):
    """A lookup with ``io=False`` would have to read the index or a payload file: ask again with ``io=True``."""


#: OS errors that mean "no space": the disk or a quota.
_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
#: OS errors that mean the store cannot be written now (read-only, not permitted, failing storage).
_UNWRITABLE_ERRNOS = (errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG, *_FULL_ERRNOS)
#: SQLite primary result codes of the same conditions (the extended code's low byte).
_SQLITE_FULL = (sqlite3.SQLITE_FULL,)
_SQLITE_UNWRITABLE = (sqlite3.SQLITE_READONLY, sqlite3.SQLITE_IOERR, sqlite3.SQLITE_CANTOPEN, *_SQLITE_FULL)


class StoreUnwritable(UserError):
    """A write to the GI tree failed for a reason outside the request: ``full`` (no space left on its file
    system or quota, or SQLite's page limit) or not (read-only, not permitted, failing storage). One line
    naming the store and the real cause; the original error is the ``__cause__``."""

    def __init__(self, root: Path, cause: str, full: bool) -> None:
        todo = "free space on its file system (or lower the budget)" if full else "make the store writable again"
        super().__init__(f"cannot write the GI tree at {root} ({cause})", todo)
        self.root = root
        self.cause = cause
        self.full = full

    def __reduce__(self) -> tuple:
        return type(self), (self.root, self.cause, self.full)

    @classmethod
    def from_error(cls, root: Path, exc: BaseException) -> StoreUnwritable | None:
        """The StoreUnwritable that ``exc`` means, or None when it is not such a failure (a bug, a constraint)."""
        if isinstance(exc, sqlite3.OperationalError) and getattr(exc, "sqlite_errorcode", None) is not None:
            code = exc.sqlite_errorcode & 0xFF
            if code in _SQLITE_UNWRITABLE:
                return cls(root, f"{exc} (SQLite {exc.sqlite_errorname})", code in _SQLITE_FULL)
        if isinstance(exc, OSError) and exc.errno in _UNWRITABLE_ERRNOS:
            where = f": {exc.filename}" if exc.filename else ""
            return cls(root, f"{exc.strerror or exc}{where}", exc.errno in _FULL_ERRNOS)
        return None
