"""The statistics of one replay on hand-made page records (no browser): each frame's phase, the frames
drawn while each map was made, and perceived latency by the GI tree's rule."""

from __future__ import annotations

from typing import Any

import pytest

from web3d.headless import Segment
from web3d.replay_stats import GIGAN, Replayed, frames_during, perceived, phases


def pane(ms: float, sent: bool = False, landed: bool = False, inflight: bool = False, shown: int | None = 0) -> dict:
    return {"ms": ms, "request_ms": 30.0 if sent else 0.0, "land_ms": 5.0 if landed else 0.0, "sent": sent,
            "landed": landed, "inflight": inflight, "map_frame": shown}  # fmt: skip


def frame(t: float, gigan: dict) -> dict[str, Any]:
    return {"t": t, "frame_ms": gigan["ms"], "gigan": gigan, "cloud": None, "replay": None}


def recorded(x: float) -> dict[str, Any]:
    """A recorded frame whose eye is at ``x`` (1 unit apart: far outside the GI tree's tolerance)."""
    camera = {"eye": [x, 1.0, 3.0], "target": [0.0, 0.5, 0.0], "up": [0.0, 1.0, 0.0], "fov": 60.0, "near": 0.05,
              "far": 50.0}  # fmt: skip
    return {"t_ms": 0.0, "camera": camera, "light": [1.0, 3.0, 1.0]}


@pytest.fixture
def run() -> Replayed:
    """Frames 0-5 of a page: frame 1 asks for a map (drawn after sending), 2 draws while it is made, 3 lands it
    (frame 1's view), 4 is idle and 5 asks again, its map landing after the replay; the camera moves on frames 1
    and 2 and stays from 3."""
    frames = [
        frame(0.0, pane(10.0)),
        frame(100.0, pane(50.0, sent=True, inflight=True)),
        frame(200.0, pane(12.0, inflight=True)),
        frame(300.0, pane(20.0, landed=True, shown=1)),
        frame(400.0, pane(9.0, shown=1)),
        frame(500.0, pane(40.0, sent=True, inflight=True, shown=1)),
    ]
    maps = [{"system": GIGAN, "frame": 1, "stages": {}, "total": 1.0}]
    views = [recorded(x) for x in (0.0, 1.0, 2.0, 2.0, 2.0, 2.0)]
    return Replayed.of(Segment("lan", (1, 6), (0, 1)), frames, maps, views)


def test_each_frame_falls_in_one_phase_and_a_request_frame_counts_without_the_request(run: Replayed) -> None:
    by_phase = phases(run, "gigan")
    assert by_phase["all"] == [50.0, 12.0, 20.0, 9.0, 40.0]
    assert by_phase["in_flight"] == [50.0 - 30.0, 12.0, 40.0 - 30.0]
    assert by_phase["landing"] == [20.0] and by_phase["idle"] == [9.0]


def test_frames_drawn_while_a_map_was_made_run_from_its_request_to_the_frame_before_it_landed(run: Replayed) -> None:
    assert frames_during(run, GIGAN) == {1: 2}


def test_perceived_latency_waits_for_the_first_frame_showing_a_map_of_the_view(run: Replayed) -> None:
    rows = perceived(run, GIGAN, gi_fov=90.0, n=16, cell_size=None)
    assert len(rows) == 2  # frames 1 and 2 moved the camera; 3-5 did not
    first, second = rows
    assert first["perceived_ms"] == pytest.approx(300.0 + 20.0 - 100.0)  # frame 3 showed frame 1's map
    assert first["in_tolerance"] == 0 and first["perceived_map"] == 1
    assert second["perceived_ms"] == ""  # no map of frame 2's view: censored
