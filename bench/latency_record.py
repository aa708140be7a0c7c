"""`bench latency`'s rows from its client runs, as each client reads its run's files back
(:func:`gigan_local.client.stage_samples`, :class:`baseline_cloudbaking.client_run.RunMetrics`): stage timings per
system, profile, cache state and renderer; the ratio of totals, the link model's check and crossover
(:class:`network_sim.exchange.CloudCost`), perceived latency, SSIM along the path, and the renderers' ratios."""

from __future__ import annotations

import json
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from baseline_cloudbaking.client_run import REQUEST_STAGES, RunMetrics
from bench.intervals import add_interval, crossover_interval, ratio_interval, stream
from gicore.frame_rows import read_csv_rows, read_summary, scored_ssim
from gicore.results import Results
from gigan_local.client import stage_samples
from network_sim.exchange import CloudCost, sweep_link

GIGAN, CLOUD = "gigan", "cloud_baking"
#: The cloud client with --prefetch extrapolate (see the module docstring).
CLOUD_PREFETCH = "cloud_baking_prefetch"
#: The renderers' ratio rows: numerator / denominator, each stage's median of one run over the other's.
RENDERER_RATIO = ("gl", "mitsuba")


class Recorded(Protocol):
    """What the rows of a run record of the bench's config (:class:`bench.latency.LatencyConfig`)."""

    model: Path
    codec: str
    sweep_rate_mbit: float | None
    sweep_max_rtt_ms: float


def record(
    res: Results,
    scene: str,
    cfg: Recorded,
    runs: dict[tuple[str, str, str, str], Path],
    common: dict[str, Any],
) -> None:
    """Rows of every run (per renderer), what each client run ran (:func:`record_backends`), then the renderers'
    ratios (:func:`record_renderer_ratios`)."""
    for renderer in dict.fromkeys(key[3] for key in runs):
        mine = {key[:3]: folder for key, folder in runs.items() if key[3] == renderer}
        record_renderer(res, scene, cfg, mine, common | {"renderer": renderer})
    record_backends(res, scene, runs, common)
    record_renderer_ratios(res, scene)


def record_backends(
    res: Results, scene: str, runs: dict[tuple[str, str, str, str], Path], common: dict[str, Any]
) -> None:
    """A ``frames`` row per client run (the frames it flew), its config naming what ran: the renderer and the warp
    backend (``warp_backend``), GIGAN's inference backend (``inference``) and its device (``inference_device``), as
    the run's summary.json says; for cloud baking, the server's Mitsuba variant and denoiser (``server_variant``,
    ``server_denoiser``): the server inherits this process's environment on this machine, so it makes this
    process's choice (:func:`gicore.mitsuba_variant.mitsuba_choice`)."""
    from gicore.cuda_probe import cuda_for_torch
    from gicore.mitsuba_variant import mitsuba_choice

    for (system, profile, store, renderer), folder in runs.items():
        summary = read_summary(folder)
        ran: dict[str, Any] = {"renderer": renderer, "warp_backend": summary["warp_backend"]}
        if system == GIGAN:
            # torch runs on CUDA where torch sees a device (gigan_local.torch_backend); onnxruntime on the CPU
            device = "cuda" if summary["inference"] == "torch" and cuda_for_torch() else "cpu"
            ran |= {"inference": summary["inference"], "inference_device": device}
        else:
            server = mitsuba_choice()
            ran |= {"server_variant": server.variant, "server_denoiser": server.denoiser}
        where = {"profile": profile, "store": store} | common | ran
        res.add(system=system, scene=scene, metric="frames", value=summary["frames"], unit="count", **where)


