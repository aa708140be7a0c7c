"""`bench storage` (paper Table 2): the GI tree's size after a fly-through, against GIGAN's model.

Per scene, resolution and codec: entries counted exactly with the GI tree's own rule
(:func:`baseline_cloudbaking.viewpoints.simulate_fill`), bytes per entry measured on baked maps sampled along the
path, tree bytes extrapolated with a 95 % interval, against the shipped model's files. Also the codec table,
the tolerance knob, and the growth law over seeded user sessions (:mod:`gicore.sessions`): entries after each
session, saturation, the crossover with the model, and the paper's accounting decomposed. What each row holds:
docs/architecture.md, bench storage.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from baseline_cloudbaking.bake import BakedMap, PathFrame, bake_map, fly_through, gi_camera, map_header
from baseline_cloudbaking.codecs import CODEC_NAMES, DEPTH_CODEC, get_codec
from baseline_cloudbaking.codecs import measure as measure_codec
from baseline_cloudbaking.protocol import pack
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL
from baseline_cloudbaking.viewpoints import Tolerance, Viewpoint, ViewSet, light_cell, simulate_fill
from bench.runner import Bench, Block, Figure, Part, Rows, Section, Table, need, pick
from bench.svg import BarChart, Point, Series, XYChart
from gicore.camera import Camera
from gicore.error_policy import UserError, writable_dir
from gicore.loop import Light
from gicore.metrics import ssim
from gicore.options import FRAMES
from gicore.path_file import PathFile, read_sessions
from gicore.paths import frame_seed, light_position
from gicore.render_cache import RenderCache
from gicore.results import Results, read_rows
from gicore.scene import SceneSpec, builtin_scenes, load_scene
from gicore.sessions import Session, navigable_views, plan_sessions, session_views
from gicore.tonemap import tonemap
from gigan_local.inference import DEFAULT_MODEL

CodecName = Literal[CODEC_NAMES]  # type: ignore[valid-type]
COMPOSITIONS = {"blend": ("gi", "depth"), "residual": ("gi", "di", "depth")}
#: The paper's Table 2 (GB): GI tree per scene after its fly-through, and the one model for every scene.
PAPER_TABLE2_GB = {"lung": 1.15, "digestive": 2.38, "vessels": 3.36, "model": 0.2}
#: The paper's accounting: one uncompressed RGB8 GI map per frame, i.e. a tree that never reuses a map (Δ 0).
RAW_CODEC = "rgb8"
PAPER_TOLERANCE = Tolerance(0.0, 0.0)
#: Frames of the light's schedule scanned for the light cells it reaches (the paper scenes' repeats every 2640).
LIGHT_SCAN_FRAMES = 20_000


@dataclass(frozen=True)
class StorageConfig:
    """What one storage run measures (see the module docstring for measured vs extrapolated)."""

    #: Scene names or spec files (Table 2 rows).
    scenes: tuple[str, ...] = tuple(builtin_scenes())
    #: Frames of each scene's fly-through (paper: 1500).
    frames: int = 1500
    #: Square map resolutions.
    resolutions: tuple[int, ...] = (256, 512)
    #: GI-map codecs; the first one is the tolerance knob's.
    codecs: tuple[CodecName, ...] = CODEC_NAMES
    #: Path-tracing samples per pixel of the rendered maps (then OIDN).
    spp: int = 64
    #: Maps rendered per scene and resolution to measure bytes per entry (all entries if fewer).
    samples: int = 12
    #: Δp: eye distance within which a stored map serves a frame, scene units.
    tolerance_position: float = field(default=Tolerance.position, metadata={"min": 0.0})
    #: Δθ: view-direction angle within which a stored map serves a frame, degrees.
    tolerance_angle_deg: float = field(default=Tolerance.angle_deg, metadata={"min": 0.0, "max": 180.0})
    #: Light-cell side for scenes whose light moves, scene units.
    light_cell: float = DEFAULT_LIGHT_CELL
    #: Tolerance knob: the Δp of each setting (paired with knob_angles_deg).
    knob_positions: tuple[float, ...] = field(default=(0.0, 0.02, 0.05, 0.1, 0.2), metadata={"min": 0.0})
    #: Tolerance knob: the Δθ (degrees) of each setting.
    knob_angles_deg: tuple[float, ...] = field(default=(0.0, 1.0, 2.0, 5.0, 10.0), metadata={"min": 0.0, "max": 180.0})
    #: σ of the second pass's eye perturbation per axis, scene units.
    perturb_position: float = 0.02
    #: σ of the second pass's view perturbation, degrees.
    perturb_angle_deg: float = 1.0
    #: Hits per knob setting whose warped map is scored against a render at the perturbed camera.
    warp_samples: int = 6
    #: Folder of the shipped GIGAN model (model_fp32.onnx, model_fp16.onnx, model.json): the client storage.
    model_dir: Path = DEFAULT_MODEL.parent
    #: Growth law: user sessions the GI tree sees per scene (gicore.sessions).
    sessions: int = field(default=200, metadata={"min": 1, "max": 10_000})
    #: Growth law: how many users the sessions come from (in turn), one curve per value.
    users: tuple[int, ...] = field(default=(1, 8), metadata={"min": 1, "max": 10_000})
    #: Growth law: frames per session.
    session_frames: int = field(default=1500, metadata=FRAMES)
    #: Growth law: a folder of recorded sessions flown in place of the seeded ones: every *.json path file in it
    #: (gigan-path/1, in name order; each scene's are those naming it), one curve, recorded as 1 user.
    sessions_from: Path | None = field(default=None, metadata={"conflicts": ("sessions", "users", "session_frames")})
    #: Growth law: maps baked per scene and resolution at entries of the session tree to measure bytes per entry.
    growth_samples: int = field(default=4, metadata={"min": 1, "max": 256})
    #: Growth law: saturated from the session after which no session adds more entries than this fraction of its
    #: frames.
    saturation_rate: float = field(default=0.01, metadata={"min": 0.0, "max": 1.0})
    #: Growth law: viewpoints drawn uniformly from the navigable space to estimate the tree's saturation level.
    capacity_samples: int = field(default=50_000, metadata={"min": 10, "max": 1_000_000})
    #: Resolution of the paper-accounting row (one uncompressed RGB8 map per frame); one of --resolutions.
    paper_resolution: int = 512
    #: Folder caching the growth law's baked maps across runs (key: scene spec, camera, light, spp, seed).
    map_cache: Path = Path(".cache/storage_maps")

    @classmethod
    def quick(cls) -> StorageConfig:
        return cls(
            scenes=("lung_plane", "vessels_plane"),
            frames=300,
            spp=16,
            samples=3,
            knob_positions=(0.02, 0.05, 0.2),
            knob_angles_deg=(1.0, 2.0, 10.0),
            warp_samples=2,
            sessions=6,
            users=(2,),
            session_frames=300,
            growth_samples=1,
            capacity_samples=2000,
        )

    def check(self) -> None:
        if self.map_cache.exists() and not self.map_cache.is_dir():
            raise UserError(f"--map-cache {self.map_cache} is a file", "give a folder path")
        if self.paper_resolution not in self.resolutions:
            raise UserError(
                f"--paper-resolution {self.paper_resolution} is not one of --resolutions "
                f"{','.join(map(str, self.resolutions))}",
                "add it to --resolutions (the paper's accounting is at 512)",
            )
        if len(self.knob_positions) != len(self.knob_angles_deg):
            raise UserError(
                f"--knob-positions has {len(self.knob_positions)} values but "
                f"--knob-angles-deg {len(self.knob_angles_deg)}",
                "give one angle per position (they are paired)",
            )
        missing = [p for p in ("model_fp32.onnx", "model_fp16.onnx") if not (self.model_dir / p).is_file()]
        if missing:
            raise UserError(
                f"--model-dir {self.model_dir} lacks {', '.join(missing)}",
                "give the folder of an exported GIGAN model (gigan-export)",
            )
        if self.sessions_from is not None:  # every recorded session checked before anything is measured
            read_sessions(self.sessions_from, [load_scene(s) for s in self.scenes])

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_position, self.tolerance_angle_deg)


def _entry_frames(served: list[int]) -> list[int]:
    """The frame that created each entry (entries are numbered in insertion order)."""
    first: dict[int, int] = {}
    for frame, entry in enumerate(served):
        first.setdefault(entry, frame)
    return [first[e] for e in range(len(first))]


def _bake(renderer, frame: PathFrame, cfg: StorageConfig, seed: int) -> BakedMap:
    return bake_map(renderer, frame.camera, frame.light, cfg.spp, seed, di=True)


def measure(cfg: StorageConfig, res: Results) -> None:
    from gicore.render import Renderer

    model_bytes = {
        p: (cfg.model_dir / f"model_{p}.onnx").stat().st_size + _size(cfg.model_dir / "model.json")
        for p in ("fp32", "fp16")
    }
    for precision, size in model_bytes.items():
        res.add(
            system="gigan",
            scene="all",
            metric="client_bytes",
            value=size,
            unit="bytes",
            precision=precision,
            basis="measured: model files",
        )
    tol = cfg.tolerance
    common = {
        "frames": cfg.frames,
        "tolerance_position": tol.position,
        "tolerance_angle_deg": tol.angle_deg,
        "light_cell": cfg.light_cell,
    }
    writable_dir(cfg.map_cache, name="--map-cache")  # before any work: the growth law writes its maps there
    memo: dict = {}  # growth-law fills, shared by scenes of one camera envelope and light
    for si, scene in enumerate(cfg.scenes):
        spec, name = load_scene(scene), Path(scene).stem  # the name a prebake stores the scene under
        path = fly_through(spec, cfg.frames, cfg.resolutions[0], cfg.light_cell, res.seed)
        served = simulate_fill([f.view for f in path], [f.cell for f in path], tol)
        entry_frames = _entry_frames(served)
        n_entries = len(entry_frames)
        basis = "counted: GI-tree lookup rule along the path"
        res.add(
            system="cloud_baking", scene=name, metric="entries", value=n_entries, unit="count", basis=basis, **common
        )
        running = np.maximum.accumulate(served) + 1
        for f in sorted({int(x) for x in np.linspace(1, cfg.frames, 16)}):
            res.add(
                system="cloud_baking",
                scene=name,
                metric="entries_at",
                value=int(running[f - 1]),
                unit="count",
                at_frame=f,
            )
        picks = sorted(
            {entry_frames[int(round(k))] for k in np.linspace(0, n_entries - 1, min(cfg.samples, n_entries))}
        )
        for resolution in cfg.resolutions:
            renderer = Renderer(spec, resolution)
            frames = fly_through(spec, cfg.frames, resolution, cfg.light_cell, res.seed)
            sizes = _measure_entries(cfg, res, name, spec, renderer, [frames[i] for i in picks], picks)
            for (codec_name, composition), values in sizes.items():
                row = {"resolution": resolution, "codec": codec_name, "composition": composition}
                _add_tree_bytes(res, name, np.asarray(values, dtype=np.float64), n_entries, model_bytes, row | common)
            if si == 0 and resolution == cfg.resolutions[0]:
                _tolerance_knob(cfg, res, name, spec, frames, renderer, float(np.mean(sizes[(cfg.codecs[0], "blend")])))
        growth_sizes = measure_growth(cfg, res, scene, model_bytes, memo)
        paper_accounting(cfg, res, name, path, n_entries, growth_sizes)


def _measure_entries(
    cfg: StorageConfig, res: Results, name: str, spec, renderer, frames: list[PathFrame], indices: list[int]
) -> dict:
    """Render the sampled entries, encode them with every codec; record the codec table and the bake
    time; return the payload bytes of each sampled entry per (codec, composition)."""
    sizes: dict[tuple[str, str], list[int]] = defaultdict(list)
    sections: dict[tuple[str, str], list[int]] = defaultdict(list)
    reports = defaultdict(list)
    bake_s = []
    for frame, i in zip(frames, indices, strict=True):
        # the prebake's render seed: these are the maps `cloudbaking-prebake --seed SEED` stores
        baked = _bake(renderer, frame, cfg, frame_seed(res.seed, f"prebake/{name}", i))
        bake_s.append((baked.render_ms + baked.denoise_ms) / 1e3)
        depth = DEPTH_CODEC.encode(baked.depth)
        for codec_name in cfg.codecs:
            codec = get_codec(codec_name)
            if not reports[codec_name]:  # warm-up: the first call of a codec pays for its set-up
                codec.decode(codec.encode(baked.gi))
            report, gi, _ = measure_codec(codec, baked.gi)
            reports[codec_name].append(report)
            data = {"gi": gi, "di": codec.encode(baked.di), "depth": depth}
            header = map_header(
                baked, name, codec_name, cfg.spp, frame.light if spec.light.moves else None, report.encode_ms
            )
            for composition, names in COMPOSITIONS.items():
                sizes[(codec_name, composition)].append(len(pack(header, {n: data[n] for n in names})))
            for section, blob in data.items():
                sections[(codec_name, section)].append(len(blob))
    resolution = renderer.resolution
    res.add_timing(
        system="cloud_baking", scene=name, metric="bake_ms", samples_s=bake_s, resolution=resolution, spp=cfg.spp
    )
    for codec_name, reps in reports.items():
        row = {"resolution": resolution, "codec": codec_name}
        res.add_timing(
            system="cloud_baking", scene=name, metric="encode_ms", samples_s=[r.encode_ms / 1e3 for r in reps], **row
        )
        res.add_timing(
            system="cloud_baking", scene=name, metric="decode_ms", samples_s=[r.decode_ms / 1e3 for r in reps], **row
        )
        for metric in ("rmse", "ssim"):
            mean = float(np.mean([getattr(r, metric) for r in reps]))
            res.add(system="cloud_baking", scene=name, metric=metric, value=mean, unit="1", stat="mean", **row)
        for section in ("gi", "di", "depth"):
            mean = float(np.mean(sections[(codec_name, section)]))
            res.add(
                system="cloud_baking",
                scene=name,
                metric="section_bytes",
                value=mean,
                unit="bytes",
                stat="mean",
                section=section,
                **row,
            )
    return sizes


def _add_tree_bytes(
    res: Results, name: str, values: np.ndarray, n_entries: int, model_bytes: dict[str, int], row: dict
) -> None:
    """Bytes per entry (mean, std, n) and the GI tree's bytes: measured when every entry was rendered,
    else extrapolated with a 95 % interval; and its ratio to the model."""
    n = len(values)
    std = float(values.std(ddof=1)) if n > 1 else 0.0
    for stat, value, unit in (("mean", float(values.mean()), "bytes"), ("std", std, "bytes"), ("n", n, "count")):
        res.add(system="cloud_baking", scene=name, metric="entry_bytes", value=value, unit=unit, stat=stat, **row)
    measured = n == n_entries
    total = float(values.sum()) if measured else n_entries * float(values.mean())
    ci95 = 0.0 if measured else n_entries * 1.96 * std / math.sqrt(n)
    basis = (
        "measured: every entry rendered"
        if measured
        else f"extrapolated: {n_entries} counted entries x mean of {n} rendered maps"
    )
    for stat, value in (("estimate", total), ("ci95", ci95)):
        res.add(
            system="cloud_baking",
            scene=name,
            metric="gi_tree_bytes",
            value=value,
            unit="bytes",
            stat=stat,
            basis=basis,
            **row,
        )
    for precision, size in model_bytes.items():
        res.add(
            system="cloud_baking",
            scene=name,
            metric="ratio_to_model",
            value=total / size,
            unit="1",
            stat="estimate",
            precision=precision,
            **row,
        )


def _size(path: Path) -> int:
    return path.stat().st_size if path.is_file() else 0


def _perturbed(spec, frames: list[PathFrame], cfg: StorageConfig, seed: int) -> list[PathFrame]:
    """The second pass: every frame's eye and target moved by seeded normal noise (module docstring)."""
    rng = np.random.default_rng(seed + 1)
    out = []
    for f in frames:
        cam = f.camera
        dist = float(np.linalg.norm(np.subtract(cam.target, cam.origin)))
        eye = np.asarray(cam.origin) + rng.normal(0.0, cfg.perturb_position, 3)
        target = np.asarray(cam.target) + rng.normal(0.0, dist * math.tan(math.radians(cfg.perturb_angle_deg)), 3)
        camera = gi_camera(spec, tuple(eye), tuple(target), cam.up, cam.fov, cam.width)
        out.append(PathFrame(camera, f.light, f.cell, Viewpoint.look_at(camera.origin, camera.target)))
    return out


