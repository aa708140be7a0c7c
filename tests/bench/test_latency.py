"""`bench latency` (Table 1): the whole bench end to end at 64² (server, proxy, both clients as processes: the
one test of cloudbaking-client through a proxy against a server, and of both clients' CSVs end to end), and its
option checks (the link model's crossover: tests/network_sim/test_exchange.py)."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from baseline_cloudbaking.client import STAGES
from bench import latency
from bench.latency import LatencyConfig
from bench.runner import execute
from gicore.frame_rows import read_csv_rows
from gicore.results import read_rows
from tests.helpers.cli import check_user_error, run_main
from tests.helpers.cloud import passthrough_model, write_scenes

#: Stages every frame that binds a cloud map reports: the local DI (with the surface mask the warp reads), the
#: map's own stages (a miss), the pixel-level warp's, the composition.
CLOUD_FRAME_STAGES = ("di", "request", "lookup", "render", "denoise", "encode", "server_other", "transfer", "decode")
CLOUD_FRAME_STAGES += ("bind", "project", "splat", "fill", "compose")
GIGAN_FRAME_STAGES = ("di", "gi_render", "inference", "bind", "project", "depth_test", "lookup", "fill", "compose")
#: Stage medians cloud baking reports for hits and misses alike.
CLOUD_STATS = {"di", "transmission", "request", "transfer", "lookup", "server_other", "decode", "warp", "blend"}
CLOUD_STATS |= {"total", "pickup"}
#: What the bench writes besides its provenance.
FILES = {"latency.csv", "latency.md", "latency_stages.png", "latency_stages.svg", "latency_ratio_rtt.png"}
FILES |= {"latency_ssim.png"}


@pytest.mark.slow
def test_bench_latency_end_to_end(tmp_path: Path) -> None:
    scene = write_scenes(tmp_path / "scenes") / "ball_moving.json"
    cfg = LatencyConfig(scenes=(str(scene),), profiles=("rtt60",), resolution=64, frames=8, every=2, spp=4, gt_every=4,
                        model=passthrough_model(tmp_path / "model"), sweep_max_rtt_ms=200.0,
                        renderers=("gl",))  # fmt: skip  # one renderer: the two side by side are tested below
    out = tmp_path / "out"
    files = execute(latency.BENCH, cfg, out, seed=0)
    rows = read_rows(out / "latency.csv")
    [renderer] = json.loads((out / "latency.provenance.json").read_text())["settings"]["renderers"]["ran"]
    assert {r["config"].get("renderer") for r in rows if r["unit"] == "ms"} == {renderer}

    def stats(system: str, **config) -> set[str]:
        return {
            r["metric"]
            for r in rows
            if r["system"] == system
            and r["stat"] == "median"
            and all(r["config"].get(k) == v for k, v in config.items())
        }

    assert stats("gigan", profile="none") >= {"gi_render", "inference", "warp", "blend", "total", "di"}
    assert stats("cloud_baking", profile="rtt60", cache="hit") >= CLOUD_STATS | {"read"}
    assert stats("cloud_baking", profile="rtt60", cache="miss") >= CLOUD_STATS | {"render", "denoise", "encode"}

    def value(metric: str, stat: str = "median", system: str = "cloud_baking", **config) -> float:
        [v] = [
            r["value"]
            for r in rows
            if (r["system"], r["metric"], r["stat"]) == (system, metric, stat) and r["config"].items() >= config.items()
        ]
        return v

    for cache in ("hit", "miss"):  # the profile's 60 ms round trip is in every request's transmission
        assert value("transmission", "median", profile="rtt60", cache=cache) >= 59.0
        ratio = value("total_ratio", system="cloud_baking/gigan", profile="rtt60", cache=cache)
        assert ratio == pytest.approx(
            value("total", profile="rtt60", cache=cache) / value("total", system="gigan", profile="none")
        )
        assert value("crossover_rtt", "model", system="cloud_baking/gigan", cache=cache) >= 0
    assert value("total", profile="rtt60", cache="miss") > value("total", profile="rtt60", cache="hit")
    # the prefetching twin on the prebaked store: what ran and how long its views waited for a map, not Table 1's
    # stages
    twin = {r["metric"] for r in rows if r["system"] == "cloud_baking_prefetch"}
    assert twin == {"frames", "perceived", "in_tolerance", "requests", "ssim"}, twin
    check_client_runs(out / "latency_runs", renderer, frames=cfg.frames, gt_every=cfg.gt_every)
    assert value("failed_requests", "value", profile="rtt60", store="cold") == 0
    ssim = [r for r in rows if r["metric"] == "ssim" and r["stat"] == "frame"]
    assert {(r["system"], r["config"]["store"]) for r in ssim} == {
        ("gigan", "none"),
        ("cloud_baking", "prebaked"),
        ("cloud_baking", "cold"),
    }
    assert {r["config"]["frame"] for r in ssim} == {0, 4} and all(0 < r["value"] <= 1 for r in ssim)
    # each scored frame's GT was path-traced once and shared by every client run of the bench
    assert len(list((out / "latency_runs" / "gt_cache").glob("*.npz"))) == 2

    provenance = json.loads((out / "latency.provenance.json").read_text())
    assert provenance["settings"]["pinning"]["method"] in ("taskset -c", "none")
    table = (out / "latency.md").read_text()
    assert (
        "### profile `rtt60` (RTT 60 ms)" in table
        and "**total (interaction latency)**" in table
        and "crossover" in table
    )
    assert {p.name for p in files} >= FILES
    check_alone(rows, renderer)
    # the simulated network's own fidelity: each cloud run's proxy said how late it wrote its chunks
    late = {(r["config"]["store"], r["stat"]): r["value"] for r in rows if r["metric"] == "proxy_lateness"}
    assert {store for store, _ in late} == {"prebaked", "cold"}
    assert all(0 <= late[store, "p50"] <= late[store, "p99"] for store in ("prebaked", "cold"))
    reliable = [r for r in rows if r["metric"] == "proxy_reliable"]
    assert len(reliable) == 2 and all(r["config"]["limit_ms"] == 6.0 for r in reliable)  # a tenth of 60 ms
    assert "p99 lateness (ms; limit 6)" in table


def check_alone(rows: list[dict], renderer: str) -> None:
    """Every stage measured alone beside the loop: an ``alone`` and an ``inflation`` row for each of GIGAN's stages
    and each of a cloud hit's, the floors' total adding up the stages alone, the floors' ratio and the targets."""
    from bench.latency_floor import CLOUD_HIT_STAGES
    from gigan_local.client import MAP_STAGES

    def alone(system: str, stat: str, **config) -> dict[str, float]:
        return {
            r["metric"]: r["value"]
            for r in rows
            if r["system"] == system and r["stat"] == stat and r["config"].items() >= config.items()
        }

    gigan = alone("gigan", "alone", profile="none", renderer=renderer)
    assert set(gigan) == {*MAP_STAGES, "total"}
    assert gigan["total"] == pytest.approx(sum(gigan[s] for s in MAP_STAGES))
    assert set(alone("gigan", "inflation", profile="none")) == set(MAP_STAGES)
    cloud = alone("cloud_baking", "alone", profile="rtt60", cache="hit", renderer=renderer)
    assert set(cloud) >= {"request", "transfer", "decode", "di", "warp", "blend", "transmission", "total"}
    assert cloud["total"] == pytest.approx(sum(cloud[s] for s in CLOUD_HIT_STAGES if s in cloud))
    assert cloud["request"] >= 59.0  # the profile's round trip is in the request alone too
    [ratio] = [r for r in rows if r["metric"] == "total_ratio" and r["stat"] == "alone"]
    assert ratio["value"] == pytest.approx(cloud["total"] / gigan["total"])
    targets = {r["metric"] for r in rows if r["stat"] == "target_met"}
    assert targets >= {"decode_floor", "inflation", "decode_inflation"}


