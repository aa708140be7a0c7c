"""Command-line options derived from a config dataclass: each option is declared once, as a field.

Every console script and every ``bench`` subcommand builds its Typer command from the config dataclass it
runs: the field declares the option's type, its default, its limits (field metadata) and its help (the ``#:``
comment above it), and nothing else declares them again::

    @dataclass(frozen=True)
    class ClientConfig:
        #: GI-map period k: a new GI map every ``every`` frames.
        every: int = field(default=30, metadata={"aliases": ("-k",)})

    config_command(app, ClientConfig, client, extras=[extra("out", Annotated[Path, typer.Option()])])

How types map to options, the checks on the final config, and the limits declared here once
(:data:`RESOLUTION`, :data:`SPP`, :data:`FRAMES`, :data:`SEED`, :data:`FOV_DEGREES`, :data:`THREADS`,
:data:`HOST_PORT`): docs/architecture.md, Command-line options. Options many commands share (scenes,
resolution, spp, seed, ``--out``, ...) are declared once in :mod:`gicore.option_groups`.
"""

from __future__ import annotations

import contextvars
import dataclasses
import inspect
import linecache
import math
import re
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from gicore.camera import FOV_MIN
from gicore.error_policy import RESOLUTION_MAX, RESOLUTION_MIN, SEED_MAX, UserError

#: Most path-tracing samples per pixel a run may ask for (a 2048² map at 4096 spp takes hours on 2 cores).
SPP_MAX = 4096
#: Most frames one run renders (a fly-through, a dataset split): 100 000 frames are 55 minutes at 30 fps.
FRAMES_MAX = 100_000

#: Field metadata of a square resolution (:data:`gicore.error_policy.RESOLUTION_MIN` to ``RESOLUTION_MAX``).
RESOLUTION: Mapping[str, Any] = {"min": RESOLUTION_MIN, "max": RESOLUTION_MAX}
#: Field metadata of path-tracing samples per pixel.
SPP: Mapping[str, Any] = {"min": 1, "max": SPP_MAX}
#: Field metadata of a frame count.
FRAMES: Mapping[str, Any] = {"min": 1, "max": FRAMES_MAX}
#: Field metadata of a seed.
SEED: Mapping[str, Any] = {"min": 0, "max": SEED_MAX}
#: Field metadata of a camera field of view in degrees (cameras take FOV_MIN <= FOV < 180).
FOV_DEGREES: Mapping[str, Any] = {"min": FOV_MIN, "max": 179.0}
#: Field metadata of a thread or worker-process count.
THREADS: Mapping[str, Any] = {"min": 1, "max": 256}
#: Field metadata of a ``HOST:PORT`` address string (port 0 to 65535; 0: any free port).
HOST_PORT: Mapping[str, Any] = {"host_port": True, "metavar": "HOST:PORT"}


# --- fields: documentation, names, types, parsing ------------------------------------------------------------


def field_docs(cls: type) -> dict[str, str]:
    """Help text of each field: ``metadata["help"]``, else the ``#:`` comment lines right above it (in the
    class or the base that declares it)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        comment: list[str] = []
        for line in _class_lines(klass):
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


def _class_lines(klass: type) -> list[str]:
    """The source lines of ``klass``'s body: the block (:func:`inspect.getblock`) from its ``class`` line, found by
    name in its module's cached lines, as :func:`inspect.getsource` parses the whole module for each class (a
    tenth of a second per command start); that parse only where the name is ambiguous. Nothing for a class made at
    run time (``dataclasses.make_dataclass``): its fields' metadata is all there is."""
    try:
        lines = linecache.getlines(inspect.getsourcefile(klass) or "")
    except TypeError:  # a built-in
        return []
    heads = [i for i, line in enumerate(lines) if re.match(rf"\s*class {klass.__name__}\b", line)]
    if len(heads) != 1:
        try:
            return inspect.getsource(klass).splitlines() if heads else []
        except (OSError, TypeError):
            return []
    return inspect.getblock(lines[heads[0] :])