def _tolerance_knob(
    cfg: StorageConfig, res: Results, name: str, spec, frames: list[PathFrame], renderer, bytes_per_entry: float
) -> None:
    """Entries, bytes, second-pass hit rate and warped-map SSIM for each (Δp, Δθ) of the knob."""
    from baseline_cloudbaking.warp import PointCloud

    codec = get_codec(cfg.codecs[0])
    second = _perturbed(spec, frames, cfg, res.seed)
    maps: dict[tuple[str, int], BakedMap] = {}

    def baked(kind: str, i: int) -> BakedMap:
        if (kind, i) not in maps:
            frame = frames[i] if kind == "stored" else second[i]
            maps[(kind, i)] = _bake(renderer, frame, cfg, frame_seed(res.seed, f"storage/{kind}/{name}", i))
        return maps[(kind, i)]

    for position, angle in zip(cfg.knob_positions, cfg.knob_angles_deg, strict=True):
        tol = Tolerance(position, angle)
        served = simulate_fill([f.view for f in frames], [f.cell for f in frames], tol)
        entries = _entry_frames(served)
        sets: dict = defaultdict(lambda: (ViewSet(), []))
        for j in entries:
            views, ids = sets[frames[j].cell]
            views.add(frames[j].view)
            ids.append(j)
        hits = []
        for i, f in enumerate(second):
            views, ids = sets[f.cell]
            found = views.nearest(f.view, tol)
            if found is not None:
                hits.append((i, ids[found[0]]))
        row = {
            "knob_position": position,
            "knob_angle_deg": angle,
            "perturb_position": cfg.perturb_position,
            "perturb_angle_deg": cfg.perturb_angle_deg,
            "resolution": frames[0].camera.width,
            "codec": codec.name,
        }
        res.add(system="cloud_baking", scene=name, metric="knob_entries", value=len(entries), unit="count", **row)
        res.add(
            system="cloud_baking",
            scene=name,
            metric="knob_bytes",
            value=len(entries) * bytes_per_entry,
            unit="bytes",
            stat="estimate",
            **row,
        )
        res.add(
            system="cloud_baking", scene=name, metric="knob_hit_rate", value=len(hits) / len(second), unit="1", **row
        )
        scores = defaultdict(list)
        for k in (
            sorted({int(round(x)) for x in np.linspace(0, len(hits) - 1, min(cfg.warp_samples, len(hits)))})
            if hits
            else []
        ):
            i, j = hits[k]
            stored, reference = baked("stored", j), baked("request", i)
            gi, depth = codec.decode(codec.encode(stored.gi)), DEPTH_CODEC.decode(DEPTH_CODEC.encode(stored.depth))
            warped, _, _ = PointCloud(gi, depth, stored.camera).splat(second[i].camera, target_mask=reference.depth > 0)
            ref = tonemap(reference.gi)
            scores["knob_ssim_warped"].append(ssim(tonemap(warped), ref))
            scores["knob_ssim_stale"].append(ssim(tonemap(gi), ref))
        for metric, values in scores.items():
            res.add(
                system="cloud_baking",
                scene=name,
                metric=metric,
                value=float(np.mean(values)),
                unit="1",
                stat="mean",
                **row,
            )
            res.add(system="cloud_baking", scene=name, metric=metric, value=len(values), unit="count", stat="n", **row)


