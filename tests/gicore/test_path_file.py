"""Path files (gigan-path/1): a round trip keeps every frame, the scripted path is the clients' fly-through, and
every malformed file is one error line naming the file and the frame."""

from __future__ import annotations

import copy
import json
import math
import os
import threading
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gicore import path_file
from gicore.camera import Camera
from gicore.error_policy import UserError
from gicore.path_file import (
    PathFile,
    Waypoint,
    flown_path,
    read_path_file,
    read_sessions,
    scripted_path,
    write_path_file,
)
from gicore.paths import light_position, navigation, outside_navigation, path_views
from gicore.scene import SceneSpec, load_scene


@pytest.fixture(scope="module")
def plane() -> SceneSpec:
    return load_scene("lung_plane")  # full circle, moving light


@pytest.fixture(scope="module")
def cornell() -> SceneSpec:
    return load_scene("lung_cornell")  # a 70° arc through the box's open side


def _recorded(spec: SceneSpec) -> PathFile:
    """Three frames as a person might fly them: off the scripted path, uneven times, the light moved by hand."""
    tx, ty, tz = spec.camera.target
    frames = []
    for i, (azimuth, radius, height) in enumerate([(10.0, 1.9, 1.2), (14.0, 1.8, 1.25), (20.0, 1.7, 1.3)]):
        a = math.radians(azimuth)
        eye = (tx + radius * math.sin(a), height, tz + radius * math.cos(a))
        res = spec.resolution
        camera = Camera(eye, (tx + 0.01 * i, ty, tz), fov=55.0, near=0.02, far=40.0, width=res, height=res)
        frames.append(Waypoint([0.0, 16.7, 50.1][i], camera, light_position(spec, 37 * i)))
    return PathFile(spec.name, tuple(frames), "recorded in gigan-web")


def test_a_written_path_reads_back_frame_for_frame(plane: SceneSpec, tmp_path: Path) -> None:
    session = _recorded(plane)
    written = write_path_file(tmp_path / "s.json", session.scene, session.frames, session.source)
    back = read_path_file(written, plane)
    assert back == session
    doc = json.loads(written.read_text())
    assert doc["format"] == "gigan-path/1" and doc["source"] == "recorded in gigan-web"
    assert set(doc["frames"][0]) == {"t_ms", "camera", "light"}
    assert set(doc["frames"][0]["camera"]) == {"eye", "target", "up", "fov", "near", "far"}
    # at another resolution, and at the GI FOV: the same views
    [(camera, light)] = back.views(64, fov=90.0)[1:2]
    assert (camera.width, camera.fov, camera.origin) == (64, 90.0, session.frames[1].camera.origin)
    assert light == session.frames[1].light


@pytest.mark.parametrize("scene", ["lung_plane", "lung_cornell"])
def test_the_scripted_path_is_the_clients_fly_through(scene: str, tmp_path: Path) -> None:
    spec = load_scene(scene)
    scripted = scripted_path(spec, 450, 300, seed=7, fov=50.0)  # more frames than a lap: the lap repeats
    assert scripted.frames[30].t_ms == pytest.approx(1000.0) and "seed 7" in scripted.source
    back = read_path_file(write_path_file(tmp_path / "p.json", spec.name, scripted.frames), spec)
    views = path_views(spec, 450, 300, 7, 50.0, 48)
    for (ours, light), (theirs, their_light) in zip(back.views(48), views, strict=True):
        assert np.allclose(ours.origin, theirs.origin, atol=1e-12, rtol=0)
        assert np.allclose(ours.target, theirs.target, atol=1e-12, rtol=0)
        assert (ours.up, ours.fov, ours.near, ours.far, ours.width) == (theirs.up, 50.0, theirs.near, theirs.far, 48)
        assert np.allclose(light, their_light, atol=1e-12, rtol=0)


