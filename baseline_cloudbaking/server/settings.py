"""Server settings, declared once: environment variables prefixed ``CLOUDBAKING_`` (e.g.
``CLOUDBAKING_MAX_SPP=64``), overridden by ``cloudbaking-server`` options. A ``CLOUDBAKING_*`` variable that
names no setting is refused (:func:`check_environment`): a typo would otherwise leave the default in force
without a word.

Each setting is also an option of ``cloudbaking-server`` (:func:`setting_options`): ``--max-spp`` for
``max_spp``, with the setting's description, default, variable and limits as its help and checks;
:data:`OPTION_FORMS` says where an option differs from the setting (its name, its unit).
"""

from __future__ import annotations

import dataclasses
import os
import typing
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any

from annotated_types import Ge, Gt, Le, Lt, MinLen
from pydantic import Field, field_validator
from pydantic.fields import FieldInfo
from pydantic_settings import BaseSettings, SettingsConfigDict

from baseline_cloudbaking.server.hosts import parse_host
from baseline_cloudbaking.store import DEFAULT_BUDGET_BYTES, DEFAULT_LIGHT_CELL, store_folder
from baseline_cloudbaking.viewpoints import Tolerance
from gicore.error_policy import UserError
from gicore.options import RESOLUTION_MAX, RESOLUTION_MIN, SEED_MAX, SPP_MAX, THREADS, as_typed

ENV_PREFIX = "CLOUDBAKING_"
#: Largest GI-tree budget, bytes (16 TiB).
BUDGET_BYTES_MAX = 1 << 44

#: A square map resolution the server may serve (the one limit of every run, :mod:`gicore.options`).
ServedResolution = Annotated[int, Field(ge=RESOLUTION_MIN, le=RESOLUTION_MAX)]


class Settings(BaseSettings):
    """Everything the server process needs; immutable once the app is created."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, frozen=True, extra="forbid")

    store: Path = Field(Path("gi_store"), description="GI-tree folder (created if missing)")
    scenes_dir: Path | None = Field(None, description="extra scene specs (*.toml, *.json) served by file stem")
    budget_bytes: int = Field(
        DEFAULT_BUDGET_BYTES,
        gt=0,
        le=BUDGET_BYTES_MAX,
        description="payload byte budget of the GI tree (least recently used maps are evicted beyond it)",
    )
    tolerance_position: float = Field(
        Tolerance.position,
        ge=0.0,
        allow_inf_nan=False,
        description="Δp: largest eye distance a stored map serves, scene units",
    )
    tolerance_angle_deg: float = Field(
        Tolerance.angle_deg,
        ge=0.0,
        le=180.0,
        allow_inf_nan=False,
        description="Δθ: largest view angle a stored map serves, degrees",
    )
    light_cell: float = Field(
        DEFAULT_LIGHT_CELL,
        gt=0.0,
        allow_inf_nan=False,
        description="side of a light cell (scene units) for scenes whose light moves",
    )
    resolutions: tuple[ServedResolution, ...] = Field(
        (64, 128, 256, 512), min_length=1, description="square map resolutions served"
    )
    max_spp: int = Field(256, ge=1, le=SPP_MAX, description="largest spp a request may ask for")
    max_body_bytes: int = Field(4096, ge=256, le=1 << 20, description="largest accepted request body (held in memory)")
    max_renderers: int = Field(
        4, ge=1, le=64, description="compiled (scene, resolution) renderers kept in memory (each holds its scene)"
    )
    render_threads: int | None = Field(
        None, ge=1, le=THREADS["max"], description="Dr.Jit threads for rendering (default: all cores)"
    )
    seed: int = Field(0, ge=0, le=SEED_MAX, description="seeds every render's noise (with the scene and the camera)")
    miss_queue: int = Field(
        8, ge=0, le=10_000, description="misses that may wait for the renderer; one more is answered 503 + Retry-After"
    )
    max_connections: int = Field(
        1024,
        ge=8,
        le=1_000_000,
        description="open HTTP connections; beyond it the longest-idle one is closed, or the new one refused with 503 "
        "(lowered to fit the process's file-descriptor limit)",
    )
    idle_timeout_s: float = Field(
        5.0,
        gt=0.0,
        le=3600.0,
        allow_inf_nan=False,
        description="a connection without a whole request head for this long is closed (keep-alive, slow headers)",
    )
    graceful_timeout_s: float = Field(
        30.0,
        gt=0.0,
        le=3600.0,
        allow_inf_nan=False,
        description="on SIGTERM or SIGINT, how long the miss being rendered may take to finish, be stored and "
        "answered (misses still waiting are answered 503 at once)",
    )
    body_timeout_s: float = Field(
        10.0, gt=0.0, le=3600.0, allow_inf_nan=False, description="a request body not complete in this time gets 408"
    )
    max_header_bytes: int = Field(16_384, ge=1024, le=1 << 20, description="largest request head (line and headers)")
    cors_origins: tuple[str, ...] = Field(
        (),
        description="origins (scheme://host[:port]) whose pages may call the API from a browser; none by default, "
        "never '*'",
    )

    allowed_hosts: tuple[str, ...] = Field(
        (),
        description="Host names a request may name besides the server's address and loopback's, a guard against "
        "DNS rebinding; checked where the server listens on loopback or where this names one; '*': any",
    )

    @field_validator("allowed_hosts")
    @classmethod
    def _host_names(cls, hosts: tuple[str, ...]) -> tuple[str, ...]:
        for host in hosts:
            parsed = parse_host(host)
            if host != "*" and (parsed is None or parsed[1] is not None):
                raise ValueError(
                    f"{host!r} is not a host name: give e.g. gi.example.org or 192.0.2.7 (no port), or '*'"
                )
        return tuple(host.lower() for host in hosts)

    @field_validator("cors_origins")
    @classmethod
    def _exact_origins(cls, origins: tuple[str, ...]) -> tuple[str, ...]:
        for origin in origins:
            scheme, sep, rest = origin.partition("://")
            if scheme not in ("http", "https") or not sep or not rest or "/" in rest or "*" in rest:
                raise ValueError(f"{origin!r} is not an origin: give scheme://host[:port], e.g. http://127.0.0.1:8080")
        return origins

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_position, self.tolerance_angle_deg)

    @property
    def default_resolution(self) -> int:
        """The resolution of a request that names none: 256 where served, else the first served."""
        return 256 if 256 in self.resolutions else self.resolutions[0]

    @property
    def default_spp(self) -> int:
        """The spp of a request that names none."""
        return min(64, self.max_spp)


def env_name(field: str) -> str:
    """The environment variable of setting ``field``."""
    return f"{ENV_PREFIX}{field.upper()}"


def check_environment(environ: Mapping[str, str] = os.environ) -> None:
    """UserError naming the first ``CLOUDBAKING_*`` variable that is no setting, with the valid names."""
    valid = sorted(env_name(name) for name in Settings.model_fields)
    for name in sorted(environ):
        if name.upper().startswith(ENV_PREFIX) and name.upper() not in valid:
            raise UserError(f"environment variable {name} is not a setting", f"unset it; valid: {', '.join(valid)}")


@lru_cache
def get_settings() -> Settings:
    """The settings from the environment, read once per process."""
    return Settings()


# --- the settings as command-line options -----------------------------------------------------------------

#: Where a setting's option differs from ``--setting-name`` of the setting's type: ``option`` renames it;
#: ``scale`` takes it in ``unit`` (the setting is the option's value times ``scale``, in ``setting_unit``);
#: ``type`` reads it as that type, checked by ``check``; ``required`` makes the command require it.
OPTION_FORMS: Mapping[str, Mapping[str, Any]] = {
    "store": {"type": str, "required": True, "check": lambda option, text: store_folder(text, option)},
    "scenes_dir": {"option": "scenes"},
    "budget_bytes": {"option": "budget_mb", "type": float, "scale": 2**20, "unit": "MiB", "setting_unit": "bytes"},
}


def setting_options(base: type) -> type:
    """A frozen dataclass of ``base``'s fields then one option field per setting (:mod:`gicore.options`), each
    None unless given, when the variable or the default holds: help, limits and checks from the setting."""
    fields = [_option_field(name, info) for name, info in Settings.model_fields.items()]
    return dataclasses.make_dataclass("SettingOptions", fields, bases=(base,), frozen=True)


def given_settings(options: Any) -> dict[str, Any]:
    """The settings that ``options`` (of :func:`setting_options`) give, in the settings' units."""
    given = {}
    for f in dataclasses.fields(options):
        value = getattr(options, f.name)
        if "setting" in f.metadata and value is not None:
            scale = f.metadata.get("scale")
            given[f.metadata["setting"]] = value if scale is None else round(value * scale)
    return given


