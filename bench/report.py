"""`bench report`: a static HTML dashboard built only from the CSV files (and provenance JSON) under a
results folder (SPEC §8).

Each section reads one bench's ``<bench>.csv`` (found anywhere under ``--results`` outside the ``--ignore``
folders; the newest run's when there are several) and the ``<bench>.provenance.json`` beside it, and shows
the paper's table or figure drawn from those rows alone: Table 1 (``latency``), Table 2 (``storage``),
Table 3 (``frequency``), Fig. 6 (``quality``), Fig. 7 (``warp``), Fig. 9 (``fov``), the Pareto fronts of
error against run time (``pareto``; hovering a point shows its full config) and the stability table
(``stability``). Tables are the benches' own Markdown tables (the functions their ``plot`` writes
``*_table.md`` with) or, for Fig. 6, 7 and 9, this module's (``quality_table``, ``warp_table``,
``fov_table``), rendered to HTML; charts are inline SVG. Each section names its provenance: command, git SHA, machine, date.

A section whose CSV is missing, or malformed (wrong columns, unparsable values, or rows its bench never
writes), says so and names the file; the others still render. The page is one self-contained file
(``report.html``: style sheet and script from ``bench/report_assets`` inlined, no network access), so it
opens offline. The run's own CSV (``report.csv``) has one row per section: the rows read, and the
section's status (``ok`` / ``missing`` / ``malformed``) as ``stat``.

From the same CSVs it also writes ``results.md``, the README's results section (``bench/report_md.py``),
and with ``--readme FILE`` puts that between the file's ``<!-- results:begin -->`` and
``<!-- results:end -->`` lines.
"""

from __future__ import annotations

import csv
import fnmatch
import html
import json
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.runner import Bench
from gicore.cli import UserError
from gicore.fileio import atomic_write_bytes
from gicore.results import COLUMNS, Results, read_rows

ASSETS = Path(__file__).parent / "report_assets"
PALETTE = ("#3366cc", "#dc3912", "#109618", "#ff9900", "#990099", "#0099c6", "#dd4477", "#66aa00", "#b82e2e", "#316395")


@dataclass(frozen=True)
class ReportConfig:
    """Where the bench outputs are."""

    #: Folder of bench outputs (searched recursively for <bench>.csv and <bench>.provenance.json).
    results: Path = Path("results")
    #: Folders under --results to leave out (relative to it; glob patterns allowed), e.g. a side run such as
    #: latency_nopin, or the frequency runs bench pareto makes in pareto/pareto_runs.
    ignore: tuple[str, ...] = field(default=(), metadata={"min_len": 0})
    #: Markdown file (e.g. README.md) whose text between the lines <!-- results:begin --> and <!-- results:end -->
    #: becomes results.md; none: no file is changed.
    readme: Path | None = None

    @classmethod
    def quick(cls) -> ReportConfig:
        return cls()

    def check(self) -> None:
        from bench.report_md import check_readme

        if not self.results.is_dir():
            raise UserError(
                f"--results {self.results} is not a folder", "give the folder your bench runs wrote into (their --out)"
            )
        check_readme(self.readme)


# -- SVG charts -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Point:
    """One mark: position, its tooltip text, and whether it is drawn hollow (e.g. a dominated point)."""

    x: float
    y: float
    tip: str
    hollow: bool = False


@dataclass(frozen=True)
class Series:
    name: str
    points: list[Point]
    #: Join the points (sorted by x) with a line.
    line: bool = True
    colour: str = ""


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def _ticks(lo: float, hi: float, log: bool) -> list[float]:
    """Round tick values covering [lo, hi]."""
    if log:
        a, b = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
        for steps in ((1,), (1, 2, 5)):  # decades, else 1-2-5 within them
            ticks = [t for t in (m * 10.0**k for k in range(a, b + 1) for m in steps) if lo * 0.999 <= t <= hi * 1.001]
            if len(ticks) >= 3:
                return ticks
        return [
            t for t in _ticks(lo, hi, False) if t > 0
        ]  # within one decade: round linear values, placed on the log scale
    raw = (hi - lo) / 5
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step) * step
    return [first + i * step for i in range(int((hi - first) / step + 1e-9) + 1)]


def _domain(values: list[float], log: bool, zero: bool = False) -> tuple[float, float]:
    lo, hi = min(values), max(values)
    if zero and not log:
        lo = min(lo, 0.0)
    if log:
        lo, hi = lo / 1.3, hi * 1.3
    else:
        pad = (hi - lo) * 0.06 or abs(hi) * 0.1 or 1.0
        lo, hi = (lo if zero and lo == 0 else lo - pad), hi + pad
    return lo, hi


def _legend(entries: Iterable[tuple[str, str, bool]]) -> str:
    """Swatches (name, colour, hollow): a hollow swatch stands for hollow marks."""

    def swatch(colour: str, hollow: bool) -> str:
        return (
            f'<i style="border:2px solid {colour};background:#fff"></i>'
            if hollow
            else f'<i style="background:{colour}"></i>'
        )

    return (
        '<div class="legend">'
        + "".join(f"<span>{swatch(c, hollow)}{_e(n)}</span>" for n, c, hollow in entries)
        + "</div>"
    )


