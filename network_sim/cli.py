"""``network-sim``: the link-emulating proxy, its profiles and traces, the endpoint server, the self-test.

The options of ``proxy``, ``server`` and ``selftest`` are derived from :class:`ProxyOptions`,
:class:`ServerOptions` and :class:`SelftestOptions` (:mod:`gicore.options`): each option is declared once, as a
field, with its default, its limits and its help; :meth:`ProxyOptions.link` maps the proxy's options onto a
:class:`~network_sim.link.LinkConfig`.
"""

from __future__ import annotations

import asyncio
import textwrap
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from gicore import option_groups
from gicore.error_policy import UserError, entry_point, writable_dir
from gicore.options import HOST_PORT, build_config, check_fields, config_command, split_host_port
from network_sim import SERVICES
from network_sim import profiles as profile_table
from network_sim.chunklog import LOG_FIX
from network_sim.files import refuse_irregular
from network_sim.link import DEFAULT_WINDOW_BYTES, JITTER_DISTS, DirectionConfig, LinkConfig
from network_sim.proxy import IDLE_MIN_BYTES, IDLE_TIMEOUT_S, MAX_CONNECTIONS
from network_sim.trace import OPPORTUNITY_BYTES, Trace

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__.split("\n\n")[0])
main = entry_point(app, resume="nothing is kept from an interrupted run; run the command again", services=SERVICES)

#: Largest one-way delay or jitter, ms: a minute (a GEO satellite hop is ~270 ms; more is a typo).
DELAY_MS_MAX = 60_000.0
#: Largest rate, Mbit/s (100 Gbit/s: far above what the proxy forwards on one core).
RATE_MBIT_MAX = 100_000.0
#: Largest bottleneck queue or connection window, bytes (1 GiB; the proxy may hold that much per direction).
BUFFER_BYTES_MAX = 2**30
#: Longest idle timeout, s (a day).
IDLE_TIMEOUT_MAX_S = 86_400.0

DELAY: dict[str, Any] = {"min": 0.0, "max": DELAY_MS_MAX}
#: A rate may be 0: a dead link (nothing passes; a client's request ends in its timeout, never a hang).
RATE: dict[str, Any] = {"min": 0.0, "max": RATE_MBIT_MAX}
BUFFER: dict[str, Any] = {"min": OPPORTUNITY_BYTES, "max": BUFFER_BYTES_MAX}


@dataclass(frozen=True)
class ProxyOptions:
    """``network-sim proxy``'s options: the profile's link (or an unshaped one) with each given setting laid
    over both directions (the ``*_up_*``/``*_down_*`` ones over one); :meth:`link` is the link they describe."""

    #: HOST:PORT of the server the proxy forwards to (checked at start).
    upstream: str | None = field(default=None, metadata={**HOST_PORT, "required": True})
    #: HOST:PORT to accept clients on (port 0: any free port; printed first).
    listen: str = field(default="127.0.0.1:0", metadata=HOST_PORT)
    profile: str | None = profile_table.profile_field(None, note="the link; the options below override its values")
    #: One-way delay added in each direction, ms (an empty round trip takes twice it).
    delay_ms: float | None = field(default=None, metadata=DELAY)
    #: Standard deviation of the delay variation, ms (never reorders a stream).
    jitter_ms: float | None = field(default=None, metadata=DELAY)
    #: Distribution of the delay variation.
    jitter_dist: Literal[JITTER_DISTS] | None = None  # type: ignore[valid-type]
    #: Rate of both directions, Mbit/s of payload (0: nothing passes).
    rate_mbit: float | None = field(default=None, metadata=RATE)
    #: Rate of the client -> upstream direction, Mbit/s.
    rate_up_mbit: float | None = field(default=None, metadata=RATE)
    #: Rate of the upstream -> client direction, Mbit/s.
    rate_down_mbit: float | None = field(default=None, metadata=RATE)
    #: Bottleneck queue per direction, bytes (full: the sender is not read).
    queue_bytes: int | None = field(default=None, metadata=BUFFER)
    #: Bytes a connection may have sent but not acknowledged.
    window_bytes: int = field(default=DEFAULT_WINDOW_BYTES, metadata=BUFFER)
    #: Loss probability per segment transmission (each loss: one retransmission timeout).
    loss: float | None = field(default=None, metadata={"min": 0.0, "max": 1.0})
    #: Mahimahi trace shaping client -> upstream (replaces the rate).
    trace_up: Path | None = None
    #: Mahimahi trace shaping upstream -> client (the server's responses).
    trace_down: Path | None = None
    seed: int = option_groups.seed(note="the jitter and loss draws")
    #: Write one CSV row per chunk (arrival, admission, release, actual send time).
    log: Path | None = None
    #: At exit write how late chunks were written after their release (per direction: chunks, p50, p99, max) and
    #: whether the run was reliable (p99 <= max(0.1 RTT, 1 ms)), as JSON.
    lateness: Path | None = None
    #: Client connections at once; one more is closed on accept (lowered to fit the file-descriptor limit).
    max_connections: int = field(default=MAX_CONNECTIONS, metadata={"min": 1, "max": 1_000_000})
    #: A connection that moved fewer than --idle-min-bytes for this long, s, is closed on both sides.
    idle_timeout_s: float = field(default=IDLE_TIMEOUT_S, metadata={"min": 0.1, "max": IDLE_TIMEOUT_MAX_S})
    #: Bytes a connection must move (read plus written, both legs) per idle timeout not to count as idle.
    idle_min_bytes: int = field(default=IDLE_MIN_BYTES, metadata={"min": 1, "max": BUFFER_BYTES_MAX})

    def __post_init__(self) -> None:
        check_fields(self)  # code building the options meets the command line's limits

    def link(self) -> LinkConfig:
        """The link these options describe: the profile's settings (or none), overridden by each given option."""
        base = profile_table.get(self.profile) if self.profile is not None else None
        shared = {
            "delay_ms": self.delay_ms,
            "jitter_ms": self.jitter_ms,
            "jitter_dist": self.jitter_dist,
            "queue_bytes": self.queue_bytes,
            "loss": self.loss,
        }

        def direction(name: str, current: DirectionConfig, rate: float | None, trace: Path | None) -> DirectionConfig:
            if rate is not None and trace is not None:
                raise UserError(
                    f"--trace-{name} and a rate for the {name} direction were both given",
                    f"drop one: a trace replaces the rate of the {name} direction",
                )
            changes: dict[str, object] = {k: v for k, v in shared.items() if v is not None}
            if rate is not None:
                changes.update(rate_mbit=rate, trace=None)
            if trace is not None:
                changes["trace"] = Trace.load(trace, f"--trace-{name}")
            try:
                return replace(current, **changes)
            except ValueError as exc:  # what the option limits cannot say, e.g. a rate that is neither 0 nor usable
                raise UserError(f"the {name} direction's {exc}", "change that option (see --help)") from None

        up_rate = self.rate_up_mbit if self.rate_up_mbit is not None else self.rate_mbit
        down_rate = self.rate_down_mbit if self.rate_down_mbit is not None else self.rate_mbit
        up = direction("up", base.up if base else DirectionConfig(), up_rate, self.trace_up)
        down = direction("down", base.down if base else DirectionConfig(), down_rate, self.trace_down)
        return LinkConfig(up=up, down=down, window_bytes=self.window_bytes, seed=self.seed)


