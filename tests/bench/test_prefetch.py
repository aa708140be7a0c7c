"""`bench prefetch` from its rows: the targets' verdicts, the table, and the options it refuses. (The processes it
drives, and what one client run's CSVs give, are tested in tests/baseline_cloudbaking.)"""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.prefetch import BENCH, PrefetchConfig, record, targets
from gicore.error_policy import UserError
from gicore.options import build_config
from gicore.present.markdown import tables_text
from gicore.results import Results, read_rows

HEAD = ("frame", "ssim", "in_tolerance", "perceived_ms", "perceived_map")


def write_run(folder: Path, perceived: list[float | str], requests: int) -> Path:
    folder.mkdir(parents=True)
    head = ",".join(HEAD)
    lines = [f"{f},0.9,{int(p != '' and p < 60)},{p},{'0' if p != '' else ''}" for f, p in enumerate(perceived)]
    (folder / "frames.csv").write_text("\n".join([head, *lines]) + "\n")
    cols = "frame,hit,status,bytes_up,bytes_down,latency_ms,total_ms"
    reqs = [f"{f},1,ok,300,1000,40.0," for f in range(requests)]
    (folder / "requests.csv").write_text("\n".join([cols, *reqs]) + "\n")
    (folder / "summary.json").write_text('{"renderer": "mitsuba"}')
    return folder


def test_targets_compare_the_variants_named_by_the_issue(tmp_path: Path) -> None:
    """wan: prefetch's median perceived latency 50 ms against hold's 300 (met, 0.17); with hold's frames mostly
    never served its median is endless. lan: hold 60 requests against period's 100 (missed, 0.6)."""
    res = Results("prefetch", tmp_path, 0)
    runs = {
        ("wan", "hold"): ([300.0, 300.0, "", 250.0, 400.0], 5),
        ("wan", "prefetch"): ([50.0, 40.0, 60.0, "", 50.0], 4),
        ("lan", "period"): ([30.0] * 5, 100),
        ("lan", "hold"): ([30.0] * 5, 60),
    }
    for (profile, variant), (perceived, n) in runs.items():
        folder = write_run(tmp_path / f"{profile}_{variant}", perceived, n)
        record(res, "s", folder, {"profile": profile, "variant": variant, "in_flight": 3})
    targets(res, "s")
    for store, floor in (("prebaked", 58), ("placed", 41)):
        res.add(system="cloud_baking", scene="s", metric="request_floor", value=floor, unit="count", store=store)
    rows = read_rows(res.write())
    met = {
        r["config"]["target"].split(",")[0] + r["config"]["target"][-5:]: r for r in rows if r["stat"] == "target_met"
    }
    assert len(met) == 3  # prefetch at lan was not run: no row
    wan = met["median perceived latency(wan)"]
    assert wan["value"] == 1 and wan["config"]["ratio"] == pytest.approx(50.0 / 300.0)
    lan = met["requests(lan)"]
    assert lan["value"] == 0 and lan["config"]["ratio"] == pytest.approx(0.6)
    text = tables_text(BENCH.parts, rows, 2)
    assert "| wan | hold (3) | 5 |" in text and "MISSED" in text and "| yes |" in text
    assert "with perfect foresight: 58 from the prebaked store's maps" in text and ", 41 from maps centred" in text


def test_options_it_refuses() -> None:
    with pytest.raises(UserError, match="--profiles 'moon'"):
        build_config(PrefetchConfig, {"profiles": "lan,moon"})
    with pytest.raises(UserError, match="--variants 'always'"):
        build_config(PrefetchConfig, {"variants": "hold,always"})
    with pytest.raises(UserError, match="--resolution 32 is not served by cloudbaking-server: use one of 64, 128"):
        build_config(PrefetchConfig, {"resolution": 32})
    assert BENCH.name == "prefetch" and BENCH.readme is not None


@pytest.mark.slow
def test_bench_prefetch_end_to_end(tmp_path: Path) -> None:
    """The bench with its processes at 64² (a prebaked store, a fresh copy of it and a server per run, the proxy,
    the client): the run's rows, one GT render per scored frame in the bench's cache, the prebake counted and the
    request floors. One variant: the clients of the request rules run through a proxy against a prebaked
    server in tests/bench/test_latency.py::test_bench_latency_end_to_end (its plain client holds, its twin
    prefetches), and the variants' rows are compared in test_targets_compare_the_variants_named_by_the_issue."""
    from bench.runner import execute
    from tests.helpers.cloud import write_scenes

    scene = write_scenes(tmp_path / "scenes") / "ball_moving.json"
    cfg = PrefetchConfig(scenes=(str(scene),), profiles=("lan",), variants=("prefetch",), resolution=64,
                         frames=10, spp=2, gt_every=5)  # fmt: skip
    execute(BENCH, cfg, tmp_path / "out", seed=0)
    rows = read_rows(tmp_path / "out" / "prefetch.csv")
    got = {r["metric"] for r in rows if r["config"].get("variant") == "prefetch"}
    assert {"requests", "perceived", "in_tolerance", "ssim"} <= got, got
    [prebake] = [r for r in rows if r["metric"] == "prebake_maps"]
    assert prebake["value"] >= 1
    # the floors: the stored maps are path views where the prebake missed, so centring maps on every view of
    # the path needs no more of them, and the stored maps all together serve the path
    floor = {r["config"]["store"]: r["value"] for r in rows if r["metric"] == "request_floor"}
    assert 1 <= floor["placed"] <= floor["prebaked"] <= prebake["value"], (floor, prebake["value"])
    assert len(list((tmp_path / "out" / "prefetch_runs" / "gt_cache").glob("*.npz"))) == 2  # frames 0 and 5