def xy_chart(
    series: list[Series], xlabel: str, ylabel: str, *, xlog: bool = False, ylog: bool = False, caption: str = ""
) -> str:
    """An inline SVG scatter/line chart; every point is a hoverable ``.pt`` mark with its tooltip."""
    series = [Series(s.name, s.points, s.line, s.colour or PALETTE[i % len(PALETTE)]) for i, s in enumerate(series)]
    ok = [
        p
        for s in series
        for p in s.points
        if math.isfinite(p.x) and math.isfinite(p.y) and (p.x > 0 or not xlog) and (p.y > 0 or not ylog)
    ]
    if not ok:
        return '<p class="problem">no finite values to plot</p>'
    w, h, left, right, top, bottom = 560, 330, 62, 14, 12, 44
    (x0, x1), (y0, y1) = _domain([p.x for p in ok], xlog), _domain([p.y for p in ok], ylog)

    def sx(v: float) -> float:
        f = (math.log10(v) - math.log10(x0)) / (math.log10(x1) - math.log10(x0)) if xlog else (v - x0) / (x1 - x0)
        return left + f * (w - left - right)

    def sy(v: float) -> float:
        f = (math.log10(v) - math.log10(y0)) / (math.log10(y1) - math.log10(y0)) if ylog else (v - y0) / (y1 - y0)
        return h - bottom - f * (h - top - bottom)

    parts = [
        f'<svg class="chart" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img" aria-label="{_e(ylabel)} against {_e(xlabel)}">'
    ]
    for t in _ticks(x0, x1, xlog):
        parts.append(f'<line class="grid" x1="{sx(t):.1f}" x2="{sx(t):.1f}" y1="{top}" y2="{h - bottom}"/>')
        parts.append(f'<text x="{sx(t):.1f}" y="{h - bottom + 14}" text-anchor="middle">{_fmt(t)}</text>')
    for t in _ticks(y0, y1, ylog):
        parts.append(f'<line class="grid" x1="{left}" x2="{w - right}" y1="{sy(t):.1f}" y2="{sy(t):.1f}"/>')
        parts.append(f'<text x="{left - 5}" y="{sy(t) + 4:.1f}" text-anchor="end">{_fmt(t)}</text>')
    parts.append(f'<line class="axis" x1="{left}" x2="{w - right}" y1="{h - bottom}" y2="{h - bottom}"/>')
    parts.append(f'<line class="axis" x1="{left}" x2="{left}" y1="{top}" y2="{h - bottom}"/>')
    parts.append(
        f'<text x="{(left + w - right) / 2}" y="{h - 8}" text-anchor="middle">{_e(xlabel)}{" (log)" if xlog else ""}</text>'
    )
    parts.append(
        f'<text transform="translate(13 {(top + h - bottom) / 2}) rotate(-90)" text-anchor="middle">{_e(ylabel)}{" (log)" if ylog else ""}</text>'
    )
    inside = {id(p) for p in ok}
    for s in series:
        pts = sorted((p for p in s.points if id(p) in inside), key=lambda p: p.x)
        if s.line and len(pts) > 1:
            path = " ".join(f"{sx(p.x):.1f},{sy(p.y):.1f}" for p in pts)
            parts.append(f'<polyline points="{path}" fill="none" stroke="{s.colour}" stroke-width="1.6"/>')
        for p in pts:
            fill = "#fff" if p.hollow else s.colour
            parts.append(
                f'<circle class="pt" cx="{sx(p.x):.1f}" cy="{sy(p.y):.1f}" r="4.5" fill="{fill}" stroke="{s.colour}" '
                f'stroke-width="1.5" data-tip="{_e(p.tip)}"/>'
            )
    parts.append("</svg>")
    legend = _legend((s.name, s.colour, bool(s.points) and all(p.hollow for p in s.points)) for s in series)
    return (
        f"<figure>{''.join(parts)}{legend}"
        + (f"<figcaption>{_e(caption)}</figcaption>" if caption else "")
        + "</figure>"
    )


