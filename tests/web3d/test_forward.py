"""gigan-web's POST /v1/gimap: forwarded body and content type unchanged to the chosen profile's server for the
chosen store, the upstream's status, bytes, content type, X-GIMap-Hit and Content-Location (no other upstream
header) back with X-Profile and X-Store;
refused before forwarding with 415 (not JSON), 413 (too large as it arrives, whatever Content-Length says), 408
(too slow), 422 (unknown profile or store), 503 (no server); 502 when the upstream fails, 504 when it is too
slow. The upstreams here are small servers that answer what they were sent (the forwarding is under test; the
end-to-end run with a real cloudbaking-server behind a real proxy is in test_children.py)."""

from __future__ import annotations

import asyncio
import json
import select
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest
import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

import web3d.upstreams
from tests.web3d.test_stop import silent_upstream
from web3d.serve import WebServer, create_app
from web3d.site import Site, WebSettings
from web3d.upstreams import Fixed

HANG_GUARD_S = 60.0


def upstream_app(name: str, scripted: bool) -> Starlette:
    """A stand-in for a cloud-baking server: answers what it was sent, tagged with its name; when ``scripted``,
    a body's ``status`` and ``media`` set the answer's status and content type, ``sleep`` delays it."""

    async def gimap(request: Request) -> Response:
        body = await request.body()
        ask = json.loads(body) if scripted else {}
        await asyncio.sleep(float(ask.get("sleep", 0)))
        seen = {
            "upstream": name,
            "body": body.decode(errors="replace"),
            "content_type": request.headers["content-type"],
        }
        headers = {"X-GIMap-Hit": "1", "Content-Location": f"/v1/maps/{name}", "X-Other": "not passed"}
        headers["Content-Type"] = ask.get("media", "application/x-gimap")
        return Response(json.dumps(seen).encode(), status_code=int(ask.get("status", 200)), headers=headers)

    async def health(_: Request) -> Response:
        return Response(b"{}", media_type="application/json")

    return Starlette(routes=[Route("/v1/gimap", gimap, methods=["POST"]), Route("/v1/health", health)])


@contextmanager
def upstream(name: str, scripted: bool = True) -> Iterator[str]:
    """``upstream_app(name, scripted)`` served on a free loopback port; yields its URL."""
    sock = socket.create_server(("127.0.0.1", 0))
    app = upstream_app(name, scripted)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", timeout_graceful_shutdown=1))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    while not server.started:
        thread.join(0.01)
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        server.should_exit = True
        thread.join(HANG_GUARD_S)
        sock.close()


def closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


SETTINGS = WebSettings(body_timeout_s=1.0, read_timeout_s=1.0)


@pytest.fixture(scope="module")
def cloud() -> Iterator[Fixed]:
    """Profiles lan and wan in front of a given store, lan in front of a cold one; wan of the cold store has
    nothing listening."""
    with upstream("given-lan") as a, upstream("given-wan") as b, upstream("cold-lan") as c:
        dead = f"http://127.0.0.1:{closed_port()}"
        yield Fixed({("given", "lan"): a, ("given", "wan"): b, ("cold", "lan"): c, ("cold", "wan"): dead})


@pytest.fixture(scope="module")
def web(cloud: Fixed, tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebServer]:
    site = Site(tmp_path_factory.mktemp("assets"), {"scene": "s"}, cloud, settings=SETTINGS)
    with WebServer(site) as server:
        yield server


def post(web: WebServer, query: str = "", body: bytes = b'{"scene": "s"}', **headers: str) -> httpx.Response:
    headers = {"Content-Type": "application/json"} | headers
    return httpx.post(f"{web.url}/v1/gimap{query}", content=body, headers=headers, timeout=HANG_GUARD_S)


def test_the_chosen_profile_and_store_reach_their_server_unchanged(web: WebServer) -> None:
    body = b'{"scene": "s", "camera": {"eye": [1, 2, 3]}}'
    for query, (profile, store) in [
        ("", ("lan", "given")),
        ("?profile=wan", ("wan", "given")),
        ("?store=cold", ("lan", "cold")),
        ("?profile=lan&store=cold", ("lan", "cold")),
    ]:
        r = post(web, query, body, **{"Content-Type": "application/json; charset=utf-8"})
        assert r.status_code == 200, (query, r.text)
        assert (r.headers["x-profile"], r.headers["x-store"], r.headers["x-gimap-hit"]) == (profile, store, "1")
        assert r.headers["content-type"] == "application/x-gimap" and "x-other" not in r.headers
        assert r.headers["content-location"] == f"/v1/maps/{store}-{profile}"  # the stored map's address
        seen = r.json()
        assert seen == {
            "upstream": f"{store}-{profile}",
            "body": body.decode(),
            "content_type": "application/json; charset=utf-8",
        }
    config = httpx.get(f"{web.url}/config.json").json()
    assert (config["profiles"], config["profile"], config["stores"], config["store"]) == (
        ["lan", "wan"],
        "lan",
        ["given", "cold"],
        "given",
    )