def check_client_runs(runs: Path, renderer: str, frames: int, gt_every: int) -> None:
    """What the client runs of the bench wrote: GIGAN's and the cloud client's frames (every stage of the frame
    binding the run's first map, a miss for the cold store's client), the SSIM and LF error of every scored frame;
    the cloud client's requests (the profile's 60 ms round trip in each one's request stage, the stages adding up
    to its total; the prebaked store answering every request of its run, the cold one missing its first: later ones
    hit only where the run had baked a map within the tolerance already) and summary; each run on the renderer it
    was asked for, with no fallback."""
    for name, stages in (
        (f"gigan_{renderer}", GIGAN_FRAME_STAGES),
        (f"cloud_rtt60_cold_{renderer}", CLOUD_FRAME_STAGES),
    ):
        rows = read_csv_rows(runs / name / "frames.csv")
        assert [r["frame"] for r in rows] == [str(f) for f in range(frames)]
        first = rows[0]  # binds the run's first map
        assert first["gi_new"] == "1" and all(float(first[f"{s}_ms"]) > 0 for s in stages), (name, first)
        assert all(float(r["frame_ms"]) > 0 and float(r["valid_frac"]) > 0.5 for r in rows), name
        scored = [f % gt_every == 0 for f in range(frames)]
        assert [bool(r["ssim"]) for r in rows] == scored and all(0.2 < float(r["ssim"]) <= 1 for r in rows if r["ssim"])
        assert [bool(r["lf_error"]) for r in rows] == scored
        assert all(0 <= float(r["lf_error"]) <= 10 ** (-float(r["psnr"]) / 20) + 1e-9 for r in rows if r["lf_error"])
        summary = json.loads((runs / name / "summary.json").read_text())
        assert summary["renderer"] == summary["config"]["renderer"] == renderer, summary
        assert "unavailable" not in (runs / name / "console.txt").read_text()
    for store in ("prebaked", "cold"):
        folder = runs / f"cloud_rtt60_{store}_{renderer}"
        rows = read_csv_rows(folder / "frames.csv")
        assert all(float(r["di_ms"]) > 0 and float(r["splat_ms"]) > 0 for r in rows), store
        requests = read_csv_rows(folder / "requests.csv")
        answered = [r["hit"] for r in requests if r["status"] == "ok"]
        assert answered and (answered[0] == "0" if store == "cold" else set(answered) == {"1"}), (store, answered)
        shown = [r for r in requests if r["total_ms"]]
        assert shown and all(r["status"] in ("ok", "abandoned") for r in requests)
        for r in shown:
            assert float(r["request_ms"]) >= 59.0, r  # the profile's 2 x 30 ms round trip is in the request stage
            parts = sum(float(r[f"{s}_ms"]) for s in STAGES if r[f"{s}_ms"]) + sum(
                float(r[c]) for c in ("di_ms", "bind_ms", "warp_ms", "blend_ms")
            )
            assert float(r["total_ms"]) == pytest.approx(parts)
        summary = json.loads((folder / "summary.json").read_text())
        assert summary["requests"] == len(requests) and 0 < summary["mean_ssim"] <= 1
        if store == "cold":
            assert summary["misses"] >= 1 and shown[0]["hit"] == "0" and float(shown[0]["render_ms"]) > 0


