"""``network-sim``: the link-emulating proxy, its profiles and traces, the endpoint server, the self-test."""

from __future__ import annotations

import asyncio
import math
import textwrap
from dataclasses import replace
from enum import Enum
from pathlib import Path

import typer

from gicore.cli import UserError, entry_point, writable_dir
from network_sim import profiles as profile_table
from network_sim.link import DEFAULT_WINDOW_BYTES, JITTER_DISTS, DirectionConfig, LinkConfig
from network_sim.trace import Trace

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__)
main = entry_point(app, resume="nothing is kept from an interrupted run; run the command again")
Dist = Enum("Dist", {name: name for name in JITTER_DISTS}, type=str)  # type: ignore[misc]


def _finite(flag: str, value: float | None) -> float | None:
    if value is not None and not math.isfinite(value):
        raise UserError(f"{flag} {value!r} is not a finite number", f"give {flag} a finite value")
    return value


def link_config(
    profile: str | None = None,
    *,
    delay_ms: float | None = None,
    jitter_ms: float | None = None,
    jitter_dist: str | None = None,
    rate_mbit: float | None = None,
    rate_up_mbit: float | None = None,
    rate_down_mbit: float | None = None,
    queue_bytes: int | None = None,
    loss: float | None = None,
    trace_up: Path | None = None,
    trace_down: Path | None = None,
    window_bytes: int = DEFAULT_WINDOW_BYTES,
    seed: int = 0,
) -> LinkConfig:
    """The link the proxy flags describe: the profile's settings (or none), overridden by each given flag."""
    for flag, value in (
        ("--delay-ms", delay_ms),
        ("--jitter-ms", jitter_ms),
        ("--rate-mbit", rate_mbit),
        ("--rate-up-mbit", rate_up_mbit),
        ("--rate-down-mbit", rate_down_mbit),
        ("--loss", loss),
    ):
        _finite(flag, value)
    base = profile_table.get(profile) if profile is not None else None

    def direction(name: str, current: DirectionConfig, rate: float | None, trace: Path | None) -> DirectionConfig:
        if rate is not None and trace is not None:
            raise UserError(
                f"--trace-{name} and a rate for the {name} direction were both given",
                f"drop one: a trace replaces the rate of the {name} direction",
            )
        changes: dict[str, object] = {
            k: v
            for k, v in (
                ("delay_ms", delay_ms),
                ("jitter_ms", jitter_ms),
                ("jitter_dist", jitter_dist),
                ("queue_bytes", queue_bytes),
                ("loss", loss),
            )
            if v is not None
        }
        if rate is not None:
            changes.update(rate_mbit=rate, trace=None)
        if trace is not None:
            changes["trace"] = Trace.load(trace)
        return replace(current, **changes)

    up = direction(
        "up", base.up if base else DirectionConfig(), rate_up_mbit if rate_up_mbit is not None else rate_mbit, trace_up
    )
    down = direction(
        "down",
        base.down if base else DirectionConfig(),
        rate_down_mbit if rate_down_mbit is not None else rate_mbit,
        trace_down,
    )
    return LinkConfig(up=up, down=down, window_bytes=window_bytes, seed=seed)


