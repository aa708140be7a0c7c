"""The cloud-baking server as its own process on 127.0.0.1 (ephemeral port), and its schema in-process."""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from baseline_cloudbaking.codecs import CODECS, DEPTH_CODEC
from baseline_cloudbaking.protocol import MEDIA_TYPE, decode_payload
from tests.helpers.cloud import RES, SPP, gimap_body, server_process, write_scenes


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("cloud_scenes"))


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, scenes_dir: Path):
    """One server process for the module: (base URL, store folder)."""
    store = tmp_path_factory.mktemp("cloud_store")
    # two compiled renderers at most: the tests' scenes and resolutions also exercise their eviction
    with server_process(store, scenes_dir, "--max-spp", "16", env={"CLOUDBAKING_MAX_RENDERERS": "2"}) as url:
        yield url, store


@pytest.fixture(scope="module")
def client(server):
    with httpx.Client(base_url=server[0], timeout=httpx.Timeout(120.0, connect=10.0)) as c:
        yield c


def post(client: httpx.Client, body) -> httpx.Response:
    content = body if isinstance(body, (str, bytes)) else json.dumps(body)
    return client.post("/v1/gimap", content=content, headers={"content-type": "application/json"})


@pytest.mark.slow
def test_miss_renders_and_stores_then_the_same_request_hits(client: httpx.Client, server) -> None:
    body = gimap_body(eye=(1.5, 1.2, 1.3), light=[0.1, 2.2, 0.3], di=True)
    before = client.get("/v1/stats").json()
    miss = post(client, body)
    assert miss.status_code == 200, miss.text
    assert miss.headers["content-type"] == MEDIA_TYPE and miss.headers["x-gimap-hit"] == "0"
    first = decode_payload(miss.content)
    assert first.hit is False and set(first.timings_ms) == {"lookup", "render", "denoise", "encode", "total"}
    assert first.gi.shape == (RES, RES, 3) and first.di.shape == (RES, RES, 3) and (first.depth > 0).mean() > 0.5
    assert first.header["light"] == [0.1, 2.2, 0.3] and first.header["spp"] == SPP and first.header["codec"] == "jpeg"
    hit = post(client, body)
    assert hit.status_code == 200 and hit.headers["x-gimap-hit"] == "1"
    second = decode_payload(hit.content)
    assert second.hit is True and set(second.timings_ms) == {"lookup", "read", "total"}
    assert (
        np.array_equal(second.gi, first.gi)
        and np.array_equal(second.di, first.di)
        and np.array_equal(second.depth, first.depth)
    )
    assert second.camera == first.camera and np.allclose(second.view, first.camera.view())
    # nearby (within the default Δp = 0.05) is served the stored map, with its own camera
    near = decode_payload(post(client, gimap_body(eye=(1.52, 1.2, 1.3), light=[0.1, 2.2, 0.3])).content)
    assert near.hit is True and near.camera == first.camera and near.di is None  # DI only when asked for
    assert 0.019 < near.header["distance"]["position"] < 0.021
    after = client.get("/v1/stats").json()
    assert (after["misses"] - before["misses"], after["hits"] - before["hits"]) == (1, 2)
    assert after["entries"] == before["entries"] + 1
    # the stored payload is the response minus the per-request header fields (hit, timings, distance)
    assert 0 < len(miss.content) - (after["bytes"] - before["bytes"]) < 300


def test_codecs_serve_what_they_state(client: httpx.Client) -> None:
    for i, name in enumerate(CODECS):
        response = post(client, gimap_body(eye=(-1.4, 1.0 + 0.1 * i, 1.5), codec=name))
        assert response.status_code == 200, (name, response.text)
        payload = decode_payload(response.content)
        assert payload.header["codec"] == name and payload.gi.shape == (RES, RES, 3)
        assert [s["codec"] for s in payload.header["sections"]] == [name, DEPTH_CODEC.name]


def test_static_light_scene_has_no_light_level(client: httpx.Client, server) -> None:
    from baseline_cloudbaking.store import GITree

    response = post(client, gimap_body("ball_static", eye=(0.5, 1.4, 2.0)))
    assert response.status_code == 200, response.text
    assert "light" not in decode_payload(response.content).header
    refused = post(client, gimap_body("ball_static", light=[0.0, 3.0, 0.0]))
    assert refused.status_code == 422 and refused.json()["detail"][0]["loc"] == ["body", "light"]
    assert "static light" in refused.json()["detail"][0]["msg"]
    info = {s["name"]: s for s in client.get("/v1/scenes").json()["scenes"]}
    assert info["ball_static"]["light_cell"] is None and info["ball_moving"]["light_cell"] == 0.25
    with GITree(server[1]) as tree:  # a second opener, next to the server: reads, sweeps nothing
        assert {e.key.light_cell for e in tree.entries("ball_static")} == {None}
        assert all(e.key.light_cell is not None for e in tree.entries("ball_moving"))


