"""`bench stability`: extreme and stiff inputs through every stage, each with its expected behaviour.

Every case runs one stage on one extreme input and expects ``finite`` (the stage runs to the end, every output
finite, within the case's error bound where a reference exists) or ``rejected`` (a clear refusal: a
``ValueError``/``UserError`` naming what is wrong, an HTTP 4xx naming the field, or a client timeout on a dead
link). Stages: ``render``, ``tonemap``, ``inference``, ``warp``, ``composition``, ``codecs``, ``store``,
``network`` and ``server`` (see :func:`cases`). Each case runs in a worker thread with a time limit (past it:
a hang); any other exception is a crash. Any failed case makes the command exit 2 naming it, after the files
are written; crash tracebacks go to ``stability_failures.txt``. docs/architecture.md, Numerical stability.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bench.runner import Alert, Bench, Block, Part, Rows, Section, Table, need
from gicore.error_policy import UserError
from gicore.results import Results, read_rows
from gigan_local.inference import DEFAULT_MODEL
from network_sim.cli import DELAY_MS_MAX

BIN = Path(sys.executable).parent
Expect = Literal["finite", "rejected"]
#: Outcomes of a case; the first two are passes.
PASSED = ("finite", "rejected")
STAGES = ("render", "tonemap", "inference", "warp", "composition", "codecs", "store", "network", "server")


@dataclass(frozen=True)
class StabilityConfig:
    """What one stability run covers (see the module docstring)."""

    #: The scene of the render, inference, warp and server cases (name or spec file).
    scenes: tuple[str, ...] = field(default=("lung_plane",), metadata={"max_len": 1})
    #: Square resolution of renders, GI maps and warps (inference runs at the model's own resolution).
    resolution: int = 128
    #: Samples per pixel of the path-traced GI maps, references and server maps.
    spp: int = 16
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


# -- cases and their verdicts -------------------------------------------------------------------------------
class Rejected(Exception):
    """A clean refusal that is not an exception of the stage itself: an HTTP 4xx naming the field, a
    client timeout, a link that never delivers."""


@dataclass(frozen=True)
class Outcome:
    """What a case that ran to the end produced: its outputs (checked finite) and, where a reference
    exists, its error against it and the bound that error must stay within."""

    outputs: tuple[Any, ...] = ()
    error: float | None = None
    #: What ``error`` measures (its unit column).
    error_kind: str = ""
    bound: float | None = None
    note: str = ""


@dataclass(frozen=True)
class Case:
    stage: str
    name: str
    expect: Expect
    run: Callable[[], Outcome]


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


# -- helpers of the cases -------------------------------------------------------------------------------------
def _tm_rmse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """RMSE of the tone-mapped images (on ``mask`` pixels only when given)."""
    from gicore.tonemap import tonemap

    d = tonemap(a) - tonemap(b)
    d = d[mask] if mask is not None else d
    return float(np.sqrt(np.mean(d.astype(np.float64) ** 2))) if d.size else 0.0


def _max_rel(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| / max(|b|, tiny): relative deviation of ``a`` from ``b``."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    scale = np.maximum(np.abs(b), 1e-30)
    return float(np.max(np.abs(a - b) / scale)) if a.size else 0.0


def _with_nan(x: np.ndarray, value: float = math.nan) -> np.ndarray:
    y = np.array(x, dtype=np.float32, copy=True)
    y.reshape(-1)[y.size // 2] = value
    return y


@dataclass
class Scene:
    """The scene's renderers, its reference view (local and GI camera, light) and a GI map there."""

    spec: Any
    renderer: Any
    local: Any
    gi_camera: Any
    light: tuple[float, float, float]
    spp: int
    seed: int
    _renderers: dict[float, Any] = field(default_factory=dict)

    @classmethod
    def load(cls, name: str, resolution: int, spp: int, seed: int) -> Scene:
        from gicore.paths import camera_path, light_position
        from gicore.render import Renderer
        from gicore.scene import load_scene

        spec = load_scene(name)
        local = camera_path(spec, 30, seed=seed, fov=spec.camera.local_fov, resolution=resolution)[0]
        return cls(
            spec,
            Renderer(spec, resolution),
            local,
            local.with_fov(spec.camera.gi_fov),
            light_position(spec, 0),
            spp,
            seed,
        )

    def scaled(self, factor: float) -> Any:
        """A renderer of the same scene with the light's intensity times ``factor``."""
        from gicore.render import Renderer

        if factor not in self._renderers:
            spec = self.spec.model_copy(
                update={"light": self.spec.light.model_copy(update={"intensity": self.spec.light.intensity * factor})}
            )
            self._renderers[factor] = Renderer(spec, self.renderer.resolution)
        return self._renderers[factor]

    def passes(self, camera, light=None, renderer=None) -> dict[str, np.ndarray]:
        """Every render pass at ``camera``: DI, centre-sampled G-buffers, path-traced GT, the warp raster."""
        r = renderer or self.renderer
        light = self.light if light is None else light
        out = r.render_di_gbuffers(camera, light, seed=self.seed, centre=True)
        out["gt"] = r.render_gt(camera, light, spp=self.spp, seed=self.seed)
        uv = r.render_uv(camera)
        return out | {"uv": uv["uv"], "position_uv": uv["position"]}

    def touching_light(self) -> tuple[float, float, float]:
        """A light 1e-4 in front of the surface point seen at the local camera's centre pixel (less than
        Mitsuba's ray-spawn offset, ~9e-5 x (1 + |p|)), towards the camera: visible, never occluded."""
        uv = self.renderer.render_uv(self.local)
        rows, cols = np.nonzero(uv["mask"])
        if rows.size == 0:
            raise RuntimeError("the reference view shows no surface")
        h, w = uv["mask"].shape
        i = int(np.argmin((rows - h / 2) ** 2 + (cols - w / 2) ** 2))
        p = uv["position"][rows[i], cols[i]].astype(np.float64)
        towards = np.subtract(self.local.origin, p)
        return tuple(map(float, p + 1e-4 * towards / np.linalg.norm(towards)))

    def gi_map(self, camera=None):
        """A GI map at ``camera`` (default: the GI camera): path-traced GI, its DI, texel depth."""
        from gicore.loop import GIMap, texel_depth

        camera = camera or self.gi_camera
        r = self.renderer
        return GIMap(
            camera,
            r.render_gt(camera, self.light, spp=self.spp, seed=self.seed),
            texel_depth(r, camera),
            r.render_di(camera, self.light),
        )


