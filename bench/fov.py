"""`bench fov` (paper Fig. 9 and Fig. 8): the GI camera's field of view F_GI against the quality of the GI
map itself and of the map warped to a camera that has since turned or moved.

At several views along the camera path a GI map is made at the GI camera (FOV F_GI, same position and
orientation as the local camera) by the configured source -- the generator (``gi_source = "model"``) or
the path-traced GT stand-in, whose "quality" is only the noise floor of two independent renders -- and
compared with a path-traced GT at that camera (Fig. 9). Then the local camera (FOV ``local_fov``) turns
about the vertical axis or moves sideways by several amounts, the map is warped there by each method,
and the result is compared with the GT at the moved camera (Fig. 8). Without warping the best one can do
is paste a map made at the local FOV; that reference is reported too. The light stays where it was for
the map, so the error is the warp's and the FOV's alone.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bench.common import WARP_LABELS, make_warp
from bench.runner import FOV_DEGREES, Bench, Block, Section
from gicore import option_groups
from gicore.camera import Camera
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, per, pick, spread, unique, wide
from gicore.results import Results
from gigan_local.client import GI_SOURCES
from gigan_local.inference import DEFAULT_MODEL, check_model_resolution


@dataclass(frozen=True)
class FovConfig:
    """The parameter grid of one run."""

    scenes: tuple[str, ...] = option_groups.scenes()
    resolution: int = option_groups.resolution()
    #: GI-camera FOVs F_GI compared, degrees.
    gi_fovs: tuple[float, ...] = field(default=(60.0, 90.0, 120.0), metadata=FOV_DEGREES)
    #: FOV of the local (client) camera, degrees; at this F_GI the no-warping reference is scored too.
    local_fov: float = field(default=60.0, metadata=FOV_DEGREES)
    #: Frames along the camera path where GI maps are made (the views).
    base_frames: tuple[int, ...] = field(default=(0, 60, 120, 180, 240), metadata={"min": 0})
    orbit_frames: int = option_groups.orbit_frames()
    #: Camera turns after the GI map, degrees about the vertical axis.
    rotations: tuple[float, ...] = (5.0, 10.0, 20.0, 30.0)
    #: Sideways camera moves after the GI map, scene units.
    translations: tuple[float, ...] = (0.1, 0.2, 0.4)
    #: Warp methods compared.
    warps: tuple[Literal["structure", "pixel"], ...] = ("structure", "pixel")
    spp: int = option_groups.spp(note="of the path-traced GT: the gt GI source and the evaluation GT")
    denoise: bool = option_groups.denoise()
    #: Where GI maps come from: the path-traced GT stand-in, or the generator (--model).
    gi_source: Literal[GI_SOURCES] = "gt"
    #: ONNX generator for --gi-source model (gigan-export output).
    model: Path = DEFAULT_MODEL

    @classmethod
    def quick(cls) -> FovConfig:
        return cls(resolution=128, base_frames=(0, 150), rotations=(5.0, 15.0, 30.0), translations=(0.1, 0.3), spp=16)

    def check(self) -> None:
        if self.gi_source == "model":
            check_model_resolution(self.model, self.resolution)


def measure(cfg: FovConfig, res: Results) -> None:
    for scene in cfg.scenes:
        _measure_scene(cfg, res, scene)


def _measure_scene(cfg: FovConfig, res: Results, scene: str) -> None:
    from gicore.paths import camera_path, light_position
    from gicore.render import Renderer
    from gicore.scene import load_scene
    from gigan_local.client import ClientConfig, make_gi_source

    spec = load_scene(scene)
    renderer = Renderer(spec, cfg.resolution)
    client = ClientConfig(scene=scene, resolution=cfg.resolution, gi_source=cfg.gi_source, model=cfg.model,
                          spp=cfg.spp, denoise=cfg.denoise, seed=res.seed)  # fmt: skip
    run = _SceneRun(cfg, renderer, make_gi_source(client, renderer), res.seed)
    cams = camera_path(spec, cfg.orbit_frames, seed=res.seed, fov=cfg.local_fov, resolution=cfg.resolution)
    for b in cfg.base_frames:
        run.base_view(cams[b % cfg.orbit_frames], light_position(spec, b), b)
    run.record(res, spec.name)


class _SceneRun:
    """One scene's measurements: per base view, the moved cameras' GT, then each GI-camera FOV's map and its
    warps to every moved camera; their SSIM and covered share collected in ``quality`` until :meth:`record`."""

    def __init__(self, cfg: FovConfig, renderer: Any, source: Any, seed: int) -> None:
        self.cfg, self.renderer, self.source, self.seed = cfg, renderer, source, seed
        self.motions = [("rotation", r, "deg") for r in cfg.rotations]
        self.motions += [("translation", t, "units") for t in cfg.translations]
        self.warps = {m: make_warp(m, renderer) for m in cfg.warps}
        self.paste = make_warp("none", renderer)
        self.quality: dict[tuple, list[float]] = defaultdict(list)

    def base_view(self, base: Camera, light, b: int) -> None:
        """Base frame ``b``: every motion's moved camera with its tone-mapped GT (shared by all F_GI), then each
        F_GI's map scored and warped."""
        from gicore.ground_truth import render_gt
        from gicore.paths import frame_seed
        from gicore.tonemap import tonemap

        cfg = self.cfg
        moves = {}
        for kind, amount, _ in self.motions:
            cam = base.turned(amount) if kind == "rotation" else base.moved(right=amount)
            seed = frame_seed(self.seed, f"gt/{kind}/{amount}", b)
            moves[kind, amount] = (cam, tonemap(render_gt(self.renderer, cam, light, cfg.spp, seed, cfg.denoise)))
        for gi_fov in cfg.gi_fovs:
            self._gi_fov(base, light, b, gi_fov, moves)

    def _gi_fov(self, base: Camera, light, b: int, gi_fov: float, moves: dict) -> None:
        """The map at ``gi_fov`` against its own GT, each warp of it to every moved camera, and (at the local FOV)
        the map pasted without warping."""
        from gicore.ground_truth import render_gt
        from gicore.loop import warp_view
        from gicore.metrics import ssim
        from gicore.paths import frame_seed
        from gicore.tonemap import tonemap

        cfg, renderer, quality = self.cfg, self.renderer, self.quality
        gi = self.source.produce(base.with_fov(gi_fov), light, b)
        reference = render_gt(renderer, gi.camera, light, cfg.spp, frame_seed(self.seed, "gt/gi", b), cfg.denoise)
        quality["map", gi_fov].append(ssim(tonemap(gi.radiance), tonemap(reference)))
        for method, warp in self.warps.items():
            warp.bind(gi)
            for kind, amount, _ in self.motions:
                cam, ref = moves[kind, amount]
                _, image, valid = warp_view(warp, renderer, cam, light, seed=b)
                quality[method, gi_fov, kind, amount].append(ssim(tonemap(image), ref))
                quality["valid", method, gi_fov, kind, amount].append(float(valid.mean()))
        if gi_fov == cfg.local_fov:
            self.paste.bind(gi)
            for kind, amount, _ in self.motions:
                cam, ref = moves[kind, amount]
                image = warp_view(self.paste, renderer, cam, light, seed=b)[1]
                quality["none", gi_fov, kind, amount].append(ssim(tonemap(image), ref))

    def record(self, res: Results, scene: str) -> None:
        """The means over the base views: the map's SSIM per F_GI, each warp's SSIM and covered share per F_GI
        and motion."""
        cfg, quality = self.cfg, self.quality
        common = {"resolution": cfg.resolution, "local_fov": cfg.local_fov, "views": len(cfg.base_frames),
                  "spp": cfg.spp, "gi_source": cfg.gi_source}  # fmt: skip
        source_label = "generator" if cfg.gi_source == "model" else "GT stand-in"
        for gi_fov in cfg.gi_fovs:
            value = float(np.mean(quality["map", gi_fov]))
            res.add(system=source_label, scene=scene, metric="ssim_gi_map", value=value, unit="1", stat="mean",
                    gi_fov=gi_fov, **common)  # fmt: skip
            for method in (*cfg.warps, "none"):
                for kind, amount, unit in self.motions:
                    if (method, gi_fov, kind, amount) not in quality:
                        continue
                    row = common | {"gi_fov": gi_fov, "motion": kind, "amount": amount, "amount_unit": unit}
                    value = float(np.mean(quality[method, gi_fov, kind, amount]))
                    res.add(system=WARP_LABELS[method], scene=scene, metric="ssim_warped", value=value, unit="1",
                            stat="mean", **row)  # fmt: skip
                    if method != "none":
                        value = float(np.mean(quality["valid", method, gi_fov, kind, amount]))
                        res.add(system=WARP_LABELS[method], scene=scene, metric="valid_fraction", value=value,
                                unit="1", stat="mean", **row)  # fmt: skip


