"""What `bench latency` shows of its CSV: Table 1 per network profile (a column per system, cache state and
renderer), the renderers side by side, perceived latency on the prebaked store, the crossover RTTs, the short
Table 1 of the README, and the figures (stage bars, the ratio of totals against RTT, SSIM along the path)."""

from __future__ import annotations

import math
from functools import partial
from typing import Any

from baseline_cloudbaking.client_run import REQUEST_STAGES, TRANSMISSION_PARTS
from bench.latency_record import CLOUD, CLOUD_PREFETCH, GIGAN, RENDERER_RATIO
from gicore.intervals import MIN_SAMPLES, cell, legend, level_of, recorded, suffix, too_few
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, fill, flat, matches, per, unique
from gigan_local.client import MAP_STAGES

#: Table 1's rows: (metric, label); sub-stages of transmission are indented.
TABLE_ROWS = (
    ("transmission", "transmission"),
    ("request", "&nbsp;&nbsp;request: upload, round trip, HTTP + proxy"),
    ("transfer", "&nbsp;&nbsp;transfer: response body"),
    ("lookup", "server: GI-tree lookup"),
    ("read", "server: read stored map"),
    ("render", "server: path tracing (+ DI, depth)"),
    ("denoise", "server: denoise (OIDN, or OptiX on CUDA)"),
    ("encode", "server: encode"),
    ("server_other", "server: other (store the map, header)"),
    ("gi_render", "GI-camera render (DI + G-buffers)"),
    ("inference", "inference"),
    ("decode", "decode"),
    ("di", "local render: DI + the warp's pass (the frame showing the map)"),
    ("warp", "warp (per-map bind + per-frame warp stages)"),
    ("blend", "blend"),
    ("total", "**total (interaction latency)**"),
)
#: Table 1's columns per renderer: (system, cache, label).
SYSTEMS = ((GIGAN, None, "GIGAN"), (CLOUD, "hit", "cloud baking, hit"), (CLOUD, "miss", "cloud baking, miss"))
#: The stages the renderers' comparison shows: those a raster pass is in, and the totals.
RENDERER_ROWS = (
    ("di", "local render (DI + warp pass)"),
    ("gi_render", "GI-camera render"),
    ("warp", "warp"),
    ("total", "total"),
)
#: GIGAN's stages as the README's sentence names them.
GIGAN_LABELS = (
    ("di", "local render"),
    ("gi_render", "GI-camera render"),
    ("inference", "inference"),
    ("warp", "warp"),
    ("blend", "blend"),
)


def with_renderer(rows: Rows) -> Rows:
    """The rows, each config naming its renderer: runs from before the clients had a choice ran Mitsuba's. Their
    ``di`` rows are left out: they timed every frame's DI, which their totals did not count."""
    return [
        r if "renderer" in r["config"] else r | {"config": r["config"] | {"renderer": "mitsuba"}}
        for r in rows
        if "renderer" in r["config"] or r["metric"] != "di"
    ]


def renderers_of(rows: Rows) -> list[str]:
    """The renderers with measured totals, in the run's order."""
    return unique(r["config"]["renderer"] for r in rows if matches(r, "total", "median"))


def profiles_of(rows: Rows) -> list[str]:
    return unique(r["config"]["profile"] for r in rows if r["system"] == CLOUD and "cache" in r["config"])


def lookup(rows: Rows, system: str, metric: str, stat: str, **config: Any) -> float | None:
    """The value of the row of ``system``, ``metric`` and ``stat`` whose config holds ``config``. A scan, not a
    DataFrame: a run has about a thousand rows whose configs differ in their keys per system, and every table here
    is built in about 0.1 s this way; a frame would flatten and re-nest those configs for no grouping it saves."""
    return next((r["value"] for r in rows if r["system"] == system and matches(r, metric, stat, **config)), None)


def _where(system: str, cache: str | None, profile: str, renderer: str) -> dict[str, Any]:
    return ({"profile": "none"} if system == GIGAN else {"profile": profile, "cache": cache}) | {"renderer": renderer}


