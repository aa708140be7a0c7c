"""A deterministic virtual-clock model of one emulated link: chunk arrivals in, release times out
(docs/architecture.md, Link model).

The proxy (:mod:`network_sim.proxy`) schedules every chunk with this same code, so the model and the process
cannot drift apart; benches use it directly for fast sweeps. Times are seconds on a virtual clock whose origin
is the link's start. Each direction of a chunk passes admission (a shared drop-tail queue and a per-connection
window: backpressure, never loss), serialization (a rate, or a Mahimahi trace's delivery opportunities), loss
as TCP sees it (one retransmission timeout ``max(200 ms, 2 RTT)`` per lost segment) and propagation (one-way
delay plus a seeded jitter process that never reorders a stream). Random numbers are seeded by ``(seed,
direction[, connection])``, so a run is reproduced by its seed and its chunk arrivals.
"""

from __future__ import annotations

import hashlib
import math
import random
from collections import deque
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Literal

from network_sim.trace import OPPORTUNITY_BYTES, Trace

#: TCP payload of one 1500-byte Ethernet frame with the timestamp option (1500 - 20 IP - 20 TCP - 12).
MSS = 1448
#: Linux's minimum retransmission timeout (``TCP_RTO_MIN`` = HZ/5 in include/net/tcp.h).
MIN_RTO_S = 0.200
#: Default bottleneck queue: Linux's default ``txqueuelen`` of 1000 packets of 1500 bytes.
DEFAULT_QUEUE_BYTES = 1000 * 1500
#: Default per-connection window: Linux's ``tcp_rmem`` maximum (6 MiB) halved by ``tcp_adv_win_scale = 1``.
DEFAULT_WINDOW_BYTES = 3 * 2**20
#: Largest chunk the model takes on a shaped direction (finer release steps) and on an unshaped one.
SHAPED_CHUNK_BYTES = 16 * 1024
UNSHAPED_CHUNK_BYTES = 256 * 1024
#: Spacing of the jitter process's independent knots, in units of the jitter standard deviation.
#: Wide enough that the delay rarely falls faster than time passes (which would reorder without the FIFO max).
KNOT_SPACING_PER_SIGMA = 4.0

JitterDist = Literal["normal", "pareto", "uniform"]
JITTER_DISTS: tuple[str, ...] = ("normal", "pareto", "uniform")
#: Pareto jitter as netem's table makes it (iproute2 ``netem/pareto.c``, from NIST Net): shape alpha = 3, and
#: the tail cut at x = 4.5 x_m, where that table's int16 entries ((x - 1.5) * 4/3 * 8192) saturate. The cut
#: keeps spikes within ~5 standard deviations, so the FIFO release rarely has to hold a falling delay.
PARETO_ALPHA = 3.0
PARETO_CAP = 4.5
_PARETO_MEAN = PARETO_ALPHA / (PARETO_ALPHA - 1) - PARETO_CAP ** (1 - PARETO_ALPHA) / (PARETO_ALPHA - 1)
_PARETO_STD = math.sqrt(
    PARETO_ALPHA / (PARETO_ALPHA - 2) - 2 * PARETO_CAP ** (2 - PARETO_ALPHA) / (PARETO_ALPHA - 2) - _PARETO_MEAN**2
)
UP, DOWN = "up", "down"
_STANDARD_NORMAL = NormalDist()


#: Smallest non-zero rate, Mbit/s (1 kbit/s: a 1 KiB chunk every 8 s).
RATE_MBIT_MIN = 1e-3