# -- the growth law: the tree under many sessions ----------------------------------------------------------
@dataclass(frozen=True)
class SessionFrames:
    """Every frame of a run of sessions as the GI tree sees it: GI camera and light, viewpoint, light cell
    (None for a static light), and the frame count after each session."""

    frames: list[tuple[Camera, Light]]
    views: list[Viewpoint]
    cells: list[tuple[int, int, int] | None]
    ends: np.ndarray


@dataclass(frozen=True)
class SessionFill:
    """The GI tree filled by the lookup rule along sessions: entries after each session, and the frame (GI
    camera, light) that created each entry, in insertion order."""

    entries: np.ndarray
    creators: list[tuple[Camera, Light]]


def session_frames(
    spec: SceneSpec, sessions: Sequence[Session | PathFile], light_cell_size: float, fov: float
) -> SessionFrames:
    """The frames of ``sessions`` in turn at GI FOV ``fov``: seeded ones (:func:`gicore.sessions.session_views`)
    or recorded ones (path files)."""
    size = light_cell_size if spec.light.moves else None
    frames: list[tuple[Camera, Light]] = []
    views: list[Viewpoint] = []
    ends = []
    for session in sessions:
        seen: dict[int, Viewpoint] = {}  # a session's laps repeat their cameras: one viewpoint per camera
        if isinstance(session, PathFile):
            flown = session.views(spec.resolution, fov)
        else:
            flown = session_views(spec, session, fov, spec.resolution)
        for cam, light in flown:
            if id(cam) not in seen:
                seen[id(cam)] = Viewpoint.look_at(cam.origin, cam.target)
            views.append(seen[id(cam)])
            frames.append((cam, light))
        ends.append(len(views))
    cells = [light_cell(light, size) for _, light in frames]
    return SessionFrames(frames, views, cells, np.asarray(ends))


def fill_sessions(run: SessionFrames, tol: Tolerance) -> SessionFill:
    """Walk the sessions' frames through one empty tree with the store's own rule
    (:func:`baseline_cloudbaking.viewpoints.simulate_fill`: nearest stored viewpoint within ``tol`` in the same
    light cell, else a new entry)."""
    served = simulate_fill(run.views, run.cells, tol)
    running = np.maximum.accumulate(served) + 1
    return SessionFill(running[run.ends - 1], [run.frames[f] for f in _entry_frames(served)])


