"""`bench storage`'s growth law: the GI tree under many user sessions (:mod:`gicore.sessions`, or recorded path
files), filled by the store's own lookup rule (:mod:`baseline_cloudbaking.growth`); its saturation, the sessions
until it passes the model or the paper's figure, bytes per entry measured on maps baked at entries spread over
the tree; and the paper's accounting along the fly-through, decomposed."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from baseline_cloudbaking.bake import PathFrame
from baseline_cloudbaking.growth import (
    SessionFill,
    capacity,
    entry_bytes,
    fill_sessions,
    first_session_over,
    saturation_session,
    session_frames,
)
from baseline_cloudbaking.viewpoints import simulate_fill
from bench.storage_config import PAPER_TABLE2_GB, PAPER_TOLERANCE, RAW_CODEC, StorageConfig
from gicore.camera import Camera
from gicore.path_file import PathFile, read_sessions
from gicore.paths import Light
from gicore.results import Results
from gicore.scene import SceneSpec, load_scene
from gicore.sessions import plan_sessions

SYSTEM = "cloud_baking"


def add_entry_bytes(add: Callable[..., None], metric: str, values: Sequence[float], **row: Any) -> tuple[int, float]:
    """``metric`` rows of bytes per entry: mean, std and n of ``values``; returns (n, std)."""
    v = np.asarray(values, dtype=np.float64)
    std = float(v.std(ddof=1)) if len(v) > 1 else 0.0
    for stat, value, unit in (("mean", float(v.mean()), "bytes"), ("std", std, "bytes"), ("n", len(v), "count")):
        add(metric=metric, value=value, unit=unit, stat=stat, **row)
    return len(v), std


def _growth_entry_bytes(
    cfg: StorageConfig, spec: SceneSpec, name: str, creators: list[tuple[Camera, Light]], seed: int
) -> dict[tuple[int, str], list[int]]:
    """Bytes per entry of the growth law (:func:`baseline_cloudbaking.growth.entry_bytes`) per (resolution, codec),
    the uncompressed RGB8 maps' under :data:`RAW_CODEC`."""
    sizes = entry_bytes(
        spec, name, creators, cfg.resolutions, cfg.codecs, spp=cfg.spp, samples=cfg.growth_samples,
        cache=cfg.map_cache, seed=seed,
    )  # fmt: skip
    return {(resolution, codec or RAW_CODEC): values for (resolution, codec), values in sizes.items()}


def _growth_sessions_grid(n: int) -> list[int]:
    """Session counts at which byte curves are written: about 24, log-spaced, always 1 and n."""
    return sorted({int(round(x)) for x in np.geomspace(1, n, min(n, 24))} | {1, n})


class GrowthSessions(NamedTuple):
    """The sessions of ``spec``'s growth law: ``cfg`` as it runs them, the recorded sessions (None: seeded
    ones), each session's frames, and the key of the fill they make (:func:`growth_sessions`)."""

    cfg: StorageConfig
    recorded: list[PathFile] | None
    frames: int | np.ndarray
    space: str


def growth_sessions(cfg: StorageConfig, spec: SceneSpec) -> GrowthSessions:
    """The seeded sessions of ``cfg``, or with ``cfg.sessions_from`` the recorded ones of ``spec``: one curve, of
    as many sessions as there are files, each its own length (``session_frames`` their mean). Entries depend on
    the camera envelope and the light only, so scenes that share both share a seeded fill; recorded sessions
    are the scene's own."""
    key = [spec.camera.model_dump(mode="json"), spec.light.model_dump(mode="json")]
    if cfg.sessions_from is None:
        return GrowthSessions(cfg, None, cfg.session_frames, json.dumps(key, sort_keys=True))
    recorded = read_sessions(cfg.sessions_from, [load_scene(s) for s in cfg.scenes])[spec.name]
    lengths = np.array([len(p.frames) for p in recorded])
    cfg = replace(cfg, sessions=len(recorded), users=(1,), session_frames=round(float(lengths.mean())))
    return GrowthSessions(cfg, recorded, lengths, json.dumps([*key, spec.name], sort_keys=True))


