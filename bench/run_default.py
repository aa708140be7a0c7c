"""`bench run-default` (what ``make run`` runs): the main job, the paper's Table 1 and Table 2 on the default scene.

``bench latency --quick --renderers gl`` (GIGAN with the shipped model and cloud baking, both clients as
processes rasterising with OpenGL, the server and a network proxy per profile between them) and ``bench
storage --quick`` (the GI tree after a fly-through against the model's size), both restricted to the one
scene ``--scenes``, into ``--out``: each writes its own CSV, provenance and plots there. Both tables are
printed at the end. Its own CSV records each bench's wall time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import time
from dataclasses import dataclass, field
from functools import partial

from bench.runner import Bench, check_config, execute
from gicore import option_groups
from gicore.options import FRAMES
from gicore.results import Results


@dataclass(frozen=True)
class RunDefaultConfig:
    """The scene and the renderers of the main job."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="both benches run on it")
    #: Renderers of the latency clients' raster passes (bench latency --renderers): gl, what a Web3D client
    #: rasterises with (mitsuba where no GL context opens); gl,mitsuba adds the side-by-side comparison.
    renderers: tuple[str, ...] = ("gl",)
    #: Frames each latency client flies (fewer: a faster look, fewer maps per median); none: bench latency
    #: --quick's.
    frames: int | None = field(default=None, metadata=FRAMES)

    @classmethod
    def quick(cls) -> RunDefaultConfig:
        return cls()  # the main job runs the quick presets already


#: A bench of the main job: the bench, run from its quick preset, the table it writes, and the main job's own
#: options it takes (those given: not None).
Job = tuple[Bench, str, tuple[str, ...]]


def measure(cfg: RunDefaultConfig, res: Results, jobs: tuple[Job, ...]) -> None:
    configs = [
        (bench, dataclasses.replace(bench.config.quick(), **_given(cfg, names)), table) for bench, table, names in jobs
    ]
    for _, config, _ in configs:  # both checked before either runs: a missing model fails at once
        check_config(config)
    for bench, config, _ in configs:
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):  # a bench's own printout of its table: shown once, below
            res.files += execute(bench, config, res.out, res.seed)
        res.add(
            system=bench.name,
            scene=cfg.scenes[0],
            metric="wall_time",
            value=time.perf_counter() - t0,
            unit="s",
            stat="wall",
        )
    for _, _, table in configs:
        print(f"\n{(res.out / table).read_text()}")


def _given(cfg: RunDefaultConfig, names: tuple[str, ...]) -> dict[str, object]:
    return {name: getattr(cfg, name) for name in names if getattr(cfg, name) is not None}


def bench(latency: Bench, storage: Bench) -> Bench:
    """``bench run-default``, running ``latency`` and ``storage`` (:mod:`bench.registry` hands them in: benches
    import no bench)."""
    jobs = (
        (latency, "latency.md", ("scenes", "renderers", "frames")),
        (storage, "storage.md", ("scenes",)),
    )
    return Bench(
        "run-default",
        RunDefaultConfig,
        partial(measure, jobs=jobs),
        help="The main job (make run): bench latency --quick (Table 1) and bench storage --quick (Table 2) on the "
        "default scene, with the shipped GIGAN model; both tables printed at the end.",
    )
