"""`bench latency` (paper Table 1): interaction latency of GIGAN and of cloud baking, stage by stage, from
real processes talking over the simulated network.

One run starts a ``gigan-client`` (once per renderer: it needs no network) and, per network profile, a
``network-sim proxy`` in front of a ``cloudbaking-server`` with a ``cloudbaking-client`` behind it, against a
prebaked store (hits) and a cold one (misses); every client run is made once per renderer of ``renderers``.
Rows: each stage's median and p95 per system, profile, cache state and renderer; ``total_ratio`` (cloud over
GIGAN, same run), ``renderer_ratio`` (gl over mitsuba, same run), the crossover RTT from the link model, and
SSIM along the path. What each stage holds, and why the local render counts for both systems:
docs/architecture.md, bench latency and Honest accounting.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC
from bench.exported_models import check_model_resolution
from bench.processes import (
    BIN,
    ask_path,
    check_served,
    path_options,
    pinned_proxy,
    pinned_server,
    run_client,
    run_place,
    threads,
    with_path_frames,
)
from bench.runner import Bench, Block, Figure, Part, Rows, Section, Table, cell, need, pick
from bench.svg import Point, Series, XYChart
from gicore.blend import COMPOSITIONS
from gicore.error_policy import UserError
from gicore.loop import RENDERERS
from gicore.options import PATH_FILE
from gicore.results import Results, read_rows
from gigan_local.inference import DEFAULT_MODEL
from network_sim.exchange import CloudCost, sweep_link

CodecName = Literal[CODEC_NAMES]  # type: ignore[valid-type]
GIGAN, CLOUD = "gigan", "cloud_baking"
#: The cloud client with --prefetch extrapolate (see the module docstring).
CLOUD_PREFETCH = "cloud_baking_prefetch"
#: GIGAN's stages, then cloud baking's, in the order a map goes through them (``total`` last).
GIGAN_STAGES = ("di", "gi_render", "inference", "warp", "blend")
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
    "di",
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
    path: Path | None = field(default=None, metadata=PATH_FILE)
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
    #: Renderers of both clients' per-frame raster passes, each a run of every client side by side: gl (OpenGL,
    #: level of detail auto; left out with one warning where no GL context opens) and/or mitsuba.
    renderers: tuple[str, ...] = ("gl", "mitsuba")
    #: Requests in flight of a cloud client with --prefetch extrapolate run beside the plain one on the prebaked
    #: store (first renderer only; 0: none).
    prefetch_in_flight: int = field(default=3, metadata={"min": 0, "max": 16})

    @classmethod
    def quick(cls) -> LatencyConfig:
        return cls(profiles=("lan", "wan"), frames=90, every=5, spp=16)

    def check(self) -> None:
        from network_sim import profiles

        check_served(self.resolution)
        known = profiles.profiles()
        for name in self.profiles:
            if name not in known:
                raise UserError(
                    f"--profiles {name!r} is not a network profile",
                    f"use some of {', '.join(known)} (see network-sim profiles)",
                )
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
    used = json.loads((folder / "summary.json").read_text())["renderer"]
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
    shutil.rmtree(work / "gt_cache", ignore_errors=True)  # rendered again by each bench run's code

    def client(argv: list[str], name: str, renderer: str) -> Path:
        folder = run_client(plan, [*argv, "--renderer", renderer], work / f"{name}_{renderer}", per_run)
        return _ran_on(folder, renderer)

    # Runs are keyed (system, profile, store, renderer); each renderer's run of a slot follows the other's at once,
    # so the renderers' ratios compare runs taken minutes apart at most, under the same load.
    gigan_argv = [str(BIN / "gigan-client"), *path_args, "--gi-source", "model", "--model", str(cfg.model),
                  "--threads", str(threads(plan, "client"))]  # fmt: skip
    runs = {(GIGAN, "none", "local", r): client(gigan_argv, "gigan", r) for r in renderers}
    cloud_argv = [str(BIN / "cloudbaking-client"), *path_args, "--codec", cfg.codec,
                  "--read-timeout", str(cfg.read_timeout_s), "--deadline", str(2 * cfg.read_timeout_s)]  # fmt: skip
    shutil.rmtree(work / "store_prebaked", ignore_errors=True)  # every run prebakes its own store
    residual = cfg.composition == "residual"  # the first pass asks for the maps the runs will ask for
    with pinned_server(plan, work / "store_prebaked", scenes_dir) as warm:
        t0 = time.perf_counter()
        first = ask_path(warm, scene, cfg, res.seed, residual=residual)
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
            # a cold store per renderer: each run's requests miss as the other's did
            for renderer in renderers:
                store = work / f"store_cold_{profile}_{renderer}"
                shutil.rmtree(store, ignore_errors=True)
                with pinned_server(plan, store, scenes_dir) as cold:
                    ask_path(cold, scene, cfg, res.seed, residual=residual, off_path=True)  # compiles every pass
                    with pinned_proxy(plan, profile, cold, res.seed) as url:
                        runs[CLOUD, profile, "cold", renderer] = client(
                            [*cloud_argv, "--server", url], f"cloud_{profile}_cold", renderer
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
            "di": float(row["di_ms"]),
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
    res: Results,
    scene: str,
    cfg: LatencyConfig,
    runs: dict[tuple[str, str, str, str], Path],
    common: dict[str, Any],
) -> None:
    """Rows of every run (per renderer), then the renderers' ratios (:func:`record_renderer_ratios`)."""
    for renderer in dict.fromkeys(key[3] for key in runs):
        mine = {key[:3]: folder for key, folder in runs.items() if key[3] == renderer}
        record_renderer(res, scene, cfg, mine, common | {"renderer": renderer})
    record_renderer_ratios(res, scene)


