"""The extreme inputs gicore's own stages must survive, as :class:`gicore.stability.Case` lists: render, tone
map, warp and composition. The warps themselves belong to the systems, so :func:`warp_cases` takes them as
factories (``bench stability`` wires both systems' warps); ``bench stability`` judges every case."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from gicore.stability import Case, Outcome, Scene, max_rel, tm_rmse, with_nan

if TYPE_CHECKING:
    from gicore.loop import Warp

#: Builds a warp (bound to a GI map by the case) for the scene's renderer.
WarpFactory = Callable[[Any], "Warp"]


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
        err = max(tm_rmse(out[k], ref["base"][k]) for k in ("di", "gt"))
        return Outcome(tuple(out.values()), err, "RMSE vs near/far 0.01/100 (tone-mapped DI, GT)", 1e-4)

    def light_scaled(factor: float) -> Callable[[], Outcome]:
        def run() -> Outcome:
            out = s.passes(base, renderer=s.scaled(factor))
            err = max(max_rel(out[k] / factor, ref["base"][k]) for k in ("di", "gt") if np.any(ref["base"][k]))
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
        err = max_rel(inverse_tonemap(y[mid]), x[mid])
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
        Case("tonemap", "NaN radiance", "rejected", lambda: Outcome((tonemap(with_nan(np.ones(16))),))),
        Case("tonemap", "Inf radiance", "rejected", lambda: Outcome((tonemap(with_nan(np.ones(16), math.inf)),))),
        Case("tonemap", "NaN network output", "rejected", lambda: Outcome((from_signed(with_nan(np.zeros(16))),))),
    ]


class Warps:
    """The warp cases' runs: each warp binds a GI map of the scene (made once per GI camera) and warps it."""

    def __init__(self, s: Scene, warps: Mapping[str, WarpFactory]) -> None:
        self.s = s
        #: Case label -> the factory of its warp.
        self.kinds = dict(warps)
        self.maps: dict[Any, Any] = {}

    def gi_map(self, camera: Any = None) -> Any:
        key = camera or self.s.gi_camera
        if key not in self.maps:
            self.maps[key] = self.s.gi_map(camera)
        return self.maps[key]

    def warped(self, kind: str, gi: Any, camera: Any) -> tuple[np.ndarray, np.ndarray]:
        from gicore.blend import blend
        from gicore.loop import warp_view

        w = self.kinds[kind](self.s.renderer)
        w.bind(gi)
        di, image, valid = warp_view(w, self.s.renderer, camera, self.s.light, seed=self.s.seed)
        return blend(di, image, 0.0), valid

    def identity(self, kind: str) -> Callable[[], Outcome]:
        def run() -> Outcome:
            gi = self.gi_map()
            image, valid = self.warped(kind, gi, gi.camera)
            surface = gi.depth > 0
            err = float(np.abs(image - gi.radiance)[surface].max()) if surface.any() else 0.0
            return Outcome((image,), err, "max |warped - map| on surface pixels", 1e-5, f"valid {valid.mean():.3f}")

        return run

    def against_gt(self, kind: str, camera_fn: Callable[[], Any], gi_fov: float | None = None) -> Callable[[], Outcome]:
        s = self.s

        def run() -> Outcome:
            camera = camera_fn()
            image, valid = self.warped(kind, self.gi_map(s.gi_camera.with_fov(gi_fov) if gi_fov else None), camera)
            gt = s.renderer.render_gt(camera, s.light, spp=s.spp, seed=s.seed)
            what = "RMSE vs path-traced GT at the local camera (tone-mapped)"
            return Outcome((image,), tm_rmse(image, gt), what, None, f"valid {valid.mean():.3f}")

        return run

    def black(self, kind: str) -> Callable[[], Outcome]:
        from gicore.gi_map import GIMap

        def run() -> Outcome:
            image, valid = self.warped(kind, GIMap.blank(self.s.gi_camera), self.s.local)
            return Outcome((image,), note=f"valid {valid.mean():.3f}, max {float(image.max()):.3g}")

        return run

    def bad_map(self, kind: str, what: str) -> Callable[[], Outcome]:
        def run() -> Outcome:
            gi = self.gi_map()
            radiance, depth = (
                (with_nan(gi.radiance), gi.depth) if what == "radiance" else (gi.radiance, with_nan(gi.depth, math.inf))
            )
            return Outcome(self.warped(kind, replace(gi, linear=radiance, depth=depth, display=None), self.s.local))

        return run


def warp_cases(s: Scene, warps: Mapping[str, WarpFactory]) -> list[Case]:
    """Every warp case for each warp of ``warps`` (case label -> factory), in its order."""
    w = Warps(s, warps)
    local, gi = s.local, s.gi_camera
    cases = []
    for kind in w.kinds:
        cases += [
            Case("warp", f"{kind}: zero motion (identity)", "finite", w.identity(kind)),
            Case("warp", f"{kind}: reference view (control)", "finite", w.against_gt(kind, lambda: local)),
            Case("warp", f"{kind}: local camera 1 unit behind the GI camera", "finite",
                 w.against_gt(kind, lambda: gi.with_fov(60.0).moved(back=1.0))),
            Case("warp", f"{kind}: local camera at the GI camera plane, turned 90°", "finite",
                 w.against_gt(kind, lambda: local.turned(90.0))),
            Case("warp", f"{kind}: local camera turned 180° (all behind)", "finite",
                 w.against_gt(kind, lambda: local.turned(180.0))),
            Case("warp", f"{kind}: GI camera FOV 1°", "finite", w.against_gt(kind, lambda: local, gi_fov=1.0)),
            Case("warp", f"{kind}: GI camera FOV 170°", "finite", w.against_gt(kind, lambda: local, gi_fov=170.0)),
            Case("warp", f"{kind}: local FOV 1°", "finite", w.against_gt(kind, lambda: local.with_fov(1.0))),
            Case("warp", f"{kind}: local FOV 170°", "finite", w.against_gt(kind, lambda: local.with_fov(170.0))),
            Case("warp", f"{kind}: black GI map", "finite", w.black(kind)),
            Case("warp", f"{kind}: NaN in the GI map", "rejected", w.bad_map(kind, "radiance")),
            Case("warp", f"{kind}: Inf in the GI depth", "rejected", w.bad_map(kind, "depth")),
        ]  # fmt: skip
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
            return Outcome((out,), max_rel(out, ref), "max relative error vs float64 eq. 1", 1e-6)

        return run

    def residual_case() -> Outcome:
        out = residual(hdr, other, zeros)
        return Outcome((out,), max_rel(out, hdr.astype(np.float64) + other), "max relative error vs float64", 1e-6)

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
        Case("composition", "NaN in the GI map", "rejected", lambda: Outcome((blend(hdr, with_nan(other), 0.5),))),
        Case(
            "composition",
            "Inf in the DI (residual)",
            "rejected",
            lambda: Outcome((residual(with_nan(hdr, math.inf), other, zeros),)),
        ),
        Case("composition", "τ = 1.5", "rejected", lambda: Outcome((blend(hdr, other, 1.5),))),
        Case("composition", "shape mismatch", "rejected", lambda: Outcome((blend(hdr, other[:8], 0.5),))),
    ]
