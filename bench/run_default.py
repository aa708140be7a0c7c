"""`bench run-default` (what ``make run`` runs): the main job on the embedded default scene.

A small dataset of one scene (``bench.quality.QUICK_DATASET``: 6 training and 3 held-out frames at 256²)
and a contact sheet of its buffers, the quick GT-convergence bench, and the shipped GIGAN model scored
on the held-out frames by ``bench quality``, all into ``--out``. Its own CSV records the dataset: frames,
size and the wall time of rendering it (0 frames rendered when a rerun finds them all present).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

from bench import convergence, quality
from bench.contact_sheet import contact_sheet
from bench.runner import Bench, execute
from gicore.results import Results


@dataclass(frozen=True)
class RunDefaultConfig:
    """The scene of the main job."""

    #: The one scene (name or spec file) to render, bench and score.
    scenes: tuple[str, ...] = field(default=("lung_plane",), metadata={"max_len": 1})
    #: Timed inference calls of the shipped model, after three warm-ups.
    timing_repeats: int = 10
    #: Held-out frames in the image grid (quality_grid.png).
    grid_frames: int = field(default=2, metadata={"min": 0})

    @classmethod
    def quick(cls) -> "RunDefaultConfig":
        return cls()  # the main job is already small


def measure(cfg: RunDefaultConfig, res: Results) -> None:
    from gicore.dataset import frame_paths
    from gicore.dataset_cli import build_dataset, plan_frames
    from gicore.scene import load_scene

    spec = load_scene(cfg.scenes[0])
    root = res.out / "dataset" / spec.name
    missing = sum(not (root / r.file).is_file() for r in plan_frames(spec, quality.QUICK_DATASET))
    t0 = time.perf_counter()
    meta = build_dataset(spec, root, quality.QUICK_DATASET)
    seconds = time.perf_counter() - t0
    size = sum(p.stat().st_size for split in ("train", "val") for p in frame_paths(root, split))
    settings = dataclasses.asdict(quality.QUICK_DATASET)
    res.add(system="dataset", scene=spec.name, metric="frames", value=len(meta.frames), unit="count", **settings)
    res.add(system="dataset", scene=spec.name, metric="frames_rendered", value=missing, unit="count", **settings)
    res.add(system="dataset", scene=spec.name, metric="build_time", value=seconds, unit="s", stat="wall", **settings)
    res.add(system="dataset", scene=spec.name, metric="frame_size", value=size / len(meta.frames) / 1024, unit="KiB", stat="mean", **settings)
    contact_sheet(root, res.output("contact_sheet.png"))
    conv = dataclasses.replace(convergence.ConvergenceConfig.quick(), scenes=(spec.name,))
    res.files += execute(convergence.BENCH, conv, res.out, res.seed)
    scored = quality.QualityConfig(datasets=res.out / "dataset", scenes=(spec.name,), timing_repeats=cfg.timing_repeats, grid_frames=cfg.grid_frames)
    res.files += execute(quality.BENCH, scored, res.out, res.seed)


BENCH = Bench(
    "run-default",
    RunDefaultConfig,
    measure,
    None,
    help="The main job (make run): a small dataset of the default scene and its contact sheet, the quick convergence bench, "
    "and the shipped GIGAN model scored on the held-out frames.",
)
