"""What a bench shows, declared once as data: its tables, figures, images and alerts.

A declaration names the rows it shows (``rows`` / ``points``: a function of the bench's CSV rows, most often
:func:`pick` or :func:`wide`), its columns or axes, and its captions; :mod:`gicore.present.markdown`,
:mod:`gicore.present.html` and :mod:`gicore.present.charts` render it. Cells, labels and tooltips are
``str.format`` templates over one derived row (:func:`fill`): a field the row lacks, None or NaN shows as a dash.
``where`` says which outputs show a part: the dashboard, the README's results block, or both (a bench's own
``<bench>.md`` and figure files hold every part).
"""

from __future__ import annotations

import math
import re
import string
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Literal

#: The rows of a results CSV as :func:`gicore.results.read_rows` gives them (``config`` decoded).
Rows = list[dict[str, Any]]
#: A declaration's own rows, derived from the CSV's: flat dicts (a CSV row's config keys beside its columns).
Derive = Callable[[Rows], list[dict[str, Any]]]
#: Fixed text, or text made from the CSV's rows.
Text = str | Callable[[Rows], str]
Where = Literal["both", "dashboard", "readme"]
DASH = "—"


@dataclass(frozen=True)
class Column:
    """A table column: its header and its cell, a template over the table's derived row."""

    header: str
    cell: str


@dataclass(frozen=True)
class Table:
    """A table: one line per derived row, split into sub-tables by ``group`` (a template; each sub-table headed by
    it, with ``group_note`` below it); a table without rows is not shown."""

    rows: Derive
    columns: tuple[Column, ...] | Callable[[Rows], tuple[Column, ...]]
    title: Text = ""
    caption: Text = ""
    notes: Text = ""
    group: str = ""
    group_note: str = ""
    where: Where = "both"
    #: Dashboard: inside a scrolling box (a long or wide table).
    scroll: bool = False


@dataclass(frozen=True)
class Chart:
    """One panel: ``points`` drawn as ``x`` against ``y`` (field names), one series per value of the ``series``
    template. ``line``: series joined in x order (hollow points apart); ``scatter``: marks only; ``bar``: grouped
    bars, one group per x value; ``stack``: horizontal bars, one per x value, stacked by series."""

    points: Derive
    x: str
    y: str = "value"
    series: str = ""
    kind: Literal["line", "scatter", "bar", "stack"] = "line"
    xlabel: Text = ""
    ylabel: Text = ""
    xlog: bool = False
    ylog: bool = False
    title: Text = ""
    #: A mark's tooltip on the dashboard (template over its point, with ``series`` added); empty: x and y.
    tip: str = ""
    #: A field: points where it is true are drawn hollow and left off the series' line.
    hollow: str = ""
    #: A template written beside each mark (e.g. its spp).
    label: str = ""


@dataclass(frozen=True)
class Figure:
    """Charts side by side, written as ``<name>.png`` and ``<name>.svg``; a figure whose charts have no points is
    not drawn."""

    name: str
    charts: tuple[Chart, ...]
    title: Text = ""
    caption: Text = ""
    where: Where = "both"


@dataclass(frozen=True)
class Image:
    """A picture the bench wrote beside its CSV (``file``), shown as it is."""

    file: str
    caption: str = ""
    where: Where = "both"


@dataclass(frozen=True)
class Alert:
    """A line the dashboard shows as a problem when ``text`` makes one (e.g. the stability cases that failed)."""

    text: Callable[[Rows], str]
    where: Where = "dashboard"


Part = Table | Figure | Image | Alert


def shown(parts: Iterable[Part], place: str) -> list[Part]:
    """The parts shown in ``place`` (``dashboard`` or ``readme``), in order."""
    return [p for p in parts if p.where in ("both", place)]


def text(value: Text, rows: Rows) -> str:
    return value(rows) if callable(value) else value


# -- templates -------------------------------------------------------------------------------------------------
def mib(n: float) -> str:
    """Bytes as MiB with three significant digits (tiny trees stay readable)."""
    m = n / 2**20
    return f"{m:,.0f}" if m >= 100 else f"{m:.3g}"


#: Format specs beyond Python's: ``{bytes:mib}``.
NAMED: dict[str, Callable[[Any], str]] = {"mib": mib}


def missing(value: Any) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


