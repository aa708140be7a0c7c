"""Train GIGAN, Deep Shading or Deep Illumination on dataset folders, within a step and time budget.

A run lives in one output folder::

    config.json     TrainConfig + the NetworkConfig of every network (plain JSON)
    checkpoint.pt   weights, optimizer states, step/epoch counters, torch RNG state
    metrics.csv     tidy long rows: run_id, model, epoch, step, split, metric, value, unit
                    (epoch = epochs completed when the row was written; split "train" rows are
                    means of the logged losses and step_seconds since the previous train rows)

A run folder is held by one run at a time (:func:`gicore.fileio.exclusive_run`); the config and the
checkpoint are written atomically, and ``metrics.csv`` is cut back to the rows the checkpoint counts
when a run resumes, so an interrupted run (Ctrl-C, kill) resumes with ``--resume`` as if never stopped.

Validation (whole val frames, generator in eval mode as exported) runs before the first step, after
every epoch and when the run stops; it scores RMSE/PSNR/SSIM and lf_error (``gicore.metrics``) on tone-mapped [0, 1]
images. Data order and crops follow (seed, epoch), and the checkpoint keeps the RNG states (the CPU's,
and the GPU's on CUDA), so a resumed CPU run continues exactly where a straight run would be (on
CUDA, up to cuDNN's non-deterministic kernels). Non-finite or exploding losses and
non-finite weights stop training with :class:`TrainingDiverged`, keeping the last good checkpoint.
Training runs on the CPU or a CUDA GPU (``TrainConfig.device``); validation runs the generator on the
training device and scores its output on the CPU, and a run may move between the two on ``--resume``.
"""

from __future__ import annotations

import csv
import io
import math
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from gicore.error_policy import UserError
from gicore.fileio import atomic_write, atomic_write_bytes, exclusive_run
from gicore.metrics import all_metrics
from gicore.tonemap import tonemap
from gigan_local.config import BUDGET_FIELDS, TrainConfig, read_run_config, write_run_config
from gigan_local.data import FrameDataset, dataset_resolution, median_foreground_depth
from gigan_local.models import BaseModel, create_model
from gigan_local.preprocess import albedo_divisor, input_albedo, output_to_radiance
from gigan_local.warmstart import init_depth_scale, load_into

CHECKPOINT = "checkpoint.pt"
METRICS = "metrics.csv"
METRIC_COLUMNS = ("run_id", "model", "epoch", "step", "split", "metric", "value", "unit")
UNITS = {"rmse": "1", "psnr": "dB", "ssim": "1", "lf_error": "1", "step_seconds": "s"}


class TrainingDiverged(UserError):
    """Training produced non-finite or exploding losses or weights (the user lowers --lr or fixes the data)."""


@dataclass
class RunState:
    """Where a run stands; saved in the checkpoint."""

    step: int = 0
    #: Completed epochs; ``batch`` batches of the current epoch are done.
    epoch: int = 0
    batch: int = 0
    #: Running sums of logged losses (and step seconds) over the current epoch, for the epoch means.
    loss_sums: dict[str, float] = field(default_factory=dict)
    loss_counts: dict[str, int] = field(default_factory=dict)
    #: Step of the latest validation (-1: none yet) and how long a validation + checkpoint took.
    last_val_step: int = -1
    finish_seconds: float = 0.0
    #: Metrics of the latest validation.
    val_metrics: dict[str, float] = field(default_factory=dict)
    #: Data rows of metrics.csv written up to this state (None: a checkpoint that does not record it).
    metrics_rows: int | None = None


