"""gigan-web's server against malformed and hostile HTTP, on raw sockets: an HTTP/0.9 request line, a NUL in
the path, a 256-character path segment, ``Content-Length: abc``, Content-Length beside chunked, a chunked body,
a GET with a body, a second request hidden in a refused POST's body (desync), a head that never ends, and a
traceback for none of them (the server's log is read: the ``tracebacks`` fixture of conftest.py); the errors that
uvicorn, the connection limits and Starlette's error handler write carry the headers every response does."""

from __future__ import annotations

import re
import socket
import time
from collections.abc import Iterator

import pytest

from web3d.serve import HEADERS, WebServer
from web3d.site import Site, WebSettings
from web3d.upstreams import Fixed

HANG_GUARD_S = 60.0
SETTINGS = WebSettings(idle_timeout_s=0.5, body_timeout_s=1.0)
HOST = b"Host: 127.0.0.1\r\n"


@pytest.fixture(scope="module")
def web(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebServer]:
    assets = tmp_path_factory.mktemp("assets")
    (assets / "scene.json").write_text("{}")
    with WebServer(Site(assets, {"scene": "s"}, settings=SETTINGS)) as server:
        yield server


def exchange(web: WebServer, data: bytes) -> bytes:
    """Send ``data`` on a fresh connection and read until the server closes it (hang guard: 60 s)."""
    with socket.create_connection(web.socket.getsockname()[:2], timeout=HANG_GUARD_S) as sock:
        sock.sendall(data)
        answer = b""
        while chunk := sock.recv(65536):
            answer += chunk
        return answer


def statuses(answer: bytes) -> list[int]:
    """The status of each response in ``answer`` (a response's body may run into the next status line)."""
    return [int(code) for code in re.findall(rb"HTTP/1\.1 (\d{3}) ", answer)]


@pytest.mark.parametrize(
    "request_bytes,expected",
    [
        (b"GET /\r\n\r\n", [400]),  # HTTP/0.9: no version, no Host
        (b"GET /a\x00b HTTP/1.1\r\n" + HOST + b"\r\n", [400]),
        (b"GET /a%00b HTTP/1.1\r\n" + HOST + b"Connection: close\r\n\r\n", [404]),
        (b"GET /js/" + b"a" * 256 + b".js HTTP/1.1\r\n" + HOST + b"Connection: close\r\n\r\n", [404]),
        (b"GET /assets/" + b"a" * 256 + b" HTTP/1.1\r\n" + HOST + b"Connection: close\r\n\r\n", [404]),
        (
            b"POST /v1/gimap HTTP/1.1\r\n" + HOST + b"Content-Type: application/json\r\nContent-Length: abc\r\n\r\n{}",
            [400],
        ),
        (b"POST /v1/gimap HTTP/1.1\r\n" + HOST + b"Content-Length: -1\r\n\r\n", [400]),
        (b"GET / HTTP/1.1\r\n" + HOST + b"Content-Length: 1\r\nContent-Length: 2\r\n\r\nab", [400]),
        (b"GET / HTTP/9.9\r\n" + HOST + b"\r\n", [400]),
        (b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + bytes(32), [400]),  # a TLS hello
    ],
)
def test_malformed_requests_are_400_or_404_and_closed(web: WebServer, tracebacks, request_bytes, expected) -> None:
    assert statuses(exchange(web, request_bytes)) == expected


def test_content_length_beside_chunked_smuggles_nothing(web: WebServer, tracebacks) -> None:
    smuggled = b"GET /assets/scene.json HTTP/1.1\r\n" + HOST + b"\r\n"
    head = b"POST /v1/gimap HTTP/1.1\r\n" + HOST + b"Content-Type: application/json\r\n"
    answer = exchange(web, head + b"Content-Length: 4\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n" + smuggled)
    assert statuses(answer) == [400]


def test_a_chunked_body_is_read_whole(web: WebServer, tracebacks) -> None:
    head = b"POST /v1/gimap HTTP/1.1\r\n" + HOST + b"Content-Type: application/json\r\nConnection: close\r\n"
    answer = exchange(web, head + b"Transfer-Encoding: chunked\r\n\r\n1\r\n{\r\n1\r\n}\r\n0\r\n\r\n")
    assert statuses(answer) == [503]  # read, then refused: the cloud side is off here


def test_a_get_with_a_body_is_answered_and_the_next_request_too(web: WebServer, tracebacks) -> None:
    first = b"GET /config.json HTTP/1.1\r\n" + HOST + b"Content-Length: 5\r\n\r\nhello"
    second = b"GET /assets/scene.json HTTP/1.1\r\n" + HOST + b"Connection: close\r\n\r\n"
    answer = exchange(web, first + second)
    assert statuses(answer) == [200, 200] and answer.endswith(b"{}")


def test_a_refused_post_does_not_answer_the_request_in_its_body(web: WebServer, tracebacks) -> None:
    """The body of a POST the server refuses (404, 405, 503) without reading it is still that POST's body: the
    request hidden in it is never answered, whatever comes after."""
    hidden = b"GET /assets/scene.json HTTP/1.1\r\n" + HOST + b"\r\n"
    for path in (b"/nothing", b"/js/main.js", b"/v1/gimap"):
        head = b"POST " + path + b" HTTP/1.1\r\n" + HOST + b"Content-Type: application/json\r\n"
        answer = exchange(web, head + b"Content-Length: %d\r\n\r\n" % len(hidden) + hidden)
        assert len(statuses(answer)) == 1 and statuses(answer)[0] in (404, 405, 503), answer
        assert not answer.endswith(b"{}"), answer


