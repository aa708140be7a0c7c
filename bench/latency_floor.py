"""`bench latency`'s stages alone beside the loop (measured by :mod:`baseline_cloudbaking.stages_alone`): the rows, each
system's floor (the sum of its stages alone), the floor's ratio and crossover, the targets of a fair baseline, and
the table that shows them (docs/architecture.md, Each stage alone).

Rows, each with the config of the loop's median row it stands beside: ``stat = "alone"`` (the median alone, ms;
for ``total``, the floor), ``stat = "inflation"`` (in the loop over alone); ``cloud_baking/gigan`` ``total_ratio``
and ``crossover_rtt`` with ``stat = "alone"`` (the floors' ratio; the link model's crossover with the stages
alone); ``stat = "target_met"`` rows for the targets (:func:`record_targets`).
"""

from __future__ import annotations

import sys
from functools import partial
from typing import Any

import numpy as np

from bench.latency_record import CLOUD, GIGAN
from bench.latency_tables import lookup
from gicore.intervals import LEVEL, MIN_SAMPLES, RESAMPLES, Interval, quantiles, resampled, stream, values_of
from gicore.present.declarations import Column, Rows, Table, flat, matches
from gicore.results import Results
from gigan_local.client import MAP_STAGES
from network_sim.exchange import CloudCost

#: A stage whose median in the loop exceeds this many times its median alone, and by more than NOISE_MS, is named
#: in a warning (below NOISE_MS a stage's ratio is the timer's and the scheduler's noise, not a cost).
INFLATION_WARN = 1.5
NOISE_MS = 0.5
#: The stages a cloud hit's total adds up (``transmission`` is request + transfer).
CLOUD_HIT_STAGES = ("request", "transfer", "lookup", "read", "server_other", "decode", "di", "warp", "blend")
#: Targets: a decode at most this many times the libraries' own on the same bytes; a stage in the loop at most
#: INFLATION_WARN times alone.
DECODE_BOUND = 1.3

Alone = dict[tuple[str, str, str], dict[str, list[float]]]


def _row(rows: Rows, system: str, metric: str, stat: str, **config: Any) -> dict[str, Any] | None:
    return next((r for r in rows if r["system"] == system and matches(r, metric, stat, **config)), None)


def record_alone(res: Results, scene: str, alone: Alone) -> list[str]:
    """The ``alone``, ``inflation`` and floor rows of every stage measured both ways (``alone``: samples per
    (system, profile, renderer), profile ``none`` for GIGAN); returns one warning per stage inflated beyond
    :data:`INFLATION_WARN`."""
    warnings = []
    for (system, profile, renderer), samples in alone.items():
        where = {"profile": profile, "renderer": renderer} | ({} if system == GIGAN else {"cache": "hit"})
        stages = MAP_STAGES if system == GIGAN else CLOUD_HIT_STAGES
        floor = 0.0
        for stage in (*stages, *(() if system == GIGAN else ("transmission",))):
            loop = _row(res.rows, system, stage, "median", **where)
            if loop is None or not samples.get(stage):
                continue
            value = float(np.median(samples[stage]))
            add = partial(res.add, system=system, scene=scene, metric=stage, **loop["config"])
            add(value=value, unit="ms", stat="alone")
            floor += value if stage in stages else 0.0
            if value > 0:
                add(value=loop["value"] / value, unit="1", stat="inflation")
                if loop["value"] > INFLATION_WARN * value and loop["value"] - value > NOISE_MS:
                    warnings.append(
                        f"warning: {system} {stage} ({renderer}, {profile}) takes {loop['value']:.1f} ms in the loop"
                        f" against {value:.1f} ms alone ({loop['value'] / value:.1f}x)"
                    )
        total = _row(res.rows, system, "total", "median", **where)
        if total is not None:
            res.add(system=system, scene=scene, metric="total", value=floor, unit="ms", stat="alone", **total["config"])
    return warnings