def option_name(f: dataclasses.Field) -> str:
    """How messages name field ``f``: ``--field-name`` (or its ``metadata["option"]``); an argument's NAME."""
    if f.metadata.get("argument"):
        return f.name.upper()
    return "--" + f.metadata.get("option", f.name).replace("_", "-").lower()


def _strip_optional(tp: Any) -> Any:
    """``X | None`` -> X (an absent option already means "the base config's value", which may be None)."""
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
    if origin in (tuple, list):
        words = raw if isinstance(raw, (list, tuple)) else raw.split(",")  # an argument's words, or one option
        items = (_parse_scalar(typing.get_args(inner)[0], s, option) for s in words if s.strip())
        return origin(items)
    if origin is dict:
        value_type = typing.get_args(inner)[1]
        pairs = [p.split("=", 1) for p in raw.split(",") if p.strip()]
        if any(len(p) != 2 or not p[0].strip() for p in pairs):
            raise UserError(
                f"{option} {raw!r} is not a list of NAME=VALUE pairs", f"give {option} as NAME=VALUE[,NAME=VALUE...]"
            )
        return {name.strip(): _parse_scalar(value_type, value, option) for name, value in pairs}
    return raw


def _is_number(tp: Any) -> bool:
    """Whether values of field type ``tp`` (or its entries) are numbers, which have limits."""
    inner = _strip_optional(tp)
    origin = typing.get_origin(inner)
    if origin in (tuple, list, dict):
        return _is_number(typing.get_args(inner)[-1 if origin is dict else 0])
    return inner in (int, float)


def limits_text(meta: Mapping[str, Any]) -> str:
    """A number's limits as --help states them, e.g. ``[> 0]``, ``[1 to 100000]``."""
    lo, hi = meta.get("min"), meta.get("max")
    low = "> 0" if lo is None else f">= {lo}"
    if hi is None:
        return f"[{low}]"
    if meta.get("max_open"):
        return f"[{low}, < {hi}]"
    return f"[> 0, <= {hi}]" if lo is None else f"[{lo} to {hi}]"


def _option_type(f: dataclasses.Field, tp: Any, help_text: str) -> Any:
    """The annotation of the command parameter for field ``f`` of type ``tp`` (always optional: None = absent)."""
    inner = _strip_optional(tp)
    origin = typing.get_origin(inner)
    name = option_name(f)
    if f.metadata.get("argument"):
        if origin not in (tuple, list):
            raise TypeError(f"field {f.name}: only a tuple or list field can be the command's argument")
        return Annotated[list[str] | None, typer.Argument(help=help_text, metavar=name, show_default=False)]
    names = (name, *f.metadata.get("aliases", ()))
    if origin in (tuple, list):
        metavar = f"{_scalar_kind(typing.get_args(inner)[0])},..."
        return Annotated[str | None, typer.Option(*names, help=help_text, metavar=metavar, show_default=False)]
    if origin is dict:
        metavar = f"NAME={_scalar_kind(typing.get_args(inner)[1])},..."
        return Annotated[str | None, typer.Option(*names, help=help_text, metavar=metavar, show_default=False)]
    if inner is bool:
        return Annotated[bool | None, typer.Option(f"{name}/--no-{name[2:]}", help=help_text, show_default=False)]
    if inner in (int, float, str, Path) or origin is Literal:
        metavar = f.metadata.get("metavar")
        return Annotated[inner | None, typer.Option(*names, help=help_text, metavar=metavar, show_default=False)]
    raise TypeError(f"config field {f.name} of type {tp!r} has no command-line form")


def as_typed(value: Any) -> str:
    """A default as it would be typed on the command line."""
    if isinstance(value, (tuple, list)):
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


# --- checks ------------------------------------------------------------------------------------------------


