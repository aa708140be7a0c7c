"""The proxy's records of its chunks: the per-chunk CSV log (what the link model computed for each chunk and when
the proxy wrote it) and the lateness summary (how late it wrote them, the run's fidelity; docs/architecture.md,
Proxy)."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TextIO

from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes
from network_sim.files import open_regular
from network_sim.link import DOWN, UP, Chunk

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

#: What to do about a ``--log`` that is no regular file.
LOG_FIX = "give a regular file path, or one that does not exist yet"


class ChunkLog:
    """The per-chunk CSV log: one row per chunk when it is written (or, at shutdown, never written).

    A log that cannot be written (a folder, no space, ``/dev/full``) raises :class:`UserError`: at once when
    it is opened (the header is flushed), else from the row or the close that met the failure.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        with self._failing():
            self._fh: TextIO = open_regular(path, "--log", LOG_FIX, "w", newline="")
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


# -- lateness: sent minus the model's release time -------------------------------------------------------------
#: Lateness is counted in log-spaced bins from :data:`LATENESS_FLOOR_S` up, this many per decade: a percentile
#: is its bin's upper edge, never below the true value and at most 2.3 % above it (or the exact maximum).
LATENESS_BINS_PER_DECADE = 100
#: Lateness at or under 1 µs is one bin (the proxy writes a chunk due within 1 µs as on time).
LATENESS_FLOOR_S = 1e-6
#: Bins above the floor: 10 decades, 1 µs to 10,000 s; the last one holds everything above (a percentile there is
#: the exact maximum).
_LATENESS_BINS = 10 * LATENESS_BINS_PER_DECADE
#: The keys of a lateness summary's parts (:func:`lateness`).
LATENESS_PARTS = (UP, DOWN, "all")


def lateness_limit_ms(rtt_ms: float) -> float:
    """The largest p99 lateness, ms, of a reliable run over a link of base round-trip time ``rtt_ms``: a tenth of
    the RTT, at least 1 ms. Later than that, the timing the link adds is not what was configured."""
    return max(0.1 * rtt_ms, 1.0)


class LatenessSummary:
    """How late the proxy wrote each direction's chunks after their release time in the model: a fixed histogram
    per direction (one logarithm per chunk, a few kilobytes however long the run), so the proxy can keep it on
    every run; :meth:`summary` gives :func:`lateness`'s dict."""

    def __init__(self) -> None:
        self.counts = {d: [0] * (_LATENESS_BINS + 1) for d in (UP, DOWN)}
        self.dropped = {UP: 0, DOWN: 0}
        self.max_s = {UP: -math.inf, DOWN: -math.inf}

    def add(self, direction: str, late_s: float | None) -> None:
        """One chunk of ``direction`` written ``late_s`` after its release (None: dropped, never written)."""
        if late_s is None:
            self.dropped[direction] += 1
            return
        if late_s > LATENESS_FLOOR_S:
            index = min(math.ceil(math.log10(late_s / LATENESS_FLOOR_S) * LATENESS_BINS_PER_DECADE), _LATENESS_BINS)
        else:
            index = 0
        self.counts[direction][index] += 1
        if late_s > self.max_s[direction]:
            self.max_s[direction] = late_s

    @staticmethod
    def _part(counts: list[int], dropped: int, max_s: float) -> dict[str, Any]:
        chunks = sum(counts)
        part: dict[str, Any] = {"chunks": chunks, "dropped": dropped}
        for q in (50, 99):
            rank, seen, index = math.ceil(q / 100 * chunks), 0, 0  # the nearest-rank percentile's bin
            while chunks and seen + counts[index] < rank:
                seen += counts[index]
                index += 1
            edge = LATENESS_FLOOR_S * 10 ** (index / LATENESS_BINS_PER_DECADE) if index < _LATENESS_BINS else math.inf
            part[f"p{q}_ms"] = min(edge, max_s) * 1e3 if chunks else None
        part["max_ms"] = max_s * 1e3 if chunks else None
        return part

    def summary(self) -> dict[str, dict[str, Any]]:
        both = [u + d for u, d in zip(self.counts[UP], self.counts[DOWN])]
        out = {d: self._part(self.counts[d], self.dropped[d], self.max_s[d]) for d in (UP, DOWN)}
        out["all"] = self._part(both, sum(self.dropped.values()), max(self.max_s.values()))
        return out


def lateness(log_path: Path) -> dict[str, dict[str, Any]]:
    """How late the proxy wrote the chunks of the per-chunk CSV log at ``log_path`` (``network-sim proxy --log``).

    Lateness is ``sent_s - release_s``: when the proxy wrote a chunk minus when the link model released it to
    the receiver. Returns ``{"up": part, "down": part, "all": part}``, each part ``{"chunks": written chunks,
    "dropped": chunks never written (shut down, receiver gone, dead link), "p50_ms", "p99_ms", "max_ms"}``; the
    percentiles are nearest-rank over the written chunks, never below the true value and at most 2.3 % above it
    (never above the maximum), and None without a written chunk. The same dict, for the same chunks, as the
    proxy's ``--lateness`` summary (:func:`read_lateness`), which costs no log.
    """
    summary = LatenessSummary()
    with log_path.open(newline="") as fh:
        for row in csv.DictReader(fh):
            sent = row["sent_s"]
            summary.add(row["direction"], float(sent) - float(row["release_s"]) if sent else None)
    return summary.summary()


def reliable(summary: dict[str, Any], rtt_ms: float) -> bool:
    """Whether a run whose :func:`lateness` is ``summary`` kept time over a link of base round-trip time ``rtt_ms``:
    its p99 lateness (both directions) is at most :func:`lateness_limit_ms` (a run that wrote no chunk was never
    late). Its numbers are then the configured link's; otherwise the machine was too busy for them."""
    p99 = summary["all"]["p99_ms"]
    return p99 is None or p99 <= lateness_limit_ms(rtt_ms)


def lateness_report(summary: LatenessSummary, rtt_ms: float) -> dict[str, Any]:
    """The ``--lateness`` file's content: :func:`lateness`'s parts, the link's base RTT, the limit and the verdict."""
    parts = summary.summary()
    return {**parts, "rtt_ms": rtt_ms, "limit_ms": lateness_limit_ms(rtt_ms), "reliable": reliable(parts, rtt_ms)}


def write_lateness(path: Path, report: dict[str, Any]) -> None:
    """Write the ``--lateness`` JSON atomically; a failure is one :class:`UserError` line."""
    try:
        atomic_write_bytes(path, json.dumps(report, indent=1).encode() + b"\n", fsync=False)
    except OSError as exc:
        raise UserError(f"--lateness {path} cannot be written ({exc.strerror or exc})", LOG_FIX) from None


def read_lateness(path: Path) -> dict[str, Any]:
    """The summary a proxy wrote to ``--lateness`` at its exit: :func:`lateness`'s parts plus ``rtt_ms`` (the
    link's base round-trip time), ``limit_ms`` (:func:`lateness_limit_ms`) and ``reliable`` (:func:`reliable`)."""
    try:
        report = json.loads(path.read_bytes())
    except FileNotFoundError:
        raise UserError(
            f"no lateness summary at {path}", "the proxy writes it when it stops on SIGTERM or SIGINT; stop it so"
        ) from None
    except (OSError, ValueError) as exc:
        raise UserError(f"lateness summary {path} cannot be read ({exc})", "run the proxy again") from None
    if not isinstance(report, dict) or any(not isinstance(report.get(k), dict) for k in LATENESS_PARTS):
        raise UserError(f"lateness summary {path} is not a proxy's", "give the file network-sim proxy --lateness wrote")
    return report