def record_floor_ratios(res: Results, scene: str, alone: Alone) -> None:
    """Per profile and renderer, the floors' ratio (cloud hit over GIGAN) beside the loop's; per renderer the link
    model's crossover RTT with the stages alone (the first profile's), beside the loop's."""
    ratio_system = f"{CLOUD}/{GIGAN}"
    for (system, profile, renderer), samples in alone.items():
        if system != CLOUD:
            continue
        gigan = _row(res.rows, GIGAN, "total", "alone", profile="none", renderer=renderer)
        cloud = _row(res.rows, CLOUD, "total", "alone", profile=profile, cache="hit", renderer=renderer)
        loop_ratio = _row(res.rows, ratio_system, "total_ratio", "median", profile=profile, cache="hit",
                          renderer=renderer)  # fmt: skip
        if gigan is None or cloud is None or loop_ratio is None:
            continue
        add = partial(res.add, system=ratio_system, scene=scene, unit="1", metric="total_ratio")
        add(value=cloud["value"] / gigan["value"], stat="alone", **loop_ratio["config"])
        interval = _floor_interval(res, alone, (profile, renderer), stream(res.seed, "floor_ratio", profile, renderer))
        for stat, value in (("alone_ci_low", interval.low), ("alone_ci_high", interval.high)) if interval else ():
            add(value=value, stat=stat, ci=interval.level, resamples=interval.resamples, **loop_ratio["config"])
        crossover = _row(res.rows, ratio_system, "crossover_rtt", "model", cache="hit", renderer=renderer)
        done = _row(res.rows, ratio_system, "crossover_rtt", "alone", cache="hit", renderer=renderer)
        if crossover is None or done is not None or not samples.get("server"):
            continue
        bytes_of = {m: _row(res.rows, CLOUD, m, "median", profile=profile, cache="hit", renderer=renderer)
                    for m in ("bytes_up", "bytes_down")}  # fmt: skip
        transmission = float(np.median(samples["request"])) + float(np.median(samples["transfer"]))
        cost = CloudCost(cloud["value"] - transmission, float(np.median(samples["server"])),
                         int(bytes_of["bytes_up"]["value"]), int(bytes_of["bytes_down"]["value"]))  # fmt: skip
        rate = crossover["config"].get("rate_mbit")
        value = cost.crossover_rtt_ms(gigan["value"], rate)
        res.add(system=ratio_system, scene=scene, metric="crossover_rtt", value=value, unit="ms", stat="alone",
                **crossover["config"] | {"from_profile": profile})  # fmt: skip


def _floor_interval(res: Results, alone: Alone, at: tuple[str, str], seed: list[int]) -> Interval | None:
    """The 95 % bootstrap interval of the floors' ratio at (profile, renderer): each stage's samples alone resampled
    apart, their medians summed per system (the stages each floor adds up; None where one has under 3 samples)."""
    rng = np.random.default_rng(seed)
    floors = []
    for system, profile in ((CLOUD, at[0]), (GIGAN, "none")):
        samples = alone[system, profile, at[1]]
        where = {"profile": profile, "renderer": at[1]}
        stages = [r["metric"] for r in res.rows if r["system"] == system and matches(r, None, "alone", **where)
                  and r["metric"] in (*MAP_STAGES, *CLOUD_HIT_STAGES)]  # fmt: skip
        if any(len(samples.get(stage, ())) < MIN_SAMPLES for stage in stages):
            return None
        floors.append(sum(resampled(values_of(samples[stage]), rng, RESAMPLES, np.median) for stage in stages))
    return quantiles(floors[0] / floors[1], LEVEL, RESAMPLES)


