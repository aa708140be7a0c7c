"""What `bench storage` shows of its CSV: Table 2 (per resolution and composition, the GI tree per scene and
codec against the model), its short form for the README, the codecs, the growth law (the tree after sessions,
the sessions until it passes the model or the paper's figure, the paper's accounting decomposed) and the
figures (the tree against the model, its growth, the tolerance knob)."""

from __future__ import annotations

from typing import Any

from bench.storage_config import PAPER_TABLE2_GB, RAW_CODEC
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, flat, matches, mib, per, unique

COMPOSED = {"blend": "GI + depth", "residual": "GI + DI + depth (residual composition)"}


def _model(rows: Rows) -> dict[str, float]:
    return {r["config"]["precision"]: r["value"] for r in rows if r["metric"] == "client_bytes"}


def _index(rows: Rows, metric: str, stat: str, *keys: str) -> dict[tuple, float]:
    """``{(scene, config[key], ...): value}`` of the rows of ``metric`` with ``stat``."""
    return {(r["scene"], *(r["config"].get(k) for k in keys)): r["value"] for r in rows if matches(r, metric, stat)}


def _gb(n: float) -> str:
    """Bytes as GB (10⁹ B, the paper's unit) with three significant digits."""
    return f"{n / 1e9:.3g}"


# -- Table 2 -------------------------------------------------------------------------------------------------
def _codecs(rows: Rows) -> list[str]:
    return unique(r["config"]["codec"] for r in rows if matches(r, "gi_tree_bytes", "estimate"))


def table2(rows: Rows) -> list[dict[str, Any]]:
    """Per resolution, composition and scene: the GI tree per codec (± its 95 % interval when extrapolated), and
    against the fp16 model."""
    keys = ("resolution", "codec", "composition")
    trees, ci = _index(rows, "gi_tree_bytes", "estimate", *keys), _index(rows, "gi_tree_bytes", "ci95", *keys)
    fp16 = _model(rows).get("fp16")
    out = []
    for resolution in unique(k[1] for k in trees):
        for composition in COMPOSED:
            for r in (r for r in rows if r["metric"] == "entries"):
                at = [(r["scene"], resolution, codec, composition) for codec in _codecs(rows)]
                tree = [trees.get(k) for k in at]
                out.append(
                    {
                        "resolution": resolution,
                        "what": COMPOSED[composition],
                        "scene": r["scene"],
                        "frames": r["config"]["frames"],
                        "entries": int(r["value"]),
                        "tree": tree,
                        "ci": [ci.get(k) or None for k in at],
                        "ratio": [t and fp16 and t / fp16 for t in tree],
                    }
                )
    return out


def _table2_caption(rows: Rows) -> str:
    model, paper = _model(rows), PAPER_TABLE2_GB
    return (
        f"GIGAN client storage (measured: model files, the same for every scene): fp32 {mib(model.get('fp32', 0))} "
        f"MiB, fp16 {mib(model.get('fp16', 0))} MiB. Paper: GI tree {paper['lung']} / {paper['digestive']} / "
        f"{paper['vessels']} GB (lung / digestive / vessels) vs {paper['model']} GB for the model.\n\n"
        "Entries: counted with the GI tree's lookup rule along the fly-through. MiB: entries x mean payload bytes of "
        "the rendered sample, ± its 95 % interval (extrapolated), or the sum when every entry was rendered "
        "(measured). (xN): GI tree / fp16 model."
    )


def short(rows: Rows) -> list[dict[str, Any]]:
    """Each scene's GI tree per resolution and codec (blend composition), against the fp16 model."""
    trees = _index(rows, "gi_tree_bytes", "estimate", "resolution", "codec", "composition")
    fp16 = _model(rows).get("fp16")
    columns = unique((k[1], k[2]) for k in trees if k[3] == "blend")
    out = []
    for r in (r for r in rows if r["metric"] == "entries"):
        tree = [trees.get((r["scene"], res, codec, "blend")) for res, codec in columns]
        row = {"scene": r["scene"], "frames": r["config"].get("frames"), "entries": r["value"], "tree": tree}
        out.append(row | {"ratio": [t and fp16 and t / fp16 for t in tree]})
    return out


def _short_columns(rows: Rows) -> tuple[Column, ...]:
    trees = _index(rows, "gi_tree_bytes", "estimate", "resolution", "codec", "composition")
    headers = [f"{codec} {res}²" for res, codec in unique((k[1], k[2]) for k in trees if k[3] == "blend")]
    fixed = (Column("scene", "{scene}"), Column("frames", "{frames}"), Column("entries", "{entries:.0f}"))
    return fixed + per(headers, "{}", "{tree[#]:mib}[[ (×{ratio[#]:.2g})]]")