def _columns(rows: Rows) -> list[tuple[str, str | None, str, str]]:
    """Table 1's columns: (system, cache, renderer, header)."""
    return [(s, c, r, f"{label}, {r}") for r in renderers_of(with_renderer(rows)) for s, c, label in SYSTEMS]


#: The systems as the notes on what ran name them.
SYSTEM_LABELS = {GIGAN: "GIGAN", CLOUD: "cloud baking", CLOUD_PREFETCH: "cloud baking with prefetch"}


def what_ran(raw: Rows) -> str:
    """What each system's client runs ran, per renderer, from their ``frames`` rows: the inference backend and its
    device, the warp backend, the server's Mitsuba variant and denoiser (empty for runs that did not record it)."""
    ran: dict[tuple[str, str], dict[str, None]] = {}
    for r in raw:
        if matches(r, "frames", "value") and "warp_backend" in r["config"]:
            c = r["config"]
            how = fill("[[inference {inference} on {inference_device}, ]]warp {warp_backend}[[, server "
                       "{server_variant} with {server_denoiser}]]", c)  # fmt: skip
            ran.setdefault((r["system"], c["renderer"]), {})[how] = None
    if not ran:
        return ""
    shown = [f"{SYSTEM_LABELS.get(s, s)} on {renderer}: {' or '.join(how)}" for (s, renderer), how in ran.items()]
    return "What ran: " + "; ".join(shown) + "."


# -- Table 1 in full ------------------------------------------------------------------------------------------
def table1(raw: Rows) -> list[dict[str, Any]]:
    """Per profile: each stage's median and p95 per column (stages no column measured left out), the ratio of
    totals with its interval (:func:`gicore.intervals.cell`) and what the interval rests on (:func:`rests_on`), the
    link model's total and the maps measured; the profile's note on the pickup wait."""
    rows, columns = with_renderer(raw), _columns(raw)
    out = []
    for profile in profiles_of(rows):
        rtt = next((r["config"]["rtt_ms"] for r in rows if matches(r, "total_ratio", profile=profile)), None)
        head = {"profile": profile, "rtt": rtt, "note": f"{_pickup(rows, profile)} {fidelity(rows, profile)}".strip()}
        for metric, label in TABLE_ROWS:
            where = [_where(s, c, profile, r) for s, c, r, _ in columns]
            m = [lookup(rows, s, metric, "median", **w) for (s, *_), w in zip(columns, where)]
            p = [lookup(rows, s, metric, "p95", **w) for (s, *_), w in zip(columns, where)]
            if any(v is not None for v in m):
                out.append(head | {"stage": label, "fmt": ".1f", "m": m, "p": p})

        def cloud(system: str, metric: str) -> list[float | None]:
            return [
                None if s == GIGAN else lookup(rows, system, metric, "median", profile=profile, cache=c, renderer=r)
                for s, c, r, _ in columns
            ]

        counts = [lookup(rows, s, "total", "n", **_where(s, c, profile, r)) or 0 for s, c, r, _ in columns]
        gigan_n = {r: lookup(rows, GIGAN, "total", "n", profile="none", renderer=r) for _, _, r, _ in columns}
        ratio = partial(cell, rows, f"{CLOUD}/{GIGAN}", "total_ratio", "median", fmt=".2f", even=1.0)
        # each ratio's samples: its column's maps and GIGAN's on the same renderer
        ratios = [
            None if s == GIGAN else ratio((n, gigan_n[r]), profile=profile, cache=c, renderer=r)
            for (s, c, r, _), n in zip(columns, counts)
        ]
        level = level_of(rows, "total_ratio")
        shown = "" if level is None else f" [{level * 100:g} % interval]"
        label = f"ratio of totals, cloud / GIGAN (same renderer){shown}"
        out.append(head | {"stage": label, "fmt": "s", "m": ratios})
        if level is not None:  # runs from before the intervals recorded none
            rests = [
                None if s == GIGAN else rests_on(rows, n, gigan_n[r], profile=profile, cache=c, renderer=r)
                for (s, c, r, _), n in zip(columns, counts)
            ]
            out.append(head | {"stage": "the interval rests on (maps: cloud / GIGAN)", "fmt": "s", "m": rests})
        out += [
            head | {"stage": "total by the link model (check)", "fmt": ".1f", "m": cloud(CLOUD, "total_model")},
            head | {"stage": "maps measured", "fmt": ".0f", "m": counts},
        ]
    return out