def bar_chart(
    groups: list[str],
    series: dict[str, list[float | None]],
    ylabel: str,
    *,
    tips: dict[str, list[str]] | None = None,
    caption: str = "",
) -> str:
    """Grouped bars (one group per entry of ``groups``, one bar per series); each bar is a hoverable mark."""
    values = [v for vs in series.values() for v in vs if v is not None and math.isfinite(v)]
    if not values:
        return '<p class="problem">no finite values to plot</p>'
    w, h, left, right, top, bottom = 560, 280, 62, 10, 12, 30
    y0, y1 = _domain(values, False, zero=True)
    y0 = min(y0, 0.0)

    def sy(v: float) -> float:
        return h - bottom - (v - y0) / (y1 - y0) * (h - top - bottom)

    parts = [f'<svg class="chart" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img" aria-label="{_e(ylabel)}">']
    for t in _ticks(y0, y1, False):
        parts.append(f'<line class="grid" x1="{left}" x2="{w - right}" y1="{sy(t):.1f}" y2="{sy(t):.1f}"/>')
        parts.append(f'<text x="{left - 5}" y="{sy(t) + 4:.1f}" text-anchor="end">{_fmt(t)}</text>')
    band = (w - left - right) / max(len(groups), 1)
    bar = band * 0.8 / max(len(series), 1)
    colours = {name: PALETTE[i % len(PALETTE)] for i, name in enumerate(series)}
    for g, group in enumerate(groups):
        gx = left + g * band + band * 0.1
        parts.append(
            f'<text x="{left + (g + 0.5) * band:.1f}" y="{h - bottom + 14}" text-anchor="middle">{_e(group)}</text>'
        )
        for i, (name, vs) in enumerate(series.items()):
            v = vs[g]
            if v is None or not math.isfinite(v):
                continue
            top_y, base_y = sy(max(v, 0.0)), sy(min(v, 0.0))
            tip = tips[name][g] if tips else f"{name}, {group}: {_fmt(v)} {ylabel}"
            parts.append(
                f'<rect class="pt" x="{gx + i * bar:.1f}" y="{top_y:.1f}" width="{bar * 0.92:.1f}" height="{max(base_y - top_y, 0.5):.1f}" '
                f'fill="{colours[name]}" data-tip="{_e(tip)}"/>'
            )
    parts.append(f'<line class="axis" x1="{left}" x2="{w - right}" y1="{sy(0.0):.1f}" y2="{sy(0.0):.1f}"/>')
    parts.append(
        f'<text transform="translate(13 {(top + h - bottom) / 2}) rotate(-90)" text-anchor="middle">{_e(ylabel)}</text>'
    )
    parts.append("</svg>")
    return (
        f"<figure>{''.join(parts)}{_legend((n, c, False) for n, c in colours.items())}"
        + (f"<figcaption>{_e(caption)}</figcaption>" if caption else "")
        + "</figure>"
    )


def charts(*figures: str) -> str:
    return '<div class="charts">' + "".join(figures) + "</div>"


def markdown(text: str) -> str:
    """A bench's Markdown table as HTML (headings demoted below the section's own)."""
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark", {"html": False}).enable("table").render(text)
    for level in (3, 2, 1):
        body = body.replace(f"<h{level}>", f"<h{level + 2}>").replace(f"</h{level}>", f"</h{level + 2}>")
    return f'<div class="md">{body}</div>'


# -- sections -------------------------------------------------------------------------------------------------
Rows = list[dict[str, Any]]


def _pick(rows: Rows, metric: str, stat: str | None = None) -> Rows:
    return [r for r in rows if r["metric"] == metric and (stat is None or r["stat"] == stat)]


def _need(rows: Rows, *metrics: str) -> None:
    """Refuse rows that hold none of the metrics a section draws (another bench's CSV, or a stub)."""
    missing = [m for m in metrics if not _pick(rows, m)]
    if missing:
        raise ValueError(f"it has no {', '.join(missing)} rows")


def latency_section(rows: Rows, csv_path: Path) -> str:
    from bench.latency import table

    _need(rows, "total")
    lines = []
    for cache in ("hit", "miss"):
        model = [Point(r["config"]["rtt_ms"], r["value"], f"{cache}, link model: RTT {r['config']['rtt_ms']:g} ms → ratio {r['value']:.3g}")
                 for r in _pick(rows, "ratio_model") if r["config"].get("cache") == cache]  # fmt: skip
        measured = [Point(r["config"]["rtt_ms"], r["value"], f"{cache}, profile {r['config']['profile']}: ratio {r['value']:.3g}")
                    for r in _pick(rows, "total_ratio") if r["config"].get("cache") == cache]  # fmt: skip
        if model:
            lines.append(Series(f"{cache}: link model", model))
        if measured:
            lines.append(Series(f"{cache}: measured profiles", measured, line=False))
    figure = xy_chart(
        lines,
        "round-trip time [ms]",
        "cloud total / GIGAN total",
        ylog=True,
        caption="Above 1: GIGAN's interaction latency is lower.",
    )
    return markdown(table(rows)) + (charts(figure) if lines else "")


def storage_section(rows: Rows, csv_path: Path) -> str:
    from bench.storage import codec_table, table2

    _need(rows, "gi_tree_bytes", "client_bytes")
    trees = [r for r in _pick(rows, "gi_tree_bytes", "estimate") if r["config"].get("composition") == "blend"]
    resolution = trees[0]["config"]["resolution"]
    scenes = list(dict.fromkeys(r["scene"] for r in trees))
    codecs = list(dict.fromkeys(r["config"]["codec"] for r in trees))
    mib = {
        (r["scene"], r["config"]["codec"]): r["value"] / 2**20 for r in trees if r["config"]["resolution"] == resolution
    }
    series: dict[str, list[float | None]] = {c: [mib.get((s, c)) for s in scenes] for c in codecs}
    model = {r["config"]["precision"]: r["value"] / 2**20 for r in _pick(rows, "client_bytes")}
    if "fp16" in model:
        series["GIGAN model fp16"] = [model["fp16"]] * len(scenes)
    figure = bar_chart(
        scenes,
        series,
        "MiB",
        caption=f"GI tree after the fly-through ({resolution}², GI + depth) per codec, against the model.",
    )
    return (
        markdown(table2(rows))
        + charts(figure)
        + markdown("### Codecs (sampled GI maps, per map)\n\n" + codec_table(rows))
    )