def _short_caption(rows: Rows) -> str:
    model = _model(rows)
    return (
        "GIGAN's model (the same for every scene): "
        + ", ".join(f"{p} {mib(v)} MiB" for p, v in model.items())
        + ". The GI tree of each scene's fly-through (GI + depth, blend composition): entries counted with the GI "
        "tree's lookup rule, MiB = entries × mean payload"
        + (", × = against the fp16 model" if model.get("fp16") else "")
        + "."
    )


def codecs(rows: Rows) -> list[dict[str, Any]]:
    """Per codec and resolution, means over the scenes: GI and depth bytes, encode and decode ms (medians), the
    tone-mapped error of the decoded GI map."""
    columns = {
        "bytes": _index(rows, "section_bytes", "mean", "codec", "resolution", "section"),
        "encode": _index(rows, "encode_ms", "median", "codec", "resolution"),
        "decode": _index(rows, "decode_ms", "median", "codec", "resolution"),
        "rmse": _index(rows, "rmse", "mean", "codec", "resolution"),
        "ssim": _index(rows, "ssim", "mean", "codec", "resolution"),
    }

    def mean(column: str, *key: Any) -> float | None:
        vs = [v for k, v in columns[column].items() if k[1:] == key]
        return sum(vs) / len(vs) if vs else None

    out = []
    for codec, res in unique(k[1:3] for k in columns["rmse"]):
        row = {"codec": codec, "resolution": res, "gi": mean("bytes", codec, res, "gi")}
        row["depth"] = mean("bytes", codec, res, "depth")
        out.append(row | {m: mean(m, codec, res) for m in ("encode", "decode", "rmse", "ssim")})
    return out


# -- the growth law --------------------------------------------------------------------------------------------
def _sessions_cell(row: dict | None) -> str:
    """A session count: measured, or ``> N`` when not reached within the N sessions run."""
    if row is None:
        return "—"
    return f"{row['value']:.0f}" if row["stat"] == "measured" else f"> {row['value']:.0f}"


def _growth(rows: Rows) -> dict[str, Any]:
    """What the growth tables share: the store tolerance's entries per (scene, users, sessions), the sessions
    run, the marks shown, the resolution and codec the saturation level is priced at."""
    entries = [r for r in rows if r["metric"] == "growth_entries"]
    store = {
        (r["scene"], r["config"]["users"], r["config"]["sessions"]): r["value"]
        for r in entries
        if r["config"]["tolerance"] == "store"
    }
    n = max(k[2] for k in store)
    per_entry = _index(rows, "growth_entry_bytes", "mean", "codec", "resolution")
    # the tree's bytes once saturated, for the first codec at the largest resolution (the paper's 512²)
    level = next((k[1:] for k in sorted(per_entry, key=lambda k: -k[2]) if k[1] != RAW_CODEC), (RAW_CODEC, 0))
    return {
        "entries": entries,
        "store": store,
        "n": n,
        "marks": sorted({1, min(10, n), n}),
        "per_entry": per_entry,
        "level": level,
    }


def growth(rows: Rows) -> list[dict[str, Any]]:
    """Per scene and user count: entries after the marked sessions, the last session's, saturation, the saturation
    level, how full the tree is, and the saturated tree's GB."""
    if not any(r["metric"] == "growth_entries" for r in rows):
        return []
    g = _growth(rows)
    sat = {
        (r["scene"], r["config"]["users"]): r
        for r in rows
        if r["metric"] == "saturation_sessions" and r["config"]["tolerance"] == "store"
    }
    cap = {r["scene"]: r for r in rows if r["metric"] == "capacity_entries"}
    out = []
    for scene in unique(r["scene"] for r in g["entries"]):
        for users in sorted({k[1] for k in g["store"]}):
            count, level = g["store"][(scene, users, g["n"])], cap.get(scene)
            row = {"scene": scene, "users": users, "at": [g["store"][(scene, users, m)] for m in g["marks"]]}
            row |= {
                "last": count - g["store"].get((scene, users, g["n"] - 1), 0),
                "sat": _sessions_cell(sat.get((scene, users))),
            }
            if level:
                c = level["config"]
                row["level"] = (
                    f"{'≥ ' if c['last_tenth_miss_rate'] > 0 else ''}{level['value']:,.0f} "
                    f"({c['per_cell']:,} × {c['light_cells']} cells)"
                )
                size = g["per_entry"].get((scene, *g["level"]))
                row |= {"filled": count / level["value"], "gb": _gb(level["value"] * size) if size else None}
            out.append(row)
    return out