def capacity(spec: SceneSpec, tol: Tolerance, light_cell_size: float, samples: int, seed: int) -> dict[str, float]:
    """What the tree holds once every configuration has been visited, estimated: the lookup rule over
    ``samples`` viewpoints drawn uniformly from the navigable space (:func:`gicore.sessions.navigable_views`)
    fills one light cell; times the light cells the light's schedule reaches. A lower estimate while the
    last tenth of the samples still adds entries (``last_tenth_miss_rate``)."""
    views = [Viewpoint.look_at(eye, target) for eye, target in navigable_views(spec, samples, seed)]
    served = np.asarray(simulate_fill(views, [None] * samples, tol))
    per_cell = int(served.max()) + 1
    tail = served[int(0.9 * samples) :]
    before = int(served[: int(0.9 * samples)].max()) + 1 if samples >= 10 else 0
    size = light_cell_size if spec.light.moves else None
    cells = len({light_cell(light_position(spec, f), size) for f in range(LIGHT_SCAN_FRAMES)})
    return {
        "entries": per_cell * cells,
        "per_cell": per_cell,
        "light_cells": cells,
        "last_tenth_miss_rate": (per_cell - before) / max(len(tail), 1),
    }


def saturation_session(entries: np.ndarray, frames: int | np.ndarray, rate: float) -> int | None:
    """The session count after which no later session adds more than ``rate`` × ``frames`` entries (``frames``:
    one count for all, or each session's), with at
    least max(2, n // 10) sessions seen after it (else None: not saturated within the sessions run)."""
    added = np.diff(np.concatenate([[0], entries]))
    over = np.flatnonzero(added > rate * frames)
    k = int(over[-1]) + 1 if len(over) else 0  # sessions up to k still grew the tree by more
    return max(k, 1) if len(entries) - k >= max(2, len(entries) // 10) else None


def first_session_over(entries: np.ndarray, bytes_per_entry: float, limit: float) -> int | None:
    """The first session count whose tree (entries × bytes per entry) exceeds ``limit`` bytes, or None."""
    over = np.flatnonzero(entries * bytes_per_entry > limit)
    return int(over[0]) + 1 if len(over) else None


def _cached_bake(cfg: StorageConfig, renderer, spec: SceneSpec, camera: Camera, light: Light, seed: int) -> BakedMap:
    """A GI map (GI + texel depth, no DI) from ``cfg.map_cache``, baked and stored there on a miss."""

    def bake() -> dict[str, np.ndarray]:
        baked = bake_map(renderer, camera, light, cfg.spp, seed, di=False)
        times = np.array([baked.render_ms, baked.denoise_ms])
        return {"gi": baked.gi, "depth": baked.depth, "times_ms": times}

    key = ("gi_map", camera, list(light), cfg.spp, seed, renderer.resolution)
    entry = RenderCache(cfg.map_cache, spec).fetch(key, bake)
    return BakedMap(camera, entry["gi"], None, entry["depth"], *map(float, entry["times_ms"]))


def _growth_entry_bytes(
    cfg: StorageConfig, spec: SceneSpec, name: str, creators: list[tuple[Camera, Light]], seed: int
) -> dict[tuple[int, str], list[int]]:
    """Bytes per entry, measured on ``growth_samples`` maps baked at entries spread over the session tree
    (by insertion order, so over the sessions): the stored payload (GI + depth, blend) per codec, and the
    GI map as uncompressed RGB8 (the paper's accounting), per resolution."""
    from gicore.render import Renderer

    n = min(cfg.growth_samples, len(creators))
    picks = sorted({int(round(k)) for k in np.linspace(0, len(creators) - 1, n)})
    sizes: dict[tuple[int, str], list[int]] = defaultdict(list)
    for resolution in cfg.resolutions:
        renderer = Renderer(spec, resolution)
        for i in picks:
            cam, light = creators[i]
            camera = gi_camera(spec, cam.origin, cam.target, cam.up, cam.fov, resolution)
            baked = _cached_bake(cfg, renderer, spec, camera, light, frame_seed(seed, f"growth/{name}", i))
            sizes[(resolution, RAW_CODEC)].append(len(rgb8(baked.gi).tobytes()))
            depth = DEPTH_CODEC.encode(baked.depth)
            for codec_name in cfg.codecs:
                header = map_header(baked, name, codec_name, cfg.spp, light if spec.light.moves else None, 0.0)
                sizes[(resolution, codec_name)].append(
                    len(pack(header, {"gi": get_codec(codec_name).encode(baked.gi), "depth": depth}))
                )
    return sizes


def rgb8(gi: np.ndarray) -> np.ndarray:
    """A GI map as the paper stores it: tone-mapped, 8 bits per channel, uncompressed (HxWx3 uint8)."""
    return np.round(np.clip(tonemap(gi), 0.0, 1.0) * 255.0).astype(np.uint8)


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
    fov = spec.camera.gi_fov
    cfg, recorded, session_lengths, space = growth_sessions(cfg, spec)
    widest = max(cfg.users)
    fills: dict[tuple[int, str], SessionFill] = {}
    for users in cfg.users:
        # the paper's Δ 0 needs no user model (every frame is its own map): one curve, the widest user count's
        for label, tol in (("store", cfg.tolerance), ("paper", PAPER_TOLERANCE))[: 2 if users == widest else 1]:
            key = (space, users, label)
            if key not in memo:
                if (space, users) not in memo:
                    plan = recorded or plan_sessions(spec, cfg.sessions, users, cfg.session_frames, res.seed)
                    memo[(space, users)] = session_frames(spec, plan, cfg.light_cell, fov)
                memo[key] = fill_sessions(memo[(space, users)], tol)
            fills[(users, label)] = memo[key]
        memo.pop((space, users), None)  # the frames are only needed until both fills are done
    if (space, "capacity") not in memo:
        memo[(space, "capacity")] = capacity(spec, cfg.tolerance, cfg.light_cell, cfg.capacity_samples, res.seed)
    cap = memo[(space, "capacity")]
    sizes = _growth_entry_bytes(cfg, spec, name, fills[(widest, "store")].creators, res.seed)
    common = {
        "session_frames": cfg.session_frames,
        "light_cell": cfg.light_cell,
        "tolerance_position": cfg.tolerance.position,
        "tolerance_angle_deg": cfg.tolerance.angle_deg,
    }
    common |= {} if recorded is None else {"sessions_from": str(cfg.sessions_from)}
    basis = f"measured: {len(next(iter(sizes.values())))} maps baked at entries spread over the session tree"
    for (resolution, codec), values in sizes.items():
        row = {"resolution": resolution, "codec": codec, "composition": "gi" if codec == RAW_CODEC else "blend"}
        v = np.asarray(values, dtype=np.float64)
        for stat, value, unit in (
            ("mean", float(v.mean()), "bytes"),
            ("std", float(v.std(ddof=1)) if len(v) > 1 else 0.0, "bytes"),
            ("n", len(v), "count"),
        ):
            res.add(
                system="cloud_baking",
                scene=name,
                metric="growth_entry_bytes",
                value=value,
                unit=unit,
                stat=stat,
                basis=basis,
                **row,
            )
    res.add(
        system="cloud_baking",
        scene=name,
        metric="capacity_entries",
        value=cap["entries"],
        unit="count",
        stat="estimate",
        samples=cfg.capacity_samples,
        per_cell=cap["per_cell"],
        light_cells=cap["light_cells"],
        last_tenth_miss_rate=cap["last_tenth_miss_rate"],
        basis="counted: the lookup rule over uniform samples of the navigable space, per light cell x light cells",
        **common,
    )
    grid = _growth_sessions_grid(cfg.sessions)
    paper_gb = PAPER_TABLE2_GB.get(name.split("_")[0])
    for (users, label), fill in fills.items():
        tol = cfg.tolerance if label == "store" else PAPER_TOLERANCE
        at = common | {"users": users, "tolerance": label, "tolerance_position": tol.position}
        at |= {"tolerance_angle_deg": tol.angle_deg}
        for k, n in enumerate(fill.entries, start=1):
            res.add(
                system="cloud_baking",
                scene=name,
                metric="growth_entries",
                value=int(n),
                unit="count",
                sessions=k,
                basis="counted: the GI tree's lookup rule along the sessions",
                **at,
            )
        sat = saturation_session(fill.entries, session_lengths, cfg.saturation_rate)
        res.add(
            system="cloud_baking",
            scene=name,
            metric="saturation_sessions",
            value=cfg.sessions if sat is None else sat,
            unit="count",
            stat="beyond" if sat is None else "measured",
            saturation_rate=cfg.saturation_rate,
            sessions_run=cfg.sessions,
            entries=int(fill.entries[-1] if sat is None else fill.entries[sat - 1]),
            capacity_fraction=float(fill.entries[-1]) / cap["entries"] if label == "store" else None,
            last_added=int(fill.entries[-1] - (fill.entries[-2] if len(fill.entries) > 1 else 0)),
            **at,
        )
        for (resolution, codec), values in sizes.items():
            if (codec == RAW_CODEC) != (label == "paper"):  # the paper's accounting is Δ 0 with RGB8 maps
                continue
            per_entry = float(np.mean(values))
            row = at | {
                "resolution": resolution,
                "codec": codec,
                "composition": "gi" if codec == RAW_CODEC else "blend",
            }
            for k in grid:
                res.add(
                    system="cloud_baking",
                    scene=name,
                    metric="growth_bytes",
                    value=float(fill.entries[k - 1]) * per_entry,
                    unit="bytes",
                    stat="estimate",
                    sessions=k,
                    basis="counted entries x measured mean bytes per entry",
                    **row,
                )
            limits = {f"model_{p}": float(b) for p, b in model_bytes.items()}
            if paper_gb is not None:
                limits["paper_gb"] = paper_gb * 1e9
            for what, limit in limits.items():
                k = first_session_over(fill.entries, per_entry, limit)
                res.add(
                    system="cloud_baking",
                    scene=name,
                    metric="crossover_sessions",
                    value=cfg.sessions if k is None else k,
                    unit="count",
                    stat="beyond" if k is None else "measured",
                    against=what,
                    limit_bytes=limit,
                    **row,
                )
    return sizes


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
        res.add(system="cloud_baking", scene=name, metric="accounting_entries", value=int(entries), unit="count", **row)
        res.add(
            system="cloud_baking",
            scene=name,
            metric="accounting_bytes",
            value=entries * per_entry,
            unit="bytes",
            stat="estimate",
            bytes_per_entry=per_entry,
            **row,
        )


# -- outputs built from the CSV -------------------------------------------------------------------------
def _mib(n: float) -> str:
    """Bytes as MiB with three significant digits (tiny quick-run trees stay readable)."""
    mib = n / 2**20
    return f"{mib:,.0f}" if mib >= 100 else f"{mib:.3g}"


def _index(rows: list[dict], metric: str, stat: str, *keys: str) -> dict[tuple, float]:
    """``{(scene, config[key], ...): value}`` of the rows of ``metric`` with ``stat``."""
    return {
        (r["scene"], *(r["config"].get(k) for k in keys)): r["value"]
        for r in rows
        if r["metric"] == metric and r["stat"] == stat
    }


def table2(rows: list[dict]) -> str:
    """The Table-2 markdown: per resolution and composition, GI-tree MiB per scene and codec against the
    model's fp16 bytes."""
    model = {r["config"]["precision"]: r["value"] for r in rows if r["metric"] == "client_bytes"}
    keys = ("resolution", "codec", "composition")
    trees, ci = _index(rows, "gi_tree_bytes", "estimate", *keys), _index(rows, "gi_tree_bytes", "ci95", *keys)
    entries = {r["scene"]: (int(r["value"]), r["config"]["frames"]) for r in rows if r["metric"] == "entries"}
    codecs = list(dict.fromkeys(k[2] for k in trees))
    paper = PAPER_TABLE2_GB
    lines = [
        "# Table 2: GI-tree storage (cloud baking) vs the GIGAN model (client)",
        "",
        f"GIGAN client storage (measured: model files, the same for every scene): fp32 {_mib(model.get('fp32', 0))} "
        f"MiB, fp16 {_mib(model.get('fp16', 0))} MiB. Paper: GI tree {paper['lung']} / {paper['digestive']} / "
        f"{paper['vessels']} GB (lung / digestive / vessels) vs {paper['model']} GB for the model.",
        "",
        "Entries: counted with the GI tree's lookup rule along the fly-through. MiB: entries x mean payload bytes of "
        "the rendered sample, ± its 95 % interval (extrapolated), or the sum when every entry was rendered (measured). "
        "(xN): GI tree / fp16 model.",
    ]
    for resolution in dict.fromkeys(k[1] for k in trees):
        for composition in ("blend", "residual"):
            what = "GI + depth" if composition == "blend" else "GI + DI + depth (residual composition)"
            lines += ["", f"## {resolution}², {what}", "", "| scene | frames | entries | " + " | ".join(codecs) + " |"]
            lines.append("|---" * (3 + len(codecs)) + "|")
            for scene, (n, frames) in entries.items():
                cells = []
                for codec in codecs:
                    key = (scene, resolution, codec, composition)
                    if key not in trees:
                        cells.append("")
                        continue
                    spread = f" ± {_mib(ci[key])}" if ci.get(key) else ""
                    ratio = f" (x{trees[key] / model['fp16']:.2g})" if model.get("fp16") else ""
                    cells.append(f"{_mib(trees[key])}{spread}{ratio}")
                lines.append(f"| {scene} | {frames} | {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _gb(n: float) -> str:
    """Bytes as GB (10⁹ B, the paper's unit) with three significant digits."""
    return f"{n / 1e9:.3g}"


def _sessions_cell(row: dict | None) -> str:
    """A session count: measured, or ``> N`` when not reached within the N sessions run."""
    if row is None:
        return "—"
    return f"{row['value']:.0f}" if row["stat"] == "measured" else f"> {row['value']:.0f}"


def growth_table(rows: Rows) -> str:
    """Markdown of the growth law (empty without its rows): the tree after 1, 10 and N sessions against its
    saturation level; the session counts where it passes the model and the paper's GB figure; and the paper's
    accounting along the fly-through, decomposed into the tolerance and the codec."""
    entries = pick(rows, "growth_entries")
    if not entries:
        return ""
    c = entries[0]["config"]
    widest = max(r["config"]["users"] for r in entries)
    scenes = list(dict.fromkeys(r["scene"] for r in entries))
    model = {r["config"]["precision"]: r["value"] for r in pick(rows, "client_bytes")}
    store = {
        (r["scene"], r["config"]["users"], r["config"]["sessions"]): r["value"]
        for r in entries
        if r["config"]["tolerance"] == "store"
    }
    n = max(k[2] for k in store)
    marks = sorted({1, min(10, n), n})
    users = sorted({k[1] for k in store})
    sat = {
        (r["scene"], r["config"]["users"]): r
        for r in pick(rows, "saturation_sessions")
        if r["config"]["tolerance"] == "store"
    }
    cap = {r["scene"]: r for r in pick(rows, "capacity_entries")}
    per_entry = {
        (r["scene"], r["config"]["codec"], r["config"]["resolution"]): r["value"]
        for r in pick(rows, "growth_entry_bytes", "mean")
    }
    # the tree's bytes once saturated, for the first codec at the largest resolution (the paper's 512²)
    level_key = next((k[1:] for k in sorted(per_entry, key=lambda k: -k[2]) if k[1] != RAW_CODEC), (RAW_CODEC, 0))
    at_level = f"{level_key[0]} {level_key[1]}², GB"
    lines = [
        f"## Growth law: the GI tree under user sessions ({c['session_frames']} frames each, Δp "
        f"{c['tolerance_position']:g}, Δθ {c['tolerance_angle_deg']:g}°)",
        "",
        "Sessions (`gicore.sessions`): seeded fly-throughs and orbits over each scene's navigable space at varied "
        "speeds, each starting at its own light state; users take turns, each with a habit. Entries: counted with the "
        "GI tree's own lookup rule (`simulate_fill`). Saturated: the session after which no session adds more than "
        f"{sat[next(iter(sat))]['config']['saturation_rate']:.0%} of its frames; `> N`: not within the N sessions run. "
        "Saturation level: the lookup rule over uniform samples of the navigable space in one light cell × the light "
        "cells the light reaches (a lower estimate while samples still add entries).",
        "",
        "| scene | users | " + " | ".join(f"entries @{m}" for m in marks) + " | added by session "
        f"{n} | saturated after | saturation level (est.) | filled at {n} | at saturation level: {at_level} |",
        "|---" * (7 + len(marks)) + "|",
    ]
    for scene in scenes:
        for u in users:
            s_row = sat.get((scene, u))
            level = cap.get(scene)
            last = store[(scene, u, n)] - store.get((scene, u, n - 1), 0)
            filled = f"{store[(scene, u, n)] / level['value']:.0%}" if level else "—"
            level_text = (
                f"{'≥ ' if level['config']['last_tenth_miss_rate'] > 0 else ''}{level['value']:,.0f} "
                f"({level['config']['per_cell']:,} × {level['config']['light_cells']} cells)"
                if level
                else "—"
            )
            size = per_entry.get((scene, *level_key))
            level_gb = _gb(level["value"] * size) if level and size else "—"
            lines.append(
                f"| {scene} | {u} | "
                + " | ".join(f"{store[(scene, u, m)]:,.0f}" for m in marks)
                + f" | {last:,.0f} | {_sessions_cell(s_row)} | {level_text} | {filled} | {level_gb} |"
            )
    cross = [r for r in pick(rows, "crossover_sessions") if r["config"]["users"] == widest]
    columns = list(dict.fromkeys((r["config"]["codec"], r["config"]["resolution"]) for r in cross))
    index = {(r["scene"], r["config"]["codec"], r["config"]["resolution"], r["config"]["against"]): r for r in cross}
    n_maps = int(pick(rows, "growth_entry_bytes", "n")[0]["value"])
    if columns:
        maps = f"{n_maps} map{'s' if n_maps != 1 else ''}"
        lines += [
            "",
            f"### Sessions until the tree passes the fp16 model ({_mib(model.get('fp16', 0))} MiB) / reaches the "
            f"paper's GB figure for the scene ({widest} users)",
            "",
            f"Bytes = counted entries × mean bytes per entry (in brackets), measured on {maps} per scene and "
            "resolution baked at entries spread over the session tree (not every entry is baked). Codecs: the "
            "stored payload (GI + depth + header) at the store's tolerance; `rgb8`: the paper's accounting (Δ 0, "
            "one uncompressed RGB8 GI map per frame). Paper: lung 1.15, digestive 2.38, vessels 3.36 GB.",
            "",
            "| scene | " + " | ".join(f"{codec} {res}²" for codec, res in columns) + " |",
            "|---" * (1 + len(columns)) + "|",
        ]
        for scene in scenes:
            cells = []
            for codec, res in columns:
                model_k = _sessions_cell(index.get((scene, codec, res, "model_fp16")))
                paper_k = _sessions_cell(index.get((scene, codec, res, "paper_gb")))
                size = per_entry.get((scene, codec, res), float("nan"))
                cells.append(f"{model_k} / {paper_k} ({size:,.0f} B)")
            lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    accounting = pick(rows, "accounting_bytes")
    if accounting:
        a0 = accounting[0]["config"]
        raw = a0["frames"] * a0["resolution"] ** 2 * 3
        counts = {
            (r["scene"], r["config"]["step"], r["config"]["codec"]): r["value"]
            for r in pick(rows, "accounting_entries")
        }
        codecs = [
            r["config"]["codec"]
            for r in accounting
            if r["config"]["step"] == "payload" and r["scene"] == accounting[0]["scene"]
        ]
        lines += [
            "",
            f"### The paper's accounting, decomposed ({a0['frames']}-frame fly-through, {a0['resolution']}², "
            "GB = 10⁹ B)",
            "",
            f"Paper: one uncompressed RGB8 map per frame (the lookup rule at Δ 0 stores every frame); {a0['frames']} × "
            f"{a0['resolution']}² × 3 B = {_gb(raw)} GB (1500 frames at 512²: 1.18 GB; the paper's lung figure: "
            "1.15 GB). Then the store's tolerance "
            "(the same maps, fewer of them), then each codec's stored payload (GI + depth). Bytes per entry measured "
            "on the growth law's baked maps.",
            "",
            f"| scene | paper's figure | paper accounting: entries, GB (vs {a0['frames']} × {a0['resolution']}² × 3) | "
            "store's tolerance: entries, GB | " + " | ".join(f"{codec}: GB" for codec in codecs) + " |",
            "|---" * (4 + len(codecs)) + "|",
        ]
        value = {(r["scene"], r["config"]["step"], r["config"]["codec"]): r["value"] for r in accounting}
        for scene in dict.fromkeys(r["scene"] for r in accounting):
            paper = PAPER_TABLE2_GB.get(scene.split("_")[0])
            p_bytes = value[(scene, "paper", "rgb8 per frame")]
            t_bytes = value[(scene, "tolerance", RAW_CODEC)]
            lines.append(
                f"| {scene} | {'—' if paper is None else f'{paper} GB'} | "
                f"{counts[(scene, 'paper', 'rgb8 per frame')]:,.0f}, {_gb(p_bytes)} ({p_bytes / raw - 1:+.1%}) | "
                f"{counts[(scene, 'tolerance', RAW_CODEC)]:,.0f}, {_gb(t_bytes)} (×{t_bytes / p_bytes:.3g}) | "
                + " | ".join(
                    f"{_gb(value[(scene, 'payload', codec)])} (×{value[(scene, 'payload', codec)] / p_bytes:.2g})"
                    for codec in codecs
                )
                + " |"
            )
    return "\n".join(lines) + "\n"


def codec_table(rows: list[dict]) -> str:
    """Markdown: per codec and resolution, mean over scenes of GI-map and depth bytes, encode/decode ms
    (medians) and the tone-mapped error of the decoded GI map."""
    columns = {
        "GI bytes": _index(rows, "section_bytes", "mean", "codec", "resolution", "section"),  # and depth bytes
        "encode ms": _index(rows, "encode_ms", "median", "codec", "resolution"),
        "decode ms": _index(rows, "decode_ms", "median", "codec", "resolution"),
        "RMSE": _index(rows, "rmse", "mean", "codec", "resolution"),
        "SSIM": _index(rows, "ssim", "mean", "codec", "resolution"),
    }
    pairs = list(dict.fromkeys(k[1:3] for k in columns["RMSE"]))
    lines = [
        "| codec | resolution | GI bytes | depth bytes | encode ms | decode ms | RMSE (tone-mapped) | SSIM |",
        "|---" * 8 + "|",
    ]
    for codec, resolution in pairs:

        def mean(column: str, *extra: str) -> float:
            return float(np.mean([v for k, v in columns[column].items() if k[1:] == (codec, resolution, *extra)]))

        lines.append(
            f"| {codec} | {resolution}² | {mean('GI bytes', 'gi'):,.0f} | {mean('GI bytes', 'depth'):,.0f} | "
            f"{mean('encode ms'):.1f} | {mean('decode ms'):.1f} | {mean('RMSE'):.4f} | {mean('SSIM'):.4f} |"
        )
    return "\n".join(lines) + "\n"


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """GI-tree bytes against frames per scene (codecs at each resolution, the model as lines); the
    tolerance knob; and the Table-2 and codec markdown."""
    from gicore.plotting import plt, save

    rows = read_rows(csv_path)
    written = []
    md = out_dir / "storage_table2.md"
    growth = growth_table(rows)
    md.write_text(
        table2(rows)
        + "\n## Codecs (sampled GI maps, per map)\n\n"
        + codec_table(rows)
        + ("\n" + growth if growth else "")
    )
    written.append(md)
    if pick(rows, "growth_bytes"):
        written.append(_plot_growth(rows, out_dir / "storage_growth.png"))
    model = {r["config"]["precision"]: r["value"] for r in rows if r["metric"] == "client_bytes"}
    scenes = list(dict.fromkeys(r["scene"] for r in rows if r["metric"] == "entries"))
    mean_bytes = {
        (r["scene"], r["config"]["resolution"], r["config"]["codec"]): r["value"]
        for r in rows
        if r["metric"] == "entry_bytes" and r["stat"] == "mean" and r["config"]["composition"] == "blend"
    }
    resolutions = list(dict.fromkeys(k[1] for k in mean_bytes))
    codecs = list(dict.fromkeys(k[2] for k in mean_bytes))
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.2 * len(scenes), 4.0), squeeze=False, sharey=True)
    colours = {c: f"C{i}" for i, c in enumerate(codecs)}
    for ax, scene in zip(axes[0], scenes, strict=True):
        at = sorted(
            (r["config"]["at_frame"], r["value"]) for r in rows if r["metric"] == "entries_at" and r["scene"] == scene
        )
        x, n = np.array([a for a, _ in at]), np.array([v for _, v in at])
        for resolution, style in zip(resolutions, ("-", "--", ":"), strict=False):
            for codec in codecs:
                b = mean_bytes.get((scene, resolution, codec))
                if b is not None:
                    ax.plot(x, n * b, style, color=colours[codec], label=f"{codec} {resolution}²")
        for precision, style in (("fp32", "k-"), ("fp16", "k:")):
            if precision in model:
                ax.axhline(
                    model[precision], color="k", linestyle=style[1:], linewidth=1.5, label=f"GIGAN model {precision}"
                )
        ax.set_yscale("log")
        ax.set_xlabel("fly-through frames")
        ax.set_title(scene, fontsize=9)
        ax.grid(alpha=0.3, which="both")
    axes[0][0].set_ylabel("bytes")
    fig.suptitle("GI tree (counted entries x measured mean bytes per GI + depth entry) vs the GIGAN model", fontsize=9)
    axes[0][-1].legend(fontsize=6, ncols=2)
    written.append(save(fig, out_dir / "storage.png"))
    knob = [r for r in rows if r["metric"].startswith("knob_")]
    if knob:
        settings = list(dict.fromkeys((r["config"]["knob_position"], r["config"]["knob_angle_deg"]) for r in knob))

        def series(metric: str, stat: str = "value") -> list[float]:
            values = {k[1:]: v for k, v in _index(knob, metric, stat, "knob_position", "knob_angle_deg").items()}
            return [values.get(setting, float("nan")) for setting in settings]

        fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
        labels = [f"Δp {p:g}\nΔθ {a:g}°" for p, a in settings]
        xs = np.arange(len(settings))
        a1.bar(xs, series("knob_entries"), color="C0")
        a1.set_ylabel("entries (first pass)")
        a1.set_xticks(xs, labels, fontsize=7)
        twin = a1.twinx()
        twin.plot(xs, series("knob_hit_rate"), "o-", color="C3")
        twin.set_ylabel("hit rate of the perturbed pass", color="C3")
        twin.set_ylim(0, 1.05)
        a2.plot(xs, series("knob_ssim_warped", "mean"), "o-", label="served map, pixel-level warped")
        a2.plot(xs, series("knob_ssim_stale", "mean"), "s--", label="served map as is (stale)")
        a2.set_xticks(xs, labels, fontsize=7)
        a2.set_ylabel("SSIM vs render at the request")
        a2.legend(fontsize=7)
        a2.grid(alpha=0.3)
        fig.suptitle(
            f"GI-tree tolerance knob ({knob[0]['scene']}, {knob[0]['config']['codec']} "
            f"{knob[0]['config']['resolution']}²)",
            fontsize=9,
        )
        written.append(save(fig, out_dir / "storage_tolerance.png"))
    return written