@dataclass
class TrainResult:
    """What a call to :func:`train` ended with."""

    step: int
    epoch: int
    #: ``epochs``, ``max_steps`` or ``max_minutes``.
    stop_reason: str
    val_metrics: dict[str, float]
    checkpoint: Path


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Load a checkpoint on the CPU (tensors and plain containers only, no arbitrary pickles)."""
    if not Path(path).is_file():
        raise UserError(f"checkpoint {path} is missing", "train one with `gigan-train`")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types on truncated or foreign files
        raise UserError(
            f"{path} is not a readable checkpoint ({type(e).__name__})",
            "restore it, or train a new run with `gigan-train`",
        ) from e


def prepare_config(cfg: TrainConfig, out_dir: Path) -> TrainConfig:
    """Fill the fields derived from the data (resolution, depth scale) and the run id."""
    roots = [Path(d) for d in cfg.datasets]
    resolution = dataset_resolution(roots, tuple(cfg.buffers))
    if cfg.resolution is not None and cfg.resolution != resolution:
        raise UserError(
            f"the run was made at resolution {cfg.resolution} but the datasets are {resolution}x{resolution}",
            "train on datasets of the run's resolution",
        )
    depth_scale = cfg.depth_scale
    if depth_scale is None and cfg.init_generator is not None:  # a warm start keeps the model's input encoding
        depth_scale = init_depth_scale(Path(cfg.init_generator))
    if depth_scale is None:
        depth_scale = float(f"{median_foreground_depth(roots):.3g}") if "depth" in cfg.buffers else 1.0
    cfg = replace(
        cfg, resolution=resolution, depth_scale=depth_scale, run_id=cfg.run_id or Path(out_dir).resolve().name
    )
    try:
        cfg.network_configs()  # the architecture must fit the frames (and crops) of these datasets
    except ValueError as e:
        raise UserError(str(e), "change --n-down or --crop to fit the frame size") from None
    return cfg


def _check_resume(saved: TrainConfig, cfg: TrainConfig) -> None:
    diffs = {
        f.name: (getattr(saved, f.name), getattr(cfg, f.name))
        for f in fields(TrainConfig)
        if f.name not in BUDGET_FIELDS and getattr(saved, f.name) != getattr(cfg, f.name)
    }
    if diffs:
        detail = ", ".join(f"{k}: saved {a!r} vs given {b!r}" for k, (a, b) in diffs.items())
        raise UserError(
            f"--resume may change only {list(BUDGET_FIELDS)}; these differ: {detail}",
            "start a new run in another --out instead",
        )


@torch.no_grad()
def validate(generator: torch.nn.Module, dataset: FrameDataset, max_frames: int | None = None) -> dict[str, float]:
    """Mean RMSE/PSNR/SSIM/lf_error over (evenly spaced, at most ``max_frames``) whole frames, in eval mode, of the
    tone-mapped GI maps the output and the target decode to (:func:`output_to_radiance`: radiance and demodulated
    models score alike)."""
    n = len(dataset) if max_frames is None else min(len(dataset), max_frames)
    indices = np.unique(np.linspace(0, len(dataset) - 1, n).round().astype(int))
    was_training = generator.training
    generator.eval()
    device = next(generator.parameters()).device
    totals: dict[str, float] = {}
    for i in indices:
        x, y = dataset[int(i)]
        pred = generator(x[None].to(device))[0].cpu().numpy()
        floor = dataset.spec.albedo_floor
        divisor = None if floor is None else albedo_divisor(input_albedo(x.numpy(), dataset.spec), floor)
        maps = [tonemap(output_to_radiance(out, dataset.spec, divisor)) for out in (pred, y.numpy())]
        for k, v in all_metrics(*maps).items():
            totals[k] = totals.get(k, 0.0) + v
    generator.train(was_training)
    return {k: v / len(indices) for k, v in totals.items()}


def _append_rows(path: Path, rows: list[dict[str, Any]]) -> int:
    """Append ``rows`` to metrics.csv (with the header if it is new) in one write; returns how many."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=METRIC_COLUMNS)
    if not path.is_file() or path.stat().st_size == 0:
        writer.writeheader()
    writer.writerows(rows)
    with path.open("a", newline="") as f:
        f.write(buf.getvalue())
    return len(rows)


