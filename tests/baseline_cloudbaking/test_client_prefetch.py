"""The cloud client's request rule and prefetch: the GI tree's tolerance rule held on the client,
the motion extrapolation, Retry-After and the perceived latency of a run (the hold against a real server is in
test_client.py, beside its server)."""

from __future__ import annotations

import email.utils
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest

from baseline_cloudbaking.client import RemoteConfig, RemoteSource
from baseline_cloudbaking.client_run import CloudClientConfig, perceived_latency
from baseline_cloudbaking.fetch import retry_after_s
from baseline_cloudbaking.request_policy import MotionPredictor, RequestPolicy, covers
from baseline_cloudbaking.viewpoints import Tolerance
from gicore.camera import Camera
from gicore.error_policy import UserError
from gicore.gi_map import GIMap
from gicore.options import build_config
from gicore.paths import path_views
from gicore.scene import load_scene
from tests.helpers.cloud import RES, SPP

TOL = Tolerance(0.05, 2.0)


def cam(x: float, turn_deg: float = 0.0) -> Camera:
    """A camera at (x, 1, 3) looking down -z, turned ``turn_deg`` about y."""
    a = np.radians(turn_deg)
    eye = (x, 1.0, 3.0)
    return Camera(eye, (x - np.sin(a), 1.0, 3.0 - np.cos(a)), fov=90.0, width=8, height=8)


def test_covers_is_the_trees_rule_at_its_bounds() -> None:
    assert covers(cam(0.0), None, cam(0.049), None, TOL) and not covers(cam(0.0), None, cam(0.051), None, TOL)
    assert covers(cam(0.0), None, cam(0.0, 1.9), None, TOL) and not covers(cam(0.0), None, cam(0.0, 2.1), None, TOL)
    assert not covers(cam(0.0), (0, 1, 0), cam(0.0), (1, 1, 0), TOL)  # another light cell is another subtree


def test_the_motion_of_an_orbit_is_extrapolated_within_tolerance() -> None:
    """lung_plane's path at 30 fps with 6 ms of timing jitter: 10 frames ahead (0.33 s, ~10 tolerance widths of
    motion) the prediction is within the tree's tolerance of the true view, which the last view is far from, and
    the moving light is predicted too (a map asked under the current light misses past a light-cell boundary)."""
    spec = load_scene("lung_plane")
    path = [(c.with_fov(90.0), light) for c, light in path_views(spec, 60, 300, 0, 60.0, 64)]
    times = np.arange(60) / 30.0 + np.random.default_rng(0).normal(0.0, 0.006, 60)
    motion = MotionPredictor(8)
    motion.add(0, times[0], *path[0])
    motion.add(1, times[1], *path[1])
    assert motion.predict(path[1][0], 0.3) is None  # too little motion known yet
    hits = 0
    for now in range(10, 50):
        for f in range(now - 7, now + 1):
            motion.add(f, times[f], *path[f])
        (camera, light), (future, future_light) = path[now], path[now + 10]
        predicted, predicted_light = motion.predict(camera, 10 * motion.frame_interval_s())
        assert not covers(camera, None, future, None, TOL)
        hits += covers(predicted, None, future, None, TOL)
        moved = np.linalg.norm(np.subtract(future_light, light))
        assert moved > 0.03 and np.linalg.norm(np.subtract(predicted_light, future_light)) < 0.1 * moved
    assert hits == 40, hits
    assert motion.frame_interval_s() == pytest.approx(1 / 30, rel=0.2)
    # 0.039 units (0.78 x 0.05) and 1.18° (0.59 x 2°) a frame: the eye leaves the tolerance first, in 1.28 frames
    assert motion.crossing_s(TOL) == pytest.approx(motion.frame_interval_s() * 1.28, rel=0.1)


def test_retry_after_values() -> None:
    assert retry_after_s("3", 1.0, 60.0) == 3.0
    assert retry_after_s(None, 1.0, 60.0) == 1.0 and retry_after_s("soon", 1.0, 60.0) == 1.0
    assert retry_after_s("100000", 1.0, 60.0) == 60.0 and retry_after_s("-5", 1.0, 60.0) == 0.0
    sent = time.time()
    date = email.utils.formatdate(sent + 20.0, usegmt=True)  # whole seconds: up to 1 s less than asked
    waited = retry_after_s(date, 1.0, 60.0)
    assert 19.0 - (time.time() - sent) <= waited <= 20.0


#: Hang guard of a wait for a request's answer.
WAIT_S = 60.0


