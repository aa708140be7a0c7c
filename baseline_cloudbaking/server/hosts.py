"""The ``Host`` check against DNS rebinding, for ``cloudbaking-server`` and ``gigan-web``.

A page from another site can make the browser send requests to a server on this machine by having its own name
resolve to 127.0.0.1 (DNS rebinding); the request then names that site in ``Host``. :class:`HostCheck` answers
400 to a request whose ``Host`` names no address or name of this server (:func:`allowed_hosts`), or, where the
server knows the port the browser reaches (gigan-web), another port, and to one with no ``Host`` or two. A
bracketed IPv6 address (``[::1]:8080``) is a name like any other.
"""

from __future__ import annotations

import ipaddress
import re
import socket
from collections.abc import Collection

from starlette.datastructures import Headers
from starlette.responses import PlainTextResponse
from starlette.types import ASGIApp, Receive, Scope, Send

#: Names any loopback server answers to, besides the one it listens on.
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
#: ``Host``: a name or IPv4 address, or an IPv6 address in brackets; then an optional port.
_HOST = re.compile(r"(?:\[(?P<ipv6>[0-9A-Fa-f:.]+)\]|(?P<name>[^\s:\[\]/@]+))(?::(?P<port>\d{1,5}))?")


def parse_host(value: str) -> tuple[str, int | None] | None:
    """``Host``'s name (lower case, an IPv6 address without its brackets) and port (None: not given); None when
    it is malformed."""
    match = _HOST.fullmatch(value)
    if match is None:
        return None
    port = int(match["port"]) if match["port"] else None
    if match["ipv6"] is None:
        return match["name"].lower(), port
    try:
        return str(ipaddress.IPv6Address(match["ipv6"])), port  # its shortest form, as the bound address is named
    except ValueError:
        return None


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a bind address or name) reaches this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def allowed_hosts(host: str, sock: socket.socket) -> list[str]:
    """The ``Host`` names a server listening on ``host`` (bound as ``sock``) answers: that name, the address
    bound, loopback's; and this machine's names and addresses when it listens on every interface."""
    names = {host.strip("[]").lower(), sock.getsockname()[0], *LOOPBACK_HOSTS}
    if host in ("0.0.0.0", "::", ""):
        names |= {socket.gethostname(), socket.getfqdn()}
        names |= {str(info[4][0]) for info in socket.getaddrinfo(socket.gethostname(), None)}
    return sorted(name.lower() for name in names)


class HostCheck:
    """ASGI middleware: a request whose ``Host`` is not among ``names`` (lower case), or names a port other than
    ``port`` (None: any port, for a server reached through proxies on other ports), is refused 400."""

    def __init__(self, app: ASGIApp, names: Collection[str], port: int | None = None) -> None:
        self.app = app
        self.names = frozenset(names)
        self.port = port

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            given = Headers(scope=scope).getlist("host")
            host = parse_host(given[0]) if len(given) == 1 else None  # two: HTTP/1.1 says 400, not which to trust
            wrong_port = self.port is not None and host is not None and host[1] not in (None, self.port)
            if host is None or host[0] not in self.names or wrong_port:
                msg = f"Host {', '.join(given)!r} does not name this server: open it by its address"
                await PlainTextResponse(msg, status_code=400)(scope, receive, send)
                return
        await self.app(scope, receive, send)
