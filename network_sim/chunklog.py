"""The proxy's per-chunk CSV log: what the link model computed for each chunk and when the proxy wrote it."""

from __future__ import annotations

import csv
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

from gicore.error_policy import UserError
from network_sim.link import Chunk

#: Columns of the per-chunk log; times are seconds from the link origin (the model's clock).
LOG_COLUMNS = (
    "seq",
    "conn",
    "direction",
    "bytes",
    "arrival_s",
    "admitted_s",
    "finish_s",
    "ready_s",
    "release_s",
    "sent_s",
    "lost",
)


class ChunkLog:
    """The per-chunk CSV log: one row per chunk when it is written (or, at shutdown, never written).

    A log that cannot be written (a folder, no space, ``/dev/full``) raises :class:`UserError`: at once when
    it is opened (the header is flushed), else from the row or the close that met the failure.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        with self._failing():
            self._fh: TextIO = path.open("w", newline="")
            self._writer = csv.writer(self._fh)
            self._writer.writerow(LOG_COLUMNS)
            self._fh.flush()

    @contextmanager
    def _failing(self) -> Iterator[None]:
        try:
            yield
        except OSError as exc:
            raise UserError(
                f"--log {self.path} cannot be written ({exc.strerror or exc})", "give a writable file path"
            ) from None

    def row(self, chunk: Chunk, sent: float | None) -> None:
        c = chunk
        sent_s = "" if sent is None else repr(sent)
        times = (c.arrival, c.admitted, c.finish, c.ready, c.release)
        with self._failing():
            self._writer.writerow((c.seq, c.conn, c.direction, c.nbytes, *map(repr, times), sent_s, repr(c.lost)))

    def close(self) -> None:
        with self._failing():
            self._fh.close()  # the file is closed even when the last flush fails
