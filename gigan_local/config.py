"""Training and network configuration: JSON-serialisable dataclasses that, with the data, fix a training run.

``config.json`` beside each checkpoint holds the :class:`TrainConfig` and the :class:`NetworkConfig` of
every network it builds, so a run can be resumed, exported or rebuilt without the command line that
started it. Both are read back with :func:`gicore.config.strict_from_dict`. This module does not import
torch (``gigan_local.networks`` builds the networks), so reading a config stays cheap.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from gicore import option_groups
from gicore.buffers import GENERATOR_INPUTS
from gicore.config import strict_from_dict
from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes
from gicore.options import RESOLUTION_MAX
from gigan_local.preprocess import ALBEDO_FLOOR, InputSpec

#: A run folder's config file: the TrainConfig and every NetworkConfig (see :func:`write_run_config`).
CONFIG = "config.json"
MODELS = ("gigan", "deep_shading", "deep_illumination")
#: Fields that only bound how long and where one invocation runs; ``--resume`` may change them, nothing else.
BUDGET_FIELDS = ("epochs", "max_steps", "max_minutes", "max_val_frames", "checkpoint_every", "device")
#: Where training runs: the CPU (everything here is built and tested for it) or a CUDA GPU.
DEVICES = ("cpu", "cuda")


GENERATORS = ("unet", "deep_shading")
CRITICS = ("patchgan",)
NORMS = ("batch", "none")
UPSAMPLINGS = ("transposed", "resize")
#: Field metadata of a network width (channels of the first layer).
WIDTH = {"min": 1, "max": 1024}
#: Field metadata of an Adam beta: 0 <= beta < 1.
BETA = {"min": 0.0, "max": 1.0, "max_open": True}


@dataclass
class NetworkConfig:
    """One network's architecture; stored as JSON beside checkpoints and exported models."""

    #: Architecture name: ``unet`` or ``deep_shading`` (generators), ``patchgan`` (critic).
    name: str
    #: Generator input channels (from the buffer list). For the critic: the channels of the condition
    #: (the generator input) it is given beside the image; 0 makes it unconditional (the image alone).
    in_channels: int
    #: Image channels: what a generator outputs and what a critic judges.
    out_channels: int = 3
    #: Channels of the first layer (pix2pix ``ngf`` for generators, ``ndf`` for critics); deeper layers
    #: use ``width * min(2**level, 8)``.
    width: int = 64
    #: Generators: number of 2x down-samplings (the input side must be divisible by 2**n_down; unet
    #: with n_down = log2(side) has a 1x1 bottleneck). patchgan: number of stride-2 convolutions
    #: (pix2pix ``n_layers``), giving n_down + 2 convolutions in all.
    n_down: int = 8
    #: Normalisation: ``batch`` (pix2pix BatchNorm; unet, and Deep Illumination's critic) or ``none``.
    norm: str = "batch"
    #: unet only: dropout probability in the first ``n_dropout`` up layers after the innermost one
    #: (they replace the noise input z, paper IV.A); 0 disables it.
    dropout: float = 0.5
    #: unet only: how many up layers after the innermost one carry dropout.
    n_dropout: int = 3
    #: unet only: how up layers double the side: ``transposed`` (pix2pix 4x4 stride-2 transposed conv)
    #: or ``resize`` (nearest 2x + 3x3 conv, which cannot make a checkerboard).
    upsample: str = "transposed"

    def __post_init__(self) -> None:
        if self.name not in GENERATORS + CRITICS:
            raise ValueError(f"unknown network {self.name!r}; choose one of {list(GENERATORS + CRITICS)}")
        if self.norm not in NORMS:
            raise ValueError(f"norm must be one of {list(NORMS)}, got {self.norm!r}")
        if self.upsample not in UPSAMPLINGS:
            raise ValueError(f"upsample must be one of {list(UPSAMPLINGS)}, got {self.upsample!r}")
        for f in ("in_channels", "out_channels", "width", "n_down"):
            least = 0 if f == "in_channels" and self.name in CRITICS else 1  # a critic may be unconditional
            if int(getattr(self, f)) < least:
                raise ValueError(f"{f} must be >= {least}, got {getattr(self, f)}")
        if self.name == "unet" and self.n_down < 2:
            raise ValueError(f"unet needs n_down >= 2 (an outermost and an innermost layer), got {self.n_down}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")

    @property
    def is_generator(self) -> bool:
        return self.name in GENERATORS

    def check_size(self, side: int) -> None:
        """Raise ValueError unless this network can run on side x side images."""
        if not self.is_generator:
            # Two stride-1 4x4 convs (padding 1) after the strided ones each shrink the map by one pixel.
            if side < 3 * 2**self.n_down:
                raise ValueError(
                    f"{self.name} with n_down={self.n_down} needs images of at least {3 * 2**self.n_down} px,"
                    f" got {side}; use a larger --crop"
                )
            return
        if side % (2**self.n_down) != 0:
            raise ValueError(
                f"{self.name} with n_down={self.n_down} needs image sides divisible by {2**self.n_down}, got {side}; "
                f"lower n_down (at most {int(math.log2(side & -side))} for this size) or change the size"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NetworkConfig:
        return strict_from_dict(cls, d, "network")


@dataclass
class TrainConfig:
    """How to train one model (paper IV.B defaults); ``None`` fields are derived from the data.

    ``gigan-train``'s options are derived from these fields (:mod:`gicore.options`): each option's default,
    limits and help are declared here once."""

    #: Which model: gigan (U-Net + PatchGAN, conditional WGAN-GP + L1), deep_shading (CNN U-Net, L1 + SSIM,
    #: no adversary) or deep_illumination (U-Net + PatchGAN, vanilla BCE GAN + L1).
    model: Literal[MODELS] = "gigan"  # type: ignore[valid-type]
    #: Dataset folders made by gicore-dataset (their train splits train, their val splits validate); not
    #: needed with --resume.
    datasets: list[str] = field(default_factory=list, metadata={"argument": True, "min_len": 0})
    #: Generator input buffers, in channel order (encodings: ``gigan_local.preprocess``).
    buffers: list[str] = field(default_factory=lambda: list(GENERATOR_INPUTS))
    #: Depth that encodes to 0; absent: the median foreground depth of the training data.
    depth_scale: float | None = None
    #: Albedo-demodulated input and output: the network sees the DI and predicts the GI divided by the first hit's
    #: albedo (floor 0.05, gigan_local.preprocess), and clients multiply it back, so it learns light rather than
    #: its training scenes' colours. Needs albedo among --buffers.
    demodulate: bool = False
    resolution: int | None = option_groups.resolution(None, note="absent: read from the datasets, which must agree")
    #: Train on random crop x crop windows (cheaper steps); validation always uses whole frames.
    crop: int | None = field(default=None, metadata={"min": 1, "max": RESOLUTION_MAX})
    #: Generator width (pix2pix ngf).
    ngf: int = field(default=64, metadata=WIDTH)
    #: Critic width (pix2pix ndf); absent: equal to ngf (the paper's 64/64), so shrinking the generator for
    #: a CPU budget shrinks the critic too (at 256 px, ndf 64 makes an ngf-16 GIGAN step ~6x slower).
    ndf: int | None = field(default=None, metadata=WIDTH)
    #: Generator down-samplings; absent: log2 of the training side (1x1 bottleneck) for unet, two fewer
    #: for deep_shading (see ``networks.DeepShadingGenerator``).
    n_down: int | None = field(default=None, metadata={"min": 1, "max": RESOLUTION_MAX.bit_length() - 1})
    #: U-Net up-sampling: transposed (pix2pix 4x4 transposed conv, the paper) or resize (nearest 2x + 3x3 conv).
    upsample: Literal[UPSAMPLINGS] = "transposed"  # type: ignore[valid-type]
    #: Whether the critic sees the generator input beside the image (pix2pix and the paper: yes).
    critic_condition: bool = True
    #: Frames per training step.
    batch_size: int = field(default=8, metadata={"min": 1, "max": 4096})
    #: Adam learning rate, for generator and critic alike.
    lr: float = 2e-4
    #: Adam beta1, for generator and critic alike.
    beta1: float = field(default=0.5, metadata=BETA)
    #: Adam beta2, for generator and critic alike.
    beta2: float = field(default=0.999, metadata=BETA)
    #: Weight of the L1 term (eq. 4); also deep_shading's L1 weight.
    lambda_L1: float = field(default=100.0, metadata={"min": 0.0})
    #: Weight of the gradient penalty (eq. 2); gigan only.
    lambda_gp: float = field(default=10.0, metadata={"min": 0.0})
    #: Critic steps per generator step (gigan); 1 alternates them as the paper does.
    n_critic: int = field(default=1, metadata={"min": 1, "max": 1000})
    #: Critic-only steps at the start of a run (gigan): the generator takes no step until the critic has
    #: taken this many, so a fresh critic (a fine-tune's) learns to judge before its gradients reach the
    #: generator, as WGAN's own schedule front-loads critic iterations. 0: none.
    critic_warmup: int = field(default=0, metadata={"min": 0})
    #: Weight of deep_shading's (1 - SSIM) term; equal to lambda_L1 by default (with Adam only the
    #: ratio of the two matters).
    lambda_ssim: float = field(default=100.0, metadata={"min": 0.0})
    #: Budget: stop after this many epochs (the budget stops at whichever of its limits comes first).
    epochs: int = 100
    #: Budget: stop after this many steps in all.
    max_steps: int | None = field(default=None, metadata={"min": 0})
    #: Budget: stop (validated and checkpointed) within this many minutes of wall time of one invocation.
    max_minutes: float | None = None
    seed: int = option_groups.seed(note="weights, dropout, penalty interpolation, data order and crops")
    #: Validate on at most this many val frames (per epoch); absent: all of them.
    max_val_frames: int | None = field(default=None, metadata={"min": 1})
    #: Also checkpoint every this many steps (0: only at epoch ends and at the stop).
    checkpoint_every: int = field(default=500, metadata={"min": 0})
    #: Where this invocation trains (cpu or cuda); checkpoints load on either (on the CPU first).
    #: A CUDA run is not bit-reproducible: cuDNN picks its kernels (and may use TF32), so a resumed or
    #: repeated CUDA run matches a straight one only up to rounding; checkpoints keep the GPU's RNG state.
    device: Literal[DEVICES] = "cpu"  # type: ignore[valid-type]
    #: A loss whose magnitude exceeds this counts as divergence and stops training.
    max_abs_loss: float = 1e4
    #: Name of the run in metrics.csv; empty: the output folder's name.
    run_id: str = ""
    #: Start the generator from this exported model (a gigan-export ONNX file with its model.json)
    #: instead of random weights, to fine-tune it; its architecture and input encoding must be this
    #: run's (the depth scale defaults to the model's). A critic starts fresh. Absent: random weights.
    init_generator: str | None = None

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"unknown model {self.model!r}; choose one of {list(MODELS)}")
        for name in ("ngf", "ndf", "n_down", "crop", "batch_size", "n_critic", "epochs"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.upsample not in UPSAMPLINGS:
            raise ValueError(f"upsample must be one of {list(UPSAMPLINGS)}, got {self.upsample!r}")
        if self.model == "deep_shading" and self.upsample != "transposed":
            raise ValueError("upsample applies to the unet generators; deep_shading always up-samples bilinearly")
        if self.device not in DEVICES:
            raise ValueError(f"device must be one of {list(DEVICES)}, got {self.device!r}")
        if self.critic_warmup < 0:
            raise ValueError(f"critic_warmup must be >= 0, got {self.critic_warmup}")
        if self.max_steps is not None and self.max_steps < 0:
            raise ValueError(f"max_steps must be >= 0, got {self.max_steps}")
        if self.max_minutes is not None and self.max_minutes < 0:
            raise ValueError(f"max_minutes must be >= 0, got {self.max_minutes}")
        if not self.lr > 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")
        self.buffers = list(self.buffers)
        InputSpec(tuple(self.buffers), albedo_floor=self.albedo_floor)  # (the depth scale is checked once derived)
        self.datasets = [str(d) for d in self.datasets]
        if self.init_generator is not None:
            self.init_generator = str(self.init_generator)

    @property
    def train_side(self) -> int:
        """Side of the training images (the crop, else the frame)."""
        if self.resolution is None:
            raise ValueError("resolution is unknown; train() reads it from the datasets")
        return self.resolution if self.crop is None else self.crop

    @property
    def albedo_floor(self) -> float | None:
        """The floor of the albedo the I/O is demodulated by (:attr:`InputSpec.albedo_floor`); None: radiance."""
        return ALBEDO_FLOOR if self.demodulate else None

    def input_spec(self) -> InputSpec:
        """The generator's input contract (buffers, depth scale, demodulation)."""
        if self.depth_scale is None:
            raise ValueError("depth_scale is unknown; train() derives it from the training data")
        return InputSpec(tuple(self.buffers), self.depth_scale, self.albedo_floor)

    def network_configs(self) -> dict[str, NetworkConfig]:
        """Architectures this run builds: ``G`` always, ``D`` for the adversarial models."""
        side = self.train_side
        if side > self.resolution:
            raise ValueError(f"crop {side} exceeds the frame size {self.resolution}")
        full_down = (side & -side).bit_length() - 1  # log2 of the largest power of two dividing side
        in_ch = self.input_spec().in_channels
        if self.model == "deep_shading":
            g = NetworkConfig(
                "deep_shading", in_ch, 3, self.ngf, max(1, full_down - 2) if self.n_down is None else self.n_down
            )
        else:
            g = NetworkConfig(
                "unet", in_ch, 3, self.ngf, full_down if self.n_down is None else self.n_down, upsample=self.upsample
            )
        for s in {side, self.resolution}:
            g.check_size(s)
        nets = {"G": g}
        if self.model != "deep_shading":
            # GIGAN's critic has no norm (per-sample gradient penalty); Deep Illumination keeps pix2pix's BN.
            norm = "none" if self.model == "gigan" else "batch"
            cond_ch = in_ch if self.critic_condition else 0
            nets["D"] = NetworkConfig("patchgan", cond_ch, 3, self.ngf if self.ndf is None else self.ndf, 3, norm=norm)
            nets["D"].check_size(side)
        return nets

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        return strict_from_dict(cls, d, "training")


def write_run_config(out_dir: Path, cfg: TrainConfig, nets: dict[str, NetworkConfig]) -> None:
    """Write ``config.json``: the training config and each network's architecture."""
    doc = {"train": cfg.to_dict(), "networks": {k: v.to_dict() for k, v in nets.items()}}
    atomic_write_bytes(out_dir / CONFIG, json.dumps(doc, indent=1).encode())


def read_run_config(run_dir: Path) -> tuple[TrainConfig, dict[str, NetworkConfig]]:
    """Read a run folder's ``config.json`` (see :func:`write_run_config`); UserError naming it if missing or
    unreadable."""
    path = Path(run_dir) / CONFIG
    if not path.is_file():
        raise UserError(
            f"{path} is missing", f"give a training run folder made by `gigan-train` ({run_dir} is not one)"
        )
    try:
        doc = json.loads(path.read_text())
        return TrainConfig.from_dict(doc["train"]), {k: NetworkConfig.from_dict(v) for k, v in doc["networks"].items()}
    except (
        ValueError,
        TypeError,
        KeyError,
        AttributeError,
    ) as e:  # JSON syntax, missing sections, unknown or bad fields
        raise UserError(
            f"{path} is not a readable run config ({type(e).__name__}: {e})",
            "restore it, or train a new run with `gigan-train`",
        ) from None
