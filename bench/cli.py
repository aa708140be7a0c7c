"""The ``bench`` command: one subcommand per experiment, each writing tidy CSV, provenance and a plot.

Each subcommand is a bench declared in its module (``BENCH``: config, measure, plot); :mod:`bench.runner`
builds its options and runs it. To add one, append its ``BENCH`` to :data:`BENCHES`.
"""

from __future__ import annotations

import typer

from bench import (
    convergence,
    fov,
    frequency,
    latency,
    model_card,
    pareto,
    quality,
    render_bench,
    report,
    run_default,
    scaling,
    service,
    stability,
    storage,
    training,
    warp_bench,
)
from bench.runner import register
from gicore.cli import entry_point

#: Every ``bench`` subcommand, in the order ``bench --help`` lists them.
BENCHES = tuple(
    m.BENCH
    for m in (
        run_default,
        convergence,
        render_bench,
        quality,
        training,
        model_card,
        warp_bench,
        frequency,
        fov,
        latency,
        storage,
        service,
        stability,
        scaling,
        pareto,
        report,
    )
)

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="Experiments of the GIGAN testbed (CSV + provenance + plots)."
)
for _bench in BENCHES:
    register(app, _bench)
main = entry_point(app, resume="run the same command again; each bench rewrites its CSV, provenance and plots whole")
