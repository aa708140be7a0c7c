"""`bench storage` (paper Table 2): the GI tree's size after a fly-through, against GIGAN's model, the codecs,
the tolerance knob and the growth law (docs/architecture.md, bench storage). The growth law and the paper's
accounting: :mod:`bench.storage_growth`; what it shows: :mod:`bench.storage_tables`."""

from __future__ import annotations

import math
from collections import defaultdict
from functools import partial
from pathlib import Path

import numpy as np

from baseline_cloudbaking.bake import BakedMap, PathFrame, bake_map, fly_through, gi_camera, map_header
from baseline_cloudbaking.codecs import DEPTH_CODEC, get_codec
from baseline_cloudbaking.codecs import measure as measure_codec
from baseline_cloudbaking.growth import entry_frames, spread_picks
from baseline_cloudbaking.protocol import pack
from baseline_cloudbaking.viewpoints import CellViews, Tolerance, Viewpoint, simulate_fill
from bench.runner import Bench, Block, Section
from bench.storage_config import COMPOSITIONS, StorageConfig
from bench.storage_growth import SYSTEM, add_entry_bytes, measure_growth, paper_accounting
from bench.storage_tables import PARTS
from gicore.error_policy import writable_dir
from gicore.metrics import ssim
from gicore.paths import frame_seed
from gicore.results import Results
from gicore.scene import load_scene
from gicore.tonemap import tonemap


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
        add = partial(res.add, system=SYSTEM, scene=name)
        path = fly_through(spec, cfg.frames, cfg.resolutions[0], cfg.light_cell, res.seed)
        served = simulate_fill([f.view for f in path], [f.cell for f in path], tol)
        created = entry_frames(served)
        n_entries = len(created)
        add(metric="entries", value=n_entries, unit="count", basis="counted: GI-tree lookup rule along the path",
            **common)  # fmt: skip
        running = np.maximum.accumulate(served) + 1
        for f in sorted({int(x) for x in np.linspace(1, cfg.frames, 16)}):
            add(metric="entries_at", value=int(running[f - 1]), unit="count", at_frame=f)
        picks = [created[k] for k in spread_picks(n_entries, cfg.samples)]
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
    add, timing = partial(res.add, system=SYSTEM, scene=name), partial(res.add_timing, system=SYSTEM, scene=name)
    resolution = renderer.resolution
    timing(metric="bake_ms", samples_s=bake_s, resolution=resolution, spp=cfg.spp)
    for codec_name, reps in reports.items():
        row = {"resolution": resolution, "codec": codec_name}
        for metric in ("encode_ms", "decode_ms"):
            timing(metric=metric, samples_s=[getattr(r, metric) / 1e3 for r in reps], **row)
        for metric in ("rmse", "ssim"):
            add(metric=metric, value=float(np.mean([getattr(r, metric) for r in reps])), unit="1", stat="mean", **row)
        for section in ("gi", "di", "depth"):
            mean = float(np.mean(sections[(codec_name, section)]))
            add(metric="section_bytes", value=mean, unit="bytes", stat="mean", section=section, **row)
    return sizes


def _add_tree_bytes(
    res: Results, name: str, values: np.ndarray, n_entries: int, model_bytes: dict[str, int], row: dict
) -> None:
    """Bytes per entry (mean, std, n) and the GI tree's bytes: measured when every entry was rendered,
    else extrapolated with a 95 % interval; and its ratio to the model."""
    add = partial(res.add, system=SYSTEM, scene=name)
    n, std = add_entry_bytes(add, "entry_bytes", values, **row)
    measured = n == n_entries
    total = float(values.sum()) if measured else n_entries * float(values.mean())
    ci95 = 0.0 if measured else n_entries * 1.96 * std / math.sqrt(n)
    basis = "measured: every entry rendered" if measured else (
        f"extrapolated: {n_entries} counted entries x mean of {n} rendered maps")  # fmt: skip
    for stat, value in (("estimate", total), ("ci95", ci95)):
        add(metric="gi_tree_bytes", value=value, unit="bytes", stat=stat, basis=basis, **row)
    for precision, size in model_bytes.items():
        add(metric="ratio_to_model", value=total / size, unit="1", stat="estimate", precision=precision, **row)


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
        entries = entry_frames(served)
        stored = CellViews()  # the first pass's maps, each serving the second pass by the tree's rule
        for j in entries:
            stored.add(frames[j].view, frames[j].cell, j)
        hits = [(i, j) for i, f in enumerate(second) if (j := stored.find(f.view, f.cell, tol)) is not None]
        row = {
            "knob_position": position,
            "knob_angle_deg": angle,
            "perturb_position": cfg.perturb_position,
            "perturb_angle_deg": cfg.perturb_angle_deg,
            "resolution": frames[0].camera.width,
            "codec": codec.name,
        }
        add = partial(res.add, system=SYSTEM, scene=name, **row)
        add(metric="knob_entries", value=len(entries), unit="count")
        add(metric="knob_bytes", value=len(entries) * bytes_per_entry, unit="bytes", stat="estimate")
        add(metric="knob_hit_rate", value=len(hits) / len(second), unit="1")
        scores = defaultdict(list)
        for i, j in [hits[k] for k in spread_picks(len(hits), cfg.warp_samples)]:
            stored, reference = baked("stored", j), baked("request", i)
            gi, depth = codec.decode(codec.encode(stored.gi)), DEPTH_CODEC.decode(DEPTH_CODEC.encode(stored.depth))
            warped, _, _ = PointCloud(gi, depth, stored.camera).splat(second[i].camera, target_mask=reference.depth > 0)
            ref = tonemap(reference.gi)
            scores["knob_ssim_warped"].append(ssim(tonemap(warped), ref))
            scores["knob_ssim_stale"].append(ssim(tonemap(gi), ref))
        for metric, values in scores.items():
            add(metric=metric, value=float(np.mean(values)), unit="1", stat="mean")
            add(metric=metric, value=len(values), unit="count", stat="n")


BENCH = Bench(
    "storage",
    StorageConfig,
    measure,
    help="Table 2: GI-tree entries and bytes after a fly-through per scene, codec and resolution vs the GIGAN model; "
    "codec table; tolerance knob; the growth law over --sessions user sessions from --users users (saturation, "
    "crossover with the model, the paper's accounting decomposed).",
    dashboard=Section("table2", "Table 2: storage (GI tree vs model)", 20),
    readme=Block("GI-tree storage, Table 2", 20),
    parts=PARTS,
    needs=("gi_tree_bytes", "client_bytes", "entries"),
)