def frequency_section(rows: Rows, csv_path: Path) -> str:
    from bench.frequency import table

    _need(rows, "fps", "ssim")
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    figures = []
    for metric, label, log in (("fps", "frames per second", True), ("ssim", "mean SSIM vs GT", False)):
        lines = []
        for key in dict.fromkeys((r["scene"], r["system"], r["config"]["composition"]) for r in _pick(rows, metric)):
            name = f"{key[1]} ({key[2]})" if len(scenes) == 1 else f"{key[0]}: {key[1]} ({key[2]})"
            pts = [Point(r["config"]["k"], r["value"], f"{name}, k = {r['config']['k']}: {metric} {r['value']:.4g}")
                   for r in _pick(rows, metric) if (r["scene"], r["system"], r["config"]["composition"]) == key]  # fmt: skip
            lines.append(Series(name, pts))
        figures.append(xy_chart(lines, "GI-map period k [frames]", label, ylog=log))
    return markdown(table(csv_path)) + charts(*figures)


def quality_section(rows: Rows, csv_path: Path) -> str:
    _need(rows, "ssim", "rmse", "psnr")
    scenes = list(dict.fromkeys(r["scene"] for r in _pick(rows, "ssim")))
    systems = list(dict.fromkeys(r["system"] for r in _pick(rows, "ssim")))
    figures = []
    # lf_error: the low-frequency error (gicore.metrics.lf_error); quality CSVs older than it have none ("—").
    shown_metrics = (
        ("rmse", "RMSE (tone-mapped)"),
        ("ssim", "SSIM"),
        ("psnr", "PSNR [dB]"),
        ("lf_error", "LF error (tone-mapped)"),
    )
    for metric, label in shown_metrics:
        value = {(r["scene"], r["system"]): r["value"] for r in _pick(rows, metric, "mean")}
        if value:
            figures.append(bar_chart(scenes, {s: [value.get((sc, s)) for sc in scenes] for s in systems}, label))
    return charts(*figures) + markdown(quality_table(rows))