def _camera_moved(camera, *, back: float = 0.0, turn_deg: float = 0.0):
    """``camera`` moved ``back`` units against its view direction and/or turned ``turn_deg`` about the vertical."""
    o, t = np.asarray(camera.origin), np.asarray(camera.target)
    d = (t - o) / np.linalg.norm(t - o)
    o = o - back * d
    a = math.radians(turn_deg)
    rd = np.array([d[0] * math.cos(a) + d[2] * math.sin(a), d[1], -d[0] * math.sin(a) + d[2] * math.cos(a)])
    return replace(camera, origin=tuple(o), target=tuple(o + rd))


# -- the cases, stage by stage ----------------------------------------------------------------------------------
def render_cases(s: Scene) -> list[Case]:
    from gicore.camera import Camera

    base = s.local
    ref: dict[str, dict[str, np.ndarray]] = {}

    def reference() -> Outcome:
        ref["base"] = s.passes(base)
        return Outcome(tuple(ref["base"].values()))

    def view(camera_fn: Callable[[], Any]) -> Callable[[], Outcome]:
        return lambda: Outcome(tuple(s.passes(camera_fn()).values()))

    def near_far() -> Outcome:
        out = s.passes(replace(base, near=1e-4, far=1e4))
        err = max(_tm_rmse(out[k], ref["base"][k]) for k in ("di", "gt"))
        return Outcome(tuple(out.values()), err, "RMSE vs near/far 0.01/100 (tone-mapped DI, GT)", 1e-4)

    def light_scaled(factor: float) -> Callable[[], Outcome]:
        def run() -> Outcome:
            out = s.passes(base, renderer=s.scaled(factor))
            err = max(_max_rel(out[k] / factor, ref["base"][k]) for k in ("di", "gt") if np.any(ref["base"][k]))
            return Outcome(tuple(out.values()), err, f"max relative |radiance / {factor:g} - reference|", 1e-3)

        return run

    def touching() -> Outcome:
        light = s.touching_light()
        out = s.passes(base, light=light)
        return Outcome(
            tuple(out.values()),
            note=f"light at {np.round(light, 4).tolist()}, peak GT radiance {float(out['gt'].max()):.3g}",
        )

    def black() -> Outcome:
        o = base.origin
        out = s.passes(Camera(o, (o[0], o[1] + 1.0, o[2]), up=(0.0, 0.0, 1.0), width=base.width, height=base.height))
        peak = max(float(np.abs(v).max()) for k, v in out.items() if k in ("di", "gt", "albedo"))
        return Outcome(tuple(out.values()), peak, "max radiance/albedo of a view of empty space", 0.0)

    return [
        Case("render", "reference view (control)", "finite", reference),
        Case("render", "local FOV 1°", "finite", view(lambda: base.with_fov(1.0))),
        Case("render", "local FOV 170°", "finite", view(lambda: base.with_fov(170.0))),
        Case("render", "near/far 1e-4/1e4", "finite", near_far),
        Case("render", "light ×1e4", "finite", light_scaled(1e4)),
        Case("render", "light ×1e-4", "finite", light_scaled(1e-4)),
        Case("render", "light 1e-4 from a surface", "finite", touching),
        Case("render", "black frame (view of empty space)", "finite", black),
        Case(
            "render",
            "degenerate look-at (up ∥ view)",
            "rejected",
            view(lambda: Camera((0.0, 3.0, 0.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))),
        ),
        Case("render", "camera origin = target", "rejected", view(lambda: Camera((1.0, 1.0, 1.0), (1.0, 1.0, 1.0)))),
        Case("render", "NaN camera origin", "rejected", view(lambda: replace(base, origin=(math.nan, 1.0, 1.0)))),
        Case(
            "render",
            "NaN light position",
            "rejected",
            lambda: Outcome((s.renderer.render_di(base, (math.nan, 2.0, 0.0)),)),
        ),
    ]


