"""Tidy, long-format benchmark results with provenance (docs/architecture.md, Results files).

Every bench writes ``<out>/<bench>.csv`` with one row per measurement and ``<out>/<bench>.provenance.json``
describing how the numbers were produced (:class:`Results`). Plots and dashboards read only these files
(:func:`find_results`, :func:`load_results`, :func:`read_provenance`).

CSV columns: ``run_id, bench, system, scene, metric, stat, value, unit, config`` where ``stat`` says what
the value summarises (``value`` for a single measurement, ``median``/``p95``/``n`` for repeated timings)
and ``config`` is a compact JSON object of the knobs that produced the row (spp, denoise, k, ...).
"""

from __future__ import annotations

import csv
import fnmatch
import io
import json
import os
import platform
import shutil
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from gicore.fileio import atomic_write_bytes

COLUMNS = ("run_id", "bench", "system", "scene", "metric", "stat", "value", "unit", "config")
_PACKAGES = (
    "numpy",
    "torch",
    "mitsuba",
    "drjit",
    "onnxruntime",
    "scikit-image",
    "pyoidn",
    "fastapi",
    "uvicorn",
    "httpx",
    "zstandard",
    "pillow",
)


def git_revision() -> dict[str, Any]:
    """Commit SHA of the working tree and whether it had uncommitted changes."""
    root = Path(__file__).resolve().parent.parent
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = bool(
            subprocess.run(
                ["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True, text=True
            ).stdout.strip()
        )
    except (OSError, subprocess.CalledProcessError):
        return {"sha": None, "dirty": None}
    return {"sha": sha, "dirty": dirty}


def machine_info() -> dict[str, Any]:
    cpu = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "gpu": _nvidia_gpu(),
    }


def _nvidia_gpu() -> str | None:
    """The name of the first NVIDIA GPU ``nvidia-smi`` lists (None: none, or no nvidia-smi)."""
    if shutil.which("nvidia-smi") is None:
        return None
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=20, check=True).stdout  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    return out.strip().splitlines()[0] if out.strip() else None


def machine_text(info: dict[str, Any] | None = None) -> str:
    """A machine (default: this one, :func:`machine_info`) in a few words: its CPU, cores and GPU."""
    info = info or machine_info()
    return f"{info['cpu']}, {info['cpu_count']} cores" + (f", {info['gpu']}" if info.get("gpu") else "")


def package_versions() -> dict[str, str | None]:
    versions: dict[str, str | None] = {}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


