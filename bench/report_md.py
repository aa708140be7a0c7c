"""The README's results section, in Markdown, from the same CSV files and provenance as the dashboard.

``bench report`` writes it as ``results.md`` beside ``report.html`` and, with ``--readme FILE``, puts it
between the lines ``<!-- results:begin -->`` and ``<!-- results:end -->`` of that file (everything between
them is replaced; everything outside them, such as what the numbers mean for choosing a system, is left
alone; a second run with the same results changes nothing). Each block reads one bench's newest CSV under
``--results`` (outside the ``--ignore`` folders) through :func:`bench.report.attempt` (the dashboard's
finder, loader and checks), shows its numbers as a short table, and ends with the command that wrote the
CSV, its git SHA, date and machine (from the provenance JSON beside it). A block whose CSV is missing or
malformed says so in one line.

Blocks: Table 1 (latency per profile and cache state, ratio, crossover), Table 2 (GI-tree storage against
the model, codecs), error against run time (the best configuration of each system per time budget),
Table 3 (inference frequency), Fig. 6 (GI-map quality), Fig. 7 (warp cost), Fig. 9 (GI-camera FOV), the
cloud-baking server (``bench service``), the network simulator's self-test (``network-sim selftest``),
numerical stability (cases, finite, cleanly rejected, failed) and scaling (``bench scaling``, projections
labelled).
"""

from __future__ import annotations

import json
import math
import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.report import (
    Attempt,
    Rows,
    _need,
    _pick,
    attempt,
    best_table,
    fov_table,
    pareto_points,
    provenance_fields,
    quality_table,
    warp_table,
)
from gicore.cli import UserError
from gicore.fileio import atomic_write_bytes

BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"


def _f(value: float | None, spec: str = ".1f") -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def _demote(text: str, top: int = 4) -> str:
    """A bench's Markdown with its headings moved down so that the highest is level ``top``."""
    levels = [len(m.group(1)) for m in re.finditer(r"^(#+) ", text, re.MULTILINE)]
    shift = max(0, top - min(levels)) if levels else 0
    return re.sub(r"^(#+) ", lambda m: "#" * (len(m.group(1)) + shift) + " ", text, flags=re.MULTILINE)


# -- one block per bench -----------------------------------------------------------------------------------------
def latency_md(rows: Rows, csv_path: Path) -> str:
    """Table 1: one line per network profile (totals, ratio, SSIM), GIGAN's stages, the crossover RTTs."""
    from bench.latency import CLOUD, GIGAN, _lookup

    _need(rows, "total", "total_ratio")
    ratios = _pick(rows, "total_ratio")
    rtt = {r["config"]["profile"]: r["config"].get("rtt_ms") for r in ratios}
    c = ratios[0]["config"]
    gigan = _lookup(rows, GIGAN, "total", "median", profile="none")
    lines = [
        f"{rows[0]['scene']}, {c.get('resolution')}², {c.get('frames')} frames, GI period k = {c.get('k')}, {c.get('spp')} spp + OIDN on the "
        f"server, {c.get('codec')} maps; medians in ms.",
        "",
        "| profile (RTT) | GIGAN | cloud hit | cloud miss | cloud / GIGAN: hit / miss | mean SSIM vs GT: GIGAN / prebaked / cold |",
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
            f"| `{profile}` ({_f(rtt_ms, 'g')} ms) | {_f(gigan)} | {_f(hit)} | {_f(miss)} | {' / '.join(_f(r, '.2f') for r in ratio)} | "
            + " / ".join(_f(s, ".3f") for s in ssim)
            + " |"
        )
    stages = [(label, _lookup(rows, GIGAN, metric, "median", profile="none"))
              for metric, label in (("gi_render", "GI-camera render"), ("inference", "inference"), ("warp", "warp"), ("blend", "blend"))]  # fmt: skip
    lines += [
        "",
        f"GIGAN's total {_f(gigan)} ms = "
        + " + ".join(f"{label} {v:.1f}" for label, v in stages if v is not None)
        + ".",
    ]
    crossings = []
    for r in _pick(rows, "crossover_rtt"):
        cache, value = r["config"].get("cache"), r["value"]
        crossings.append(f"a cloud {cache} at any RTT" if value == 0 else f"a cloud {cache} at no RTT up to a minute" if math.isinf(value)
                         else f"a cloud {cache} beyond an RTT of {value:.0f} ms")  # fmt: skip
    if crossings:
        lines.append(
            "Crossover (the link model with the measured stages): GIGAN's median total beats "
            + "; ".join(crossings)
            + "."
        )
    return "\n".join(lines)