def record_renderer(
    res: Results, scene: str, cfg: Recorded, runs: dict[tuple[str, str, str], Path], common: dict[str, Any]
) -> None:
    """Rows of one renderer's runs: stage timings, ratios, the link model's check and crossover, quality along
    the path."""
    gigan_totals = _record_gigan(res, scene, cfg, runs[GIGAN, "none", "local"], common)
    cloud = _record_cloud_runs(res, scene, cfg, runs, common)
    for (profile, cache), samples in cloud.items():
        config = {"profile": profile, "cache": cache, "codec": cfg.codec} | common
        _record_cloud_stages(res, scene, profile, samples, gigan_totals, config)
    for cache in ("hit", "miss"):
        pooled = _pool([s for (_, c), s in cloud.items() if c == cache])
        if pooled.get("total"):
            config = {"cache": cache, "rate_mbit": cfg.sweep_rate_mbit, "codec": cfg.codec} | common
            _record_crossover(res, scene, cfg, pooled, gigan_totals, config)


def _record_gigan(res: Results, scene: str, cfg: Recorded, folder: Path, common: dict[str, Any]) -> list[float]:
    """GIGAN's stage timings and SSIM rows; its per-map totals (ms)."""
    frames = read_csv_rows(folder / "frames.csv")
    gigan = stage_samples(frames)
    for stage, values in gigan.items():
        res.add_timing(
            system=GIGAN,
            scene=scene,
            metric=stage,
            samples_s=[v / 1e3 for v in values],
            profile="none",
            **common,
            model=cfg.model.name,
        )
    _ssim_rows(res, scene, GIGAN, scored_ssim(frames), {"profile": "none", "store": "none"} | common)
    return gigan["total"]


def _record_cloud_runs(
    res: Results, scene: str, cfg: Recorded, runs: dict[tuple[str, str, str], Path], common: dict[str, Any]
) -> dict[tuple[str, str], dict[str, list[float]]]:
    """Each cloud run's perceived latency, failed requests and SSIM rows; the plain client's stage samples per
    (profile, cache state), its runs on both stores pooled."""
    cloud: dict[tuple[str, str], dict[str, list[float]]] = {}
    for (system, profile, store), folder in runs.items():
        if system not in (CLOUD, CLOUD_PREFETCH):
            continue
        run = RunMetrics.read(folder)
        where = {"profile": profile, "store": store} | common
        if store == "prebaked":
            _perceived_rows(res, scene, system, run, where)
        if system == CLOUD_PREFETCH:  # its requests ask ahead: its per-map stages are no Table 1 column
            continue
        for cache, samples in run.stages.items():  # both stores' runs pooled
            cloud[profile, cache] = _pool([cloud.get((profile, cache), {}), samples])
        res.add(system=CLOUD, scene=scene, metric="failed_requests", value=run.failed_requests, unit="count", **where)
        _ssim_rows(res, scene, CLOUD, run.ssim, where | {"codec": cfg.codec})
    return cloud


def _record_cloud_stages(
    res: Results, scene: str, profile: str, samples: dict[str, list[float]], gigan: Sequence[float], config: dict
) -> None:
    """Cloud baking's stage timings, bytes, the ratio of totals (over GIGAN's per-map totals ``gigan``) with its
    bootstrap interval (:mod:`bench.intervals`), and the link model's total at ``profile``."""
    from network_sim import profiles as profile_table

    add = partial(res.add, system=CLOUD, scene=scene, stat="median")
    for stage in (*REQUEST_STAGES, "total", "pickup"):
        if samples.get(stage):
            res.add_timing(
                system=CLOUD, scene=scene, metric=stage, samples_s=[v / 1e3 for v in samples[stage]], **config
            )
    for name in ("bytes_up", "bytes_down"):
        add(metric=name, value=float(np.median(samples[name])), unit="B", **config)
    link = profile_table.get(profile).link(seed=res.seed)
    config = config | {"rtt_ms": link.rtt_s * 1e3}
    ratio = float(np.median(samples["total"])) / float(np.median(gigan))
    add(system=f"{CLOUD}/{GIGAN}", metric="total_ratio", value=ratio, unit="1", **config)
    interval = ratio_interval(samples["total"], gigan, stream(res.seed, "total_ratio", config))
    add_interval(res, interval, system=f"{CLOUD}/{GIGAN}", scene=scene, metric="total_ratio", unit="1", **config)
    add(metric="total_model", value=CloudCost.of(samples).total_ms(link, starts=20), unit="ms", **config)