def record_targets(
    res: Results, scene: str, decode: dict[str, list[float]], client_cores: int, where: str
) -> list[dict[str, Any]]:
    """The fair baseline's targets as ``target_met`` rows (config: ``target``, ``measured``, ``bound``, ``applies``,
    ``machine``): each decode alone (to linear, and to display values) within :data:`DECODE_BOUND` of the
    libraries' decode of the same bytes; per
    renderer and profile, every cloud stage and the decode in the loop within :data:`INFLATION_WARN` of alone
    (where the client has 2 cores or more: with one, its frame loop and its requests share it), and the ``lan``
    request in the loop within it of the request alone. Returns the rows added."""
    added: list[dict[str, Any]] = []

    def target(key: str, text: str, measured: float, bound: float, applies: bool = True, **config: Any) -> None:
        res.add(system=CLOUD, scene=scene, metric=key, value=int(measured <= bound), unit="bool", stat="target_met",
                target=text, measured=measured, bound=bound, applies=applies, machine=where, **config)  # fmt: skip
        added.append(res.rows[-1])

    for kind, to in (("decode", "linear, for a warp on the host"), ("display", "display values, for a GL warp")):
        if decode.get(kind):  # runs from before the display decode have none
            ratio = float(np.median(decode[kind])) / float(np.median(decode["library"]))
            target(f"{kind}_floor", f"decode ({to}) alone <= 1.3 x Pillow's + zstandard's decode of the same bytes",
                   ratio, DECODE_BOUND, maps=len(decode[kind]))  # fmt: skip
    inflations = [r for r in res.rows if r["system"] == CLOUD and r["stat"] == "inflation"]
    for key in dict.fromkeys((r["config"]["renderer"], r["config"]["profile"]) for r in inflations):
        renderer, profile = key
        mine = {r["metric"]: r["value"] for r in inflations if (r["config"]["renderer"], r["config"]["profile"]) == key}
        config = {"renderer": renderer, "profile": profile}
        worst = max((s for s in mine if s in CLOUD_HIT_STAGES), key=mine.__getitem__)
        target("inflation", f"every cloud stage in the loop <= 1.5 x alone (worst: {worst})", mine[worst],
               INFLATION_WARN, client_cores >= 2, **config)  # fmt: skip
        if "decode" in mine:
            target("decode_inflation", "decode in the loop <= 1.5 x alone", mine["decode"], INFLATION_WARN, **config)
        if profile == "lan" and "request" in mine:
            target("request_inflation", "lan request in the loop <= 1.5 x alone", mine["request"], INFLATION_WARN,
                   **config)  # fmt: skip
    return added


def report(warnings: list[str], targets: list[dict[str, Any]]) -> None:
    """The inflation warnings, then each target met or MISSED, on stderr."""
    for line in warnings:
        print(line, file=sys.stderr)
    for r in targets:
        c = r["config"]
        verdict = "met" if r["value"] else "MISSED"
        verdict = verdict if c["applies"] else f"{verdict} (not applicable: the client has one core)"
        print(f"target {c['target']}: {c['measured']:.2f} (bound {c['bound']:g}) {verdict} on {c['machine']}",
              file=sys.stderr)  # fmt: skip


# -- what it shows --------------------------------------------------------------------------------------------
def stages_alone(raw: Rows) -> list[dict[str, Any]]:
    """Per system, cache state, profile and renderer: each stage in the loop, alone, and their ratio; the totals."""
    out = []
    stages = {*MAP_STAGES, *CLOUD_HIT_STAGES, "transmission", "total"}
    for r in (r for r in raw if r["stat"] == "alone" and r["metric"] in stages):
        c = r["config"]
        where = {k: c[k] for k in ("profile", "renderer", "cache") if k in c}
        loop = _row(raw, r["system"], r["metric"], "median", **where)
        inflation = _row(raw, r["system"], r["metric"], "inflation", **where)
        label = "GIGAN" if r["system"] == GIGAN else f"cloud {c.get('cache')}, `{c.get('profile')}`"
        shown = {"column": f"{label}, {c.get('renderer')}", "alone": r["value"], "loop": loop and loop["value"]}
        out.append(flat(r) | shown | {"inflation": inflation and inflation["value"]})
    return out