@dataclass
class Results:
    """Collects rows for one bench run and writes CSV + provenance JSON on :meth:`write`. A row is as
    :func:`read_rows` gives it back, its ``config`` a dict (JSON in the CSV).

    ``settings`` is the run's final configuration (what the provenance records); ``files`` are the other
    files the run wrote, each named through :meth:`output`.
    """

    bench: str
    out: Path
    seed: int = 0
    settings: dict[str, Any] = field(default_factory=dict)
    run_id: str = field(default_factory=lambda: time.strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:6])
    rows: list[dict[str, Any]] = field(default_factory=list)
    started: float = field(default_factory=time.time)
    files: list[Path] = field(default_factory=list)

    def output(self, name: str) -> Path:
        """The path of an extra file ``name`` in the output folder (a table, an image grid), recorded in
        :attr:`files` and in the provenance."""
        path = self.out / name
        self.files.append(path)
        return path

    def add(
        self, *, system: str, scene: str, metric: str, value: float, unit: str, stat: str = "value", **config: Any
    ) -> None:
        self.rows.append(
            {
                "run_id": self.run_id,
                "bench": self.bench,
                "system": system,
                "scene": scene,
                "metric": metric,
                "stat": stat,
                "value": value,
                "unit": unit,
                "config": config,
            }
        )

    def add_timing(self, *, system: str, scene: str, metric: str, samples_s: list[float], **config: Any) -> None:
        """Median and p95 (ms) of repeated timings taken after warm-up, plus the repeat count."""
        from gicore.timing import summarize_ms

        summary = summarize_ms(samples_s)
        for stat in ("median", "p95"):
            self.add(system=system, scene=scene, metric=metric, value=summary[stat], unit="ms", stat=stat, **config)
        self.add(system=system, scene=scene, metric=metric, value=len(samples_s), unit="count", stat="n", **config)

    @property
    def csv_path(self) -> Path:
        return self.out / f"{self.bench}.csv"

    @property
    def provenance_path(self) -> Path:
        return self.out / f"{self.bench}.provenance.json"

    def write(self) -> Path:
        """Write ``<bench>.csv`` and ``<bench>.provenance.json`` (each atomically); returns the CSV path."""
        self.out.mkdir(parents=True, exist_ok=True)
        text = io.StringIO(newline="")
        writer = csv.DictWriter(text, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(
            r | {"config": json.dumps(r["config"], sort_keys=True, separators=(",", ":"))} for r in self.rows
        )
        atomic_write_bytes(self.csv_path, text.getvalue().encode())
        provenance = {
            "run_id": self.run_id,
            "bench": self.bench,
            "argv": sys.argv,
            "seed": self.seed,
            "settings": self.settings,
            "git": git_revision(),
            "versions": package_versions(),
            "machine": machine_info(),
            "started_unix": self.started,
            "finished_unix": time.time(),
            "rows": len(self.rows),
            "files": [str(p) for p in self.files],
        }
        atomic_write_bytes(self.provenance_path, json.dumps(provenance, indent=1, default=str).encode())
        return self.csv_path


def read_rows(path: Path) -> list[dict[str, Any]]:
    """Rows of a results CSV with ``value`` as float and ``config`` decoded."""
    with Path(path).open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    for row in rows:
        row["value"] = float(row["value"])
        row["config"] = json.loads(row["config"]) if row["config"] else {}
    return rows


# -- reading results back -------------------------------------------------------------------------------------


class Malformed(ValueError):
    """A CSV that is not a bench's tidy result."""


def read_provenance(csv_path: Path) -> dict[str, Any] | None:
    """The provenance JSON beside ``csv_path`` (``<bench>.provenance.json``), or None without a readable one."""
    path = csv_path.with_name(csv_path.stem + ".provenance.json")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _finished(csv_path: Path) -> float:
    prov = read_provenance(csv_path) or {}
    value = prov.get("finished_unix")
    return float(value) if isinstance(value, (int, float)) else csv_path.stat().st_mtime


def find_results(results: Path, bench: str, ignore: tuple[str, ...] = ()) -> list[Path]:
    """Every ``<bench>.csv`` under ``results``, newest run first, except those inside a folder that one of the
    ``ignore`` patterns (paths relative to ``results``, glob allowed) names."""

    def ignored(path: Path) -> bool:
        folders = [f.as_posix() for f in path.relative_to(results).parents if f != Path(".")]
        return any(fnmatch.fnmatchcase(folder, pattern.strip("/")) for folder in folders for pattern in ignore)

    return sorted((p for p in results.rglob(f"{bench}.csv") if not ignored(p)), key=_finished, reverse=True)


def load_results(path: Path) -> list[dict[str, Any]]:
    """The rows of a results CSV, or :class:`Malformed` saying what is wrong with it."""
    try:
        with path.open(newline="") as fh:
            header = next(csv.reader(fh), None)
        if header != list(COLUMNS):
            raise Malformed(f"its columns are {header}, not {', '.join(COLUMNS)}")
        rows = read_rows(path)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise Malformed(f"it cannot be read ({exc})") from None
    except (KeyError, ValueError, TypeError) as exc:
        raise Malformed(f"a row does not parse ({type(exc).__name__}: {exc})") from None
    if not rows:
        raise Malformed("it has no rows")
    if any(not isinstance(r["config"], dict) for r in rows):
        raise Malformed("a config cell is not a JSON object")
    return rows


def provenance_fields(csv_path: Path) -> dict[str, str] | None:
    """What the provenance JSON beside ``csv_path`` says, as text: the command (the program by its name, not
    the path it was started by, and its arguments), git (short SHA; whether the tree had uncommitted
    changes), machine, date, run and seed; None without one."""
    prov = read_provenance(csv_path)
    if prov is None:
        return None
    argv = [str(a) for a in prov.get("argv") or []]
    if argv:
        argv[0] = "bench" if Path(argv[0]).name == "__main__.py" else Path(argv[0]).name
    git = prov.get("git") or {}
    m = prov.get("machine") or {}
    finished = prov.get("finished_unix")
    cpu = f"{m.get('cpu', '?')}, {m.get('cpu_count', '?')} cores"
    return {
        "command": " ".join(argv) or "(unknown)",
        "git": (git.get("sha") or "unknown")[:12] + (" (uncommitted changes)" if git.get("dirty") else ""),
        "machine": f"{cpu}, {m.get('platform', '?')}, Python {m.get('python', '?')}",
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(finished))
        if isinstance(finished, (int, float))
        else "unknown",
        "run": str(prov.get("run_id", "?")),
        "seed": str(prov.get("seed", "?")),
    }