def test_unknown_profile_is_a_user_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    argv = ["bench", "latency", "--profiles", "lan,moon", "--out", str(tmp_path / "out")]
    line = check_user_error(run_main(argv, tmp_path, monkeypatch, capfd), "--profiles 'moon'")
    assert "wan" in line  # the profiles it knows


# -- totals and the renderers side by side, from client outputs written here -------------------------------------
def _write_csv(path: Path, rows: list[dict]) -> None:
    import csv

    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _gigan_frames(di: float, gi_render: float, ssim: float = 0.9) -> list[dict]:
    """Two frames: the first binds a map (its stages in ms), the second binds none (its DI is no map's)."""
    from gigan_local.warp import StructureAwareWarp

    per_frame = {f"{s}_ms": 0.25 for s in StructureAwareWarp.stages if s != "bind"}
    bound = {"frame": 0, "gi_new": 1, "di_ms": di, "gi_render_ms": gi_render, "inference_ms": 20.0, "bind_ms": 1.0}
    bound |= per_frame | {"compose_ms": 0.5, "ssim": ssim}
    return [bound, bound | {"frame": 1, "gi_new": 0, "di_ms": 100.0, "ssim": ""}]


def _cloud_run(folder: Path, di: float, hit: int, perceived_ms: float = 90.0) -> None:
    from baseline_cloudbaking.client_run import REQUEST_COLUMNS

    stages = {"transmission": 70.0, "request": 65.0, "transfer": 5.0, "lookup": 0.1, "decode": 2.0, "blend": 0.5}
    stages |= {"read": 0.2} if hit else {"render": 300.0, "denoise": 100.0, "encode": 3.0}
    request = dict.fromkeys(REQUEST_COLUMNS, "") | {f"{s}_ms": v for s, v in stages.items()}
    request |= {"status": "ok", "hit": hit, "bytes_up": 400, "bytes_down": 30_000, "server_ms": 1.0 if hit else 403.0}
    request |= {"frame": 0, "latency_ms": 80.0, "di_ms": di, "bind_ms": 1.0, "warp_ms": 6.0, "pickup_ms": 3.0}
    request["total_ms"] = sum(stages.values()) - stages["transmission"] + di + 1.0 + 6.0
    _write_csv(folder / "requests.csv", [request])
    perceived = {"in_tolerance": 1, "perceived_ms": perceived_ms, "perceived_map": 0}
    _write_csv(folder / "frames.csv", [{"frame": 0, "di_ms": di, "ssim": 0.95} | perceived])


