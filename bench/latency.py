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

import numpy as np

from baseline_cloudbaking.client import request_path_maps
from baseline_cloudbaking.client_run import open_cloud_warp
from baseline_cloudbaking.codecs import DEFAULT_CODEC, CodecName
from baseline_cloudbaking.fetch import FetcherName
from baseline_cloudbaking.server.settings import check_served
from baseline_cloudbaking.stages_alone import decode_floor, local_alone, requests_alone, stored_payloads
from bench.latency_floor import PARTS as FLOOR_PARTS
from bench.latency_floor import Alone, record_alone, record_floor_ratios, record_targets, report
from bench.latency_record import CLOUD, CLOUD_PREFETCH, GIGAN, LATENESS_FILE, pool, record
from bench.latency_tables import PARTS
from bench.processes import BIN, path_options, pinned_proxy, pinned_server, run_client, run_place, with_path_frames
from bench.runner import Bench, Block, Section
from gicore import option_groups
from gicore.blend import COMPOSITIONS
from gicore.cores import client_cores, threads
from gicore.error_policy import UserError
from gicore.frame_rows import read_summary
from gicore.path_file import flown_path
from gicore.results import Results, machine_text
from gicore.run_config import RENDERERS
from gigan_local.client import ClientConfig, stages_of_run
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
    #: Frames per second both clients are paced to, as a display refreshes (0: each frame as soon as the last
    #: is composed, which leaves the cloud client's requests less of its cores than a display would).
    frame_rate: float = field(default=60.0, metadata={"min": 0.0, "max": 1000.0})
    #: Where the cloud client's requests and decode run (cloudbaking-client --fetch).
    fetch: FetcherName = "process"
    #: Also measure every stage alone, on the clients' cores with nothing else running (Table 1's alone and
    #: inflation columns, each system's floor).
    alone: bool = True
    #: Run the whole measurement (every client run and the stages alone) this many times, each repeat in its own
    #: folder (latency_runs/r0, r1, ...), and record the repeats pooled; from 3 on, each ratio's and crossover's
    #: interval is over the runs (bench.latency_record), which shows how much runs vary, not only their maps.
    repeats: int = field(default=1, metadata={"min": 1, "max": 20})

    @classmethod
    def quick(cls) -> LatencyConfig:
        """Table 1 behind lan and wan along 200 frames (GI period k = 5: GIGAN's 40 maps), 16 spp. The sizing is
        the cold store's: its client asks only when no map it holds or awaits is within the server's tolerance, so
        it sends a request per miss, and a miss took 1 to 2 s on the 2-core Xeon (its path tracing shares the
        cores with the client): one every 35 to 70 frames after the first two, so 90 frames measured 1 to 3 misses
        and 150 frames 3 behind each profile. 200 frames give each miss column 3 or more, the fewest an interval
        rests on. Here, with other jobs running, ``--renderers gl`` (make run's Table 1) took 3 min at 150 frames;
        200 frames take about a third longer, and both renderers (the default) run every client twice."""
        return cls(profiles=("lan", "wan"), frames=200, every=5, spp=16)

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


@dataclass(frozen=True)
class _Place:
    """What every repeat of a run shares: its config, scene, pinning plan and renderers, the clients' common
    options and their time limit."""

    cfg: LatencyConfig
    spec: SceneSpec
    scenes_dir: Path | None
    plan: dict[str, Any]
    renderers: tuple[str, ...]
    seed: int
    path_args: list[str]
    per_run_s: float

    def client(self, argv: list[str], out: Path, renderer: str) -> Path:
        folder = run_client(self.plan, [*argv, "--renderer", renderer], out, self.per_run_s)
        return _ran_on(folder, renderer)


@dataclass(frozen=True)
class _Repeat:
    """One repeat of the measurement: its client runs' folders, its prebake (maps baked, seconds) and, where the
    stages alone were measured, their samples and the decode floor's."""

    runs: dict[tuple[str, str, str, str], Path]
    prebake_maps: int
    prebake_s: float
    alone: Alone
    decode: dict[str, list[float]]


