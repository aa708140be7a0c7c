"""`bench stability`: extreme and stiff inputs through every stage, each with its expected behaviour.

Every case runs one stage on one extreme input and expects ``finite`` (the stage runs to the end, every output
finite, within the case's error bound where a reference exists) or ``rejected`` (a clear refusal: a
``ValueError``/``UserError`` naming what is wrong, an HTTP 4xx naming the field, or a client timeout on a dead
link). Stages: ``render``, ``tonemap``, ``inference``, ``warp``, ``composition``, ``codecs``, ``store``,
``network`` and ``server`` (see :func:`cases`). Each case runs in a worker thread with a time limit (past it:
a hang); any other exception is a crash. Any failed case makes the command exit 2 naming it, after the files
are written; crash tracebacks go to ``stability_failures.txt``. What a case is: :mod:`gicore.stability`; the
cases: each package's ``stability_cases`` module, and :mod:`bench.stability_network` for the cloud client
through real proxies. docs/architecture.md, Numerical stability.
"""

from __future__ import annotations

import math
import shutil
import threading
import time
import traceback
from contextlib import ExitStack
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from baseline_cloudbaking.stability_cases import Served, codec_cases, server_cases, store_cases
from bench.common import WARP_LABELS, make_warp
from bench.processes import scene_folder
from bench.runner import Bench, Block, Section
from bench.stability_network import network_cases
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.present.declarations import Alert, Chart, Column, Figure, Rows, Table
from gicore.results import Results
from gicore.stability import Case, Outcome, Rejected, Scene
from gicore.stability_cases import WarpFactory, composition_cases, render_cases, tonemap_cases, warp_cases
from gigan_local.inference import DEFAULT_MODEL
from gigan_local.stability_cases import inference_cases
from network_sim.stability_cases import link_model_cases

#: Outcomes of a case; the first two are passes.
PASSED = ("finite", "rejected")
STAGES = ("render", "tonemap", "inference", "warp", "composition", "codecs", "store", "network", "server")