def _value(rows: list[dict], system: str, metric: str, stat: str, **config) -> float:
    """The value of the one row of ``system``, ``metric``, ``stat`` and ``config``."""
    [v] = [
        r["value"]
        for r in rows
        if (r["system"], r["metric"], r["stat"]) == (system, metric, stat) and r["config"].items() >= config.items()
    ]
    return v


def _summaries(runs: dict) -> None:
    """What each client's summary.json says it ran."""
    from bench.latency_record import GIGAN

    for (system, *_, renderer), folders in runs.items():
        summary = {"frames": 2, "renderer": renderer, "warp_backend": "gl" if renderer == "gl" else "numpy"}
        for folder in folders:
            (folder / "summary.json").write_text(
                json.dumps(summary | ({"inference": "onnxruntime"} if system == GIGAN else {}))
            )


def test_totals_count_the_local_di_and_the_renderers_stand_side_by_side(tmp_path: Path) -> None:
    from bench.latency_record import CLOUD, GIGAN, record
    from bench.latency_tables import PARTS, SHORT
    from gicore.mitsuba_variant import mitsuba_choice
    from gicore.present.markdown import table_text, tables_text
    from gicore.results import Results

    gl, mi = {"di": 2.0, "gi_render": 5.0}, {"di": 10.0, "gi_render": 15.0}
    per_frame = 0.25 * 4  # project, depth_test, lookup, fill

    runs = {}
    for renderer, times in (("gl", gl), ("mitsuba", mi)):
        _write_csv(tmp_path / f"gigan_{renderer}" / "frames.csv", _gigan_frames(**times))
        runs[GIGAN, "none", "local", renderer] = [tmp_path / f"gigan_{renderer}"]
        for store, hit in (("prebaked", 1), ("cold", 0)):
            folder = tmp_path / f"cloud_rtt60_{store}_{renderer}"
            _cloud_run(folder, times["di"], hit)
            runs[CLOUD, "rtt60", store, renderer] = [folder]
    _summaries(runs)
    cfg = LatencyConfig(profiles=("rtt60",), sweep_max_rtt_ms=100.0)
    res = Results("latency", tmp_path / "out", 0)
    record(res, "lung_plane", cfg, runs, {"resolution": 256, "k": 10, "frames": 2, "repeats": 1})
    res.write()
    rows = read_rows(res.csv_path)
    value = partial(_value, rows)

    gigan_total = {"gl": 2.0 + 5.0 + 21.0 + per_frame + 0.5, "mitsuba": 10.0 + 15.0 + 21.0 + per_frame + 0.5}
    for renderer, total in gigan_total.items():
        assert value(GIGAN, "total", "median", renderer=renderer) == pytest.approx(total)
        miss = value(CLOUD, "total", "median", renderer=renderer, cache="miss")
        # request + transfer + lookup + render + denoise + encode + decode, then DI + bind + warp + blend
        assert miss == pytest.approx(65.0 + 5.0 + 0.1 + 403.0 + 2.0 + (gl if renderer == "gl" else mi)["di"] + 7.5)
        ratio = value(f"{CLOUD}/{GIGAN}", "total_ratio", "median", renderer=renderer, cache="miss")
        assert ratio == pytest.approx(miss / total)  # each system on the same renderer
    gl_over_mi = gigan_total["gl"] / gigan_total["mitsuba"]
    assert value(GIGAN, "total", "renderer_ratio", renderer="gl/mitsuba") == pytest.approx(gl_over_mi)
    assert value(GIGAN, "di", "renderer_ratio", renderer="gl/mitsuba") == pytest.approx(0.2)
    assert value(CLOUD, "di", "renderer_ratio", renderer="gl/mitsuba", cache="hit") == pytest.approx(0.2)
    assert not [r for r in rows if r["stat"] == "renderer_ratio" and r["metric"] == "inference" and r["value"] != 1.0]
    # a row per client run names what ran; the renderers' ratios are unaffected by the runs' differing backends
    assert value(GIGAN, "frames", "value", inference="onnxruntime", inference_device="cpu", warp_backend="gl") == 2
    server = mitsuba_choice()
    assert value(CLOUD, "frames", "value", store="cold", renderer="mitsuba", server_variant=server.variant) == 2
    # perceived latency of the runs on the prebaked store (RunMetrics: tests/baseline_cloudbaking/test_run_metrics.py)
    assert value(CLOUD, "perceived", "p95", store="prebaked", renderer="gl") == 90.0
    assert not [r for r in rows if r["metric"] == "perceived" and r["config"]["store"] == "cold"]
    ran = (
        f"What ran: GIGAN on gl: inference onnxruntime on cpu, warp gl; cloud baking on gl: warp gl, server "
        f"{server.variant} with {server.denoiser}; GIGAN on mitsuba: inference onnxruntime on cpu, warp numpy;"
    )

    text = tables_text([p for p in PARTS if p is not SHORT], rows, 2)
    assert "| stage | GIGAN, gl | cloud baking, hit, gl | cloud baking, miss, gl | GIGAN, mitsuba |" in text
    local = "| local render: DI + the warp's pass (the frame showing the map) |"
    assert f"{local} 2.0 (2.0) | 2.0 (2.0) | 2.0 (2.0) | 10.0 (10.0) |" in text
    assert "## renderers side by side: median with gl / median with mitsuba (same run)" in text
    assert f"| total | {gl_over_mi:.2f} |" in text and "| local render (DI + warp pass) | 0.20 | 0.20 | 0.20 |" in text
    assert "| gl | miss | 0 (GIGAN is faster at any RTT) |" in text
    assert ran in text  # Table 1's notes
    block = table_text(SHORT, rows, 4)
    assert f"| `rtt60` (60 ms) | gl | {gigan_total['gl']:.1f} |" in block
    assert f"| `rtt60` (60 ms) | mitsuba | {gigan_total['mitsuba']:.1f} |" in block
    assert f"gl / mitsuba in the same run, GIGAN: total {gl_over_mi:.2f}, warp 1.00, GI-camera render 0.33" in block
    assert ran in block