def _keep_rows(path: Path, n: int) -> None:
    """Cut metrics.csv back to its header and first ``n`` rows: those a resumed checkpoint counts."""
    if not path.is_file():
        return
    lines = path.read_text().splitlines(keepends=True)
    if len(lines) > n + 1:
        atomic_write_bytes(path, "".join(lines[: n + 1]).encode())


def _device(name: str) -> torch.device:
    """The torch device of ``--device``; CUDA only where torch sees a GPU."""
    if name == "cuda":
        if not torch.cuda.is_available():
            raise UserError(
                f"--device cuda: torch {torch.__version__} sees no CUDA GPU on this machine",
                "train with --device cpu (the default)",
            )
        torch.backends.cudnn.benchmark = True  # fixed input sizes: let cuDNN pick its fastest kernels once
    return torch.device(name)


def _check_divergence(step: int, losses: dict[str, float], model: BaseModel, cfg: TrainConfig, last_ckpt: str) -> None:
    advice = (
        f"the last good checkpoint ({last_ckpt}) is kept; "
        "check the data for extreme values or start a new run with a lower --lr"
    )
    for name, value in losses.items():
        if not math.isfinite(value):
            raise TrainingDiverged(f"training diverged at step {step}: loss {name} = {value} (non-finite)", advice)
        if abs(value) > cfg.max_abs_loss:
            raise TrainingDiverged(
                f"training diverged at step {step}: "
                f"loss {name} = {value:.4g} exceeds max_abs_loss {cfg.max_abs_loss:g}",
                advice,
            )
    if not model.parameters_finite():
        raise TrainingDiverged(
            f"training diverged at step {step}: the weights became non-finite (losses {losses})", advice
        )


def train(
    cfg: TrainConfig, out_dir: Path, resume: bool = False, progress: bool = True, cache_frames: bool = True
) -> TrainResult:
    """Train ``cfg.model`` into ``out_dir`` until the first of epochs / max_steps / max_minutes.

    With ``resume``, ``out_dir`` must hold a run whose config equals ``cfg`` except for the budget
    fields; training continues from its checkpoint (same step counter, optimizer and RNG state).
    ``max_minutes`` counts from this call's start; a step starts only if the estimated step time plus
    the measured duration of the last validation + checkpoint still fits before the deadline.
    ``cache_frames`` keeps the encoded frames in memory (:class:`FrameDataset`); it changes speed and
    memory use, not results. A second run into ``out_dir`` while this one runs is refused (UserError).
    """
    with exclusive_run(Path(out_dir)):
        return _train(cfg, Path(out_dir), resume, progress, cache_frames)


def _train(cfg: TrainConfig, out_dir: Path, resume: bool, progress: bool, cache_frames: bool) -> TrainResult:
    t_start = time.monotonic()
    cfg, ckpt = _prepared(cfg, out_dir, resume)
    run = _Run(cfg, out_dir, ckpt, cache_frames)
    deadline = math.inf if cfg.max_minutes is None else t_start + 60.0 * cfg.max_minutes
    return run.loop(deadline, progress)


def _prepared(cfg: TrainConfig, out_dir: Path, resume: bool) -> tuple[TrainConfig, dict[str, Any] | None]:
    """The run's config (on resume: the saved run's, with this call's budget) and the checkpoint it resumes
    from (None for a new run)."""
    ckpt_path = out_dir / CHECKPOINT
    if not resume:
        if ckpt_path.exists():
            raise UserError(
                f"--out {out_dir} already holds a run", "pass --resume to continue it or choose another --out"
            )
        return prepare_config(cfg, out_dir), None
    saved, _ = read_run_config(out_dir)
    ckpt = load_checkpoint(ckpt_path)
    filled = replace(
        cfg,
        resolution=saved.resolution if cfg.resolution is None else cfg.resolution,
        depth_scale=saved.depth_scale if cfg.depth_scale is None else cfg.depth_scale,
        run_id=cfg.run_id or saved.run_id,
    )
    cfg = prepare_config(filled, out_dir)
    _check_resume(saved, cfg)
    return cfg, ckpt


