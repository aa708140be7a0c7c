"""`bench latency` (Table 1): the whole bench end to end at 64² (server, proxy, both clients as processes),
and its option checks (the link model's crossover: tests/network_sim/test_exchange.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bench import latency
from bench.latency import LatencyConfig
from bench.runner import execute
from gicore.results import read_rows
from tests.helpers.cloud import passthrough_model, write_scenes


@pytest.mark.slow
def test_bench_latency_end_to_end(tmp_path: Path) -> None:
    scene = write_scenes(tmp_path / "scenes") / "ball_moving.json"
    cfg = LatencyConfig(scenes=(str(scene),), profiles=("rtt60",), resolution=64, frames=12, every=2, spp=4, gt_every=4,
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
    common = {
        "di",
        "transmission",
        "request",
        "transfer",
        "lookup",
        "server_other",
        "decode",
        "warp",
        "blend",
        "total",
        "pickup",
    }
    assert stats("cloud_baking", profile="rtt60", cache="hit") >= common | {"read"}
    assert stats("cloud_baking", profile="rtt60", cache="miss") >= common | {"render", "denoise", "encode"}

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
    # the prebaked store answered every request of its run; the cold one missed its first (later ones hit
    # only where this run had baked a map within the tolerance already)
    prebaked, cold = (
        [r for r in _csv(out / "latency_runs" / f"cloud_rtt60_{s}_{renderer}" / "requests.csv") if r["status"] == "ok"]
        for s in ("prebaked", "cold")
    )
    assert prebaked and {r["hit"] for r in prebaked} == {"1"} and cold[0]["hit"] == "0"
    assert value("failed_requests", "value", profile="rtt60", store="cold") == 0
    ssim = [r for r in rows if r["metric"] == "ssim" and r["stat"] == "frame"]
    assert {(r["system"], r["config"]["store"]) for r in ssim} == {
        ("gigan", "none"),
        ("cloud_baking", "prebaked"),
        ("cloud_baking", "cold"),
    }
    assert {r["config"]["frame"] for r in ssim} == {0, 4, 8} and all(0 < r["value"] <= 1 for r in ssim)
    # each scored frame's GT was path-traced once and shared by every client run of the bench
    assert len(list((out / "latency_runs" / "gt_cache").glob("*.npz"))) == 3

    provenance = json.loads((out / "latency.provenance.json").read_text())
    assert provenance["settings"]["pinning"]["method"] in ("taskset -c", "none")
    table = (out / "latency.md").read_text()
    assert (
        "### profile `rtt60` (RTT 60 ms)" in table
        and "**total (interaction latency)**" in table
        and "crossover" in table
    )
    assert {p.name for p in files} >= {
        "latency.csv",
        "latency.md",
        "latency_stages.png",
        "latency_stages.svg",
        "latency_ratio_rtt.png",
        "latency_ssim.png",
    }


def _csv(path: Path) -> list[dict[str, str]]:
    import csv

    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_unknown_profile_is_a_user_error(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "bench", "latency", "--profiles", "lan,moon", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    [line] = [x for x in proc.stderr.splitlines() if x.startswith("error:")]
    assert "--profiles 'moon'" in line and "wan" in line


# -- totals and the renderers side by side, from client outputs written here -------------------------------------
def _write_csv(path: Path, rows: list[dict]) -> None:
    import csv

    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _gigan_frames(di: float, gi_render: float) -> list[dict]:
    """Two frames: the first binds a map (its stages in ms), the second binds none (its DI is no map's)."""
    from gigan_local.warp import StructureAwareWarp

    per_frame = {f"{s}_ms": 0.25 for s in StructureAwareWarp.stages if s != "bind"}
    bound = {"frame": 0, "gi_new": 1, "di_ms": di, "gi_render_ms": gi_render, "inference_ms": 20.0, "bind_ms": 1.0}
    bound |= per_frame | {"compose_ms": 0.5, "ssim": 0.9}
    return [bound, bound | {"frame": 1, "gi_new": 0, "di_ms": 100.0, "ssim": ""}]


def _cloud_run(folder: Path, di: float, hit: int) -> None:
    from baseline_cloudbaking.client_run import REQUEST_COLUMNS

    stages = {"transmission": 70.0, "request": 65.0, "transfer": 5.0, "lookup": 0.1, "decode": 2.0, "blend": 0.5}
    stages |= {"read": 0.2} if hit else {"render": 300.0, "denoise": 100.0, "encode": 3.0}
    request = dict.fromkeys(REQUEST_COLUMNS, "") | {f"{s}_ms": v for s, v in stages.items()}
    request |= {"status": "ok", "hit": hit, "bytes_up": 400, "bytes_down": 30_000, "server_ms": 1.0 if hit else 403.0}
    request |= {"di_ms": di, "bind_ms": 1.0, "warp_ms": 6.0, "pickup_ms": 3.0}
    request["total_ms"] = sum(stages.values()) - stages["transmission"] + di + 1.0 + 6.0
    _write_csv(folder / "requests.csv", [request])
    _write_csv(folder / "frames.csv", [{"frame": 0, "di_ms": di, "ssim": 0.95}])


def test_totals_count_the_local_di_and_the_renderers_stand_side_by_side(tmp_path: Path) -> None:
    from bench.latency_record import CLOUD, GIGAN, gigan_samples, record
    from bench.latency_tables import PARTS, SHORT
    from bench.present.markdown import table_text, tables_text
    from gicore.mitsuba_variant import mitsuba_choice
    from gicore.results import Results

    gl, mi = {"di": 2.0, "gi_render": 5.0}, {"di": 10.0, "gi_render": 15.0}
    samples = gigan_samples([{k: str(v) for k, v in r.items()} for r in _gigan_frames(**gl)])
    per_frame = 0.25 * 4  # project, depth_test, lookup, fill
    assert samples["di"] == [2.0] and samples["total"] == [pytest.approx(2.0 + 5.0 + 20.0 + 1.0 + per_frame + 0.5)]

    runs = {}
    for renderer, times in (("gl", gl), ("mitsuba", mi)):
        _write_csv(tmp_path / f"gigan_{renderer}" / "frames.csv", _gigan_frames(**times))
        runs[GIGAN, "none", "local", renderer] = tmp_path / f"gigan_{renderer}"
        for store, hit in (("prebaked", 1), ("cold", 0)):
            folder = tmp_path / f"cloud_rtt60_{store}_{renderer}"
            _cloud_run(folder, times["di"], hit)
            runs[CLOUD, "rtt60", store, renderer] = folder
    for (system, *_, renderer), folder in runs.items():  # what each client's summary.json says it ran
        summary = {"frames": 2, "renderer": renderer, "warp_backend": "gl" if renderer == "gl" else "numpy"}
        (folder / "summary.json").write_text(
            json.dumps(summary | ({"inference": "onnxruntime"} if system == GIGAN else {}))
        )
    cfg = LatencyConfig(profiles=("rtt60",), sweep_max_rtt_ms=100.0)
    res = Results("latency", tmp_path / "out", 0)
    record(res, "lung_plane", cfg, runs, {"resolution": 256, "k": 10, "frames": 2})
    res.write()
    rows = read_rows(res.csv_path)

    def value(system: str, metric: str, stat: str, **config) -> float:
        [v] = [
            r["value"]
            for r in rows
            if (r["system"], r["metric"], r["stat"]) == (system, metric, stat) and r["config"].items() >= config.items()
        ]
        return v

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