def quality_table(rows: Rows) -> str:
    """Fig. 6 as Markdown: per system and scene, the mean RMSE, SSIM, PSNR, LF and checkerboard errors,
    the shadow tint and the median inference time."""
    _need(rows, "ssim", "rmse", "psnr")
    scenes = list(dict.fromkeys(r["scene"] for r in _pick(rows, "ssim")))
    systems = list(dict.fromkeys(r["system"] for r in _pick(rows, "ssim")))
    lines = [
        "| system | scene | RMSE | SSIM | PSNR (dB) | LF error | checker error | shadow tint | inference ms (median) | config |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    mean = {(r["scene"], r["system"], r["metric"]): r for r in rows if r["stat"] in ("mean", "median")}
    for system in systems:
        for scene in scenes:
            cells = [
                mean.get((scene, system, m))
                for m in ("rmse", "ssim", "psnr", "lf_error", "checker_error", "shadow_tint", "inference_time")
            ]
            shown = ["—" if c is None else f"{c['value']:.4g}" for c in cells]
            config = next((c["config"] for c in cells if c is not None and c["config"]), {})
            knobs = ", ".join(f"{k}={v}" for k, v in config.items() if k not in ("frames",))
            lines.append(f"| {system} | {scene} | " + " | ".join(shown) + f" | {knobs.replace('|', '/')} |")
    return "\n".join(lines)


def warp_section(rows: Rows, csv_path: Path) -> str:
    _need(rows, "warp_time")
    scenes = list(dict.fromkeys(r["scene"] for r in _pick(rows, "warp_time")))
    systems = list(dict.fromkeys(r["system"] for r in _pick(rows, "warp_time")))
    figures = []
    for metric, stat, label in (
        ("warp_time", "median", "warp time per frame [ms]"),
        ("cpu_percent", "mean", "CPU [% of one core]"),
        ("ssim", "mean", "SSIM vs GT"),
    ):
        value = {(r["scene"], r["system"]): r["value"] for r in _pick(rows, metric, stat)}
        p95 = {(r["scene"], r["system"]): r["value"] for r in _pick(rows, metric, "p95")}
        tips = {s: [f"{s}, {sc}: {stat} {_fmt(value.get((sc, s), math.nan))}" + (f", p95 {_fmt(p95[sc, s])}" if (sc, s) in p95 else "")
                    for sc in scenes]
                for s in systems}  # fmt: skip
        figures.append(bar_chart(scenes, {s: [value.get((sc, s)) for sc in scenes] for s in systems}, label, tips=tips))
    return charts(*figures) + markdown(warp_table(rows))


def warp_table(rows: Rows) -> str:
    """Fig. 7 as Markdown: per scene and warp, time per frame, CPU and SSIM; then the pixel / structure ratios."""
    _need(rows, "warp_time")
    scenes = list(dict.fromkeys(r["scene"] for r in _pick(rows, "warp_time")))
    systems = list(dict.fromkeys(r["system"] for r in _pick(rows, "warp_time")))
    value = {(r["scene"], r["system"], r["metric"], r["stat"]): r["value"] for r in rows}
    lines = [
        "| scene | warp | time per frame ms (median, p95) | CPU % of one core (mean) | SSIM vs GT (mean) |",
        "|---|---|---|---|---|",
    ]
    for scene in scenes:
        for s in systems:
            cells = [value.get((scene, s, "warp_time", stat), math.nan) for stat in ("median", "p95")]
            cells += [value.get((scene, s, metric, "mean"), math.nan) for metric in ("cpu_percent", "ssim")]
            lines.append(f"| {scene} | {s} | {cells[0]:.2f} ({cells[1]:.2f}) | {cells[2]:.0f} | {cells[3]:.3f} |")
    lines += ["", "| scene | pixel / structure time (median) | pixel / structure CPU (mean) |", "|---|---|---|"]
    for scene in scenes:
        ratio = {
            r["metric"]: r["value"] for r in rows if r["scene"] == scene and r["metric"] in ("time_ratio", "cpu_ratio")
        }
        lines.append(
            f"| {scene} | {ratio.get('time_ratio', math.nan):.2f}× | {ratio.get('cpu_ratio', math.nan):.2f}× |"
        )
    return "\n".join(lines)


def fov_section(rows: Rows, csv_path: Path) -> str:
    _need(rows, "ssim_gi_map", "ssim_warped")
    maps = [
        Series(
            scene,
            [
                Point(
                    r["config"]["gi_fov"],
                    r["value"],
                    f"{scene}, F_GI {r['config']['gi_fov']:g}°: SSIM {r['value']:.4f}",
                )
                for r in _pick(rows, "ssim_gi_map")
                if r["scene"] == scene
            ],
        )  # fmt: skip
        for scene in dict.fromkeys(r["scene"] for r in _pick(rows, "ssim_gi_map"))
    ]
    figures = [
        xy_chart(
            maps,
            "GI-camera FOV F_GI [°]",
            "SSIM of the GI map vs GT",
            caption=f"Source: {_pick(rows, 'ssim_gi_map')[0]['system']}.",
        )
    ]
    for motion in dict.fromkeys(r["config"]["motion"] for r in _pick(rows, "ssim_warped")):
        sel = [r for r in _pick(rows, "ssim_warped") if r["config"]["motion"] == motion]
        lines = []
        for system, gi_fov in dict.fromkeys((r["system"], r["config"]["gi_fov"]) for r in sel):
            name = f"{system}, F_GI {gi_fov:g}°"
            tip = "{name}, {motion} {amount:g} {unit}: SSIM {value:.4f}"
            pts = [
                Point(
                    c["amount"],
                    r["value"],
                    tip.format(name=name, motion=motion, amount=c["amount"], unit=c["amount_unit"], value=r["value"]),
                )
                for r in sel
                if (r["system"], (c := r["config"])["gi_fov"]) == (system, gi_fov)
            ]
            lines.append(Series(name, pts))
        figures.append(
            xy_chart(lines, f"camera {motion} [{sel[0]['config']['amount_unit']}]", "SSIM of the warped GI vs GT")
        )
    return charts(*figures) + markdown(fov_table(rows))


def fov_table(rows: Rows) -> str:
    """Fig. 9 as Markdown: per scene and GI-camera FOV, the GI map's SSIM and each warp's SSIM (and the share of
    pixels the map covers), each the mean over every camera motion measured."""
    _need(rows, "ssim_gi_map", "ssim_warped")
    warped = _pick(rows, "ssim_warped")
    systems = list(dict.fromkeys(r["system"] for r in warped))
    source = ", ".join(dict.fromkeys(r["system"] for r in _pick(rows, "ssim_gi_map")))
    motions = []
    for motion in dict.fromkeys(r["config"]["motion"] for r in warped):
        sel = [r["config"] for r in warped if r["config"]["motion"] == motion]
        amounts = ", ".join(dict.fromkeys(f"{c['amount']:g}" for c in sel))
        motions.append(f"{motion} {amounts} {sel[0]['amount_unit']}")
    lines = [
        f"GI maps: {source}. Warped: the mean over {'; '.join(motions)}; in brackets, the share of pixels the map covers.",
        "",
        "| scene | F_GI | SSIM of the GI map | " + " | ".join(f"SSIM warped: {s}" for s in systems) + " |",
        "|---" * (3 + len(systems)) + "|",
    ]
    for scene, fov in dict.fromkeys(
        (r["scene"], r["config"]["gi_fov"]) for r in rows if r["metric"] in ("ssim_gi_map", "ssim_warped")
    ):

        def mean(metric: str, system: str | None = None) -> float | None:
            vs = [
                r["value"]
                for r in _pick(rows, metric)
                if (r["scene"], r["config"]["gi_fov"]) == (scene, fov) and system in (None, r["system"])
            ]
            return sum(vs) / len(vs) if vs else None

        cells = []
        for s in systems:
            ssim, covered = mean("ssim_warped", s), mean("valid_fraction", s)
            cells.append("—" if ssim is None else f"{ssim:.3f}" + ("" if covered is None else f" ({covered:.0%})"))
        gi_map = mean("ssim_gi_map")
        lines.append(
            f"| {scene} | {fov:g}° | {'—' if gi_map is None else f'{gi_map:.3f}'} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines)


def pareto_points(rows: Rows) -> list[dict[str, Any]]:
    """The points of a pareto CSV (:func:`bench.pareto.front_points`); a ValueError when it has none."""
    from bench.pareto import front_points

    points = front_points(rows)
    if not points:
        raise ValueError("it has no points with both run_time and error rows")
    return points


def pareto_section(rows: Rows, csv_path: Path) -> str:
    from bench.pareto import ABLATION

    points = pareto_points(rows)
    blocks = []
    for unit in dict.fromkeys(p["per"] for p in points):
        here = [p for p in points if p["per"] == unit]
        figures = []
        systems = list(dict.fromkeys(p["system"] for p in here if p["system"] != ABLATION))
        ablations = [Point(p["time"], p["error"], p["tip"], hollow=True) for p in here if p["system"] == ABLATION]
        for scope in [*systems, "combined"]:
            chosen = here if scope == "combined" else [p for p in here if p["system"] == scope]
            # cross-system ablations: grey, on no front
            series = (
                [Series("ablation (cross-system)", ablations, line=False, colour="#999999")]
                if scope == "combined" and ablations
                else []
            )
            for i, system in enumerate(systems):
                mine = [p for p in chosen if p["system"] == system]
                if not mine:
                    continue
                colour = PALETTE[i % len(PALETTE)]
                flag = "dominated_combined" if scope == "combined" else "dominated"
                front = [Point(p["time"], p["error"], p["tip"]) for p in mine if not p[flag]]
                rest = [Point(p["time"], p["error"], p["tip"], hollow=True) for p in mine if p[flag]]
                series.append(Series(f"{system}: front", front, colour=colour))
                if rest:
                    series.append(Series(f"{system}: dominated", rest, line=False, colour=colour))
            title = f"{scope}: error against run time per {unit}"
            figures.append(
                xy_chart(
                    series,
                    f"median run time per {unit} [ms]",
                    "error: 1 - SSIM vs path-traced GT",
                    xlog=True,
                    ylog=True,
                    caption=title,
                )
            )
        blocks.append(charts(*figures))
    best = best_table(points)
    return "".join(blocks) + markdown(best)


def best_table(points: list[dict[str, Any]]) -> str:
    """The lowest-error point of each system (cross-system ablations excluded) within each time budget, per unit
    of work, with what its run time covers and assumes (Markdown)."""
    from bench.pareto import ABLATION, best_within, caveat

    lines = [
        "| unit | time budget (ms) | system | error | run time (ms) | config | run time covers |",
        "|---|---|---|---|---|---|---|",
    ]
    systems = [p for p in points if p["system"] != ABLATION]
    for unit in dict.fromkeys(p["per"] for p in systems):
        here = [p for p in systems if p["per"] == unit]
        for budget in budgets([p["time"] for p in here]):
            for system in dict.fromkeys(p["system"] for p in here):
                p = best_within([q for q in here if q["system"] == system], budget)
                if p is not None:
                    cells = [
                        unit,
                        f"{budget:g}",
                        system,
                        f"{p['error']:.4g}",
                        f"{p['time']:.3g}",
                        p["label"],
                        caveat(p, points),
                    ]
                    lines.append("| " + " | ".join(cell.replace("|", "/") for cell in cells) + " |")
    note = (
        "Per frame, cloud baking's time is the client's work alone: its maps are made on the server and arrive after the per-GI-map "
        "latency above, so its point at period k holds only if that latency stays under k frames."
    )
    return "### Best configuration per time budget\n\n" + "\n".join(lines) + "\n\n" + note


def budgets(times: list[float]) -> list[float]:
    """Three round time budgets (one significant digit) at a quarter, half and all of the measured run
    times' log range; the last holds every point."""
    lo, hi = min(times), max(times)
    picks = [10 ** (math.log10(lo) + f * (math.log10(hi) - math.log10(lo))) for f in (0.25, 0.5)] if hi > lo else []
    top = 10 ** math.floor(math.log10(hi))
    return list(dict.fromkeys([float(f"{b:.1g}") for b in picks] + [float(math.ceil(hi / top) * top)]))


def stability_section(rows: Rows, csv_path: Path) -> str:
    from bench.stability import PASSED, summary, table

    _need(rows, "status")
    entries = summary(rows)
    failed = [e for e in entries if e["status"] not in PASSED]
    head = (
        ""
        if not failed
        else '<p class="problem">Failed cases: '
        + _e("; ".join(f"{e['stage']}/{e['case']} ({e['status']})" for e in failed))
        + "</p>"
    )
    return head + f'<div class="scroll">{markdown(table(entries))}</div>'


@dataclass(frozen=True)
class Section:
    """A dashboard section: its anchor, title, the bench whose CSV it reads, and how it draws the rows."""

    key: str
    title: str
    bench: str
    draw: Callable[[Rows, Path], str]


SECTIONS = (
    Section("table1", "Table 1: interaction latency", "latency", latency_section),
    Section("table2", "Table 2: storage (GI tree vs model)", "storage", storage_section),
    Section("table3", "Table 3: inference frequency", "frequency", frequency_section),
    Section("fig6", "Fig. 6: GI-map quality", "quality", quality_section),
    Section("fig7", "Fig. 7: cost of warping", "warp", warp_section),
    Section("fig9", "Fig. 9: GI-camera FOV", "fov", fov_section),
    Section("pareto", "Error against run time (Pareto fronts)", "pareto", pareto_section),
    Section("stability", "Numerical stability", "stability", stability_section),
)


# -- reading results ------------------------------------------------------------------------------------------
class Malformed(ValueError):
    """A CSV that is not a bench's tidy result."""


def _provenance(csv_path: Path) -> dict[str, Any] | None:
    path = csv_path.with_name(csv_path.stem + ".provenance.json")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _finished(csv_path: Path) -> float:
    prov = _provenance(csv_path) or {}
    value = prov.get("finished_unix")
    return float(value) if isinstance(value, (int, float)) else csv_path.stat().st_mtime


def find(results: Path, bench: str, ignore: tuple[str, ...] = ()) -> list[Path]:
    """Every ``<bench>.csv`` under ``results``, newest run first, except those inside a folder that one of the
    ``ignore`` patterns (paths relative to ``results``, glob allowed) names."""

    def ignored(path: Path) -> bool:
        folders = [f.as_posix() for f in path.relative_to(results).parents if f != Path(".")]
        return any(fnmatch.fnmatchcase(folder, pattern.strip("/")) for folder in folders for pattern in ignore)

    return sorted((p for p in results.rglob(f"{bench}.csv") if not ignored(p)), key=_finished, reverse=True)


def load(path: Path) -> Rows:
    """The rows of a results CSV, or :class:`Malformed` saying what is wrong with it."""
    try:
        with path.open(newline="") as fh:
            header = next(csv.reader(fh), None)
        if header != list(COLUMNS):
            raise Malformed(f"its columns are {header}, not {', '.join(COLUMNS)}")
        rows = read_rows(path)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise Malformed(f"it cannot be read ({exc})") from None
    except (KeyError, ValueError, TypeError) as exc:
        raise Malformed(f"a row does not parse ({type(exc).__name__}: {exc})") from None
    if not rows:
        raise Malformed("it has no rows")
    if any(not isinstance(r["config"], dict) for r in rows):
        raise Malformed("a config cell is not a JSON object")
    return rows


def provenance_fields(csv_path: Path) -> dict[str, str] | None:
    """What the provenance JSON beside ``csv_path`` says, as text: the command (the program by its name, not
    the path it was started by, and its arguments), git (short SHA; whether the tree had uncommitted
    changes), machine, date, run and seed; None without one."""
    prov = _provenance(csv_path)
    if prov is None:
        return None
    argv = [str(a) for a in prov.get("argv") or []]
    if argv:
        argv[0] = "bench" if Path(argv[0]).name == "__main__.py" else Path(argv[0]).name
    git = prov.get("git") or {}
    m = prov.get("machine") or {}
    finished = prov.get("finished_unix")
    return {
        "command": " ".join(argv) or "(unknown)",
        "git": (git.get("sha") or "unknown")[:12] + (" (uncommitted changes)" if git.get("dirty") else ""),
        "machine": f"{m.get('cpu', '?')}, {m.get('cpu_count', '?')} cores, {m.get('platform', '?')}, Python {m.get('python', '?')}",
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(finished))
        if isinstance(finished, (int, float))
        else "unknown",
        "run": str(prov.get("run_id", "?")),
        "seed": str(prov.get("seed", "?")),
    }


def provenance_html(csv_path: Path, results: Path) -> str:
    prov = provenance_fields(csv_path)
    shown = _e(csv_path.relative_to(results))
    if prov is None:
        missing = f"missing ({_e(csv_path.stem)}.provenance.json)"
        return f'<dl class="prov"><dt>file</dt><dd><code>{shown}</code></dd><dt>provenance</dt><dd>{missing}</dd></dl>'
    items = [("file", f"<code>{shown}</code>"), ("command", f"<code>{_e(prov['command'])}</code>"), ("git", f"<code>{_e(prov['git'])}</code>"),
             ("machine", _e(prov["machine"])), ("date", _e(prov["date"])),
             ("run", f"<code>{_e(prov['run'])}</code>, seed {_e(prov['seed'])}")]  # fmt: skip
    return '<dl class="prov">' + "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in items) + "</dl>"


@dataclass
class Rendered:
    """One section as drawn: status ``ok`` / ``missing`` / ``malformed``, its HTML, what it read."""

    section: Section
    status: str
    body: str
    file: str = ""
    rows: int = 0
    problem: str = ""
    others: list[str] = field(default_factory=list)


@dataclass
class Attempt:
    """A bench's newest CSV under a results folder, drawn: status ``ok`` / ``missing`` / ``malformed``, what the
    drawing made of it (when ``ok``), the file (None when missing), the problem in one line, the older runs."""

    status: str
    body: str = ""
    path: Path | None = None
    rel: str = ""
    rows: int = 0
    problem: str = ""
    others: list[str] = field(default_factory=list)


def attempt(bench: str, results: Path, draw: Callable[[Rows, Path], str], ignore: tuple[str, ...] = ()) -> Attempt:
    """Find the newest ``<bench>.csv`` under ``results`` (outside the ``ignore`` folders), load it and ``draw`` its
    rows (the dashboard's HTML or the README's Markdown): a CSV that is missing, or does not load or draw,
    comes back with its problem."""
    found = find(results, bench, ignore)
    if not found:
        left_out = f" (leaving out {', '.join(ignore)})" if ignore else ""
        return Attempt("missing", problem=f"missing: no {bench}.csv under {results}{left_out}")
    path = found[0]
    rel = str(path.relative_to(results))
    others = [str(p.relative_to(results)) for p in found[1:]]
    try:
        rows = load(path)
        body = draw(rows, path)
    except Exception as exc:  # noqa: BLE001 -- any reason a CSV cannot be drawn is reported in its section, and the others still render
        why = " ".join(str(exc if isinstance(exc, Malformed) else f"{type(exc).__name__}: {exc}").split())
        return Attempt("malformed", path=path, rel=rel, problem=f"malformed: {rel}: {why}", others=others)
    return Attempt("ok", body, path, rel, len(rows), others=others)


def render(section: Section, results: Path, ignore: tuple[str, ...] = ()) -> Rendered:
    a = attempt(section.bench, results, section.draw, ignore)
    if a.path is None:
        todo = f"run <code>bench {section.bench} --out {_e(results)}</code> (or into a folder under it)"
        return Rendered(section, "missing", f'<p class="problem">{_e(a.problem)}; {todo}.</p>', problem=a.problem)
    prov = provenance_html(a.path, results)
    if a.status != "ok":
        return Rendered(
            section,
            a.status,
            prov + f'<p class="problem">{_e(a.problem)}</p>',
            a.rel,
            problem=a.problem,
            others=a.others,
        )
    note = f"<p>Newest of {len(a.others) + 1} runs; older: {_e(', '.join(a.others))}.</p>" if a.others else ""
    return Rendered(section, "ok", prov + note + a.body, a.rel, a.rows, others=a.others)


def page(parts: list[Rendered], results: Path) -> str:
    css = (ASSETS / "report.css").read_text()
    js = (ASSETS / "report.js").read_text()
    nav = "".join(
        f'<a class="{p.status}" href="#{p.section.key}">{_e(p.section.title.split(":")[0])}: {p.status}</a>'
        for p in parts
    )
    sections = "".join(
        f'<section id="{p.section.key}" data-status="{p.status}" data-bench="{p.section.bench}"><h2>{_e(p.section.title)}</h2>{p.body}</section>'
        for p in parts
    )
    made = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>GIGAN testbed results</title><style>{css}</style></head><body>"
        f"<header><h1>GIGAN testbed: results dashboard</h1><p>Built {made} from the CSV files under <code>{_e(results)}</code> "
        "(bench report). Hover a chart mark for its values; Pareto points show their full config.</p></header>"
        f'<nav>{nav}</nav><main>{sections}</main><div id="tip" hidden></div><script>{js}</script></body></html>\n'
    )


def measure(cfg: ReportConfig, res: Results) -> None:
    from bench.report_md import results_markdown, update_readme

    results = cfg.results.resolve()
    parts = [render(section, results, cfg.ignore) for section in SECTIONS]
    atomic_write_bytes(res.output("report.html"), page(parts, results).encode())
    text = results_markdown(cfg.results, cfg.ignore)
    atomic_write_bytes(res.output("results.md"), text.encode())
    if cfg.readme is not None:
        update_readme(cfg.readme, text)
        res.files.append(cfg.readme)
    for p in parts:
        config = {
            "section": p.section.key,
            "bench": p.section.bench,
            "file": p.file,
            "problem": p.problem,
            "older_runs": p.others,
        }
        res.add(system="report", scene="all", metric="section_rows", value=p.rows, unit="rows", stat=p.status, **config)


BENCH = Bench(
    "report",
    ReportConfig,
    measure,
    None,
    help="A static HTML dashboard (report.html, opens offline) from the CSV files and provenance under --results: Tables 1-3, Fig. 6, 7, 9, "
    "the Pareto fronts (hover a point for its config), the stability table; a missing or malformed CSV is named in its section. Also "
    "results.md, the README's results section (each block with the command that made it); --readme puts it between the file's markers.",
)