@dataclass(frozen=True)
class StabilityConfig:
    """What one stability run covers (see the module docstring)."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="of the render, inference, warp and server cases")
    resolution: int = option_groups.resolution(
        128, note="of renders, GI maps and warps; inference runs at the model's own"
    )
    spp: int = option_groups.spp(16, note="of the GI maps, references and server maps")
    #: ONNX generator of the inference cases (gigan-export output).
    model: Path = DEFAULT_MODEL
    #: Longest one case may run, s; past it the case is a hang (a failure).
    case_timeout_s: float = 120.0
    #: Connect, read and (twice it) total timeout of the cloud client in the real network cases, s.
    client_timeout_s: float = 2.0
    #: Run the network and server cases against real proxy and server processes (else the link model only).
    processes: bool = True

    @classmethod
    def quick(cls) -> StabilityConfig:
        return cls(resolution=64, spp=4, case_timeout_s=60.0, client_timeout_s=1.0)

    def check(self) -> None:
        from baseline_cloudbaking.server.settings import Settings

        served = Settings.model_fields["resolutions"].default
        if self.processes and self.resolution not in served:
            raise UserError(
                f"--resolution {self.resolution} is not served by cloudbaking-server",
                f"use one of {', '.join(map(str, served))}, or --no-processes",
            )


# -- a case's verdict -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Verdict:
    """How a case ended: ``status`` is ``finite`` or ``rejected`` (passes) or ``FAIL: ...``."""

    status: str
    message: str
    time_ms: float
    finite: bool | None = None
    error: float | None = None
    error_kind: str = ""
    bound: float | None = None
    trace: str = ""

    @property
    def passed(self) -> bool:
        return self.status in PASSED


#: Exceptions that are clean refusals of bad input (a stage names what is wrong).
CLEAN = (ValueError, UserError, Rejected)


def _all_finite(outputs: tuple[Any, ...]) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(o, dtype=np.float64)))) for o in outputs)


def _line(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())[:400]


def judge(case: Case, timeout_s: float) -> Verdict:
    """Run ``case`` in a worker thread for at most ``timeout_s`` and judge what it did."""
    box: dict[str, Any] = {}

    def target() -> None:
        t0 = time.perf_counter()
        try:
            box["outcome"] = case.run()
        except BaseException as exc:  # judged below: a clean refusal or a crash
            box["exc"], box["trace"] = exc, traceback.format_exc()
        box["ms"] = (time.perf_counter() - t0) * 1e3

    worker = threading.Thread(target=target, name=f"case {case.stage}/{case.name}", daemon=True)
    worker.start()
    worker.join(timeout_s)
    if worker.is_alive():  # left running as a daemon; the run ends with a failure
        return Verdict("FAIL: hang", f"still running after {timeout_s:g} s", timeout_s * 1e3)
    ms = box["ms"]
    exc = box.get("exc")
    if exc is not None:
        if not isinstance(exc, CLEAN):
            return Verdict("FAIL: crashed", _line(exc), ms, trace=box["trace"])
        if case.expect == "finite":
            return Verdict("FAIL: valid input refused", _line(exc), ms, trace=box["trace"])
        return Verdict("rejected", _line(exc), ms)
    out: Outcome = box["outcome"]
    finite = _all_finite(out.outputs)
    common = {"time_ms": ms, "finite": finite, "error": out.error, "error_kind": out.error_kind, "bound": out.bound}
    if case.expect == "rejected":
        return Verdict("FAIL: invalid input accepted", out.note or "ran to the end", **common)
    if not finite:
        return Verdict("FAIL: non-finite output", out.note, **common)
    if out.error is not None and (not math.isfinite(out.error) or (out.bound is not None and out.error > out.bound)):
        limit = "finite" if out.bound is None else f"<= {out.bound:g}"
        return Verdict(
            "FAIL: error above bound", f"{out.error:.3g}, not {limit} ({out.error_kind}); {out.note}", **common
        )
    return Verdict("finite", out.note, **common)


# -- the bench ------------------------------------------------------------------------------------------------
def warps() -> dict[str, WarpFactory]:
    """The warp cases' warps, both systems' (wired here: cross-system code lives in neither): label -> factory."""
    return {WARP_LABELS[method]: partial(make_warp, method) for method in ("structure", "pixel")}


def cases(cfg: StabilityConfig, s: Scene, work: Path) -> list[Case]:
    """Every case that needs no process (the process cases are added by :func:`measure`)."""
    return [
        *render_cases(s),
        *tonemap_cases(),
        *inference_cases(s, cfg.model),
        *warp_cases(s, warps()),
        *composition_cases(),
        *codec_cases(s),
        *store_cases(work),
        *link_model_cases(),
    ]


def record(res: Results, scene: str, case: Case, v: Verdict) -> None:
    """The case's rows: status (1 = passed), finite, rejected, time and, where measured, the error."""
    config = {"case": case.name, "expect": case.expect, "status": v.status, "message": v.message}
    add = {"system": case.stage, "scene": scene}
    res.add(**add, metric="status", value=float(v.passed), unit="1", stat="pass", **config)
    if v.finite is not None:
        res.add(**add, metric="finite", value=float(v.finite), unit="1", **config)
    res.add(**add, metric="rejected", value=float(v.status == "rejected"), unit="1", **config)
    res.add(**add, metric="time", value=v.time_ms, unit="ms", **config)
    if v.error is not None:
        res.add(
            **add,
            metric="error",
            value=v.error,
            unit=v.error_kind,
            stat="max" if v.bound is not None else "value",
            bound=v.bound,
            **config,
        )


def measure(cfg: StabilityConfig, res: Results) -> None:
    from baseline_cloudbaking.client import RemoteConfig
    from web3d.children import start_server, url

    work = res.out / "stability_work"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    scene = cfg.scenes[0]
    s = Scene.load(scene, cfg.resolution, cfg.spp, res.seed)
    failures: list[str] = []
    with ExitStack() as stack:
        todo = cases(cfg, s, work)
        if cfg.processes:
            server = start_server(work / "server_store", scene_folder(scene), "--max-spp", str(max(cfg.spp, 1)))
            remote = RemoteConfig(url(stack.enter_context(server)), Path(scene).stem, cfg.resolution, "jpeg", cfg.spp,
                                  light_moves=s.spec.light.moves)  # fmt: skip
            served = Served(remote, cfg.case_timeout_s, cfg.client_timeout_s)
            todo += server_cases(s, served) + network_cases(s, served, stack)
        for case in todo:
            v = judge(case, cfg.case_timeout_s)
            record(
                res,
                s.spec.name if case.stage in ("render", "inference", "warp", "network", "server") else "none",
                case,
                v,
            )
            if v.trace:
                failures.append(f"== {case.stage}: {case.name}: {v.status}\n{v.trace}")
            print(f"{case.stage:>11} | {v.status:<28} | {v.time_ms:9.1f} ms | {case.name}", flush=True)
    if failures:
        res.output("stability_failures.txt").write_text("\n".join(failures))
    shutil.rmtree(work, ignore_errors=True)