def tonemap_cases() -> list[Case]:
    from gicore.tonemap import from_signed, inverse_tonemap, tonemap

    def extreme() -> Outcome:
        x = np.concatenate(
            [[0.0, 1e-38, 1e-30], np.logspace(-4, 3, 200), [1e4, 1e30, float(np.finfo(np.float32).max)]]
        ).astype(np.float32)
        y = tonemap(x)
        inside = bool(
            np.all((y >= 0) & (y <= 1)) and np.all(np.diff(y) >= 0)
        )  # float32 x / (1 + x) rounds to 1 past ~1.7e7
        mid = slice(3, 203)
        err = _max_rel(inverse_tonemap(y[mid]), x[mid])
        note = "monotone, in [0, 1]" if inside else "NOT monotone in [0, 1]"
        return Outcome((y,), err if inside else math.inf, "max relative round-trip error on [1e-4, 1e3]", 1e-3, note)

    def black() -> Outcome:
        z = np.zeros((8, 8, 3), np.float32)
        y = tonemap(z)
        return Outcome((y, inverse_tonemap(y)), float(np.abs(inverse_tonemap(y)).max()), "max |T^-1(T(0))|", 0.0)

    def negative() -> Outcome:
        y = tonemap(np.array([-1e30, -1.0, -1e-30], np.float32))
        return Outcome((y,), float(np.abs(y).max()), "max |T(negative)| (clipped to 0)", 0.0)

    def top() -> Outcome:
        x = inverse_tonemap(np.array([1.0, 1.0 + 1e-3], np.float32))
        return Outcome((x,), note=f"T^-1(1) = {float(x[0]):.4g} (clipped below 1)")

    return [
        Case("tonemap", "extreme HDR 0 … 3.4e38", "finite", extreme),
        Case("tonemap", "black", "finite", black),
        Case("tonemap", "negative radiance", "finite", negative),
        Case("tonemap", "inverse at the top of the range", "finite", top),
        Case("tonemap", "NaN radiance", "rejected", lambda: Outcome((tonemap(_with_nan(np.ones(16))),))),
        Case("tonemap", "Inf radiance", "rejected", lambda: Outcome((tonemap(_with_nan(np.ones(16), math.inf)),))),
        Case("tonemap", "NaN network output", "rejected", lambda: Outcome((from_signed(_with_nan(np.zeros(16))),))),
    ]


def inference_cases(s: Scene, model_path: Path) -> list[Case]:
    from gicore.render import Renderer
    from gigan_local.inference import GIModel

    state: dict[str, Any] = {}

    def setup() -> Outcome:
        model = GIModel(model_path, threads=2)
        renderer = s.renderer if model.resolution == s.renderer.resolution else Renderer(s.spec, model.resolution)
        camera = replace(s.gi_camera, width=model.resolution, height=model.resolution)
        buffers = renderer.render_di_gbuffers(camera, s.light, seed=s.seed, centre=True)
        state.update(model=model, renderer=renderer, camera=camera, buffers=buffers)
        gt = renderer.render_gt(camera, s.light, spp=s.spp, seed=s.seed)
        out = model.predict(buffers)
        return Outcome(
            (out,),
            _tm_rmse(out, gt),
            "RMSE vs path-traced GT (tone-mapped)",
            None,
            f"{model_path.name} at {model.resolution}²",
        )

    def on(change: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]]) -> Callable[[], Outcome]:
        return lambda: Outcome((state["model"].predict(change(dict(state["buffers"]))),))

    def at_fov(fov: float) -> Callable[[], Outcome]:
        def run() -> Outcome:
            buffers = state["renderer"].render_di_gbuffers(
                state["camera"].with_fov(fov), s.light, seed=s.seed, centre=True
            )
            return Outcome((state["model"].predict(buffers),))

        return run

    return [
        Case("inference", "reference view (control)", "finite", setup),
        Case("inference", "black buffers", "finite", on(lambda b: {k: np.zeros_like(v) for k, v in b.items()})),
        Case("inference", "DI ×1e4", "finite", on(lambda b: b | {"di": b["di"] * 1e4})),
        Case("inference", "DI 1e30 everywhere", "finite", on(lambda b: b | {"di": np.full_like(b["di"], 1e30)})),
        Case("inference", "depth 1e4 everywhere", "finite", on(lambda b: b | {"depth": np.full_like(b["depth"], 1e4)})),
        Case("inference", "GI camera FOV 1°", "finite", at_fov(1.0)),
        Case("inference", "GI camera FOV 170°", "finite", at_fov(170.0)),
        Case("inference", "NaN in DI", "rejected", on(lambda b: b | {"di": _with_nan(b["di"])})),
        Case("inference", "Inf in depth", "rejected", on(lambda b: b | {"depth": _with_nan(b["depth"], math.inf)})),
        Case("inference", "NaN in normal", "rejected", on(lambda b: b | {"normal": _with_nan(b["normal"])})),
    ]


