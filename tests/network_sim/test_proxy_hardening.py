"""The proxy against a hostile or careless user: idle sockets give their slots back, trace files are read
bounded and as text, an unwritable log and absurd flag values are one error line, floods leave it serving."""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Iterator

import pytest

from network_sim import endpoint
from network_sim.process import Running, network_sim

TIMEOUT = 60.0


@pytest.fixture(scope="module")
def server() -> Iterator[Running]:
    with network_sim("server") as running:
        yield running


def proxy(server: Running, *args: str) -> Running:
    host, port = server.addr
    running = network_sim("proxy", "--upstream", f"{host}:{port}", *args)
    running.readline(10.0)  # the clock-origin line
    return running


def echoes(addr: tuple[str, int], payload: bytes = b"ping") -> bool:
    """Whether a fresh connection through the proxy echoes ``payload`` (False: it was closed, i.e. refused)."""
    with endpoint.connect(addr, b"E", TIMEOUT) as sock:
        try:
            sock.sendall(payload)
            return endpoint.recv_exactly(sock, len(payload)) == payload
        except ConnectionError:  # closed before the echo: refused at the cap
            return False


def wait_closed(sock: socket.socket) -> None:
    """Wait until the peer closes ``sock`` (EOF or a reset); a socket left open fails on the timeout."""
    sock.settimeout(TIMEOUT)
    try:
        while sock.recv(4096):
            pass
    except ConnectionResetError:
        pass


def test_idle_sockets_give_their_slots_back(server: Running) -> None:
    """Sockets held open without a byte, both legs open or the upstream gone, fill the cap only until the
    idle timeout: then both legs are closed and new clients get through."""
    with proxy(server, "--max-connections", "4", "--idle-timeout-s", "1") as p:
        both_open = [endpoint.connect(p.addr, b"E", TIMEOUT) for _ in range(2)]
        upstream_gone = [endpoint.connect(p.addr, b"G", TIMEOUT) for _ in range(2)]
        for sock in upstream_gone:  # the source sends nothing and closes: the client keeps its socket
            sock.sendall(endpoint.SOURCE_REQUEST.pack(0, 0))
            assert sock.recv(10) == b""
        for sock in both_open:
            sock.sendall(b"x")
            assert endpoint.recv_exactly(sock, 1) == b"x"
        assert not echoes(p.addr), "a fifth connection got through a cap of 4"
        for sock in both_open:
            wait_closed(sock)
        deadline = time.monotonic() + TIMEOUT
        while not echoes(p.addr):  # the half-closed ones go at the same check, or the next
            assert time.monotonic() < deadline, "the idle connections kept their slots"
            time.sleep(0.2)
        assert all(echoes(p.addr) for _ in range(3))
        for sock in both_open + upstream_gone:
            sock.close()


def test_a_connection_that_moves_bytes_or_has_bytes_due_is_not_idle(server: Running) -> None:
    """Echoes every 50 ms for 2.5 idle timeouts, and a round trip whose delay is 3 idle timeouts long,
    both come through whole."""
    with proxy(server, "--idle-timeout-s", "2") as p:
        with endpoint.connect(p.addr, b"E", TIMEOUT) as sock:
            end = time.monotonic() + 5.0
            while time.monotonic() < end:
                sock.sendall(b"k")
                assert endpoint.recv_exactly(sock, 1) == b"k"
                time.sleep(0.05)
    with proxy(server, "--idle-timeout-s", "0.5", "--delay-ms", "1500") as p:
        assert echoes(p.addr, struct.pack("!Q", 7))
