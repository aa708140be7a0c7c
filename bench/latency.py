"""`bench latency` (paper Table 1): interaction latency of GIGAN and of cloud baking, stage by stage, from
real processes talking over the simulated network (docs/architecture.md, bench latency and Honest accounting).
The rows: :mod:`bench.latency_record`; what the bench shows of them: :mod:`bench.latency_tables`."""

from __future__ import annotations

import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from baseline_cloudbaking.client import request_path_maps
from baseline_cloudbaking.codecs import DEFAULT_CODEC, CodecName
from baseline_cloudbaking.fetch import FetcherName
from baseline_cloudbaking.server.settings import check_served
from bench.latency_alone import decode_floor, gigan_alone, local_alone, path_views, requests_alone, stored_payloads
from bench.latency_floor import PARTS as FLOOR_PARTS
from bench.latency_floor import Alone, machine, record_alone, record_floor_ratios, record_targets, report
from bench.latency_record import CLOUD, CLOUD_PREFETCH, GIGAN, record
from bench.latency_tables import PARTS
from bench.processes import BIN, path_options, pinned_proxy, pinned_server, run_client, run_place, with_path_frames
from bench.runner import Bench, Block, Section
from gicore import option_groups
from gicore.blend import COMPOSITIONS
from gicore.cores import client_cores, threads
from gicore.error_policy import UserError
from gicore.frame_rows import read_summary
from gicore.results import Results
from gicore.run_config import RENDERERS
from gigan_local.inference import DEFAULT_MODEL, check_model_resolution
from network_sim.profiles import profiles_field

if TYPE_CHECKING:
    from gicore.scene import SceneSpec