def record_renderer(
    res: Results, scene: str, cfg: LatencyConfig, runs: dict[tuple[str, str, str], Path], common: dict[str, Any]
) -> None:
    """Rows of one renderer's runs: stage timings, ratios, the link model's check and crossover, quality along
    the path."""
    from network_sim import profiles as profile_table

    gigan_frames = _csv(runs[GIGAN, "none", "local"] / "frames.csv")
    gigan = gigan_samples(gigan_frames)
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
        if system not in (CLOUD, CLOUD_PREFETCH):
            continue
        frames = _csv(folder / "frames.csv")
        requests = _csv(folder / "requests.csv")
        if store == "prebaked" and frames and "perceived_ms" in frames[0]:  # absent: no perceived rows
            _perceived_rows(res, scene, system, frames, requests, {"profile": profile, "store": store} | common)
        if system == CLOUD_PREFETCH:  # its requests ask ahead: its per-map stages are no Table 1 column
            continue
        for cache, samples in cloud_samples(requests).items():
            merged = cloud.setdefault((profile, cache), {})
            for name, values in samples.items():
                merged.setdefault(name, []).extend(values)
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
        for stage in (*CLOUD_STAGES, "total", "pickup"):
            if samples.get(stage):
                res.add_timing(
                    system=CLOUD, scene=scene, metric=stage, samples_s=[v / 1e3 for v in samples[stage]], **config
                )
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


#: The renderers' ratio rows: numerator / denominator, each stage's median of one run over the other's.
RENDERER_RATIO = ("gl", "mitsuba")


def record_renderer_ratios(res: Results, scene: str) -> None:
    """``stat = "renderer_ratio"`` rows (config ``renderer = "gl/mitsuba"``): for every stage median both
    renderers measured in this run with otherwise equal settings, gl's over mitsuba's."""
    num, den = RENDERER_RATIO
    medians = [r for r in res.rows if r["stat"] == "median" and r["unit"] == "ms"]

    def key(r: dict[str, Any]) -> tuple:
        config = json.loads(r["config"])
        rest = tuple(sorted((k, json.dumps(v)) for k, v in config.items() if k != "renderer"))
        return r["system"], r["metric"], rest

    by_renderer: dict[str, dict[tuple, dict[str, Any]]] = {}
    for r in medians:
        by_renderer.setdefault(json.loads(r["config"]).get("renderer"), {})[key(r)] = r
    for k, r in by_renderer.get(num, {}).items():
        other = by_renderer.get(den, {}).get(k)
        if other is None or not other["value"] > 0:
            continue
        config = json.loads(r["config"]) | {"renderer": f"{num}/{den}"}
        res.add(
            system=r["system"],
            scene=scene,
            metric=r["metric"],
            value=r["value"] / other["value"],
            unit="1",
            stat="renderer_ratio",
            **config,
        )


