"""`bench latency`'s rows from its client runs, as each client reads its run's files back
(:func:`gigan_local.client.stage_samples`, :class:`baseline_cloudbaking.client_run.RunMetrics`): stage timings per
system, profile, cache state and renderer; the ratio of totals, the link model's check and crossover
(:class:`network_sim.exchange.CloudCost`), perceived latency, SSIM along the path, and the renderers' ratios.

Each client run may be repeated (``bench latency --repeats N``): the rows pool the repeats' per-map samples (stage
medians, p95, counts, ratios and crossovers from the pooled maps; perceived latency from the pooled frames; SSIM
per frame the mean over repeats; failed requests summed). Where every one of N >= 3 repeats measured a ratio or
crossover, its interval is over the runs' own values (:func:`gicore.intervals.interval_over_runs`), else the per-map
bootstrap; its rows' ``ci_over`` says which."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from baseline_cloudbaking.client_run import REQUEST_STAGES, RunMetrics
from gicore.frame_rows import read_csv_rows, read_summary, scored_ssim
from gicore.intervals import (
    MIN_SAMPLES,
    Interval,
    Seed,
    add_interval,
    interval_over_runs,
    ratio_interval,
    stream,
)
from gicore.results import Results
from gigan_local.client import stage_samples
from network_sim.exchange import CloudCost, crossover_interval, sweep_link

GIGAN, CLOUD = "gigan", "cloud_baking"
#: The cloud client with --prefetch extrapolate (see the module docstring).
CLOUD_PREFETCH = "cloud_baking_prefetch"
#: The renderers' ratio rows: numerator / denominator, each stage's median of one run over the other's.
RENDERER_RATIO = ("gl", "mitsuba")

#: The file in a cloud client run's folder where its proxy wrote how late it wrote its chunks (``--lateness``).
LATENESS_FILE = "proxy_lateness.json"

Samples = dict[str, list[float]]
#: Client runs by (system, profile, store, renderer): each repeat's output folder, every key as many.
Runs = dict[tuple[str, str, str, str], list[Path]]


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
    runs: Runs,
    common: dict[str, Any],
) -> None:
    """Rows of every run (per renderer, its repeats pooled), what each client run ran (:func:`record_backends`),
    then the renderers' ratios (:func:`record_renderer_ratios`)."""
    for renderer in dict.fromkeys(key[3] for key in runs):
        mine = {key[:3]: folder for key, folder in runs.items() if key[3] == renderer}
        record_renderer(res, scene, cfg, mine, common | {"renderer": renderer})
    record_backends(res, scene, runs, common)
    record_renderer_ratios(res, scene)
    record_lateness(res, scene, runs, common)


def record_lateness(res: Results, scene: str, runs: Runs, common: dict[str, Any]) -> None:
    """The simulated network's own fidelity per cloud client run: how late its proxy wrote its chunks after the
    link model's release (``network_sim`` ``proxy_lateness`` rows, ms, ``stat`` p50 and p99: the worst of its
    repeats) and whether that stayed within the limit (``proxy_reliable``: 1 when every repeat's p99 is at most
    :func:`network_sim.chunklog.lateness_limit_ms` of the profile's RTT, config ``limit_ms``)."""
    from network_sim.chunklog import read_lateness

    for (system, profile, store, renderer), folders in runs.items():
        reports = [read_lateness(f / LATENESS_FILE) for f in folders if (f / LATENESS_FILE).is_file()]
        if system != CLOUD or not reports:
            continue
        where = common | {"profile": profile, "store": store, "renderer": renderer, "limit_ms": reports[0]["limit_ms"]}
        add = partial(res.add, system="network_sim", scene=scene, **where)
        for stat in ("p50", "p99"):
            values = [r["all"][f"{stat}_ms"] for r in reports if r["all"][f"{stat}_ms"] is not None]
            if values:
                add(metric="proxy_lateness", value=max(values), unit="ms", stat=stat)
        add(metric="proxy_reliable", value=int(all(r["reliable"] for r in reports)), unit="bool")


def record_backends(res: Results, scene: str, runs: Runs, common: dict[str, Any]) -> None:
    """A ``frames`` row per client run (the frames it flew; one for a run's repeats that ran alike), its config
    naming what ran: the renderer and the warp
    backend (``warp_backend``), GIGAN's inference backend (``inference``) and its device (``inference_device``), as
    the run's summary.json says; for cloud baking, the server's Mitsuba variant and denoiser (``server_variant``,
    ``server_denoiser``): the server inherits this process's environment on this machine, so it makes this
    process's choice (:func:`gicore.mitsuba_variant.mitsuba_choice`)."""
    from gicore.cuda_probe import cuda_for_torch
    from gicore.mitsuba_variant import mitsuba_choice

    for (system, profile, store, renderer), folders in runs.items():
        seen: list[dict[str, Any]] = []
        for folder in folders:
            summary = read_summary(folder)
            ran: dict[str, Any] = {"renderer": renderer, "warp_backend": summary["warp_backend"]}
            if system == GIGAN:
                # torch runs on CUDA where torch sees a device (gigan_local.torch_backend); onnxruntime on the CPU
                device = "cuda" if summary["inference"] == "torch" and cuda_for_torch() else "cpu"
                ran |= {"inference": summary["inference"], "inference_device": device}
            else:
                server = mitsuba_choice()
                ran |= {"server_variant": server.variant, "server_denoiser": server.denoiser}
            if ran in seen:
                continue
            seen.append(ran)
            where = {"profile": profile, "store": store} | common | ran
            res.add(system=system, scene=scene, metric="frames", value=summary["frames"], unit="count", **where)


