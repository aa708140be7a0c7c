"""Both clients' --gt-cache: a file where the folder belongs, or a place no folder can be made, is one error line
naming the option, before any frame is path-traced and with nothing written."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

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
