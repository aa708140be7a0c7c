"""Mahimahi-format capacity traces: when a link may deliver bytes.

A trace file has one line per *delivery opportunity*: a whole number of milliseconds from the start of
the trace at which the link may pass one 1500-byte packet (Mahimahi ``traces/README``; a file holding just
``1`` is a 12 Mbit/s link). Timestamps never decrease; the same timestamp on several lines means several
packets in that millisecond. The trace repeats with a period equal to its last timestamp, as ``mm-link``
does by default (``base_timestamp_ += schedule_.back()`` in Mahimahi's ``link_queue.cc``).

Parsing follows ``mm-link``'s rules (no empty lines, non-decreasing, at least one line, last timestamp
> 0) but every error names the file *and the line*. A file is ASCII text of at most :data:`MAX_BYTES`
(:data:`MAX_LINES` lines, timestamps up to :data:`MAX_TIMESTAMP_MS`); anything else (``/dev/zero``, a
binary file) is refused with one error line before it is held in memory whole, and so is anything but a regular
file (a FIFO would block the read forever).
"""

from __future__ import annotations

import bisect
import math
import operator
import re
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

from gicore.error_policy import UserError
from network_sim.files import open_regular

#: Bytes one delivery opportunity may carry (Mahimahi's ``PACKET_SIZE``, one MTU).
OPPORTUNITY_BYTES = 1500
#: Largest trace file read, bytes (Mahimahi's own cellular traces are under 2 MB).
MAX_BYTES = 32 * 2**20
#: Most lines (delivery opportunities per period) a trace may have.
MAX_LINES = 4_000_000
#: Largest timestamp, ms (11.6 days: a period longer than any run).
MAX_TIMESTAMP_MS = 10**9
_TIMESTAMP = re.compile(r"(-?)([0-9]+)")


@dataclass(frozen=True)
class Trace:
    """A parsed trace: opportunity times within one period, and the period (whole milliseconds, as in the
    file, so period boundaries are exact)."""

    #: Where it came from (shown in errors, logs and ``network-sim profiles``).
    name: str
    #: Opportunity times of one period, ms, non-decreasing, the last one equal to ``period_ms``.
    times_ms: tuple[int, ...]
    #: Length of one period in ms (the last timestamp).
    period_ms: int

    @classmethod
    def from_ms(cls, name: str, ms: list[int]) -> Trace:
        """A trace from integer millisecond timestamps (already validated)."""
        return cls(name, tuple(ms), ms[-1])

    @classmethod
    def load(cls, path: Path | str, option: str = "trace") -> Trace:
        """Parse a Mahimahi trace file; a malformed one raises :class:`UserError` naming file and line, anything
        but a regular file (a FIFO, a device) one naming ``option`` (the command-line option that gave it)."""
        path = Path(path)
        try:
            with open_regular(path, option, "give a Mahimahi trace file", "rb") as fh:
                data = fh.read(MAX_BYTES + 1)
        except OSError as exc:
            raise UserError(
                f"trace {path} cannot be read ({exc.strerror})", "give an existing Mahimahi trace file"
            ) from exc
        if len(data) > MAX_BYTES:
            raise UserError(
                f"trace {path} is larger than {MAX_BYTES // 2**20} MiB",
                "give a Mahimahi trace file (text, one line per packet)",
            )
        if data.count(b"\n") > MAX_LINES:  # counted before the lines are split out and held
            raise UserError(f"trace {path} has more than {MAX_LINES} lines", "give a shorter trace")
        try:
            text = data.decode("ascii")
        except UnicodeDecodeError as exc:
            line = data.count(b"\n", 0, exc.start) + 1
            raise UserError(
                f"trace {path} line {line}: byte 0x{data[exc.start]:02x} is not ASCII text",
                "give a Mahimahi trace file (text, one whole number of milliseconds per line)",
            ) from None
        return cls.from_ms(str(path), parse_lines(str(path), text.splitlines()))

    @property
    def opportunities(self) -> int:
        """Delivery opportunities per period."""
        return len(self.times_ms)

    @property
    def period_s(self) -> float:
        return self.period_ms / 1000.0

    @property
    def mean_mbit(self) -> float:
        """Mean capacity over one period, Mbit/s."""
        return self.opportunities * OPPORTUNITY_BYTES * 8 / self.period_s / 1e6

    def opportunity_time(self, k: int) -> float:
        """Time (s from the trace origin) of opportunity number ``k`` (0-based, counting across periods)."""
        cycle, index = divmod(k, len(self.times_ms))
        return (cycle * self.period_ms + self.times_ms[index]) / 1000.0

    def count_until(self, t: float) -> int:
        """Number of opportunities at times <= ``t`` (s from the origin; a time within 1 ns of a
        millisecond counts as that millisecond, so float rounding never skips an opportunity)."""
        ms = math.floor(t * 1000.0 + 1e-6)
        if ms < 0:
            return 0
        cycle, rest = divmod(ms, self.period_ms)
        return cycle * len(self.times_ms) + bisect.bisect_right(self.times_ms, rest)

    def capacity_bytes(self, t0: float, t1: float) -> int:
        """Bytes the link can deliver at opportunities in the window (t0, t1]."""
        return (self.count_until(t1) - self.count_until(t0)) * OPPORTUNITY_BYTES