def _growth_columns(rows: Rows) -> tuple[Column, ...]:
    g = _growth(rows)
    n, (codec, res) = g["n"], g["level"]
    return (
        Column("scene", "{scene}"),
        Column("users", "{users}"),
        *per(g["marks"], "entries @{}", "{at[#]:,.0f}"),
        Column(f"added by session {n}", "{last:,.0f}"),
        Column("saturated after", "{sat}"),
        Column("saturation level (est.)", "{level}"),
        Column(f"filled at {n}", "{filled:.0%}"),
        Column(f"at saturation level: {codec} {res}², GB", "{gb}"),
    )


def _growth_title(rows: Rows) -> str:
    c = next(r["config"] for r in rows if r["metric"] == "growth_entries")
    return (
        f"Growth law: the GI tree under user sessions ({c['session_frames']} frames each, Δp "
        f"{c['tolerance_position']:g}, Δθ {c['tolerance_angle_deg']:g}°)"
    )


def _growth_caption(rows: Rows) -> str:
    rate = next(r["config"]["saturation_rate"] for r in rows if r["metric"] == "saturation_sessions")
    return (
        "Sessions (`gicore.sessions`): seeded fly-throughs and orbits over each scene's navigable space at varied "
        "speeds, each starting at its own light state; users take turns, each with a habit. Entries: counted with the "
        "GI tree's own lookup rule (`simulate_fill`). Saturated: the session after which no session adds more than "
        f"{rate:.0%} of its frames; `> N`: not within the N sessions run. Saturation level: the lookup rule over "
        "uniform samples of the navigable space in one light cell × the light cells the light reaches (a lower "
        "estimate while samples still add entries)."
    )


def _crossings(rows: Rows) -> tuple[list[dict], list[tuple[str, int]], int]:
    widest = max((r["config"]["users"] for r in rows if r["metric"] == "growth_entries"), default=0)
    cross = [r for r in rows if r["metric"] == "crossover_sessions" and r["config"]["users"] == widest]
    return cross, unique((r["config"]["codec"], r["config"]["resolution"]) for r in cross), widest


def crossings(rows: Rows) -> list[dict[str, Any]]:
    """Per scene, per codec and resolution: the sessions until the tree passes the fp16 model / the paper's figure,
    and the bytes per entry."""
    cross, columns, _ = _crossings(rows)
    index = {(r["scene"], r["config"]["codec"], r["config"]["resolution"], r["config"]["against"]): r for r in cross}
    per_entry = _index(rows, "growth_entry_bytes", "mean", "codec", "resolution")
    return (
        [
            {
                "scene": scene,
                "cells": [
                    f"{_sessions_cell(index.get((scene, c, res, 'model_fp16')))} / "
                    f"{_sessions_cell(index.get((scene, c, res, 'paper_gb')))} "
                    f"({per_entry.get((scene, c, res), float('nan')):,.0f} B)"
                    for c, res in columns
                ],
            }
            for scene in unique(r["scene"] for r in rows if r["metric"] == "growth_entries")
        ]
        if columns
        else []
    )


def _crossings_title(rows: Rows) -> str:
    _, _, widest = _crossings(rows)
    return (
        f"Sessions until the tree passes the fp16 model ({mib(_model(rows).get('fp16', 0))} MiB) / reaches the "
        f"paper's GB figure for the scene ({widest} users)"
    )


def _crossings_caption(rows: Rows) -> str:
    n = int(next(r["value"] for r in rows if matches(r, "growth_entry_bytes", "n")))
    return (
        f"Bytes = counted entries × mean bytes per entry (in brackets), measured on {n} map{'s' if n != 1 else ''} per "
        "scene and resolution baked at entries spread over the session tree (not every entry is baked). Codecs: the "
        "stored payload (GI + depth + header) at the store's tolerance; `rgb8`: the paper's accounting (Δ 0, one "
        "uncompressed RGB8 GI map per frame). Paper: lung 1.15, digestive 2.38, vessels 3.36 GB."
    )


