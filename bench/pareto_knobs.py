"""`bench pareto`'s knobs: the configuration swept (:class:`ParetoConfig`), and how each knob's points are
measured (or read from earlier runs): GIGAN's maps per model and GI-camera FOV, cloud baking's bake spp, bake
resolution, codec x link x cache state and store tolerance, and both systems per frame (``bench frequency``'s
runs); :func:`mark_dominated` flags the points off each front."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from bench.common import WARP_LABELS, WARPS
from bench.runner import FOV_DEGREES, Bench, execute
from gicore import option_groups
from gicore.blend import COMPOSITIONS
from gicore.error_policy import UserError
from gicore.results import Results, find_results, read_rows
from gigan_local.inference import DEFAULT_MODEL, check_model_resolution, model_info
from network_sim.exchange import CloudCost
from network_sim.profiles import profiles_field

if TYPE_CHECKING:
    from baseline_cloudbaking.viewpoints import Tolerance

GIGAN, CLOUD, ABLATION = "gigan", "cloud_baking", "ablation"
PER_MAP, PER_FRAME = "GI map", "frame"
#: Bytes of a GI-map request (JSON body + HTTP header), as the cloud client sends it (measured: ~430 B).
REQUEST_BYTES = 450


@dataclass(frozen=True)
class ParetoConfig:
    """The knobs swept (see the module docstring)."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="of every point")
    #: Folder of earlier bench outputs (convergence.csv, frequency.csv) whose points are read, not measured;
    #: none: measure all.
    from_dir: Path | None = None
    resolution: int = option_groups.resolution(note="of GI maps and frames: the models'")
    #: Views along the fly-through each per-map point averages over.
    views: int = 3
    #: Samples per pixel of the per-map reference (path traced, OIDN).
    reference_spp: int = 1024
    #: GIGAN: name -> exported ONNX model (width and precision knob).
    models: dict[str, Path] = field(
        default_factory=lambda: {"fp16": DEFAULT_MODEL, "fp32": DEFAULT_MODEL.with_name("model_fp32.onnx")}
    )
    #: GIGAN: GI-camera FOVs, degrees.
    gi_fovs: tuple[float, ...] = field(default=(60.0, 90.0, 120.0), metadata=FOV_DEGREES)
    #: Cloud baking: bake spp (each with and without OIDN).
    spps: tuple[int, ...] = (1, 4, 16, 64, 256)
    #: Cloud baking: spp of the baked map behind the codec, resolution and tolerance points (then OIDN).
    bake_spp: int = 64
    #: Cloud baking: bake resolutions (lower ones are upsampled to --resolution).
    resolutions: tuple[int, ...] = (64, 128, 256)
    #: Cloud baking: codecs, NAME or NAME:QUALITY (jpeg, webp, avif take a quality).
    codecs: tuple[str, ...] = (
        "jpeg:50",
        "jpeg:75",
        "jpeg:90",
        "jpeg:95",
        "webp:50",
        "webp:90",
        "avif:50",
        "avif:80",
        "png",
        "exr-half",
        "zstd-f16",
    )
    profiles: tuple[str, ...] = profiles_field(
        ("lan", "wifi", "lte", "wan", "3g"), note="cloud baking: the maps travel over each"
    )
    #: Cloud baking: store tolerances as DP:DTHETA (scene units : degrees).
    tolerances: tuple[str, ...] = ("0.01:0.5", "0.05:2", "0.1:5", "0.2:10")
    #: Fly-through frames of the tolerance points' hit rate.
    path_frames: int = 600
    #: Per frame: GI periods k.
    ks: tuple[int, ...] = (1, 5, 10, 30)
    #: Per frame: warp methods.
    warps: tuple[Literal[WARPS], ...] = ("structure", "pixel", "none")
    #: Per frame: compositions.
    compositions: tuple[Literal[COMPOSITIONS], ...] = ("blend", "residual")
    #: Per frame: client frames per configuration.
    frames: int = 60
    #: Per frame: score against path-traced GT every this many frames.
    gt_every: int = 6
    #: Per frame: spp of the path-traced GT (and of the server's maps).
    frame_spp: int = 64
    #: Timed repeats per per-map measurement, after one warm-up.
    repeats: int = 5

    @classmethod
    def quick(cls) -> ParetoConfig:
        return cls(
            views=1, reference_spp=128, gi_fovs=(60.0, 90.0), spps=(1, 4, 16), bake_spp=16, resolutions=(128, 256),
            codecs=("jpeg:50", "jpeg:90", "webp:90", "png", "zstd-f16"), profiles=("lan", "wan", "3g"),
            tolerances=("0.05:2", "0.2:10"), path_frames=300, ks=(1, 8), warps=("structure", "pixel"), frames=16,
            gt_every=8, frame_spp=8, repeats=2,
        )  # fmt: skip

    def check(self) -> None:
        from baseline_cloudbaking.codecs import CODEC_NAMES, QUALITY_OPTION, get_codec

        for name, path in self.models.items():
            check_model_resolution(path, self.resolution, f"--models {name}")
        for spec in self.codecs:
            try:
                get_codec(spec)
            except ValueError:
                raise UserError(
                    f"--codecs {spec!r} is not NAME or NAME:QUALITY",
                    f"use {', '.join(CODEC_NAMES)}; quality 1-100 for {', '.join(QUALITY_OPTION)}",
                ) from None
        for text in self.tolerances:
            parse_tolerance(text)
        if max(self.resolutions) > self.resolution:
            raise UserError(
                f"--resolutions {max(self.resolutions)} exceeds --resolution {self.resolution}",
                "bake at the map resolution or below",
            )
        if self.from_dir is not None and not self.from_dir.is_dir():
            raise UserError(
                f"--from-dir {self.from_dir} is not a folder",
                "give the folder of earlier bench outputs, or leave it out",
            )


