"""`cloudbaking-server`: the GI-map server as its own process.

    cloudbaking-server --host 127.0.0.1 --port 0 --store gi_store [--scenes DIR] [--budget-mb 500]

The socket is bound here, before uvicorn starts, so with ``--port 0`` the real port is known: the
first stdout line is ``listening on http://HOST:PORT`` (flushed), and connections made after it wait
in the listen backlog until the app is ready. Options override ``CLOUDBAKING_*`` environment settings.
Under load (:mod:`~baseline_cloudbaking.server.limits`): at most ``--miss-queue`` misses wait (then 503 +
Retry-After), at most ``--max-connections`` connections stay open (the longest-idle one is closed for a
new one), a connection idle for ``--idle-timeout-s`` (or trickling its request head that long) is closed,
and repeated log lines are throttled. SIGTERM and SIGINT (Ctrl-C) stop it alike: no new connection is taken,
the miss being rendered is finished, stored and answered within ``--graceful-timeout-s`` (waiting misses are
answered 503 at once), the GI tree is closed, and the process exits 0 (:mod:`~baseline_cloudbaking.server.stop`).
"""

from __future__ import annotations

import re
import socket
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import typer

from gicore.error_policy import UserError, entry_point, serving, writable_dir
from gicore.options import SPP, build_config, config_command, extra

if TYPE_CHECKING:
    import uvicorn
    from fastapi import FastAPI

    from baseline_cloudbaking.server.settings import Settings

app = typer.Typer(add_completion=False, help=__doc__)
#: Largest GI-tree budget, MiB (16 TiB, the settings' limit).
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
    sock.listen(ACCEPT_BACKLOG)
    return sock


#: Listen backlog, which asyncio also takes as the most connections it accepts in one go: each costs the
#: event loop ~0.2 ms, so a flood accepted 2,048 at a time stalled hits for ~0.5 s per batch; 64 at a time,
#: hits are served between batches and the rest of a flood waits in the kernel.
ACCEPT_BACKLOG = 64
#: uvicorn's event loop: uvloop (libuv) answers hits with less CPU than asyncio's own loop. With 80 misses and 32
#: hit clients each asking every 20 ms on this 2-core machine (``python -m baseline_cloudbaking.server.loadtest
#: --misses 80 --hit-clients 32 --resolution 64 --spp 4``, a fresh server, six runs each in alternating rounds):
#: hit p50 24.8-27.3 ms against 30.1-57.7, p99 48.5-57.7 against 53.9-99.2, and 19-114 % more hits answered in
#: the same time; without misses p99 is the same on both (43.9-54.9 against 46.3-53.7). The tail of
#: test_server_load's gentler load (a hit per client every 100 ms) did not move (77 and 119 ms on either loop).
EVENT_LOOP = "uvloop"
#: GIL switch interval of the server process, s (see serve()).
SWITCH_INTERVAL_S = 0.0005
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
    #: GI-tree byte budget in MiB (LRU eviction); absent: CLOUDBAKING_BUDGET_BYTES or 4 GiB.
    budget_mb: float | None = field(default=None, metadata={"min": 0.001, "max": BUDGET_MB_MAX})
    #: Largest spp a request may ask for; absent: CLOUDBAKING_MAX_SPP or 256.
    max_spp: int | None = field(default=None, metadata=SPP)
    #: Misses that may wait for the renderer (one more: 503 + Retry-After); absent: CLOUDBAKING_MISS_QUEUE or 8.
    miss_queue: int | None = field(default=None, metadata={"min": 0, "max": 10_000})
    #: Open connections kept (beyond: the longest-idle is closed); absent: CLOUDBAKING_MAX_CONNECTIONS or 1024.
    max_connections: int | None = field(default=None, metadata={"min": 8, "max": 1_000_000})
    #: Seconds a connection may stay without a whole request head; absent: CLOUDBAKING_IDLE_TIMEOUT_S or 5.
    idle_timeout_s: float | None = field(default=None, metadata={"min": 0.01, "max": 3600.0})
    #: Seconds the miss being rendered may take to finish once told to stop; absent: CLOUDBAKING_GRACEFUL_TIMEOUT_S
    #: or 30.
    graceful_timeout_s: float | None = field(default=None, metadata={"min": 0.01, "max": 3600.0})
    #: uvicorn log level.
    log_level: Literal[LOG_LEVELS] = "warning"  # type: ignore[valid-type]


#: Settings that an option of the same name (``--miss-queue`` for ``miss_queue``) overrides.
_SAME_NAME = ("max_spp", "miss_queue", "max_connections", "idle_timeout_s", "graceful_timeout_s")