@dataclass(frozen=True)
class LatencyConfig:
    """What one latency run measures (see the module docstring)."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="the one both clients fly through")
    profiles: tuple[str, ...] = profiles_field(note="the cloud-baking client runs behind each")
    resolution: int = option_groups.resolution(note="of every render and GI map: the model's")
    #: Frames per client run.
    frames: int = 300
    every: int = option_groups.every(10, note="the cloud client also asks when its view leaves the tolerance")
    orbit_frames: int = option_groups.orbit_frames()
    path: Path | None = option_groups.path()
    #: GI-map codec of the cloud-baking maps.
    codec: CodecName = DEFAULT_CODEC
    spp: int = option_groups.spp(note="of the server's maps and the evaluation GT")
    #: Score composed frames against the path-traced GT every this many frames (0: never).
    gt_every: int = field(default=10, metadata={"min": 0})
    #: How the GI map and the frame's DI are composed.
    composition: Literal[COMPOSITIONS] = "blend"  # type: ignore[valid-type]
    #: ONNX generator GIGAN runs (gigan-export output).
    model: Path = DEFAULT_MODEL
    #: Pin the server, the proxy and the clients to separate cores (taskset) where the machine has them.
    pin: bool = True
    #: Rate of the crossover sweep's link, Mbit/s (none: unlimited, the RTT alone varies).
    sweep_rate_mbit: float | None = None
    #: Largest RTT of the ratio-against-RTT curve, ms.
    sweep_max_rtt_ms: float = 500.0
    #: The cloud client's read timeout, s (bounds one miss's server render; its deadline is twice it).
    read_timeout_s: float = 120.0
    #: Renderers of both clients' per-frame raster passes, each a run of every client side by side: gl (OpenGL,
    #: level of detail auto; left out with one warning where no GL context opens) and/or mitsuba.
    renderers: tuple[str, ...] = ("gl", "mitsuba")
    #: Requests in flight of a cloud client with --prefetch extrapolate run beside the plain one on the prebaked
    #: store (first renderer only; 0: none).
    prefetch_in_flight: int = field(default=3, metadata={"min": 0, "max": 16})
    #: Frames per second both clients are paced to, as a display refreshes (none: each frame as soon as the last
    #: is composed, which leaves the cloud client's requests less of its cores than a display would).
    frame_rate: float | None = field(default=60.0, metadata={"min": 1.0, "max": 1000.0})
    #: Where the cloud client's requests and decode run (cloudbaking-client --fetch).
    fetch: FetcherName = "process"
    #: Also measure every stage alone, on the clients' cores with nothing else running (Table 1's alone and
    #: inflation columns, each system's floor).
    alone: bool = True

    @classmethod
    def quick(cls) -> LatencyConfig:
        return cls(profiles=("lan", "wan"), frames=90, every=5, spp=16)

    def check(self) -> None:
        check_served(self.resolution)
        check_model_resolution(self.model, self.resolution)
        for name in self.renderers:
            if name not in RENDERERS:
                raise UserError(f"--renderers {name!r} is not a renderer", f"use some of {', '.join(RENDERERS)}")
        if len(set(self.renderers)) != len(self.renderers):
            raise UserError(f"--renderers {','.join(self.renderers)} names a renderer twice", "name each once")


# -- measuring ----------------------------------------------------------------------------------------------
def available_renderers(asked: tuple[str, ...]) -> tuple[tuple[str, ...], dict[str, Any]]:
    """The renderers of ``asked`` that can run here, and what to record about them: ``gl`` needs a headless GL
    context (checked in this process, as the clients would open it); without one it is left out after one
    line on stderr, and ``mitsuba`` runs instead where nothing else would."""
    from gicore.gl import gl_available

    settings: dict[str, Any] = {"asked": list(asked)}
    ran = asked
    if "gl" in asked:
        ok, info = gl_available()
        settings["gl"] = info
        if not ok:
            print(f"warning: renderer gl is unavailable, measuring mitsuba alone: {info}", file=sys.stderr, flush=True)
            ran = tuple(r for r in asked if r != "gl") or ("mitsuba",)
    settings["ran"] = list(ran)
    return ran, settings


def _ran_on(folder: Path, renderer: str) -> Path:
    """``folder`` (a client's output) after checking that its raster passes ran on ``renderer``: a client that
    fell back would put another renderer's times under this one's name."""
    used = read_summary(folder)["renderer"]
    if used != renderer:
        raise RuntimeError(f"the client in {folder} was asked for renderer {renderer} but ran {used}")
    return folder


def measure(cfg: LatencyConfig, res: Results) -> None:
    scene = cfg.scenes[0]
    spec, scenes_dir, work, plan = run_place(scene, res, "latency_runs", cfg.pin)
    cfg = with_path_frames(cfg, spec)
    renderers, res.settings["renderers"] = available_renderers(cfg.renderers)
    common = {
        "resolution": cfg.resolution,
        "k": cfg.every,
        "frames": cfg.frames,
        "composition": cfg.composition,
        "spp": cfg.spp,
    }
    per_run = (
        180.0 + cfg.frames * 2.0 + (cfg.frames // cfg.gt_every + 1 if cfg.gt_every else 0) * 20.0 + cfg.read_timeout_s
    )
    path_args = ["--scene", scene, *path_options(cfg), "--resolution", str(cfg.resolution), "-k", str(cfg.every),
                 "--spp", str(cfg.spp), "--gt-every", str(cfg.gt_every), "--composition", cfg.composition,
                 "--seed", str(res.seed), "--gt-cache", str(work / "gt_cache")]  # fmt: skip
    if cfg.frame_rate:
        path_args += ["--frame-rate", f"{cfg.frame_rate:g}"]
    res.settings["frames_paced"] = f"{cfg.frame_rate:g} fps" if cfg.frame_rate else "unpaced"
    shutil.rmtree(work / "gt_cache", ignore_errors=True)  # rendered again by each bench run's code

    def client(argv: list[str], name: str, renderer: str) -> Path:
        folder = run_client(plan, [*argv, "--renderer", renderer], work / f"{name}_{renderer}", per_run)
        return _ran_on(folder, renderer)

    # Runs are keyed (system, profile, store, renderer); each renderer's run of a slot follows the other's at once,
    # so the renderers' ratios compare runs taken minutes apart at most, under the same load.
    gigan_argv = [str(BIN / "gigan-client"), *path_args, "--gi-source", "model", "--model", str(cfg.model),
                  "--threads", str(threads(plan, "client"))]  # fmt: skip
    runs = {(GIGAN, "none", "local", r): client(gigan_argv, "gigan", r) for r in renderers}
    cloud_argv = [str(BIN / "cloudbaking-client"), *path_args, "--codec", cfg.codec, "--fetch", cfg.fetch,
                  "--read-timeout", str(cfg.read_timeout_s), "--deadline", str(2 * cfg.read_timeout_s)]  # fmt: skip
    shutil.rmtree(work / "store_prebaked", ignore_errors=True)  # every run prebakes its own store
    residual = cfg.composition == "residual"  # the first pass asks for the maps the runs will ask for
    with pinned_server(plan, work / "store_prebaked", scenes_dir) as warm:
        t0 = time.perf_counter()
        first = request_path_maps(warm, scene, cfg, res.seed, residual=residual)
        prebake = {"system": CLOUD, "scene": spec.name, "store": "prebaked", **common}
        res.add(metric="prebake_maps", value=first["misses"], unit="count", **prebake)
        res.add(metric="prebake_time", value=time.perf_counter() - t0, unit="s", stat="wall", **prebake)
        for profile in cfg.profiles:
            # the prebaked store answers every renderer's run (its maps do not depend on the client's renderer)
            for renderer in renderers:
                with pinned_proxy(plan, profile, warm, res.seed) as url:
                    runs[CLOUD, profile, "prebaked", renderer] = client(
                        [*cloud_argv, "--server", url], f"cloud_{profile}_prebaked", renderer
                    )
                if cfg.prefetch_in_flight and renderer == renderers[0]:
                    prefetch = ["--prefetch", "extrapolate", "--in-flight", str(cfg.prefetch_in_flight)]
                    with pinned_proxy(plan, profile, warm, res.seed) as url:
                        runs[CLOUD_PREFETCH, profile, "prebaked", renderer] = client(
                            [*cloud_argv, *prefetch, "--server", url], f"cloud_prefetch_{profile}_prebaked", renderer
                        )
        if cfg.alone:
            alone = measure_alone(cfg, plan, scene, spec, warm, renderers, res.seed)
            decode = decode_floor(stored_payloads(work / "store_prebaked", spec.name))
        for profile in cfg.profiles:
            # a cold store per renderer: each run's requests miss as the other's did
            for renderer in renderers:
                store = work / f"store_cold_{profile}_{renderer}"
                shutil.rmtree(store, ignore_errors=True)
                with pinned_server(plan, store, scenes_dir) as cold:
                    # one request off the path compiles every pass and stores nothing a run would hit
                    request_path_maps(cold, scene, cfg, res.seed, residual=residual, off_path=True)
                    with pinned_proxy(plan, profile, cold, res.seed) as url:
                        runs[CLOUD, profile, "cold", renderer] = client(
                            [*cloud_argv, "--server", url], f"cloud_{profile}_cold", renderer
                        )
                shutil.rmtree(store, ignore_errors=True)
    shutil.rmtree(work / "store_prebaked", ignore_errors=True)
    record(res, spec.name, cfg, runs, common)
    if cfg.alone:
        warnings = record_alone(res, spec.name, alone)
        record_floor_ratios(res, spec.name, alone)
        report(warnings, record_targets(res, spec.name, decode, threads(plan, "client"), machine()))


def measure_alone(
    cfg: LatencyConfig, plan: dict[str, Any], scene: str, spec: SceneSpec, server: str, renderers: tuple[str, ...],
    seed: int,
) -> Alone:  # fmt: skip
    """Every stage alone (:mod:`bench.latency_alone`) in this process on the clients' cores: GIGAN's loop per
    renderer; per profile the requests through a fresh proxy in front of ``server`` (the prebaked store), and the
    cloud client's loop on the first profile's maps per renderer (it does not depend on the profile)."""
    views = path_views(spec, cfg, seed)
    alone: Alone = {}
    with client_cores(plan):
        for renderer in renderers:
            alone[GIGAN, "none", renderer] = gigan_alone(scene, cfg, renderer, seed, threads(plan, "client"),
                                                         cfg.frame_rate)  # fmt: skip
        local: dict[str, dict[str, list[float]]] = {}
        for profile in cfg.profiles:
            with pinned_proxy(plan, profile, server, seed) as url:
                requests, maps = requests_alone(url, scene, spec, cfg, views)
            for renderer in renderers:
                if renderer not in local:
                    local[renderer] = local_alone(spec, cfg, renderer, views, maps)
                alone[CLOUD, profile, renderer] = requests | local[renderer]
    return alone


BENCH = Bench(
    "latency",
    LatencyConfig,
    measure,
    help="Table 1: interaction latency per stage of GIGAN and cloud baking (prebaked and cold store) from real "
    "processes over simulated network profiles; ratios, crossover RTT, SSIM along the path.",
    dashboard=Section("table1", "Table 1: interaction latency", 10),
    readme=Block("Interaction latency, Table 1", 10),
    parts=(*PARTS, *FLOOR_PARTS),
    needs=("total", "total_ratio"),
)