def _growth_series(rows: Rows, scene: str, users: int) -> dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]:
    """(codec, resolution) -> (sessions, bytes) of the growth law's byte curves of ``scene`` for ``users``."""
    out: dict[tuple[str, int], list[tuple[int, float]]] = defaultdict(list)
    for r in pick(rows, "growth_bytes"):
        c = r["config"]
        if r["scene"] == scene and c["users"] == users:
            out[(c["codec"], c["resolution"])].append((c["sessions"], r["value"]))
    return {k: (np.array([x for x, _ in sorted(v)]), np.array([y for _, y in sorted(v)])) for k, v in out.items()}


def _plot_growth(rows: Rows, png: Path) -> Path:
    """Per scene: entries after each session (per user count, store tolerance and Δ 0) over the saturation
    level; bytes per codec and resolution against the model and the paper's figure."""
    from gicore.plotting import plt, save

    entries = pick(rows, "growth_entries")
    scenes = list(dict.fromkeys(r["scene"] for r in entries))
    widest = max(r["config"]["users"] for r in entries)
    model = {r["config"]["precision"]: r["value"] for r in pick(rows, "client_bytes")}
    cap = {r["scene"]: r["value"] for r in pick(rows, "capacity_entries")}
    fig, axes = plt.subplots(2, len(scenes), figsize=(4.4 * len(scenes), 7.6), squeeze=False)
    for col, scene in enumerate(scenes):
        top, bottom = axes[0][col], axes[1][col]
        curves: dict[tuple[int, str], list[tuple[int, float]]] = defaultdict(list)
        for r in entries:
            if r["scene"] == scene:
                curves[(r["config"]["users"], r["config"]["tolerance"])].append((r["config"]["sessions"], r["value"]))
        for (users, tolerance), points in sorted(curves.items()):
            x, y = zip(*sorted(points), strict=True)
            label = f"{users} user{'s' if users > 1 else ''}" + (" (Δ 0, paper)" if tolerance == "paper" else "")
            top.plot(x, y, ":" if tolerance == "paper" else "-", label=label)
        if scene in cap:
            top.axhline(cap[scene], color="k", linestyle="--", linewidth=1, label="saturation level (est., store's Δ)")
        top.set_yscale("log")
        top.set_xlabel("sessions")
        top.set_ylabel("GI-tree entries")
        top.set_title(scene, fontsize=9)
        top.grid(alpha=0.3, which="both")
        top.legend(fontsize=6)
        series = _growth_series(rows, scene, widest)
        resolutions = sorted({k[1] for k in series})
        codecs = list(dict.fromkeys(k[0] for k in series))
        for ci, codec in enumerate(codecs):
            for resolution, style in zip(resolutions, ("-", "--", ":"), strict=False):
                if (codec, resolution) in series:
                    x, y = series[(codec, resolution)]
                    bottom.plot(x, y, style, color=f"C{ci}", label=f"{codec} {resolution}²")
        if "fp16" in model:
            bottom.axhline(model["fp16"], color="k", linewidth=1.5, label="GIGAN model fp16")
        paper = PAPER_TABLE2_GB.get(scene.split("_")[0])
        if paper is not None:
            bottom.axhline(paper * 1e9, color="r", linewidth=1, linestyle="-.", label=f"paper {paper} GB")
        bottom.set_xscale("log")
        bottom.set_yscale("log")
        bottom.set_xlabel("sessions")
        bottom.set_ylabel("GI-tree bytes")
        bottom.grid(alpha=0.3, which="both")
        bottom.legend(fontsize=5, ncols=2)
    fig.suptitle(
        f"GI-tree growth law ({widest} users for bytes; rgb8 = the paper's Δ 0 accounting; bytes = counted entries x "
        "measured mean bytes per entry)",
        fontsize=9,
    )
    return save(fig, png)