def test_a_head_that_never_ends_is_closed(web: WebServer, tracebacks) -> None:
    """A request head trickled and never finished, or a connection that sends nothing, is closed after the idle
    timeout (exchange reads until the server closes; the hang guard is far above it)."""
    assert exchange(web, b"GET / HTTP/1.1\r\nHost: 127") == b""
    assert exchange(web, b"") == b""


def test_a_head_too_large_is_431(web: WebServer, tracebacks) -> None:
    huge = b"GET / HTTP/1.1\r\n" + HOST + b"X-Big: " + b"a" * (SETTINGS.max_head_bytes + 1) + b"\r\n\r\n"
    assert statuses(exchange(web, huge)) == [431]


def head_lines(answer: bytes) -> set[str]:
    """The header lines of the first response in ``answer``, lower-cased."""
    return {line.decode().lower() for line in answer.partition(b"\r\n\r\n")[0].split(b"\r\n")[1:]}


EVERY_RESPONSE = {f"{name}: {value}".lower() for name, value in HEADERS}


def test_errors_written_outside_the_app_carry_every_responses_headers(web: WebServer, tracebacks) -> None:
    huge = b"GET / HTTP/1.1\r\n" + HOST + b"X-Big: " + b"a" * (SETTINGS.max_head_bytes + 1) + b"\r\n\r\n"
    for request, status in [(b"GET /\r\n\r\n", 400), (huge, 431), (b"GET / HTTP/1.1\r\nHost: evil\r\n\r\n", 400)]:
        answer = exchange(web, request)
        assert statuses(answer) == [status] and EVERY_RESPONSE <= head_lines(answer), answer


def test_a_refusal_at_the_connection_limit_carries_them(tmp_path) -> None:
    settings = WebSettings(max_connections=1, body_timeout_s=HANG_GUARD_S)
    with WebServer(Site(tmp_path, {}, Fixed.direct("http://127.0.0.1:1"), settings=settings)) as server:
        address = server.socket.getsockname()[:2]
        with socket.create_connection(address, timeout=HANG_GUARD_S) as busy:  # a body still to come: busy
            busy.sendall(
                b"POST /v1/gimap HTTP/1.1\r\n" + HOST + b"Content-Type: application/json\r\nContent-Length: 9\r\n\r\n"
            )
            answer = exchange(server, b"")  # refused as it connects (sending would reset the connection)
    assert statuses(answer) == [503] and EVERY_RESPONSE <= head_lines(answer), answer


class Failing(Fixed):
    def status(self) -> dict[str, dict[str, str]]:
        raise RuntimeError("a bug")


def test_a_500_carries_them(tmp_path) -> None:
    with WebServer(Site(tmp_path, {}, Failing.direct("http://127.0.0.1:1"))) as server:
        answer = exchange(server, b"GET /v1/status HTTP/1.1\r\n" + HOST + b"Connection: close\r\n\r\n")
    assert statuses(answer) == [500] and EVERY_RESPONSE <= head_lines(answer), answer


def test_a_reader_that_stalls_is_dropped_and_frees_its_slot(tmp_path) -> None:
    """A client with a 4 KiB receive buffer asks for a 64 MiB file and takes nothing: once the socket buffers are
    full, it has write_timeout_s to take some, then its connection is dropped; with one slot, the next client is
    refused until then and served after."""
    size = 64 << 20  # more than the socket buffers between the two hold
    (tmp_path / "scene.bin").write_bytes(bytes(size))
    settings = WebSettings(max_connections=1, write_timeout_s=0.5)
    with WebServer(Site(tmp_path, {}, settings=settings)) as server:
        with socket.socket() as slow:
            slow.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            slow.settimeout(HANG_GUARD_S)
            slow.connect(server.socket.getsockname()[:2])
            slow.sendall(b"GET /assets/scene.bin HTTP/1.1\r\n" + HOST + b"\r\n")
            deadline = time.monotonic() + HANG_GUARD_S  # a hang guard only
            while (answer := refused_or(server, b"GET /config.json HTTP/1.1\r\n" + HOST + b"\r\n")) is None:
                assert time.monotonic() < deadline, "the stalled reader still holds the one slot"
                time.sleep(0.1)
            assert statuses(answer) == [200], answer
            received = 0
            try:
                while chunk := slow.recv(1 << 20):
                    received += len(chunk)
            except ConnectionResetError:  # dropped: aborted, not closed
                pass
    assert 0 < received < size


def refused_or(web: WebServer, request: bytes) -> bytes | None:
    """The answer to ``request`` (closing the connection), or None when the server refused the connection at its
    limit (503, or a reset: the server closed it with the request unread)."""
    try:
        answer = exchange(web, request.replace(b"\r\n\r\n", b"\r\nConnection: close\r\n\r\n"))
    except ConnectionResetError:
        return None
    return None if answer.startswith(b"HTTP/1.1 503 ") else answer