def accounting(rows: Rows) -> list[dict[str, Any]]:
    """Per scene: the paper's figure, its accounting along the fly-through, the store's tolerance, each codec."""
    counts = _index(rows, "accounting_entries", "value", "step", "codec")
    value = _index(rows, "accounting_bytes", "estimate", "step", "codec")
    out = []
    for scene in unique(r["scene"] for r in rows if r["metric"] == "accounting_bytes"):
        paper, tol = value[(scene, "paper", "rgb8 per frame")], value[(scene, "tolerance", RAW_CODEC)]
        raw = _raw(rows)
        row = {
            "scene": scene,
            "figure": PAPER_TABLE2_GB.get(scene.split("_")[0]),
            "p_gb": _gb(paper),
            "p_entries": counts[(scene, "paper", "rgb8 per frame")],
            "p_dev": paper / raw - 1,
            "t_entries": counts[(scene, "tolerance", RAW_CODEC)],
            "t_gb": _gb(tol),
            "t_ratio": tol / paper,
        }
        payload = [value[(scene, "payload", c)] for c in _payload_codecs(rows)]
        out.append(row | {"c_gb": [_gb(v) for v in payload], "c_ratio": [v / paper for v in payload]})
    return out


def _payload_codecs(rows: Rows) -> list[str]:
    acc = [r for r in rows if r["metric"] == "accounting_bytes"]
    return [r["config"]["codec"] for r in acc if r["config"]["step"] == "payload" and r["scene"] == acc[0]["scene"]]


def _raw(rows: Rows) -> float:
    c = next(r["config"] for r in rows if r["metric"] == "accounting_bytes")
    return c["frames"] * c["resolution"] ** 2 * 3


def _accounting_columns(rows: Rows) -> tuple[Column, ...]:
    c = next(r["config"] for r in rows if r["metric"] == "accounting_bytes")
    return (
        Column("scene", "{scene}"),
        Column("paper's figure", "{figure} GB"),
        Column(
            f"paper accounting: entries, GB (vs {c['frames']} × {c['resolution']}² × 3)",
            "{p_entries:,.0f}, {p_gb} ({p_dev:+.1%})",
        ),
        Column("store's tolerance: entries, GB", "{t_entries:,.0f}, {t_gb} (×{t_ratio:.3g})"),
        *per([f"{codec}: GB" for codec in _payload_codecs(rows)], "{}", "{c_gb[#]} (×{c_ratio[#]:.2g})"),
    )


def _accounting_title(rows: Rows) -> str:
    c = next(r["config"] for r in rows if r["metric"] == "accounting_bytes")
    return f"The paper's accounting, decomposed ({c['frames']}-frame fly-through, {c['resolution']}², GB = 10⁹ B)"


def _accounting_caption(rows: Rows) -> str:
    c = next(r["config"] for r in rows if r["metric"] == "accounting_bytes")
    return (
        f"Paper: one uncompressed RGB8 map per frame (the lookup rule at Δ 0 stores every frame); {c['frames']} × "
        f"{c['resolution']}² × 3 B = {_gb(_raw(rows))} GB (1500 frames at 512²: 1.18 GB; the paper's lung figure: "
        "1.15 GB). Then the store's tolerance (the same maps, fewer of them), then each codec's stored payload (GI + "
        "depth). Bytes per entry measured on the growth law's baked maps."
    )


# -- figures ---------------------------------------------------------------------------------------------------
def tree_bars(rows: Rows) -> list[dict[str, Any]]:
    """The GI tree after the fly-through (first resolution, GI + depth) per scene and codec, and the fp16 model."""
    trees = [flat(r) for r in rows if matches(r, "gi_tree_bytes", "estimate", composition="blend")]
    mine = [
        r | {"MiB": r["value"] / 2**20, "name": r["codec"]} for r in trees if r["resolution"] == trees[0]["resolution"]
    ]
    fp16 = _model(rows).get("fp16")
    return mine + (
        [{"scene": s, "MiB": fp16 / 2**20, "name": "GIGAN model fp16"} for s in unique(r["scene"] for r in mine)]
        if fp16
        else []
    )


def along_path(rows: Rows) -> list[dict[str, Any]]:
    """The tree's entries along the fly-through, per scene."""
    return [flat(r) for r in rows if matches(r, "entries_at")]


def knob(metric: str, stat: str | None = None) -> Any:
    """The tolerance knob's ``metric`` per setting."""
    return lambda rows: [
        flat(r)
        | {
            "setting": f"Δp {r['config']['knob_position']:g} / Δθ {r['config']['knob_angle_deg']:g}°",
            "name": r["metric"].removeprefix("knob_"),
        }
        for r in rows
        if matches(r, metric, stat)
    ]