def _growth_charts(rows: Rows) -> list[XYChart]:
    """Dashboard charts: entries against sessions (every scene and user count), and each scene's bytes at the
    paper's resolution per codec against the model."""
    entries = pick(rows, "growth_entries")
    if not entries:
        return []
    curves: dict[str, list[Point]] = defaultdict(list)
    for r in entries:
        c = r["config"]
        name = f"{r['scene']}, {c['users']} users" + (", Δ 0" if c["tolerance"] == "paper" else "")
        curves[name].append(
            Point(c["sessions"], r["value"], f"{name}: {r['value']:,.0f} entries after {c['sessions']}")
        )
    charts = [
        XYChart(
            [Series(k, v) for k, v in curves.items()],
            "sessions",
            "GI-tree entries",
            ylog=True,
            caption="Entries after each session, counted with the GI tree's lookup rule.",
        )
    ]
    widest = max(r["config"]["users"] for r in entries)
    model = {r["config"]["precision"]: r["value"] for r in pick(rows, "client_bytes")}
    resolution = max(r["config"]["resolution"] for r in pick(rows, "growth_bytes"))
    for scene in dict.fromkeys(r["scene"] for r in entries):
        series = [
            Series(
                f"{codec} {res}²",
                [Point(float(a), float(b), f"{codec}: {_mib(b)} MiB after {a}") for a, b in zip(x, y, strict=True)],
            )
            for (codec, res), (x, y) in _growth_series(rows, scene, widest).items()
            if res == resolution
        ]
        if "fp16" in model and series:
            xs = [p.x for p in series[0].points]
            series.append(
                Series("GIGAN model fp16", [Point(x, model["fp16"], "the model") for x in (min(xs), max(xs))])
            )
        charts.append(
            XYChart(
                series,
                "sessions",
                "bytes",
                xlog=True,
                ylog=True,
                caption=f"{scene}: GI tree at {resolution}², {widest} users.",
            )
        )
    return charts