def test_the_upstreams_errors_come_back_as_they_are(web: WebServer) -> None:
    for status in (409, 422, 503, 507):
        body = json.dumps({"status": status, "media": "application/json"}).encode()
        r = post(web, "", body)
        assert r.status_code == status and r.headers["content-type"] == "application/json"
        assert r.json()["body"] == body.decode() and r.headers["x-profile"] == "lan"


def test_unknown_profile_or_store_is_422_and_an_upstream_down_502(web: WebServer) -> None:
    for query in ("?profile=lte", "?store=warm", "?profile=", "?profile=lan&store=given%00"):
        r = post(web, query)
        assert r.status_code == 422 and isinstance(r.json()["detail"], str), query
    down = post(web, "?profile=wan&store=cold")
    assert down.status_code == 502 and "x-profile" not in down.headers
    assert isinstance(down.json()["detail"], str)


def test_a_slow_upstream_is_504(web: WebServer) -> None:
    r = post(web, "", json.dumps({"sleep": 2 * SETTINGS.read_timeout_s}).encode())
    assert r.status_code == 504


def test_the_body_must_be_json(web: WebServer) -> None:
    for media in ("text/plain", "application/x-www-form-urlencoded", "application/jsonx", ""):
        r = post(web, "", b"{}", **{"Content-Type": media})
        assert r.status_code == 415, media
    headers = {"Content-Type": "application/json"}
    assert httpx.post(f"{web.url}/v1/gimap", content=b"{}", headers=headers | {"Content-Type": ""}).status_code == 415


def test_a_content_type_that_is_not_ascii_is_415(web: WebServer, tracebacks) -> None:
    """A byte past ASCII in a JSON Content-Type (forwarded as it came, which no HTTP client sends) is refused
    before forwarding, with no traceback logged."""
    for media in (b"application/json; charset=\xe9", b"application/json;\x80"):
        with socket.create_connection(web.socket.getsockname()[:2], timeout=HANG_GUARD_S) as sock:
            head = b"POST /v1/gimap HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\nContent-Length: 2\r\n"
            sock.sendall(head + b"Content-Type: " + media + b"\r\n\r\n{}")
            answer = b"".join(iter(lambda: sock.recv(65536), b""))
        assert answer.startswith(b"HTTP/1.1 415 ") and b"ASCII" in answer, answer