def _pool(groups: list[dict[str, list[float]]]) -> dict[str, list[float]]:
    pooled: dict[str, list[float]] = {}
    for group in groups:
        for name, values in group.items():
            pooled.setdefault(name, []).extend(values)
    return pooled


def _perceived_rows(
    res: Results,
    scene: str,
    system: str,
    frames: list[dict[str, str]],
    requests: list[dict[str, str]],
    config: dict[str, Any],
) -> None:
    """A cloud run's perceived latency (median, p95; never-served frames as endless), in-tolerance share, requests
    and mean SSIM (see the module docstring)."""
    waits = [math.inf if r["perceived_ms"] == "" else float(r["perceived_ms"]) for r in frames]
    for stat, q in (("median", 50), ("p95", 95)):
        value = float(np.percentile(waits, q, method="inverted_cdf"))
        res.add(system=system, scene=scene, metric="perceived", value=value, unit="ms", stat=stat, **config)
    shown = float(np.mean([int(r["in_tolerance"]) for r in frames]))
    res.add(system=system, scene=scene, metric="in_tolerance", value=shown, unit="1", **config)
    res.add(system=system, scene=scene, metric="requests", value=len(requests), unit="count", **config)
    scored = [float(r["ssim"]) for r in frames if r.get("ssim")]
    if system == CLOUD_PREFETCH and scored:  # the plain client's SSIM rows come with its Table 1 rows
        res.add(
            system=system, scene=scene, metric="ssim", value=float(np.mean(scored)), unit="1", stat="mean", **config
        )


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
    ("di", "local render: DI + the warp's pass (the frame showing the map)"),
    ("warp", "warp (per-map bind + per-frame warp stages)"),
    ("blend", "blend"),
    ("total", "**total (interaction latency)**"),
)
COLUMNS = ((GIGAN, None, "GIGAN"), (CLOUD, "hit", "cloud baking, hit"), (CLOUD, "miss", "cloud baking, miss"))
#: The stages the renderers' comparison shows: those a raster pass is in, and the totals.
RENDERER_ROWS = (
    ("di", "local render (DI + warp pass)"),
    ("gi_render", "GI-camera render"),
    ("warp", "warp"),
    ("total", "total"),
)


def with_renderer(rows: list[dict]) -> list[dict]:
    """The rows, each config naming its renderer: runs from before the clients had a choice ran Mitsuba's. Their
    ``di`` rows are left out: they timed every frame's DI, which their totals did not count."""
    return [
        r if "renderer" in r["config"] else r | {"config": r["config"] | {"renderer": "mitsuba"}}
        for r in rows
        if "renderer" in r["config"] or r["metric"] != "di"
    ]


def renderers_of(rows: list[dict]) -> list[str]:
    """The renderers with measured totals, in the run's order."""
    return list(
        dict.fromkeys(r["config"]["renderer"] for r in rows if r["metric"] == "total" and r["stat"] == "median")
    )


def _lookup(rows: list[dict], system: str, metric: str, stat: str, **config: Any) -> float | None:
    for r in rows:
        if (r["system"], r["metric"], r["stat"]) == (system, metric, stat) and all(
            r["config"].get(k) == v for k, v in config.items()
        ):
            return r["value"]
    return None


def _column_config(system: str, cache: str | None, profile: str, renderer: str) -> dict[str, Any]:
    where = {"profile": "none"} if system == GIGAN else {"profile": profile, "cache": cache}
    return where | {"renderer": renderer}


def _profiles(rows: list[dict]) -> list[str]:
    return list(dict.fromkeys(r["config"]["profile"] for r in rows if r["system"] == CLOUD and "cache" in r["config"]))


