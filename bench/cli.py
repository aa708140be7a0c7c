"""The ``bench`` command: one subcommand per experiment, each writing tidy CSV, provenance and a plot.

Each subcommand is a bench declared in its module (``BENCH``: config, measure, plot, what the report shows)
and registered in :mod:`bench.registry`; :mod:`bench.runner` builds its options and runs it.
"""

from __future__ import annotations

import typer

from bench import registry, report
from bench.runner import register
from gicore.error_policy import entry_point

#: Every ``bench`` subcommand, in the order ``bench --help`` lists them: the registered benches, then the
#: report that shows them.
BENCHES = (*registry.BENCHES, report.BENCH)

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="Experiments of the GIGAN testbed (CSV + provenance + plots)."
)
for _bench in BENCHES:
    register(app, _bench)
main = entry_point(app, resume="run the same command again; each bench rewrites its CSV, provenance and plots whole")
