"""What ``bench web`` shows (:mod:`gicore.present`): the screenshot; per system and profile its frame times, the
frames drawn while a map was made, map age and perceived latency; each stage's median; GIGAN's checks (met or
not); the inference timing and the parity checks."""

from __future__ import annotations

from typing import Any

from gicore.present.declarations import Column, Image, Rows, Table, fill, first, matches, per, unique
from web3d.parity import PORT_BUFFERS
from web3d.replay_stats import CLOUD, GIGAN

SCREENSHOT = "web_screenshot.png"
STAGES = ("gi_render", "inference", "transmission", "server", "decode", "di", "warp", "blend", "total")
LABELS = {GIGAN: "GIGAN", CLOUD: "cloud baking"}


def _runs(rows: Rows) -> list[tuple[str, str]]:
    """(system, profile) of every replay's rows, in order."""
    return unique((r["system"], r["config"]["profile"]) for r in rows if matches(r, "frame_ms", "median", phase="all"))


def replays(rows: Rows) -> list[dict[str, Any]]:
    """One row per system and profile."""
    out = []
    for system, profile in _runs(rows):
        mine = [r for r in rows if r["system"] == system]

        def v(metric: str, stat: str = "value", **extra: Any) -> float | None:
            return first(mine, metric, stat, profile=profile, **extra)  # noqa: B023 -- used within this iteration

        row = {"system": LABELS[system], "profile": profile, "maps": v("total", "n"), "hits": v("hit_rate")}
        row |= {"frame": v("frame_ms", "median", phase="all"), "frame95": v("frame_ms", "p95", phase="all")}
        row |= {f"{p}95": v("frame_ms", "p95", phase=p) for p in ("idle", "in_flight", "landing")}
        row |= {"during": v("frames_during_map", "min"), "during_median": v("frames_during_map", "median")}
        row |= {"age": v("map_age_ms", "median"), "age95": v("map_age_ms", "p95")}
        row |= {"age_f": v("map_age_frames", "median")}
        row |= {"perceived": v("perceived_ms", "median"), "perceived95": v("perceived_ms", "p95")}
        maps_kib, link = v("map_bytes"), v("link_bytes_down")
        row |= {"maps_kib": maps_kib and maps_kib / 1024, "link_kib": link and link / 1024}
        out.append(row | {"censored": v("censored"), "tolerance": v("in_tolerance")})
    return out


def stage_rows(rows: Rows) -> list[dict[str, Any]]:
    """Each stage's median per system and profile (a list in :func:`stage_columns`' order)."""
    runs = _runs(rows)
    out = []
    for stage in STAGES:
        values = [first([r for r in rows if r["system"] == s], stage, "median", profile=p) for s, p in runs]
        if any(v is not None for v in values):
            out.append({"stage": "**total**" if stage == "total" else stage, "v": values})
    return out


def stage_columns(rows: Rows) -> tuple[Column, ...]:
    names = [f"{LABELS[s]} ({p})" for s, p in _runs(rows)]
    return (Column("stage (median ms)", "{stage}"), *per(names, "{}", "{v[#]:.1f}"))


def checks(rows: Rows) -> list[dict[str, Any]]:
    out = []
    for r in (r for r in rows if r["stat"] == "target_met"):
        met = "not measured" if r["value"] != r["value"] else "met" if r["value"] else "NOT MET"
        out.append(r["config"] | {"met": met})
    return out


def summary(rows: Rows) -> str:
    """The run's settings, the inference comparison and the parity checks."""
    values = {r["metric"]: r["value"] for r in rows if r["stat"] == "value" and "profile" not in r["config"]}
    runs = {r["config"]["runtime"]: r["value"] for r in rows if matches(r, "inference_run", "median")}
    c = rows[0]["config"]
    ports = ", ".join(f"{b} {{port_{b}_rel_diff:.1e}}" for b in PORT_BUFFERS)
    return fill(
        f"Path: {c['path']} ({c['frames']} frames), k = {c['every']}, {c['store']} store, {c['codec']}, {c['spp']} "
        f"spp. WebGL: {c['webgl']}; onnxruntime-web {c['backend']}, {c['threads']} threads.\n\n"
        "session.run on the same input: browser {web:.1f} ms, Python onnxruntime {python:.1f} ms "
        "(**{inference_ratio:.2f}x**). Parity with GIModel.predict on the page's G-buffers, tone-mapped: max |Δ| = "
        "{parity_max_abs_diff:.2e}, mean {parity_mean_abs_diff:.2e}. The page's DI + G-buffers against GLRenderer's "
        "at the same GI camera: coverage differs on {port_coverage_mismatch:.1e} of the pixels; mean |Δ| relative to "
        f"the mean: {ports}.",
        values | {"web": runs.get("onnxruntime-web"), "python": runs.get("onnxruntime-python")},
    )


PARTS = (
    Image(
        SCREENSHOT,
        "Both panes and their HUDs as the last replay drew its last path frame: each shows its latest map (a few "
        "frames old) warped to that view",
        where="dashboard",
    ),
    Table(
        replays,
        (
            Column("system", "{system}"),
            Column("profile", "{profile}"),
            Column("frame ms: median (p95)", "{frame:.0f} ({frame95:.0f})"),
            Column("p95: idle / map in flight / landing", "{idle95:.0f} / {in_flight95:.0f} / {landing95:.0f}"),
            Column("frames while a map was made: min (median)", "{during:.0f} ({during_median:.0f})"),
            Column("map age: median ms (p95), frames", "{age:.0f} ({age95:.0f}), {age_f:.0f}"),
            Column("perceived ms: median (p95)", "{perceived:.0f} ({perceived95:.0f})"),
            Column("censored", "{censored:.0f}"),
            Column("maps", "{maps:.0f}[[ ({hits:.0%} hits)]]"),
            Column("KiB of maps (through its proxy), whole run", "{maps_kib:.0f} ({link_kib:.0f})"),
        ),
        caption="Per replay of the path (one per network profile, the same page): a pane's frame time, and its p95 "
        "on frames drawn with no map in flight, while one was being made (its request's own G-buffer pass and "
        "encoding left out), and as one landed; frames drawn while each map was made; the age of the map each frame "
        "showed; perceived latency, from a frame that moved the camera to the first frame showing a map within the "
        "GI tree's tolerance of its view (censored: none did).",
        scroll=True,
    ),
    Table(
        stage_rows,
        stage_columns,
        caption="Each stage's median over the replay's maps; di: the local render of the frame that first shows "
        "the map, counted for both systems.",
        notes=summary,
    ),  # fmt: skip
    Table(
        checks,
        (
            Column("check (GIGAN pane)", "{target}"),
            Column("profile", "{profile}"),
            Column("measured (bound)", "{measured:.1f} ({bound:.1f})"),
            Column("met", "{met}"),
        ),
    ),
)