def table(rows: list[dict]) -> str:
    """Table 1 per profile, a column per system and renderer (median ms, p95 in brackets), the ratios, the link
    model's check, the renderers side by side and the crossovers."""
    rows = with_renderer(rows)
    renderers = renderers_of(rows)
    columns = [
        (system, cache, renderer, f"{label}, {renderer}") for renderer in renderers for system, cache, label in COLUMNS
    ]
    profiles = _profiles(rows)
    scene = rows[0]["scene"] if rows else ""
    lines = [f"## Table 1: interaction latency, {scene} (ms: median, p95 in brackets)", ""]
    for profile in profiles:
        rtt_ms = next(
            (r["config"]["rtt_ms"] for r in rows if r["metric"] == "total_ratio" and r["config"]["profile"] == profile),
            None,
        )
        lines += [f"### profile `{profile}`" + (f" (RTT {rtt_ms:g} ms)" if rtt_ms is not None else ""), ""]
        lines += ["| stage | " + " | ".join(c[3] for c in columns) + " |", "|---" * (1 + len(columns)) + "|"]
        for metric, label in TABLE_ROWS:
            cells = []
            for system, cache, renderer, _ in columns:
                where = _column_config(system, cache, profile, renderer)
                median = _lookup(rows, system, metric, "median", **where)
                p95 = _lookup(rows, system, metric, "p95", **where)
                cells.append("—" if median is None else f"{median:.1f} ({p95:.1f})")
            if any(c != "—" for c in cells):
                lines.append(f"| {label} | " + " | ".join(cells) + " |")

        def cloud_cells(system: str, metric: str, spec: str) -> str:
            values = [
                None if s == GIGAN else _lookup(rows, system, metric, "median", profile=profile, cache=c, renderer=r)
                for s, c, r, _ in columns
            ]
            return " | ".join(cell(v, spec) if v is not None else "—" for v in values)

        lines.append(
            "| ratio of totals, cloud / GIGAN (same renderer) | "
            + cloud_cells(f"{CLOUD}/{GIGAN}", "total_ratio", ".2f")
            + " |"
        )
        lines.append("| total by the link model (check) | " + cloud_cells(CLOUD, "total_model", ".1f") + " |")
        counts = [_lookup(rows, s, "total", "n", **_column_config(s, c, profile, r)) for s, c, r, _ in columns]
        lines.append("| maps measured | " + " | ".join("0" if n is None else f"{n:.0f}" for n in counts) + " |")
        pickup = [
            cell(_lookup(rows, CLOUD, "pickup", "median", profile=profile, cache=c, renderer=r))
            for r in renderers
            for c in ("hit", "miss")
        ]
        lines += [
            "",
            "Not in the totals: cloud baking's wait from a map's arrival to the next frame taking it (median "
            + " / ".join(pickup)
            + " ms: "
            + " / ".join(f"{c} {r}" for r in renderers for c in ("hit", "miss"))
            + ").",
            "",
        ]
    lines += _renderer_table(rows, profiles)
    lines += _perceived_table(rows, profiles)
    crossings = [
        (r["config"]["renderer"], r["config"]["cache"], r["value"], r["config"].get("rate_mbit"))
        for r in rows
        if r["metric"] == "crossover_rtt"
    ]
    if crossings:
        lines += [
            "### crossover: the RTT beyond which GIGAN's median total beats cloud baking's "
            "(link model, measured stages)",
            "",
        ]
        lines += ["| renderer | cache | crossover RTT (ms) | link rate |", "|---|---|---|---|"]
        for renderer, cache, value, rate in crossings:
            shown = (
                "0 (GIGAN is faster at any RTT)"
                if value == 0
                else ("none up to a minute" if math.isinf(value) else f"{value:.0f}")
            )
            lines.append(f"| {renderer} | {cache} | {shown} | {'unlimited' if rate is None else f'{rate:g} Mbit/s'} |")
        lines.append("")
    return "\n".join(lines)


