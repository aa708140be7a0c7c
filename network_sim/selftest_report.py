"""What a report shows of ``network-sim selftest``'s CSV (:mod:`network_sim.selftest`), declared as data
(:mod:`gicore.present`): each check against its target, and the self-test's own figure. ``bench report``
shows it beside the benches' (:mod:`bench.registry`)."""

from __future__ import annotations

import json

from gicore.present.declarations import Column, Image, Part, Rows, Table
from network_sim.selftest import BENCH as NAME


def checks(rows: Rows) -> list[dict]:
    """Each check with a target: what was configured and measured, the target and whether it was met."""
    value = {(r["scene"], r["metric"], r["stat"], json.dumps(r["config"], sort_keys=True)): r for r in rows}
    out = []
    for t in (r for r in rows if r["stat"] == "target_met"):
        key = json.dumps({k: v for k, v in t["config"].items() if k not in ("target", "measured_stat")}, sort_keys=True)
        stat = t["config"]["measured_stat"]
        measured, configured = (value.get((t["scene"], t["metric"], s, key)) for s in (stat, "configured"))
        row = {"check": t["scene"], "metric": f"{t['metric']} ({stat})", "target": t["config"]["target"]}
        out.append(row | {"configured": configured, "measured": measured, "met": "yes" if t["value"] else "MISSED"})
    return out


def _met(rows: Rows) -> str:
    targets = [r for r in rows if r["stat"] == "target_met"]
    return f"{sum(r['value'] == 1 for r in targets)} of {len(targets)} targets met."


PARTS: tuple[Part, ...] = (
    Table(
        checks,
        (
            Column("check", "{check}"),
            Column("metric", "{metric}"),
            Column("configured", "{configured[value]:.4g} {configured[unit]}"),
            Column("measured", "{measured[value]:.4g} {measured[unit]}"),
            Column("target", "{target}"),
            Column("met", "{met}"),
        ),
        caption=_met,
    ),
    Image(f"{NAME}.png"),  # the self-test's own figure, beside its CSV
)
