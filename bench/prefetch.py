"""`bench prefetch`: how well the cloud-baking client hides the network, per network profile, with three
request rules (``period``, ``hold``, ``prefetch``) on the same camera path against the same prebaked GI tree,
and their targets (docs/architecture.md, bench prefetch)."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from baseline_cloudbaking.client import request_path_maps
from baseline_cloudbaking.client_run import RunMetrics, check_server, request_floors
from baseline_cloudbaking.codecs import DEFAULT_CODEC, CodecName
from baseline_cloudbaking.server.settings import check_served
from bench.processes import BIN, path_options, pinned_proxy, pinned_server, run_client, run_place, with_path_frames
from bench.runner import Bench, Block, Section
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.frame_rows import read_summary
from gicore.path_file import flown_path
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, fill, first, flat, matches, pick
from gicore.results import Results
from network_sim.profiles import profiles_field

SYSTEM = "cloud_baking"
#: Variant -> the client's request-rule options (module docstring).
VARIANTS = {
    "period": ["--hold", "none"],
    "hold": ["--hold", "tolerance", "--prefetch", "none"],
    "prefetch": ["--hold", "tolerance", "--prefetch", "extrapolate"],
}
#: The targets' bounds: prefetch's perceived latency of hits at wan over hold's; hold's requests at lan over period's.
PERCEIVED_BOUND, REQUESTS_BOUND = 0.5, 0.5


@dataclass(frozen=True)
class PrefetchConfig:
    """What one prefetch run measures (see the module docstring)."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="the one the clients fly through")
    profiles: tuple[str, ...] = profiles_field(("lan", "wan"), note="the clients run behind each")
    #: Request rules compared (period, hold, prefetch).
    variants: tuple[str, ...] = tuple(VARIANTS)
    resolution: int = option_groups.resolution(note="of every render and GI map")
    #: Frames per client run.
    frames: int = 300
    orbit_frames: int = option_groups.orbit_frames()
    path: Path | None = option_groups.path()
    #: Frames per second the clients are paced to.
    frame_rate: float = field(default=30.0, metadata={"min": 1.0, "max": 1000.0})
    every: int = option_groups.every(10, note="the period variant's, as bench latency's")
    #: Requests in flight at most for the hold and prefetch variants (period: 1).
    in_flight: int = field(default=3, metadata={"min": 1, "max": 16})
    #: GI-map codec.
    codec: CodecName = DEFAULT_CODEC
    spp: int = option_groups.spp(note="of the server's maps and the evaluation GT")
    #: Score composed frames against the path-traced GT every this many frames (staleness).
    gt_every: int = 10
    #: Pin the server, the proxy and the clients to separate cores (taskset) where the machine has them.
    pin: bool = True
    #: The client's read timeout, s (bounds one miss's server render; its deadline is twice it).
    read_timeout_s: float = 120.0

    @classmethod
    def quick(cls) -> PrefetchConfig:
        return cls(resolution=64, frames=150, spp=8)

    def check(self) -> None:
        check_served(self.resolution)
        for name in self.variants:
            if name not in VARIANTS:
                raise UserError(f"--variants {name!r} is not a variant", f"use some of {', '.join(VARIANTS)}")