def test_a_run_flies_its_path_file_or_the_scripted_path(plane: SceneSpec, tmp_path: Path) -> None:
    class Run:
        path: Path | None = None
        frames, orbit_frames = 4, 300

    assert flown_path(plane, Run(), seed=2) == scripted_path(plane, 4, 300, 2)
    session = _recorded(plane)
    Run.path = write_path_file(tmp_path / "s.json", session.scene, session.frames, session.source)
    assert flown_path(plane, Run(), seed=2) == session


def _doc(spec: SceneSpec) -> dict[str, Any]:
    return _recorded(spec).to_json()


def _frame(doc: dict[str, Any], i: int = 1) -> dict[str, Any]:
    return doc["frames"][i]


def _look_along(doc: dict[str, Any]) -> None:
    camera = _frame(doc)["camera"]
    camera["up"] = list(np.subtract(camera["target"], camera["eye"]))


def _bad_eye(spec: SceneSpec, radius: float, height: float, azimuth: float = 0.0) -> list[float]:
    tx, _, tz = spec.camera.target
    a = math.radians(azimuth)
    return [tx + radius * math.sin(a), height, tz + radius * math.cos(a)]


#: (case, how to break a good document, what the error line says)
BROKEN = [
    ("format", lambda d, s: d.update(format="gigan-path/2"), "format"),
    ("scene", lambda d, s: d.update(scene="lung_cornell"), "is for scene 'lung_cornell'"),
    ("top key missing", lambda d, s: d.pop("frames"), "lacks frames"),
    ("top key extra", lambda d, s: d.update(fps=30), "unknown key"),
    ("source not text", lambda d, s: d.update(source=3), "source is not text"),
    ("no frames", lambda d, s: d.update(frames=[]), "has 0 frames"),
    ("frames not a list", lambda d, s: d.update(frames={}), "frames not a list"),
    ("frame key missing", lambda d, s: _frame(d).pop("light"), "frame 1: the frame lacks light"),
    ("frame key extra", lambda d, s: _frame(d).update(shadow={}), "frame 1: the frame has unknown key"),
    ("camera key missing", lambda d, s: _frame(d)["camera"].pop("near"), "frame 1: its camera lacks near"),
    ("camera key extra", lambda d, s: _frame(d)["camera"].update(view=[]), "frame 1: its camera has unknown key"),
    ("not a number", lambda d, s: _frame(d)["camera"].update(fov="wide"), "frame 1: camera.fov is not a number"),
    ("a bool", lambda d, s: _frame(d).update(t_ms=True), "frame 1: t_ms is not a number"),
    ("non-finite", lambda d, s: _frame(d)["camera"]["eye"].__setitem__(0, math.nan), "camera.eye[0] is not finite"),
    ("huge", lambda d, s: _frame(d).update(t_ms=10**400), "frame 1: t_ms is not finite"),
    ("short vector", lambda d, s: _frame(d).update(light=[1.0, 2.0]), "frame 1: light is not a list of 3"),
    ("eye == target", lambda d, s: _frame(d)["camera"].update(target=_frame(d)["camera"]["eye"]), "camera.eye and"),
    ("up parallel", lambda d, s: _look_along(d), "camera.up"),
    ("up zero", lambda d, s: _frame(d)["camera"].update(up=[0, 0, 0]), "camera.up [0.0, 0.0, 0.0] has no length"),
    ("eye far out", lambda d, s: _frame(d)["camera"].update(eye=[1e308, 1.2, 0]), "camera.eye [1e+308, 1.2, 0.0] lies"),
    ("fov 0", lambda d, s: _frame(d)["camera"].update(fov=0.0), "camera.fov"),
    ("fov 180", lambda d, s: _frame(d)["camera"].update(fov=180.0), "camera.fov"),
    ("fov too narrow", lambda d, s: _frame(d)["camera"].update(fov=1e-300), "camera.fov"),
    ("near 0", lambda d, s: _frame(d)["camera"].update(near=0.0), "camera.near/far"),
    ("far < near", lambda d, s: _frame(d)["camera"].update(far=0.01), "camera.near/far"),
    ("far too far", lambda d, s: _frame(d)["camera"].update(far=1e31), "camera.near/far"),
    (
        "light outside",
        lambda d, s: _frame(d).update(light=[0.0, 2.0, 3.0]),
        "frame 1: light [0.0, 2.0, 3.0] is outside",
    ),
    ("eye too far", lambda d, s: _frame(d)["camera"].update(eye=_bad_eye(s, 2.5, 1.2)), "its radius 2.5 is outside"),
    ("eye too high", lambda d, s: _frame(d)["camera"].update(eye=_bad_eye(s, 1.8, 2.0)), "its height 2 is outside"),
    ("t_ms decreasing", lambda d, s: _frame(d, 2).update(t_ms=10.0), "frame 2: t_ms 10 is before"),
]