def _perceived_table(rows: list[dict], profiles: list[str]) -> list[str]:
    """The plain and the prefetching cloud client on the prebaked store, per profile and renderer: perceived
    latency, in-tolerance share, requests, mean SSIM (none in runs without these rows)."""
    runs = [
        (p, r, s)
        for p in profiles
        for r in renderers_of(rows)
        for s in (CLOUD, CLOUD_PREFETCH)
        if _lookup(rows, s, "perceived", "median", profile=p, renderer=r, store="prebaked") is not None
    ]
    if not runs:
        return []
    lines = [
        "### perceived latency on the prebaked store: from a camera move to a frame showing a map within tolerance",
        "",
        "| profile | renderer | client | perceived median (p95) ms | frames within tolerance | requests | mean SSIM |",
        "|---|---|---|---|---|---|---|",
    ]
    for profile, renderer, system in runs:
        where = {"profile": profile, "renderer": renderer, "store": "prebaked"}
        shown = _lookup(rows, system, "in_tolerance", "value", **where)
        lines.append(
            f"| `{profile}` | {renderer} | {'prefetch' if system == CLOUD_PREFETCH else 'plain'} "
            f"| {cell(_lookup(rows, system, 'perceived', 'median', **where), '.0f')} "
            f"({cell(_lookup(rows, system, 'perceived', 'p95', **where), '.0f')}) "
            f"| {cell(shown and 100 * shown, '.0f')} % "
            f"| {cell(_lookup(rows, system, 'requests', 'value', **where), '.0f')} "
            f"| {cell(_lookup(rows, system, 'ssim', 'mean', **where), '.3f')} |"
        )
    for renderer in dict.fromkeys(r for _, r, _ in runs):
        gigan = _lookup(rows, GIGAN, "total", "median", profile="none", renderer=renderer)
        k = next((r["config"].get("k") for r in rows if r["system"] == GIGAN), None)
        lines += [
            "",
            f"GIGAN ({renderer}) shows a map of the frame's own view every k = {k} frames, its Table 1 total "
            f"({cell(gigan, '.0f')} ms) after that frame's camera move; the frames between warp it.",
        ]
    return [*lines, ""]


