"""The extreme inputs GIGAN's inference must survive, as :class:`gicore.stability.Case` lists: black and huge
buffers, extreme GI camera FOVs and NaN/Inf in every input; ``bench stability`` judges them."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from gicore.stability import Case, Outcome, Scene, tm_rmse, with_nan


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
            tm_rmse(out, gt),
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
        Case("inference", "NaN in DI", "rejected", on(lambda b: b | {"di": with_nan(b["di"])})),
        Case("inference", "Inf in depth", "rejected", on(lambda b: b | {"depth": with_nan(b["depth"], math.inf)})),
        Case("inference", "NaN in normal", "rejected", on(lambda b: b | {"normal": with_nan(b["normal"])})),
    ]