def record_renderer(
    res: Results, scene: str, cfg: Recorded, runs: dict[tuple[str, str, str], list[Path]], common: dict[str, Any]
) -> None:
    """Rows of one renderer's runs: stage timings, ratios, the link model's check and crossover, quality along
    the path."""
    gigan_totals = _record_gigan(res, scene, cfg, runs[GIGAN, "none", "local"], common)
    cloud = _record_cloud_runs(res, scene, cfg, runs, common)
    for (profile, cache), repeats in cloud.items():
        config = {"profile": profile, "cache": cache, "codec": cfg.codec} | common
        _record_cloud_stages(res, scene, profile, repeats, gigan_totals, config)
    for cache in ("hit", "miss"):
        # each repeat's requests of every profile pooled: the link model takes the profile out
        repeats = [pool([s[i] for (_, c), s in cloud.items() if c == cache]) for i in range(len(gigan_totals))]
        if any(r.get("total") for r in repeats):
            config = {"cache": cache, "rate_mbit": cfg.sweep_rate_mbit, "codec": cfg.codec} | common
            _record_crossover(res, scene, cfg, repeats, gigan_totals, config)


def _record_gigan(
    res: Results, scene: str, cfg: Recorded, folders: list[Path], common: dict[str, Any]
) -> list[list[float]]:
    """GIGAN's stage timings and SSIM rows, its repeats pooled; each repeat's per-map totals (ms)."""
    frames = [read_csv_rows(folder / "frames.csv") for folder in folders]
    repeats = [stage_samples(rows) for rows in frames]
    for stage, values in pool(repeats).items():
        res.add_timing(
            system=GIGAN,
            scene=scene,
            metric=stage,
            samples_s=[v / 1e3 for v in values],
            profile="none",
            **common,
            model=cfg.model.name,
        )
    ssim = _mean_ssim([scored_ssim(rows) for rows in frames])
    _ssim_rows(res, scene, GIGAN, ssim, {"profile": "none", "store": "none"} | common)
    return [repeat["total"] for repeat in repeats]


def _record_cloud_runs(
    res: Results, scene: str, cfg: Recorded, runs: dict[tuple[str, str, str], list[Path]], common: dict[str, Any]
) -> dict[tuple[str, str], list[Samples]]:
    """Each cloud run's perceived latency, failed requests and SSIM rows (its repeats pooled); the plain client's
    stage samples per (profile, cache state) and repeat, its runs on both stores pooled."""
    cloud: dict[tuple[str, str], list[Samples]] = {}
    for (system, profile, store), folders in runs.items():
        if system not in (CLOUD, CLOUD_PREFETCH):
            continue
        repeats = [RunMetrics.read(folder) for folder in folders]
        where = {"profile": profile, "store": store} | common
        if store == "prebaked":
            _perceived_rows(res, scene, system, repeats, where)
        if system == CLOUD_PREFETCH:  # its requests ask ahead: its per-map stages are no Table 1 column
            continue
        for i, run in enumerate(repeats):
            for cache, samples in run.stages.items():  # both stores' runs pooled
                mine = cloud.setdefault((profile, cache), [{} for _ in folders])
                mine[i] = pool([mine[i], samples])
        failed = sum(run.failed_requests for run in repeats)  # every failure counts, whichever repeat it fell in
        res.add(system=CLOUD, scene=scene, metric="failed_requests", value=failed, unit="count", **where)
        ssim = _mean_ssim([run.ssim for run in repeats])
        _ssim_rows(res, scene, CLOUD, ssim, where | {"codec": cfg.codec})
    return cloud