def check_number(option: str, value: Any, meta: Mapping[str, Any]) -> None:
    """A number must be finite and within the field's limits (> 0 unless ``min`` is given)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    lo, hi = meta.get("min"), meta.get("max")
    if not math.isfinite(value):
        raise UserError(f"{option} = {value!r} is not finite", f"give {option} a finite number")
    if lo is None and value <= 0:
        raise UserError(f"{option} = {value!r} is not positive", f"give {option} a value > 0")
    if lo is not None and value < lo:
        raise UserError(f"{option} = {value!r} is below {lo}", f"give {option} a value >= {lo}")
    if hi is not None and meta.get("max_open") and value >= hi:
        raise UserError(f"{option} = {value!r} is not below {hi}", f"give {option} a value < {hi}")
    if hi is not None and value > hi:
        raise UserError(f"{option} = {value!r} is above {hi}", f"give {option} a value <= {hi}")


def limits(f: dataclasses.Field) -> Mapping[str, Any]:
    """Field ``f``'s metadata with the limits it takes by name (a resolution's, unless it sets its own)."""
    is_resolution = f.name == "resolution" or f.name.endswith("_resolution")
    if is_resolution and "min" not in f.metadata and "max" not in f.metadata:
        return {**RESOLUTION, **f.metadata}
    return f.metadata


def check_field(f: dataclasses.Field, tp: Any, value: Any) -> None:
    """Field ``f`` (of type ``tp``) may hold ``value`` (see the module docstring); UserError naming it."""
    option = option_name(f)
    if isinstance(value, (tuple, list, dict)):
        if len(value) < f.metadata.get("min_len", 1):
            raise UserError(f"{option} is empty", f"give at least one value to {option}")
        if len(value) > f.metadata.get("max_len", len(value)):
            raise UserError(f"{option} has {len(value)} values", f"give at most {f.metadata['max_len']} to {option}")
    inner = _strip_optional(tp)
    items = value if isinstance(value, (tuple, list)) else value.values() if isinstance(value, dict) else (value,)
    for item in items:
        check_number(option, item, limits(f))
    if typing.get_origin(inner) is Literal and value is not None and value not in typing.get_args(inner):
        choices = ", ".join(map(str, typing.get_args(inner)))
        raise UserError(f"{option} {value!r} is not one of {choices}", "pick one of those")
    check = f.metadata.get("check")  # an entry's own check, e.g. that a scene loads (gicore.option_groups)
    if check is not None and value is not None:
        for item in items:
            check(option, item)
    if f.metadata.get("host_port") and value is not None:
        split_host_port(value, option)


def split_host_port(value: str, option: str) -> tuple[str, int]:
    """``HOST:PORT`` (an IPv6 host in brackets; port 0 to 65535) as (host, port), or a UserError naming ``option``."""
    host, sep, port = value.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise UserError(
            f"{option} {value!r} is not HOST:PORT", f"give e.g. {option} 127.0.0.1:8000 (port 0 picks a free port)"
        )
    return host.strip("[]"), int(port)


def check_fields(cfg: Any, names: Iterable[str] | None = None) -> None:
    """:func:`check_field` on every field of ``cfg`` (or on those in ``names``); a config's ``__post_init__``
    may call it so that code building the config meets the command line's limits."""
    hints = typing.get_type_hints(type(cfg))
    wanted = None if names is None else set(names)
    for f in dataclasses.fields(cfg):
        if wanted is None or f.name in wanted:
            check_field(f, hints[f.name], getattr(cfg, f.name))


def check_config(cfg: Any) -> None:
    """Checks on every field of the final config (see the module docstring), then ``cfg.check()``."""
    check_fields(cfg)
    if hasattr(cfg, "check"):
        cfg.check()


# --- config: base, options given, checks -------------------------------------------------------------------


