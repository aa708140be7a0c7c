"""`bench storage` (paper Table 2): the GI tree's size after a fly-through, against GIGAN's model.

Per scene, along its fly-through of ``frames`` frames (camera path with the GI-camera FOV, light
schedule; what ``cloudbaking-prebake`` bakes), at each resolution and codec:

- **entries: counted, exactly.** The GI tree's own rule (:func:`baseline_cloudbaking.store.simulate_fill`:
  nearest stored viewpoint within Δp/Δθ in the same light cell, else a new entry) walks the path. No
  rendering is needed to count; the count is what a prebake of the path stores (tested against the store).
- **bytes per entry: measured** on ``samples`` maps rendered at entries spread evenly along the path
  (path traced at ``spp`` + OIDN, the GI view's DI, texel depth), encoded with every codec and packed as
  the stored payload. ``blend`` entries hold GI + depth (what GIGAN's output replaces), ``residual``
  entries GI + DI + depth.
- **GI-tree bytes: extrapolated** as entries × mean bytes per entry, with a 95 % interval from the
  sample's spread (``stat`` = ``estimate`` / ``ci95``); when ``samples`` covers every entry the value is
  the measured sum (``basis`` in the row's config says which).
- **GIGAN's client storage: measured**: the shipped model's files (ONNX + model.json), fp32 and fp16,
  the same for every scene.

Also the codec table (bytes, encode/decode ms, tone-mapped RMSE/SSIM of each codec on the sampled GI
maps) and the tolerance knob on the first scene, first resolution and first codec: for each (Δp, Δθ),
the entries of the first pass (counted), their bytes (extrapolated as above), the hit rate of a second,
perturbed pass (eyes moved by N(0, σ_p²) per axis, targets by N(0, (d·tan σ_θ)²) per axis; counted with
the same lookup rule), and the SSIM of the served map, pixel-level warped to the perturbed camera
(:class:`baseline_cloudbaking.warp.PointCloud`, decoded through the codec), against the map rendered at
that camera (``warp_samples`` hits per setting; also unwarped, i.e. the stale map as is).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from baseline_cloudbaking.bake import BakedMap, PathFrame, bake_map, fly_through, gi_camera, map_header
from baseline_cloudbaking.codecs import CODEC_NAMES, DEPTH_CODEC, get_codec
from baseline_cloudbaking.codecs import measure as measure_codec
from baseline_cloudbaking.protocol import pack
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, Tolerance, Viewpoint, ViewSet, simulate_fill
from bench.runner import Bench, Block, Figure, Part, Rows, Section, Table, need, pick
from bench.svg import BarChart
from gicore.cli import UserError
from gicore.metrics import ssim
from gicore.paths import frame_seed
from gicore.results import Results, read_rows
from gicore.scene import builtin_scenes, load_scene
from gicore.tonemap import tonemap
from gigan_local.inference import DEFAULT_MODEL

CodecName = Literal[CODEC_NAMES]  # type: ignore[valid-type]
COMPOSITIONS = {"blend": ("gi", "depth"), "residual": ("gi", "di", "depth")}
#: The paper's Table 2 (GB): GI tree per scene after its fly-through, and the one model for every scene.
PAPER_TABLE2_GB = {"lung": 1.15, "digestive": 2.38, "vessels": 3.36, "model": 0.2}


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
        )

    def check(self) -> None:
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
    md.write_text(table2(rows) + "\n## Codecs (sampled GI maps, per map)\n\n" + codec_table(rows))
    written.append(md)
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
    return [Table(table2(rows)), Figure((figure,)), Table(codecs_md)]


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
    return [Table("\n".join(lines) + "\n\n" + codecs)]


BENCH = Bench(
    "storage",
    StorageConfig,
    measure,
    plot,
    help="Table 2: GI-tree entries and bytes after a fly-through per scene, codec and resolution vs the GIGAN model; "
    "codec table; tolerance knob.",
    dashboard=Section("table2", "Table 2: storage (GI tree vs model)", 20, dashboard_section),
    readme=Block("GI-tree storage, Table 2", 20, readme_block),
)
