"""`bench pareto`'s points read back from its CSV, each system's best configuration per time budget, and what the
bench shows: per unit of work, the front of each system and the combined one, and the best-configuration table."""

from __future__ import annotations

import json
import math
from collections import Counter
from typing import Any

from bench.pareto_knobs import ABLATION, CLOUD, GIGAN, PER_FRAME, PER_MAP
from gicore.present.declarations import Chart, Column, Figure, Rows, Table


def front_points(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The points of a pareto CSV: system, unit, time, error, both dominated flags, config, tooltip and label."""
    points: dict[str, dict[str, Any]] = {}
    for r in rows:
        key = json.dumps([r["system"], r["scene"], r["config"]], sort_keys=True)
        p = points.setdefault(
            key, {"system": r["system"], "scene": r["scene"], "config": r["config"], "per": r["config"].get("per", "?")}
        )
        if r["metric"] == "run_time":
            p["time"] = r["value"]
        elif r["metric"] == "error":
            p["error"] = r["value"]
        elif r["metric"] == "dominated":
            p["dominated" if r["stat"] == "system" else "dominated_combined"] = bool(r["value"])
    out = [p for p in points.values() if "time" in p and "error" in p]
    for p in out:
        p.setdefault("dominated", False)
        p.setdefault("dominated_combined", False)
        settings = ", ".join(f"{k}={v}" for k, v in p["config"].items() if k not in ("knob", "per", "source"))
        p["label"] = f"{p['config'].get('knob', '?')}: {settings}"
        state = "dominated" if p["dominated"] else "on the front"
        p["tip"] = (f"{p['system']} ({p['scene']}), {state}\nrun time {p['time']:.4g} ms per {p['per']}\n"
                    f"error (1-SSIM) {p['error']:.4g}\n"
                    + json.dumps(p["config"], indent=1, sort_keys=True, ensure_ascii=False))  # fmt: skip
    return out


def best_within(points: list[dict[str, Any]], budget_ms: float) -> dict[str, Any] | None:
    """The lowest-error point whose run time fits ``budget_ms`` (None if none does)."""
    fitting = [p for p in points if p["time"] <= budget_ms]
    return min(fitting, key=lambda p: (p["error"], p["time"])) if fitting else None


def caveat(p: dict[str, Any], points: list[dict[str, Any]]) -> str:
    """What point ``p``'s run time covers and what it assumes (a column of the best-configuration table).
    A cloud per-frame point assumes its maps arrive within k frames (``map_latency_budget_ms``; its run time
    is its frame time); this says whether the fastest cloud map hit and miss measured per GI map (in
    ``points``) arrive that fast."""
    c = p["config"]
    if p["per"] == PER_MAP:
        if p["system"] == GIGAN:
            return "client: DI + G-buffers + inference"
        if c.get("knob") == "store tolerance":
            return f"hit-rate-weighted delivery on {c.get('profile')}, stale map warped"
        if "cache" in c:
            return f"delivered on {c['profile']}: " + (
                "bake + encode + network + decode" if c["cache"] == "miss" else "store hit: network + decode"
            )
        return "server bake only: no encode, network or decode"
    if c.get("gi_source") == "model":
        return f"client frame + its map's cost / k (k={c['k']})"
    due = c["k"] * p["time"]
    verdicts = []
    for cache in ("hit", "miss"):
        maps = [q for q in points if q["system"] == CLOUD and q["per"] == PER_MAP and q["config"].get("cache") == cache]
        if maps:
            q = min(maps, key=lambda q: q["time"])
            verdicts.append(f"fastest map {cache} {q['time']:.3g} ms ({q['config']['codec']}, "
                            f"{q['config']['profile']}): " + ("met" if q["time"] <= due else "NOT met"))  # fmt: skip
    return f"client frame only; assumes a GI map within k={c['k']} frames = {due:.3g} ms; " + (
        "; ".join(verdicts) or "no map delivery measured"
    )


def budgets(times: list[float]) -> list[float]:
    """Three round time budgets (one significant digit) at a quarter, half and all of the measured run
    times' log range; the last holds every point."""
    lo, hi = min(times), max(times)
    picks = [10 ** (math.log10(lo) + f * (math.log10(hi) - math.log10(lo))) for f in (0.25, 0.5)] if hi > lo else []
    top = 10 ** math.floor(math.log10(hi))
    return list(dict.fromkeys([float(f"{b:.1g}") for b in picks] + [float(math.ceil(hi / top) * top)]))


# -- what it shows --------------------------------------------------------------------------------------------
def pareto_points(rows: Rows) -> list[dict[str, Any]]:
    """The points of a pareto CSV (:func:`front_points`); a ValueError when it has none."""
    points = front_points(rows)
    if not points:
        raise ValueError("it has no points with both run_time and error rows")
    return points


def best_rows(points: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The lowest-error point of each system (cross-system ablations left out) within each time budget, per unit
    of work, with what its run time covers and assumes."""
    out = []
    systems = [p for p in points if p["system"] != ABLATION]
    for unit in dict.fromkeys(p["per"] for p in systems):
        here = [p for p in systems if p["per"] == unit]
        for budget in budgets([p["time"] for p in here]):
            for system in dict.fromkeys(p["system"] for p in here):
                p = best_within([q for q in here if q["system"] == system], budget)
                if p is not None:
                    out.append(p | {"unit": unit, "budget": budget, "caveat": caveat(p, points)})
    return out


def _count(rows: Rows) -> str:
    points = pareto_points(rows)
    count = Counter(p["system"] for p in points)
    return (
        f"Error = 1 − SSIM against a path-traced GT; {len(points)} points: "
        + ", ".join(f"{n} {system}" for system, n in count.items())
        + (" (cross-system pairings: on no front and in no row below)" if count[ABLATION] else "")
        + "."
    )


def _front(unit: str, scope: str) -> Chart:
    """The points of ``scope`` (a system, or ``combined``: every point, ablations hollow) per ``unit``; the points
    off that scope's front hollow; a point's tooltip is its full config."""
    flag = "dominated_combined" if scope == "combined" else "dominated"

    def points(rows: Rows) -> list[dict[str, Any]]:
        mine = [p for p in pareto_points(rows) if p["per"] == unit and scope in (p["system"], "combined")]
        return [p | {"off": p[flag] or p["system"] == ABLATION} for p in mine]

    return Chart(points, "time", "error", "{system}", xlog=True, ylog=True, hollow="off", tip="{tip}",
                 xlabel=f"median run time per {unit} [ms]", ylabel="error: 1 - SSIM vs path-traced GT",
                 title=f"{scope}: error against run time per {unit}")  # fmt: skip


PARTS = (
    *(
        Figure(f"pareto_{unit.replace(' ', '_').lower()}", tuple(_front(unit, s) for s in (GIGAN, CLOUD, "combined")))
        for unit in (PER_MAP, PER_FRAME)
    ),
    Table(
        lambda rows: best_rows(pareto_points(rows)),
        (
            Column("unit", "{unit}"),
            Column("time budget (ms)", "{budget:g}"),
            Column("system", "{system}"),
            Column("error", "{error:.4g}"),
            Column("run time (ms)", "{time:.3g}"),
            Column("config", "{label}"),
            Column("run time covers", "{caveat}"),
        ),
        title="Best configuration per time budget",
        caption=_count,
        notes="Per frame, cloud baking's time is the client's work alone: its maps are made on the server and arrive "
        "after the per-GI-map latency above, so its point at period k holds only if that latency stays under k frames.",
    ),
)
