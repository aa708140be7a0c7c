"""`cloudbaking-server`: the GI-map server as its own process.

    cloudbaking-server --host 127.0.0.1 --port 0 --store gi_store [--scenes DIR] [--budget-mb 500]

The socket is bound here, before uvicorn starts, so with ``--port 0`` the real port is known: the
first stdout line is ``listening on http://HOST:PORT`` (flushed), and connections made after it wait
in the listen backlog until the app is ready. Options override ``CLOUDBAKING_*`` environment settings.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from gicore.cli import UserError, entry_point, writable_dir
from gicore.options import SPP, build_config, config_command, extra

app = typer.Typer(add_completion=False, help=__doc__)
#: Largest GI-tree budget, MiB (16 TiB).
BUDGET_MB_MAX = 2.0**24


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (port 0: an ephemeral one); UserError if it cannot bind."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise UserError(
            f"--host {host!r} does not resolve ({exc.strerror})",
            "give an IP address or a resolvable name, e.g. 127.0.0.1",
        ) from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise UserError(
            f"cannot listen on {host}:{port} ({exc.strerror})", "choose another --port (0 picks a free one) or --host"
        ) from None
    sock.listen(2048)
    return sock


#: uvicorn's log levels.
LOG_LEVELS = ("critical", "error", "warning", "info", "debug", "trace")


@dataclass(frozen=True)
class ServeOptions:
    """What the command line sets beside the GI tree: where to listen, and the settings it overrides
    (:class:`~baseline_cloudbaking.server.settings.Settings`; absent: ``CLOUDBAKING_*`` or the default).
    The command's options are derived from these fields (:mod:`gicore.options`)."""

    #: Address to bind; 127.0.0.1 keeps the server local.
    host: str = "127.0.0.1"
    #: TCP port; 0 picks a free one.
    port: int = field(default=8000, metadata={"min": 0, "max": 65535})
    #: GI-tree byte budget in MiB (LRU eviction); absent: none.
    budget_mb: float | None = field(default=None, metadata={"min": 0.001, "max": BUDGET_MB_MAX})
    #: Largest spp a request may ask for; absent: CLOUDBAKING_MAX_SPP or 256.
    max_spp: int | None = field(default=None, metadata=SPP)
    #: uvicorn log level.
    log_level: Literal[LOG_LEVELS] = "warning"  # type: ignore[valid-type]


def serve(given: dict[str, Any], *, store: Path, scenes: Path | None) -> None:
    """Serve GI maps over HTTP from the GI tree in --store."""
    import uvicorn
    from pydantic import ValidationError

    from baseline_cloudbaking.server.app import create_app
    from baseline_cloudbaking.server.settings import Settings

    opts = build_config(ServeOptions, given)
    writable_dir(store, name="--store")
    if scenes is not None and not scenes.is_dir():
        raise UserError(f"--scenes {scenes} is not a folder", "give a folder of scene spec files")
    overrides = {
        "store": store,
        "scenes_dir": scenes,
        "max_spp": opts.max_spp,
        "budget_bytes": None if opts.budget_mb is None else max(1, round(opts.budget_mb * 2**20)),
    }
    try:
        settings = Settings(**{k: v for k, v in overrides.items() if v is not None})
    except ValidationError as exc:
        err = exc.errors()[0]
        field_name = str(err["loc"][0])
        where = ".".join(map(str, err["loc"]))
        option = {"store": "--store", "scenes_dir": "--scenes", "budget_bytes": "--budget-mb", "max_spp": "--max-spp"}
        env = f"CLOUDBAKING_{field_name.upper()}"
        source = f"{option[field_name]} or {env}" if field_name in option else env
        raise UserError(f"setting {where} (from {source}) is invalid: {err['msg']}", "fix its value") from None
    sock = bind(opts.host, opts.port)
    actual_host, actual_port = sock.getsockname()[:2]
    shown = f"[{actual_host}]" if ":" in actual_host else actual_host
    print(f"listening on http://{shown}:{actual_port}", flush=True)
    config = uvicorn.Config(create_app(settings), log_level=opts.log_level, timeout_graceful_shutdown=5)
    uvicorn.Server(config).run(sockets=[sock])


config_command(
    app,
    ServeOptions,
    serve,
    extras=[
        extra("store", Annotated[Path, typer.Option("--store", help="GI-tree folder (created if missing)")]),
        extra(
            "scenes",
            Annotated[
                Path | None,
                typer.Option("--scenes", help="folder of extra scene specs (*.toml, *.json), served by file stem"),
            ],
            None,
        ),
    ],
)

main = entry_point(app, resume="nothing is lost: the GI tree keeps every finished map")