def storage_md(rows: Rows, csv_path: Path) -> str:
    """Table 2: the GI tree of each scene's fly-through per codec and resolution against the model; the codecs."""
    from bench.storage import _index, _mib, codec_table

    _need(rows, "gi_tree_bytes", "client_bytes", "entries")
    model = {r["config"]["precision"]: r["value"] for r in _pick(rows, "client_bytes")}
    trees = _index(rows, "gi_tree_bytes", "estimate", "resolution", "codec", "composition")
    columns = list(dict.fromkeys((k[1], k[2]) for k in trees if k[3] == "blend"))
    lines = [
        "GIGAN's model (the same for every scene): "
        + ", ".join(f"{p} {_mib(v)} MiB" for p, v in model.items())
        + ". The GI tree of each "
        "scene's fly-through (GI + depth, blend composition): entries counted with the GI tree's lookup rule, MiB = entries × mean "
        "payload" + (", × = against the fp16 model" if model.get("fp16") else "") + ".",
        "",
        "| scene | frames | entries | " + " | ".join(f"{codec} {resolution}²" for resolution, codec in columns) + " |",
        "|---" * (3 + len(columns)) + "|",
    ]
    for r in _pick(rows, "entries"):
        cells = []
        for resolution, codec in columns:
            value = trees.get((r["scene"], resolution, codec, "blend"))
            ratio = f" (×{value / model['fp16']:.2g})" if value is not None and model.get("fp16") else ""
            cells.append("—" if value is None else _mib(value) + ratio)
        lines.append(f"| {r['scene']} | {r['config'].get('frames')} | {r['value']:.0f} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n\nCodecs, per GI map (means over the scenes):\n\n" + codec_table(rows).rstrip()


def pareto_md(rows: Rows, csv_path: Path) -> str:
    """Error against run time: how many points, and each system's best configuration per time budget."""
    from bench.pareto import ABLATION

    points = pareto_points(rows)
    count = Counter(p["system"] for p in points)
    head = (
        f"Error = 1 − SSIM against a path-traced GT; {len(points)} points: " + ", ".join(f"{n} {system}" for system, n in count.items())
        + (" (cross-system pairings: on no front and in no row below)" if count[ABLATION] else "") + "."
    )  # fmt: skip
    return head + "\n\n" + _demote(best_table(points))


def frequency_md(rows: Rows, csv_path: Path) -> str:
    """Table 3: frame rate and SSIM against the GI period k, per warp and composition."""
    from bench.frequency import table

    _need(rows, "fps", "ssim")
    c = rows[0]["config"]
    sources = ", ".join(str(s) for s in dict.fromkeys(r["config"].get("gi_source") for r in rows))
    head = (f"GI maps: {sources} (model: the generator's; gt: path-traced, a perfect-model stand-in); {c.get('resolution')}², "
            f"{c.get('frames')} frames; SSIM against path-traced GT at the local camera.")  # fmt: skip
    return head + "\n\n" + _demote(table(csv_path)).strip()


def quality_md(rows: Rows, csv_path: Path) -> str:
    return quality_table(rows)


def warp_md(rows: Rows, csv_path: Path) -> str:
    return warp_table(rows)


def fov_md(rows: Rows, csv_path: Path) -> str:
    return fov_table(rows)


def service_md(rows: Rows, csv_path: Path) -> str:
    """The cloud-baking server on loopback: stage times, load and its targets (``bench service``'s own table)."""
    from bench.service import table

    _need(rows, "hit_e2e", "miss_e2e")
    return "Times in ms (first: the first miss, with its JIT compile).\n\n" + table(rows).rstrip()


def netself_md(rows: Rows, csv_path: Path) -> str:
    """The network simulator's self-test: each check with a target, what was configured and measured."""
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
        lines.append(
            f"| {t['scene']} | {t['metric']} ({stat}) | {cells[0]} | {cells[1]} | {target} | {'yes' if t['value'] else 'MISSED'} |"
        )
    return "\n".join(lines)


def stability_md(rows: Rows, csv_path: Path) -> str:
    """SPEC §9's cases: the counts, per stage, and the failed cases by name."""
    from bench.stability import PASSED, counts, summary

    _need(rows, "status")
    entries = summary(rows)
    n = counts(entries)
    lines = [
        f"**{n['cases']} cases: {n['finite']} finite, {n['rejected']} cleanly rejected, {n['failed']} failed** (crashed, hung or went non-finite).",
        "",
        "| stage | cases | finite | cleanly rejected | failed |",
        "|---|---|---|---|---|",
    ]
    for stage in dict.fromkeys(e["stage"] for e in entries):
        c = counts([e for e in entries if e["stage"] == stage])
        lines.append(f"| {stage} | {c['cases']} | {c['finite']} | {c['rejected']} | {c['failed']} |")
    failed = [f"{e['stage']}/{e['case']} ({e['status']})" for e in entries if e["status"] not in PASSED]
    return "\n".join(lines) + ("\n\nFailed: " + "; ".join(failed) + "." if failed else "")


def scaling_md(rows: Rows, csv_path: Path) -> str:
    """Scaling: measured throughput per executor and worker count; then the projections, labelled as such."""
    from bench.scaling import ALL, _value

    _need(rows, "throughput")
    measured = _pick(rows, "throughput")
    c = measured[0]["config"]
    executors = list(dict.fromkeys(r["system"] for r in measured))
    workers = sorted({r["config"]["workers"] for r in measured})
    lines = [
        f"Measured on {measured[0]['scene']} at {c.get('resolution')}², {c.get('spp')} spp + OIDN, single-threaded workers.",
        "",
        "| executor | workers | frames/s | maps/s | efficiency (frames, against 1 worker) | no-op task round trip ms (median) |",
        "|---|---|---|---|---|---|",
    ]
    for ex in executors:
        for w in workers:
            frames, maps = (
                _value(rows, system=ex, metric="throughput", workers=w, kind=kind) for kind in ("frame", "map")
            )
            efficiency = 1.0 if w == 1 else _value(rows, system=ex, metric="efficiency", workers=w, kind="frame")
            trip = _value(rows, system=ex, metric="task_roundtrip", stat="median", workers=w)
            lines.append(
                f"| {ex} | {w} | {_f(frames, '.3g')} | {_f(maps, '.3g')} | {_f(efficiency, '.2f')} | {_f(trip, '.3g')} |"
            )
    projected = [r for r in rows if r["stat"] == "projection" and r["scene"] == ALL]
    if projected:
        what = {r["metric"]: r["config"] for r in projected}
        names = {"dataset_wall": "the paper's data set", "bake_wall": "GI-tree bakes of 5 scenes"}
        shown = [m for m in names if m in what]
        lines += [
            "",
            "PROJECTED, not measured: wall hours on N workers ("
            + "; ".join(f"{names[m]}: {what[m].get('items')} items at {what[m].get('resolution')}²" for m in shown)
            + f"; {projected[0]['config'].get('assumption')}).",
            "",
            "| N workers | " + " | ".join(f"{names[m]}, {ex} [h]" for ex in executors for m in shown) + " |",
            "|---" * (1 + len(executors) * len(shown)) + "|",
        ]
        for n in sorted({r["config"]["workers"] for r in projected}):
            cells = [
                _f(_value(rows, system=ex, scene=ALL, metric=m, workers=n), ".3g") for ex in executors for m in shown
            ]
            lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


@dataclass(frozen=True)
class Block:
    """A block of the results section: its title, the bench whose CSV it reads, how it writes the rows, and
    the command that makes the CSV when it is missing (``{out}``: the results folder)."""

    title: str
    bench: str
    write: Callable[[Rows, Path], str]
    make: str = ""

    def command(self, results: Path) -> str:
        return (self.make or f"bench {self.bench} --out {{out}}").format(out=results)


BLOCKS = (
    Block("Interaction latency, Table 1", "latency", latency_md),
    Block("GI-tree storage, Table 2", "storage", storage_md),
    Block("Error against run time", "pareto", pareto_md, "bench pareto --from-dir {out} --out {out}/pareto"),
    Block("Inference frequency, Table 3", "frequency", frequency_md),
    Block("GI-map quality, Fig. 6", "quality", quality_md),
    Block("Cost of warping, Fig. 7", "warp", warp_md),
    Block("GI-camera FOV, Fig. 9", "fov", fov_md),
    Block("Cloud-baking server", "service", service_md),
    Block("Network simulator", "network_selftest", netself_md, "network-sim selftest --out {out}/netself"),
    Block("Numerical stability", "stability", stability_md),
    Block("Scaling", "scaling", scaling_md),
)


def command_line(a: Attempt) -> str:
    """Where a block's numbers come from: the command, git SHA, date and machine of its CSV."""
    assert a.path is not None
    where = f"`{a.rel}`" + (f", the newest of {len(a.others) + 1} runs" if a.others else "")
    prov = provenance_fields(a.path)
    if prov is None:
        return f"Command: unknown (no {a.path.stem}.provenance.json beside {where})."
    return f"Command: `{prov['command']}` (git {prov['git']}, {prov['date']}, {prov['machine']}; {where})."


def _shown(results: Path) -> Path:
    """``results`` relative to the working folder when it lies inside it (so the text does not name this machine's paths)."""
    try:
        return results.resolve().relative_to(Path.cwd().resolve())
    except ValueError:
        return results


def results_markdown(results: Path, ignore: tuple[str, ...] = ()) -> str:
    """The results section: a heading per block, its numbers and the command that made them (or one line saying
    what is missing or malformed). Nothing in it depends on when it is built, so rebuilding it from the same
    results gives the same text."""
    results = _shown(results)
    options = f"--results {results}" + (f" --ignore {','.join(ignore)}" if ignore else "")
    parts = [
        f"<!-- Generated by `bench report {options} --readme FILE` from the CSV files under {results}; "
        "edits between the results markers are replaced on the next run. -->",
        f"Generated from the CSV files under `{results}` by `bench report`; each block ends with the command that wrote its CSV.",
    ]
    for block in BLOCKS:
        a = attempt(block.bench, results, block.write, ignore)
        parts.append(f"### {block.title}")
        if a.status == "missing":
            parts.append(f"Not in these results: {a.problem}; `{block.command(results)}` makes it.")
        elif a.status == "malformed":
            parts.append(f"Not shown: {a.problem}.")
        else:
            parts += [a.body.strip(), command_line(a)]
    return "\n\n".join(parts) + "\n"


# -- the README's markers ------------------------------------------------------------------------------------------
def marker_span(text: str, readme: Path) -> tuple[int, int]:
    """Where the generated section goes in ``text``: from the end of the begin marker to the start of the end
    marker; a :class:`UserError` unless there is exactly one of each, in that order."""
    begins, ends = text.count(BEGIN), text.count(END)
    start, stop = text.find(BEGIN), text.find(END)
    if begins != 1 or ends != 1 or stop < start:
        raise UserError(
            f"--readme {readme} has {begins} '{BEGIN}' and {ends} '{END}' lines, not one of each in that order",
            f"put the line {BEGIN} where the generated results begin and {END} where they end (the text between is replaced), then run again",
        )
    return start + len(BEGIN), stop


def read_readme(readme: Path) -> str:
    try:
        return readme.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(
            f"--readme {readme} cannot be read ({getattr(exc, 'strerror', None) or exc})",
            "give the Markdown file to update, e.g. --readme README.md",
        ) from None


def update_readme(readme: Path, section: str) -> bool:
    """Put ``section`` between the markers of ``readme``; True when the file changed (the same section twice: no change)."""
    text = read_readme(readme)
    start, stop = marker_span(text, readme)
    new = text[:start] + "\n\n" + section.strip("\n") + "\n\n" + text[stop:]
    if new == text:
        return False
    atomic_write_bytes(readme, new.encode("utf-8"))
    return True


def check_readme(readme: Any) -> None:
    """Refuse a ``--readme`` that cannot be read or has no markers, before the report is built."""
    if readme is not None:
        marker_span(read_readme(Path(readme)), Path(readme))
