"""gigan-web's server: the page's files only from its roots (no path out of them, no node_modules but the two
packages' distribution folders), every response cross-origin isolated, /v1/gimap refused without an upstream."""

from __future__ import annotations

import http.client
import json
from pathlib import Path

import pytest

from web3d.serve import WEB_DIR, Site, WebServer


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    assets = tmp_path_factory.mktemp("assets")
    (assets / "scene.bin").write_bytes(b"\x00\x01")
    with WebServer(Site(assets, {"scene": "s", "cloud": False})) as web:
        yield web


def get(web: WebServer, path: str, method: str = "GET", body: bytes | None = None) -> http.client.HTTPResponse:
    host, port = web.httpd.server_address[:2]
    conn = http.client.HTTPConnection(host, port, timeout=60)
    conn.request(method, path, body=body, headers={"Content-Type": "application/json"})
    response = conn.getresponse()
    response.body = response.read()  # type: ignore[attr-defined]
    conn.close()
    return response


def test_files_come_from_the_roots_only_and_every_response_is_isolated(server) -> None:
    for path, status in [
        ("/", 200),
        ("/js/main.js", 200),
        ("/config.json", 200),
        ("/assets/scene.bin", 200),
        ("/assets/../../etc/passwd", 404),
        ("/../pyproject.toml", 404),
        ("/node_modules/fzstd/package.json", 404),
        ("/assets/missing.bin", 404),
    ]:
        r = get(server, path)
        assert r.status == status, path
        assert r.getheader("Cross-Origin-Opener-Policy") == "same-origin", path
        assert r.getheader("Cross-Origin-Embedder-Policy") == "require-corp", path
    assert json.loads(get(server, "/config.json").body) == {"scene": "s", "cloud": False}
    assert get(server, "/assets/scene.bin").body == b"\x00\x01"
    assert get(server, "/js/main.js").getheader("Content-Type").startswith("text/javascript")
    if (WEB_DIR / "node_modules" / "onnxruntime-web").is_dir():
        r = get(server, "/npm/onnxruntime-web/ort.all.min.mjs")
        assert r.status == 200 and r.getheader("Content-Type").startswith("text/javascript")


def test_gimap_without_an_upstream_is_503_and_a_huge_body_413(server) -> None:
    assert get(server, "/v1/gimap", "POST", b"{}").status == 503
    assert get(server, "/v1/gimap", "POST", b"x" * (1 << 17)).status == 413
    assert get(server, "/v1/other", "POST", b"{}").status == 404


def test_web_dir_is_the_repositorys_page() -> None:
    assert (WEB_DIR / "index.html").is_file() and WEB_DIR == Path(__file__).resolve().parents[2] / "web3d" / "static"