@pytest.fixture
def overloaded() -> Iterator[str]:
    """A real HTTP server that answers every POST after 0.2 s with 503 and ``Retry-After: 1``, counting them."""

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802 -- http.server's name
            self.rfile.read(int(self.headers["content-length"]))
            self.server.posts += 1  # type: ignore[attr-defined]
            time.sleep(0.2)
            body = b'{"detail": "the miss queue is full; retry after 1 s"}'
            self.send_response(503)
            self.send_header("retry-after", "1")
            self.send_header("content-type", "application/json")
            self.send_header("content-length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    httpd.posts = 0  # type: ignore[attr-defined]
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield httpd
    httpd.shutdown()
    httpd.server_close()


def test_a_503_holds_requests_back_for_its_retry_after(overloaded) -> None:
    url = f"http://127.0.0.1:{overloaded.server_address[1]}"
    remote = RemoteConfig(url, "ball_moving", RES, "jpeg", SPP, retry_after_s=0.0)
    with RemoteSource(remote) as source:
        assert source.request(cam(0.0), (0.0, 2.0, 0.0), 0) and source.wait(WAIT_S)
        t_failed = time.perf_counter()
        assert source.records[0]["status"] == "overloaded" and "retry after" in source.records[0]["error"]
        assert not source.request(cam(0.0), (0.0, 2.0, 0.0), 1)  # retry_after_s 0 would have sent it
        time.sleep(max(0.0, t_failed + 1.05 - time.perf_counter()))
        assert source.request(cam(0.0), (0.0, 2.0, 0.0), 2) and source.wait(WAIT_S)
    assert overloaded.posts == 2


def test_requests_in_flight_at_most_as_allowed_each_recorded_once(overloaded) -> None:
    remote = RemoteConfig(f"http://127.0.0.1:{overloaded.server_address[1]}", "ball_moving", RES, "jpeg", SPP)
    with RemoteSource(remote, RequestPolicy(in_flight=2)) as source:
        assert [source.request(cam(0.0), (0.0, 2.0, 0.0), f) for f in range(3)] == [True, True, False]
        assert source.wait(WAIT_S)
    assert sorted((r["request_id"], r["frame"], r["status"]) for r in source.records) == [
        (0, 0, "overloaded"),
        (1, 1, "overloaded"),
    ]
    with RemoteSource(replace(remote, retry_after_s=0.0), RequestPolicy(in_flight=2)) as source:
        assert source.request(cam(0.0), (0.0, 2.0, 0.0), 0) and source.request(cam(0.0), (0.0, 2.0, 0.0), 1)
    assert [(r["request_id"], r["status"]) for r in source.records] == [(0, "abandoned"), (1, "abandoned")]


def blank(camera: Camera, frame: int) -> GIMap:
    return replace(GIMap.blank(camera), frame=frame)


def test_perceived_latency_waits_for_the_first_frame_showing_a_map_that_serves_the_view() -> None:
    """Frames 0.1 s apart moving 0.04 a frame; a map of frame 0's view shown until frame 4, one of frame 5's view
    from frame 5 on: frames 0 and 1 are served at once, 2 and 3 never (censored), 4 once frame 5 shows."""
    views = [(cam(0.04 * f), None) for f in range(7)]
    a, b = blank(cam(0.0), 0), blank(cam(0.2), 5)
    shown = [(0.1 * f, 0.1 * f + 0.05, a if f < 5 else b, None) for f in range(7)]
    rows = perceived_latency(views, shown, TOL)
    assert [r["in_tolerance"] for r in rows] == [1, 1, 0, 0, 0, 1, 1]
    assert [r["perceived_map"] for r in rows] == [0, 0, "", "", 5, 5, 5]
    ms = [r["perceived_ms"] for r in rows]
    assert ms[2] == ms[3] == "" and ms[4] == pytest.approx(150.0)
    assert all(ms[f] == pytest.approx(50.0) for f in (0, 1, 5, 6))
    other_cell = perceived_latency([(c, (1, 0, 0)) for c, _ in views], shown, TOL)
    assert all(r["perceived_ms"] == "" for r in other_cell)  # a map of another light cell serves no view


def test_prefetch_needs_the_hold() -> None:
    """A user error naming both options (the command line turns it into one ``error:`` line, exit 2)."""
    with pytest.raises(UserError, match=r"--prefetch extrapolate needs --hold tolerance"):
        build_config(CloudClientConfig, {"hold": "none", "prefetch": "extrapolate"})
