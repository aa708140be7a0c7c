"""What ``bench report`` shows of ``network-sim selftest``'s CSV (:mod:`network_sim.selftest`): it is no
``bench`` subcommand, and the network simulator sits below ``bench`` (it cannot declare its README block
itself), so its block is declared here and registered in :mod:`bench.registry` beside the benches'."""

from __future__ import annotations

import json

from bench.runner import Block, External, Rows, Table
from network_sim.selftest import BENCH as NAME


def readme_block(rows: Rows) -> list[Table]:
    """The self-test's checks: each with a target, what was configured and measured, and whether it was met."""
    targets = [r for r in rows if r["stat"] == "target_met"]
    if not targets:
        raise ValueError("it has no target_met rows")
    value = {(r["scene"], r["metric"], r["stat"], json.dumps(r["config"], sort_keys=True)): r for r in rows}
    lines = [
        f"{sum(r['value'] == 1 for r in targets)} of {len(targets)} targets met.",
        "",
        "| check | metric | configured | measured | target | met |",
        "|---|---|---|---|---|---|",
    ]
    for t in targets:
        config = {k: v for k, v in t["config"].items() if k not in ("target", "measured_stat")}
        key = json.dumps(config, sort_keys=True)
        measured = value.get((t["scene"], t["metric"], t["config"]["measured_stat"], key))
        configured = value.get((t["scene"], t["metric"], "configured", key))
        cells = [f"{c['value']:.4g} {c['unit']}" if c else "—" for c in (configured, measured)]
        target = str(t["config"]["target"]).replace("|", "\\|")  # e.g. |err| <= 1 ms, inside a table cell
        stat = t["config"]["measured_stat"]
        met = "yes" if t["value"] else "MISSED"
        lines.append(f"| {t['scene']} | {t['metric']} ({stat}) | {cells[0]} | {cells[1]} | {target} | {met} |")
    return [Table("\n".join(lines))]


SELFTEST = External(
    NAME, readme=Block("Network simulator", 90, readme_block, make="network-sim selftest --out {out}/netself")
)