def parse_options(cls: type, given: Mapping[str, Any]) -> dict[str, Any]:
    """The field values of the options given (``given``: field name -> raw option value, only for options
    present), parsed and each checked on its own."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values = {}
    for name, raw in given.items():
        value = _parse(hints[name], raw, option_name(fields[name]))
        check_field(fields[name], hints[name], value)
        values[name] = value
    for name in values:
        clash = [fields[c] for c in fields[name].metadata.get("conflicts", ()) if c in values]
        if clash:
            option, other = option_name(fields[name]), option_name(clash[0])
            raise UserError(f"{option} and {other} conflict: {option} sets what {other} would", f"drop {other}")
    return values


def build_config(cls: type, given: Mapping[str, Any], base: Any = None) -> Any:
    """``base`` (default: ``cls()``, the defaults) with the options the user gave (see :func:`parse_options`),
    checked as a whole (:func:`check_config`). A ``ValueError`` of the constructor is a user error."""
    values = parse_options(cls, given)
    try:
        cfg = dataclasses.replace(cls() if base is None else base, **values)
    except ValueError as err:  # a combination of values the config refuses
        raise UserError(f"invalid options: {' '.join(str(err).split())}", f"see '{_command_path()} --help'") from None
    check_config(cfg)
    return cfg


def build_options(cls: type, **received: Any) -> Any:
    """:func:`build_config` of the options a command received as parameters of its own (those
    :func:`config_options` adds; ``None``: not given)."""
    return build_config(cls, {k: v for k, v in received.items() if v is not None})


#: The running command's path (``gigan-client``), for messages; set by the commands :func:`config_command` makes.
_COMMAND: contextvars.ContextVar[str] = contextvars.ContextVar("command", default="the command")


def _command_path() -> str:
    return _COMMAND.get()


# --- commands ------------------------------------------------------------------------------------------------


def extra(name: str, annotation: Any, default: Any = inspect.Parameter.empty) -> inspect.Parameter:
    """A command parameter that is no config field (``--out``, ``--server``): ``annotation`` is an
    ``Annotated[type, typer.Option(...)]``; without a default it is required."""
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)


def config_options(
    config: type, *, exclude: Sequence[str] = (), preset: Any = None, preset_option: str = "--quick"
) -> list[inspect.Parameter]:
    """The command parameters of ``config``'s fields (all but ``exclude``), each None when absent; help shows
    the default, ``preset``'s value where it differs (under ``preset_option``) and the limits."""
    docs = field_docs(config)
    hints = typing.get_type_hints(config)
    defaults = config()
    params = []
    for f in dataclasses.fields(config):
        if f.name in exclude or not f.init:
            continue
        if not docs.get(f.name):
            raise TypeError(f"{config.__name__}.{f.name} has no #: comment (its --help text)")
        default = getattr(defaults, f.name)
        shown = [] if default is None or as_typed(default) == "" else [f"default: {as_typed(default)}"]
        if preset is not None and getattr(preset, f.name) != getattr(defaults, f.name):
            shown.append(f"{preset_option}: {as_typed(getattr(preset, f.name))}")
        help_text = docs[f.name] + (f" ({'; '.join(shown)})" if shown else "")
        if _is_number(hints[f.name]):
            help_text += f" {limits_text(limits(f))}"
        annotation = _option_type(f, hints[f.name], help_text)
        absent = inspect.Parameter.empty if f.metadata.get("required") else None  # no default: typer requires it
        params.append(inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=absent, annotation=annotation))
    return params


def config_command(
    app: typer.Typer,
    config: type,
    body: Callable[..., None],
    *,
    name: str | None = None,
    help: str | None = None,
    extras: Sequence[inspect.Parameter] = (),
    exclude: Sequence[str] = (),
    preset: Any = None,
    preset_option: str = "--quick",
) -> Callable[..., None]:
    """Add a command to ``app`` with one option per field of ``config`` (:func:`config_options`) and the
    ``extras`` (:func:`extra`). It calls ``body(given, **extras)``: ``given`` maps each field whose option
    the user gave to its raw value (for :func:`build_config`), the extras come by name."""
    params = [*config_options(config, exclude=exclude, preset=preset, preset_option=preset_option), *extras]
    fields = [p.name for p in params[: len(params) - len(extras)]]
    clash = set(fields) & {p.name for p in extras}
    if clash:
        raise TypeError(f"{config.__name__}: the command already adds {sorted(clash)}")

    def command(command_context: typer.Context, **values: Any) -> None:
        given = {k: values[k] for k in fields if values[k] is not None}
        token = _COMMAND.set(command_context.command_path)
        try:
            body(given, **{p.name: values[p.name] for p in extras})
        finally:
            _COMMAND.reset(token)

    context = inspect.Parameter("command_context", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=typer.Context)
    command.__signature__ = inspect.Signature([context, *params])  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in (context, *params)}
    command.__doc__ = help or body.__doc__
    command.__name__ = (name or body.__name__).replace("-", "_")
    app.command(name, help=help)(command)
    return command