def link_config(profile: str | None = None, **options: Any) -> LinkConfig:
    """The link of ``network-sim proxy --profile PROFILE`` with ``options`` (:class:`ProxyOptions` fields, by
    name: ``delay_ms=10.0, seed=11``), for code and tests that replay what a proxy ran."""
    return ProxyOptions(profile=profile, **options).link()


def proxy(given: dict[str, Any]) -> None:
    """Proxy TCP connections through an emulated link until SIGTERM/SIGINT."""
    from network_sim.proxy import Settings, run

    opts = build_config(ProxyOptions, given)
    config = opts.link()
    for option, path in (("--log", opts.log), ("--lateness", opts.lateness)):
        if path is not None:  # before the upstream is checked: a FIFO would block the proxy once it opens it
            refuse_irregular(path, option, LOG_FIX)
            writable_dir(path.parent, name=f"{option} folder")
    assert opts.upstream is not None  # a required option
    listen, upstream = split_host_port(opts.listen, "--listen"), split_host_port(opts.upstream, "--upstream")
    settings = Settings(opts.log, opts.lateness, opts.max_connections, opts.idle_timeout_s, opts.idle_min_bytes)
    run(config, listen, upstream, settings)


config_command(app, ProxyOptions, proxy)


@app.command()
def profiles() -> None:
    """List the named links with their parameters and sources."""
    for p in profile_table.profiles().values():
        typer.echo(f"{p.name}\n  up:     {p.up.describe()}\n  down:   {p.down.describe()}")
        typer.echo(textwrap.fill(p.source, 110, initial_indent="  source: ", subsequent_indent="          "))


@dataclass(frozen=True)
class ServerOptions:
    """``network-sim server``'s options."""

    #: HOST:PORT (port 0: any free port; printed first).
    listen: str = field(default="127.0.0.1:0", metadata=HOST_PORT)


def server(given: dict[str, Any]) -> None:
    """Run the echo/sink/source/probe server the self-test and the tests put behind the proxy."""
    from network_sim.endpoint import serve

    opts = build_config(ServerOptions, given)
    host, port = split_host_port(opts.listen, "--listen")
    try:
        asyncio.run(serve(host, port))
    except OSError as exc:
        raise UserError(
            f"--listen {opts.listen}: cannot listen ({exc.strerror or exc})", "pick a free port, or 0 for any"
        ) from None


config_command(app, ServerOptions, server)


@dataclass(frozen=True)
class SelftestOptions:
    """``network-sim selftest``'s options beside ``--out``."""

    #: Shorter runs (about a minute and a half).
    quick: bool = False
    seed: int = option_groups.seed(note="the links and the probe schedule")


def selftest(given: dict[str, Any], *, out: Path) -> None:
    """Measure configured vs realised delay, jitter, goodput, loss delay and overhead; exit 1 if a target is missed."""
    from network_sim.selftest import run_selftest
    from network_sim.selftest_checks import SelftestConfig

    opts = build_config(SelftestOptions, given)
    config = SelftestConfig.quick() if opts.quick else SelftestConfig()
    missed = run_selftest(config, writable_dir(out), opts.seed)
    if missed:
        typer.echo(f"selftest: {missed} target(s) missed (see the table above and {out})", err=True)
        raise typer.Exit(1)


config_command(
    app, SelftestOptions, selftest, extras=[option_groups.out("network_selftest.csv, its provenance JSON and the plot")]
)


@app.command()
def traces(out: Annotated[Path, option_groups.out_option("the generated trace files")]) -> None:
    """Regenerate the shipped LTE traces from their seeded models; show their statistics against the recorded ones."""
    from network_sim.tracegen import MODELS, trace_stats, write_traces

    for model, path in zip(MODELS.values(), write_traces(writable_dir(out))):
        stats = trace_stats(Trace.load(path))
        typer.echo(
            f"{path}: mean {stats['mean_mbit']:.2f} Mbit/s, cv100 {stats['cv100']:.2f}, ac100 {stats['ac100']:.2f}, "
            f"empty100 {stats['empty100']:.3f}  (fitted to {model.source})"
        )