# -- bench report: the dashboard's section and the README's block ------------------------------------------
def dashboard_section(rows: Rows) -> list[Part]:
    """Table 2 in full, the GI tree per scene and codec against the model as bars, then the codec table."""
    need(rows, "gi_tree_bytes", "client_bytes")
    trees = [r for r in pick(rows, "gi_tree_bytes", "estimate") if r["config"].get("composition") == "blend"]
    resolution = trees[0]["config"]["resolution"]
    scenes = list(dict.fromkeys(r["scene"] for r in trees))
    codecs = list(dict.fromkeys(r["config"]["codec"] for r in trees))
    mib = {
        (r["scene"], r["config"]["codec"]): r["value"] / 2**20 for r in trees if r["config"]["resolution"] == resolution
    }
    series: dict[str, list[float | None]] = {c: [mib.get((s, c)) for s in scenes] for c in codecs}
    model = {r["config"]["precision"]: r["value"] / 2**20 for r in pick(rows, "client_bytes")}
    if "fp16" in model:
        series["GIGAN model fp16"] = [model["fp16"]] * len(scenes)
    figure = BarChart(
        scenes,
        series,
        "MiB",
        caption=f"GI tree after the fly-through ({resolution}², GI + depth) per codec, against the model.",
    )
    codecs_md = "### Codecs (sampled GI maps, per map)\n\n" + codec_table(rows)
    parts: list[Part] = [Table(table2(rows)), Figure((figure,)), Table(codecs_md)]
    growth = growth_table(rows)
    if growth:
        parts += [Table(growth, scroll=True), Figure(tuple(_growth_charts(rows)))]
    return parts


