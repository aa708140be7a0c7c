"""The dashboard's charts as values, and their inline SVG (``bench report``).

A bench describes a chart (:class:`XYChart`, :class:`BarChart`) from its CSV rows; the dashboard draws it with
``svg()``. Every mark is a ``.pt`` element whose ``data-tip`` the page's script shows on hover, so the classes
here match ``bench/report_assets``. Nothing here imports from ``bench``: benches and the report both use it.
"""

from __future__ import annotations

import html
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

PALETTE = ("#3366cc", "#dc3912", "#109618", "#ff9900", "#990099", "#0099c6", "#dd4477", "#66aa00", "#b82e2e", "#316395")
NO_VALUES = '<p class="problem">no finite values to plot</p>'


@dataclass(frozen=True)
class Point:
    """One mark: position, its tooltip text, and whether it is drawn hollow (e.g. a dominated point)."""

    x: float
    y: float
    tip: str
    hollow: bool = False


@dataclass(frozen=True)
class Series:
    """Marks drawn in one colour under one legend entry."""

    name: str
    points: list[Point]
    #: Join the points (sorted by x) with a line.
    line: bool = True
    #: Empty: the palette's colour for the series' place in its chart.
    colour: str = ""


@dataclass(frozen=True)
class XYChart:
    """A scatter/line chart of series against two axes, either of which may be logarithmic."""

    series: list[Series]
    xlabel: str
    ylabel: str
    xlog: bool = False
    ylog: bool = False
    caption: str = ""

    def svg(self) -> str:
        """The chart as a ``<figure>`` with inline SVG and its legend; a problem line when nothing is finite."""
        series = [
            Series(s.name, s.points, s.line, s.colour or PALETTE[i % len(PALETTE)]) for i, s in enumerate(self.series)
        ]
        xlog, ylog = self.xlog, self.ylog
        ok = [
            p
            for s in series
            for p in s.points
            if math.isfinite(p.x) and math.isfinite(p.y) and (p.x > 0 or not xlog) and (p.y > 0 or not ylog)
        ]
        if not ok:
            return NO_VALUES
        w, h, left, right, top, bottom = 560, 330, 62, 14, 12, 44
        (x0, x1), (y0, y1) = _domain([p.x for p in ok], xlog), _domain([p.y for p in ok], ylog)

        def sx(v: float) -> float:
            f = (math.log10(v) - math.log10(x0)) / (math.log10(x1) - math.log10(x0)) if xlog else (v - x0) / (x1 - x0)
            return left + f * (w - left - right)

        def sy(v: float) -> float:
            f = (math.log10(v) - math.log10(y0)) / (math.log10(y1) - math.log10(y0)) if ylog else (v - y0) / (y1 - y0)
            return h - bottom - f * (h - top - bottom)

        label = f"{_e(self.ylabel)} against {_e(self.xlabel)}"
        parts = [f'<svg class="chart" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img" aria-label="{label}">']
        for t in _ticks(x0, x1, xlog):
            parts.append(f'<line class="grid" x1="{sx(t):.1f}" x2="{sx(t):.1f}" y1="{top}" y2="{h - bottom}"/>')
            parts.append(f'<text x="{sx(t):.1f}" y="{h - bottom + 14}" text-anchor="middle">{_fmt(t)}</text>')
        for t in _ticks(y0, y1, ylog):
            parts.append(f'<line class="grid" x1="{left}" x2="{w - right}" y1="{sy(t):.1f}" y2="{sy(t):.1f}"/>')
            parts.append(f'<text x="{left - 5}" y="{sy(t) + 4:.1f}" text-anchor="end">{_fmt(t)}</text>')
        parts.append(f'<line class="axis" x1="{left}" x2="{w - right}" y1="{h - bottom}" y2="{h - bottom}"/>')
        parts.append(f'<line class="axis" x1="{left}" x2="{left}" y1="{top}" y2="{h - bottom}"/>')
        parts.append(
            f'<text x="{(left + w - right) / 2}" y="{h - 8}" text-anchor="middle">'
            f"{_e(self.xlabel)}{' (log)' if xlog else ''}</text>"
        )
        parts.append(
            f'<text transform="translate(13 {(top + h - bottom) / 2}) rotate(-90)" text-anchor="middle">'
            f"{_e(self.ylabel)}{' (log)' if ylog else ''}</text>"
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
                    f'<circle class="pt" cx="{sx(p.x):.1f}" cy="{sy(p.y):.1f}" r="4.5" fill="{fill}" '
                    f'stroke="{s.colour}" stroke-width="1.5" data-tip="{_e(p.tip)}"/>'
                )
        parts.append("</svg>")
        legend = _legend((s.name, s.colour, bool(s.points) and all(p.hollow for p in s.points)) for s in series)
        return _figure("".join(parts) + legend, self.caption)