def rests_on(rows: Rows, cloud_maps: float, gigan_maps: float | None, **where: Any) -> str:
    """What the ratio's interval at ``where`` rests on: the maps of its cloud column and GIGAN's (and the repeats,
    for an interval over runs), or that too few maps made none."""
    if min(cloud_maps, gigan_maps or 0) < MIN_SAMPLES:
        return "too few maps for an interval: raise --frames"
    maps = f"{cloud_maps:.0f} / {gigan_maps:.0f}"
    interval = recorded(rows, f"{CLOUD}/{GIGAN}", "total_ratio", **where)
    if interval is None or interval.over == "maps":
        return maps
    repeats = next(r["config"]["repeats"] for r in rows if matches(r, "total_ratio", "ci_low", **where))
    return f"{repeats} runs ({maps} in all)"


def _pickup(rows: Rows, profile: str) -> str:
    renderers = renderers_of(rows)
    pickup = [
        lookup(rows, CLOUD, "pickup", "median", profile=profile, cache=c, renderer=r)
        for r in renderers
        for c in ("hit", "miss")
    ]
    return (
        "Not in the totals: cloud baking's wait from a map's arrival to the next frame taking it (median "
        + " / ".join(fill("{v:.1f}", {"v": v}) for v in pickup)
        + " ms: "
        + " / ".join(f"{c} {r}" for r in renderers for c in ("hit", "miss"))
        + ")."
    )


def fidelity(rows: Rows, profile: str) -> str:
    """The simulated network's own timing at ``profile``: its proxies' p99 lateness per run, and a warning when
    one was later than the limit (the link's timing was then the machine's, not the profile's)."""
    late = [r for r in rows if r["system"] == "network_sim" and matches(r, "proxy_lateness", "p99", profile=profile)]
    if not late:
        return ""
    runs = ", ".join(f"{r['config']['store']} {r['config']['renderer']} {r['value']:.2f}" for r in late)
    limit = late[0]["config"]["limit_ms"]
    bad = [r for r in rows if r["system"] == "network_sim" and matches(r, "proxy_reliable", profile=profile)]
    verdict = (
        "**UNRELIABLE**: a proxy wrote chunks later than that, so this profile's times hold the machine's delays"
        if any(not r["value"] for r in bad)
        else "within it: the link kept the profile's timing"
    )
    return f"The proxies' p99 lateness (ms; limit {limit:g}): {runs}; {verdict}."


def _table1_columns(rows: Rows) -> tuple[Column, ...]:
    headers = [header for *_, header in _columns(rows)]
    return (Column("stage", "{stage}"), *per(headers, "{}", "{m[#]:{fmt}}[[ ({p[#]:.1f})]]"))


# -- the renderers, perceived latency, crossovers -----------------------------------------------------------
def _renderer_where(rows: Rows) -> list[tuple[str, dict[str, Any], str]]:
    where = [(GIGAN, {"profile": "none"}, "GIGAN")]
    return where + [
        (CLOUD, {"profile": p, "cache": c}, f"cloud {c}, `{p}`")
        for p in profiles_of(with_renderer(rows))
        for c in ("hit", "miss")
    ]


def renderer_ratios(raw: Rows) -> list[dict[str, Any]]:
    """Each raster stage's and each total's median with gl over with mitsuba, per column (same run)."""
    ratios = [r for r in with_renderer(raw) if r["stat"] == "renderer_ratio"]
    out = []
    for metric, label in RENDERER_ROWS:
        values = [lookup(ratios, s, metric, "renderer_ratio", **config) for s, config, _ in _renderer_where(raw)]
        out += [{"stage": label, "v": values}] if any(v is not None for v in values) else []
    return out