@dataclass(frozen=True)
class DirectionConfig:
    """How one direction of the link treats the bytes crossing it (``up``: client to upstream)."""

    #: Mean one-way delay added to every byte, ms (Mahimahi's ``mm-delay``): an empty round trip takes twice it.
    delay_ms: float = 0.0
    #: Standard deviation of the delay's variation around ``delay_ms``, ms (0 = constant delay).
    jitter_ms: float = 0.0
    #: Distribution of the delay variation (all scaled to mean 0 and standard deviation ``jitter_ms``).
    jitter_dist: JitterDist = "normal"
    #: Serialization rate of payload bytes, Mbit/s; None = unlimited, 0 = a dead link (nothing passes).
    rate_mbit: float | None = None
    #: Mahimahi delivery-opportunity trace; when set it replaces ``rate_mbit``.
    trace: Trace | None = None
    #: Bottleneck queue bound in bytes (drop-tail; a full queue stops reading the sender).
    queue_bytes: int = DEFAULT_QUEUE_BYTES
    #: Probability that one transmission of a segment is lost (each loss costs one retransmission timeout).
    loss: float = 0.0

    def __post_init__(self) -> None:
        for name in ("delay_ms", "jitter_ms"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} = {value!r} must be a finite number >= 0")
        if self.jitter_dist not in JITTER_DISTS:
            raise ValueError(f"jitter_dist = {self.jitter_dist!r} must be one of {', '.join(JITTER_DISTS)}")
        if self.rate_mbit is not None and not (math.isfinite(self.rate_mbit) and self.rate_mbit >= 0):
            raise ValueError(f"rate_mbit = {self.rate_mbit!r} must be a finite number >= 0 (or None for unlimited)")
        if self.rate_mbit is not None and 0 < self.rate_mbit < RATE_MBIT_MIN:
            # a rate this small schedules bytes centuries ahead: the connection would never count as idle
            raise ValueError(f"rate_mbit = {self.rate_mbit!r} must be 0 (a dead link) or >= {RATE_MBIT_MIN:g}")
        if not (isinstance(self.queue_bytes, int) and self.queue_bytes >= OPPORTUNITY_BYTES):
            raise ValueError(f"queue_bytes = {self.queue_bytes!r} must be an integer >= {OPPORTUNITY_BYTES}")
        if not (0.0 <= self.loss <= 1.0):
            raise ValueError(f"loss = {self.loss!r} must be within [0, 1]")

    @property
    def shaped(self) -> bool:
        """Whether a rate or a trace limits this direction."""
        return self.trace is not None or self.rate_mbit is not None

    def describe(self) -> str:
        """One line: the parameters that differ from an unshaped, undelayed direction."""
        parts = [f"delay {self.delay_ms:g} ms"]
        if self.jitter_ms:
            parts.append(f"jitter {self.jitter_ms:g} ms ({self.jitter_dist})")
        if self.trace is not None:
            parts.append(f"trace {self.trace.name.rsplit('/', 1)[-1]} (mean {self.trace.mean_mbit:.2f} Mbit/s)")
        elif self.rate_mbit is not None:
            parts.append(f"rate {self.rate_mbit:g} Mbit/s")
        else:
            parts.append("rate unlimited")
        if self.loss:
            parts.append(f"loss {self.loss:g}")
        return ", ".join(parts)


@dataclass(frozen=True)
class LinkConfig:
    """Both directions of the link, the per-connection window and the seed of every random draw."""

    #: Client -> upstream (requests).
    up: DirectionConfig = field(default_factory=DirectionConfig)
    #: Upstream -> client (responses).
    down: DirectionConfig = field(default_factory=DirectionConfig)
    #: Bytes a connection may have sent but not yet acknowledged (per direction).
    window_bytes: int = DEFAULT_WINDOW_BYTES
    #: Seed of the jitter processes and of every connection's loss draws.
    seed: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.window_bytes, int) and self.window_bytes >= OPPORTUNITY_BYTES):
            raise ValueError(f"window_bytes = {self.window_bytes!r} must be an integer >= {OPPORTUNITY_BYTES}")

    @property
    def rtt_s(self) -> float:
        """Base round-trip time (the two one-way delays), seconds."""
        return (self.up.delay_ms + self.down.delay_ms) / 1000.0

    @property
    def rto_s(self) -> float:
        """Retransmission timeout one lost segment costs: max(200 ms, 2 RTT)."""
        return max(MIN_RTO_S, 2.0 * self.rtt_s)

    def direction(self, name: str) -> DirectionConfig:
        return {UP: self.up, DOWN: self.down}[name]


# --- stage 2: serializers (one per direction, shared by its connections) ---------------------------------


class _Unlimited:
    """No rate limit: a chunk leaves the bottleneck the moment it is admitted."""

    def room_at(self, nbytes: int, t: float) -> float:
        return t

    def admit(self, nbytes: int, t: float, marks: list[int]) -> list[float]:
        return [t] * len(marks)


class _Dead:
    """Zero capacity: the queue fills and nothing ever leaves."""

    def __init__(self, queue_bytes: int) -> None:
        self.queue_bytes = queue_bytes
        self.queued = 0

    def room_at(self, nbytes: int, t: float) -> float:
        return t if self.queued + nbytes <= self.queue_bytes else math.inf

    def admit(self, nbytes: int, t: float, marks: list[int]) -> list[float]:
        self.queued += nbytes
        return [math.inf] * len(marks)