def growth_entries(rows: Rows) -> list[dict[str, Any]]:
    return [
        flat(r)
        | {
            "name": f"{r['scene']}, {r['config']['users']} users"
            + (", Δ 0" if r["config"]["tolerance"] == "paper" else "")
        }
        for r in rows
        if matches(r, "growth_entries")
    ]


def growth_bytes(rows: Rows) -> list[dict[str, Any]]:
    """The tree's bytes after each session at the largest resolution for the most users, and the fp16 model."""
    mine = [flat(r) for r in rows if matches(r, "growth_bytes")]
    if not mine:
        return []
    widest, res = max(r["users"] for r in mine), max(r["resolution"] for r in mine)
    out = [
        r | {"name": f"{r['scene']}: {r['codec']} {res}²"}
        for r in mine
        if (r["users"], r["resolution"]) == (widest, res)
    ]
    fp16 = _model(rows).get("fp16")
    ends = (min(r["sessions"] for r in out), max(r["sessions"] for r in out))
    return out + ([{"sessions": k, "value": fp16, "name": "GIGAN model fp16"} for k in ends] if fp16 else [])


PARTS = (
    Table(
        table2,
        lambda rows: (
            Column("scene", "{scene}"),
            Column("frames", "{frames}"),
            Column("entries", "{entries}"),
            *per(_codecs(rows), "{}", "{tree[#]:mib}[[ ± {ci[#]:mib}]][[ (x{ratio[#]:.2g})]]"),
        ),
        title="Table 2: GI-tree storage (cloud baking) vs the GIGAN model (client)",
        caption=_table2_caption,
        group="{resolution}², {what}",
        where="dashboard",
    ),
    Figure(
        "storage",
        (
            Chart(
                tree_bars,
                "scene",
                "MiB",
                "{name}",
                kind="bar",
                ylabel="MiB",
                title="GI tree after the fly-through vs the model",
            ),
            Chart(
                along_path,
                "at_frame",
                series="{scene}",
                xlabel="fly-through frames",
                ylabel="GI-tree entries (the lookup rule)",
                title="Entries along the fly-through",
            ),
        ),
    ),
    Table(short, _short_columns, caption=_short_caption, where="readme"),
    Table(
        codecs,
        (
            Column("codec", "{codec}"),
            Column("resolution", "{resolution}²"),
            Column("GI bytes", "{gi:,.0f}"),
            Column("depth bytes", "{depth:,.0f}"),
            Column("encode ms", "{encode:.1f}"),
            Column("decode ms", "{decode:.1f}"),
            Column("RMSE (tone-mapped)", "{rmse:.4f}"),
            Column("SSIM", "{ssim:.4f}"),
        ),
        title="Codecs (sampled GI maps, per map; means over the scenes)",
    ),
    Table(growth, _growth_columns, title=_growth_title, caption=_growth_caption, scroll=True),
    Table(
        crossings,
        lambda rows: (
            Column("scene", "{scene}"),
            *per([f"{c} {res}²" for c, res in _crossings(rows)[1]], "{}", "{cells[#]}"),
        ),
        title=_crossings_title,
        caption=_crossings_caption,
    ),
    Table(accounting, _accounting_columns, title=_accounting_title, caption=_accounting_caption),
    Figure(
        "storage_growth",
        (
            Chart(
                growth_entries,
                "sessions",
                series="{name}",
                ylog=True,
                xlabel="sessions",
                ylabel="GI-tree entries",
                title="Entries after each session (the GI tree's lookup rule)",
            ),
            Chart(
                growth_bytes,
                "sessions",
                series="{name}",
                xlog=True,
                ylog=True,
                xlabel="sessions",
                ylabel="GI-tree bytes",
                title="The tree's bytes against the model",
            ),
        ),
    ),
    Figure(
        "storage_tolerance",
        (
            Chart(knob("knob_entries"), "setting", series="{scene}", kind="bar", ylabel="entries (first pass)"),
            Chart(
                knob("knob_hit_rate"), "setting", series="{scene}", kind="bar", ylabel="hit rate of the perturbed pass"
            ),
            Chart(
                lambda rows: knob("knob_ssim_warped", "mean")(rows) + knob("knob_ssim_stale", "mean")(rows),
                "setting",
                series="{name}",
                kind="bar",
                ylabel="SSIM vs a render at the request",
            ),
        ),
        title="GI-tree tolerance knob (ssim_warped: the served map warped pixel-level; ssim_stale: as is)",
    ),
)