def _record_crossover(
    res: Results, scene: str, cfg: Recorded, pooled: dict[str, list[float]], gigan: Sequence[float], config: dict
) -> None:
    """The link model with one cache state's pooled stages: the crossover RTT against the median of GIGAN's per-map
    totals ``gigan`` with its bootstrap interval (:func:`bench.intervals.crossover_interval`), and the ratio over an
    RTT sweep."""
    cost, gigan_total = CloudCost.of(pooled), float(np.median(gigan))
    crossover = cost.crossover_rtt_ms(gigan_total, cfg.sweep_rate_mbit)
    add = partial(res.add, system=f"{CLOUD}/{GIGAN}", scene=scene, stat="model", **config)
    add(metric="crossover_rtt", value=crossover, unit="ms")
    seed = stream(res.seed, "crossover_rtt", config)
    interval = crossover_interval(pooled, gigan, cfg.sweep_rate_mbit, seed)
    add_interval(res, interval, system=f"{CLOUD}/{GIGAN}", scene=scene, metric="crossover_rtt", unit="ms", **config)
    for rtt in np.linspace(0.0, cfg.sweep_max_rtt_ms, 26):
        total = cost.total_ms(sweep_link(float(rtt), cfg.sweep_rate_mbit))
        add(metric="ratio_model", value=total / gigan_total, unit="1", rtt_ms=float(rtt))


def record_renderer_ratios(res: Results, scene: str) -> None:
    """``stat = "renderer_ratio"`` rows (config ``renderer = "gl/mitsuba"``): for every stage median both
    renderers measured in this run with otherwise equal settings, gl's over mitsuba's."""
    num, den = RENDERER_RATIO
    medians = [r for r in res.rows if r["stat"] == "median" and r["unit"] == "ms"]

    def key(r: dict[str, Any]) -> tuple:
        rest = tuple(sorted((k, json.dumps(v)) for k, v in r["config"].items() if k != "renderer"))
        return r["system"], r["metric"], rest

    by_renderer: dict[str, dict[tuple, dict[str, Any]]] = {}
    for r in medians:
        by_renderer.setdefault(r["config"].get("renderer"), {})[key(r)] = r
    for k, r in by_renderer.get(num, {}).items():
        other = by_renderer.get(den, {}).get(k)
        if other is None or not other["value"] > 0:
            continue
        config = r["config"] | {"renderer": f"{num}/{den}"}
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


def _perceived_rows(res: Results, scene: str, system: str, run: RunMetrics, config: dict) -> None:
    """A cloud run's perceived latency (median, p95; never-served frames as endless), in-tolerance share, requests
    and mean SSIM (see the module docstring)."""
    add = partial(res.add, system=system, scene=scene, **config)
    for stat, value in run.quantiles().items():
        add(metric="perceived", value=value, unit="ms", stat=stat)
    add(metric="in_tolerance", value=run.in_tolerance, unit="1")
    add(metric="requests", value=run.requests, unit="count")
    if system == CLOUD_PREFETCH and run.ssim:  # the plain client's SSIM rows come with its Table 1 rows
        add(metric="ssim", value=run.mean_ssim, unit="1", stat="mean")


def _ssim_rows(res: Results, scene: str, system: str, scored: dict[int, float], config: dict[str, Any]) -> None:
    add = partial(res.add, system=system, scene=scene, metric="ssim", unit="1", **config)
    for frame, value in scored.items():
        add(value=value, stat="frame", frame=frame)
    if scored:
        add(value=float(np.mean(list(scored.values()))), stat="mean")