def perceived(raw: Rows) -> list[dict[str, Any]]:
    """The plain and the prefetching cloud client on the prebaked store, per profile and renderer."""
    rows, out = with_renderer(raw), []
    for profile in profiles_of(rows):
        for renderer in renderers_of(rows):
            for system in (CLOUD, CLOUD_PREFETCH):
                where = {"profile": profile, "renderer": renderer, "store": "prebaked"}
                p50 = lookup(rows, system, "perceived", "median", **where)
                if p50 is None:
                    continue
                shown = lookup(rows, system, "in_tolerance", "value", **where)
                out.append(
                    where
                    | {
                        "client": "prefetch" if system == CLOUD_PREFETCH else "plain",
                        "p50": p50,
                        "p95": lookup(rows, system, "perceived", "p95", **where),
                        "shown": shown and 100 * shown,
                        "requests": lookup(rows, system, "requests", "value", **where),
                        "ssim": lookup(rows, system, "ssim", "mean", **where),
                    }
                )
    return out


def _perceived_notes(raw: Rows) -> str:
    rows = with_renderer(raw)
    k = next((r["config"].get("k") for r in rows if r["system"] == GIGAN), None)
    return "\n\n".join(
        f"GIGAN ({renderer}) shows a map of the frame's own view every k = {k} frames, its Table 1 total "
        + fill("({v:.0f} ms)", {"v": lookup(rows, GIGAN, "total", "median", profile="none", renderer=renderer)})
        + " after that frame's camera move; the frames between warp it."
        for renderer in unique(r["renderer"] for r in perceived(raw))
    )


def crossovers(raw: Rows) -> list[dict[str, Any]]:
    """Each crossover RTT with its interval (``interval``: the text after the value, :func:`gicore.intervals.suffix`;
    its samples: every profile's maps of the cache state, and GIGAN's)."""
    rows, out = with_renderer(raw), []
    for row in (r for r in rows if matches(r, "crossover_rtt", "model")):
        r, v = flat(row), row["value"]
        where = {"cache": r.get("cache"), "renderer": r["renderer"]}
        cloud = sum(x["value"] for x in rows if x["system"] == CLOUD and matches(x, "total", "n", **where))
        counts = (cloud, lookup(rows, GIGAN, "total", "n", profile="none", renderer=r["renderer"]))
        interval = recorded(rows, row["system"], "crossover_rtt", **row["config"])
        extra = suffix(interval, too_few(rows, "crossover_rtt", counts), ".0f")
        value = "none up to a minute" if math.isinf(v) else f"{v:.0f}"
        shown = f"0{extra} (GIGAN is faster at any RTT)" if v == 0 else value + extra
        rate = r.get("rate_mbit")
        out.append(r | {"shown": shown, "interval": extra, "rate": "unlimited" if rate is None else f"{rate:g} Mbit/s"})
    return out


# -- the README's Table 1 in short ------------------------------------------------------------------------------
def short(raw: Rows) -> list[dict[str, Any]]:
    """One line per network profile and renderer: totals, the ratios (with their intervals,
    :func:`gicore.intervals.cell`) and mean SSIM of each system."""
    rows, out = with_renderer(raw), []
    rtt = {r["config"]["profile"]: r["config"].get("rtt_ms") for r in rows if matches(r, "total_ratio")}
    for profile, rtt_ms in rtt.items():
        for renderer in renderers_of(rows):
            at = {"profile": profile, "renderer": renderer}
            row = at | {
                "rtt": rtt_ms,
                "gigan": lookup(rows, GIGAN, "total", "median", profile="none", renderer=renderer),
                "gigan_n": lookup(rows, GIGAN, "total", "n", profile="none", renderer=renderer),
            }
            for cache in ("hit", "miss"):
                row[cache] = lookup(rows, CLOUD, "total", "median", cache=cache, **at)
                counts = (lookup(rows, CLOUD, "total", "n", cache=cache, **at), row["gigan_n"])
                ratio = cell(rows, f"{CLOUD}/{GIGAN}", "total_ratio", "median", counts, ".2f", 1.0, cache=cache, **at)
                row[f"{cache}_ratio"] = ratio
            row["ssim"] = lookup(rows, GIGAN, "ssim", "mean", profile="none", renderer=renderer)
            row |= {store: lookup(rows, CLOUD, "ssim", "mean", store=store, **at) for store in ("prebaked", "cold")}
            out.append(row)
    return out