def warp_cases(s: Scene) -> list[Case]:
    from baseline_cloudbaking.warp import PixelWarp
    from gicore.blend import blend
    from gicore.loop import GIMap, warp_view
    from gigan_local.warp import StructureAwareWarp

    warps = {"structure-aware": lambda: StructureAwareWarp(s.renderer), "pixel-level": PixelWarp}
    maps: dict[Any, Any] = {}

    def gi_map(camera=None):
        key = camera or s.gi_camera
        if key not in maps:
            maps[key] = s.gi_map(camera)
        return maps[key]

    def warped(kind: str, gi, camera) -> tuple[np.ndarray, np.ndarray]:
        w = warps[kind]()
        w.bind(gi)
        di, image, valid = warp_view(w, s.renderer, camera, s.light, seed=s.seed)
        return blend(di, image, 0.0), valid

    def identity(kind: str) -> Outcome:
        gi = gi_map()
        image, valid = warped(kind, gi, gi.camera)
        surface = gi.depth > 0
        err = float(np.abs(image - gi.radiance)[surface].max()) if surface.any() else 0.0
        return Outcome((image,), err, "max |warped - map| on surface pixels", 1e-5, f"valid {valid.mean():.3f}")

    def against_gt(kind: str, camera_fn: Callable[[], Any], gi_fov: float | None = None) -> Callable[[], Outcome]:
        def run() -> Outcome:
            camera = camera_fn()
            gi = gi_map(s.gi_camera.with_fov(gi_fov) if gi_fov else None)
            image, valid = warped(kind, gi, camera)
            gt = s.renderer.render_gt(camera, s.light, spp=s.spp, seed=s.seed)
            return Outcome(
                (image,),
                _tm_rmse(image, gt),
                "RMSE vs path-traced GT at the local camera (tone-mapped)",
                None,
                f"valid {valid.mean():.3f}",
            )

        return run

    def black(kind: str) -> Outcome:
        image, valid = warped(kind, GIMap.blank(s.gi_camera), s.local)
        return Outcome((image,), note=f"valid {valid.mean():.3f}, max {float(image.max()):.3g}")

    def bad_map(kind: str, what: str) -> Callable[[], Outcome]:
        def run() -> Outcome:
            gi = gi_map()
            bad = (
                replace(gi, radiance=_with_nan(gi.radiance))
                if what == "radiance"
                else replace(gi, depth=_with_nan(gi.depth, math.inf))
            )
            return Outcome(warped(kind, bad, s.local))

        return run

    cases = []
    for kind in warps:
        local = s.local
        cases += [
            Case("warp", f"{kind}: zero motion (identity)", "finite", lambda k=kind: identity(k)),
            Case("warp", f"{kind}: reference view (control)", "finite", against_gt(kind, lambda: local)),
            Case(
                "warp",
                f"{kind}: local camera 1 unit behind the GI camera",
                "finite",
                against_gt(kind, lambda: _camera_moved(s.gi_camera.with_fov(60.0), back=1.0)),
            ),
            Case(
                "warp",
                f"{kind}: local camera at the GI camera plane, turned 90°",
                "finite",
                against_gt(kind, lambda: _camera_moved(local, turn_deg=90.0)),
            ),
            Case(
                "warp",
                f"{kind}: local camera turned 180° (all behind)",
                "finite",
                against_gt(kind, lambda: _camera_moved(local, turn_deg=180.0)),
            ),
            Case("warp", f"{kind}: GI camera FOV 1°", "finite", against_gt(kind, lambda: local, gi_fov=1.0)),
            Case("warp", f"{kind}: GI camera FOV 170°", "finite", against_gt(kind, lambda: local, gi_fov=170.0)),
            Case("warp", f"{kind}: local FOV 1°", "finite", against_gt(kind, lambda: local.with_fov(1.0))),
            Case("warp", f"{kind}: local FOV 170°", "finite", against_gt(kind, lambda: local.with_fov(170.0))),
            Case("warp", f"{kind}: black GI map", "finite", lambda k=kind: black(k)),
            Case("warp", f"{kind}: NaN in the GI map", "rejected", bad_map(kind, "radiance")),
            Case("warp", f"{kind}: Inf in the GI depth", "rejected", bad_map(kind, "depth")),
        ]
    return cases


def composition_cases() -> list[Case]:
    from gicore.blend import blend, residual

    rng = np.random.default_rng(0)
    hdr = (10.0 ** rng.uniform(-30, 30, (16, 16, 3))).astype(np.float32)
    other = (10.0 ** rng.uniform(-30, 30, (16, 16, 3))).astype(np.float32)
    zeros = np.zeros_like(hdr)

    def blend_case(tau: float) -> Callable[[], Outcome]:
        def run() -> Outcome:
            out = blend(hdr, other, tau)
            ref = tau * hdr.astype(np.float64) + (1 - tau) * other.astype(np.float64)
            return Outcome((out,), _max_rel(out, ref), "max relative error vs float64 eq. 1", 1e-6)

        return run

    def residual_case() -> Outcome:
        out = residual(hdr, other, zeros)
        return Outcome((out,), _max_rel(out, hdr.astype(np.float64) + other), "max relative error vs float64", 1e-6)

    return [
        Case("composition", "blend τ=0, HDR 1e-30 … 1e30", "finite", blend_case(0.0)),
        Case("composition", "blend τ=0.5, HDR 1e-30 … 1e30", "finite", blend_case(0.5)),
        Case("composition", "blend τ=1, HDR 1e-30 … 1e30", "finite", blend_case(1.0)),
        Case("composition", "residual, HDR 1e-30 … 1e30", "finite", residual_case),
        Case(
            "composition",
            "blend of black frames",
            "finite",
            lambda: Outcome((b := blend(zeros, zeros, 0.3),), float(np.abs(b).max()), "max |blend|", 0.0),
        ),
        Case("composition", "NaN in the GI map", "rejected", lambda: Outcome((blend(hdr, _with_nan(other), 0.5),))),
        Case(
            "composition",
            "Inf in the DI (residual)",
            "rejected",
            lambda: Outcome((residual(_with_nan(hdr, math.inf), other, zeros),)),
        ),
        Case("composition", "τ = 1.5", "rejected", lambda: Outcome((blend(hdr, other, 1.5),))),
        Case("composition", "shape mismatch", "rejected", lambda: Outcome((blend(hdr, other[:8], 0.5),))),
    ]


