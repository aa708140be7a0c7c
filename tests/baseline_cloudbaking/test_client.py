"""The cloud-baking client (baseline_cloudbaking.client): its remote GI source against a real server process,
the client process on the GL warp backend, a server shut down mid-run, and dead links that must end in a timeout,
never a hang. All on 127.0.0.1 with ephemeral ports, at 64². The client process end to end through a network
proxy, beside gigan-client, on the GL renderer, is tests/bench/test_latency.py::test_bench_latency_end_to_end
(the bench runs exactly that)."""

from __future__ import annotations

import json
import logging
import subprocess
import time
from pathlib import Path

import httpx
import pytest

from baseline_cloudbaking.client import STAGES, RemoteConfig, RemoteSource
from baseline_cloudbaking.request_policy import RequestPolicy, covers
from baseline_cloudbaking.viewpoints import Tolerance
from gicore.frame_rows import read_csv_rows
from gicore.paths import path_views
from gicore.scene import load_scene
from network_sim.process import Running, network_sim
from tests.helpers.cloud import BIN, RES, SPP, server_process, write_scenes
from tests.helpers.guards import HANG_GUARD_S


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("client_scenes"))


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, scenes_dir: Path):
    with server_process(tmp_path_factory.mktemp("client_store"), scenes_dir, "--max-spp", "16") as url:
        yield url


def remote(url: str, **changes) -> RemoteConfig:
    return RemoteConfig(url, "ball_moving", RES, "jpeg", SPP, **changes)


def views(scenes_dir: Path, frames: int):
    spec = load_scene(scenes_dir / "ball_moving.json")
    return spec, [(cam.with_fov(90.0), light) for cam, light in path_views(spec, frames, 300, 0, 60.0, RES)]


@pytest.mark.slow
def test_remote_source_splits_a_miss_and_a_hit_into_stages(server: str, scenes_dir: Path) -> None:
    _, [(camera, light)] = views(scenes_dir, 1)
    camera = camera.with_fov(71.0)  # a GI format no other test asks for: the first request must miss
    with RemoteSource(remote(server)) as source:
        source.warm_up(camera, light)
        assert source.request(camera, light, 0) is True
        assert source.request(camera, light, 1) is False  # one request in flight at most
        assert source.wait(60.0)
        assert source.request(camera, light, 2) is True and source.wait(60.0)
        miss, hit = source.records
        gi = source.latest()
    assert (miss["status"], miss["hit"], hit["status"], hit["hit"]) == ("ok", 0, "ok", 1)
    assert (
        all(miss[f"{s}_ms"] > 0 for s in ("render", "denoise", "encode", "request", "decode")) and miss["read_ms"] == ""
    )
    assert hit["read_ms"] > 0 and hit["render_ms"] == "" and hit["server_ms"] < miss["server_ms"]
    for record in (miss, hit):  # the stages add up to the request's latency; transmission is its network share
        stages = sum(record[f"{s}_ms"] for s in STAGES if record[f"{s}_ms"] != "")
        assert abs(stages - record["latency_ms"]) < 1.0, record
        assert record["transmission_ms"] == pytest.approx(record["request_ms"] + record["transfer_ms"])
        assert 200 < record["bytes_up"] < 1000 and record["bytes_down"] > 2 * 1024
    assert (
        gi.frame == 2
        and gi.camera == camera.with_fov(71.0)
        and gi.radiance.shape == (RES, RES, 3)
        and (gi.depth > 0).mean() > 0.3
    )
    assert sum(gi.stages.values()) == pytest.approx(gi.latency_ms, abs=1.0)