def test_three_repeats_pool_their_maps_and_their_intervals_are_over_the_runs(tmp_path: Path) -> None:
    """Each repeat's client outputs written here (one renderer, one map per run and cache state, each repeat's
    timings apart): stage medians and counts over the pooled maps, perceived latency over the pooled frames, SSIM
    per frame the repeats' mean; each ratio's and crossover's interval over the runs, holding their mean."""
    from bench.latency_record import CLOUD, GIGAN, record
    from bench.latency_tables import SHORT, TABLE1
    from gicore.intervals import recorded
    from gicore.present.markdown import table_text
    from gicore.results import Results

    gi_render, di, ssim, perceived = (5.0, 8.0, 20.0), (2.0, 3.0, 10.0), (0.9, 0.8, 0.7), (90.0, 100.0, 110.0)
    runs: dict = {}
    for i in range(3):
        folder = tmp_path / f"r{i}"
        _write_csv(folder / "gigan_gl" / "frames.csv", _gigan_frames(di[0], gi_render[i], ssim[i]))
        runs.setdefault((GIGAN, "none", "local", "gl"), []).append(folder / "gigan_gl")
        for store, hit in (("prebaked", 1), ("cold", 0)):
            _cloud_run(folder / f"cloud_rtt60_{store}_gl", di[i], hit, perceived[i])
            runs.setdefault((CLOUD, "rtt60", store, "gl"), []).append(folder / f"cloud_rtt60_{store}_gl")
    _summaries(runs)
    res = Results("latency", tmp_path / "out", 0)
    record(res, "lung_plane", LatencyConfig(profiles=("rtt60",), sweep_max_rtt_ms=100.0), runs,
           {"resolution": 256, "k": 10, "frames": 2, "repeats": 3})  # fmt: skip
    res.write()
    rows = read_rows(res.csv_path)
    value = partial(_value, rows)

    gigan = [di[0] + g + 21.0 + 0.25 * 4 + 0.5 for g in gi_render]  # DI, GI camera, inference + bind, warp, blend
    miss = [65.0 + 5.0 + 0.1 + 403.0 + 2.0 + d + 7.5 for d in di]  # as in the test above
    assert value(GIGAN, "total", "median", repeats=3) == pytest.approx(gigan[1])
    assert value(GIGAN, "gi_render", "median") == 8.0 and value(GIGAN, "total", "n") == 3
    assert value(CLOUD, "total", "median", cache="miss") == pytest.approx(miss[1])
    assert value(CLOUD, "di", "median", cache="hit") == 3.0 and value(CLOUD, "total", "n", cache="hit") == 3
    assert value(CLOUD, "perceived", "median", store="prebaked") == 100.0
    assert value(CLOUD, "perceived", "p95", store="prebaked") == 110.0
    assert value(CLOUD, "requests", "value", store="prebaked") == 1 and value(GIGAN, "frames", "value") == 2
    assert value(GIGAN, "ssim", "frame", frame=0) == pytest.approx(0.8)
    ratio = value(f"{CLOUD}/{GIGAN}", "total_ratio", "median", cache="miss")
    assert ratio == pytest.approx(miss[1] / gigan[1])  # the pooled maps' medians
    per_run = [m / g for m, g in zip(miss, gigan, strict=True)]
    interval = recorded(rows, f"{CLOUD}/{GIGAN}", "total_ratio", cache="miss", renderer="gl")
    assert interval is not None and interval.over == "runs"
    # the mean of resampled runs: within the runs' range and, at 95 %, around their mean
    assert min(per_run) <= interval.low < np.mean(per_run) < interval.high <= max(per_run)
    crossing = recorded(rows, f"{CLOUD}/{GIGAN}", "crossover_rtt", cache="hit", renderer="gl")
    assert crossing is not None and crossing.over == "runs"
    assert {r["config"]["ci_over"] for r in rows if r["stat"].startswith("ci_")} == {"runs"}

    rests = "3 runs (3 / 3 in all)"
    assert f"| the interval rests on (maps: cloud / GIGAN) | — | {rests} | {rests} |" in table_text(TABLE1, rows, 2)
    assert "2000 resamples of the 3 runs' own values" in table_text(SHORT, rows, 2)