def codec_cases(s: Scene) -> list[Case]:
    from baseline_cloudbaking.codecs import CODECS, DEPTH_CODEC
    from baseline_cloudbaking.codecs import measure as measure_codec

    side = 64
    ramp = np.logspace(-30, 30, side * side * 3, dtype=np.float64).reshape(side, side, 3).astype(np.float32)
    maps = {
        "extreme HDR 1e-30 … 1e30": ramp,
        "black": np.zeros((side, side, 3), np.float32),
        "tiny values 1e-38": np.full((side, side, 3), 1e-38, np.float32),
    }
    rendered: dict[str, np.ndarray] = {}

    def round_trip(codec, image_fn: Callable[[], np.ndarray]) -> Callable[[], Outcome]:
        def run() -> Outcome:
            image = image_fn()
            report, data, decoded = measure_codec(codec, image)
            if codec.lossless:
                err = float(np.abs(decoded - codec.quantize(image)).max())
                return Outcome((decoded,), err, "max |decoded - quantized input| (lossless)", 0.0, f"{report.bytes} B")
            return Outcome((decoded,), report.rmse, "RMSE vs input (tone-mapped)", codec.max_rmse, f"{report.bytes} B")

        return run

    def rendered_map() -> np.ndarray:
        if "gi" not in rendered:
            rendered["gi"] = s.renderer.render_gt(s.gi_camera, s.light, spp=s.spp, seed=s.seed)
        return rendered["gi"]

    def corrupt(codec) -> Outcome:
        data = codec.encode(maps["black"])
        return Outcome((codec.decode(data[: len(data) // 2] + b"\x00" * 7),))

    cases = []
    for name, codec in CODECS.items():
        for label, image in maps.items():
            cases.append(Case("codecs", f"{name}: {label}", "finite", round_trip(codec, lambda im=image: im)))
        cases += [
            Case("codecs", f"{name}: rendered GI map", "finite", round_trip(codec, rendered_map)),
            Case(
                "codecs",
                f"{name}: NaN in the map",
                "rejected",
                lambda c=codec: Outcome((c.encode(_with_nan(maps["black"])),)),
            ),
            Case("codecs", f"{name}: truncated bytes", "rejected", lambda c=codec: corrupt(c)),
        ]

    def depth_extremes() -> Outcome:
        depth = np.array([[0.0, 1e-4, 1.0, 1e4, 65504.0]] * 4, np.float32)
        decoded = DEPTH_CODEC.decode(DEPTH_CODEC.encode(depth))
        nz = depth > 6.1e-5  # float16's smallest normal: below it the relative bound does not hold
        err = _max_rel(decoded[nz], depth[nz])
        return Outcome((decoded,), err, "max relative depth error (normal float16 range)", DEPTH_CODEC.max_rel_error)

    cases += [
        Case("codecs", "depth: 0 … 65504", "finite", depth_extremes),
        Case(
            "codecs",
            "depth: 1e5 (beyond float16)",
            "rejected",
            lambda: Outcome((DEPTH_CODEC.encode(np.full((4, 4), 1e5, np.float32)),)),
        ),
        Case("codecs", "depth: NaN", "rejected", lambda: Outcome((DEPTH_CODEC.encode(_with_nan(np.ones((4, 4)))),))),
        Case(
            "codecs",
            "depth: negative",
            "rejected",
            lambda: Outcome((DEPTH_CODEC.encode(np.full((4, 4), -1.0, np.float32)),)),
        ),
    ]
    return cases


def store_cases(work: Path) -> list[Case]:
    from baseline_cloudbaking.store import GITree
    from baseline_cloudbaking.viewpoints import MapKey, Tolerance, Viewpoint

    key = MapKey("stability", None, 64, 90.0, "jpeg", 4, False)
    payload = b"GIM1" + bytes(range(256)) * 8

    @contextmanager
    def tree(name: str, **kwargs: Any) -> Iterator[GITree]:
        root = work / name
        shutil.rmtree(root, ignore_errors=True)
        with GITree(root, **kwargs) as t:
            t.register_scene("stability", "0" * 64, None)
            yield t

    def exact(eye: tuple[float, float, float], tol: Tolerance, name: str) -> Callable[[], Outcome]:
        def run() -> Outcome:
            with tree(name, tolerance=tol) as t:
                view = Viewpoint.look_at(eye, (0.0, 0.0, 0.0))
                t.insert(key, view, payload)
                hit = t.lookup(key, view)
                if hit is None or hit.payload != payload:
                    raise RuntimeError("a stored viewpoint was not found again at distance 0")
                return Outcome(
                    (hit.distance, hit.angle_deg), hit.distance + hit.angle_deg, "distance + angle of the hit", 1e-9
                )

        return run

    def over_budget() -> Outcome:
        with tree("budget", budget_bytes=1024) as t:
            if t.insert(key, Viewpoint.look_at((1.0, 1.0, 1.0), (0.0, 0.0, 0.0)), payload) is None:
                raise Rejected(
                    f"a {len(payload)}-byte payload over the 1024-byte budget is not stored (counted as rejected)"
                )
            return Outcome(note="stored beyond its budget")

    return [
        Case("store", "zero tolerance: exact hit", "finite", exact((1.0, 2.0, 3.0), Tolerance(0.0, 0.0), "zero_tol")),
        Case("store", "eye at 1e4 (the request bound)", "finite", exact((1e4, 1e4, 1e4), Tolerance(), "far")),
        Case("store", "eye at 1e-4 from the target", "finite", exact((1e-4, 0.0, 0.0), Tolerance(), "near")),
        Case(
            "store",
            "NaN viewpoint",
            "rejected",
            lambda: Outcome((Viewpoint.look_at((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0)).eye,)),
        ),
        Case(
            "store",
            "eye = target",
            "rejected",
            lambda: Outcome((Viewpoint.look_at((1.0, 1.0, 1.0), (1.0, 1.0, 1.0)).eye,)),
        ),
        Case("store", "NaN tolerance", "rejected", lambda: Outcome((Tolerance(math.nan, 1.0).position,))),
        Case("store", "payload over the byte budget", "rejected", over_budget),
    ]


#: The dead and stiff links of the network cases: name -> one direction's settings (both directions alike).
DEAD_LINKS = {
    "zero bandwidth": {"rate_mbit": 0.0},
    "100 % loss": {"loss": 1.0},
    f"{DELAY_MS_MAX / 1e3:g} s one-way delay (the proxy's bound)": {"delay_ms": DELAY_MS_MAX},
}


def link_model_cases() -> list[Case]:
    from network_sim.link import DOWN, UP, DirectionConfig, Link, LinkConfig

    request, response = 600, 40_000

    def exchange(settings: dict[str, float]) -> Callable[[], Outcome]:
        def run() -> Outcome:
            direction = DirectionConfig(**settings)
            link = Link(LinkConfig(up=direction, down=direction))
            arrived = link.message(0, UP, request, 0.0)
            done = link.message(0, DOWN, response, arrived) if math.isfinite(arrived) else math.inf
            if not math.isfinite(done):
                raise Rejected(
                    "the model never delivers the request/response (release time inf): a client sees its timeout"
                )
            expected = 2 * direction.delay_ms / 1e3
            return Outcome(
                (done,),
                abs(done - expected) / expected,
                "relative error vs 2 × one-way delay",
                1e-9,
                f"response after {done:.6g} s",
            )

        return run

    expect: dict[str, Expect] = {name: "finite" if "delay" in name else "rejected" for name in DEAD_LINKS}
    return [
        Case("network", f"link model: {name}", expect[name], exchange(settings))
        for name, settings in DEAD_LINKS.items()
    ]


def process_cases(s: Scene, cfg: StabilityConfig, server_url: str, scene_name: str, stack: ExitStack) -> list[Case]:
    """Cases against the real server process: through real proxies (network) and directly (server)."""
    import httpx

    from baseline_cloudbaking.client import RemoteConfig, RemoteSource
    from baseline_cloudbaking.protocol import decode_payload
    from network_sim.process import network_sim

    body = {"scene": scene_name, "camera": {"eye": list(s.gi_camera.origin), "target": list(s.gi_camera.target)},
            "resolution": cfg.resolution, "spp": cfg.spp, "codec": "jpeg"}  # fmt: skip
    if s.spec.light.moves:
        body["light"] = list(s.light)

    def through_proxy(flags: list[str], timeout: float) -> Callable[[], Outcome]:
        def run() -> Outcome:
            proxy = stack.enter_context(
                network_sim("proxy", "--upstream", server_url.removeprefix("http://"), *flags, timeout=30.0)
            )
            remote = RemoteConfig(f"http://{proxy.addr[0]}:{proxy.addr[1]}", scene_name, cfg.resolution, "jpeg",
                                  cfg.spp, False, s.spec.light.moves, connect_timeout_s=timeout,
                                  read_timeout_s=timeout, deadline_s=2 * timeout, retry_after_s=0.0)  # fmt: skip
            with RemoteSource(remote) as source:
                source.request(s.gi_camera, s.light, 0)
                if not source.wait(4 * timeout + 5.0):
                    raise RuntimeError(
                        f"the client's request is still in flight {4 * timeout + 5:g} s later despite its timeouts"
                    )
                record = source.records[-1]
                gi = source.latest()
            if record["status"] != "ok":
                raise Rejected(
                    f"client gave up after {float(record['latency_ms']) / 1e3:.2f} s: "
                    f"{record['status']}: {record['error']}"
                )
            return Outcome((gi.radiance, gi.depth), note=f"map in {float(record['latency_ms']):.0f} ms")

        return run

    # the control asks for the map the server case "valid request" baked (a hit), with room for a miss's render
    network = [
        Case(
            "network",
            "proxy + client: LAN profile (control)",
            "finite",
            through_proxy(["--profile", "lan"], cfg.case_timeout_s / 3),
        )
    ]
    for name, settings in DEAD_LINKS.items():
        flag, value = next(iter(settings.items()))
        flags = [f"--{flag.replace('_', '-')}", f"{value:g}"]
        network.append(
            Case("network", f"proxy + client: {name}", "rejected", through_proxy(flags, cfg.client_timeout_s))
        )

    def post(content: bytes | str, expect_ok: bool = False) -> Callable[[], Outcome]:
        def run() -> Outcome:
            r = httpx.post(
                f"{server_url}/v1/gimap",
                content=content,
                headers={"content-type": "application/json"},
                timeout=cfg.case_timeout_s,
            )
            if r.status_code >= 500:
                raise RuntimeError(f"HTTP {r.status_code}: {r.text[:200]}")
            if r.status_code != 200:
                detail = r.json().get("detail")
                where = (
                    "/".join(map(str, detail[0]["loc"]))
                    if isinstance(detail, list) and detail and "loc" in detail[0]
                    else "?"
                )
                msg = detail[0].get("msg", "") if isinstance(detail, list) and detail else str(detail)
                raise Rejected(f"HTTP {r.status_code} at {where}: {msg}")
            payload = decode_payload(r.content)
            return Outcome((payload.gi, payload.depth), note=f"HTTP 200, {len(r.content)} B, hit={payload.hit}")

        return run

    def with_camera(**camera: Any) -> bytes:
        return json.dumps(body | {"camera": body["camera"] | camera}).encode()

    far = 1e4
    cases = [
        Case("server", "valid request (control)", "finite", post(json.dumps(body))),
        Case("server", "GI camera FOV 170°", "finite", post(with_camera(fov=170.0))),
        Case("server", "GI camera FOV 1°", "finite", post(with_camera(fov=1.0))),
        Case("server", "eye at 1e4 (the coordinate bound)", "finite", post(with_camera(eye=[far, far, far], fov=1.0))),
        Case("server", "malformed JSON", "rejected", post(b'{"scene": "x", "camera": ')),
        Case("server", "empty body", "rejected", post(b"")),
        Case("server", "NaN eye", "rejected", post(with_camera(eye=[math.nan, 1.0, 1.0]))),  # json.dumps writes NaN
        Case("server", "Infinity FOV", "rejected", post(with_camera(fov=math.inf))),
        Case("server", "FOV 0°", "rejected", post(with_camera(fov=0.0))),
        Case("server", "FOV 180°", "rejected", post(with_camera(fov=180.0))),
        Case(
            "server",
            "degenerate look-at (up ∥ view)",
            "rejected",
            post(with_camera(eye=[0.0, 3.0, 0.0], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0])),
        ),
        Case("server", "eye = target", "rejected", post(with_camera(eye=[0.5, 0.5, 0.5], target=[0.5, 0.5, 0.5]))),
        Case("server", "eye at 1e5 (beyond the bound)", "rejected", post(with_camera(eye=[1e5, 0.0, 0.0]))),
        Case("server", "resolution not served", "rejected", post(json.dumps(body | {"resolution": 100}))),
        Case("server", "spp above the server's maximum", "rejected", post(json.dumps(body | {"spp": 10**9}))),
        Case("server", "unknown scene", "rejected", post(json.dumps(body | {"scene": "no_such_scene"}))),
        Case("server", "unknown field", "rejected", post(json.dumps(body | {"extra": 1}))),
        Case("server", "1 MB body", "rejected", post(json.dumps(body | {"pad": "x" * 1_000_000}))),
    ]
    if s.spec.light.moves:
        cases.append(touching_light_case(s, body, post))
    return cases + network


def touching_light_case(s: Scene, body: dict[str, Any], post: Callable[[str], Callable[[], Outcome]]) -> Case:
    """A light 1e-4 from a surface, sent to the server: baked where the scene's light can be there, otherwise
    refused, since the server only bakes lights within the range the scene's light sweeps (plus a light cell)."""
    from baseline_cloudbaking.server.service import light_bounds
    from baseline_cloudbaking.server.settings import Settings

    light = s.touching_light()
    low, high = light_bounds(s.spec, Settings.model_fields["light_cell"].default)
    inside = all(lo <= v <= hi for v, lo, hi in zip(light, low, high))
    name = "light 1e-4 from a surface" + ("" if inside else " (outside the scene's light range)")
    return Case("server", name, "finite" if inside else "rejected", post(json.dumps(body | {"light": list(light)})))


@contextmanager
def server_process(store: Path, scene: str, max_spp: int) -> Iterator[str]:
    """A real ``cloudbaking-server`` on an ephemeral port (serving ``scene``'s folder if it is a file); its URL."""
    from network_sim.process import Running

    argv = [str(BIN / "cloudbaking-server"), "--port", "0", "--store", str(store), "--max-spp", str(max_spp)]
    if Path(scene).suffix:
        argv += ["--scenes", str(Path(scene).resolve().parent)]
    with Running(argv, timeout=120.0) as server:
        host, port = server.addr
        yield f"{host}:{port}"  # host is "http://127.0.0.1" (the server prints a URL)


# -- the bench ------------------------------------------------------------------------------------------------
def cases(cfg: StabilityConfig, s: Scene, work: Path) -> list[Case]:
    """Every case that needs no process (the process cases are added by :func:`measure`)."""
    return [
        *render_cases(s),
        *tonemap_cases(),
        *inference_cases(s, cfg.model),
        *warp_cases(s),
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
    work = res.out / "stability_work"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    scene = cfg.scenes[0]
    s = Scene.load(scene, cfg.resolution, cfg.spp, res.seed)
    failures: list[str] = []
    with ExitStack() as stack:
        todo = cases(cfg, s, work)
        if cfg.processes:
            url = stack.enter_context(server_process(work / "server_store", scene, max(cfg.spp, 1)))
            todo += process_cases(s, cfg, url, Path(scene).stem, stack)
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


# -- table, plot, verdict (from the CSV only) ---------------------------------------------------------------
def summary(rows: list[dict]) -> list[dict[str, Any]]:
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


def table(entries: list[dict[str, Any]]) -> str:
    """``stability_table.md``: the counts, then one line per case."""
    n = counts(entries)
    lines = [
        f"## Numerical stability: {n['cases']} cases, {n['finite']} finite, "
        f"{n['rejected']} cleanly rejected, {n['failed']} failed",
        "",
        "| stage | case | expected | outcome | error (bound) | time (ms) | message |",
        "|---|---|---|---|---|---|---|",
    ]
    for e in entries:
        err = (
            "—" if e["error"] is None else f"{e['error']:.3g}" + ("" if e["bound"] is None else f" (≤ {e['bound']:g})")
        )
        message = e["message"].replace("|", "\\|")
        lines.append(
            f"| {e['stage']} | {e['case']} | {e['expect']} | {e['status']} | {err} | {e['time_ms']:.1f} | {message} |"
        )
    return "\n".join(lines) + "\n"


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """``stability_table.md`` and a bar per stage (finite / rejected / failed cases); then the verdict: any
    failed case is a :class:`UserError` naming them (exit status 2), raised after the files are written."""
    from gicore.plotting import plt, save

    entries = summary(read_rows(csv_path))
    md = out_dir / "stability_table.md"
    md.write_text(table(entries))
    stages = list(dict.fromkeys(e["stage"] for e in entries))
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(stages) + 1.6))
    left = np.zeros(len(stages))
    for label, colour, test in (
        ("finite", "tab:green", lambda e: e["status"] == "finite"),
        ("cleanly rejected", "tab:blue", lambda e: e["status"] == "rejected"),
        ("failed", "tab:red", lambda e: e["status"] not in PASSED),
    ):
        values = np.array([sum(test(e) for e in entries if e["stage"] == st) for st in stages], float)
        ax.barh(stages, values, left=left, color=colour, label=label)
        left += values
    ax.invert_yaxis()
    ax.set_xlabel("cases")
    ax.legend(fontsize=8, loc="lower right")
    n = counts(entries)
    ax.set_title(f"Stability: {n['cases']} extreme cases, {n['failed']} failed")
    written = [md, save(fig, out_dir / "stability.png")]
    failed = [e for e in entries if e["status"] not in PASSED]
    if failed:
        names = "; ".join(f"{e['stage']}/{e['case']} ({e['status'].removeprefix('FAIL: ')})" for e in failed)
        raise UserError(
            f"{len(failed)} of {n['cases']} stability cases failed: {names}",
            f"see {md} (and stability_failures.txt for tracebacks)",
        )
    return written


# -- bench report: the dashboard's section and the README's block ------------------------------------------
def dashboard_section(rows: Rows) -> list[Part]:
    """The failed cases by name (if any), then every case (a wide table: it scrolls)."""
    need(rows, "status")
    entries = summary(rows)
    failed = [e for e in entries if e["status"] not in PASSED]
    alert = "Failed cases: " + "; ".join(f"{e['stage']}/{e['case']} ({e['status']})" for e in failed)
    return [*([Alert(alert)] if failed else []), Table(table(entries), scroll=True)]


def readme_block(rows: Rows) -> list[Table]:
    """The stability cases: the counts, per stage, and the failed cases by name."""
    need(rows, "status")
    entries = summary(rows)
    n = counts(entries)
    lines = [
        f"**{n['cases']} cases: {n['finite']} finite, {n['rejected']} cleanly rejected, {n['failed']} failed** "
        "(crashed, hung or went non-finite).",
        "",
        "| stage | cases | finite | cleanly rejected | failed |",
        "|---|---|---|---|---|",
    ]
    for stage in dict.fromkeys(e["stage"] for e in entries):
        c = counts([e for e in entries if e["stage"] == stage])
        lines.append(f"| {stage} | {c['cases']} | {c['finite']} | {c['rejected']} | {c['failed']} |")
    failed = [f"{e['stage']}/{e['case']} ({e['status']})" for e in entries if e["status"] not in PASSED]
    return [Table("\n".join(lines) + ("\n\nFailed: " + "; ".join(failed) + "." if failed else ""))]


BENCH = Bench(
    "stability",
    StabilityConfig,
    measure,
    plot,
    help="Extreme and stiff inputs through every stage (render, tone map, inference, warps, composition, "
    "codecs, store, network, server); finite or cleanly rejected, never a crash or a hang (exit 2 naming any failed "
    "case).",
    dashboard=Section("stability", "Numerical stability", 80, dashboard_section),
    readme=Block("Numerical stability", 100, readme_block),
)
