"""`cloudbaking-server`: the GI-map server as its own process.

    cloudbaking-server --host 127.0.0.1 --port 0 --store gi_store [--scenes DIR] [--budget-mb 500]

The socket is bound here, before uvicorn starts, so with ``--port 0`` the real port is known: the
first stdout line is ``listening on http://HOST:PORT`` (flushed), and connections made after it wait
in the listen backlog until the app is ready. Every setting (:class:`~baseline_cloudbaking.server.settings.Settings`)
is an option, which overrides its ``CLOUDBAKING_*`` variable; ``--help`` names each one's variable.
Under load (:mod:`~baseline_cloudbaking.server.limits`): at most ``--miss-queue`` misses wait (then 503 + Retry-
After), at most ``--max-connections`` connections stay open (the longest-idle one is closed for a new one), a
connection idle for ``--idle-timeout-s`` (or trickling its request head that long) is closed, and repeated log lines
are throttled. On loopback (the default), a request whose ``Host`` names another server is refused 400 (DNS
rebinding; ``--allowed-hosts`` adds names). SIGTERM and SIGINT (Ctrl-C) stop it alike: no new connection is taken,
the miss being rendered is finished, stored and answered within ``--graceful-timeout-s`` (waiting misses are
answered 503 at once), the GI tree is closed, and the process exits 0 (:mod:`~baseline_cloudbaking.server.stop`).
"""

from __future__ import annotations

import dataclasses
import re
import socket
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import typer
from pydantic import ValidationError
from pydantic_settings import SettingsError

from baseline_cloudbaking.server.settings import Settings, check_environment, env_name, given_settings, setting_options
from gicore.error_policy import UserError, entry_point, writable_dir
from gicore.options import build_config, config_command, option_name

if TYPE_CHECKING:
    import uvicorn
    from fastapi import FastAPI

app = typer.Typer(add_completion=False, help=__doc__)


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
    """What the command line sets beside the settings: where to listen, and uvicorn's log level."""

    #: Address to bind; 127.0.0.1 keeps the server local.
    host: str = "127.0.0.1"
    #: TCP port; 0 picks a free one.
    port: int = field(default=8000, metadata={"min": 0, "max": 65535})
    #: uvicorn log level.
    log_level: Literal[LOG_LEVELS] = "warning"  # type: ignore[valid-type]


#: The command's options: :class:`ServeOptions`, then one per setting (absent: ``CLOUDBAKING_*`` or the default).
CommandOptions = setting_options(ServeOptions)


def load_settings(opts: Any) -> Settings:
    """The settings: ``CLOUDBAKING_*`` variables, overridden by the options given (``opts``, a
    :data:`CommandOptions`); UserError naming the option or variable of the first invalid one, or a variable
    that is no setting."""
    check_environment()
    try:
        return Settings(**given_settings(opts))
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
        option = {f.metadata.get("setting"): option_name(f) for f in dataclasses.fields(CommandOptions)}
        source = " or ".join(filter(None, (option.get(field_name), env_name(field_name))))
        raise UserError(f"setting {where} (from {source}) is invalid: {err['msg']}", "fix its value") from None


def serve(given: dict[str, Any]) -> None:
    """Serve GI maps over HTTP from the GI tree in --store."""
    from baseline_cloudbaking.server.stop import StoppingServer

    opts = build_config(CommandOptions, given)
    if opts.scenes is not None and not opts.scenes.is_dir():
        raise UserError(f"--scenes {opts.scenes} is not a folder", "give a folder of scene spec files")
    for line in skipped_specs(opts.scenes) if opts.scenes is not None else ():
        print(line, file=sys.stderr, flush=True)
    settings = load_settings(opts)
    writable_dir(settings.store, name="--store")
    app, config = server_config(settings, opts.log_level)
    sock = bind(opts.host, opts.port)
    guard_hosts(app, settings.allowed_hosts, opts.host, sock)
    actual_host, actual_port = sock.getsockname()[:2]
    shown = f"[{actual_host}]" if ":" in actual_host else actual_host
    print(f"listening on http://{shown}:{actual_port}", flush=True)
    # The event loop, the hit threads and the miss thread share the GIL: a thread waiting for it waits up to
    # the switch interval (5 ms by default) while another computes, which a hit would pay several times.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    StoppingServer(config, app).run(sockets=[sock])


def guard_hosts(app: FastAPI, extra: tuple[str, ...], host: str, sock: socket.socket) -> None:
    """Refuse 400 a request whose ``Host`` names neither this server nor one of ``extra``
    (:mod:`~baseline_cloudbaking.server.hosts`; any port: clients reach it through proxies), where it listens on
    loopback (``host``, bound as ``sock``), which a page elsewhere reaches by DNS rebinding, or where ``extra``
    names some; '*' among them answers any ``Host``."""
    from baseline_cloudbaking.server.hosts import HostCheck, allowed_hosts, is_loopback

    if "*" not in extra and (is_loopback(host) or extra):
        app.add_middleware(HostCheck, names=[*allowed_hosts(host, sock), *extra])


def skipped_specs(scenes: Path) -> list[str]:
    """One line for each spec file (``.toml``, ``.json``) in ``scenes`` that the server will not serve, and why:
    a request for it is refused, and a person who added it should hear so when the server starts."""
    from baseline_cloudbaking.bake import SCENE_NAME, SPEC_SUFFIXES
    from gicore.scene import SceneSpecError, load_scene

    lines = []
    for path in sorted(scenes.iterdir()):
        if path.suffix not in SPEC_SUFFIXES:
            continue
        if not SCENE_NAME.match(path.stem):
            why = "its name is no scene name (a letter or '_', then letters, digits or '_'; at most 64)"
        else:
            try:
                load_scene(path)
                continue
            except (SceneSpecError, OSError) as err:
                why = " ".join(str(err).split())[:300]
        lines.append(f"cloudbaking-server: --scenes: skipped {path.name}: {why}")
    return lines


def server_config(settings: Settings, log_level: str) -> tuple[FastAPI, uvicorn.Config]:
    """The app for ``settings`` and uvicorn's configuration of it, held to the connection limits."""
    from baseline_cloudbaking.server.app import create_app
    from baseline_cloudbaking.server.limits import FD_RESERVE, ConnectionLimits, uvicorn_config
    from baseline_cloudbaking.store import GITree
    from gicore.fd_budget import connection_budget

    max_connections, _ = connection_budget(
        settings.max_connections, FD_RESERVE, who="cloudbaking-server: max_connections"
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


config_command(app, CommandOptions, serve)

main = entry_point(app, services=True)