def _option_field(name: str, info: FieldInfo) -> tuple[str, Any, Any]:
    """The option field of setting ``name``: (field name, type, field)."""
    form = OPTION_FORMS.get(name, {})
    plain, entry = _plain(info.annotation)
    scale = form.get("scale", 1)
    default = info.default if scale == 1 else info.default / scale
    shown = "" if default is None or as_typed(default) == "" else f"default: {as_typed(default)}; "
    unit = f", in {form['unit']}" if "unit" in form else ""
    env = env_name(name) + (f" in {form['setting_unit']}" if "setting_unit" in form else "")
    source = "" if form.get("required") else f" ({shown}env {env})"  # a required option overrides both
    metadata = {
        **_limits([*info.metadata, *entry], scale),
        **{k: form[k] for k in ("required", "check") if k in form},
        "help": f"{info.description}{unit}{source}",
        "setting": name,
        **({"scale": scale} if scale != 1 else {}),
    }
    return form.get("option", name), form.get("type", plain) | None, dataclasses.field(default=None, metadata=metadata)


def _plain(annotation: Any) -> tuple[Any, list[Any]]:
    """A setting's type without ``None`` or constraints, and the constraints on each entry of a tuple."""
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) is tuple and typing.get_origin(args[0]) is Annotated:
        entry, *infos = typing.get_args(args[0])
        return tuple[entry, ...], [c for i in infos for c in i.metadata]
    if type(None) in typing.get_args(annotation):
        return args[0], []
    return annotation, []


def _limits(constraints: list[Any], scale: float) -> dict[str, Any]:
    """Pydantic's constraints as :mod:`gicore.options` limits (a number without a lower one must be > 0)."""
    limits: dict[str, Any] = {"min_len": 0}
    for c in constraints:
        if isinstance(c, Ge):
            limits["min"] = c.ge if scale == 1 else c.ge / scale
        elif isinstance(c, Gt) and c.gt != 0:
            raise TypeError(f"no option form for > {c.gt}: give the setting ge= or gt=0")
        elif isinstance(c, (Le, Lt)):
            bound = c.le if isinstance(c, Le) else c.lt
            limits |= {"max": bound if scale == 1 else bound / scale, "max_open": isinstance(c, Lt)}
        elif isinstance(c, MinLen):
            limits["min_len"] = c.min_length
    return limits


def check_served(resolution: int) -> None:
    """Refuse, before any process starts, a map resolution a server started from this environment would not
    serve (its settings: the defaults, or CLOUDBAKING_RESOLUTIONS, which a child process inherits)."""
    served = Settings().resolutions
    if resolution not in served:
        raise UserError(
            f"--resolution {resolution} is not served by cloudbaking-server",
            f"use one of {', '.join(map(str, served))}",
        )
