"""The ``bench`` command: one subcommand per experiment, each writing tidy CSV, provenance and a plot."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import typer

from bench import convergence, render_bench
from bench.runner import execute, register
from gicore.cli import entry_point

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Experiments of the GIGAN testbed (CSV + provenance + plots).")
main = entry_point(app, resume="run the same command again; each bench rewrites its CSV, provenance and plots whole")

CONVERGENCE = register(app, "convergence", convergence.ConvergenceConfig, convergence.measure, convergence.plot,
                       help="GT error (RMSE/SSIM against a high-spp reference) against render time, with and without OIDN.")
register(app, "render", render_bench.RenderBenchConfig, render_bench.measure, render_bench.plot,
         help="Per-pass render times (DI, G-buffers, GT with/without OIDN) and triangle counts per scene.")

OutOpt = Annotated[Path, typer.Option("--out", help="folder for CSV, provenance JSON and plots")]
QuickOpt = Annotated[bool, typer.Option("--quick", help="small preset that finishes in minutes on 2 cores")]
SeedOpt = Annotated[int, typer.Option("--seed")]
ScenesOpt = Annotated[str | None, typer.Option(help="comma-separated scene names (default: the bench's own list)")]
ResolutionOpt = Annotated[int | None, typer.Option(help="square resolution")]
SceneOpt = Annotated[str | None, typer.Option(help="scene name or spec file (default: lung_plane)")]
GISourceOpt = Annotated[str | None, typer.Option(help="gt (path-traced stand-in, default) or model")]
ModelOpt = Annotated[Path | None, typer.Option(help="ONNX model for --gi-source model")]


def _config(cls: Any, quick: bool, **options: Any) -> Any:
    """A bench config: its quick or default preset with every option the user gave (not None) applied;
    ``scenes`` is given as a comma-separated string."""
    if options.get("scenes") is not None:
        options["scenes"] = tuple(s.strip() for s in options["scenes"].split(",") if s.strip())
    return replace(cls.quick() if quick else cls(), **{k: v for k, v in options.items() if v is not None})


@app.command("run-default")
def run_default(out: OutOpt = Path("results"), scene: str = "lung_plane") -> None:
    """The main job on the embedded default scene: a small dataset and its contact sheet, the quick
    convergence bench, and the shipped GIGAN model scored on the dataset's held-out frames."""
    from bench.contact_sheet import contact_sheet
    from bench.quality import QualityConfig
    from bench.quality import run as run_quality
    from gicore.dataset_cli import DatasetConfig, build_dataset
    from gicore.scene import load_scene

    spec = load_scene(scene)
    datasets = out / "dataset"
    # 256² because the shipped model runs at that resolution.
    build_dataset(spec, datasets / spec.name, DatasetConfig(n_train=6, n_val=3, resolution=256, spp=64, denoise=True))
    typer.echo(f"wrote {contact_sheet(datasets / spec.name, out / 'contact_sheet.png')}")
    for path in execute(CONVERGENCE, replace(convergence.ConvergenceConfig.quick(), scenes=(spec.name,)), out):
        typer.echo(f"wrote {path}")
    quality = QualityConfig(datasets=datasets, scenes=(spec.name,), timing_repeats=10, grid_frames=2)
    typer.echo(f"wrote {run_quality(quality, out)}")


@app.command()
def warp(
    out: OutOpt = Path("results"),
    quick: QuickOpt = False,
    seed: SeedOpt = 0,
    scenes: ScenesOpt = None,
    resolution: ResolutionOpt = None,
) -> None:
    """Fig. 7: CPU time, CPU load, memory and SSIM of pixel-level vs structure-aware warping."""
    from bench.warp_bench import WarpBenchConfig, run

    typer.echo(f"wrote {run(_config(WarpBenchConfig, quick, scenes=scenes, resolution=resolution), out, seed)}")


@app.command()
def frequency(
    out: OutOpt = Path("results"),
    quick: QuickOpt = False,
    seed: SeedOpt = 0,
    scene: SceneOpt = None,
    resolution: ResolutionOpt = None,
    gi_source: GISourceOpt = None,
    model: ModelOpt = None,
    inference_ms: Annotated[float | None, typer.Option(help="GI-map cost in the fps instead of the source's measured cost")] = None,
) -> None:
    """Table 3: GI-map period k against fps and SSIM, with and without warping, both compositions."""
    from bench.frequency import FrequencyConfig, run

    cfg = _config(FrequencyConfig, quick, scene=scene, resolution=resolution, gi_source=gi_source, model=model, inference_ms=inference_ms)
    typer.echo(f"wrote {run(cfg, out, seed)}")
    typer.echo((out / "frequency_table.md").read_text())


@app.command()
def fov(
    out: OutOpt = Path("results"),
    quick: QuickOpt = False,
    seed: SeedOpt = 0,
    scene: SceneOpt = None,
    resolution: ResolutionOpt = None,
    gi_source: GISourceOpt = None,
    model: ModelOpt = None,
) -> None:
    """Fig. 9 and Fig. 8: GI-camera FOV against GI-map quality and warped quality after camera motion."""
    from bench.fov import FovConfig, run

    cfg = _config(FovConfig, quick, scene=scene, resolution=resolution, gi_source=gi_source, model=model)
    typer.echo(f"wrote {run(cfg, out, seed)}")


@app.command()
def quality(
    out: OutOpt = Path("results"),
    quick: QuickOpt = False,
    seed: SeedOpt = 0,
    datasets: Annotated[Path, typer.Option(help="root of per-scene datasets (gicore-dataset --out)")] = Path("data/datasets"),
    model: Annotated[list[str] | None, typer.Option(help="NAME=PATH.onnx, repeatable (default: the shipped GIGAN model)")] = None,
    scenes: ScenesOpt = None,
) -> None:
    """Fig. 6: RMSE/SSIM/PSNR of each model and of DI alone on held-out frames, plus inference ms."""
    from bench.quality import QualityConfig, run

    pairs = [m.split("=", 1) for m in model or []]
    if any(len(p) != 2 for p in pairs):
        raise typer.BadParameter("--model takes NAME=PATH.onnx")
    models = {name: Path(path) for name, path in pairs} or None
    typer.echo(f"wrote {run(_config(QualityConfig, quick, datasets=datasets, models=models, scenes=scenes), out, seed)}")


@app.command()
def training(
    runs: Annotated[list[Path], typer.Argument(help="gigan-train run folders")],
    out: OutOpt = Path("results"),
) -> None:
    """Learning curves of training runs (labelled by folder): validation SSIM and training L1 against step."""
    from bench.training import run

    typer.echo(f"wrote {run(runs, out)}")


@app.command("model-card")
def model_card(
    run: Annotated[Path, typer.Argument(help="gigan-train run folder of the model")],
    export: Annotated[Path, typer.Argument(help="gigan-export folder of the model (MODEL_CARD.md goes here)")],
    quality_csv: Annotated[Path, typer.Argument(help="a bench quality CSV that scored the model")],
    system: Annotated[str, typer.Option(help="the model's system name in the quality CSV")] = "gigan",
    dataset_command: Annotated[str, typer.Option(help="the command that rendered the training data")] = "",
    train_command: Annotated[str, typer.Option(help="the command that trained the model")] = "",
) -> None:
    """Write MODEL_CARD.md for an exported model from its run, export and quality results."""
    from bench.model_card import write_model_card

    typer.echo(f"wrote {write_model_card(run, export, quality_csv, system, dataset_command, train_command)}")
