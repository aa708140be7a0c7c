"""Training configuration: one JSON-serialisable dataclass that, with the data, fixes a training run.

``config.json`` beside each checkpoint holds this config and the :class:`NetworkConfig` of every network
it builds, so a run can be resumed, exported or rebuilt without the command line that started it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from gigan_local.networks import NetworkConfig, strict_from_dict
from gigan_local.preprocess import DEFAULT_BUFFERS, InputSpec

MODELS = ("gigan", "deep_shading", "deep_illumination")
#: Fields that only bound how long a run goes on; ``--resume`` may change them, nothing else.
BUDGET_FIELDS = ("epochs", "max_steps", "max_minutes", "max_val_frames", "checkpoint_every")


@dataclass
class TrainConfig:
    """How to train one model (paper IV.B defaults); ``None`` fields are derived from the data."""

    #: ``gigan`` (U-Net + PatchGAN, conditional WGAN-GP + L1), ``deep_shading`` (CNN U-Net, L1 + SSIM,
    #: no adversary) or ``deep_illumination`` (U-Net + PatchGAN, vanilla BCE GAN + L1).
    model: str = "gigan"
    #: Dataset folders (``gicore.dataset``): their train splits train, their val splits validate.
    datasets: list[str] = field(default_factory=list)
    #: Generator input buffers, in channel order (encodings: ``gigan_local.preprocess``).
    buffers: list[str] = field(default_factory=lambda: list(DEFAULT_BUFFERS))
    #: Depth that encodes to 0; None: the median foreground depth of the training data.
    depth_scale: float | None = None
    #: Frame side in pixels; None: read from the datasets (which must agree).
    resolution: int | None = None
    #: Train on random crop x crop windows (cheaper steps); validation always uses whole frames.
    crop: int | None = None
    #: Generator width (pix2pix ngf).
    ngf: int = 64
    #: Critic width (pix2pix ndf); None: equal to ngf (the paper's 64/64), so shrinking the generator for
    #: a CPU budget shrinks the critic too (at 256 px, ndf 64 makes an ngf-16 GIGAN step ~6x slower).
    ndf: int | None = None
    #: Generator down-samplings; None: log2 of the training side (1x1 bottleneck) for unet, two fewer
    #: for deep_shading (see ``networks.DeepShadingGenerator``).
    n_down: int | None = None
    batch_size: int = 8
    #: Adam learning rate and betas, for generator and critic alike.
    lr: float = 2e-4
    beta1: float = 0.5
    beta2: float = 0.999
    #: Weight of the L1 term (eq. 4); also deep_shading's L1 weight.
    lambda_L1: float = 100.0
    #: Weight of the gradient penalty (eq. 2); gigan only.
    lambda_gp: float = 10.0
    #: Critic steps per generator step (gigan); 1 alternates them as the paper does.
    n_critic: int = 1
    #: Weight of deep_shading's (1 - SSIM) term; equal to lambda_L1 by default (with Adam only the
    #: ratio of the two matters).
    lambda_ssim: float = 100.0
    #: Budget: stop at whichever of these comes first (max_minutes counts wall time of one invocation).
    epochs: int = 100
    max_steps: int | None = None
    max_minutes: float | None = None
    #: Seeds weights, dropout, penalty interpolation, data order and crops.
    seed: int = 0
    #: Validate on at most this many val frames (per epoch); None: all of them.
    max_val_frames: int | None = None
    #: Also checkpoint every this many steps (0: only at epoch ends and at the stop).
    checkpoint_every: int = 500
    #: A loss whose magnitude exceeds this counts as divergence and stops training.
    max_abs_loss: float = 1e4
    #: Name of the run in metrics.csv; empty: the output folder's name.
    run_id: str = ""

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"unknown model {self.model!r}; choose one of {list(MODELS)}")
        for name in ("ngf", "ndf", "batch_size", "n_critic", "epochs"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_steps is not None and self.max_steps < 0:
            raise ValueError(f"max_steps must be >= 0, got {self.max_steps}")
        if self.max_minutes is not None and self.max_minutes < 0:
            raise ValueError(f"max_minutes must be >= 0, got {self.max_minutes}")
        if not self.lr > 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")
        self.buffers = list(self.buffers)
        self.datasets = [str(d) for d in self.datasets]

    @property
    def train_side(self) -> int:
        """Side of the training images (the crop, else the frame)."""
        if self.resolution is None:
            raise ValueError("resolution is unknown; train() reads it from the datasets")
        return self.crop or self.resolution

    def input_spec(self) -> InputSpec:
        """The generator's input contract (buffers and depth scale)."""
        if self.depth_scale is None:
            raise ValueError("depth_scale is unknown; train() derives it from the training data")
        return InputSpec(tuple(self.buffers), self.depth_scale)

    def network_configs(self) -> dict[str, NetworkConfig]:
        """Architectures this run builds: ``G`` always, ``D`` for the adversarial models."""
        side = self.train_side
        full_down = (side & -side).bit_length() - 1  # log2 of the largest power of two dividing side
        in_ch = self.input_spec().in_channels
        if self.model == "deep_shading":
            g = NetworkConfig("deep_shading", in_ch, 3, self.ngf, self.n_down or max(1, full_down - 2))
        else:
            g = NetworkConfig("unet", in_ch, 3, self.ngf, self.n_down or full_down)
        for s in {side, self.resolution}:
            g.check_size(s)
        nets = {"G": g}
        if self.model != "deep_shading":
            # GIGAN's critic has no norm (per-sample gradient penalty); Deep Illumination keeps pix2pix's BN.
            norm = "none" if self.model == "gigan" else "batch"
            nets["D"] = NetworkConfig("patchgan", in_ch, 3, self.ndf or self.ngf, 3, norm=norm)
            nets["D"].check_size(side)
        return nets

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "TrainConfig":
        return strict_from_dict(cls, d, "training")