@pytest.mark.slow
def test_client_survives_the_server_shutting_down(scenes_dir: Path, tmp_path: Path) -> None:
    """kill -9 of the server once two maps were served: the client logs the failed requests and composes
    every remaining frame with its last map."""
    argv = [
        str(BIN / "cloudbaking-server"),
        "--port",
        "0",
        "--store",
        str(tmp_path / "store"),
        "--scenes",
        str(scenes_dir),
    ]
    with Running(argv, timeout=60.0) as srv:
        url = "{}:{}".format(*srv.addr)
        client = subprocess.Popen(
            [str(BIN / "cloudbaking-client"), "--server", url, "--scene", str(scenes_dir / "ball_moving.json"),
             "--frames", "150", "--resolution", str(RES), "-k", "2", "--spp", str(SPP), "--out", str(tmp_path / "run")],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        deadline = time.monotonic() + 90
        while httpx.get(f"{url}/v1/stats", timeout=60).json()["requests"] < 2:
            assert time.monotonic() < deadline and client.poll() is None, "the client did not get two maps"
            time.sleep(0.02)
        srv.proc.kill()
        out, err = client.communicate(timeout=120)
    assert client.returncode == 0, err
    requests = read_csv_rows(tmp_path / "run" / "requests.csv")
    frames = read_csv_rows(tmp_path / "run" / "frames.csv")
    failed = [r for r in requests if r["status"] == "connection"]
    assert failed and "failed: connection" in err and f"{len(failed)} connection" in out
    last = max((r for r in requests if r["bound_frame"]), key=lambda r: int(r["bound_frame"]))
    after = frames[int(last["bound_frame"]) + 1 :]
    assert len(frames) == 150 and len(after) > 10
    assert all(r["gi_new"] == "0" and float(r["valid_frac"]) > 0.5 for r in after)
    # none waits for the dead server: each a small part of the first frame's wait for its map (a compile and a bake)
    assert max(float(r["gi_wait_ms"]) for r in after) < 0.5 * float(frames[0]["gi_wait_ms"])
    assert int(after[-1]["gi_age_frames"]) == 149 - int(last["frame"])  # still the last map, ageing


@pytest.mark.parametrize("link", [["--rate-mbit", "0"], ["--loss", "1"]], ids=["zero_rate", "full_loss"])
def test_a_dead_link_ends_in_a_timeout_never_a_hang(server: str, scenes_dir: Path, link: list[str], caplog) -> None:
    """Nothing passes the proxy: the request fails at the read timeout and is logged; the loop waits once for
    the first map, until that request fails (not the first map's whole timeout: nothing is on its way any more),
    then shows the DI without waiting again."""
    from baseline_cloudbaking.warp import PixelWarp
    from gicore.loop import ClientLoop, LoopConfig
    from gicore.render import Renderer

    read_s, deadline_s, first_map_s = 0.5, 2.0, 10.0
    spec, path = views(scenes_dir, 3)
    with network_sim("proxy", "--upstream", server.removeprefix("http://"), *link) as proxy:
        url = "http://{}:{}".format(*proxy.addr)
        cfg = remote(url, read_timeout_s=read_s, deadline_s=deadline_s, retry_after_s=30.0)
        with caplog.at_level(logging.WARNING, logger="cloudbaking.client"), RemoteSource(cfg) as source:
            renderer = Renderer(spec, RES)
            loop_cfg = LoopConfig(every=1, gi_fov=90.0, first_map_timeout_s=first_map_s)
            loop = ClientLoop(loop_cfg, renderer, source, PixelWarp())
            rows = [loop.step(f, cam.with_fov(60.0), light).row for f, (cam, light) in enumerate(path)]
    # each wait ends at its timeout, not later than a busy machine makes it (the margins are multiples of it)
    [record] = source.records
    assert record["status"] == "timeout" and 0.8 * read_s * 1e3 < record["latency_ms"] < 2 * deadline_s * 1e3
    assert source.latest() is None and any("failed: timeout" in m for m in caplog.messages)
    assert 0.8 * read_s * 1e3 <= rows[0]["gi_wait_ms"] < 0.5 * first_map_s * 1e3, rows[0]
    assert all(r["gi_wait_ms"] < 0.5 * read_s * 1e3 and r["valid_frac"] == 0 for r in rows[1:]), rows
    assert [r["gi_requested"] for r in rows] == [1, 0, 0]  # retry_after holds the next request back


def test_timeouts_are_explicit() -> None:
    timeout = RemoteConfig("http://127.0.0.1:1", "s", connect_timeout_s=2.0, read_timeout_s=3.0).timeout()
    assert (timeout.connect, timeout.read, timeout.write, timeout.pool) == (2.0, 3.0, 3.0, 2.0)
    with pytest.raises(ValueError, match="read_timeout_s"):
        RemoteConfig("http://127.0.0.1:1", "s", read_timeout_s=0.0)


def test_cloud_client_with_the_gl_warp_backend(server: str, scenes_dir: Path, tmp_path: Path) -> None:
    """``cloudbaking-client --warp-backend gl`` (baseline_cloudbaking.gl_warp, tests in test_gl_warp.py): frames
    warped and composed in GL, the GL warp's stages in the frame columns and in each request's warp time, and the
    summary naming the backend that ran."""
    from gicore.gl import gl_available

    ok, why = gl_available()
    if not ok:
        pytest.skip(f"no OpenGL context: {why}")
    argv = [str(BIN / "cloudbaking-client"), "--server", server, "--scene", str(scenes_dir / "ball_moving.json")]
    argv += ["--frames", "4", "--resolution", str(RES), "-k", "2", "--spp", str(SPP), "--warp-backend", "gl"]
    proc = subprocess.run([*argv, "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["warp_backend"] == "gl" and summary["config"]["warp_backend"] == "gl"
    frames = read_csv_rows(tmp_path / "out" / "frames.csv")
    assert "project_ms" not in frames[0] and float(frames[0]["bind_ms"]) > 0
    assert all(float(r["splat_ms"]) > 0 and float(r["fill_ms"]) > 0 and float(r["valid_frac"]) > 0.5 for r in frames)
    shown = [r for r in read_csv_rows(tmp_path / "out" / "requests.csv") if r["total_ms"]]
    assert shown and all(float(r["warp_ms"]) > 0 for r in shown)


def test_the_hold_asks_only_for_views_no_held_map_serves(server: str, scenes_dir: Path) -> None:
    """The path flown one request at a time: with the hold (the server's tolerance and light cells), a request goes
    out only when no held map serves the view, and the map shown then serves it; without it, every frame asks. Last in
    the module: it stores the path's maps, and the tests before it need their first map to miss."""
    _, path = views(scenes_dir, 30)
    hold = RequestPolicy(Tolerance(0.05, 2.0), light_cell=0.25)  # the server's defaults
    sent = {}
    for name, policy in (("hold", hold), ("none", RequestPolicy())):
        with RemoteSource(remote(server), policy) as source:
            asked = []
            for frame, (camera, light) in enumerate(path):
                cell = hold.cell(light)
                held = [(gi.camera, c) for gi, c in source.kept]
                asked.append(source.request(camera, light, frame))
                if policy is hold:
                    assert asked[-1] == (not any(covers(*h, camera, cell, hold.tolerance) for h in held))
                assert source.wait(60.0)
                shown = source.latest()
                assert policy is not hold or covers(shown.camera, source.cell_of(shown), camera, cell, hold.tolerance)
            assert all(r["status"] == "ok" for r in source.records)
            sent[name] = sum(asked)
    assert sent["none"] == len(path)
    assert 2 <= sent["hold"] <= 0.4 * len(path), sent