def _record_cloud_stages(
    res: Results, scene: str, profile: str, repeats: list[Samples], gigan: list[list[float]], config: dict
) -> None:
    """Cloud baking's stage timings and bytes (its ``repeats`` pooled), the ratio of totals over GIGAN's per-map
    totals (``gigan``, per repeat) with its interval (:func:`_interval`), and the link model's total at
    ``profile``."""
    from network_sim import profiles as profile_table

    samples, gigan_maps = pool(repeats), [v for totals in gigan for v in totals]
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
    ratio = float(np.median(samples["total"])) / float(np.median(gigan_maps))
    add(system=f"{CLOUD}/{GIGAN}", metric="total_ratio", value=ratio, unit="1", **config)
    seed = _stream(res.seed, "total_ratio", config)
    per_run = [
        float(np.median(r["total"])) / float(np.median(g)) if r.get("total") and g else None
        for r, g in zip(repeats, gigan, strict=True)
    ]
    interval = _interval(per_run, lambda: ratio_interval(samples["total"], gigan_maps, seed), seed)
    add_interval(res, interval, system=f"{CLOUD}/{GIGAN}", scene=scene, metric="total_ratio", unit="1", **config)
    add(metric="total_model", value=CloudCost.of(samples).total_ms(link, starts=20), unit="ms", **config)


def _record_crossover(
    res: Results, scene: str, cfg: Recorded, repeats: list[Samples], gigan: list[list[float]], config: dict
) -> None:
    """The link model with one cache state's stages (its ``repeats`` pooled): the crossover RTT against the median
    of GIGAN's per-map totals (``gigan``, per repeat) with its interval (:func:`_interval`; per map,
    :func:`network_sim.exchange.crossover_interval`), and the ratio over an RTT sweep."""
    pooled, gigan_maps, rate = pool(repeats), [v for totals in gigan for v in totals], cfg.sweep_rate_mbit
    cost, gigan_total = CloudCost.of(pooled), float(np.median(gigan_maps))
    crossover = cost.crossover_rtt_ms(gigan_total, rate)
    add = partial(res.add, system=f"{CLOUD}/{GIGAN}", scene=scene, stat="model", **config)
    add(metric="crossover_rtt", value=crossover, unit="ms")
    seed = _stream(res.seed, "crossover_rtt", config)
    per_run = [
        CloudCost.of(r).crossover_rtt_ms(float(np.median(g)), rate) if r.get("total") and g else None
        for r, g in zip(repeats, gigan, strict=True)
    ]
    interval = _interval(per_run, lambda: crossover_interval(pooled, gigan_maps, rate, seed), seed)
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


def _stream(seed: int, metric: str, config: dict[str, Any]) -> list[int]:
    """The interval's seed stream (:func:`gicore.intervals.stream`): a column draws the same stream however many
    repeats pooled its maps."""
    return stream(seed, metric, {k: v for k, v in config.items() if k != "repeats"})


def _interval(per_run: list[float | None], per_map: Callable[[], Interval | None], seed: Seed) -> Interval | None:
    """The interval over the runs' own values where at least :data:`~gicore.intervals.MIN_SAMPLES` repeats each
    measured one (repeats vary more than one run's maps show: the load, the scheduler, the server's warm state);
    else ``per_map``'s bootstrap of the pooled maps."""
    if len(per_run) >= MIN_SAMPLES and all(v is not None for v in per_run):
        return interval_over_runs([v for v in per_run if v is not None], seed)
    return per_map()


def pool(groups: Sequence[Samples]) -> Samples:
    """Each name's samples of every group, in the groups' order."""
    pooled: Samples = {}
    for group in groups:
        for name, values in group.items():
            pooled.setdefault(name, []).extend(values)
    return pooled


def _perceived_rows(res: Results, scene: str, system: str, repeats: list[RunMetrics], config: dict) -> None:
    """A cloud run's perceived latency (median, p95 of its repeats' frames; never-served frames as endless),
    in-tolerance share and requests (each the mean over repeats: a run's), and mean SSIM (see the module
    docstring)."""
    add = partial(res.add, system=system, scene=scene, **config)
    frames = replace(repeats[0], perceived=pool([run.perceived for run in repeats]))
    for stat, value in frames.quantiles().items():
        add(metric="perceived", value=value, unit="ms", stat=stat)
    add(metric="in_tolerance", value=float(np.mean([run.in_tolerance for run in repeats])), unit="1")
    add(metric="requests", value=float(np.mean([run.requests for run in repeats])), unit="count")
    ssim = _mean_ssim([run.ssim for run in repeats])
    if system == CLOUD_PREFETCH and ssim:  # the plain client's SSIM rows come with its Table 1 rows
        add(metric="ssim", value=float(np.mean(list(ssim.values()))), unit="1", stat="mean")


def _mean_ssim(repeats: list[dict[int, float]]) -> dict[int, float]:
    """Each scored frame's SSIM, the mean over the repeats that scored it."""
    by_frame: dict[int, list[float]] = {}
    for scored in repeats:
        for frame, value in scored.items():
            by_frame.setdefault(frame, []).append(value)
    return {frame: float(np.mean(values)) for frame, values in by_frame.items()}


def _ssim_rows(res: Results, scene: str, system: str, scored: dict[int, float], config: dict[str, Any]) -> None:
    add = partial(res.add, system=system, scene=scene, metric="ssim", unit="1", **config)
    for frame, value in scored.items():
        add(value=value, stat="frame", frame=frame)
    if scored:
        add(value=float(np.mean(list(scored.values()))), stat="mean")
