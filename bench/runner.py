"""The one bench runner: every ``bench`` subcommand is a declared config plus ``measure`` and ``plot``.

How to add a bench (say ``bench latency``), in ``bench/latency.py``::

    @dataclass(frozen=True)
    class LatencyConfig:
        \"\"\"What one run measures.\"\"\"

        #: Scene names or spec files.
        scenes: tuple[str, ...] = ("lung_plane",)
        #: Square resolution in pixels.
        resolution: int = 256
        #: Network profiles to replay (``network_sim``).
        profiles: tuple[str, ...] = ("4g", "wifi")
        #: Seconds between requests; 0 sends back to back.
        gap_s: float = field(default=0.5, metadata={"min": 0.0})

        @classmethod
        def quick(cls) -> "LatencyConfig":
            return cls(resolution=128, profiles=("wifi",))

    def measure(cfg: LatencyConfig, results: Results) -> None:
        ...  # results.add(...) / results.add_timing(...); seed: results.seed; extra files: results.output("x.md")

    def plot(csv_path: Path, out_dir: Path) -> list[Path]:
        ...  # reads only the CSV; returns the PNGs it wrote

    BENCH = Bench("latency", LatencyConfig, measure, plot, help="Table 1: ...")

and add ``latency.BENCH`` to the list in ``bench/cli.py``. A bench that runs others (``run-default``)
calls :func:`execute` on their ``BENCH`` objects.

What the runner derives from the config with :mod:`gicore.options` (so no bench declares options by hand):

- one option per field, ``--field-name``; help is the field's ``#:`` comment (or ``metadata["help"]``),
  followed by its default and its ``quick()`` value; every field must be documented;
- types: ``int``/``float``/``str``/``Path`` as they are, ``bool`` as ``--x/--no-x``, ``X | None`` as X
  (absent = the preset's value, which may be None), ``Literal[...]`` as a choice, ``tuple[X, ...]`` as one
  comma-separated option (``--scenes a,b``), ``dict[str, X]`` as comma-separated ``NAME=VALUE`` pairs;
- checks on the final config (preset, then the options the user gave; an absent option never falls back
  to a default by truthiness): numbers must be > 0 unless the field's metadata sets ``min`` (inclusive;
  ``max`` inclusive too), tuples must be non-empty unless ``metadata["min_len"] = 0`` and hold at most
  ``metadata["max_len"]`` entries (``max_len=1``: a bench of one scene), and every entry of
  a ``scenes`` field must load as a scene; a config may add a ``check(self)`` method raising ``UserError``;
- always ``--out DIR`` (checked with :func:`gicore.cli.writable_dir`), ``--quick`` (start from
  ``quick()`` instead of the defaults) and ``--seed``.

A run: ``measure`` fills a :class:`gicore.results.Results`; the runner writes ``<out>/<bench>.csv`` and
``<out>/<bench>.provenance.json`` (whose ``settings`` is the final config), calls ``plot`` on the CSV and
prints every path written. User errors raise :class:`gicore.cli.UserError`; the ``bench`` entry point
turns them into one ``error:`` line and exit status 2.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from gicore import options
from gicore.cli import writable_dir
from gicore.options import (  # noqa: F401  (field_docs, check_config, config_dict: the bench API)
    FOV_DEGREES,
    SEED_MAX,
    check_config,
    config_command,
    config_dict,
    extra,
    field_docs,
)
from gicore.results import Results

#: Option names the runner adds to every bench; config fields may not use them.
RESERVED = ("out", "quick", "seed")


@dataclass(frozen=True)
class Bench:
    """One ``bench`` subcommand: its config class (defaults, ``quick()`` preset), what it measures into a
    :class:`Results`, and how it plots the resulting CSV into a folder (returning the files written)."""

    name: str
    config: type
    measure: Callable[[Any, Results], None]
    plot: Callable[[Path, Path], list[Path]] | None
    help: str


# --- options: derived from the config (gicore.options) -----------------------------------------------------


def build_config(cls: type, quick: bool, given: dict[str, Any]) -> Any:
    """The ``quick()`` preset (or the defaults) with the options the user gave (``given``: field name -> raw
    option value, only for options present), parsed and checked (:func:`gicore.options.build_config`)."""
    return options.build_config(cls, given, cls.quick() if quick else None)


# --- running and registering ------------------------------------------------------------------------


def execute(bench: Bench, cfg: Any, out: Path, seed: int = 0) -> list[Path]:
    """Measure ``cfg`` into ``out``, write CSV + provenance, plot; returns every file written."""
    results = Results(bench.name, out, seed, settings=config_dict(cfg))
    bench.measure(cfg, results)
    csv_path = results.write()
    plots = bench.plot(csv_path, out) if bench.plot else []
    return [csv_path, results.provenance_path, *results.files, *plots]


def register(app: typer.Typer, bench: Bench) -> Bench:
    """Add ``bench <name>`` to ``app`` with options built from the bench's config (module docstring)."""
    config = bench.config
    for f in dataclasses.fields(config):
        if f.name in RESERVED:
            raise TypeError(f"{config.__name__}.{f.name}: the runner already adds --{f.name}")
    out_help = "folder for the CSV, provenance JSON and plots"
    quick_help = "start from the small preset (minutes on 2 cores)"
    seed_help = f"seeds cameras, noise and training [0 to {SEED_MAX}]"
    extras = [
        extra("out", Annotated[Path, typer.Option("--out", help=out_help)], Path("results")),
        extra("quick", Annotated[bool, typer.Option("--quick", help=quick_help)], False),
        extra("seed", Annotated[int, typer.Option("--seed", min=0, max=SEED_MAX, help=seed_help)], 0),
    ]

    def run(given: dict[str, Any], *, out: Path, quick: bool, seed: int) -> None:
        cfg = build_config(config, quick, given)
        for path in execute(bench, cfg, writable_dir(out), seed):
            typer.echo(f"wrote {path}")

    config_command(app, config, run, name=bench.name, help=bench.help, extras=extras, preset=config.quick())
    return bench
