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

What the runner derives from the config (so no bench declares options by hand):

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
import inspect
import math
import re
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from gicore.cli import UserError, writable_dir
from gicore.results import Results

#: Option names the runner adds to every bench; config fields may not use them.
RESERVED = ("out", "quick", "seed")
#: Field metadata of a camera field of view in degrees (cameras take 0 < FOV < 180).
FOV_DEGREES = {"max": 179.0}


@dataclass(frozen=True)
class Bench:
    """One ``bench`` subcommand: its config class (defaults, ``quick()`` preset), what it measures into a
    :class:`Results`, and how it plots the resulting CSV into a folder (returning the files written)."""

    name: str
    config: type
    measure: Callable[[Any, Results], None]
    plot: Callable[[Path, Path], list[Path]] | None
    help: str


# --- fields: documentation, types, parsing -----------------------------------------------------------


def field_docs(cls: type) -> dict[str, str]:
    """Help text of each field: ``metadata["help"]``, else the ``#:`` comment lines right above it."""
    docs: dict[str, str] = {}
    comment: list[str] = []
    try:
        source = inspect.getsource(cls)
    except (OSError, TypeError):  # made at run time (dataclasses.make_dataclass): metadata only
        source = ""
    for line in source.splitlines():
        text = line.strip()
        if text.startswith("#:"):
            comment.append(text[2:].strip())
            continue
        match = re.match(r"(\w+)\s*:", text)
        if match and comment:
            docs[match.group(1)] = " ".join(comment)
        comment = []
    for f in dataclasses.fields(cls):
        if "help" in f.metadata:
            docs[f.name] = f.metadata["help"]
    return docs