class _Cells(string.Formatter):
    """``str.format`` where a field the row lacks is None, and None or NaN formats as a dash."""

    def __init__(self) -> None:
        self.fields = self.missing = 0

    def get_field(self, field_name: str, args: Any, kwargs: Any) -> Any:
        try:
            return super().get_field(field_name, args, kwargs)
        except (KeyError, IndexError, TypeError, AttributeError):
            return None, field_name

    def format_field(self, value: Any, format_spec: str) -> str:
        self.fields += 1
        if missing(value):
            self.missing += 1
            return DASH
        return NAMED[format_spec](value) if format_spec in NAMED else format(value, format_spec)


#: An optional piece of a template: left out when a field in it is missing.
OPTIONAL = re.compile(r"\[\[(.*?)\]\]")


def fill(template: str, row: dict[str, Any]) -> str:
    """``template`` filled from ``row``: a ``[[...]]`` piece left out when a field in it is missing, and the whole
    a dash alone when every other field it names is missing."""
    pieces = OPTIONAL.split(template)
    cells = _Cells()
    out = []
    for i, piece in enumerate(pieces):
        if i % 2:
            optional = _Cells()
            filled = optional.vformat(piece, (), row)
            out.append("" if optional.missing else filled)
        else:
            out.append(cells.vformat(piece, (), row))
    return DASH if cells.fields and cells.missing == cells.fields else "".join(out)


def per(values: Iterable[Any], header: str, cell: str) -> tuple[Column, ...]:
    """A column per value: ``header`` with the value in its ``{}``, ``cell`` with the value's index for each ``#``
    (the derived rows hold a list per field, see :func:`spread`)."""
    return tuple(Column(header.format(v), cell.replace("#", str(i))) for i, v in enumerate(values))


# -- rows ------------------------------------------------------------------------------------------------------
def flat(row: dict[str, Any]) -> dict[str, Any]:
    """A CSV row as one flat dict: its config's keys beside its columns (the columns win a clash)."""
    return {**row["config"], **row}


def matches(row: dict[str, Any], metric: str | None = None, stat: str | None = None, **config: Any) -> bool:
    return (
        (metric is None or row["metric"] == metric)
        and (stat is None or row["stat"] == stat)
        and all(row["config"].get(k) == v for k, v in config.items())
    )


def pick(metric: str, stat: str | None = None, **config: Any) -> Derive:
    """The rows of ``metric`` (with ``stat`` and the ``config`` values given), flat."""
    return lambda rows: [flat(r) for r in rows if matches(r, metric, stat, **config)]


def first(rows: Rows, metric: str, stat: str | None = None, **config: Any) -> float | None:
    """The value of the first row that matches, else None."""
    return next((r["value"] for r in rows if matches(r, metric, stat, **config)), None)


def unique(values: Iterable[Any]) -> list[Any]:
    """The distinct values in order of first appearance."""
    return list(dict.fromkeys(values))


def wide(
    rows: Rows, keys: tuple[str, ...], fields: dict[str, str], mean: bool = False, **config: Any
) -> list[dict[str, Any]]:
    """One derived row per distinct value of ``keys`` (flat field names) among the rows of the ``fields``' metrics,
    in order of first appearance, with each field (``name: "metric"`` or ``"metric/stat"``) the value of the row
    of that key and metric (the mean of them with ``mean``; None when there is none)."""
    wanted = {name: (spec.split("/") + [None])[:2] for name, spec in fields.items()}
    out: dict[tuple, dict[str, Any]] = {}
    values: dict[tuple, dict[str, list[float]]] = {}
    for r in rows:
        f = flat(r)
        for name, (metric, stat) in wanted.items():
            if matches(r, metric, stat, **config):
                key = tuple(f.get(k) for k in keys)
                out.setdefault(key, {k: f.get(k) for k in keys} | {"config": r["config"]})
                values.setdefault(key, {}).setdefault(name, []).append(r["value"])
    for key, row in out.items():
        for name in wanted:
            vs = values[key].get(name)
            row[name] = None if not vs else (sum(vs) / len(vs) if mean else vs[0])
    return list(out.values())


def spread(derived: list[dict[str, Any]], keys: tuple[str, ...], by: str, values: list[Any]) -> list[dict[str, Any]]:
    """One row per distinct value of ``keys``, each other field a list with an entry per value of ``by`` in
    ``values`` (None where there is no row): the rows of a table with a column per ``by``."""
    out: dict[tuple, dict[str, Any]] = {}
    for r in derived:
        row = out.setdefault(tuple(r[k] for k in keys), {k: r[k] for k in keys})
        if r[by] in values:
            for name, v in r.items():
                if name not in (*keys, by, "config"):
                    row.setdefault(name, [None] * len(values))[values.index(r[by])] = v
    return list(out.values())