def test_health_scenes_and_openapi(client: httpx.Client) -> None:
    assert client.get("/v1/health").json()["status"] == "ok"
    scenes = client.get("/v1/scenes").json()
    assert {"ball_moving", "ball_static", "lung_plane"} <= {s["name"] for s in scenes["scenes"]}
    assert scenes["max_spp"] == 16 and scenes["codecs"] == list(CODECS)
    moving = next(s for s in scenes["scenes"] if s["name"] == "ball_moving")
    assert moving["light_min"] == pytest.approx([-0.6, 2.05, 0.3]) and moving["camera_azimuth_deg"] == [-35.0, 35.0]
    spec = client.get("/openapi.json").json()
    assert MEDIA_TYPE in spec["paths"]["/v1/gimap"]["post"]["responses"]["200"]["content"]
    assert {"/v1/health", "/v1/stats", "/v1/scenes"} <= set(spec["paths"])


BAD_REQUESTS = [
    # (what, body, status, field in detail[].loc)
    ("NaN eye", '{"scene": "ball_moving", "camera": {"eye": [NaN, 1, 1], "target": [0, 0.5, 0]}}', 422, "eye"),
    (
        "infinite target",
        '{"scene": "ball_moving", "camera": {"eye": [1, 1, 1], "target": [1e999, 0.5, 0]}}',
        422,
        "target",
    ),
    (
        "Infinity light",
        '{"scene": "ball_moving", "camera": {"eye": [1, 1, 1], "target": [0, 0.5, 0]}, "light": [Infinity, 2, 0]}',
        422,
        "light",
    ),
    ("unknown scene", gimap_body("no_such_scene"), 422, "scene"),
    ("path traversal", gimap_body("../../etc/passwd"), 422, "scene"),
    ("traversal, encoded", gimap_body("..%2F..%2Fetc"), 422, "scene"),
    ("unknown codec", gimap_body(codec="gif"), 422, "codec"),
    ("resolution 0", gimap_body(resolution=0), 422, "resolution"),
    ("huge resolution", gimap_body(resolution=10**9), 422, "resolution"),
    ("unserved resolution", gimap_body(resolution=100), 422, "resolution"),
    ("spp 0", gimap_body(spp=0), 422, "spp"),
    ("spp over the limit", gimap_body(spp=17), 422, "spp"),
    ("fov 180", gimap_body(camera={"eye": [1, 1, 1], "target": [0, 0.5, 0], "fov": 180}), 422, "fov"),
    ("eye = target", gimap_body(camera={"eye": [1, 1, 1], "target": [1, 1, 1]}), 422, "camera"),
    ("up parallel to view", gimap_body(camera={"eye": [0, 2, 0], "target": [0, 0, 0]}), 422, "camera"),
    ("far away eye", gimap_body(eye=(1e6, 0, 0)), 422, "eye"),
    ("unknown field", gimap_body(quality=99), 422, "quality"),
    ("missing camera", {"scene": "ball_moving"}, 422, "camera"),
    ("malformed JSON", '{"scene": "ball_moving", "camera": ', 422, "body"),
    ("not an object", "[1, 2, 3]", 422, "body"),
    ("body too large", json.dumps(gimap_body() | {"pad": "x" * 5000}), 413, "body"),
]


@pytest.mark.parametrize("what,body,status,field", BAD_REQUESTS, ids=[b[0] for b in BAD_REQUESTS])
def test_bad_requests_are_4xx_naming_the_field(client: httpx.Client, what: str, body, status: int, field: str) -> None:
    response = post(client, body)
    assert response.status_code == status, (what, response.status_code, response.text)
    locs = [[str(p) for p in d["loc"]] for d in response.json()["detail"]]
    assert any(field in loc for loc in locs), (what, locs)


def test_wrong_method_and_path_are_4xx(client: httpx.Client) -> None:
    assert client.get("/v1/gimap").status_code == 405
    assert client.get("/v1/scenes/../../etc/passwd").status_code == 404
    assert (
        client.post("/v1/gimap", content=b"\xff\xfe", headers={"content-type": "application/json"}).status_code == 422
    )