def measure_growth(
    cfg: StorageConfig, res: Results, scene: str, model_bytes: dict[str, int], memo: dict
) -> dict[tuple[int, str], list[int]]:
    """The growth law of one scene (module docstring): entries after each session per user count and
    tolerance, bytes per codec and resolution, saturation, crossover with the model, the paper's figures."""
    spec, name = load_scene(scene), Path(scene).stem
    cfg, recorded, session_lengths, space = growth_sessions(cfg, spec)
    fills = _fills(cfg, spec, recorded, space, memo, res.seed)
    if (space, "capacity") not in memo:
        memo[(space, "capacity")] = capacity(spec, cfg.tolerance, cfg.light_cell, cfg.capacity_samples, res.seed)
    cap = memo[(space, "capacity")]
    sizes = _growth_entry_bytes(cfg, spec, name, fills[(max(cfg.users), "store")].creators, res.seed)
    common = {"session_frames": cfg.session_frames, "light_cell": cfg.light_cell}
    common |= {"tolerance_position": cfg.tolerance.position, "tolerance_angle_deg": cfg.tolerance.angle_deg}
    common |= {} if recorded is None else {"sessions_from": str(cfg.sessions_from)}
    add = partial(res.add, system=SYSTEM, scene=name)
    basis = f"measured: {len(next(iter(sizes.values())))} maps baked at entries spread over the session tree"
    for (resolution, codec), values in sizes.items():
        row = {"resolution": resolution, "codec": codec, "composition": "gi" if codec == RAW_CODEC else "blend"}
        add_entry_bytes(add, "growth_entry_bytes", values, basis=basis, **row)
    basis = "counted: the lookup rule over uniform samples of the navigable space, per light cell x light cells"
    add(metric="capacity_entries", value=cap["entries"], unit="count", stat="estimate", samples=cfg.capacity_samples,
        **{k: cap[k] for k in ("per_cell", "light_cells", "last_tenth_miss_rate")}, basis=basis, **common)  # fmt: skip
    for (users, label), fill in fills.items():
        tol = cfg.tolerance if label == "store" else PAPER_TOLERANCE
        at = common | {"users": users, "tolerance": label, "tolerance_position": tol.position}
        at |= {"tolerance_angle_deg": tol.angle_deg}
        _record_fill(res, cfg, name, fill, session_lengths, cap if label == "store" else None, at)
        for (resolution, codec), values in sizes.items():
            if (codec == RAW_CODEC) == (label == "paper"):  # the paper's accounting is Δ 0 with RGB8 maps
                row = at | {"resolution": resolution, "codec": codec}
                row["composition"] = "gi" if codec == RAW_CODEC else "blend"
                _record_bytes(res, cfg, name, fill, float(np.mean(values)), model_bytes, row)
    return sizes


def _fills(
    cfg: StorageConfig, spec: SceneSpec, recorded: list[PathFile] | None, space: str, memo: dict, seed: int
) -> dict[tuple[int, str], SessionFill]:
    """The tree filled along the sessions per user count, at the store's tolerance and (for the most users) at
    the paper's Δ 0, which needs no user model (every frame is its own map); fills of the same space are shared
    through ``memo``."""
    widest = max(cfg.users)
    fills: dict[tuple[int, str], SessionFill] = {}
    for users in cfg.users:
        for label, tol in (("store", cfg.tolerance), ("paper", PAPER_TOLERANCE))[: 2 if users == widest else 1]:
            key = (space, users, label)
            if key not in memo:
                if (space, users) not in memo:
                    plan = recorded or plan_sessions(spec, cfg.sessions, users, cfg.session_frames, seed)
                    memo[(space, users)] = session_frames(spec, plan, cfg.light_cell, spec.camera.gi_fov)
                memo[key] = fill_sessions(memo[(space, users)], tol)
            fills[(users, label)] = memo[key]
        memo.pop((space, users), None)  # the frames are only needed until both fills are done
    return fills


