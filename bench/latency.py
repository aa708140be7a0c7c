"""`bench latency` (paper Table 1): interaction latency of GIGAN and of cloud baking, stage by stage, from
real processes talking over the simulated network.

One run starts, as separate processes pinned to separate cores where the machine has them (see
:func:`pinning`; recorded in the provenance's ``settings.pinning``):

- ``gigan-client`` with the ONNX model (``--gi-source model``): it needs no network, so it runs once
  and its rows carry ``profile = "none"``;
- per network profile, ``network-sim proxy --profile P`` in front of a ``cloudbaking-server`` and a
  ``cloudbaking-client`` behind the proxy, twice: against a **prebaked** store (the server answered
  every GI camera of the path once before, directly: a first pass along the same path, so the run's
  requests hit) and against a **cold** store (a fresh store per profile, the server warmed up by one
  request far off the path: its requests miss, except where the run itself has just baked a map within
  the tolerance). Rows are grouped by each request's own ``hit`` flag (``cache`` = ``hit`` | ``miss``),
  whatever store it went to.

Both clients fly the same camera path (``orbit_frames`` frames per orbit, seed) at ``resolution``, ask for
a GI map every ``every`` frames (the cloud client also when its view leaves the server's tolerance, with
at most one request in flight) and compose with ``composition``.

**Stages** (``metric``; median and p95 over the maps, ms). A map's interaction latency (``total``) is the
sum of every stage from the request to the composition of the first frame showing it. Only the local DI
render (``di``) is shared by both systems, so it is reported and left out of both totals; everything else
counts toward the system that needs it:

- GIGAN: ``gi_render`` (DI + G-buffers + texel depth at the GI camera: the generator's input),
  ``inference`` (``GIModel.predict``, with its pre- and post-processing), ``warp`` (the structure-aware
  warp's per-map ``bind`` plus its per-frame stages on the frame that binds the map, the local
  uv/position ``raster`` included), ``blend`` (composition);
- cloud baking (the split is :mod:`baseline_cloudbaking.client`'s): ``transmission`` = ``request``
  (time to the response's first byte minus the server's time: upload, round trip, HTTP and proxy
  overhead) + ``transfer`` (first to last response byte); the server's ``lookup``, ``read`` (hit) or
  ``render``, ``denoise``, ``encode`` (miss) and ``server_other``; ``decode``; ``warp`` (pixel-level:
  ``bind`` plus per-frame stages, its surface-mask ``raster`` included); ``blend``. ``pickup`` (arrival
  to the next frame taking the map) is reported, not counted: it is a wait for the frame clock.

Stage medians do not add up to the median total (each is a median of its own samples).

**Ratio and crossover.** ``total_ratio``: cloud baking's median total over GIGAN's, per profile and
cache state. The crossover RTT (``crossover_rtt``) is where the link model says GIGAN's median total
beats cloud baking's: cloud's total at a round-trip time ``r`` is its measured non-network stages
(median of total minus transmission) plus the network time of its median request and response bytes
through :mod:`network_sim.link`'s virtual-clock model of a link with ``r / 2`` each way at
``sweep_rate_mbit`` (unlimited by default: RTT alone, as the ``rtt*`` profiles); 0 when GIGAN is faster
at any RTT. The same model at each measured profile (``total_model``) is set beside the process runs'
median; their difference is the HTTP and proxy overhead the link model does not have (so the
crossover errs in cloud baking's favour by about that much).

**Quality along the path.** Each client scores its composed frames against the path-traced GT every
``gt_every`` frames (``ssim`` rows with ``stat = frame``): the cost of stale maps while requests are in
flight. Outputs besides the CSV: ``latency_table.md`` (Table 1 per profile, also printed), stacked stage
bars, the ratio against RTT, SSIM along the path; each client's own CSVs under ``latency_runs/``.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC
from bench.models import check_model_resolution
from bench.runner import Bench, Block, Figure, Part, Rows, Section, Table, cell, need, pick
from bench.svg import Point, Series, XYChart
from gicore.blend import COMPOSITIONS
from gicore.cli import UserError
from gicore.results import Results, read_rows
from gigan_local.inference import DEFAULT_MODEL

CodecName = Literal[CODEC_NAMES]  # type: ignore[valid-type]
BIN = Path(sys.executable).parent
GIGAN, CLOUD = "gigan", "cloud_baking"
#: GIGAN's stages, then cloud baking's, in the order a map goes through them (``total`` last).
GIGAN_STAGES = ("gi_render", "inference", "warp", "blend")
CLOUD_STAGES = (
    "transmission",
    "request",
    "transfer",
    "lookup",
    "read",
    "render",
    "denoise",
    "encode",
    "server_other",
    "decode",
    "warp",
    "blend",
)
#: Sub-stages of ``transmission`` (its parts, not added again).
TRANSMISSION_PARTS = ("request", "transfer")


@dataclass(frozen=True)
class LatencyConfig:
    """What one latency run measures (see the module docstring)."""

    #: The scene both clients fly through (name or spec file).
    scenes: tuple[str, ...] = field(default=("lung_plane",), metadata={"max_len": 1})
    #: Network profiles the cloud-baking client runs behind (see network-sim profiles).
    profiles: tuple[str, ...] = ("lan", "wifi", "lte", "wan")
    #: Square resolution of every render and GI map (the model's).
    resolution: int = 256
    #: Frames per client run.
    frames: int = 300
    #: GI-map period k: a new map every k frames (the cloud client also asks when its view leaves the tolerance).
    every: int = 10
    #: Frames per full orbit of the camera path.
    orbit_frames: int = 300
    #: GI-map codec of the cloud-baking maps.
    codec: CodecName = DEFAULT_CODEC
    #: Samples per pixel of path tracing: the server's maps and the evaluation GT.
    spp: int = 64
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

    @classmethod
    def quick(cls) -> LatencyConfig:
        return cls(profiles=("lan", "wan"), frames=90, every=5, spp=16)

    def check(self) -> None:
        from network_sim import profiles

        known = profiles.profiles()
        for name in self.profiles:
            if name not in known:
                raise UserError(
                    f"--profiles {name!r} is not a network profile",
                    f"use some of {', '.join(known)} (see network-sim profiles)",
                )
        check_model_resolution(self.model, self.resolution)


# -- processes ----------------------------------------------------------------------------------------------
def pinning(enabled: bool) -> dict[str, Any]:
    """Cores of the server, the proxy and the clients (``taskset -c``): with 2 cores the server and the
    proxy share one and the clients get the other; with more the proxy gets one, the server about half
    of the rest and the clients the others. ``method`` is ``none`` (with the reason) when not pinned."""
    cores = sorted(os.sched_getaffinity(0))
    if not enabled:
        return {"method": "none", "reason": "--no-pin", "cores": cores}
    if shutil.which("taskset") is None:
        return {"method": "none", "reason": "taskset (util-linux) is not installed", "cores": cores}
    if len(cores) < 2:
        return {"method": "none", "reason": "one core: every process shares it", "cores": cores}
    if len(cores) == 2:
        roles = {"server": cores[:1], "proxy": cores[:1], "client": cores[1:]}
    else:
        split = 1 + (len(cores) - 1) // 2
        roles = {"proxy": cores[:1], "server": cores[1:split], "client": cores[split:]}
    return {"method": "taskset -c", "cores": cores} | roles


def _prefix(plan: dict[str, Any], role: str) -> list[str]:
    return ["taskset", "-c", ",".join(map(str, plan[role]))] if plan["method"] != "none" else []


def _threads(plan: dict[str, Any], role: str) -> int:
    return len(plan[role]) if plan["method"] != "none" else len(plan["cores"])


@contextmanager
def pinned_server(plan: dict[str, Any], store: Path, scenes_dir: Path | None) -> Iterator[str]:
    """A pinned ``cloudbaking-server`` on an ephemeral port; yields its base URL."""
    from network_sim.process import Running

    env = ["env", f"CLOUDBAKING_RENDER_THREADS={_threads(plan, 'server')}"]
    argv = [*env, *_prefix(plan, "server"), str(BIN / "cloudbaking-server"), "--port", "0", "--store", str(store)]
    with Running(argv + (["--scenes", str(scenes_dir)] if scenes_dir else []), timeout=120.0) as server:
        host, port = server.addr
        yield f"{host}:{port}"  # host is "http://127.0.0.1" (the server prints a URL)


@contextmanager
def _proxy(plan: dict[str, Any], profile: str, upstream: str, seed: int) -> Iterator[str]:
    """A pinned ``network-sim proxy --profile`` in front of ``upstream`` (a URL); yields the proxy's URL."""
    from network_sim.process import Running

    target = upstream.removeprefix("http://")
    argv = [
        *_prefix(plan, "proxy"),
        sys.executable,
        "-m",
        "network_sim",
        "proxy",
        "--upstream",
        target,
        "--profile",
        profile,
        "--seed",
        str(seed),
    ]
    with Running(argv, timeout=60.0) as proxy:
        host, port = proxy.addr
        yield f"http://{host}:{port}"