def floors(raw: Rows) -> list[dict[str, Any]]:
    """Per profile and renderer: each system's total in the loop and its floor, the ratios of both, and the
    crossover RTTs (loop and floor) of the hit."""
    ratio_system, out = f"{CLOUD}/{GIGAN}", []
    for r in (r for r in raw if r["system"] == ratio_system and matches(r, "total_ratio", "alone")):
        c = r["config"]
        at = {"renderer": c["renderer"]}
        cross = {s: _row(raw, ratio_system, "crossover_rtt", s, cache="hit", **at) for s in ("model", "alone")}
        shown = {s: x and x["value"] for s, x in cross.items()}
        out.append(flat(r) | {
            "gigan": lookup(raw, GIGAN, "total", "median", profile="none", **at),
            "gigan_floor": lookup(raw, GIGAN, "total", "alone", profile="none", **at),
            "cloud": lookup(raw, CLOUD, "total", "median", profile=c["profile"], cache="hit", **at),
            "cloud_floor": lookup(raw, CLOUD, "total", "alone", profile=c["profile"], cache="hit", **at),
            "ratio": lookup(raw, ratio_system, "total_ratio", "median", profile=c["profile"], cache="hit", **at),
            "ratio_floor": _with_interval(raw, r), "cross": shown["model"], "cross_floor": shown["alone"],
        })  # fmt: skip
    return out


def _with_interval(rows: Rows, floor_ratio: dict[str, Any]) -> str:
    """The floors' ratio, with its interval where the run recorded one (``0.55 [0.50, 0.61]``)."""
    c, value = floor_ratio["config"], floor_ratio["value"]
    at = {"profile": c["profile"], "cache": "hit", "renderer": c["renderer"]}
    low, high = (lookup(rows, floor_ratio["system"], "total_ratio", f"alone_ci_{b}", **at) for b in ("low", "high"))
    return f"{value:.2f}" if low is None or high is None else f"{value:.2f} [{low:.2f}, {high:.2f}]"


def targets_shown(raw: Rows) -> list[dict[str, Any]]:
    out = []
    for r in (r for r in raw if r["stat"] == "target_met"):
        met = "yes" if r["value"] else "MISSED"
        out.append(flat(r) | {"met": met if r["config"].get("applies", True) else f"{met} (n/a: one client core)"})
    return out


def _machine(raw: Rows) -> str:
    where = next((r["config"].get("machine") for r in raw if r["stat"] == "target_met"), None)
    return f"Measured on {where}." if where else ""


STAGES_ALONE = Table(
    stages_alone,
    (
        Column("column", "{column}"),
        Column("stage", "{metric}"),
        Column("in the loop (ms)", "{loop:.1f}"),
        Column("alone (ms)", "{alone:.1f}"),
        Column("inflation", "{inflation:.2f}"),
    ),
    title="Table 1's stages alone: each stage's median in the loop, alone (same cores, inputs and cameras, nothing "
    "else in the process), and their ratio; total alone: the floor, the sum of the stages alone",
    scroll=True,
)
TARGETS = Table(
    targets_shown,
    (
        Column("target", "{target}"),
        Column("renderer, profile", "[[{renderer}, {profile}]]"),
        Column("measured", "{measured:.2f}"),
        Column("met", "{met}"),
    ),
    title="a fair baseline's targets",
    notes=_machine,
)
FLOORS = Table(
    floors,
    (
        Column("profile, renderer", "`{profile}`, {renderer}"),
        Column("GIGAN: loop / floor", "{gigan:.1f} / {gigan_floor:.1f}"),
        Column("cloud hit: loop / floor", "{cloud:.1f} / {cloud_floor:.1f}"),
        Column(
            "cloud hit / GIGAN: loop / floor",
            "{ratio:.2f} / {ratio_floor}",
        ),
        Column("hit crossover RTT (ms): loop / floor", "{cross:.0f} / {cross_floor:.0f}"),
    ),
    title="each system in the loop and at its floor (the sum of its stages alone), ms",
    caption="The floor is what each system's stages cost with nothing else in the process: the answer to compare "
    "when the question is the systems, not this testbed's clients. Crossover: the RTT beyond which GIGAN's median "
    "total beats a cloud hit (the link model with the measured stages; at the floor, with the stages alone).",
)
PARTS = (STAGES_ALONE, FLOORS, TARGETS)