def parse_tolerance(text: str) -> Tolerance:
    """A ``--tolerances`` value: its points warp a map by half of Δp and Δθ, so Δp > 0 and 0 < Δθ < 180."""
    from baseline_cloudbaking.viewpoints import Tolerance

    try:
        tol = Tolerance.parse(text)
    except ValueError as exc:
        raise UserError(f"--tolerances {exc}", "give e.g. 0.05:2 (scene units : degrees)") from None
    if not (tol.position > 0 and 0 < tol.angle_deg < 180):
        raise UserError(f"--tolerances {text!r} is out of range", "Δp > 0 and 0 < Δθ < 180")
    return tol


# -- measuring -------------------------------------------------------------------------------------------------
@dataclass
class Context:
    """The scene, its renderer at the map resolution, the GI views, their references."""

    cfg: ParetoConfig
    spec: Any
    renderer: Any
    cameras: list[Any]
    light: list[tuple[float, float, float]]
    seed: int
    references: dict[Any, np.ndarray] = field(default_factory=dict)

    def reference(self, camera, light) -> np.ndarray:
        """Tone-mapped path-traced reference at ``camera`` (``reference_spp``, OIDN; another seed)."""
        from gicore.ground_truth import render_gt
        from gicore.tonemap import tonemap

        key = (camera, tuple(light))
        if key not in self.references:
            self.references[key] = tonemap(
                render_gt(self.renderer, camera, light, self.cfg.reference_spp, self.seed + 10_007, True)
            )
        return self.references[key]

    def error(self, image: np.ndarray, camera, light) -> float:
        from gicore.metrics import ssim
        from gicore.tonemap import tonemap

        return 1.0 - ssim(tonemap(image), self.reference(camera, light))