@app.command()
def proxy(
    upstream: str = typer.Option(..., help="HOST:PORT of the server the proxy forwards to (checked at start)."),
    listen: str = typer.Option(
        "127.0.0.1:0", help="HOST:PORT to accept clients on (port 0: any free port; printed first)."
    ),
    profile: str = typer.Option(
        None, help="Named link (see 'network-sim profiles'); the flags below override its values."
    ),
    delay_ms: float = typer.Option(
        None, min=0, help="One-way delay added in each direction, ms (an empty round trip takes twice it)."
    ),
    jitter_ms: float = typer.Option(
        None, min=0, help="Standard deviation of the delay variation, ms (never reorders a stream)."
    ),
    jitter_dist: Dist = typer.Option(None, help="Distribution of the delay variation."),
    rate_mbit: float = typer.Option(
        None, min=0, help="Rate of both directions, Mbit/s of payload (0: nothing passes)."
    ),
    rate_up_mbit: float = typer.Option(None, min=0, help="Rate of the client -> upstream direction, Mbit/s."),
    rate_down_mbit: float = typer.Option(None, min=0, help="Rate of the upstream -> client direction, Mbit/s."),
    queue_bytes: int = typer.Option(
        None, min=1500, help="Bottleneck queue per direction, bytes (full: the sender is not read)."
    ),
    window_bytes: int = typer.Option(
        DEFAULT_WINDOW_BYTES, min=1500, help="Bytes a connection may have sent but not acknowledged."
    ),
    loss: float = typer.Option(
        None, min=0, max=1, help="Loss probability per segment transmission (each loss: one retransmission timeout)."
    ),
    trace_up: Path = typer.Option(None, help="Mahimahi trace shaping client -> upstream (replaces the rate)."),
    trace_down: Path = typer.Option(None, help="Mahimahi trace shaping upstream -> client (the server's responses)."),
    seed: int = typer.Option(0, help="Seed of the jitter and loss draws."),
    log: Path = typer.Option(None, help="Write one CSV row per chunk (arrival, admission, release, actual send time)."),
) -> None:
    """Proxy TCP connections through an emulated link until SIGTERM/SIGINT."""
    from network_sim.proxy import parse_hostport, run

    config = link_config(
        profile,
        delay_ms=delay_ms,
        jitter_ms=jitter_ms,
        jitter_dist=jitter_dist and jitter_dist.value,
        rate_mbit=rate_mbit,
        rate_up_mbit=rate_up_mbit,
        rate_down_mbit=rate_down_mbit,
        queue_bytes=queue_bytes,
        loss=loss,
        trace_up=trace_up,
        trace_down=trace_down,
        window_bytes=window_bytes,
        seed=seed,
    )
    if log is not None:
        writable_dir(log.parent, name="--log folder")
    run(config, parse_hostport(listen, "--listen"), parse_hostport(upstream, "--upstream"), log)


@app.command()
def profiles() -> None:
    """List the named links with their parameters and sources."""
    for p in profile_table.profiles().values():
        typer.echo(f"{p.name}\n  up:     {p.up.describe()}\n  down:   {p.down.describe()}")
        typer.echo(textwrap.fill(p.source, 110, initial_indent="  source: ", subsequent_indent="          "))


@app.command()
def server(listen: str = typer.Option("127.0.0.1:0", help="HOST:PORT (port 0: any free port; printed first).")) -> None:
    """Run the echo/sink/source/probe server the self-test and the tests put behind the proxy."""
    from network_sim.endpoint import serve
    from network_sim.proxy import parse_hostport

    host, port = parse_hostport(listen, "--listen")
    try:
        asyncio.run(serve(host, port))
    except OSError as exc:
        raise UserError(
            f"--listen {listen}: cannot listen ({exc.strerror or exc})", "pick a free port, or 0 for any"
        ) from None


@app.command()
def selftest(
    out: Path = typer.Option(..., help="Folder for network_selftest.csv, its provenance JSON and the plot."),
    quick: bool = typer.Option(False, help="Shorter runs (about a minute and a half)."),
    seed: int = typer.Option(0, help="Seed of the links and of the probe schedule."),
) -> None:
    """Measure configured against realised delay, jitter, goodput, loss delay and overhead; exit 1 if a target is missed."""
    from network_sim.selftest import SelftestConfig, run_selftest

    missed = run_selftest(SelftestConfig.quick() if quick else SelftestConfig(), writable_dir(out), seed)
    if missed:
        typer.echo(f"selftest: {missed} target(s) missed (see the table above and {out})", err=True)
        raise typer.Exit(1)


@app.command()
def traces(out: Path = typer.Option(..., help="Folder to write the generated trace files into.")) -> None:
    """Regenerate the shipped LTE traces from their seeded models and show their statistics against the recorded ones."""
    from network_sim.tracegen import MODELS, trace_stats, write_traces

    for model, path in zip(MODELS.values(), write_traces(writable_dir(out))):
        stats = trace_stats(Trace.load(path))
        typer.echo(
            f"{path}: mean {stats['mean_mbit']:.2f} Mbit/s, cv100 {stats['cv100']:.2f}, ac100 {stats['ac100']:.2f}, "
            f"empty100 {stats['empty100']:.3f}  (fitted to {model.source})"
        )
