"""gigan-client's --gt-cache: a file where the folder belongs, or a place no folder can be made, is one error line
naming the option, before any frame is path-traced and with nothing written."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tests.helpers.cli import check_user_error, run_script

RUN = [
    "gigan-client",
    "--scene",
    "lung_plane",
    "--frames",
    "1",
    "--with-gt",
    "--resolution",
    "16",
    "--spp",
    "1",
    "--no-denoise",
]


def test_a_gt_cache_that_cannot_be_a_folder_is_one_error_line(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("a file where a folder belongs\n")
    caches = ["afile", "afile/sub"]
    with ThreadPoolExecutor(len(caches)) as pool:
        outcomes = list(pool.map(lambda c: run_script([*RUN, "--gt-cache", c, "--out", "out"], tmp_path), caches))
    for outcome, cache in zip(outcomes, caches):
        line = check_user_error(outcome, f"--gt-cache {cache}")
        assert "folder" in line
