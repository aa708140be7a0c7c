"""The cloud stages alone keep the loop's pace: a request leaves when the loop's frame would send it, so an idle
wait's wake-ups are in both measurements (or in neither, unpaced)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from time import sleep as time_sleep
from typing import Any

import numpy as np
import pytest

import baseline_cloudbaking.stages_alone as stages_alone
from gicore.camera import Camera
from gicore.gi_map import GIMap
from gicore.paths import path_views
from gicore.scene import load_scene


@dataclass
class Runs:
    """The fields :class:`stages_alone.AloneRuns` reads."""

    frame_rate: float
    every: int = 2
    composition: str = "blend"
    resolution: int = 8
    codec: str = "jpeg"
    spp: int = 1
    read_timeout_s: float = 5.0


class StampingSource:
    """A remote source that answers at once and keeps when each request left."""

    sent: list[float] = []

    def __init__(self, remote: Any) -> None:
        self.records: list[dict[str, Any]] = []
        self._latest: GIMap | None = None

    def __enter__(self) -> StampingSource:
        StampingSource.sent = []
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def warm_up(self, camera: Camera, light: Any) -> None:
        return None

    def request(self, camera: Camera, light: Any, frame: int) -> bool:
        StampingSource.sent.append(time.perf_counter())
        zeros = np.zeros((camera.height, camera.width), np.float32)
        self._latest = GIMap(camera, zeros[..., None].repeat(3, 2), zeros, frame=frame)
        self.records.append({"status": "ok", "latency_ms": 1.0})
        return True

    def wait(self, timeout: float) -> bool:
        return True

    def latest(self) -> GIMap | None:
        return self._latest


@pytest.mark.parametrize("frame_rate", [0.0, 40.0])
def test_requests_alone_leave_at_the_loops_pace(monkeypatch: pytest.MonkeyPatch, frame_rate: float) -> None:
    monkeypatch.setattr(stages_alone, "RemoteSource", StampingSource)
    slept: list[float] = []
    monkeypatch.setattr(stages_alone.time, "sleep", lambda s: slept.append(s) or time_sleep(s))
    spec = load_scene("lung_plane")
    views = path_views(spec, frames=9, orbit_frames=9, seed=0, fov=spec.camera.local_fov, resolution=8)
    _, maps = stages_alone.requests_alone("http://unused", "lung_plane", spec, Runs(frame_rate), views)
    since_first = np.subtract(StampingSource.sent, StampingSource.sent[0])
    assert len(maps) == 5 and len(since_first) == 5
    if frame_rate:  # request i at frame 2i, 2i / 40 s after the first (a sleep never ends early; 10 ms of slack
        # for the first request's own start)
        assert (since_first >= np.arange(5) * 2 / frame_rate - 0.01).all(), since_first
    else:  # back to back: nothing waits between the requests
        assert not [s for s in slept if s > 0], slept