# -- measuring ----------------------------------------------------------------------------------------------
def measure(cfg: PrefetchConfig, res: Results) -> None:
    scene = cfg.scenes[0]
    spec, scenes_dir, work, plan, flown = run_place(scene, res, "prefetch_runs", cfg.pin, cfg.path)
    cfg = with_path_frames(cfg, flown)
    common = {"resolution": cfg.resolution, "frames": cfg.frames, "orbit_frames": cfg.orbit_frames,
              "frame_rate": cfg.frame_rate, "spp": cfg.spp, "codec": cfg.codec}  # fmt: skip
    prebaked = work / "store_prebaked"
    shutil.rmtree(prebaked, ignore_errors=True)
    with pinned_server(plan, prebaked, scenes_dir) as url:
        misses = request_path_maps(url, scene, cfg, res.seed)["misses"]
        server = check_server(url, Path(scene).stem, cfg.resolution, cfg.codec, cfg.spp, cfg.read_timeout_s)
    res.add(system=SYSTEM, scene=spec.name, metric="prebake_maps", value=misses, unit="count", **common)
    views = flown_path(spec, cfg, res.seed).views(cfg.resolution)
    for store, floor in request_floors(views, spec.camera.gi_fov, prebaked, spec.name, server).items():
        res.add(system=SYSTEM, scene=spec.name, metric="request_floor", value=floor, unit="count", store=store,
                **common)  # fmt: skip
    argv = [str(BIN / "cloudbaking-client"), "--scene", scene, *path_options(cfg),
            "--resolution", str(cfg.resolution), "--spp", str(cfg.spp),
            "--gt-every", str(cfg.gt_every), "--codec", cfg.codec, "--frame-rate", str(cfg.frame_rate),
            "-k", str(cfg.every), "--seed", str(res.seed), "--read-timeout", str(cfg.read_timeout_s),
            "--deadline", str(2 * cfg.read_timeout_s), "--gt-cache", str(work / "gt_cache")]  # fmt: skip
    shutil.rmtree(work / "gt_cache", ignore_errors=True)  # one GT per bench run, shared by its client runs
    in_flight = {"period": 1, "hold": cfg.in_flight, "prefetch": cfg.in_flight}
    timeout = 300.0 + cfg.frames * 2.0 + (cfg.frames // cfg.gt_every + 1) * 20.0 + cfg.read_timeout_s
    for profile in cfg.profiles:
        for variant in cfg.variants:
            store = work / "store_run"
            shutil.rmtree(store, ignore_errors=True)
            shutil.copytree(prebaked, store)
            with pinned_server(plan, store, scenes_dir) as url:
                request_path_maps(url, scene, cfg, res.seed, off_path=True)  # compiles the scene and every pass
                with pinned_proxy(plan, profile, url, res.seed) as proxied:
                    folder = run_client(plan, [*argv, *VARIANTS[variant], "--in-flight", str(in_flight[variant]),
                                            "--server", proxied], work / f"{profile}_{variant}", timeout)  # fmt: skip
            shutil.rmtree(store, ignore_errors=True)
            config = common | {"profile": profile, "variant": variant, "k": cfg.every, "in_flight": in_flight[variant]}
            record(res, spec.name, folder, config)
    shutil.rmtree(prebaked, ignore_errors=True)
    targets(res, spec.name)


def record(res: Results, scene: str, folder: Path, config: dict[str, Any]) -> None:
    """Rows of one client run (its ``frames.csv``, ``requests.csv`` and ``summary.json``)."""
    m = RunMetrics.read(folder)
    config = config | {"renderer": read_summary(folder)["renderer"]}
    for cache, values in m.perceived.items():
        if values:
            for stat, value in m.quantiles(cache).items():
                res.add(system=SYSTEM, scene=scene, metric="perceived", value=value, unit="ms", stat=stat,
                        cache=cache, **config)  # fmt: skip
            res.add(system=SYSTEM, scene=scene, metric="perceived", value=len(values), unit="count", stat="n",
                    cache=cache, **config)  # fmt: skip
    if m.request_latency:
        samples = [v / 1e3 for v in m.request_latency]
        res.add_timing(system=SYSTEM, scene=scene, metric="request_latency", samples_s=samples, **config)
    res.add(system=SYSTEM, scene=scene, metric="censored", value=m.censored, unit="frames", **config)
    res.add(system=SYSTEM, scene=scene, metric="in_tolerance", value=m.in_tolerance, unit="fraction", **config)
    if m.mean_ssim is not None:
        res.add(system=SYSTEM, scene=scene, metric="ssim", value=m.mean_ssim, unit="ssim", stat="mean", **config)
    for name, value in (("requests", m.requests), ("failed_requests", m.failed_requests)):
        res.add(system=SYSTEM, scene=scene, metric=name, value=value, unit="count", **config)
    for name, value in (("bytes_up", m.bytes_up), ("bytes_down", m.bytes_down)):
        res.add(system=SYSTEM, scene=scene, metric=name, value=value, unit="bytes", stat="total", **config)


def targets(res: Results, scene: str) -> None:
    """The two targets as ``target_met`` rows, where the runs they compare were made."""
    rows = res.rows
    checks = [
        ("wan", "perceived", "median", {"cache": "all"}, "prefetch", "hold", PERCEIVED_BOUND,
         "median perceived latency, never-served frames as endless, prefetch <= 0.5 x hold (wan)"),
        ("wan", "perceived", "median", {"cache": "hit"}, "prefetch", "hold", PERCEIVED_BOUND,
         "median perceived latency of frames served by a hit, prefetch <= 0.5 x hold (wan)"),
        ("lan", "requests", "value", {}, "hold", "period", REQUESTS_BOUND, "requests, hold <= 0.5 x period (lan)"),
        ("lan", "requests", "value", {}, "prefetch", "period", REQUESTS_BOUND,
         "requests, prefetch <= 0.5 x period (lan)"),
    ]  # fmt: skip
    for profile, metric, stat, extra, variant, against, bound, text in checks:
        mine = first(rows, metric, stat, profile=profile, variant=variant, **extra)
        base = first(rows, metric, stat, profile=profile, variant=against, **extra)
        if mine is None or base is None:
            continue
        ratio = mine / base if base > 0 else float("inf")
        res.add(system=SYSTEM, scene=scene, metric=metric, value=int(ratio <= bound), unit="bool", stat="target_met",
                profile=profile, target=text, ratio=ratio, measured=mine, baseline=base)  # fmt: skip


# -- what it shows ------------------------------------------------------------------------------------------
def runs(rows: Rows) -> list[dict]:
    """Per profile and variant: requests, KiB down, in-tolerance share, perceived latency (all, and hits), censored
    frames and mean SSIM."""
    out = []
    for r in (r for r in rows if matches(r, "requests", "value")):
        key = {"profile": r["config"]["profile"], "variant": r["config"]["variant"]}

        def v(metric: str, stat: str = "value", **extra: Any) -> float | None:
            return first(rows, metric, stat, **key, **extra)  # noqa: B023 -- used within this iteration

        down, tol = v("bytes_down", "total"), v("in_tolerance")
        row = key | {"in_flight": r["config"].get("in_flight"), "requests": r["value"], "ssim": v("ssim", "mean")}
        row |= {"kib": down and down / 1024, "tol": tol and 100 * tol, "censored": v("censored")}
        row |= {"p50": v("perceived", "median", cache="all"), "p95": v("perceived", "p95", cache="all")}
        out.append(row | {"hits": v("perceived", "median", cache="hit")})
    return out


def floors(rows: Rows) -> str:
    floor = {r["config"]["store"]: r["value"] for r in rows if matches(r, "request_floor", "value")}
    return fill(
        "Fewest requests that serve every view of the path, with perfect foresight: {prebaked:.0f} from the prebaked "
        "store's maps (no request policy sends fewer here), {placed:.0f} from maps centred on the path's own views (a "
        "client choosing where maps are baked, on a cold store: each request a bake).",
        floor,
    ) if floor else ""  # fmt: skip


PARTS = (
    Table(
        runs,
        (
            Column("profile", "{profile}"),
            Column("variant (in flight)", "{variant} ({in_flight})"),
            Column("requests", "{requests:.0f}"),
            Column("KiB down", "{kib:.0f}"),
            Column("in tolerance", "{tol:.0f} %"),
            Column("perceived median (p95) ms", "{p50:.0f} ({p95:.0f})"),
            Column("hits: median ms", "{hits:.0f}"),
            Column("censored frames", "{censored:.0f}"),
            Column("mean SSIM", "{ssim:.3f}"),
        ),
        caption="Perceived latency: per frame, from its start (the camera moved) to the first frame showing a map "
        "within the server's tolerance of its view; frames no map ever served (censored) count as endless in the "
        "median and p95 of all frames and are left out of the hits' median. Same path, a fresh copy of the same "
        "prebaked store per run, frames paced like a display; hold and prefetch with the run's in_flight requests in "
        "flight, period with one.",
        notes=floors,
        scroll=True,
    ),
    Table(
        lambda rows: [flat(r) | {"met": "yes" if r["value"] else "MISSED"} for r in rows if r["stat"] == "target_met"],
        (
            Column("target", "{target}"),
            Column("measured", "{measured:.1f} vs {baseline:.1f}"),
            Column("ratio", "{ratio:.2f}"),
            Column("met", "{met}"),
        ),
    ),
    Figure(
        "prefetch",
        (
            Chart(
                pick("perceived", "median", cache="hit"),
                "profile",
                series="{variant}",
                kind="bar",
                ylabel="perceived latency of hits, median [ms]",
            ),
            Chart(pick("requests", "value"), "profile", series="{variant}", kind="bar", ylabel="requests"),
        ),  # fmt: skip
    ),
)


BENCH = Bench(
    "prefetch",
    PrefetchConfig,
    measure,
    help="The cloud client's request rules and prefetch: perceived latency, staleness, requests, bytes",
    dashboard=Section("prefetch", "Prefetch: hiding the network in cloud baking", 12),
    readme=Block("Cloud-baking prefetch", 12),
    parts=PARTS,
    needs=("perceived", "requests"),
)