def _short_caption(raw: Rows) -> str:
    rows = with_renderer(raw)
    c = next(r["config"] for r in rows if r["metric"] == "total_ratio")
    return (
        f"{rows[0]['scene']}, {c.get('resolution')}², {c.get('frames')} frames, GI period k = {c.get('k')}, "
        f"{c.get('spp')} spp + OIDN on the server, {c.get('codec')} maps; the clients' raster passes on "
        f"{' and on '.join(renderers_of(rows))}{_pacing(c)}; medians in ms."
    )


def _pacing(config: dict[str, Any]) -> str:
    """How the run paced both clients' frames (nothing for runs from before it was recorded)."""
    if "frame_rate" not in config:
        return ""
    rate = config["frame_rate"]
    return f", both paced at {rate:g} frames/s" if rate else ", both unpaced"


def _short_notes(raw: Rows) -> str:
    """GIGAN's stages per renderer, the renderers' ratios, the crossover RTTs."""
    rows = with_renderer(raw)
    lines = []
    for renderer in renderers_of(rows):
        stages = [
            (label, lookup(rows, GIGAN, m, "median", profile="none", renderer=renderer)) for m, label in GIGAN_LABELS
        ]
        total = fill("{v:.1f}", {"v": lookup(rows, GIGAN, "total", "median", profile="none", renderer=renderer)})
        lines.append(
            f"GIGAN's total on {renderer} {total} ms = "
            + " + ".join(f"{label} {v:.1f}" for label, v in stages if v is not None)
            + "."
        )
    ratio = [(label, lookup(rows, GIGAN, m, "renderer_ratio", profile="none")) for m, label in RENDERER_ROWS[::-1]]
    if any(v is not None for _, v in ratio):
        shown = ", ".join(f"{label} {v:.2f}" for label, v in ratio if v is not None)
        lines.append(f"{RENDERER_RATIO[0]} / {RENDERER_RATIO[1]} in the same run, GIGAN: {shown}.")
    crossings = []
    for r in crossovers(raw):
        at = (
            "at any RTT"
            if r["value"] == 0
            else "at no RTT up to a minute"
            if math.isinf(r["value"])
            else f"beyond an RTT of {r['value']:.0f} ms"
        )
        crossings.append(f"a cloud {r.get('cache')} {at}{r['interval']} ({r['renderer']})")
    if crossings:
        lines.append(
            "Crossover (the link model with the measured stages): GIGAN's median total beats "
            + "; ".join(crossings)
            + "."
        )
    intervals = legend(rows, "total_ratio", "each system's maps")
    intervals += " No clear winner: the ratio's interval holds 1." if intervals else ""
    return "\n".join(line for line in (*lines, intervals, what_ran(raw)) if line)


# -- figures ---------------------------------------------------------------------------------------------------
def stage_bars(raw: Rows) -> list[dict[str, Any]]:
    """Each system's stage medians per profile and renderer (GIGAN's once per renderer: it needs no network)."""
    rows, out = with_renderer(raw), []
    cloud_stages = tuple(s for s in REQUEST_STAGES if s not in TRANSMISSION_PARTS)
    for r in renderers_of(rows):
        bars = [(f"GIGAN, {r}", GIGAN, {"profile": "none", "renderer": r}, MAP_STAGES)]
        bars += [
            (f"cloud {c}, {p}, {r}", CLOUD, {"profile": p, "cache": c, "renderer": r}, cloud_stages)
            for p in profiles_of(rows)
            for c in ("hit", "miss")
        ]
        for label, system, where, stages in bars:
            total = lookup(rows, system, "total", "median", **where)
            values = [(s, lookup(rows, system, s, "median", **where)) for s in stages] if total is not None else []
            out += [{"bar": label, "stage": s, "value": v, "total": total} for s, v in values if v is not None]
    return out


def ratio_points(raw: Rows) -> list[dict[str, Any]]:
    """The ratio of totals against RTT: the link model's curve, and the measured profiles (drawn apart)."""
    rows = with_renderer(raw)
    model = [
        flat(r) | {"name": f"{r['config']['cache']}, {r['config']['renderer']}"}
        for r in rows
        if matches(r, "ratio_model")
    ]
    measured = [
        flat(r) | {"name": f"{r['config']['cache']}, {r['config']['renderer']}", "measured": True}
        for r in rows
        if matches(r, "total_ratio", "median")
    ]
    return model + measured