# -- what it shows (from the CSV only) ---------------------------------------------------------------------
def summary(rows: Rows) -> list[dict[str, Any]]:
    """One entry per case (in CSV order): stage, case, expect, status, message, finite, error, bound, time."""
    out: dict[tuple[str, str], dict[str, Any]] = {}
    for r in rows:
        c = r["config"]
        first = {"stage": r["system"], "case": c["case"], "expect": c["expect"], "status": c["status"],
                 "message": c["message"], "finite": None, "error": None, "error_kind": "", "bound": None,
                 "time_ms": None}  # fmt: skip
        entry = out.setdefault((r["system"], c["case"]), first)
        if r["metric"] == "finite":
            entry["finite"] = bool(r["value"])
        elif r["metric"] == "time":
            entry["time_ms"] = r["value"]
        elif r["metric"] == "error":
            entry |= {"error": r["value"], "error_kind": r["unit"], "bound": c.get("bound")}
    return list(out.values())


def counts(entries: list[dict[str, Any]]) -> dict[str, int]:
    """Cases, finite, cleanly rejected and failed."""
    return {
        "cases": len(entries),
        "finite": sum(e["status"] == "finite" for e in entries),
        "rejected": sum(e["status"] == "rejected" for e in entries),
        "failed": sum(e["status"] not in PASSED for e in entries),
    }


def _failed(rows: Rows) -> list[str]:
    return [f"{e['stage']}/{e['case']} ({e['status']})" for e in summary(rows) if e["status"] not in PASSED]


def per_stage(rows: Rows) -> list[dict[str, Any]]:
    entries = summary(rows)
    return [
        {"stage": st} | counts([e for e in entries if e["stage"] == st])
        for st in dict.fromkeys(e["stage"] for e in entries)
    ]


def outcomes(rows: Rows) -> list[dict[str, Any]]:
    """Per stage, the number of finite, cleanly rejected and failed cases (bars stacked by outcome)."""
    names = {"finite": "finite", "rejected": "cleanly rejected", "failed": "failed"}
    return [
        {"stage": r["stage"], "outcome": name, "count": r[key]} for r in per_stage(rows) for key, name in names.items()
    ]


def verdict(rows: Rows) -> None:
    """Any failed case is a :class:`UserError` naming them (exit status 2), raised once the files are written."""
    entries = summary(rows)
    failed = [e for e in entries if e["status"] not in PASSED]
    if failed:
        names = "; ".join(f"{e['stage']}/{e['case']} ({e['status'].removeprefix('FAIL: ')})" for e in failed)
        raise UserError(
            f"{len(failed)} of {len(entries)} stability cases failed: {names}",
            "see stability.md beside the CSV (and stability_failures.txt for tracebacks)",
        )


def _title(rows: Rows) -> str:
    n = counts(summary(rows))
    return (
        f"Numerical stability: {n['cases']} cases, {n['finite']} finite, {n['rejected']} cleanly rejected, "
        f"{n['failed']} failed"
    )


def _counts_line(rows: Rows) -> str:
    n = counts(summary(rows))
    return (
        f"**{n['cases']} cases: {n['finite']} finite, {n['rejected']} cleanly rejected, {n['failed']} failed** "
        "(crashed, hung or went non-finite)."
    )


PARTS = (
    Alert(lambda rows: "Failed cases: " + "; ".join(_failed(rows)) if _failed(rows) else ""),
    Table(
        summary,
        (
            Column("stage", "{stage}"),
            Column("case", "{case}"),
            Column("expected", "{expect}"),
            Column("outcome", "{status}"),
            Column("error (bound)", "{error:.3g}[[ (≤ {bound:g})]]"),
            Column("time (ms)", "{time_ms:.1f}"),
            Column("message", "{message}"),
        ),
        title=_title,
        where="dashboard",
        scroll=True,
    ),
    Table(
        per_stage,
        (
            Column("stage", "{stage}"),
            Column("cases", "{cases}"),
            Column("finite", "{finite}"),
            Column("cleanly rejected", "{rejected}"),
            Column("failed", "{failed}"),
        ),
        caption=_counts_line,
        notes=lambda rows: f"Failed: {'; '.join(_failed(rows))}." if _failed(rows) else "",
        where="readme",
    ),
    Figure(
        "stability",
        (Chart(outcomes, "stage", "count", "{outcome}", kind="stack", ylabel="cases"),),
        title=lambda rows: (
            f"Stability: {counts(summary(rows))['cases']} extreme cases, {counts(summary(rows))['failed']} failed"
        ),
    ),
)


BENCH = Bench(
    "stability",
    StabilityConfig,
    measure,
    help="Extreme and stiff inputs through every stage (render, tone map, inference, warps, composition, "
    "codecs, store, network, server); finite or cleanly rejected, never a crash or a hang (exit 2 naming any failed "
    "case).",
    dashboard=Section("stability", "Numerical stability", 80),
    readme=Block("Numerical stability", 100),
    parts=PARTS,
    needs=("status",),
    verdict=verdict,
)