def test_a_body_over_the_limit_is_413_as_it_arrives(web: WebServer) -> None:
    limit = SETTINGS.max_body_bytes
    assert post(web, "", b" " * (limit + 1)).status_code == 413

    def chunks() -> Iterator[bytes]:  # chunked: no Content-Length to trust
        for _ in range(4):
            yield b" " * (limit // 2)

    r = httpx.post(f"{web.url}/v1/gimap", content=chunks(), headers={"Content-Type": "application/json"})
    assert r.status_code == 413
    # a Content-Length of 1 MiB with only 80 KiB sent: refused once the limit is passed, not after the rest
    with socket.create_connection(web.socket.getsockname()[:2], timeout=HANG_GUARD_S) as sock:
        head = "POST /v1/gimap HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
        sock.sendall(f"{head}Content-Length: {1 << 20}\r\n\r\n".encode() + b" " * (limit + (16 << 10)))
        assert sock.recv(4096).startswith(b"HTTP/1.1 413 ")


def test_a_body_that_does_not_arrive_in_time_is_408(web: WebServer) -> None:
    with socket.create_connection(web.socket.getsockname()[:2], timeout=HANG_GUARD_S) as sock:
        head = "POST /v1/gimap HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
        sock.sendall(f"{head}Content-Length: 100\r\n\r\n{{".encode())
        answer = sock.recv(4096)
        assert answer.startswith(b"HTTP/1.1 408 "), answer
        assert sock.recv(4096) == b""  # and the connection is closed


def test_no_server_for_a_pair_is_503(tmp_path: Path) -> None:
    with upstream("given-lan") as url:
        site = Site(tmp_path, {}, Fixed({("given", "lan"): url, ("cold", "wan"): url}), settings=SETTINGS)
        with WebServer(site) as web:
            r = post(web, "?profile=wan")
            assert r.status_code == 503 and isinstance(r.json()["detail"], str)
            status = httpx.get(f"{web.url}/v1/status").json()
            assert status == {
                "profiles": {"lan": "up", "wan": "up"},
                "stores": {"given": "up", "cold": "up"},
                "scene": None,
            }
    dead = Site(tmp_path, {}, Fixed.direct(f"http://127.0.0.1:{closed_port()}"), settings=SETTINGS)
    with WebServer(dead) as web:
        status = httpx.get(f"{web.url}/v1/status").json()
        assert status["profiles"] == {"direct": "down"} and status["stores"] == {"given": "down"}
        assert post(web).status_code == 502


def test_a_status_flood_with_a_silent_server_shares_one_probe_and_leaves_the_files_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Sixty /v1/status requests while --server takes connections and never answers: one probe serves them all,
    and a file asked for after them comes while they still wait (before, each probe held a worker)."""
    monkeypatch.setattr(web3d.upstreams, "PROBE_TIMEOUT_S", HANG_GUARD_S)  # ends when the server closes
    (tmp_path / "scene.json").write_text("{}")
    with silent_upstream() as silent, WebServer(Site(tmp_path, {}, Fixed.direct(silent.url))) as web:
        flood = [socket.create_connection(web.socket.getsockname()[:2], timeout=HANG_GUARD_S) for _ in range(60)]
        for sock in flood:
            sock.sendall(b"GET /v1/status HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
        assert silent.arrived.wait(HANG_GUARD_S), "no probe reached the server"
        assert httpx.get(f"{web.url}/assets/scene.json", timeout=HANG_GUARD_S).content == b"{}"
        assert select.select(flood, [], [], 0)[0] == [], "a status was answered before the file"
        assert len(silent.held) == 1
        silent.held[0].close()  # the probe ends: the server is down
        answers = [b"".join(iter(lambda sock=sock: sock.recv(65536), b"")) for sock in flood]
    for sock in flood:
        sock.close()
    assert all(a.startswith(b"HTTP/1.1 200 ") and b'"direct":"down"' in a for a in answers), answers[0]


schemathesis = pytest.importorskip("schemathesis")
hypothesis = pytest.importorskip("hypothesis")


def _schema() -> dict:
    """The app's OpenAPI document, its profile and store each one served and one unknown name, so that the
    fuzz reaches the upstream as well as the refusals."""
    doc = create_app(Site(Path("."), {}, Fixed.direct("http://127.0.0.1"))).openapi()
    for param in doc["paths"]["/v1/gimap"]["post"]["parameters"]:
        param["schema"] = {"enum": {"profile": ["direct", "lte"], "store": ["given", "cold"]}[param["name"]]}
    return doc


SCHEMA = schemathesis.openapi.from_dict(_schema())


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebServer]:
    with upstream("given-direct", scripted=False) as url:
        with WebServer(Site(tmp_path_factory.mktemp("assets"), {}, Fixed.direct(url), settings=SETTINGS)) as server:
            yield server


@SCHEMA.include(path="/v1/gimap").parametrize()
@hypothesis.settings(max_examples=60, deadline=None, suppress_health_check=list(hypothesis.HealthCheck))
def test_fuzzed_requests_get_no_5xx_but_the_upstreams(case, fuzzed: WebServer) -> None:
    """Fuzzed profiles, stores and JSON bodies: every answer is the upstream's, or a 4xx with a detail line."""
    response = case.call(base_url=fuzzed.url, timeout=HANG_GUARD_S)
    if case.method != "POST":  # the fuzzer tries the other methods too
        assert response.status_code == (204 if case.method == "OPTIONS" else 405), case.method
    elif "x-profile" not in response.headers:  # not forwarded: refused here, never a 5xx
        assert 400 <= response.status_code < 500, (response.status_code, response.text)
        assert isinstance(response.json()["detail"], str | list)
    else:  # forwarded: the upstream's answer as it came
        assert response.status_code == 200 and response.json()["upstream"] == "given-direct"