def _renderer_table(rows: list[dict], profiles: list[str]) -> list[str]:
    """The renderers side by side: each raster stage's and each total's median with gl over with mitsuba, from
    the same run (none when the run measured one renderer)."""
    ratios = [r for r in rows if r["stat"] == "renderer_ratio"]
    if not ratios:
        return []
    num, den = RENDERER_RATIO
    where = [(GIGAN, {"profile": "none"}, "GIGAN")]
    where += [(CLOUD, {"profile": p, "cache": c}, f"cloud {c}, `{p}`") for p in profiles for c in ("hit", "miss")]
    lines = [f"### renderers side by side: median with {num} / median with {den} (same run)", ""]
    lines += ["| stage | " + " | ".join(label for *_, label in where) + " |", "|---" * (1 + len(where)) + "|"]
    for metric, label in RENDERER_ROWS:
        values = [_lookup(ratios, s, metric, "renderer_ratio", **config) for s, config, _ in where]
        if any(v is not None for v in values):
            lines.append(f"| {label} | " + " | ".join(cell(v, ".2f") for v in values) + " |")
    return [*lines, ""]


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """``latency_table.md`` (printed too), stacked stage bars, ratio against RTT, SSIM along the path."""
    from gicore.plotting import plt, save

    raw = read_rows(csv_path)
    md = out_dir / "latency_table.md"
    text = table(raw)
    md.write_text(text + "\n")
    print(text)
    written = [md]
    rows = with_renderer(raw)
    renderers = renderers_of(rows)
    profiles = _profiles(rows)

    # stacked stage bars: one bar per system, profile and renderer (GIGAN's once per renderer: it needs no network)
    cloud_stages = tuple(s for s in CLOUD_STAGES if s not in TRANSMISSION_PARTS)
    bars = []
    for r in renderers:
        bars.append((f"GIGAN, {r}", GIGAN, {"profile": "none", "renderer": r}, GIGAN_STAGES))
        bars += [(f"cloud {c}, {p}, {r}", CLOUD, {"profile": p, "cache": c, "renderer": r}, cloud_stages)
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
    for renderer, style in zip(renderers, ("-", "--")):
        for cache, colour in (("hit", "tab:blue"), ("miss", "tab:red")):
            mine = {"cache": cache, "renderer": renderer}
            curve = sorted(
                (r["config"]["rtt_ms"], r["value"])
                for r in rows
                if r["metric"] == "ratio_model" and r["config"].items() >= mine.items()
            )
            if curve:
                ax.plot(*zip(*curve), style, color=colour, label=f"{cache}, {renderer}: link model")
            points = [
                (r["config"]["rtt_ms"], r["value"], r["config"]["profile"])
                for r in rows
                if r["metric"] == "total_ratio" and r["config"].items() >= mine.items()
            ]
            for rtt, value, profile in points:
                ax.plot(rtt, value, "o" if style == "-" else "s", color=colour, mfc="none" if style != "-" else colour)
                ax.annotate(profile, (rtt, value), textcoords="offset points", xytext=(4, 4), fontsize=7)
            crossing = _lookup(rows, f"{CLOUD}/{GIGAN}", "crossover_rtt", "model", **mine)
            if crossing is not None and 0 < crossing < math.inf:
                ax.axvline(crossing, color=colour, ls=":", lw=1)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("round-trip time [ms] (points: measured profiles, whatever their rate)")
    ax.set_ylabel("cloud baking total / GIGAN total (same renderer)")
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
        for ax, profile in zip(axes[0], profiles or ["none"]):
            for renderer, style in zip(renderers, ("-", "--")):
                gigan = sorted(
                    (r["config"]["frame"], r["value"])
                    for r in scored
                    if r["system"] == GIGAN and r["config"]["renderer"] == renderer
                )
                if gigan:
                    ax.plot(*zip(*gigan), style, marker="o", ms=3, color="tab:green", label=f"GIGAN, {renderer}")
                for store, colour in (("prebaked", "tab:blue"), ("cold", "tab:red")):
                    mine = (profile, store, renderer)
                    line = sorted(
                        (r["config"]["frame"], r["value"])
                        for r in scored
                        if r["system"] == CLOUD
                        and (r["config"]["profile"], r["config"]["store"], r["config"]["renderer"]) == mine
                    )
                    if line:
                        label = f"cloud baking, {store} store, {renderer}"
                        ax.plot(*zip(*line), style, marker="s", ms=3, color=colour, label=label)
            ax.set_title(f"profile {profile}")
            ax.set_xlabel("frame")
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel("SSIM vs path-traced GT")
        axes[0][0].legend(fontsize=7)
        written.append(save(fig, out_dir / "latency_ssim.png"))
    return written


# -- bench report: the dashboard's section and the README's block ------------------------------------------
def dashboard_section(rows: Rows) -> list[Part]:
    """Table 1 in full, then the ratio of totals against RTT: the link model's curve, the measured profiles
    (per renderer)."""
    need(rows, "total")
    named = with_renderer(rows)
    lines = []
    for renderer in renderers_of(named):
        for cache in ("hit", "miss"):
            mine = {"cache": cache, "renderer": renderer}
            model = [
                Point(
                    r["config"]["rtt_ms"],
                    r["value"],
                    f"{cache}, {renderer}, link model: RTT {r['config']['rtt_ms']:g} ms → ratio {r['value']:.3g}",
                )
                for r in pick(named, "ratio_model")
                if r["config"].items() >= mine.items()
            ]
            measured = [
                Point(
                    r["config"]["rtt_ms"],
                    r["value"],
                    f"{cache}, {renderer}, profile {r['config']['profile']}: ratio {r['value']:.3g}",
                )
                for r in pick(named, "total_ratio")
                if r["config"].items() >= mine.items()
            ]
            if model:
                lines.append(Series(f"{cache}, {renderer}: link model", model))
            if measured:
                lines.append(Series(f"{cache}, {renderer}: measured profiles", measured, line=False))
    figure = XYChart(
        lines,
        "round-trip time [ms]",
        "cloud total / GIGAN total",
        ylog=True,
        caption="Above 1: GIGAN's interaction latency is lower (each system on the same renderer).",
    )
    return [Table(table(rows)), Figure((figure,))] if lines else [Table(table(rows))]


def readme_block(rows: Rows) -> list[Table]:
    """Table 1 in short: one line per network profile and renderer (totals, ratio, SSIM), GIGAN's stages, the
    renderers' ratios and the crossover RTTs."""
    need(rows, "total", "total_ratio")
    rows = with_renderer(rows)
    ratios = pick(rows, "total_ratio")
    rtt = {r["config"]["profile"]: r["config"].get("rtt_ms") for r in ratios}
    renderers = renderers_of(rows)
    c = ratios[0]["config"]
    lines = [
        f"{rows[0]['scene']}, {c.get('resolution')}², {c.get('frames')} frames, GI period k = {c.get('k')}, "
        f"{c.get('spp')} spp + OIDN on the server, {c.get('codec')} maps; the clients' raster passes on "
        f"{' and on '.join(renderers)}; medians in ms.",
        "",
        "| profile (RTT) | renderer | GIGAN | cloud hit | cloud miss | cloud / GIGAN: hit / miss "
        "| mean SSIM vs GT: GIGAN / prebaked / cold |",
        "|---|---|---|---|---|---|---|",
    ]
    for profile, rtt_ms in rtt.items():
        for renderer in renderers:
            gigan = _lookup(rows, GIGAN, "total", "median", profile="none", renderer=renderer)
            totals = [
                _lookup(rows, CLOUD, "total", "median", profile=profile, cache=cache, renderer=renderer)
                for cache in ("hit", "miss")
            ]
            ratio = [
                _lookup(
                    rows, f"{CLOUD}/{GIGAN}", "total_ratio", "median", profile=profile, cache=cache, renderer=renderer
                )
                for cache in ("hit", "miss")
            ]
            ssim = [_lookup(rows, GIGAN, "ssim", "mean", profile="none", renderer=renderer)]
            ssim += [
                _lookup(rows, CLOUD, "ssim", "mean", profile=profile, store=store, renderer=renderer)
                for store in ("prebaked", "cold")
            ]
            lines.append(
                f"| `{profile}` ({cell(rtt_ms, 'g')} ms) | {renderer} | {cell(gigan)} | {cell(totals[0])} | "
                f"{cell(totals[1])} | "
                + " / ".join(cell(r, ".2f") for r in ratio)
                + " | "
                + " / ".join(cell(s, ".3f") for s in ssim)
                + " |"
            )
    labels = (("di", "local render"), ("gi_render", "GI-camera render"), ("inference", "inference"), ("warp", "warp"),
              ("blend", "blend"))  # fmt: skip
    lines.append("")
    for renderer in renderers:
        gigan = _lookup(rows, GIGAN, "total", "median", profile="none", renderer=renderer)
        stages = [(label, _lookup(rows, GIGAN, m, "median", profile="none", renderer=renderer)) for m, label in labels]
        lines.append(
            f"GIGAN's total on {renderer} {cell(gigan)} ms = "
            + " + ".join(f"{label} {v:.1f}" for label, v in stages if v is not None)
            + "."
        )
    num, den = RENDERER_RATIO
    gigan_ratio = [
        (label, _lookup(rows, GIGAN, m, "renderer_ratio", profile="none")) for m, label in RENDERER_ROWS[::-1]
    ]
    if any(v is not None for _, v in gigan_ratio):
        lines.append(
            f"{num} / {den} in the same run, GIGAN: "
            + ", ".join(f"{label} {v:.2f}" for label, v in gigan_ratio if v is not None)
            + "."
        )
    crossings = []
    for r in pick(rows, "crossover_rtt"):
        cache, value, renderer = r["config"].get("cache"), r["value"], r["config"]["renderer"]
        if value == 0:
            crossings.append(f"a cloud {cache} at any RTT ({renderer})")
        elif math.isinf(value):
            crossings.append(f"a cloud {cache} at no RTT up to a minute ({renderer})")
        else:
            crossings.append(f"a cloud {cache} beyond an RTT of {value:.0f} ms ({renderer})")
    if crossings:
        lines.append(
            "Crossover (the link model with the measured stages): GIGAN's median total beats "
            + "; ".join(crossings)
            + "."
        )
    perceived = _perceived_table(rows, list(rtt))
    return [Table("\n".join([*lines, "", *perceived] if perceived else lines))]


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
