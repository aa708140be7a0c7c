"""The one bench runner: every ``bench`` subcommand is a declared config, its ``measure``, and what it shows.

A bench module defines a frozen config dataclass (one option per field, documented by its ``#:`` comment,
with a ``quick()`` preset), ``measure(cfg, results)``, its tables and figures declared once as data
(:mod:`gicore.present.declarations`) and ``BENCH = Bench(...)``; its line in ``bench/registry.py`` gives it its
subcommand, its dashboard section and its results block. The runner derives the options
(:mod:`gicore.options`), adds ``--out``, ``--quick`` and ``--seed``, writes ``<out>/<bench>.csv`` and
``<out>/<bench>.provenance.json``, then the bench's tables (``<bench>.md``) and figures (PNG and SVG) from
the CSV, and prints every path written, then the tables; user errors raise :class:`gicore.error_policy.UserError`.
``bench report`` renders the same declarations. Dependencies run one way: this module <- each bench <-
``bench.registry`` <- the report and the command line. An example bench: docs/architecture.md, Bench runner.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import typer

from gicore import option_groups, options, present
from gicore.fileio import made_folder
from gicore.options import (  # noqa: F401  (field_docs, check_config, config_dict: the bench API)
    FOV_DEGREES,
    check_config,
    config_command,
    config_dict,
    extra,
    field_docs,
)
from gicore.present.declarations import Rows
from gicore.results import Malformed, Results, find_results, load_results, read_rows

#: Option names the runner adds to every bench; config fields may not use them.
RESERVED = ("out", "quick", "seed")


@dataclass(frozen=True)
class Bench:
    """One ``bench`` subcommand: its config class (defaults, ``quick()`` preset), what it measures into a
    :class:`Results`, and what it shows of the resulting CSV (its tables and figures, declared once:
    :mod:`gicore.present`), written beside the CSV and shown by ``bench report``."""

    name: str
    config: type
    measure: Callable[[Any, Results], None]
    help: str
    #: Its section of the dashboard (``report.html``); None: it has none.
    dashboard: Section | None = None
    #: Its block of the README's results (``results.md``); None: it has none.
    readme: Block | None = None
    #: Its tables, figures, images and alerts, in the order shown.
    parts: tuple[present.Part, ...] = ()
    #: Metrics a CSV must hold to be the bench's (another bench's CSV is reported as malformed).
    needs: tuple[str, ...] = ()
    #: Raises a UserError on rows that fail the bench's verdict, once every file is written.
    verdict: Callable[[Rows], None] | None = None


# --- options: derived from the config (gicore.options) -----------------------------------------------------


def build_config(cls: type, quick: bool, given: dict[str, Any]) -> Any:
    """The ``quick()`` preset (or the defaults) with the options the user gave (``given``: field name -> raw
    option value, only for options present), parsed and checked (:func:`gicore.options.build_config`)."""
    return options.build_config(cls, given, cls.quick() if quick else None)


# --- running and registering ------------------------------------------------------------------------


def execute(bench: Bench, cfg: Any, out: Path, seed: int = 0) -> list[Path]:
    """Measure ``cfg`` into ``out``, write CSV + provenance, the bench's tables and figures, then apply its
    verdict; returns every file written."""
    results = Results(bench.name, out, seed, settings=config_dict(cfg))
    bench.measure(cfg, results)
    csv_path = results.write()
    rows = read_rows(csv_path)
    shown = present.write_files(bench.name, bench.parts, rows, out)
    if bench.verdict is not None:
        bench.verdict(rows)
    return [csv_path, results.provenance_path, *results.files, *shown]


def register(app: typer.Typer, bench: Bench) -> Bench:
    """Add ``bench <name>`` to ``app`` with options built from the bench's config (module docstring)."""
    config = bench.config
    for f in dataclasses.fields(config):
        if f.name in RESERVED:
            raise TypeError(f"{config.__name__}.{f.name}: the runner already adds --{f.name}")
    quick_help = "start from the small preset (minutes on 2 cores)"
    extras = [
        option_groups.out("the CSV, its provenance JSON, tables and figures", Path("results")),
        extra("quick", Annotated[bool, typer.Option("--quick", help=quick_help)], False),
        option_groups.seed_parameter("cameras, noise and training"),
    ]

    def run(given: dict[str, Any], *, out: Path, quick: bool, seed: int) -> None:
        cfg = build_config(config, quick, given)
        with made_folder(out) as folder:  # removed again if the run is refused before it writes
            written = execute(bench, cfg, folder, seed)
        for path in written:
            typer.echo(f"wrote {path}")
        tables = [path for path in written if path.name == f"{bench.name}.md"]
        for path in tables:  # the bench's tables, as they were written, so that a run shows its answer
            typer.echo(f"\n{path.read_text()}")

    config_command(app, config, run, name=bench.name, help=bench.help, extras=extras, preset=config.quick())
    return bench