class _Rate:
    """A fluid FIFO served at a constant byte rate."""

    def __init__(self, rate_mbit: float, queue_bytes: int) -> None:
        self.bytes_per_s = rate_mbit * 1e6 / 8
        self.queue_bytes = queue_bytes
        self.busy_until = -math.inf  # when every admitted byte has been serialized

    def room_at(self, nbytes: int, t: float) -> float:
        # backlog(t) = (busy_until - t) * rate; room when backlog + nbytes <= queue
        return max(t, self.busy_until - (self.queue_bytes - nbytes) / self.bytes_per_s)

    def admit(self, nbytes: int, t: float, marks: list[int]) -> list[float]:
        start = max(t, self.busy_until)
        self.busy_until = start + nbytes / self.bytes_per_s
        return [start + m / self.bytes_per_s for m in marks]


class _TraceLink:
    """Mahimahi's link queue: each delivery opportunity drains up to 1500 queued bytes (partial packets
    carry over, an opportunity that finds the queue empty is wasted)."""

    def __init__(self, trace: Trace, queue_bytes: int) -> None:
        self.trace = trace
        self.queue_bytes = queue_bytes
        self.next_opportunity = 0  # index of the first opportunity not yet passed
        self.backlog = 0  # bytes queued and not delivered by the passed opportunities

    def _advance(self, t: float) -> None:
        """Pass every opportunity at a time <= t (before a chunk arriving at t is queued, as mm-link does)."""
        passed = self.trace.count_until(t) - self.next_opportunity
        if passed > 0:
            self.backlog = max(0, self.backlog - passed * OPPORTUNITY_BYTES)
            self.next_opportunity += passed

    def room_at(self, nbytes: int, t: float) -> float:
        self._advance(t)
        excess = self.backlog + nbytes - self.queue_bytes
        if excess <= 0:
            return t
        return self.trace.opportunity_time(self.next_opportunity + math.ceil(excess / OPPORTUNITY_BYTES) - 1)

    def admit(self, nbytes: int, t: float, marks: list[int]) -> list[float]:
        self._advance(t)
        first = self.next_opportunity - 1
        times = [self.trace.opportunity_time(first + math.ceil((self.backlog + m) / OPPORTUNITY_BYTES)) for m in marks]
        self.backlog += nbytes
        return times


def _serializer(config: DirectionConfig) -> _Unlimited | _Dead | _Rate | _TraceLink:
    if config.trace is not None:
        return _TraceLink(config.trace, config.queue_bytes)
    if config.rate_mbit is None:
        return _Unlimited()
    if config.rate_mbit == 0:
        return _Dead(config.queue_bytes)
    return _Rate(config.rate_mbit, config.queue_bytes)


# --- stage 4: the delay process -------------------------------------------------------------------------


def _normal_cdf_upper(z: float) -> float:
    """P(Z > z) for a standard normal Z, accurate in the far tail."""
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def standardized(dist: str, z: float) -> float:
    """Map a standard-normal value ``z`` to a draw of ``dist`` with mean 0 and standard deviation 1
    (the quantile transform, so the mapped value has exactly that distribution)."""
    if dist == "normal":
        return z
    upper = _normal_cdf_upper(z)
    if dist == "uniform":  # U(-sqrt 3, sqrt 3) has standard deviation 1
        return math.sqrt(3.0) * (1.0 - 2.0 * upper)
    # Pareto(x_m = 1, alpha) cut at PARETO_CAP: X = min((1 - U)^(-1/alpha), cap); moments in closed form above
    x = min(max(upper, 1e-300) ** (-1.0 / PARETO_ALPHA), PARETO_CAP)
    return (x - _PARETO_MEAN) / _PARETO_STD


