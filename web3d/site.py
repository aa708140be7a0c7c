"""What ``gigan-web``'s server serves (:class:`Site`) and its limits (:class:`WebSettings`), declared once."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from web3d.routes_shadow import Shadows
from web3d.upstreams import OFF, Cloud

#: The page's folder (``web3d/static/`` at the repository root).
WEB_DIR = Path(__file__).resolve().parent / "static"


@dataclass(frozen=True)
class WebSettings:
    """The server's limits, declared once."""

    #: Largest ``/v1/gimap`` body forwarded (counted as it arrives; the cloud server takes 4 KiB).
    max_body_bytes: int = 1 << 16
    #: Seconds a request body may take to arrive.
    body_timeout_s: float = 10.0
    #: Seconds to connect to the upstream (a child proxy on this machine).
    connect_timeout_s: float = 10.0
    #: Seconds a forwarded request may take: a miss path-traces, and a cold server compiles its scene first.
    read_timeout_s: float = 600.0
    #: Seconds a response may wait for the browser to take any of it; a reader that stalls is dropped, which
    #: frees its connection slot.
    write_timeout_s: float = 30.0
    #: Seconds a connection may stay without a whole request head (fresh, or kept alive after a response).
    idle_timeout_s: float = 5.0
    #: Open connections kept (a browser opens about six per origin).
    max_connections: int = 256
    #: Largest request head (request line and headers), bytes.
    max_head_bytes: int = 16_384
    #: Seconds requests in flight may take to finish once the server is told to stop.
    graceful_timeout_s: float = 5.0


@dataclass(frozen=True)
class Site:
    """What the server serves: the exported ``assets`` folder, the page's settings (``config``; ``/config.json``
    adds the profiles and stores of ``cloud``), where ``/v1/gimap`` goes (``cloud``) and the scene's shadow-map
    setups (``shadows``; None: ``/v1/shadow`` answers 404)."""

    assets: Path
    config: dict[str, Any]
    cloud: Cloud = OFF
    shadows: Shadows | None = None
    web: Path = WEB_DIR
    settings: WebSettings = field(default_factory=WebSettings)