class _Run:
    """One call's training: its data, model and state (from ``ckpt`` on resume), the rows it appends to
    metrics.csv, its checkpoints and the step loop."""

    def __init__(self, cfg: TrainConfig, out_dir: Path, ckpt: dict[str, Any] | None, cache_frames: bool) -> None:
        self.cfg = cfg
        self.ckpt_path, self.metrics_path = out_dir / CHECKPOINT, out_dir / METRICS
        self.device = _device(cfg.device)  # refused before any data is read
        torch.manual_seed(cfg.seed)
        roots = [Path(d) for d in cfg.datasets]
        spec = cfg.input_spec()
        self.train_set = FrameDataset(roots, "train", spec, crop=cfg.crop, seed=cfg.seed, cache=cache_frames)
        self.val_set = FrameDataset(roots, "val", spec, cache=cache_frames)
        self.model = create_model(cfg)
        self.state = RunState(metrics_rows=0)
        if ckpt is None and cfg.init_generator is not None:
            # batch-norm statistics of the folded layers from a few training samples (see load_into)
            n = min(len(self.train_set), 2 * cfg.batch_size)
            calibration = torch.stack([self.train_set[i][0] for i in range(n)])
            load_into(self.model.generator, Path(cfg.init_generator), self.model.net_configs["G"], spec, calibration)
        self.model.to(self.device)  # before the optimizer states load, so that they land beside their parameters
        if ckpt is not None:
            self._resume(ckpt)
        else:  # no checkpoint: rows of a run interrupted before its first one count for nothing
            self.metrics_path.unlink(missing_ok=True)
        write_run_config(out_dir, cfg, self.model.net_configs)  # on resume: records this invocation's budget
        self.saved_step = self.state.step if ckpt is not None else -1
        #: The checkpoint a divergence falls back to, as the error names it.
        self.last_ckpt = f"step {self.state.step}"
        #: Moving average of a step's seconds (0: none yet), for the time budget.
        self.step_seconds = 0.0

    def _resume(self, ckpt: dict[str, Any]) -> None:
        self.model.load_state_dict(ckpt["model"])
        self.state = RunState(**ckpt["state"])
        torch.set_rng_state(ckpt["torch_rng"])
        if self.device.type == "cuda" and "cuda_rng" in ckpt:  # dropout and the penalty's interpolation draw on the GPU
            torch.cuda.set_rng_state(ckpt["cuda_rng"])
        if self.state.metrics_rows is not None:  # rows an interrupted run wrote after its checkpoint are redone
            _keep_rows(self.metrics_path, self.state.metrics_rows)

    # -- metrics and checkpoints -------------------------------------------------------------------
    def row(self, split: str, metric: str, value: float, unit: str) -> dict[str, Any]:
        cfg, state = self.cfg, self.state
        return {"run_id": cfg.run_id, "model": cfg.model, "epoch": state.epoch, "step": state.step, "split": split,
                "metric": metric, "value": value, "unit": unit}  # fmt: skip

    def append(self, rows: list[dict[str, Any]]) -> None:
        n = _append_rows(self.metrics_path, rows)
        if self.state.metrics_rows is not None:
            self.state.metrics_rows += n

    def flush_train_means(self) -> None:
        state = self.state
        rows = [self.row("train", k, s / state.loss_counts[k], UNITS.get(k, "1")) for k, s in state.loss_sums.items()]
        if rows:
            self.append(rows)
        state.loss_sums, state.loss_counts = {}, {}

    def save(self) -> None:
        data = {"model": self.model.state_dict(), "state": asdict(self.state), "torch_rng": torch.get_rng_state()}
        if self.device.type == "cuda":
            data["cuda_rng"] = torch.cuda.get_rng_state()
        # a crash mid-save keeps the previous checkpoint
        atomic_write(self.ckpt_path, lambda handle: torch.save(data, handle))
        self.saved_step = self.state.step

    def finish_work(self) -> None:
        """Validate and checkpoint (each unless already done at this step), timing both for the budget."""
        state = self.state
        t = time.monotonic()
        if state.last_val_step != state.step:
            state.val_metrics = validate(self.model.generator, self.val_set, self.cfg.max_val_frames)
            self.append([self.row("val", k, v, UNITS[k]) for k, v in state.val_metrics.items()])
            state.last_val_step = state.step
            state.finish_seconds = time.monotonic() - t
        if self.saved_step != state.step:
            self.save()
            state.finish_seconds = time.monotonic() - t

    # -- the loop ----------------------------------------------------------------------------------
    def loop(self, deadline: float, progress: bool) -> TrainResult:
        """Epochs of steps until the first of epochs / max_steps / the ``deadline`` (monotonic seconds);
        validation and a checkpoint before the first step, after every epoch and at the end."""
        cfg, state = self.cfg, self.state
        if state.last_val_step < 0:
            self.finish_work()  # baseline before any step; also measures validation + checkpoint time
        steps_per_epoch = math.ceil(len(self.train_set) / cfg.batch_size)
        total = (
            cfg.epochs * steps_per_epoch if cfg.max_steps is None else min(cfg.max_steps, cfg.epochs * steps_per_epoch)
        )
        stop_reason = ""
        self.model.train()
        with tqdm(
            total=total, initial=state.step, disable=not progress, desc=f"{cfg.model} {cfg.run_id}", unit="step"
        ) as bar:
            while not stop_reason:
                if state.epoch >= cfg.epochs:
                    stop_reason = "epochs"
                    break
                stop_reason = self._epoch(steps_per_epoch, deadline, bar)
                if stop_reason:
                    break
                state.epoch += 1
                state.batch = 0
                self.flush_train_means()
                self.finish_work()
                self.last_ckpt = f"step {state.step}"
            self.flush_train_means()
            self.finish_work()
        return TrainResult(state.step, state.epoch, stop_reason, state.val_metrics, self.ckpt_path)

    def _epoch(self, steps_per_epoch: int, deadline: float, bar: tqdm) -> str:
        """The rest of the current epoch's steps, in its (seed, epoch) order; the reason it stopped early, if
        it did ("max_steps", "max_minutes")."""
        cfg, state = self.cfg, self.state
        order = np.random.default_rng([cfg.seed, state.epoch]).permutation(len(self.train_set))
        self.train_set.set_epoch(state.epoch)
        while state.batch < steps_per_epoch:
            if cfg.max_steps is not None and state.step >= cfg.max_steps:
                return "max_steps"
            if time.monotonic() + self.step_seconds + state.finish_seconds > deadline:
                return "max_minutes"
            self._step(order[state.batch * cfg.batch_size : (state.batch + 1) * cfg.batch_size], bar)
        return ""

    def _step(self, idx: np.ndarray, bar: tqdm) -> None:
        """One optimizer step on the samples ``idx``: losses checked, logged into the epoch's sums, shown."""
        cfg, state = self.cfg, self.state
        t = time.monotonic()
        xs, ys = zip(*(self.train_set[int(i)] for i in idx))
        losses = self.model.optimize((torch.stack(xs).to(self.device), torch.stack(ys).to(self.device)))
        state.step += 1
        state.batch += 1
        _check_divergence(state.step, losses, self.model, cfg, self.last_ckpt)
        dt = time.monotonic() - t
        self.step_seconds = dt if self.step_seconds == 0 else 0.8 * self.step_seconds + 0.2 * dt
        for k, v in (losses | {"step_seconds": dt}).items():
            state.loss_sums[k] = state.loss_sums.get(k, 0.0) + v
            state.loss_counts[k] = state.loss_counts.get(k, 0) + 1
        bar.update(1)
        bar.set_postfix({k: f"{v:.3g}" for k, v in losses.items() if k in ("G_L1", "D_W", "G_SSIM")})
        if cfg.checkpoint_every and state.step % cfg.checkpoint_every == 0:
            self.save()
            self.last_ckpt = f"step {state.step}"