# --- what `bench report` shows of a bench ---------------------------------------------------------------------


@dataclass(frozen=True)
class Section:
    """A bench's section of the dashboard."""

    #: Anchor, and ``section`` in ``report.csv`` (e.g. ``table1``).
    key: str
    #: Heading; the part before a colon names the section in the page's navigation.
    title: str
    #: Place among the sections, lowest first (registration order is ``bench --help``'s).
    order: int


@dataclass(frozen=True)
class Block:
    """A bench's block of the README's results section."""

    title: str
    #: Place among the blocks, lowest first.
    order: int
    #: The command that makes the CSV when it is missing (``{out}``: the results folder); empty:
    #: ``bench <name> --out {out}``.
    make: str = ""


@dataclass(frozen=True)
class External:
    """The CSV ``<name>.csv`` of another program (``network-sim selftest``), shown as a bench's is."""

    name: str
    dashboard: Section | None = None
    readme: Block | None = None
    parts: tuple[present.Part, ...] = ()
    needs: tuple[str, ...] = ()


def need(rows: Rows, *metrics: str) -> None:
    """Refuse rows that hold none of the metrics a bench shows (another bench's CSV, or a stub)."""
    missing = [m for m in metrics if not any(r["metric"] == m for r in rows)]
    if missing:
        raise ValueError(f"it has no {', '.join(missing)} rows")


@dataclass
class Attempt:
    """A bench's newest CSV under a results folder, drawn: status ``ok`` / ``missing`` / ``malformed``, what the
    drawing made of it (when ``ok``), the file (None when missing), the problem in one line, the older runs."""

    status: str
    parts: Any = ()
    path: Path | None = None
    rel: str = ""
    rows: int = 0
    problem: str = ""
    others: list[str] = field(default_factory=list)


def attempt(bench: str, results: Path, draw: Callable[[Rows, Path], Any], ignore: tuple[str, ...] = ()) -> Attempt:
    """Find the newest ``<bench>.csv`` under ``results`` (outside the ``ignore`` folders), load it and ``draw`` its
    rows and folder (a dashboard section or a README block): a CSV that is missing, or does not load or draw,
    comes back with its problem."""
    found = find_results(results, bench, ignore)
    if not found:
        left_out = f" (leaving out {', '.join(ignore)})" if ignore else ""
        return Attempt("missing", problem=f"missing: no {bench}.csv under {results}{left_out}")
    path = found[0]
    rel = str(path.relative_to(results))
    others = [str(p.relative_to(results)) for p in found[1:]]
    try:
        rows = load_results(path)
        parts = draw(rows, path.parent)
    except Exception as exc:  # noqa: BLE001 -- any reason a CSV cannot be drawn is reported in its place, and the others still render
        why = " ".join(str(exc if isinstance(exc, Malformed) else f"{type(exc).__name__}: {exc}").split())
        return Attempt("malformed", path=path, rel=rel, problem=f"malformed: {rel}: {why}", others=others)
    return Attempt("ok", parts, path, rel, len(rows), others=others)