# -- what it shows ------------------------------------------------------------------------------------------
def _warps(rows: Rows) -> list[str]:
    return unique(r["system"] for r in rows if r["metric"] == "ssim_warped")


def table_rows(rows: Rows) -> list[dict]:
    """Per scene and F_GI: the GI map's SSIM, and each warp's SSIM and covered share (means over every motion)."""
    keys = ("scene", "gi_fov")
    warped = wide(rows, (*keys, "system"), {"ssim": "ssim_warped", "covered": "valid_fraction"}, mean=True)
    out: dict[tuple, dict] = {}
    for r in wide(rows, keys, {"gi_map": "ssim_gi_map"}, mean=True) + spread(warped, keys, "system", _warps(rows)):
        out.setdefault((r["scene"], r["gi_fov"]), {}).update(r)
    return list(out.values())


def caption(rows: Rows) -> str:
    warped = pick("ssim_warped")(rows)
    motions = []
    for m in unique(r["motion"] for r in warped):
        mine = [r for r in warped if r["motion"] == m]
        motions.append(f"{m} {', '.join(unique(format(r['amount'], 'g') for r in mine))} {mine[0]['amount_unit']}")
    source = ", ".join(unique(r["system"] for r in rows if r["metric"] == "ssim_gi_map"))
    return (
        f"GI maps: {source}. Warped: the mean over {'; '.join(motions)}; in brackets, the share of pixels the map "
        "covers."
    )


