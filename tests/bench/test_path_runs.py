"""Runs that fly a path file: `gigan-client --path` on a recorded-style session of 3 frames (it writes back the
path it flew), `bench latency --path` (every client gets the file, the bench counts its frames) and
`bench storage --sessions-from` (recorded sessions are the growth law's sessions); a path file a bench refuses is
one error line that leaves no folder behind."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from baseline_cloudbaking.growth import fill_sessions, session_frames
from bench import latency
from bench.latency import LatencyConfig
from bench.runner import build_config
from bench.storage_config import StorageConfig
from bench.storage_growth import measure_growth
from gicore.camera import Camera
from gicore.error_policy import UserError
from gicore.path_file import Waypoint, read_path_file, write_path_file
from gicore.paths import light_position
from gicore.results import Results, read_rows
from gicore.scene import SceneSpec, load_scene
from tests.helpers.cli import check_user_error, run_main, run_script
from tests.helpers.cloud import write_scenes
from tests.helpers.guards import HANG_GUARD_S
from tests.helpers.latency_runs import stand_in

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``ball_moving``: a 70° arc in a Cornell box, light moving (tests.helpers.cloud)."""
    return write_scenes(tmp_path_factory.mktemp("scenes")) / "ball_moving.json"


def _session(spec: SceneSpec, file: Path, start_deg: float = 0.0, frames: int = 3) -> Path:
    """A session as the viewer records one: eyes off the scripted path, uneven times, the light's schedule."""
    tx, ty, tz = spec.camera.target
    points = []
    for i in range(frames):
        a = math.radians(start_deg + 4.0 * i)
        eye = (tx + 1.9 * math.sin(a), 1.15, tz + 1.9 * math.cos(a))
        camera = Camera(eye, (tx, ty + 0.01 * i, tz), fov=spec.camera.local_fov, near=0.05, far=20.0)
        points.append(Waypoint(17.0 * i + (5.0 if i else 0.0), camera, light_position(spec, 11 * i)))
    return write_path_file(file, spec.name, points, "recorded in gigan-web")


def test_gigan_client_flies_a_path_file_and_writes_it_back(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    spec = load_scene(scene)
    session = _session(spec, tmp_path / "session.json")
    base = ["gigan-client", "--scene", str(scene), "--path", str(session), "--resolution", "16",
            "-k", "2", "--gi-source", "gt", "--spp", "1", "--no-denoise", "--renderer", "mitsuba"]  # fmt: skip
    run = subprocess.run([str(BIN / base[0]), *base[1:], "--out", str(tmp_path / "run")], capture_output=True,
                         text=True, timeout=HANG_GUARD_S)  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("3 frames,"), run.stdout
    with (tmp_path / "run" / "frames.csv").open() as fh:
        assert [row["frame"] for row in csv.DictReader(fh)] == ["0", "1", "2"]
    flown = read_path_file(tmp_path / "run" / "path.json", spec)
    assert flown == read_path_file(session, spec)  # replaying the run's path.json flies the same session
    clash = run_main([*base, "--frames", "5", "--out", str(tmp_path / "clash")], tmp_path, monkeypatch, capfd)
    line = check_user_error(clash, "--path and --frames conflict")  # in-process: the same policy, no new interpreter
    assert line == "error: --path and --frames conflict: --path sets what --frames would: drop --frames"
    assert not (tmp_path / "clash").exists()


def test_bench_latency_gives_every_client_the_path_file(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The processes are stood in for: what is checked is what each client and the prefill are told."""
    spec = load_scene(scene)
    session = _session(spec, tmp_path / "session.json")
    told = stand_in(monkeypatch)
    argvs, asked, recorded = told.argvs, told.asked, told.recorded
    cfg = LatencyConfig(scenes=(str(scene),), profiles=("lan",), resolution=16, path=session, renderers=("mitsuba",),
                        prefetch_in_flight=1, alone=False)  # fmt: skip  # the stages alone run in this process
    latency.measure(cfg, Results("latency", tmp_path / "out", 0))
    assert len(argvs) == 4  # gigan, cloud on the prebaked store, its prefetching twin, cloud on a cold store
    for argv in argvs:
        assert argv[argv.index("--path") + 1] == str(session), argv
        assert "--frames" not in argv and "--orbit-frames" not in argv
    assert asked and all(c.path == session and c.frames == 3 for c in asked)
    assert recorded["cfg"].frames == recorded["common"]["frames"] == 3
    with pytest.raises(UserError, match="--path and --orbit-frames conflict"):
        build_config(LatencyConfig, False, {"path": str(session), "orbit_frames": "90"})


def test_a_refused_path_file_leaves_no_output_folder(scene: Path, tmp_path: Path) -> None:
    """The file is read where the run's work folder would be made: refused, nothing under --out (nor --out)."""
    spec = load_scene(scene)
    session = _session(spec, tmp_path / "session.json")
    doc = json.loads(session.read_text())
    doc["frames"][1]["camera"]["up"] = [0, 0, 0]
    session.write_text(json.dumps(doc))
    for bench in ("latency", "prefetch", "web"):
        argv = ["bench", bench, "--scenes", str(scene), "--path", "session.json", "--out", "out/deeper"]
        check_user_error(run_script(argv, tmp_path), "session.json: frame 1: camera.up")


def test_bench_storage_grows_its_tree_along_recorded_sessions(scene: Path, tmp_path: Path) -> None:
    spec = load_scene(scene)
    folder = tmp_path / "sessions"
    folder.mkdir()
    files = [_session(spec, folder / f"s{k}.json", start_deg=-30.0 + 22.5 * k, frames=3 + k) for k in range(3)]
    cfg = StorageConfig(scenes=(str(scene),), resolutions=(16,), codecs=("jpeg",), spp=1, growth_samples=1,
                        capacity_samples=10, paper_resolution=16, sessions_from=folder,
                        map_cache=tmp_path / "maps")  # fmt: skip
    res = Results("storage", tmp_path / "out", 0)
    measure_growth(cfg, res, str(scene), {"fp16": 10_000}, {})
    rows = read_rows(res.write())
    curve = {r["config"]["sessions"]: r for r in rows if r["metric"] == "growth_entries"}
    [store] = [r for r in rows if r["metric"] == "saturation_sessions" and r["config"]["tolerance"] == "store"]
    flown = [read_path_file(f, spec) for f in files]
    expected = fill_sessions(session_frames(spec, flown, cfg.light_cell, spec.camera.gi_fov), cfg.tolerance).entries
    store_curve = [r for r in rows if r["metric"] == "growth_entries" and r["config"]["tolerance"] == "store"]
    assert [r["value"] for r in sorted(store_curve, key=lambda r: r["config"]["sessions"])] == list(expected)
    assert set(curve) == {1, 2, 3} and store["config"]["users"] == 1
    assert store["config"]["sessions_run"] == 3 and store["config"]["sessions_from"] == str(folder)
    assert store["config"]["session_frames"] == 4  # the sessions' mean length
    # a session of another scene, and the options the sessions replace, are one error line each
    given = {"scenes": str(scene), "sessions_from": str(folder)}
    _session(load_scene(scene.with_name("ball_static.json")), folder / "other.json")
    with pytest.raises(UserError, match="other.json is for scene 'ball_static', not one of ball_moving"):
        build_config(StorageConfig, False, given)
    with pytest.raises(UserError, match="--sessions-from and --users conflict"):
        build_config(StorageConfig, False, given | {"users": "2"})