def _strip_optional(tp: Any) -> Any:
    """``X | None`` -> X (an absent option already means "the preset's value", which may be None)."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0]
    return tp


def _scalar_kind(tp: Any) -> str:
    """How a scalar type reads from text (for error messages and metavars)."""
    if typing.get_origin(tp) is Literal:
        return "|".join(str(a) for a in typing.get_args(tp))
    return {int: "INT", float: "FLOAT", str: "TEXT", Path: "PATH"}[tp]


def _parse_scalar(tp: Any, text: str, option: str) -> Any:
    text = text.strip()
    if typing.get_origin(tp) is Literal:
        if text not in typing.get_args(tp):
            raise UserError(
                f"{option} {text!r} is not one of {', '.join(map(str, typing.get_args(tp)))}", "pick one of those"
            )
        return text
    try:
        return tp(text)
    except ValueError:
        raise UserError(
            f"{option} {text!r} is not a valid {_scalar_kind(tp).lower()}", f"give {option} as {_scalar_kind(tp)}"
        ) from None


def _parse(tp: Any, raw: Any, option: str) -> Any:
    """The value of field type ``tp`` from what the option gave (typer already converted scalars)."""
    inner = _strip_optional(tp)
    origin = typing.get_origin(inner)
    if origin is tuple:
        return tuple(_parse_scalar(typing.get_args(inner)[0], s, option) for s in raw.split(",") if s.strip())
    if origin is dict:
        value_type = typing.get_args(inner)[1]
        pairs = [p.split("=", 1) for p in raw.split(",") if p.strip()]
        if any(len(p) != 2 or not p[0].strip() for p in pairs):
            raise UserError(
                f"{option} {raw!r} is not a list of NAME=VALUE pairs", f"give {option} as NAME=VALUE[,NAME=VALUE...]"
            )
        return {name.strip(): _parse_scalar(value_type, value, option) for name, value in pairs}
    return raw


def _option_type(tp: Any, option: str, help_text: str) -> Any:
    """The annotation of the command parameter for a field of type ``tp`` (always optional: None = absent)."""
    inner = _strip_optional(tp)
    origin = typing.get_origin(inner)
    if origin is tuple:
        metavar = f"{_scalar_kind(typing.get_args(inner)[0])},..."
        return Annotated[str | None, typer.Option(option, help=help_text, metavar=metavar, show_default=False)]
    if origin is dict:
        metavar = f"NAME={_scalar_kind(typing.get_args(inner)[1])},..."
        return Annotated[str | None, typer.Option(option, help=help_text, metavar=metavar, show_default=False)]
    if inner is bool:
        return Annotated[bool | None, typer.Option(f"{option}/--no-{option[2:]}", help=help_text, show_default=False)]
    if inner in (int, float, str, Path) or origin is Literal:
        return Annotated[inner | None, typer.Option(option, help=help_text, show_default=False)]
    raise TypeError(f"bench config field type {tp!r} has no command-line form")


def _shown(value: Any) -> str:
    """A default as it would be typed on the command line."""
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value)
    if isinstance(value, dict):
        return ",".join(f"{k}={v}" for k, v in value.items())
    if isinstance(value, bool):
        return "yes" if value else "no"
    return "none" if value is None else str(value)


def config_dict(cfg: Any) -> dict[str, Any]:
    """The config as JSON-ready data (paths as strings, tuples as lists), for provenance."""

    def plain(v: Any) -> Any:
        if isinstance(v, Path):
            return str(v)
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {str(k): plain(x) for k, x in v.items()}
        return v

    return {f.name: plain(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}


# --- config: preset, overrides, checks --------------------------------------------------------------


def build_config(cls: type, quick: bool, given: dict[str, Any]) -> Any:
    """The ``quick()`` preset (or the defaults) with the options the user gave (``given``: field name ->
    raw option value, only for options present), parsed and checked."""
    hints = typing.get_type_hints(cls)
    values = {name: _parse(hints[name], raw, _option(name)) for name, raw in given.items()}
    cfg = dataclasses.replace(cls.quick() if quick else cls(), **values)
    check_config(cfg)
    return cfg


def _option(name: str) -> str:
    return "--" + name.replace("_", "-")


def _check_number(option: str, value: Any, meta: typing.Mapping[str, Any]) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    lo, hi = meta.get("min"), meta.get("max")
    if not math.isfinite(value):
        raise UserError(f"{option} = {value!r} is not finite", f"give {option} a finite number")
    if lo is None and value <= 0:
        raise UserError(f"{option} = {value!r} is not positive", f"give {option} a value > 0")
    if lo is not None and value < lo:
        raise UserError(f"{option} = {value!r} is below {lo}", f"give {option} a value >= {lo}")
    if hi is not None and value > hi:
        raise UserError(f"{option} = {value!r} is above {hi}", f"give {option} a value <= {hi}")


def check_config(cfg: Any) -> None:
    """Range checks on every field of the final config (see the module docstring), then ``cfg.check()``."""
    for f in dataclasses.fields(cfg):
        option, value = _option(f.name), getattr(cfg, f.name)
        items = value if isinstance(value, tuple) else value.values() if isinstance(value, dict) else (value,)
        if isinstance(value, (tuple, dict)) and len(value) < f.metadata.get("min_len", 1):
            raise UserError(f"{option} is empty", f"give at least one value to {option}")
        if isinstance(value, (tuple, dict)) and len(value) > f.metadata.get("max_len", len(value)):
            raise UserError(f"{option} has {len(value)} values", f"give at most {f.metadata['max_len']} to {option}")
        for item in items:
            _check_number(option, item, f.metadata)
        if f.name == "scenes":
            _check_scenes(value)
    if hasattr(cfg, "check"):
        cfg.check()


def _check_scenes(scenes: tuple[str, ...]) -> None:
    """Every scene must load before anything is measured (a typo should not cost a half-finished run)."""
    from gicore.scene import load_scene

    for scene in scenes:
        try:
            load_scene(scene)
        except (OSError, ValueError) as exc:
            raise UserError(
                f"--scenes {scene!r}: {' '.join(str(exc).split())}", "give built-in scene names or spec files"
            ) from None


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
    docs = field_docs(config)
    hints = typing.get_type_hints(config)
    defaults, quick = config(), config.quick()
    params = []
    for f in dataclasses.fields(config):
        if f.name in RESERVED:
            raise TypeError(f"{config.__name__}.{f.name}: the runner already adds --{f.name}")
        if not docs.get(f.name):
            raise TypeError(f"{config.__name__}.{f.name} has no #: comment (its --help text)")
        shown = f"default: {_shown(getattr(defaults, f.name))}"
        if getattr(quick, f.name) != getattr(defaults, f.name):
            shown += f"; --quick: {_shown(getattr(quick, f.name))}"
        annotation = _option_type(hints[f.name], _option(f.name), f"{docs[f.name]} ({shown})")
        params.append(inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=None, annotation=annotation))
    params += [
        inspect.Parameter(
            "out",
            inspect.Parameter.KEYWORD_ONLY,
            default=Path("results"),
            annotation=Annotated[Path, typer.Option("--out", help="folder for the CSV, provenance JSON and plots")],
        ),
        inspect.Parameter(
            "quick",
            inspect.Parameter.KEYWORD_ONLY,
            default=False,
            annotation=Annotated[
                bool, typer.Option("--quick", help="start from the small preset (minutes on 2 cores)")
            ],
        ),
        inspect.Parameter(
            "seed",
            inspect.Parameter.KEYWORD_ONLY,
            default=0,
            annotation=Annotated[int, typer.Option("--seed", help="seeds cameras, noise and training")],
        ),
    ]

    def command(*, out: Path, quick: bool, seed: int, **options: Any) -> None:
        cfg = build_config(config, quick, {k: v for k, v in options.items() if v is not None})
        for path in execute(bench, cfg, writable_dir(out), seed):
            typer.echo(f"wrote {path}")

    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in params}
    command.__doc__ = bench.help
    command.__name__ = bench.name.replace("-", "_")
    app.command(bench.name, help=bench.help)(command)
    return bench
