"""A client run's files read back (:mod:`gicore.frame_rows`): the scored frames' SSIM and the run's summary."""

from __future__ import annotations

import json
from pathlib import Path

from gicore.frame_rows import read_csv_rows, read_summary, scored_ssim, write_rows


def test_the_scored_frames_ssim_by_frame(tmp_path: Path) -> None:
    """Frames scored against the GT, by frame and in order; unscored ones (an empty cell) left out."""
    rows = [{"frame": f, "ssim": s} for f, s in ((0, 0.9), (1, ""), (2, 0.75), (3, ""))]
    written = read_csv_rows(write_rows(rows, tmp_path / "frames.csv"))
    assert scored_ssim(written) == scored_ssim(rows) == {0: 0.9, 2: 0.75}
    assert scored_ssim([{"frame": "0", "di_ms": "1.0"}]) == {}  # a run that scored nothing has no SSIM column


def test_the_runs_summary(tmp_path: Path) -> None:
    (tmp_path / "summary.json").write_text(json.dumps({"frames": 3, "renderer": "gl"}))
    assert read_summary(tmp_path) == {"frames": 3, "renderer": "gl"}