def _ssim_points(raw: Rows) -> list[dict[str, Any]]:
    return [flat(r) for r in with_renderer(raw) if matches(r, "ssim", "frame")]


TABLE1 = Table(
    table1,
    _table1_columns,
    title=lambda rows: f"Table 1: interaction latency, {rows[0]['scene']} (ms: median, p95 in brackets)",
    group="profile `{profile}`[[ (RTT {rtt:g} ms)]]",
    group_note="{note}",
    notes=what_ran,
    where="dashboard",
)
RENDERERS = Table(
    renderer_ratios,
    lambda rows: (Column("stage", "{stage}"), *per([label for *_, label in _renderer_where(rows)], "{}", "{v[#]:.2f}")),
    title=f"renderers side by side: median with {RENDERER_RATIO[0]} / median with {RENDERER_RATIO[1]} (same run)",
    where="dashboard",
)
SHORT = Table(
    short,
    (
        Column("profile (RTT)", "`{profile}` ({rtt:g} ms)"),
        Column("renderer", "{renderer}"),
        Column("GIGAN", "{gigan:.1f}"),
        Column("cloud hit", "{hit:.1f}"),
        Column("cloud miss", "{miss:.1f}"),
        Column("cloud / GIGAN: hit / miss", "{hit_ratio} / {miss_ratio}"),
        Column("mean SSIM vs GT: GIGAN / prebaked / cold", "{ssim:.3f} / {prebaked:.3f} / {cold:.3f}"),
    ),
    caption=_short_caption,
    notes=_short_notes,
    where="readme",
)
PERCEIVED = Table(
    perceived,
    (
        Column("profile", "`{profile}`"),
        Column("renderer", "{renderer}"),
        Column("client", "{client}"),
        Column("perceived median (p95) ms", "{p50:.0f} ({p95:.0f})"),
        Column("frames within tolerance", "{shown:.0f} %"),
        Column("requests", "{requests:.0f}"),
        Column("mean SSIM", "{ssim:.3f}"),
    ),
    title="perceived latency on the prebaked store: from a camera move to a frame showing a map within tolerance",
    notes=_perceived_notes,
)
CROSSOVERS = Table(
    crossovers,
    (
        Column("renderer", "{renderer}"),
        Column("cache", "{cache}"),
        Column("crossover RTT (ms)", "{shown}"),
        Column("link rate", "{rate}"),
    ),
    title="crossover: the RTT beyond which GIGAN's median total beats cloud baking's (link model, measured stages)",
    notes=lambda rows: legend(rows, "crossover_rtt", "the cloud requests, each with its stages, and GIGAN's maps"),
    where="dashboard",
)
PARTS = (
    TABLE1,
    RENDERERS,
    SHORT,
    PERCEIVED,
    CROSSOVERS,
    Figure(
        "latency_ratio_rtt",
        (
            Chart(
                ratio_points,
                "rtt_ms",
                series="{name}",
                ylog=True,
                hollow="measured",
                label="[[{profile}]]",
                xlabel="round-trip time [ms] (hollow: measured profiles)",
                ylabel="cloud baking total / GIGAN total (same renderer)",
                title="Above 1: GIGAN is faster",
                tip="{name}, RTT {rtt_ms:g} ms[[, profile {profile}]]: ratio {value:.3g}",
            ),
        ),
        caption="Above 1: GIGAN's interaction latency is lower (each system on the same renderer).",
    ),
    Figure(
        "latency_stages",
        (
            Chart(
                stage_bars,
                "bar",
                series="{stage}",
                kind="stack",
                ylabel="median stage time [ms]",
                title="Interaction latency by stage (Table 1)",
                tip="{bar}, {stage}: {value:.1f} ms (total {total:.0f} ms)",
            ),
        ),
    ),
    Figure(
        "latency_ssim",
        (
            Chart(
                _ssim_points,
                "frame",
                series="{profile}: {system}, {store} store, {renderer}",
                xlabel="frame",
                ylabel="SSIM vs path-traced GT",
                title="SSIM along the path (stale maps while requests are in flight)",
            ),
        ),
    ),
)
