"""A client run's per-frame rows (:meth:`gicore.loop.ClientLoop.columns`): the run's summary (amortised frame
rate, medians, mean quality) and the rows as CSV, written and read back with the run's ``summary.json``.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from gicore.fileio import atomic_write_bytes


def _values(rows: Iterable[dict[str, Any]], column: str) -> list[float]:
    return [float(r[column]) for r in rows if r.get(column, "") != ""]


def amortized_fps(rows: list[dict[str, Any]], every: int) -> dict[str, float]:
    """Frame rate with the GI-map cost spread over its ``every`` frames.

    ``local_ms``: median per-frame work other than waiting for and binding maps; ``gi_ms``: mean cost of
    one map (producing it, :attr:`GIMap.stages`, plus binding it); ``fps = 1000 / (local_ms + gi_ms /
    every)``.
    """
    local = [float(r["frame_ms"]) - float(r["gi_wait_ms"]) - float(r.get("bind_ms") or 0.0) for r in rows]
    per_map = [float(r["gi_ms"]) + float(r.get("bind_ms") or 0.0) for r in rows if r["gi_new"]]
    local_ms = float(np.median(local))
    gi_ms = float(np.mean(per_map)) if per_map else 0.0
    return {"local_ms": local_ms, "gi_ms": gi_ms, "fps": 1000.0 / (local_ms + gi_ms / every)}


def summarize(rows: list[dict[str, Any]], every: int) -> dict[str, Any]:
    """Amortised fps, median of every ``*_ms`` column and of the map's age, mean quality (SSIM, PSNR,
    low-frequency error) of scored frames."""
    out: dict[str, Any] = amortized_fps(rows, every)
    columns = [c for c in rows[0] if c.endswith("_ms")] + ["gi_age_frames"]
    out["median"] = {c: float(np.median(v)) for c in columns if (v := _values(rows, c))}
    out["mean_valid_frac"] = float(np.mean(_values(rows, "valid_frac")))
    ssims = _values(rows, "ssim")
    if ssims:
        out["mean_ssim"] = float(np.mean(ssims))
        finite = [p for p in _values(rows, "psnr") if math.isfinite(p)]
        out["mean_psnr"] = float(np.mean(finite)) if finite else math.inf
        out["mean_lf_error"] = float(np.mean(_values(rows, "lf_error")))
    return out


def write_rows(rows: list[dict[str, Any]], path: Path) -> Path:
    """The per-frame rows as CSV (columns in the rows' order), written atomically."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_bytes(path, buffer.getvalue().encode())


def read_csv_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a client run's CSV (``frames.csv``, ``requests.csv``) as text, an empty cell ``""``."""
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def read_summary(folder: Path) -> dict[str, Any]:
    """The ``summary.json`` a client run wrote under ``folder`` (``gigan-client``'s or ``cloudbaking-client``'s)."""
    return json.loads((folder / "summary.json").read_text())


def scored_ssim(rows: Iterable[dict[str, Any]]) -> dict[int, float]:
    """SSIM of each frame scored against the GT (``--gt-every``), by frame, in the rows' order."""
    return {int(r["frame"]): float(r["ssim"]) for r in rows if r.get("ssim", "") != ""}