def _record_fill(
    res: Results,
    cfg: StorageConfig,
    name: str,
    fill: SessionFill,
    lengths: int | np.ndarray,
    cap: dict | None,
    at: dict,
) -> None:
    """The entries after each session of one fill, and when it saturated."""
    add = partial(res.add, system=SYSTEM, scene=name)
    for k, n in enumerate(fill.entries, start=1):
        add(metric="growth_entries", value=int(n), unit="count", sessions=k,
            basis="counted: the GI tree's lookup rule along the sessions", **at)  # fmt: skip
    sat = saturation_session(fill.entries, lengths, cfg.saturation_rate)
    entries = int(fill.entries[-1] if sat is None else fill.entries[sat - 1])
    last = int(fill.entries[-1] - (fill.entries[-2] if len(fill.entries) > 1 else 0))
    add(metric="saturation_sessions", value=cfg.sessions if sat is None else sat, unit="count",
        stat="beyond" if sat is None else "measured", saturation_rate=cfg.saturation_rate, sessions_run=cfg.sessions,
        entries=entries, capacity_fraction=None if cap is None else float(fill.entries[-1]) / cap["entries"],
        last_added=last, **at)  # fmt: skip


def _record_bytes(
    res: Results, cfg: StorageConfig, name: str, fill: SessionFill, per_entry: float, model_bytes: dict, row: dict
) -> None:
    """A fill's bytes (entries x ``per_entry``) after the grid's sessions, and the first session it passes each
    model file and the paper's figure for the scene."""
    add = partial(res.add, system=SYSTEM, scene=name)
    for k in _growth_sessions_grid(cfg.sessions):
        add(metric="growth_bytes", value=float(fill.entries[k - 1]) * per_entry, unit="bytes", stat="estimate",
            sessions=k, basis="counted entries x measured mean bytes per entry", **row)  # fmt: skip
    limits = {f"model_{p}": float(b) for p, b in model_bytes.items()}
    paper_gb = PAPER_TABLE2_GB.get(name.split("_")[0])
    limits |= {} if paper_gb is None else {"paper_gb": paper_gb * 1e9}
    for what, limit in limits.items():
        k = first_session_over(fill.entries, per_entry, limit)
        add(metric="crossover_sessions", value=cfg.sessions if k is None else k, unit="count",
            stat="beyond" if k is None else "measured", against=what, limit_bytes=limit, **row)  # fmt: skip


def paper_accounting(
    cfg: StorageConfig, res: Results, name: str, path: list[PathFrame], n_entries: int, sizes: dict
) -> None:
    """The paper's GB figure along the fly-through, then decomposed: one uncompressed RGB8 map per frame (Δ 0,
    counted with the lookup rule), the store's tolerance (same maps, counted entries), each codec's GI
    section, then the stored payload (GI + depth + header). Bytes per entry measured (growth law's maps)."""
    paper_entries = max(simulate_fill([f.view for f in path], [f.cell for f in path], PAPER_TOLERANCE)) + 1
    resolution = cfg.paper_resolution
    raw = float(np.mean(sizes[(resolution, RAW_CODEC)]))
    steps = [("paper", "rgb8 per frame", paper_entries, raw), ("tolerance", RAW_CODEC, n_entries, raw)]
    steps += [("payload", c, n_entries, float(np.mean(sizes[(resolution, c)]))) for c in cfg.codecs]
    for step, codec, entries, per_entry in steps:
        row = {"step": step, "codec": codec, "resolution": resolution, "frames": cfg.frames}
        tol = PAPER_TOLERANCE if step == "paper" else cfg.tolerance
        row |= {"tolerance_position": tol.position, "tolerance_angle_deg": tol.angle_deg}
        add = partial(res.add, system=SYSTEM, scene=name, **row)
        add(metric="accounting_entries", value=int(entries), unit="count")
        add(metric="accounting_bytes", value=entries * per_entry, unit="bytes", stat="estimate",
            bytes_per_entry=per_entry)  # fmt: skip