@dataclass(frozen=True)
class BarChart:
    """Grouped bars: one group per entry of ``groups``, one bar per series (its values in group order; None:
    no bar). ``tips``: each bar's tooltip per series (default: series, group, value and ``ylabel``)."""

    groups: list[str]
    series: dict[str, list[float | None]]
    ylabel: str
    tips: dict[str, list[str]] | None = field(default=None)
    caption: str = ""

    def svg(self) -> str:
        """The chart as a ``<figure>`` with inline SVG and its legend; a problem line when nothing is finite."""
        groups, series, ylabel = self.groups, self.series, self.ylabel
        values = [v for vs in series.values() for v in vs if v is not None and math.isfinite(v)]
        if not values:
            return NO_VALUES
        w, h, left, right, top, bottom = 560, 280, 62, 10, 12, 30
        y0, y1 = _domain(values, False, zero=True)
        y0 = min(y0, 0.0)

        def sy(v: float) -> float:
            return h - bottom - (v - y0) / (y1 - y0) * (h - top - bottom)

        label = _e(ylabel)
        parts = [f'<svg class="chart" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img" aria-label="{label}">']
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
                tip = self.tips[name][g] if self.tips else f"{name}, {group}: {_fmt(v)} {ylabel}"
                parts.append(
                    f'<rect class="pt" x="{gx + i * bar:.1f}" y="{top_y:.1f}" width="{bar * 0.92:.1f}" '
                    f'height="{max(base_y - top_y, 0.5):.1f}" fill="{colours[name]}" data-tip="{_e(tip)}"/>'
                )
        parts.append(f'<line class="axis" x1="{left}" x2="{w - right}" y1="{sy(0.0):.1f}" y2="{sy(0.0):.1f}"/>')
        parts.append(
            f'<text transform="translate(13 {(top + h - bottom) / 2}) rotate(-90)" text-anchor="middle">{label}</text>'
        )
        parts.append("</svg>")
        return _figure("".join(parts) + _legend((n, c, False) for n, c in colours.items()), self.caption)


Chart = XYChart | BarChart


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def _figure(body: str, caption: str) -> str:
    return f"<figure>{body}" + (f"<figcaption>{_e(caption)}</figcaption>" if caption else "") + "</figure>"


def _ticks(lo: float, hi: float, log: bool) -> list[float]:
    """Round tick values covering [lo, hi]."""
    if log:
        a, b = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
        for steps in ((1,), (1, 2, 5)):  # decades, else 1-2-5 within them
            ticks = [t for t in (m * 10.0**k for k in range(a, b + 1) for m in steps) if lo * 0.999 <= t <= hi * 1.001]
            if len(ticks) >= 3:
                return ticks
        # within one decade: round linear values, placed on the log scale
        return [t for t in _ticks(lo, hi, False) if t > 0]
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
        if hollow:
            return f'<i style="border:2px solid {colour};background:#fff"></i>'
        return f'<i style="background:{colour}"></i>'

    return (
        '<div class="legend">'
        + "".join(f"<span>{swatch(c, hollow)}{_e(n)}</span>" for n, c, hollow in entries)
        + "</div>"
    )