@pytest.mark.slow
def test_concurrent_misses_across_scenes_and_resolutions(client: httpx.Client) -> None:
    """Dr.Jit fails when two threads render two scenes at once (a procedural one especially; without the
    server's render lock this failed in 2 of 4 runs): every miss must still be a 200."""
    scenes = ("ball_moving", "ball_static", "lung_plane")

    def miss(k: int) -> tuple[int, bool | str]:
        body = gimap_body(
            scenes[k % 3], eye=(-1.0 - 0.25 * k, 1.2, 1.5), resolution=(64, 128)[k // 3 % 2], di=bool(k % 2)
        )
        r = post(client, body)
        return r.status_code, decode_payload(r.content).hit if r.status_code == 200 else r.text

    with ThreadPoolExecutor(9) as pool:
        assert list(pool.map(miss, range(9))) == [(200, False)] * 9


def test_32_clients_x_50_hits_without_an_error(client: httpx.Client, server) -> None:
    body = gimap_body(eye=(0.3, 1.3, 2.1), light=[0.2, 2.2, 0.3])
    assert post(client, body).status_code == 200  # the miss: from now on every request hits

    def run_client(_: int) -> list[tuple[int, str, float]]:
        out = []
        with httpx.Client(base_url=server[0], timeout=httpx.Timeout(30.0, connect=10.0)) as c:
            for _ in range(50):
                t0 = time.perf_counter()
                r = post(c, body)
                out.append((r.status_code, r.headers.get("x-gimap-hit", ""), time.perf_counter() - t0))
        return out

    t0 = time.perf_counter()
    with ThreadPoolExecutor(32) as pool:
        results = [r for batch in pool.map(run_client, range(32)) for r in batch]
    elapsed = time.perf_counter() - t0
    assert len(results) == 1600 and {(s, h) for s, h, _ in results} == {(200, "1")}
    ms = np.array([t for *_, t in results]) * 1e3
    print(f"32x50 hits: {1600 / elapsed:.0f} req/s, p50 {np.median(ms):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms")


# -- the request schema in-process: no input gives a 5xx ---------------------------------------------
@pytest.fixture(scope="module")
def app_client(tmp_path_factory: pytest.TempPathFactory, scenes_dir: Path):
    from fastapi.testclient import TestClient

    from baseline_cloudbaking.server.app import create_app
    from baseline_cloudbaking.server.settings import Settings

    settings = Settings(
        store=tmp_path_factory.mktemp("prop_store"), scenes_dir=scenes_dir, resolutions=(32, 64), max_spp=2
    )
    with TestClient(create_app(settings)) as c:
        yield c


_number = st.one_of(
    st.floats(-3.0, 3.0),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**30), 10**30),
    st.just("1.0"),
    st.none(),
)
_junk = st.one_of(
    _number,
    st.lists(_number, max_size=4),
    st.text(max_size=8),
    st.dictionaries(st.text(max_size=3), _number, max_size=2),
)
_point = st.tuples(*[st.floats(-3.0, 3.0)] * 3)
_valid = st.fixed_dictionaries(
    {
        "scene": st.sampled_from(["ball_moving", "ball_static"]),
        "camera": st.fixed_dictionaries({"eye": _point, "target": _point}, optional={"fov": st.floats(1, 170)}),
        "resolution": st.sampled_from([32, 64]),
        "spp": st.integers(1, 2),
    },
    optional={"light": _point, "codec": st.sampled_from(list(CODECS)), "di": st.booleans()},
)


def _spoil(body: dict) -> st.SearchStrategy:
    """``body`` itself, or with one field (top level or camera) replaced by junk, removed, or added."""
    camera_fields = [("camera", k) for k in ("eye", "target", "up", "fov")]
    return st.sampled_from([None, *body, "unknown", *camera_fields]).flatmap(
        lambda field: (
            st.just(body)
            if field is None
            else _junk.map(
                lambda junk: (
                    body | {"camera": body["camera"] | {field[1]: junk}}
                    if isinstance(field, tuple)
                    else body | {field: junk}
                )
            )
        )
    )


_request = st.one_of(_valid, _valid.flatmap(_spoil), st.lists(st.integers(), max_size=2), st.text(max_size=20))


@pytest.mark.slow
@settings(
    max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
)
@given(body=_request)
@example(body="0\x00000")  # bytes json.loads cannot decode: a 400, not a 422
def test_no_request_gets_a_5xx(app_client, body) -> None:
    content = body if isinstance(body, str) else json.dumps(body)  # json.dumps writes NaN/Infinity literals
    response = app_client.post("/v1/gimap", content=content, headers={"content-type": "application/json"})
    assert response.status_code < 500, (body, response.text)
    event(f"status {response.status_code}")
    if response.status_code == 200:
        assert decode_payload(response.content).gi.shape[2] == 3
    else:
        # 400: bytes that json.loads cannot even decode (b"0\x00..." reads as UTF-16 of an odd length), which
        # FastAPI reports as a body it could not parse rather than as invalid JSON
        assert response.status_code in (400, 409, 413, 422) and response.json()["detail"][0]["loc"][0] == "body"