def _moved(motion: str, metric: str, label: str) -> Chart:
    """A warp quality against camera motion, per scene, warp and F_GI."""
    unit = lambda rows: next((r["config"]["amount_unit"] for r in rows if r["config"].get("motion") == motion), "")  # noqa: E731
    return Chart(pick(metric, motion=motion), "amount", series="{scene}: {system}, F_GI {gi_fov:g}°",
                 xlabel=lambda rows: f"camera {motion} [{unit(rows)}]", ylabel=label,
                 tip="{series}, {motion} {amount:g} {amount_unit}: {value:.4f}")  # fmt: skip


PARTS = (
    Figure(
        "fov",
        (
            Chart(
                pick("ssim_gi_map"),
                "gi_fov",
                series="{scene}",
                xlabel="GI-camera FOV F_GI [°]",
                ylabel="SSIM of the GI map vs GT",
                tip="{scene}, F_GI {gi_fov:g}°: SSIM {value:.4f}",
            ),
            _moved("rotation", "ssim_warped", "SSIM of the warped GI vs GT"),
            _moved("translation", "ssim_warped", "SSIM of the warped GI vs GT"),
            _moved("rotation", "valid_fraction", "frame covered by the GI map"),
        ),  # fmt: skip
        title="GI-camera FOV: GI-map quality (Fig. 9) and warping after camera motion (Fig. 8)",
    ),
    Table(
        table_rows,
        lambda rows: (
            Column("scene", "{scene}"),
            Column("F_GI", "{gi_fov:g}°"),
            Column("SSIM of the GI map", "{gi_map:.3f}"),
            *per(_warps(rows), "SSIM warped: {}", "{ssim[#]:.3f}[[ ({covered[#]:.0%})]]"),
        ),
        caption=caption,
    ),
)


BENCH = Bench(
    "fov",
    FovConfig,
    measure,
    help="Fig. 9 and Fig. 8: GI-camera FOV against GI-map quality and warped quality after camera motion.",
    dashboard=Section("fig9", "Fig. 9: GI-camera FOV", 60),
    readme=Block("GI-camera FOV, Fig. 9", 70),
    parts=PARTS,
    needs=("ssim_gi_map", "ssim_warped"),
)