def parse_lines(name: str, lines: list[str]) -> list[int]:
    """Validate trace lines and return the millisecond timestamps; errors name ``name`` and the line."""
    ms = _parse_clean(lines)
    return ms if ms is not None else _parse_checking(name, lines)


def _parse_clean(lines: list[str]) -> list[int] | None:
    """The timestamps of a well-formed trace (bare digits, non-decreasing, in range, last > 0) in one pass over
    the lines in C; None for anything else, which :func:`_parse_checking` then reports by line. A shipped trace
    holds ~50,000 lines, parsed by every process that validates a profile name."""
    digits = len(str(MAX_TIMESTAMP_MS))
    if not lines or not all(line.isdigit() and line.isascii() and len(line) <= digits for line in lines):
        return None
    ms = list(map(int, lines))
    ordered = all(map(operator.le, ms, islice(ms, 1, None)))
    return ms if ordered and ms[-1] <= MAX_TIMESTAMP_MS and ms[-1] > 0 else None


def _parse_checking(name: str, lines: list[str]) -> list[int]:
    """Line by line, the first fault named with its line (whitespace around a number is allowed)."""
    fix = (
        "each line must be one whole number of milliseconds, never smaller than the line before (Mahimahi trace format)"
    )
    ms: list[int] = []
    for number, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line:
            raise UserError(f"trace {name} line {number} is empty", fix)
        match = _TIMESTAMP.fullmatch(line)
        if match is None:
            raise UserError(f"trace {name} line {number}: {line[:40]!r} is not a whole number of milliseconds", fix)
        if match[1]:
            raise UserError(f"trace {name} line {number}: timestamp {line[:40]} is negative", fix)
        if len(match[2]) > len(str(MAX_TIMESTAMP_MS)) or int(match[2]) > MAX_TIMESTAMP_MS:
            raise UserError(f"trace {name} line {number}: timestamp {line[:40]} is above {MAX_TIMESTAMP_MS} ms", fix)
        value = int(match[2])
        if ms and value < ms[-1]:
            raise UserError(
                f"trace {name} line {number}: timestamp {value} is smaller than the line before ({ms[-1]})", fix
            )
        ms.append(value)
    if not ms:
        raise UserError(f"trace {name} has no timestamps", fix)
    if ms[-1] == 0:
        raise UserError(
            f"trace {name} line {len(ms)}: the last timestamp is 0, so the trace lasts no time",
            "end the trace with a timestamp > 0",
        )
    return ms
