"""Figures through matplotlib: one drawing of a :class:`Figure` writes its PNG and its SVG.

The SVG is what the dashboard embeds: every mark (a point of a series, a bar) carries ``class="pt"`` and its
tooltip in ``data-tip`` (the page's script shows it on hover), found through the ``gid`` each mark's artist is
drawn with. Matplotlib is imported inside the functions, so declaring a bench never pays for it.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any
from xml.dom import minidom

from gicore.present.declarations import Chart, Figure, Rows, fill, text, unique

#: Marks' tooltips by the gid of the artist that drew them, in drawing order.
Tips = dict[str, list[str]]
#: Charts side by side in a figure; more wrap onto further rows.
PER_ROW = 3


def _finite(chart: Chart, points: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The points a chart can draw: a finite y (positive on a log axis), and for x-y charts a finite x likewise."""

    def ok(v: Any, log: bool) -> bool:
        return isinstance(v, (int, float)) and math.isfinite(v) and (v > 0 or not log)

    xy = chart.kind in ("line", "scatter")
    return [p for p in points if ok(p.get(chart.y), chart.ylog) and (not xy or ok(p.get(chart.x), chart.xlog))]


def _series(chart: Chart, points: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    names = [fill(chart.series, p) if chart.series else "" for p in points]
    return {n: [p | {"series": n} for p, m in zip(points, names) if m == n] for n in unique(names)}


def _colour(i: int, n: int) -> Any:
    """The ``i``-th of ``n`` series' colours: matplotlib's cycle, or tab20's for more than ten series."""
    from gicore.plotting import plt

    return f"C{i}" if n <= 10 else plt.get_cmap("tab20")(i % 20)


def _tip(chart: Chart, p: dict[str, Any]) -> str:
    if chart.tip:
        return fill(chart.tip, p)
    x, y = p[chart.x], p[chart.y]
    return f"{p['series']}: {x:.4g} → {y:.4g}" if isinstance(x, float) else f"{p['series']}, {x}: {y:.4g}"


def _xy(ax: Any, chart: Chart, series: dict[str, list[dict]], tips: Tips) -> None:
    for i, (name, points) in enumerate(series.items()):
        colour = _colour(i, len(series))
        points = sorted(points, key=lambda p: p[chart.x])
        flags = [bool(chart.hollow and p.get(chart.hollow)) for p in points]
        solid = [p for p, f in zip(points, flags) if not f]
        hollow = [p for p, f in zip(points, flags) if f]
        if chart.kind == "line" and len(solid) > 1:
            ax.plot([p[chart.x] for p in solid], [p[chart.y] for p in solid], "-", color=colour, lw=1.4)
        for group, face in ((solid, colour), (hollow, "none")):
            if group:
                gid = f"pts{len(tips)}"
                xs, ys = [p[chart.x] for p in group], [p[chart.y] for p in group]
                first = group is solid or not solid
                ax.scatter(
                    xs, ys, s=22, facecolors=face, edgecolors=colour, label=name if first else None, gid=gid, zorder=3
                )
                tips[gid] = [_tip(chart, p) for p in group]
        for p in points if chart.label else ():
            ax.annotate(fill(chart.label, p), (p[chart.x], p[chart.y]), fontsize=6, alpha=0.7)


def _bars(ax: Any, chart: Chart, series: dict[str, list[dict]], tips: Tips) -> None:
    """Grouped bars (``bar``) or horizontal stacked bars (``stack``), one group or bar per x value."""
    groups = unique(str(p[chart.x]) for points in series.values() for p in points)
    width = 0.8 / max(len(series), 1)
    left = [0.0] * len(groups)
    for i, (name, points) in enumerate(series.items()):
        at = [groups.index(str(p[chart.x])) for p in points]
        values = [p[chart.y] for p in points]
        if chart.kind == "stack":
            bars = ax.barh(at, values, left=[left[g] for g in at], color=_colour(i, len(series)), label=name)
            for g, v in zip(at, values):
                left[g] += v
        else:
            bars = ax.bar(
                [g + (i + 0.5) * width - 0.4 for g in at], values, width, color=_colour(i, len(series)), label=name
            )
        for patch, p in zip(bars.patches, points):
            gid = f"bar{len(tips)}"
            patch.set_gid(gid)
            tips[gid] = [_tip(chart, p)]
    if chart.kind == "stack":
        ax.set_yticks(range(len(groups)), groups, fontsize=7)
        ax.invert_yaxis()
    else:
        ax.set_xticks(range(len(groups)), groups, fontsize=7, rotation=20 if len(groups) > 4 else 0)


def _panel(ax: Any, chart: Chart, points: list[dict], rows: Rows, tips: Tips) -> None:
    from gicore.plotting import ticker

    series = _series(chart, points)
    (_xy if chart.kind in ("line", "scatter") else _bars)(ax, chart, series, tips)
    xlabel, ylabel = text(chart.xlabel, rows), text(chart.ylabel, rows)
    if chart.kind == "stack":  # the values run along x
        xlabel, ylabel = ylabel, xlabel
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.set_title(text(chart.title, rows), fontsize=9)
    for log, axis, scale in ((chart.xlog, ax.xaxis, ax.set_xscale), (chart.ylog, ax.yaxis, ax.set_yscale)):
        if log:  # plain numbers (20, 300) rather than powers of ten
            scale("log")
            axis.set_major_formatter(ticker.LogFormatter())
            axis.set_minor_formatter(ticker.LogFormatter(minor_thresholds=(1, 0.4)))
    ax.grid(alpha=0.3, which="both")
    if len(series) > 10:  # a long legend goes beside the chart, in columns of at most 18
        ax.legend(fontsize=5, ncols=-(-len(series) // 18), loc="upper left", bbox_to_anchor=(1.02, 1.0))
    elif any(series):
        ax.legend(fontsize=6)


def _draw(figure: Figure, rows: Rows) -> tuple[Any, Tips] | None:
    from gicore.plotting import plt

    panels = [(c, p) for c in figure.charts if (p := _finite(c, c.points(rows)))]
    if not panels:
        return None
    across = min(len(panels), PER_ROW)
    down = -(-len(panels) // across)
    fig, axes = plt.subplots(down, across, figsize=(5.4 * across, 4.2 * down), squeeze=False)
    tips: Tips = {}
    for ax, (chart, points) in zip(axes.flat, panels):
        _panel(ax, chart, points, rows, tips)
    for ax in axes.flat[len(panels) :]:
        ax.set_visible(False)
    title = text(figure.title, rows)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig, tips


def _with_tips(svg: str, tips: Tips) -> str:
    """The SVG element alone, each mark of ``tips`` marked ``pt`` with its tooltip."""
    doc = minidom.parseString(svg)
    root = doc.documentElement
    root.setAttribute("class", "chart")
    for g in doc.getElementsByTagName("g"):
        marks = tips.get(g.getAttribute("id"))
        if marks:
            for mark, tip in zip(g.getElementsByTagName("use") or g.getElementsByTagName("path"), marks):
                mark.setAttribute("class", "pt")
                mark.setAttribute("data-tip", tip)
    return root.toxml()


def render(figure: Figure, rows: Rows, png: Path | None = None) -> str:
    """The figure as inline SVG with its marks' tooltips (empty when it has no points); with ``png``, written there
    too, from the same drawing."""
    from gicore.plotting import plt

    style = {"svg.fonttype": "none", "svg.hashsalt": figure.name, "font.sans-serif": ["DejaVu Sans"]}
    with plt.rc_context(style):
        drawn = _draw(figure, rows)
        if drawn is None:
            return ""
        fig, tips = drawn
        if png is not None:
            png.parent.mkdir(parents=True, exist_ok=True)
            fig.savefig(png, dpi=120)
        buf = io.StringIO()
        fig.savefig(buf, format="svg", metadata={"Date": None})
        plt.close(fig)
    return _with_tips(buf.getvalue(), tips)