def load_settings(opts: ServeOptions, store: Path, scenes: Path | None) -> Settings:
    """The settings: ``CLOUDBAKING_*`` variables, overridden by the options given; UserError naming the
    option or variable of the first invalid one, or a variable that is no setting."""
    from pydantic import ValidationError
    from pydantic_settings import SettingsError

    from baseline_cloudbaking.server.settings import Settings, check_environment, env_name

    check_environment()
    overrides = {name: getattr(opts, name) for name in _SAME_NAME}
    overrides |= {"store": store, "scenes_dir": scenes}
    overrides["budget_bytes"] = None if opts.budget_mb is None else max(1, round(opts.budget_mb * 2**20))
    try:
        return Settings(**{k: v for k, v in overrides.items() if v is not None})
    except SettingsError as exc:  # a variable of a list setting is not JSON
        match = re.search(r'field "(\w+)"', str(exc))
        name = env_name(match.group(1)) if match else "a CLOUDBAKING_* variable"
        raise UserError(
            f"{name} is not valid JSON", "give a JSON value, e.g. CLOUDBAKING_RESOLUTIONS='[64, 256]'"
        ) from None
    except ValidationError as exc:
        err = exc.errors()[0]
        field_name = str(err["loc"][0])
        where = ".".join(map(str, err["loc"]))
        option = {"store": "--store", "scenes_dir": "--scenes", "budget_bytes": "--budget-mb"}
        option |= {k: "--" + k.replace("_", "-") for k in _SAME_NAME}
        env = env_name(field_name)
        source = f"{option[field_name]} or {env}" if field_name in option else env
        raise UserError(f"setting {where} (from {source}) is invalid: {err['msg']}", "fix its value") from None


def serve(given: dict[str, Any], *, store: str, scenes: Path | None) -> None:
    """Serve GI maps over HTTP from the GI tree in --store."""
    from baseline_cloudbaking.server.stop import StoppingServer
    from baseline_cloudbaking.store import store_folder

    with serving():
        opts = build_config(ServeOptions, given)
        folder = store_folder(store)
        if scenes is not None and not scenes.is_dir():
            raise UserError(f"--scenes {scenes} is not a folder", "give a folder of scene spec files")
        settings = load_settings(opts, folder, scenes)
        writable_dir(settings.store, name="--store")
        app, config = server_config(settings, opts.log_level)
        sock = bind(opts.host, opts.port)
        actual_host, actual_port = sock.getsockname()[:2]
        shown = f"[{actual_host}]" if ":" in actual_host else actual_host
        print(f"listening on http://{shown}:{actual_port}", flush=True)
        # The event loop, the hit threads and the miss thread share the GIL: a thread waiting for it waits up to
        # the switch interval (5 ms by default) while another computes, which a hit would pay several times.
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        StoppingServer(config, app).run(sockets=[sock])


def server_config(settings: Settings, log_level: str) -> tuple[FastAPI, uvicorn.Config]:
    """The app for ``settings`` and uvicorn's configuration of it, held to the connection limits."""
    from baseline_cloudbaking.server.app import create_app
    from baseline_cloudbaking.server.limits import ConnectionLimits, fd_budget, uvicorn_config
    from baseline_cloudbaking.store import GITree

    max_connections, fd_limit = fd_budget(settings.max_connections)
    if max_connections < settings.max_connections:
        print(
            f"cloudbaking-server: max_connections lowered to {max_connections} to fit the file-descriptor limit "
            f"{fd_limit} (raise it with ulimit -n)",
            file=sys.stderr,
            flush=True,
        )
    limits = ConnectionLimits(max_connections, settings.idle_timeout_s, settings.max_header_bytes)
    # opened here, not at the app's startup: a store it cannot use is one error line, not uvicorn's traceback
    app = create_app(settings, GITree(settings.store, settings.budget_bytes, settings.tolerance))
    app.state.connections = limits
    config = uvicorn_config(
        app,
        limits,
        loop=EVENT_LOOP,
        log_level=log_level,
        # after the service's own deadline, which answers a miss still rendering (stop.StoppingServer)
        timeout_graceful_shutdown=settings.graceful_timeout_s + 1,
        backlog=ACCEPT_BACKLOG,
    )
    return app, config


config_command(
    app,
    ServeOptions,
    serve,
    extras=[
        extra("store", Annotated[str, typer.Option("--store", help="GI-tree folder (created if missing)")]),
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