class DelayProcess:
    """One direction's one-way delay as a function of the time a byte leaves the bottleneck.

    Independent standard-normal knots ``Z_k`` sit every ``T = max(KNOT_SPACING_PER_SIGMA * jitter, 1 ms)``
    seconds; between two knots ``z(t) = ((1-w) Z_k + w Z_k+1) / sqrt((1-w)^2 + w^2)`` is again exactly
    standard normal (a unit-norm combination of independent normals), and the quantile transform
    :func:`standardized` turns it into the configured distribution. So the delay at every instant has the
    configured distribution, neighbouring instants are correlated over about ``T``, and sparse probes see
    independent draws. The delay is clamped at 0 (only matters when the jitter is comparable to the delay).
    Knot ``k`` is a hash of (seed, direction, k): the process needs no memory however long it runs.
    """

    def __init__(self, config: DirectionConfig, seed: int, name: str) -> None:
        self.base_s = config.delay_ms / 1000.0
        self.sigma_s = config.jitter_ms / 1000.0
        self.dist = config.jitter_dist
        self.spacing_s = max(KNOT_SPACING_PER_SIGMA * self.sigma_s, 0.001)
        self._key = f"network_sim/jitter/{seed}/{name}/".encode()
        self._recent: dict[int, float] = {}

    def _knot(self, k: int) -> float:
        if k not in self._recent:
            if len(self._recent) > 64:
                self._recent.clear()
            word = int.from_bytes(hashlib.blake2b(self._key + str(k).encode(), digest_size=8).digest(), "big")
            self._recent[k] = _STANDARD_NORMAL.inv_cdf((word + 0.5) / 2.0**64)
        return self._recent[k]

    def at(self, t: float) -> float:
        """One-way delay (s) of a byte leaving the bottleneck at time ``t`` (s from the origin)."""
        if self.sigma_s == 0.0:
            return self.base_s
        x = max(t, 0.0) / self.spacing_s
        k = int(x)
        w = x - k
        z = ((1.0 - w) * self._knot(k) + w * self._knot(k + 1)) / math.sqrt((1.0 - w) ** 2 + w * w)
        return max(0.0, self.base_s + self.sigma_s * standardized(self.dist, z))


# --- the link -------------------------------------------------------------------------------------------


@dataclass(slots=True)
class Chunk:
    """What the model decided for one chunk (times in s from the origin; ``inf`` = never)."""

    seq: int  # order in which the link was offered chunks (all connections, both directions)
    conn: int
    direction: str
    nbytes: int
    arrival: float  # when the sender offered it
    admitted: float  # when it entered the bottleneck queue (later than arrival = backpressure)
    finish: float  # when its last byte was serialized
    ready: float  # finish plus the retransmission timeouts of its lost segments
    release: float  # when the receiver gets it (ready + propagation delay, kept in stream order)
    lost: float  # lost segment transmissions in it (inf: every transmission is lost)


class Direction:
    """The state one direction of the link shares between connections: its queue/serializer and delay."""

    def __init__(self, name: str, config: DirectionConfig, link: LinkConfig) -> None:
        self.name = name
        self.config = config
        self.serializer = _serializer(config)
        self.delay = DelayProcess(config, link.seed, name)
        self.max_chunk = min(
            config.queue_bytes, link.window_bytes, SHAPED_CHUNK_BYTES if config.shaped else UNSHAPED_CHUNK_BYTES
        )
        self.last_offer = -math.inf
        self.last_admitted = -math.inf


