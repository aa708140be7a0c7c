"""Both clients' --gt-cache: a file where the folder belongs, or a place no folder can be made, is one error line
naming the option, before any frame is path-traced and with nothing written; so is a field of view too narrow for
the renderer, given as an option or in a path file."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from gicore.path_file import scripted_path
from gicore.scene import load_scene
from tests.helpers.cli import check_user_error, run_script

PATH_RUN = [
    "--scene",
    "lung_plane",
    "--frames",
    "1",
    "--gt-every",
    "1",
    "--resolution",
    "16",
    "--spp",
    "1",
    "--no-denoise",
]
#: Both clients share the option (gicore.run_config.PathRunConfig); the cloud client's server is never asked.
CLIENTS = [["gigan-client", *PATH_RUN], ["cloudbaking-client", "--server", "http://127.0.0.1:9", *PATH_RUN]]


def test_a_gt_cache_that_cannot_be_a_folder_is_one_error_line(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("a file where a folder belongs\n")
    cases = [(client, cache) for client in CLIENTS for cache in ("afile", "afile/sub")]
    with ThreadPoolExecutor(len(cases)) as pool:
        outcomes = list(
            pool.map(lambda case: run_script([*case[0], "--gt-cache", case[1], "--out", "out"], tmp_path), cases)
        )
    for outcome, (client, cache) in zip(outcomes, cases):
        line = check_user_error(outcome, f"--gt-cache {cache}")
        assert "folder" in line, (client[0], line)


def test_a_field_of_view_too_narrow_to_render_is_one_error_line(tmp_path: Path) -> None:
    """1e-300 degrees: its focal factor 1/tan(fov/2) is past what the renderer represents (it overflowed in the
    level-of-detail model, a traceback)."""
    doc = scripted_path(load_scene("lung_plane"), 2, 300).to_json()
    doc["frames"][1]["camera"]["fov"] = 1e-300
    (tmp_path / "narrow.json").write_text(json.dumps(doc))
    cases = [(client, option) for client in CLIENTS for option in ("--local-fov", "--gi-fov")]
    argvs = [[*client, option, "1e-300", "--out", "out"] for client, option in cases]
    for client in CLIENTS:  # the path file gives the frames
        at = client.index("--frames")
        argvs.append([*client[:at], *client[at + 2 :], "--path", "narrow.json", "--out", "out"])
    with ThreadPoolExecutor(2) as pool:
        outcomes = list(pool.map(lambda argv: run_script(argv, tmp_path), argvs))
    for outcome, culprit in zip(outcomes, ["fov = 1e-300"] * 4 + ["narrow.json: frame 1: camera.fov"] * 2):
        check_user_error(outcome, culprit)