@pytest.mark.parametrize(("case", "breaks", "says"), BROKEN, ids=[b[0] for b in BROKEN])
def test_every_malformed_path_is_one_error_line(plane: SceneSpec, tmp_path: Path, case, breaks, says) -> None:
    doc = copy.deepcopy(_doc(plane))
    breaks(doc, plane)
    file = tmp_path / "bad.json"
    file.write_text(json.dumps(doc))
    with pytest.raises(UserError) as err:
        read_path_file(file, plane)
    what, todo = err.value.args
    assert str(file) in what and says in what, what
    assert "\n" not in what + todo


def test_an_eye_outside_the_arc_is_refused_and_one_at_its_edge_is_not(cornell: SceneSpec, tmp_path: Path) -> None:
    nav = navigation(cornell)
    assert nav["azimuth"] == [-35.0, 35.0]
    margin = path_file.NAVIGATION_MARGIN * cornell.camera.radius
    assert outside_navigation(nav, _bad_eye(cornell, 1.9, 1.2, 35.0), margin) is None
    assert outside_navigation(nav, _bad_eye(cornell, 1.9, 1.2, -35.5), margin) is None  # within the margin
    assert "azimuth -40" in outside_navigation(nav, _bad_eye(cornell, 1.9, 1.2, -40.0), margin)
    assert "azimuth 180" in outside_navigation(nav, _bad_eye(cornell, 1.9, 1.2, 180.0), margin)
    doc = _doc(cornell)
    doc["frames"][0]["camera"]["eye"] = _bad_eye(cornell, 1.9, 1.2, 60.0)
    file = tmp_path / "behind.json"
    file.write_text(json.dumps(doc))
    with pytest.raises(UserError, match="frame 0: camera.eye .* navigable envelope: its azimuth 60"):
        read_path_file(file, cornell)


def test_a_static_light_must_stay_at_rest(plane: SceneSpec, tmp_path: Path) -> None:
    static = plane.model_copy(update={"light": plane.light.model_copy(update={"amplitude": (0.0, 0.0)})})
    doc = _doc(static)
    rest = list(static.light.position)
    for frame in doc["frames"]:
        frame["light"] = rest
    file = tmp_path / "static.json"
    file.write_text(json.dumps(doc))
    assert read_path_file(file, static).frames[0].light == tuple(rest)
    doc["frames"][2]["light"] = [rest[0] + 0.01, rest[1], rest[2]]
    file.write_text(json.dumps(doc))
    with pytest.raises(UserError, match="frame 2: light .* is outside"):
        read_path_file(file, static)