def readme_block(rows: Rows) -> list[Table]:
    """Table 2 in short: each scene's GI tree per codec and resolution against the model; the codecs."""
    need(rows, "gi_tree_bytes", "client_bytes", "entries")
    model = {r["config"]["precision"]: r["value"] for r in pick(rows, "client_bytes")}
    trees = _index(rows, "gi_tree_bytes", "estimate", "resolution", "codec", "composition")
    columns = list(dict.fromkeys((k[1], k[2]) for k in trees if k[3] == "blend"))
    lines = [
        "GIGAN's model (the same for every scene): "
        + ", ".join(f"{p} {_mib(v)} MiB" for p, v in model.items())
        + ". The GI tree of each scene's fly-through (GI + depth, blend composition): entries counted with the GI "
        "tree's lookup rule, MiB = entries × mean payload"
        + (", × = against the fp16 model" if model.get("fp16") else "")
        + ".",
        "",
        "| scene | frames | entries | " + " | ".join(f"{codec} {resolution}²" for resolution, codec in columns) + " |",
        "|---" * (3 + len(columns)) + "|",
    ]
    for r in pick(rows, "entries"):
        cells = []
        for resolution, codec in columns:
            value = trees.get((r["scene"], resolution, codec, "blend"))
            ratio = f" (×{value / model['fp16']:.2g})" if value is not None and model.get("fp16") else ""
            cells.append("—" if value is None else _mib(value) + ratio)
        lines.append(f"| {r['scene']} | {r['config'].get('frames')} | {r['value']:.0f} | " + " | ".join(cells) + " |")
    codecs = "Codecs, per GI map (means over the scenes):\n\n" + codec_table(rows).rstrip()
    growth = growth_table(rows)
    return [Table("\n".join(lines) + "\n\n" + codecs)] + ([Table(growth)] if growth else [])


BENCH = Bench(
    "storage",
    StorageConfig,
    measure,
    plot,
    help="Table 2: GI-tree entries and bytes after a fly-through per scene, codec and resolution vs the GIGAN model; "
    "codec table; tolerance knob; the growth law over --sessions user sessions from --users users (saturation, "
    "crossover with the model, the paper's accounting decomposed).",
    dashboard=Section("table2", "Table 2: storage (GI tree vs model)", 20, dashboard_section),
    readme=Block("GI-tree storage, Table 2", 20, readme_block),
)