def _median_ms(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    from gicore.timing import time_repeats

    samples, result = time_repeats(fn, repeats)
    return float(np.median(samples)) * 1e3, result


class Points:
    """Collects points: (system, unit, config) -> run time and error."""

    def __init__(self) -> None:
        self.items: list[dict[str, Any]] = []

    def add(
        self, system: str, per: str, knob: str, time_ms: float, error: float, source: str = "measured", **config: Any
    ) -> None:
        self.items.append(
            {
                "system": system,
                "per": per,
                "time": time_ms,
                "error": error,
                "config": {"knob": knob, "per": per, "source": source, **config},
            }
        )


def gigan_maps(ctx: Context, pts: Points) -> None:
    """GIGAN per map: each model × GI-camera FOV."""
    from gigan_local.inference import GIModel

    cfg, r = ctx.cfg, ctx.renderer
    for name, path in cfg.models.items():
        model = GIModel(path, threads=2)
        info = model_info(path, f"--models {name}")
        for fov in cfg.gi_fovs:
            times, errors = [], []
            for cam, light in zip(ctx.cameras, ctx.light):
                gi_cam = cam.with_fov(fov)

                def produce(gi_cam=gi_cam, light=light):
                    return model.predict(r.render_di_gbuffers(gi_cam, light, seed=ctx.seed, centre=True))

                ms, image = _median_ms(produce, cfg.repeats)
                times.append(ms)
                errors.append(ctx.error(image, gi_cam, light))
            pts.add(GIGAN, PER_MAP, "model × GI-camera FOV", float(np.median(times)), float(np.mean(errors)),
                    model=name, gi_fov=fov, ngf=info["ngf"], precision=info["precision"],
                    resolution=cfg.resolution)  # fmt: skip


def _bake(ctx: Context, cam, light, spp: int, denoise: bool, renderer=None) -> np.ndarray:
    from gicore.ground_truth import render_gt

    return render_gt(renderer or ctx.renderer, cam, light, spp, ctx.seed, denoise)


def bake_spp(ctx: Context, pts: Points, from_dir: Path | None) -> None:
    """Cloud baking per map: bake spp × OIDN (from convergence.csv when it has this scene)."""
    cfg = ctx.cfg
    read = _convergence_points(from_dir, ctx.spec.name, cfg.resolution) if from_dir else []
    if read:
        for p in read:
            pts.add(CLOUD, PER_MAP, "bake spp × denoise", p["time"], p["error"], p["source"], **p["config"])
        return
    gi_fov = ctx.spec.camera.gi_fov
    for spp in cfg.spps:
        for denoise in (False, True):
            times, errors = [], []
            for cam, light in zip(ctx.cameras, ctx.light):
                ms, image = _median_ms(
                    lambda cam=cam, light=light: _bake(ctx, cam.with_fov(gi_fov), light, spp, denoise), cfg.repeats
                )
                times.append(ms)
                errors.append(ctx.error(image, cam.with_fov(gi_fov), light))
            pts.add(CLOUD, PER_MAP, "bake spp × denoise", float(np.median(times)), float(np.mean(errors)),
                    spp=spp, denoise=denoise, resolution=cfg.resolution, gi_fov=gi_fov)  # fmt: skip


def _convergence_points(from_dir: Path, scene: str, resolution: int) -> list[dict[str, Any]]:
    """Points of the newest convergence.csv under ``from_dir`` with ``scene`` at ``resolution``: render time and
    1 - SSIM."""

    for path in find_results(from_dir, "convergence"):
        rows = [r for r in read_rows(path) if r["scene"] == scene and r["config"].get("resolution") == resolution]
        if rows:
            break
    else:
        return []
    source = str(path.relative_to(from_dir))
    times = {
        (r["system"], r["config"]["spp"]): r for r in rows if r["metric"] == "render_time" and r["stat"] == "median"
    }
    out = []
    for r in rows:
        if r["metric"] == "ssim" and (r["system"], r["config"]["spp"]) in times:
            t = times[r["system"], r["config"]["spp"]]
            config = {
                "spp": r["config"]["spp"],
                "denoise": r["system"] == "path+oidn",
                "resolution": r["config"]["resolution"],
            }
            out.append({"time": t["value"], "error": 1.0 - r["value"], "source": source, "config": config})
    return out


def bake_resolution(ctx: Context, pts: Points) -> dict[str, float]:
    """Cloud baking per map: bake resolution (upsampled); returns the full-resolution bake's median ms."""
    from PIL import Image

    from gicore.render import Renderer

    cfg = ctx.cfg
    gi_fov = ctx.spec.camera.gi_fov
    full_ms = math.nan
    for res in cfg.resolutions:
        renderer = ctx.renderer if res == cfg.resolution else Renderer(ctx.spec, res)
        times, errors = [], []
        for cam, light in zip(ctx.cameras, ctx.light):
            small = replace(cam.with_fov(gi_fov), width=res, height=res)
            ms, image = _median_ms(
                lambda small=small, light=light: _bake(ctx, small, light, cfg.bake_spp, True, renderer), cfg.repeats
            )
            if res != cfg.resolution:
                image = np.stack(
                    [
                        np.asarray(
                            Image.fromarray(image[..., c]).resize((cfg.resolution, cfg.resolution), Image.BILINEAR)
                        )
                        for c in range(3)
                    ],
                    -1,
                )
            times.append(ms)
            errors.append(ctx.error(image, cam.with_fov(gi_fov), light))
        pts.add(CLOUD, PER_MAP, "bake resolution", float(np.median(times)), float(np.mean(errors)),
                bake_resolution=res, spp=cfg.bake_spp, denoise=True, resolution=cfg.resolution,
                gi_fov=gi_fov)  # fmt: skip
        if res == cfg.resolution:
            full_ms = float(np.median(times))
    return {"bake_ms": full_ms}


def codecs_and_links(ctx: Context, pts: Points, bake_ms: float) -> dict[str, Any]:
    """Cloud baking per map: codec and quality × network profile × cache state. Returns the first codec's
    payload bytes, encode and decode times (the tolerance points' hit and miss paths)."""
    from baseline_cloudbaking.codecs import DEPTH_CODEC, get_codec
    from baseline_cloudbaking.protocol import pack
    from gicore.gi_map import texel_depth
    from network_sim import profiles

    cfg = ctx.cfg
    gi_fov = ctx.spec.camera.gi_fov
    maps = []
    for cam, light in zip(ctx.cameras, ctx.light):
        gi_cam = cam.with_fov(gi_fov)
        maps.append((gi_cam, light, _bake(ctx, gi_cam, light, cfg.bake_spp, True), texel_depth(ctx.renderer, gi_cam)))
    first: dict[str, Any] = {}
    for spec in cfg.codecs:
        codec = get_codec(spec)
        enc, dec, sizes, errors = [], [], [], []
        for gi_cam, light, image, depth in maps:
            e_ms, data = _median_ms(lambda image=image: codec.encode(image), cfg.repeats)
            d_ms, decoded = _median_ms(lambda data=data: codec.decode(data), cfg.repeats)
            payload = pack({"codec": spec, "camera": gi_cam.to_dict(), "view": gi_cam.view().tolist(),
                            "proj": gi_cam.proj().tolist()},
                           {"gi": data, "depth": DEPTH_CODEC.encode(depth)})  # fmt: skip
            enc.append(e_ms)
            dec.append(d_ms)
            sizes.append(len(payload) + 200)  # + the HTTP response header
            errors.append(ctx.error(decoded, gi_cam, light))
        encode_ms, decode_ms, nbytes, error = (
            float(np.median(enc)),
            float(np.median(dec)),
            int(np.median(sizes)),
            float(np.mean(errors)),
        )
        first = first or {"bytes": nbytes, "encode_ms": encode_ms, "decode_ms": decode_ms, "codec": spec}
        for profile in cfg.profiles:
            link = profiles.get(profile).link(seed=ctx.seed)
            for cache in ("miss", "hit"):
                server = bake_ms + encode_ms if cache == "miss" else 0.0
                network = CloudCost(0.0, server, REQUEST_BYTES, nbytes).network_ms(link, starts=5)
                pts.add(CLOUD, PER_MAP, "codec × quality × profile × cache", server + network + decode_ms, error,
                        codec=spec, profile=profile, cache=cache, bytes=nbytes, spp=cfg.bake_spp, denoise=True,
                        resolution=cfg.resolution, gi_fov=gi_fov)  # fmt: skip
    return first


def tolerances(ctx: Context, pts: Points, bake_ms: float, hit_path: dict[str, Any]) -> None:
    """Cloud baking per map: store tolerance (warped stale map at half the tolerance; hit-rate-weighted time)."""
    from baseline_cloudbaking.viewpoints import Viewpoint, simulate_fill
    from baseline_cloudbaking.warp import PointCloud
    from gicore.gi_map import texel_depth
    from gicore.paths import camera_path
    from network_sim import profiles

    cfg = ctx.cfg
    gi_fov = ctx.spec.camera.gi_fov
    link = profiles.get("lan").link(seed=ctx.seed)
    hit_ms = CloudCost(0.0, 0.0, REQUEST_BYTES, hit_path["bytes"]).network_ms(link) + hit_path["decode_ms"]
    server_ms = bake_ms + hit_path["encode_ms"]
    miss_ms = (
        CloudCost(0.0, server_ms, REQUEST_BYTES, hit_path["bytes"]).network_ms(link) + server_ms + hit_path["decode_ms"]
    )
    path = camera_path(ctx.spec, cfg.path_frames, seed=ctx.seed, fov=gi_fov, resolution=cfg.resolution)
    rng = np.random.default_rng(ctx.seed)
    for text in cfg.tolerances:
        tol = parse_tolerance(text)
        dp, angle = tol.position, tol.angle_deg
        # a second fly-through near the first: eyes moved by dp/2, targets turned by about angle/2
        first = [Viewpoint.look_at(c.origin, c.target) for c in path]
        moved = []
        for c in path:
            eye = np.add(c.origin, rng.normal(0.0, dp / 2 / math.sqrt(3), 3))
            reach = float(np.linalg.norm(np.subtract(c.target, c.origin))) * math.tan(math.radians(angle / 2))
            moved.append(
                Viewpoint.look_at(tuple(eye), tuple(np.add(c.target, rng.normal(0.0, reach / math.sqrt(3), 3))))
            )
        served = simulate_fill(first + moved, [None] * (2 * len(path)), tol)
        known = set(served[: len(path)])
        hit_rate = float(np.mean([s in known for s in served[len(path) :]]))
        warp_ms, errors = [], []
        for cam, light in zip(ctx.cameras, ctx.light):
            stored = cam.with_fov(gi_fov)
            request = stored.moved(right=dp / 2).turned(angle / 2)
            cloud = PointCloud(_bake(ctx, stored, light, cfg.bake_spp, True), texel_depth(ctx.renderer, stored), stored)
            mask = ctx.renderer.render_uv(request)["mask"]
            ms, (image, _, _) = _median_ms(
                lambda request=request, mask=mask: cloud.splat(request, target_mask=mask), cfg.repeats
            )
            warp_ms.append(ms)
            errors.append(ctx.error(image, request, light))
        mean_ms = hit_rate * (hit_ms + float(np.median(warp_ms))) + (1.0 - hit_rate) * miss_ms
        pts.add(CLOUD, PER_MAP, "store tolerance", mean_ms, float(np.mean(errors)), tolerance_position=dp,
                tolerance_angle_deg=angle, hit_rate=round(hit_rate, 4), codec=hit_path["codec"], profile="lan",
                spp=cfg.bake_spp, resolution=cfg.resolution, gi_fov=gi_fov)  # fmt: skip


def frame_system(gi_source: str, warp: str) -> str:
    """The system a per-frame point is: GIGAN = the generator's maps (``gi_source`` ``model``) warped
    structure-aware; cloud baking = path-traced maps (``gt``) warped pixel-level; either
    without warping too. Any other pairing (``warp`` is a ``WARP_LABELS`` value) is a cross-system ablation."""
    system, own = {"model": (GIGAN, "structure"), "gt": (CLOUD, "pixel")}[gi_source]
    return system if warp in (WARP_LABELS[own], WARP_LABELS["none"]) else ABLATION


def per_frame(ctx: Context, pts: Points, res: Results, frequency: Bench) -> None:
    """Per frame: GI period k × warp × composition, GIGAN's maps and the server's (frequency.csv, read or run by
    ``frequency``)."""

    cfg = ctx.cfg
    for source in ("model", "gt"):
        rows, origin = (
            _frequency_rows(cfg.from_dir, ctx.spec.name, source, cfg.resolution) if cfg.from_dir else ([], "")
        )
        if not rows:
            run = frequency.config(
                scenes=cfg.scenes, resolution=cfg.resolution, ks=cfg.ks, frames=cfg.frames, warps=cfg.warps,
                compositions=cfg.compositions, gt_every=cfg.gt_every, spp=cfg.frame_spp, gi_source=source,
                model=cfg.models.get("fp16", next(iter(cfg.models.values()))),
            )  # fmt: skip
            folder = res.out / "pareto_runs" / f"frequency_{source}"
            execute(frequency, run, folder, res.seed)
            rows, origin = (
                [r for r in read_rows(folder / "frequency.csv") if r["scene"] == ctx.spec.name],
                f"pareto_runs/frequency_{source}/frequency.csv",
            )
        by_point: dict[str, dict[str, Any]] = {}
        for r in rows:
            key = json.dumps([r["system"], r["config"]], sort_keys=True)
            by_point.setdefault(key, {"warp": r["system"], "config": r["config"]})[r["metric"]] = r["value"]
        for p in by_point.values():
            c = p["config"]
            # the generator's map is made on the client, so its cost is paid per frame; the server's map is paid in
            # latency
            extra = {"map_latency_budget_ms": round(c["k"] * p["frame_time"], 3)} if source == "gt" else {}
            time_ms = p["frame_time"] + (p["gi_time"] / c["k"] if source == "model" else 0.0)
            pts.add(frame_system(source, p["warp"]), PER_FRAME, "k × warp × composition", time_ms, 1.0 - p["ssim"],
                    origin or "measured", warp=p["warp"], k=c["k"], composition=c["composition"], tau=c["tau"],
                    gi_source=c["gi_source"], resolution=c["resolution"], spp=c["spp"], **extra)  # fmt: skip


def _frequency_rows(from_dir: Path, scene: str, source: str, resolution: int) -> tuple[list[dict[str, Any]], str]:

    for path in find_results(from_dir, "frequency"):
        rows = [
            r
            for r in read_rows(path)
            if r["scene"] == scene
            and r["config"].get("gi_source") == source
            and r["config"].get("resolution") == resolution
        ]
        if rows:
            return rows, str(path.relative_to(from_dir))
    return [], ""


def mark_dominated(items: list[dict[str, Any]]) -> None:
    """Set ``dominated`` (by a point of the same system and unit) and ``dominated_combined`` (by a ``gigan`` or
    ``cloud_baking`` point of the same unit: an ablation is no system's configuration, so it dominates nothing)."""
    for flag, by in (
        ("dominated", lambda p, q: q["system"] == p["system"] and q["per"] == p["per"]),
        ("dominated_combined", lambda p, q: q["system"] != ABLATION and q["per"] == p["per"]),
    ):
        for p in items:
            p[flag] = any(
                by(p, q)
                and q["time"] <= p["time"]
                and q["error"] <= p["error"]
                and (q["time"] < p["time"] or q["error"] < p["error"])
                for q in items
            )