def test_unreadable_oversized_and_overlong_files_are_one_error_line(
    plane: SceneSpec, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cases = {
        "missing.json": None,
        "garbage.json": b"{not json",
        "binary.json": b"\xff\xfe\x00",
        "digits.json": b'{"format": ' + b"7" * 5000 + b"}",  # past Python's 4300-digit limit on int()
    }
    for name, data in cases.items():
        if data is not None:
            (tmp_path / name).write_bytes(data)
        with pytest.raises(UserError, match=f"path file {tmp_path / name}"):
            read_path_file(tmp_path / name, plane)
    good = write_path_file(tmp_path / "good.json", plane.name, _recorded(plane).frames)
    monkeypatch.setattr(path_file, "FRAMES_MAX", 2)
    with pytest.raises(UserError, match="has 3 frames") as err:
        read_path_file(good, plane)
    assert "1 to 2 frames" in err.value.args[1]
    monkeypatch.setattr(path_file, "PATH_BYTES_MAX", 100)  # the read stops there, whatever the file's size
    with pytest.raises(UserError, match="is over"):
        read_path_file(good, plane)


def test_a_session_folder_is_read_by_scene(plane: SceneSpec, cornell: SceneSpec, tmp_path: Path) -> None:
    for name, spec in (("b.json", plane), ("a.json", plane), ("c.json", cornell)):
        write_path_file(tmp_path / name, spec.name, _recorded(spec).frames, name)
    (tmp_path / "notes.txt").write_text("not a session")
    sessions = read_sessions(tmp_path, [plane, cornell])
    assert [p.source for p in sessions["lung_plane"]] == ["a.json", "b.json"]  # name order
    assert [p.source for p in sessions["lung_cornell"]] == ["c.json"]
    with pytest.raises(UserError, match="c.json is for scene 'lung_cornell', not one of lung_plane"):
        read_sessions(tmp_path, [plane])
    with pytest.raises(UserError, match="has no session of vessels_plane"):
        read_sessions(tmp_path, [plane, cornell, load_scene("vessels_plane")])
    with pytest.raises(UserError, match="holds no \\*.json path files"):
        read_sessions(tmp_path / "nowhere", [plane])


#: Seconds a read of a FIFO may take before the test calls it waiting for a writer (a hang guard: it is refused
#: at once).
FIFO_GUARD_S = 60.0


def test_a_file_that_is_not_regular_is_refused_without_waiting(plane: SceneSpec, tmp_path: Path) -> None:
    """A FIFO (opened, it would wait for a writer for ever), given as --path or in a session folder."""
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    for read in (lambda: read_path_file(fifo, plane), lambda: read_sessions(tmp_path, [plane])):
        outcome: list[BaseException | None] = []
        reader = threading.Thread(target=lambda read=read: outcome.append(_raised(read)))
        reader.start()
        reader.join(FIFO_GUARD_S)
        if reader.is_alive():  # let it go: a writer opens the FIFO and closes it at once
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
            pytest.fail("reading the FIFO waited for a writer")
        assert isinstance(outcome[0], UserError) and f"{fifo} is not a regular file" in str(outcome[0]), outcome


def _raised(call: Any) -> BaseException | None:
    try:
        call()
    except BaseException as err:  # noqa: BLE001 - the test looks at what it was
        return err
    return None


def test_millions_of_empty_frames_are_refused_before_they_are_parsed(plane: SceneSpec, tmp_path: Path) -> None:
    """2 million empty frames (6 MB): refused on their count, before parsing makes a dict of each (which took
    some 20 times the file's size)."""
    file = tmp_path / "empty_frames.json"
    file.write_bytes(b'{"format": "gigan-path/1", "scene": "lung_plane", "frames": [' + b"{}," * 2_000_000 + b"{}]}")
    tracemalloc.start()
    try:
        with pytest.raises(UserError, match=f"holds more than {path_file.FRAMES_MAX} frames"):
            read_path_file(file, plane)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 3 * file.stat().st_size, peak


def test_a_scene_that_is_no_name_is_refused_in_a_session_folder(plane: SceneSpec, tmp_path: Path) -> None:
    for scene in ([1, 2], {"name": "lung_plane"}, None, 3):
        doc = _doc(plane) | {"scene": scene}
        (tmp_path / "s.json").write_text(json.dumps(doc))
        with pytest.raises(UserError, match="s.json is for scene .*, not one of lung_plane"):
            read_sessions(tmp_path, [plane])
