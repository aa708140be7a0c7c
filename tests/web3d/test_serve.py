"""gigan-web's server: the page's files only from their roots and allow-lists (no dotfile, no package.json, no
file of the assets folder that the export did not write), caching headers with ETag and 304, HEAD and OPTIONS,
the Host check, every response cross-origin isolated, /config.json and /v1/shadow."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import httpx
import numpy as np
import pytest

from gicore.geometry import scene_objects
from gicore.gl.shadow import object_bounds
from gicore.options import FRAMES_MAX
from gicore.paths import light_bounds
from gicore.scene import load_scene
from tests.web3d.test_cli import IPV6
from web3d.export import shadow_setup
from web3d.routes_shadow import Shadows
from web3d.routes_static import ASSET_FILES
from web3d.serve import WebServer
from web3d.site import WEB_DIR, Site

SHADOW_SIZE = 256
ISOLATION = {"cross-origin-opener-policy": "same-origin", "cross-origin-embedder-policy": "require-corp"}
NPM = (WEB_DIR / "node_modules" / "onnxruntime-web" / "dist").is_dir()


@pytest.fixture(scope="module")
def web(tmp_path_factory: pytest.TempPathFactory):
    """The server for an assets folder holding the exported files and others an earlier use left there."""
    assets = tmp_path_factory.mktemp("assets")
    (assets / "model").mkdir()
    for name in ASSET_FILES:
        (assets / name).write_bytes(name.encode())
    for stray in (".env", "notes.txt", "model/other.onnx", "model/.hidden"):
        (assets / stray).write_text("not exported")
    shadows = Shadows(load_scene("lung_plane"), SHADOW_SIZE)
    with WebServer(Site(assets, {"scene": "lung_plane"}, shadows=shadows)) as server:
        yield server


def get(web: WebServer, path: str, method: str = "GET", **kwargs) -> httpx.Response:
    return httpx.request(method, web.url + path, timeout=60, **kwargs)


def test_files_come_from_the_roots_and_allow_lists_only(web: WebServer) -> None:
    served = ["/", "/index.html", "/js/main.js", *(f"/assets/{name}" for name in sorted(ASSET_FILES))]
    refused = [
        "/assets/.env",
        "/assets/notes.txt",
        "/assets/model/other.onnx",
        "/assets/model/.hidden",
        "/assets/../../etc/passwd",
        "/assets/%2e%2e/%2e%2e/pyproject.toml",
        "/../pyproject.toml",
        "/package.json",
        "/package-lock.json",
        "/screenshot.png",
        "/node_modules/fzstd/package.json",
        "/npm/fzstd/../package.json",
        "/npm/onnxruntime-web/../package.json",
        "/npm/three/package.json",
        "/js/",
        "/js/.eslintrc",
        "/assets/missing.bin",
        "/v1/nothing",
    ]
    for path in served:
        assert get(web, path).status_code == 200, path
    for path in refused:
        assert get(web, path).status_code == 404, path
    assert get(web, "/assets/scene.bin").content == b"scene.bin"
    assert get(web, "/js/main.js").headers["content-type"].startswith("text/javascript")
    if NPM:
        r = get(web, "/npm/onnxruntime-web/ort.all.min.mjs")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/javascript")


def test_every_response_is_cross_origin_isolated(web: WebServer) -> None:
    cases = [("GET", "/"), ("GET", "/missing"), ("POST", "/js/main.js"), ("GET", "/v1/shadow?light=x")]
    cases += [("POST", "/v1/gimap"), ("OPTIONS", "/"), ("HEAD", "/config.json")]
    for method, path in cases:
        r = get(web, path, method)
        assert {k: r.headers.get(k) for k in ISOLATION} == ISOLATION, (method, path, r.status_code)
    refused = get(web, "/", headers={"Host": "attacker.example"})
    assert refused.status_code == 400 and {k: refused.headers.get(k) for k in ISOLATION} == ISOLATION


def test_the_host_header_must_name_this_server(web: WebServer) -> None:
    port = web.socket.getsockname()[1]
    for host in ("127.0.0.1", "localhost", f"127.0.0.1:{port}", f"localhost:{port}"):
        assert get(web, "/config.json", headers={"Host": host}).status_code == 200, host
    for host in ("attacker.example", f"attacker.example:{port}", "127.0.0.2"):
        assert get(web, "/config.json", headers={"Host": host}).status_code == 400, host
    for host in ("localhost:0", f"127.0.0.1:{port + 1}", "localhost:", "[127.0.0.1]", "127.0.0.1:x", ""):
        assert get(web, "/config.json", headers={"Host": host}).status_code == 400, host
    # a second Host is not looked past: HTTP/1.1 answers a request with two 400, whichever comes first
    for hosts in ((f"127.0.0.1:{port}", "attacker.example"), ("attacker.example", f"127.0.0.1:{port}")):
        head = "GET /config.json HTTP/1.1\r\n" + "".join(f"Host: {h}\r\n" for h in hosts) + "Connection: close\r\n\r\n"
        with socket.create_connection(web.socket.getsockname()[:2], timeout=60) as sock:
            sock.sendall(head.encode())
            assert sock.recv(12) == b"HTTP/1.1 400", hosts


@pytest.mark.skipif(not IPV6, reason="this machine has no IPv6 loopback")
def test_a_bracketed_ipv6_host_is_this_server(tmp_path: Path) -> None:
    with WebServer(Site(tmp_path, {"scene": "s"}), "::1", 0) as server:
        port = server.socket.getsockname()[1]
        assert server.url == f"http://[::1]:{port}"
        for host in ("[::1]", f"[::1]:{port}", f"localhost:{port}"):
            assert get(server, "/config.json", headers={"Host": host}).status_code == 200, host
        for host in ("::1", f"::1:{port}", "[::1]:0", "[::2]", f"[::1]:{port}x"):
            assert get(server, "/config.json", headers={"Host": host}).status_code == 400, host


def test_files_carry_etags_and_caching_headers(web: WebServer) -> None:
    for path in ("/", "/js/main.js", "/assets/scene.json", "/assets/model/model.onnx"):
        first = get(web, path)
        assert first.headers["cache-control"] == "no-cache" and first.headers["etag"], path
        again = get(web, path, headers={"If-None-Match": first.headers["etag"]})
        assert again.status_code == 304 and again.content == b"" and again.headers["etag"] == first.headers["etag"]
        since = get(web, path, headers={"If-Modified-Since": first.headers["last-modified"]})
        assert since.status_code == 304, path
        assert get(web, path, headers={"If-None-Match": '"other"'}).status_code == 200
    assert get(web, "/config.json").headers["cache-control"] == "no-store"
    if NPM:
        npm = get(web, "/npm/onnxruntime-web/ort.all.min.mjs")
        assert "max-age=" in npm.headers["cache-control"] and npm.headers["etag"]


def test_head_and_options_are_answered(web: WebServer) -> None:
    for path in ("/", "/js/main.js", "/assets/scene.bin", "/config.json", "/v1/status"):
        head, body = get(web, path, "HEAD"), get(web, path)
        assert head.status_code == 200 and head.content == b"", path
        assert head.headers.get("content-length") == body.headers.get("content-length"), path
    for path, allow in [
        ("/v1/gimap", "OPTIONS, POST"),
        ("/v1/shadow", "GET, HEAD, OPTIONS"),
        ("/config.json", "GET, HEAD, OPTIONS"),
        ("/js/main.js", "GET, HEAD, OPTIONS"),
        ("/assets/scene.bin", "GET, HEAD, OPTIONS"),
    ]:
        r = get(web, path, "OPTIONS")
        assert (r.status_code, r.headers["allow"]) == (204, allow), path
    assert get(web, "/js/main.js", "POST").status_code in (404, 405)
    assert get(web, "/v1/gimap", "GET").status_code == 405


def test_config_names_no_profile_without_a_cloud_side(web: WebServer) -> None:
    config = json.loads(get(web, "/config.json").content)
    cloud_off = {"profiles": [], "profile": None, "stores": [], "store": None}
    assert config == {"scene": "lung_plane", **cloud_off, "record_frames_max": FRAMES_MAX}
    assert get(web, "/v1/gimap", "POST", json={}).status_code == 503
    status = json.loads(get(web, "/v1/status").content)
    assert status == {"profiles": {}, "stores": {}, "scene": "lung_plane"}


def test_shadow_setup_is_the_exports_for_the_same_light(web: WebServer) -> None:
    spec = load_scene("lung_plane")
    bounds = object_bounds(scene_objects(spec), len(spec.objects))
    low, high = light_bounds(spec)
    for light in (spec.light.position, low, high, tuple((a + b) / 2 for a, b in zip(low, high))):
        r = get(web, "/v1/shadow", params={"light": ",".join(repr(float(c)) for c in light)})
        assert r.status_code == 200, (light, r.text)
        expected = shadow_setup(bounds, np.asarray(light, dtype=np.float64), SHADOW_SIZE)
        assert r.json() == json.loads(json.dumps(expected)), light
    outside = f"{high[0] + 0.01},{high[1]},{high[2]}"
    for bad in (outside, "1,2", "1,2,3,4", "a,b,c", "nan,1,1", "inf,1,1", ""):
        r = get(web, "/v1/shadow", params={"light": bad})
        assert r.status_code == 422 and isinstance(r.json()["detail"], str), bad
    assert get(web, "/v1/shadow").status_code == 422


def test_web_dir_is_the_repositorys_page() -> None:
    assert (WEB_DIR / "index.html").is_file() and WEB_DIR == Path(__file__).resolve().parents[2] / "web3d" / "static"