def test_repeats_run_every_client_again_in_their_own_folders(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The processes are stood in for: each repeat runs every client and prebakes its own store in latency_runs/r<i>;
    the recorder gets each run's folders in the repeats' order, and the prebake is one row."""
    from gicore.results import Results
    from tests.helpers.latency_runs import stand_in

    told = stand_in(monkeypatch)
    given: dict = {}
    monkeypatch.setattr(latency, "record", lambda res, name, cfg, runs, common: given.update(runs=runs, common=common))
    cfg = LatencyConfig(profiles=("lan",), resolution=16, frames=3, renderers=("mitsuba",), prefetch_in_flight=1,
                        alone=False, repeats=3)  # fmt: skip
    res = Results("latency", tmp_path / "out", 0)
    latency.measure(cfg, res)
    assert len(told.argvs) == 3 * 4  # gigan, cloud prebaked, its prefetching twin, cloud cold; each repeat
    assert len(told.asked) == 3 * 2  # each repeat's prebake, and its cold store's compile request
    work = tmp_path / "out" / "latency_runs"
    assert len(given["runs"]) == 4 and given["common"]["repeats"] == 3
    for (*_, renderer), folders in given["runs"].items():
        assert [f.parent for f in folders] == [work / f"r{i}" for i in range(3)] and renderer == "mitsuba"
    assert [r["metric"] for r in res.rows] == ["prebake_maps", "prebake_time"]
    assert all(r["config"]["repeats"] == 3 for r in res.rows)


def test_renderers_option(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    """Unknown or repeated renderers are user errors; gl without a GL context is left out after one warning."""
    import gicore.gl
    from gicore.error_policy import UserError

    for renderers, message in ((("gl", "vulkan"), "'vulkan' is not a renderer"), (("gl", "gl"), "twice")):
        with pytest.raises(UserError, match=message):
            LatencyConfig(renderers=renderers).check()
    monkeypatch.setattr(gicore.gl, "gl_available", lambda: (False, "no EGL display (test)"))
    assert latency.available_renderers(("gl", "mitsuba"))[0] == ("mitsuba",)
    ran, settings = latency.available_renderers(("gl",))
    assert ran == ("mitsuba",) and settings == {"asked": ["gl"], "gl": "no EGL display (test)", "ran": ["mitsuba"]}
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all("renderer gl is unavailable" in e and "no EGL display (test)" in e for e in err)