def _client(plan: dict[str, Any], argv: list[str], out: Path, timeout_s: float) -> Path:
    """Run a pinned client process writing into ``out`` (a fresh folder); its output folder."""
    shutil.rmtree(out, ignore_errors=True)
    proc = subprocess.run(
        [*_prefix(plan, "client"), *argv, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )
    if out.is_dir():
        (out / "console.txt").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        raise RuntimeError(f"{Path(argv[0]).name} exited with {proc.returncode}:\n{proc.stderr[-3000:]}")
    return out


def _fill_store(url: str, cfg: LatencyConfig, scene: str, seed: int, off_path: bool) -> dict[str, int]:
    """Ask ``url`` directly for the GI camera of every frame of the path (``off_path``: for one camera one
    unit above the first, which no path frame is within tolerance of); returns hit and miss counts."""
    from baseline_cloudbaking.client import RemoteConfig, RemoteSource
    from gicore.loop import path_views
    from gicore.scene import load_scene

    spec = load_scene(scene)
    remote = RemoteConfig(url, Path(scene).stem, cfg.resolution, cfg.codec, cfg.spp, cfg.composition == "residual",
                          spec.light.moves, read_timeout_s=cfg.read_timeout_s, deadline_s=2 * cfg.read_timeout_s,
                          retry_after_s=0.0)  # fmt: skip
    views = path_views(
        spec, 1 if off_path else cfg.frames, cfg.orbit_frames, seed, spec.camera.local_fov, cfg.resolution
    )
    with RemoteSource(remote) as source:
        for frame, (camera, light) in enumerate(views):
            gi_camera = camera.with_fov(spec.camera.gi_fov)
            if off_path:
                gi_camera = replace(gi_camera, origin=tuple(np.add(camera.origin, (0.0, 1.0, 0.0))))
            source.request(gi_camera, light, frame)
            source.wait(2 * cfg.read_timeout_s + 10)
        failed = [r for r in source.records if r["status"] != "ok"]
        if failed:
            raise RuntimeError(
                f"the server at {url} failed a request of the first pass: {failed[0]['status']}: {failed[0]['error']}"
            )
        hits = sum(int(r["hit"]) for r in source.records)
        return {"hits": hits, "misses": len(source.records) - hits}


# -- measuring ----------------------------------------------------------------------------------------------
def measure(cfg: LatencyConfig, res: Results) -> None:
    from gicore.scene import load_scene

    scene = cfg.scenes[0]
    spec = load_scene(scene)
    scenes_dir = Path(scene).resolve().parent if Path(scene).suffix else None
    work = res.out / "latency_runs"
    work.mkdir(parents=True, exist_ok=True)
    plan = pinning(cfg.pin)
    res.settings["pinning"] = plan
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
    path_args = ["--scene", scene, "--frames", str(cfg.frames), "--resolution", str(cfg.resolution),
                 "-k", str(cfg.every), "--orbit-frames", str(cfg.orbit_frames), "--spp", str(cfg.spp),
                 "--gt-every", str(cfg.gt_every), "--composition", cfg.composition,
                 "--seed", str(res.seed)]  # fmt: skip

    gigan_argv = [str(BIN / "gigan-client"), *path_args, "--gi-source", "model", "--model", str(cfg.model),
                  "--threads", str(_threads(plan, "client"))]  # fmt: skip
    runs = {(GIGAN, "none", "local"): _client(plan, gigan_argv, work / "gigan", per_run)}
    cloud_argv = [str(BIN / "cloudbaking-client"), *path_args, "--codec", cfg.codec,
                  "--read-timeout", str(cfg.read_timeout_s), "--deadline", str(2 * cfg.read_timeout_s)]  # fmt: skip
    shutil.rmtree(work / "store_prebaked", ignore_errors=True)  # every run prebakes its own store
    with pinned_server(plan, work / "store_prebaked", scenes_dir) as warm:
        t0 = time.perf_counter()
        first = _fill_store(warm, cfg, scene, res.seed, off_path=False)
        res.add(
            system=CLOUD,
            scene=spec.name,
            metric="prebake_maps",
            value=first["misses"],
            unit="count",
            store="prebaked",
            **common,
        )
        res.add(
            system=CLOUD,
            scene=spec.name,
            metric="prebake_time",
            value=time.perf_counter() - t0,
            unit="s",
            stat="wall",
            store="prebaked",
            **common,
        )
        for profile in cfg.profiles:
            with _proxy(plan, profile, warm, res.seed) as url:
                runs[CLOUD, profile, "prebaked"] = _client(
                    plan, [*cloud_argv, "--server", url], work / f"cloud_{profile}_prebaked", per_run
                )
            store = work / f"store_cold_{profile}"
            shutil.rmtree(store, ignore_errors=True)
            with pinned_server(plan, store, scenes_dir) as cold:
                _fill_store(
                    cold, cfg, scene, res.seed, off_path=True
                )  # compiles the scene and every pass, off the path
                with _proxy(plan, profile, cold, res.seed) as url:
                    runs[CLOUD, profile, "cold"] = _client(
                        plan, [*cloud_argv, "--server", url], work / f"cloud_{profile}_cold", per_run
                    )
            shutil.rmtree(store, ignore_errors=True)
    shutil.rmtree(work / "store_prebaked", ignore_errors=True)
    record(res, spec.name, cfg, runs, common)


def _csv(path: Path) -> list[dict[str, str]]:
    import csv

    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _f(value: str) -> float | None:
    return float(value) if value not in ("", None) else None


def gigan_samples(frames: list[dict[str, str]]) -> dict[str, list[float]]:
    """Per-map stage times (ms) of a ``gigan-client`` run: one sample per frame that bound a new map."""
    from gigan_local.warp import StructureAwareWarp

    per_frame = [s for s in StructureAwareWarp.stages if s != "bind"]
    samples: dict[str, list[float]] = {s: [] for s in (*GIGAN_STAGES, "total")}
    for row in (r for r in frames if r["gi_new"] == "1"):
        stage = {
            "gi_render": float(row["gi_render_ms"]),
            "inference": float(row["inference_ms"]),
            "warp": float(row["bind_ms"]) + sum(float(row[f"{s}_ms"]) for s in per_frame),
            "blend": float(row["compose_ms"]),
        }
        for name, ms in stage.items():
            samples[name].append(ms)
        samples["total"].append(sum(stage.values()))
    return samples


def cloud_samples(requests: list[dict[str, str]]) -> dict[str, dict[str, list[float]]]:
    """Per-request stage times (ms) of a ``cloudbaking-client`` run by cache state (``hit``/``miss``), for
    the requests whose map was shown (a ``total``); also the request and response bytes."""
    out: dict[str, dict[str, list[float]]] = {}
    for row in requests:
        if row["status"] != "ok" or row["total_ms"] == "":
            continue
        samples = out.setdefault("hit" if row["hit"] == "1" else "miss", {})
        values = {s: _f(row[f"{s}_ms"]) for s in CLOUD_STAGES if s != "warp"}
        values |= {
            "warp": float(row["bind_ms"]) + float(row["warp_ms"]),
            "total": float(row["total_ms"]),
            "pickup": _f(row["pickup_ms"]),
        }
        values |= {
            "bytes_up": float(row["bytes_up"]),
            "bytes_down": float(row["bytes_down"]),
            "server": float(row["server_ms"]),
        }
        for name, value in values.items():
            if value is not None:
                samples.setdefault(name, []).append(value)
    return out


def record(
    res: Results, scene: str, cfg: LatencyConfig, runs: dict[tuple[str, str, str], Path], common: dict[str, Any]
) -> None:
    """Rows of every run: stage timings, ratios, the link model's check and crossover, quality along the path."""
    from network_sim import profiles as profile_table

    gigan_frames = _csv(runs[GIGAN, "none", "local"] / "frames.csv")
    gigan = gigan_samples(gigan_frames)
    gigan["di"] = [float(r["di_ms"]) for r in gigan_frames]
    model = {"model": cfg.model.name}
    for stage, values in gigan.items():
        res.add_timing(
            system=GIGAN,
            scene=scene,
            metric=stage,
            samples_s=[v / 1e3 for v in values],
            profile="none",
            **common,
            **model,
        )
    _ssim_rows(res, scene, GIGAN, gigan_frames, {"profile": "none", "store": "none"} | common)
    gigan_total = float(np.median(gigan["total"]))

    cloud: dict[tuple[str, str], dict[str, list[float]]] = {}
    for (system, profile, store), folder in runs.items():
        if system != CLOUD:
            continue
        frames = _csv(folder / "frames.csv")
        requests = _csv(folder / "requests.csv")
        for cache, samples in cloud_samples(requests).items():
            merged = cloud.setdefault((profile, cache), {})
            for name, values in samples.items():
                merged.setdefault(name, []).extend(values)
        merged_di = cloud.setdefault((profile, "any"), {}).setdefault("di", [])
        merged_di.extend(float(r["di_ms"]) for r in frames)
        failures = sum(r["status"] not in ("ok", "abandoned") for r in requests)
        res.add(
            system=CLOUD,
            scene=scene,
            metric="failed_requests",
            value=failures,
            unit="count",
            profile=profile,
            store=store,
            **common,
        )
        _ssim_rows(res, scene, CLOUD, frames, {"profile": profile, "store": store, "codec": cfg.codec} | common)

    for (profile, cache), samples in cloud.items():
        config = {"profile": profile, "cache": cache, "codec": cfg.codec} | common
        for stage in (*CLOUD_STAGES, "total", "pickup", "di"):
            if samples.get(stage):
                res.add_timing(
                    system=CLOUD, scene=scene, metric=stage, samples_s=[v / 1e3 for v in samples[stage]], **config
                )
        if cache == "any":
            continue
        for name in ("bytes_up", "bytes_down"):
            res.add(
                system=CLOUD,
                scene=scene,
                metric=name,
                value=float(np.median(samples[name])),
                unit="B",
                stat="median",
                **config,
            )
        link = profile_table.get(profile).link(seed=res.seed)
        rtt_ms = link.rtt_s * 1e3
        ratio = float(np.median(samples["total"])) / gigan_total
        res.add(
            system=f"{CLOUD}/{GIGAN}",
            scene=scene,
            metric="total_ratio",
            value=ratio,
            unit="1",
            stat="median",
            rtt_ms=rtt_ms,
            **config,
        )
        cost = CloudCost.of(samples)
        res.add(
            system=CLOUD,
            scene=scene,
            metric="total_model",
            value=cost.total_ms(link, starts=20),
            unit="ms",
            stat="median",
            rtt_ms=rtt_ms,
            **config,
        )

    for cache in ("hit", "miss"):
        pooled = _pool([s for (p, c), s in cloud.items() if c == cache])
        if not pooled.get("total"):
            continue
        cost = CloudCost.of(pooled)
        config = {"cache": cache, "rate_mbit": cfg.sweep_rate_mbit, "codec": cfg.codec} | common
        crossover = cost.crossover_rtt_ms(gigan_total, cfg.sweep_rate_mbit)
        res.add(
            system=f"{CLOUD}/{GIGAN}",
            scene=scene,
            metric="crossover_rtt",
            value=crossover,
            unit="ms",
            stat="model",
            **config,
        )
        for rtt in np.linspace(0.0, cfg.sweep_max_rtt_ms, 26):
            total = cost.total_ms(sweep_link(float(rtt), cfg.sweep_rate_mbit))
            res.add(
                system=f"{CLOUD}/{GIGAN}",
                scene=scene,
                metric="ratio_model",
                value=total / gigan_total,
                unit="1",
                stat="model",
                rtt_ms=float(rtt),
                **config,
            )


def _pool(groups: list[dict[str, list[float]]]) -> dict[str, list[float]]:
    pooled: dict[str, list[float]] = {}
    for group in groups:
        for name, values in group.items():
            pooled.setdefault(name, []).extend(values)
    return pooled


def _ssim_rows(res: Results, scene: str, system: str, frames: list[dict[str, str]], config: dict[str, Any]) -> None:
    scored = [(int(r["frame"]), float(r["ssim"])) for r in frames if r.get("ssim")]
    for frame, value in scored:
        res.add(system=system, scene=scene, metric="ssim", value=value, unit="1", stat="frame", frame=frame, **config)
    if scored:
        res.add(
            system=system,
            scene=scene,
            metric="ssim",
            value=float(np.mean([v for _, v in scored])),
            unit="1",
            stat="mean",
            **config,
        )


# -- the link model: cloud baking's total at any link ---------------------------------------------------------
def sweep_link(rtt_ms: float, rate_mbit: float | None):
    """A link with ``rtt_ms / 2`` one-way delay each way at ``rate_mbit`` (None: unlimited)."""
    from network_sim.link import DirectionConfig, LinkConfig

    direction = DirectionConfig(delay_ms=rtt_ms / 2, rate_mbit=rate_mbit)
    return LinkConfig(up=direction, down=direction)


@dataclass(frozen=True)
class CloudCost:
    """Cloud baking's cost of one map apart from the network (medians of the measured requests), and what
    it sends: enough to put its total on any link with :mod:`network_sim.link`'s model."""

    #: Median of total minus transmission: server, decode, warp, blend (ms).
    local_ms: float
    #: Median server time (ms): the response leaves the server this long after the request arrived.
    server_ms: float
    bytes_up: int
    bytes_down: int

    @classmethod
    def of(cls, samples: dict[str, list[float]]) -> CloudCost:
        rest = np.subtract(samples["total"], samples["transmission"])
        return cls(
            float(np.median(rest)),
            float(np.median(samples["server"])),
            int(np.median(samples["bytes_up"])),
            int(np.median(samples["bytes_down"])),
        )

    def network_ms(self, link, starts: int = 1) -> float:
        """Request upload plus response download on ``link`` (the virtual-clock model; median over
        ``starts`` start times 0.5 s apart, which matters for traces and jitter)."""
        from network_sim.link import DOWN, UP, Link

        times = []
        for i in range(starts):
            model, t0 = Link(link), 0.5 * i
            arrived = model.message(0, UP, self.bytes_up, t0)
            done = model.message(0, DOWN, self.bytes_down, arrived + self.server_ms / 1e3)
            times.append((done - t0) * 1e3 - self.server_ms)
        return float(np.median(times))

    def total_ms(self, link, starts: int = 1) -> float:
        return self.local_ms + self.network_ms(link, starts)

    def crossover_rtt_ms(self, gigan_ms: float, rate_mbit: float | None) -> float:
        """The RTT beyond which GIGAN's total ``gigan_ms`` beats this cost on a ``rate_mbit`` link (0: at any
        RTT; inf: at none up to a minute)."""

        def gap(rtt: float) -> float:
            return self.total_ms(sweep_link(rtt, rate_mbit)) - gigan_ms

        if gap(0.0) >= 0:
            return 0.0
        low, high = 0.0, 100.0
        while gap(high) < 0:
            low, high = high, 2 * high
            if high > 60_000.0:
                return math.inf
        while high - low > 0.05:
            mid = 0.5 * (low + high)
            low, high = (mid, high) if gap(mid) < 0 else (low, mid)
        return 0.5 * (low + high)


# -- table and plots (from the CSV only) --------------------------------------------------------------------
#: Table 1's rows: (metric, label); sub-stages of transmission are indented.
TABLE_ROWS = (
    ("transmission", "transmission"),
    ("request", "&nbsp;&nbsp;request: upload, round trip, HTTP + proxy"),
    ("transfer", "&nbsp;&nbsp;transfer: response body"),
    ("lookup", "server: GI-tree lookup"),
    ("read", "server: read stored map"),
    ("render", "server: path tracing (+ DI, depth)"),
    ("denoise", "server: denoise (OIDN)"),
    ("encode", "server: encode"),
    ("server_other", "server: other (store the map, header)"),
    ("gi_render", "GI-camera render (DI + G-buffers)"),
    ("inference", "inference"),
    ("decode", "decode"),
    ("warp", "warp (per-map bind + per-frame, raster included)"),
    ("blend", "blend"),
    ("total", "**total (interaction latency)**"),
)
COLUMNS = ((GIGAN, None, "GIGAN"), (CLOUD, "hit", "cloud baking, hit"), (CLOUD, "miss", "cloud baking, miss"))


def _lookup(rows: list[dict], system: str, metric: str, stat: str, **config: Any) -> float | None:
    for r in rows:
        if (r["system"], r["metric"], r["stat"]) == (system, metric, stat) and all(
            r["config"].get(k) == v for k, v in config.items()
        ):
            return r["value"]
    return None


def _column_config(system: str, cache: str | None, profile: str) -> dict[str, Any]:
    return {"profile": "none"} if system == GIGAN else {"profile": profile, "cache": cache}


def table(rows: list[dict]) -> str:
    """Table 1 per profile (median ms, p95 in brackets), the ratios, the link model's check and the crossovers."""
    profiles = list(
        dict.fromkeys(r["config"]["profile"] for r in rows if r["system"] == CLOUD and "cache" in r["config"])
    )
    scene = rows[0]["scene"] if rows else ""
    lines = [f"## Table 1: interaction latency, {scene} (ms: median, p95 in brackets)", ""]
    for profile in profiles:
        rtt = _lookup(rows, f"{CLOUD}/{GIGAN}", "total_ratio", "median", profile=profile)
        rtt_ms = next(
            (r["config"]["rtt_ms"] for r in rows if r["metric"] == "total_ratio" and r["config"]["profile"] == profile),
            None,
        )
        lines += [f"### profile `{profile}`" + (f" (RTT {rtt_ms:g} ms)" if rtt is not None else ""), ""]
        lines += ["| stage | " + " | ".join(label for _, _, label in COLUMNS) + " |", "|---" * (1 + len(COLUMNS)) + "|"]
        for metric, label in TABLE_ROWS:
            cells = []
            for system, cache, _ in COLUMNS:
                median = _lookup(rows, system, metric, "median", **_column_config(system, cache, profile))
                p95 = _lookup(rows, system, metric, "p95", **_column_config(system, cache, profile))
                cells.append("—" if median is None else f"{median:.1f} ({p95:.1f})")
            if any(c != "—" for c in cells):
                lines.append(f"| {label} | " + " | ".join(cells) + " |")
        ratio = [
            _lookup(rows, f"{CLOUD}/{GIGAN}", "total_ratio", "median", profile=profile, cache=c)
            for _, c, _ in COLUMNS[1:]
        ]
        lines.append(
            "| ratio of totals, cloud / GIGAN | — | "
            + " | ".join("—" if r is None else f"**{r:.2f}**" for r in ratio)
            + " |"
        )
        model = [_lookup(rows, CLOUD, "total_model", "median", profile=profile, cache=c) for _, c, _ in COLUMNS[1:]]
        lines.append(
            "| total by the link model (check) | — | "
            + " | ".join("—" if m is None else f"{m:.1f}" for m in model)
            + " |"
        )
        counts = [_lookup(rows, s, "total", "n", **_column_config(s, c, profile)) for s, c, _ in COLUMNS]
        lines.append("| maps measured | " + " | ".join("0" if n is None else f"{n:.0f}" for n in counts) + " |")
        di = [
            _lookup(
                rows, s, "di", "median", **({"profile": "none"} if s == GIGAN else {"profile": profile, "cache": "any"})
            )
            for s in (GIGAN, CLOUD)
        ]
        pickup = [_lookup(rows, CLOUD, "pickup", "median", profile=profile, cache=c) for c in ("hit", "miss")]
        note = "Not in the totals: the local DI render both systems run every frame (median "
        note += " / ".join("—" if d is None else f"{d:.1f}" for d in di) + " ms in the GIGAN / cloud runs); "
        note += (
            "cloud baking's wait from a map's arrival to the next frame taking it (median "
            + " / ".join("—" if p is None else f"{p:.1f}" for p in pickup)
            + " ms, hit / miss)."
        )
        lines += ["", note, ""]
    crossings = [
        (r["config"]["cache"], r["value"], r["config"].get("rate_mbit")) for r in rows if r["metric"] == "crossover_rtt"
    ]
    if crossings:
        lines += [
            "### crossover: the RTT beyond which GIGAN's median total beats cloud baking's "
            "(link model, measured stages)",
            "",
        ]
        lines += ["| cache | crossover RTT (ms) | link rate |", "|---|---|---|"]
        for cache, value, rate in crossings:
            shown = (
                "0 (GIGAN is faster at any RTT)"
                if value == 0
                else ("none up to a minute" if math.isinf(value) else f"{value:.0f}")
            )
            lines.append(f"| {cache} | {shown} | {'unlimited' if rate is None else f'{rate:g} Mbit/s'} |")
        lines.append("")
    return "\n".join(lines)


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """``latency_table.md`` (printed too), stacked stage bars, ratio against RTT, SSIM along the path."""
    from gicore.plotting import plt, save

    rows = read_rows(csv_path)
    md = out_dir / "latency_table.md"
    text = table(rows)
    md.write_text(text + "\n")
    print(text)
    written = [md]
    profiles = list(
        dict.fromkeys(r["config"]["profile"] for r in rows if r["system"] == CLOUD and "cache" in r["config"])
    )

    # stacked stage bars: one bar per system and profile (GIGAN's once, it needs no network)
    bars = [("GIGAN", GIGAN, {"profile": "none"}, GIGAN_STAGES)]
    cloud_stages = tuple(s for s in CLOUD_STAGES if s not in TRANSMISSION_PARTS)
    bars += [(f"cloud {c}, {p}", CLOUD, {"profile": p, "cache": c}, cloud_stages)
             for p in profiles for c in ("hit", "miss")]  # fmt: skip
    bars = [b for b in bars if _lookup(rows, b[1], "total", "median", **b[2]) is not None]
    stages = list(dict.fromkeys(s for *_, names in bars for s in names))
    colours = dict(zip(stages, plt.cm.tab20(np.linspace(0, 1, max(len(stages), 2)))))
    fig, ax = plt.subplots(figsize=(11, 0.5 * len(bars) + 2.2))
    for y, (_, system, config, names) in enumerate(bars):
        left = 0.0
        for stage in names:
            value = _lookup(rows, system, stage, "median", **config) or 0.0
            ax.barh(
                y,
                value,
                left=left,
                color=colours[stage],
                label=stage if y == next(i for i, b in enumerate(bars) if stage in b[3]) else None,
            )
            left += value
        total = _lookup(rows, system, "total", "median", **config)
        ax.text(left, y, f" {total:.0f} ms", va="center", fontsize=8)
    ax.set_yticks(range(len(bars)), [b[0] for b in bars])
    ax.invert_yaxis()
    ax.set_xlabel("median stage time [ms] (bar: sum of stage medians; label: median total)")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.set_title("Interaction latency by stage (Table 1)")
    written.append(save(fig, out_dir / "latency_stages.png"))

    # ratio of totals against RTT: the link model's curve, the measured profiles as points
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for cache, colour in (("hit", "tab:blue"), ("miss", "tab:red")):
        curve = sorted(
            (r["config"]["rtt_ms"], r["value"])
            for r in rows
            if r["metric"] == "ratio_model" and r["config"]["cache"] == cache
        )
        if curve:
            ax.plot(*zip(*curve), "-", color=colour, label=f"{cache}: link model")
        points = [
            (r["config"]["rtt_ms"], r["value"], r["config"]["profile"])
            for r in rows
            if r["metric"] == "total_ratio" and r["config"]["cache"] == cache
        ]
        for rtt, value, profile in points:
            ax.plot(rtt, value, "o", color=colour)
            ax.annotate(profile, (rtt, value), textcoords="offset points", xytext=(4, 4), fontsize=7)
        crossing = _lookup(rows, f"{CLOUD}/{GIGAN}", "crossover_rtt", "model", cache=cache)
        if crossing is not None and 0 < crossing < math.inf:
            ax.axvline(crossing, color=colour, ls=":", lw=1)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("round-trip time [ms] (points: measured profiles, whatever their rate)")
    ax.set_ylabel("cloud baking total / GIGAN total")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Above 1: GIGAN is faster")
    written.append(save(fig, out_dir / "latency_ratio_rtt.png"))

    # SSIM along the path: how stale maps cost quality while requests are in flight
    scored = [r for r in rows if r["metric"] == "ssim" and r["stat"] == "frame"]
    if scored:
        fig, axes = plt.subplots(
            1, len(profiles) or 1, figsize=(4.5 * max(len(profiles), 1), 3.6), squeeze=False, sharey=True
        )
        gigan = sorted((r["config"]["frame"], r["value"]) for r in scored if r["system"] == GIGAN)
        for ax, profile in zip(axes[0], profiles or ["none"]):
            if gigan:
                ax.plot(*zip(*gigan), "-o", ms=3, color="tab:green", label="GIGAN")
            for store, colour in (("prebaked", "tab:blue"), ("cold", "tab:red")):
                line = sorted(
                    (r["config"]["frame"], r["value"])
                    for r in scored
                    if r["system"] == CLOUD and (r["config"]["profile"], r["config"]["store"]) == (profile, store)
                )
                if line:
                    ax.plot(*zip(*line), "-s", ms=3, color=colour, label=f"cloud baking, {store} store")
            ax.set_title(f"profile {profile}")
            ax.set_xlabel("frame")
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel("SSIM vs path-traced GT")
        axes[0][0].legend(fontsize=7)
        written.append(save(fig, out_dir / "latency_ssim.png"))
    return written


# -- bench report: the dashboard's section and the README's block ------------------------------------------
def dashboard_section(rows: Rows) -> list[Part]:
    """Table 1 in full, then the ratio of totals against RTT: the link model's curve, the measured profiles."""
    need(rows, "total")
    lines = []
    for cache in ("hit", "miss"):
        model = [
            Point(
                r["config"]["rtt_ms"],
                r["value"],
                f"{cache}, link model: RTT {r['config']['rtt_ms']:g} ms → ratio {r['value']:.3g}",
            )
            for r in pick(rows, "ratio_model")
            if r["config"].get("cache") == cache
        ]
        measured = [
            Point(
                r["config"]["rtt_ms"], r["value"], f"{cache}, profile {r['config']['profile']}: ratio {r['value']:.3g}"
            )
            for r in pick(rows, "total_ratio")
            if r["config"].get("cache") == cache
        ]
        if model:
            lines.append(Series(f"{cache}: link model", model))
        if measured:
            lines.append(Series(f"{cache}: measured profiles", measured, line=False))
    figure = XYChart(
        lines,
        "round-trip time [ms]",
        "cloud total / GIGAN total",
        ylog=True,
        caption="Above 1: GIGAN's interaction latency is lower.",
    )
    return [Table(table(rows)), Figure((figure,))] if lines else [Table(table(rows))]


def readme_block(rows: Rows) -> list[Table]:
    """Table 1 in short: one line per network profile (totals, ratio, SSIM), GIGAN's stages, the crossover RTTs."""
    need(rows, "total", "total_ratio")
    ratios = pick(rows, "total_ratio")
    rtt = {r["config"]["profile"]: r["config"].get("rtt_ms") for r in ratios}
    c = ratios[0]["config"]
    gigan = _lookup(rows, GIGAN, "total", "median", profile="none")
    lines = [
        f"{rows[0]['scene']}, {c.get('resolution')}², {c.get('frames')} frames, GI period k = {c.get('k')}, "
        f"{c.get('spp')} spp + OIDN on the server, {c.get('codec')} maps; medians in ms.",
        "",
        "| profile (RTT) | GIGAN | cloud hit | cloud miss | cloud / GIGAN: hit / miss "
        "| mean SSIM vs GT: GIGAN / prebaked / cold |",
        "|---|---|---|---|---|---|",
    ]
    for profile, rtt_ms in rtt.items():
        hit, miss = (_lookup(rows, CLOUD, "total", "median", profile=profile, cache=cache) for cache in ("hit", "miss"))
        ratio = [
            _lookup(rows, f"{CLOUD}/{GIGAN}", "total_ratio", "median", profile=profile, cache=cache)
            for cache in ("hit", "miss")
        ]
        ssim = [_lookup(rows, GIGAN, "ssim", "mean", profile="none")]
        ssim += [_lookup(rows, CLOUD, "ssim", "mean", profile=profile, store=store) for store in ("prebaked", "cold")]
        lines.append(
            f"| `{profile}` ({cell(rtt_ms, 'g')} ms) | {cell(gigan)} | {cell(hit)} | {cell(miss)} | "
            + " / ".join(cell(r, ".2f") for r in ratio)
            + " | "
            + " / ".join(cell(s, ".3f") for s in ssim)
            + " |"
        )
    labels = (("gi_render", "GI-camera render"), ("inference", "inference"), ("warp", "warp"), ("blend", "blend"))
    stages = [(label, _lookup(rows, GIGAN, metric, "median", profile="none")) for metric, label in labels]
    lines += [
        "",
        f"GIGAN's total {cell(gigan)} ms = "
        + " + ".join(f"{label} {v:.1f}" for label, v in stages if v is not None)
        + ".",
    ]
    crossings = []
    for r in pick(rows, "crossover_rtt"):
        cache, value = r["config"].get("cache"), r["value"]
        if value == 0:
            crossings.append(f"a cloud {cache} at any RTT")
        elif math.isinf(value):
            crossings.append(f"a cloud {cache} at no RTT up to a minute")
        else:
            crossings.append(f"a cloud {cache} beyond an RTT of {value:.0f} ms")
    if crossings:
        lines.append(
            "Crossover (the link model with the measured stages): GIGAN's median total beats "
            + "; ".join(crossings)
            + "."
        )
    return [Table("\n".join(lines))]


BENCH = Bench(
    "latency",
    LatencyConfig,
    measure,
    plot,
    help="Table 1: interaction latency per stage of GIGAN and cloud baking (prebaked and cold store) from real "
    "processes over simulated network profiles; ratios, crossover RTT, SSIM along the path.",
    dashboard=Section("table1", "Table 1: interaction latency", 10, dashboard_section),
    readme=Block("Interaction latency, Table 1", 10, readme_block),
)
