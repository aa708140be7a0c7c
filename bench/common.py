"""What several benches share, so that no bench imports another (pyproject.toml, the protected contract):
the warp methods they compare, the small model a fresh checkout trains and scores, and a stated target.

The warps are wired here, in ``bench``, because cross-system ablations (GIGAN maps with cloud baking's
pixel-level warp) may not be assembled inside either system (docs/architecture.md, Import contracts).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gicore.dataset_cli import DatasetConfig
from gicore.gi_map import LAYERS
from gicore.loop import Warp
from gicore.results import Results

# --- the warp methods ----------------------------------------------------------------------------------------

#: Plot and CSV names of the warp methods the benches compare: GIGAN's structure-aware warp, cloud
#: baking's pixel-level warp, and none (the map pasted as is).
WARP_LABELS = {"structure": "structure-aware", "pixel": "pixel-level", "none": "no warping"}
WARPS = tuple(WARP_LABELS)


def make_warp(method: str, renderer, composition: str = "blend") -> Warp:
    """The :class:`gicore.loop.Warp` ``method`` (:data:`WARPS`) for ``composition``."""
    if method == "pixel":
        from baseline_cloudbaking.warp import PixelWarp

        return PixelWarp(LAYERS[composition])
    from gigan_local.client import make_warp as gigan_warp

    return gigan_warp(method, renderer, composition)


# --- the small model of a fresh checkout ---------------------------------------------------------------------

#: The small dataset a fresh checkout renders per scene (``bench quality --quick``, ``bench training --quick``,
#: ``bench model-card --quick``): 6 training and 3 held-out frames at 256², the shipped model's resolution
#: (about 7 s per scene on 2 cores).
QUICK_DATASET = DatasetConfig(n_train=6, n_val=3, resolution=256, spp=64, denoise=True)


def train_small(scenes: tuple[str, ...], widths: tuple[int, ...], steps: int, res: Results) -> list[Path]:
    """Train one small GIGAN per width on the small datasets of ``scenes`` (:data:`QUICK_DATASET`, rendered
    into ``<out>/dataset``) into ``<out>/runs/gigan_ngf<W>``; a finished run is kept, a partial one resumed.
    Returns the run folders."""
    from gicore.dataset_cli import build_dataset
    from gicore.scene import load_scene
    from gigan_local.config import TrainConfig
    from gigan_local.train import train

    datasets = []
    for scene in scenes:
        spec = load_scene(scene)
        build_dataset(spec, res.out / "dataset" / spec.name, QUICK_DATASET, progress=False)
        datasets.append(str(res.out / "dataset" / spec.name))
    runs = []
    for width in widths:
        run_dir = res.out / "runs" / f"gigan_ngf{width}"
        cfg = TrainConfig(
            model="gigan",
            datasets=datasets,
            ngf=width,
            crop=64,
            batch_size=2,
            epochs=100_000,
            max_steps=steps,
            max_val_frames=QUICK_DATASET.n_val,
            checkpoint_every=0,
            seed=res.seed,
        )
        train(cfg, run_dir, resume=(run_dir / "checkpoint.pt").is_file(), progress=False)
        runs.append(run_dir)
    return runs


# --- stated targets ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Target:
    """One of the server's stated targets (``bench service``, ``bench load``): ``metric``'s ``stat`` compared
    with ``bound`` (``at_most`` or not)."""

    metric: str
    stat: str
    bound: float
    unit: str
    at_most: bool
    label: str
    #: Extra config keys that select the row (e.g. the hit_server part).
    where: tuple[tuple[str, str], ...] = ()

    def met(self, value: float) -> bool:
        return value <= self.bound if self.at_most else value >= self.bound

    def record(self, add: Callable[..., None], measured: float | None, **config: Any) -> None:
        """Its ``stat = target_met`` row through ``add`` (a ``Results.add`` with system and scene bound): 1 when
        ``measured`` meets it, 0 when it does not or was not measured."""
        met = measured is not None and not math.isnan(measured) and self.met(measured)
        add(metric=self.metric, value=int(met), unit="bool", stat="target_met", target=self.label, bound=self.bound,
            bound_unit=self.unit, measured=measured, **config)  # fmt: skip