class Stream:
    """One connection's bytes in one direction: FIFO release, window, and its own loss draws."""

    def __init__(self, link: Link, direction: Direction, conn: int, ack_delay_s: float) -> None:
        self.link = link
        self.direction = direction
        self.conn = conn
        self.ack_delay_s = ack_delay_s
        self.offset = 0  # stream bytes offered so far
        self.last_release = -math.inf
        self.unacked: deque[tuple[float, int]] = deque()  # (ack time, bytes), ack times non-decreasing
        self.unacked_bytes = 0
        loss = direction.config.loss
        self._loss_log = math.log(loss) if 0.0 < loss < 1.0 else None
        self._rng = random.Random(f"network_sim/loss/{link.config.seed}/{direction.name}/{conn}")
        self._drawn_segment = -1
        self._drawn_losses = 0.0

    def window_open_at(self, nbytes: int, t: float) -> float:
        """Earliest time >= ``t`` at which ``nbytes`` more fit in the window (``inf``: never)."""
        window = self.link.config.window_bytes
        while self.unacked and (self.unacked[0][0] <= t or self.unacked_bytes + nbytes > window):
            ack, size = self.unacked.popleft()
            self.unacked_bytes -= size
            t = max(t, ack)
        return t

    def _losses(self, segment: int) -> float:
        """Lost transmissions of stream segment number ``segment`` (drawn once, in segment order)."""
        if segment != self._drawn_segment:
            loss = self.direction.config.loss
            if loss >= 1.0:
                self._drawn_losses = math.inf
            elif self._loss_log is None:
                self._drawn_losses = 0.0
            else:  # geometric number of failures before the first success: P(k >= 1) = loss
                self._drawn_losses = float(math.floor(math.log(1.0 - self._rng.random()) / self._loss_log))
            self._drawn_segment = segment
        return self._drawn_losses

    def send(self, nbytes: int, arrival: float) -> Chunk:
        """Offer ``nbytes`` of this stream at ``arrival``; returns the model's decision.

        Arrivals offered to a direction must not decrease (the proxy offers them as it reads them); a
        chunk the window cannot take yet is admitted when it can (callers that must not hold the shared
        queue for it wait until :meth:`window_open_at` first, as the proxy does).
        """
        d = self.direction
        if not 0 < nbytes <= d.max_chunk:
            raise ValueError(f"chunk of {nbytes} bytes; the {d.name} direction takes 1..{d.max_chunk}")
        if arrival < d.last_offer:
            raise ValueError(
                f"arrival {arrival!r} is earlier than the previous one offered to {d.name} ({d.last_offer!r})"
            )
        d.last_offer = arrival
        seq = self.link.offered
        self.link.offered += 1
        admitted = self.window_open_at(nbytes, arrival)
        if math.isfinite(admitted):
            admitted = max(d.serializer.room_at(nbytes, max(admitted, d.last_admitted)), d.last_admitted)
        if not math.isfinite(admitted):  # never enters: leave the shared queue untouched
            self.offset += nbytes
            self.last_release = math.inf
            return Chunk(seq, self.conn, d.name, nbytes, arrival, math.inf, math.inf, math.inf, math.inf, 0.0)
        d.last_admitted = admitted

        marks, losses = [nbytes], [0.0]
        if d.config.loss > 0.0:
            first, last = self.offset // MSS, (self.offset + nbytes - 1) // MSS
            for segment in range(first, last + 1):
                k = self._losses(segment)
                if k:
                    marks.append(min((segment + 1) * MSS, self.offset + nbytes) - self.offset)
                    losses.append(k)
        times = d.serializer.admit(nbytes, admitted, marks)
        finish = times[0]
        rto = self.link.config.rto_s
        ready = max(done + k * rto for done, k in zip(times, losses)) if len(marks) > 1 else finish
        release = max(self.last_release, ready + d.delay.at(ready)) if math.isfinite(ready) else math.inf
        self.last_release = release
        self.offset += nbytes
        self.unacked.append((release + self.ack_delay_s, nbytes))
        self.unacked_bytes += nbytes
        return Chunk(seq, self.conn, d.name, nbytes, arrival, admitted, finish, ready, release, sum(losses))


class Link:
    """The whole emulated link: two shared directions and a pair of streams per connection."""

    def __init__(self, config: LinkConfig) -> None:
        self.config = config
        self.directions = {UP: Direction(UP, config.up, config), DOWN: Direction(DOWN, config.down, config)}
        self.offered = 0
        self._streams: dict[tuple[int, str], Stream] = {}

    def stream(self, conn: int, direction: str) -> Stream:
        """The stream of connection ``conn`` in ``direction`` (created on first use)."""
        key = (conn, direction)
        if key not in self._streams:
            reverse = DOWN if direction == UP else UP
            ack_delay = self.config.direction(reverse).delay_ms / 1000.0
            self._streams[key] = Stream(self, self.directions[direction], conn, ack_delay)
        return self._streams[key]

    def forget(self, conn: int) -> None:
        """Drop a closed connection's streams (the shared directions keep their state)."""
        self._streams.pop((conn, UP), None)
        self._streams.pop((conn, DOWN), None)

    def message(self, conn: int, direction: str, nbytes: int, t: float) -> float:
        """Send ``nbytes`` as fast as the link lets a sender write them, starting at ``t``; returns when
        the receiver has the last byte (``inf``: never). The helper for sweeps of request/response times."""
        stream = self.stream(conn, direction)
        release = t
        max_chunk = self.directions[direction].max_chunk
        while nbytes > 0:
            size = min(nbytes, max_chunk)
            t = stream.window_open_at(size, t)
            if not math.isfinite(t):
                return math.inf
            chunk = stream.send(size, t)
            t, release = chunk.admitted, chunk.release
            nbytes -= size
        return release
