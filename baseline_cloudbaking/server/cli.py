"""`cloudbaking-server`: the GI-map server as its own process.

    cloudbaking-server --host 127.0.0.1 --port 0 --store gi_store [--scenes DIR] [--budget-mb 500]

The socket is bound here, before uvicorn starts, so with ``--port 0`` the real port is known: the
first stdout line is ``listening on http://HOST:PORT`` (flushed), and connections made after it wait
in the listen backlog until the app is ready. Options override ``CLOUDBAKING_*`` environment settings.
"""

from __future__ import annotations

import socket
from pathlib import Path
from typing import Annotated

import typer

from gicore.cli import UserError, entry_point, writable_dir

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
    sock.listen(2048)
    return sock


@app.command()
def serve(
    store: Annotated[Path, typer.Option(help="GI-tree folder (created if missing)")],
    host: Annotated[str, typer.Option(help="address to bind; 127.0.0.1 keeps the server local")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port; 0 picks a free one")] = 8000,
    scenes: Annotated[
        Path | None, typer.Option(help="folder of extra scene specs (*.toml, *.json), served by file stem")
    ] = None,
    budget_mb: Annotated[
        float | None, typer.Option(min=0.001, help="GI-tree byte budget in MiB (LRU eviction); default: none")
    ] = None,
    max_spp: Annotated[int | None, typer.Option(min=1, max=4096, help="largest spp a request may ask for")] = None,
    log_level: Annotated[str, typer.Option(help="uvicorn log level")] = "warning",
) -> None:
    """Serve GI maps over HTTP from the GI tree in --store."""
    import uvicorn
    from pydantic import ValidationError

    from baseline_cloudbaking.server.app import create_app
    from baseline_cloudbaking.server.settings import Settings

    writable_dir(store, name="--store")
    if scenes is not None and not scenes.is_dir():
        raise UserError(f"--scenes {scenes} is not a folder", "give a folder of scene spec files")
    overrides = {
        "store": store,
        "scenes_dir": scenes,
        "max_spp": max_spp,
        "budget_bytes": None if budget_mb is None else int(budget_mb * 2**20),
    }
    try:
        settings = Settings(**{k: v for k, v in overrides.items() if v is not None})
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(map(str, err["loc"]))
        source = f"--{field.replace('_', '-')} or CLOUDBAKING_{field.upper()}"
        raise UserError(f"setting {field} (from {source}) is invalid: {err['msg']}", "fix its value") from None
    sock = bind(host, port)
    actual_host, actual_port = sock.getsockname()[:2]
    shown = f"[{actual_host}]" if ":" in actual_host else actual_host
    print(f"listening on http://{shown}:{actual_port}", flush=True)
    server = uvicorn.Server(uvicorn.Config(create_app(settings), log_level=log_level, timeout_graceful_shutdown=5))
    server.run(sockets=[sock])


main = entry_point(app, resume="nothing is lost: the GI tree keeps every finished map")