def measure(cfg: LatencyConfig, res: Results) -> None:
    scene = cfg.scenes[0]
    spec, scenes_dir, work, plan, flown = run_place(scene, res, "latency_runs", cfg.pin, cfg.path)
    cfg = with_path_frames(cfg, flown)
    renderers, res.settings["renderers"] = available_renderers(cfg.renderers)
    common = {
        "resolution": cfg.resolution,
        "k": cfg.every,
        "frames": cfg.frames,
        "composition": cfg.composition,
        "spp": cfg.spp,
        "repeats": cfg.repeats,
        "frame_rate": cfg.frame_rate,
    }
    per_run_s = (
        180.0 + cfg.frames * 2.0 + (cfg.frames // cfg.gt_every + 1 if cfg.gt_every else 0) * 20.0 + cfg.read_timeout_s
    )
    path_args = ["--scene", scene, *path_options(cfg), "--resolution", str(cfg.resolution), "-k", str(cfg.every),
                 "--spp", str(cfg.spp), "--gt-every", str(cfg.gt_every), "--composition", cfg.composition,
                 "--seed", str(res.seed), "--gt-cache", str(work / "gt_cache")]  # fmt: skip
    if cfg.frame_rate:
        path_args += ["--frame-rate", f"{cfg.frame_rate:g}"]
    res.settings["frames_paced"] = f"{cfg.frame_rate:g} fps" if cfg.frame_rate else "unpaced"
    # rendered again by each bench run's code; its repeats share it (the same path, seed and scored frames)
    shutil.rmtree(work / "gt_cache", ignore_errors=True)
    place = _Place(cfg, spec, scenes_dir, plan, renderers, res.seed, path_args, per_run_s)
    # one repeat works in latency_runs itself, as runs did before there were repeats; several each in r<i>
    repeats = [_repeat(place, work if cfg.repeats == 1 else work / f"r{i}") for i in range(cfg.repeats)]
    prebake = {"system": CLOUD, "scene": spec.name, "store": "prebaked", **common}
    res.add(metric="prebake_maps", value=repeats[0].prebake_maps, unit="count", **prebake)  # the same path each time
    prebake_s = float(np.median([r.prebake_s for r in repeats]))
    res.add(metric="prebake_time", value=prebake_s, unit="s", stat="wall", **prebake)
    record(res, spec.name, cfg, {key: [r.runs[key] for r in repeats] for key in repeats[0].runs}, common)
    if cfg.alone and all(r.alone for r in repeats):
        alone = {key: pool([r.alone[key] for r in repeats]) for key in repeats[0].alone}
        warnings = record_alone(res, spec.name, alone)
        record_floor_ratios(res, spec.name, alone)
        decode = pool([r.decode for r in repeats])
        report(warnings, record_targets(res, spec.name, decode, threads(plan, "client"), machine_text()))


def _repeat(place: _Place, folder: Path) -> _Repeat:
    """Every client run of the bench once, working in ``folder``: GIGAN's per renderer, then against a store
    prebaked along the path the cloud client's per profile and renderer (and its prefetching twin), the stages
    alone, and the cloud client's against a cold store per profile and renderer."""
    cfg, scene, plan = place.cfg, place.cfg.scenes[0], place.plan
    folder.mkdir(parents=True, exist_ok=True)
    # Runs are keyed (system, profile, store, renderer); each renderer's run of a slot follows the other's at once,
    # so the renderers' ratios compare runs taken minutes apart at most, under the same load.
    gigan_argv = [str(BIN / "gigan-client"), *place.path_args, "--gi-source", "model", "--model", str(cfg.model),
                  "--threads", str(threads(plan, "client"))]  # fmt: skip
    runs = {(GIGAN, "none", "local", r): place.client(gigan_argv, folder / f"gigan_{r}", r) for r in place.renderers}
    cloud_argv = [str(BIN / "cloudbaking-client"), *place.path_args, "--codec", cfg.codec, "--fetch", cfg.fetch,
                  "--read-timeout", str(cfg.read_timeout_s), "--deadline", str(2 * cfg.read_timeout_s)]  # fmt: skip
    store = folder / "store_prebaked"
    shutil.rmtree(store, ignore_errors=True)  # every repeat prebakes its own store
    residual = cfg.composition == "residual"  # the first pass asks for the maps the runs will ask for
    alone: Alone = {}
    decode: dict[str, list[float]] = {}
    with pinned_server(plan, store, place.scenes_dir) as warm:
        t0 = time.perf_counter()
        first = request_path_maps(warm, scene, cfg, place.seed, residual=residual)
        prebake_s = time.perf_counter() - t0
        for profile in cfg.profiles:
            # the prebaked store answers every renderer's run (its maps do not depend on the client's renderer)
            for renderer in place.renderers:
                out = folder / f"cloud_{profile}_prebaked_{renderer}"
                with pinned_proxy(plan, profile, warm, place.seed, out / LATENESS_FILE) as url:
                    runs[CLOUD, profile, "prebaked", renderer] = place.client([*cloud_argv, "--server", url], out,
                                                                              renderer)  # fmt: skip
                if cfg.prefetch_in_flight and renderer == place.renderers[0]:
                    prefetch = ["--prefetch", "extrapolate", "--in-flight", str(cfg.prefetch_in_flight)]
                    with pinned_proxy(plan, profile, warm, place.seed) as url:
                        runs[CLOUD_PREFETCH, profile, "prebaked", renderer] = place.client(
                            [*cloud_argv, *prefetch, "--server", url],
                            folder / f"cloud_prefetch_{profile}_prebaked_{renderer}",
                            renderer,
                        )
        if cfg.alone:
            try:
                alone = measure_alone(cfg, plan, scene, place.spec, warm, place.renderers, place.seed)
                decode = decode_floor(stored_payloads(store, place.spec.name))
            except Exception as exc:  # the client runs stand without it: one line, and the table says nothing alone
                what = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                print(f"warning: the stages alone were not measured ({what})", file=sys.stderr, flush=True)
        runs |= _cold_runs(place, folder, cloud_argv, residual)
    shutil.rmtree(store, ignore_errors=True)
    return _Repeat(runs, first["misses"], prebake_s, alone, decode)


def _cold_runs(
    place: _Place, folder: Path, cloud_argv: list[str], residual: bool
) -> dict[tuple[str, str, str, str], Path]:
    """The cloud client against a cold store per profile and renderer, each store its own: each run's requests
    miss as the other's did."""
    runs = {}
    for profile in place.cfg.profiles:
        for renderer in place.renderers:
            store = folder / f"store_cold_{profile}_{renderer}"
            shutil.rmtree(store, ignore_errors=True)
            with pinned_server(place.plan, store, place.scenes_dir) as cold:
                # one request off the path compiles every pass and stores nothing a run would hit
                request_path_maps(cold, place.cfg.scenes[0], place.cfg, place.seed, residual=residual, off_path=True)
                out = folder / f"cloud_{profile}_cold_{renderer}"
                with pinned_proxy(place.plan, profile, cold, place.seed, out / LATENESS_FILE) as url:
                    runs[CLOUD, profile, "cold", renderer] = place.client([*cloud_argv, "--server", url], out,
                                                                          renderer)  # fmt: skip
            shutil.rmtree(store, ignore_errors=True)
    return runs


def measure_alone(
    cfg: LatencyConfig, plan: dict[str, Any], scene: str, spec: SceneSpec, server: str, renderers: tuple[str, ...],
    seed: int,
) -> Alone:  # fmt: skip
    """Every stage alone in this process on the clients' cores: GIGAN's loop per renderer (one thread: its stages
    alone are its stages, and the pair shows the measurement's noise); per profile the requests through a fresh
    proxy in front of ``server`` (the prebaked store; once per way the renderers' warps take maps: linear, or 8-bit
    display values for a GL warp), and the cloud client's loop on the first profile's maps per renderer
    (:mod:`baseline_cloudbaking.stages_alone`; it does not depend on the profile)."""
    views = flown_path(spec, cfg, seed, spec.camera.local_fov).views(cfg.resolution)
    alone: Alone = {}
    with client_cores(plan):
        for renderer in renderers:
            gigan = ClientConfig(scene=scene, frames=cfg.frames, resolution=cfg.resolution, every=cfg.every,
                                 orbit_frames=cfg.orbit_frames, path=cfg.path, composition=cfg.composition,
                                 spp=cfg.spp, seed=seed, renderer=renderer, gi_source="model", model=cfg.model,
                                 threads=threads(plan, "client"), frame_rate=cfg.frame_rate or None)  # fmt: skip
            alone[GIGAN, "none", renderer] = stages_of_run(gigan)
        from gicore.render import Renderer  # Mitsuba loads where a run needs it, not with the bench's import

        mitsuba = Renderer(spec, cfg.resolution)
        warps = {r: open_cloud_warp(spec, r, cfg.resolution, cfg.composition, mitsuba) for r in renderers}
        local: dict[str, dict[str, list[float]]] = {}
        for profile in cfg.profiles:
            asked = {}  # per display mode (a GL warp's client keeps 8-bit maps as display values)
            for renderer in renderers:
                raster, _, warp = warps[renderer]
                if warp.takes_display not in asked:
                    with pinned_proxy(plan, profile, server, seed) as url:
                        asked[warp.takes_display] = requests_alone(url, scene, spec, cfg, views, warp.takes_display)
                requests, maps = asked[warp.takes_display]
                if renderer not in local:
                    local[renderer] = local_alone(spec, cfg, views, maps, raster, warp)
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
