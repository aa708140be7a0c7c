"""`bench frequency` (paper Table 3): GI-map period k against frame rate and quality, with and without
warping, for both compositions.

Each configuration runs the shared client loop (:func:`gicore.loop.run_frames`) along the scene's camera
path (``orbit_frames`` frames per full orbit) with a new GI map every k frames, from GIGAN's source
(:mod:`gigan_local.client`) brought to the view by GIGAN's warp, cloud baking's, or none
(:func:`bench.common.make_warp`). Frame rate: the median per-frame client work plus the mean cost of
one GI map spread over its k frames (:func:`gicore.frame_rows.amortized_fps`); the GI-map cost is whatever the
configured source costs -- the generator's inference (``gi_source = "model"``) or, by default, the
path-traced GT stand-in, which is far slower than a network -- unless ``inference_ms`` replaces it with a
given inference time. Quality:
SSIM/PSNR of the composed frame against the path-traced GT at the local camera every ``gt_every`` frames,
averaged. GI maps and GT renders are cached across configurations, so every configuration sees the same
maps and the same references.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Literal

from bench.common import WARP_LABELS, WARPS, make_warp
from bench.runner import Bench, Block, Section
from gicore import option_groups
from gicore.blend import COMPOSITIONS
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, per, pick, spread, unique, wide
from gicore.results import Results
from gigan_local.client import GI_SOURCES
from gigan_local.inference import DEFAULT_MODEL, check_model_resolution


@dataclass(frozen=True)
class FrequencyConfig:
    """The parameter grid of one run."""

    scenes: tuple[str, ...] = option_groups.scenes()
    resolution: int = option_groups.resolution()
    #: GI-map periods k (a new GI map every k frames).
    ks: tuple[int, ...] = (1, 10, 20, 30, 60)
    #: Client frames per configuration.
    frames: int = 120
    #: Warp methods compared.
    warps: tuple[Literal[WARPS], ...] = ("structure", "pixel", "none")
    #: How the GI map and the DI frame are composed.
    compositions: tuple[Literal[COMPOSITIONS], ...] = ("blend", "residual")
    #: Blend threshold of the composition (0: plain blend).
    tau: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})
    #: Score the composed frame against path-traced GT every this many frames.
    gt_every: int = 4
    orbit_frames: int = option_groups.orbit_frames()
    spp: int = option_groups.spp(note="of the path-traced GT: the gt GI source and the evaluation GT")
    denoise: bool = option_groups.denoise()
    #: Where GI maps come from: the path-traced GT stand-in, or the generator (--model).
    gi_source: Literal[GI_SOURCES] = "gt"
    #: ONNX generator for --gi-source model (gigan-export output).
    model: Path = DEFAULT_MODEL
    #: When set, the cost of one GI map in the fps (ms) instead of the source's measured cost.
    inference_ms: float | None = None

    @classmethod
    def quick(cls) -> FrequencyConfig:
        return cls(frames=60, gt_every=6, spp=16)

    def check(self) -> None:
        if self.gi_source == "model":
            check_model_resolution(self.model, self.resolution)


def measure(cfg: FrequencyConfig, res: Results) -> None:
    from gicore.frame_rows import summarize
    from gicore.ground_truth import GroundTruth
    from gicore.loop import ClientLoop, LoopConfig, run_frames
    from gicore.paths import path_views
    from gicore.render import Renderer
    from gicore.scene import load_scene
    from gigan_local.client import ClientConfig, check_denoiser, make_gi_source

    check_denoiser(cfg.denoise)
    for scene in cfg.scenes:
        spec = load_scene(scene)
        renderer = Renderer(spec, cfg.resolution)
        cache: dict = {}  # GI maps and GT renders, shared by every configuration
        client = ClientConfig(
            scene=scene,
            resolution=cfg.resolution,
            gi_source=cfg.gi_source,
            model=cfg.model,
            spp=cfg.spp,
            denoise=cfg.denoise,
            seed=res.seed,
        )
        source = make_gi_source(client, renderer, cache)
        ground_truth = GroundTruth(renderer, cfg.gt_every, cfg.spp, cfg.denoise, res.seed, cache)
        local_fov = spec.camera.local_fov
        views = path_views(spec, cfg.frames, cfg.orbit_frames, res.seed, local_fov, cfg.resolution)
        for k, warp, composition in itertools.product(cfg.ks, cfg.warps, cfg.compositions):
            gi_fov = local_fov if warp == "none" else spec.camera.gi_fov  # pasting needs a map made at the local FOV
            loop_cfg = LoopConfig(every=k, gi_fov=gi_fov, composition=composition, tau=cfg.tau, seed=res.seed)
            loop = ClientLoop(loop_cfg, renderer, source, make_warp(warp, renderer, composition))
            run = summarize(run_frames(loop, views, ground_truth), k)
            gi_ms = cfg.inference_ms if cfg.inference_ms is not None else run["gi_ms"]
            config = {
                "k": k,
                "composition": composition,
                "tau": cfg.tau,
                "gi_source": cfg.gi_source,
                "resolution": cfg.resolution,
                "frames": cfg.frames,
                "spp": cfg.spp,
                "orbit_frames": cfg.orbit_frames,
            }
            add = partial(res.add, system=WARP_LABELS[warp], scene=spec.name, **config)
            add(metric="fps", value=1000.0 / (run["local_ms"] + gi_ms / k), unit="1/s")
            add(metric="frame_time", value=run["local_ms"], unit="ms", stat="median")
            add(metric="gi_time", value=gi_ms, unit="ms", stat="mean" if cfg.inference_ms is None else "given")
            for metric, unit in (("ssim", "1"), ("psnr", "dB"), ("lf_error", "1"), ("valid_frac", "1")):
                name = "valid_fraction" if metric == "valid_frac" else metric
                add(metric=name, value=run[f"mean_{metric}"], unit=unit, stat="mean")


# -- what it shows ------------------------------------------------------------------------------------------
def _warps(rows: Rows) -> list[str]:
    return unique(r["system"] for r in rows)


def table_rows(rows: Rows) -> list[dict]:
    """Per scene, composition and k (ascending): fps, SSIM and LF error of each warp."""
    keys = ("scene", "composition", "k")
    derived = wide(rows, (*keys, "system"), {"fps": "fps", "ssim": "ssim", "lf": "lf_error"})
    groups = unique((r["scene"], r["composition"]) for r in derived)
    spread_rows = spread(derived, keys, "system", _warps(rows))
    return sorted(spread_rows, key=lambda r: (groups.index((r["scene"], r["composition"])), r["k"]))


def columns(rows: Rows) -> tuple[Column, ...]:
    """k, then fps and SSIM per warp, and the LF error of each warp that has it (CSVs older than it do not)."""
    warps = _warps(rows)
    lf = [i for i, w in enumerate(warps) if any(r["metric"] == "lf_error" and r["system"] == w for r in rows)]
    return (
        Column("k", "{k}"),
        *per(warps, "fps ({})", "{fps[#]:.1f}"),
        *per(warps, "SSIM ({})", "{ssim[#]:.3f}"),
        *(Column(f"LF error ({warps[i]})", f"{{lf[{i}]:.4f}}") for i in lf),
    )


def caption(rows: Rows) -> str:
    c = rows[0]["config"]
    sources = ", ".join(str(s) for s in unique(r["config"].get("gi_source") for r in rows))
    return (
        f"GI maps: {sources} (model: the generator's; gt: path-traced, a perfect-model stand-in); "
        f"{c.get('resolution')}², {c.get('frames')} frames; SSIM against path-traced GT at the local camera."
    )


def _against_k(metric: str, label: str, log: bool) -> Chart:
    return Chart(pick(metric), "k", series="{scene}: {system} ({composition})", xlabel="GI-map period k [frames]",
                 ylabel=label, ylog=log, tip="{series}, k = {k}: " + metric + " {value:.4g}")  # fmt: skip


PARTS = (
    Table(table_rows, columns, caption=caption, group="{scene}, composition: {composition}"),
    Figure(
        "frequency",
        (
            _against_k("fps", "frames per second (GI cost amortised over k)", True),
            _against_k("ssim", "mean SSIM vs path-traced GT", False),
        ),
        title="Inference frequency vs system performance (Table 3)",
    ),
)


BENCH = Bench(
    "frequency",
    FrequencyConfig,
    measure,
    help="Table 3: GI-map period k against fps and SSIM, with and without warping, both compositions.",
    dashboard=Section("table3", "Table 3: inference frequency", 30),
    readme=Block("Inference frequency, Table 3", 40),
    parts=PARTS,
    needs=("fps", "ssim"),
)
