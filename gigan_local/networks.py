"""Generator and critic architectures, built by name from a JSON-serialisable :class:`NetworkConfig`.

- ``unet``: the GIGAN / Deep Illumination generator (paper IV.A), layer for layer the pix2pix
  ``UnetGenerator``: with 3 input channels, ngf 64 and 8 downs it is pix2pix ``unet_256`` (54,413,955
  parameters).
- ``patchgan``: Markovian PatchGAN critic (pix2pix ``NLayerDiscriminator``), conditioned on the
  generator input by channel concatenation (with ``in_channels`` 0 it judges the image alone). GIGAN
  uses it without normalisation, because batch norm couples the samples of a batch and so breaks the
  per-sample gradient penalty (paper IV.A); Deep Illumination keeps pix2pix's batch norm (its original
  is pix2pix-based and uses no penalty).
- ``deep_shading``: the Deep Shading generator (Nalbach et al. 2017): a plain CNN U-Net with one 3x3
  convolution per level and side, leaky ReLU, average-pool down, bilinear up and skip concatenation; no
  normalisation, no dropout.

Every network maps values in [-1, 1] (``gigan_local.preprocess``); generators end in tanh.
"""

from __future__ import annotations

import torch
from torch import nn

from gigan_local.config import CRITICS, GENERATORS, NetworkConfig


def _widths(width: int, n: int) -> list[int]:
    """Channels per level, doubling up to 8x the first (pix2pix)."""
    return [width * min(2**i, 8) for i in range(n)]


def _norm(kind: str, channels: int) -> list[nn.Module]:
    return [nn.BatchNorm2d(channels)] if kind == "batch" else []


def _upsampling_conv(kind: str, c_in: int, c_out: int, bias: bool) -> list[nn.Module]:
    """A layer that doubles the side: ``transposed`` (pix2pix: 4x4, stride 2, so output pixels of the two
    parities sum different kernel taps, the source of a period-2 checkerboard) or ``resize`` (nearest 2x,
    then a 3x3 conv: every output pixel sees the same taps; Odena, Dumoulin and Olah 2016)."""
    if kind == "transposed":
        return [nn.ConvTranspose2d(c_in, c_out, kernel_size=4, stride=2, padding=1, bias=bias)]
    return [nn.Upsample(scale_factor=2, mode="nearest"), nn.Conv2d(c_in, c_out, kernel_size=3, padding=1, bias=bias)]


class UnetGenerator(nn.Module):
    """pix2pix U-Net: down i and up i are joined by a skip (paper: layer i <-> layer N - i).

    Down layer i (i = 0..N-1): [LeakyReLU 0.2], 4x4 stride-2 conv, [BatchNorm] -- no activation before
    the first, no norm after the first and the innermost. Up layer i (i = N-1..0): ReLU, a 2x up-sampling
    convolution (``cfg.upsample``: pix2pix's 4x4 stride-2 transposed conv, or a nearest-neighbour 2x
    resize followed by a 3x3 conv), then BatchNorm (all but the outermost), Dropout (the first
    ``n_dropout`` after the innermost) or tanh (outermost). Convs followed by BatchNorm carry no bias (as
    pix2pix; this is what makes the parameter count match).
    """

    def __init__(self, cfg: NetworkConfig) -> None:
        super().__init__()
        n, w = cfg.n_down, _widths(cfg.width, cfg.n_down)
        bias = cfg.norm == "none"
        self.downs = nn.ModuleList()
        for i in range(n):
            c_in = cfg.in_channels if i == 0 else w[i - 1]
            layers: list[nn.Module] = [] if i == 0 else [nn.LeakyReLU(0.2)]
            layers.append(nn.Conv2d(c_in, w[i], kernel_size=4, stride=2, padding=1, bias=bias))
            if 0 < i < n - 1:
                layers += _norm(cfg.norm, w[i])
            self.downs.append(nn.Sequential(*layers))
        # ups[i] mirrors downs[i]; its input is the innermost feature (i = N-1) or [skip_i, up_{i+1}].
        self.ups = nn.ModuleList()
        for i in range(n):
            c_in = w[i] if i == n - 1 else 2 * w[i]
            if i == 0:
                layers = [nn.ReLU(), *_upsampling_conv(cfg.upsample, c_in, cfg.out_channels, bias=True), nn.Tanh()]
            else:
                layers = [nn.ReLU(), *_upsampling_conv(cfg.upsample, c_in, w[i - 1], bias=bias)]
                layers += _norm(cfg.norm, w[i - 1])
                if cfg.dropout > 0 and n - 1 - cfg.n_dropout <= i < n - 1:
                    layers.append(nn.Dropout(cfg.dropout))
            self.ups.append(nn.Sequential(*layers))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for down in self.downs:
            x = down(x)
            skips.append(x)
        x = self.ups[-1](skips[-1])
        for i in range(len(self.ups) - 2, -1, -1):
            x = self.ups[i](torch.cat([skips[i], x], dim=1))
        return x


class DeepShadingGenerator(nn.Module):
    """Deep Shading U-Net (Nalbach et al. 2017): one 3x3 conv + leaky ReLU 0.01 per level on each side,
    2x2 average pooling down, bilinear 2x upsampling, skip concatenation, 1x1 conv + tanh out.

    Its bottom level sits at side / 2**n_down and still convolves, so it wants two levels fewer than the
    unet. At ngf 64, n_down 6 it has 25.1 M parameters (unet at n_down 8: 54.4 M), but its convs run at
    the full resolution of each level, so a training step costs several times the unet's at equal ngf.
    """

    def __init__(self, cfg: NetworkConfig) -> None:
        super().__init__()
        w = _widths(cfg.width, cfg.n_down + 1)

        def conv(c_in: int, c_out: int) -> nn.Sequential:
            return nn.Sequential(nn.Conv2d(c_in, c_out, 3, padding=1), nn.LeakyReLU(0.01))

        self.encoders = nn.ModuleList(
            [conv(cfg.in_channels if i == 0 else w[i - 1], w[i]) for i in range(cfg.n_down + 1)]
        )
        self.decoders = nn.ModuleList([conv(w[i] + w[i + 1], w[i]) for i in range(cfg.n_down)])
        self.pool = nn.AvgPool2d(2)
        self.up = nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False)
        self.head = nn.Sequential(nn.Conv2d(w[0], cfg.out_channels, 1), nn.Tanh())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, enc in enumerate(self.encoders):
            x = enc(x if i == 0 else self.pool(x))
            skips.append(x)
        for i in range(len(self.decoders) - 1, -1, -1):
            x = self.decoders[i](torch.cat([skips[i], self.up(x)], dim=1))
        return self.head(x)


class PatchCritic(nn.Module):
    """Markovian PatchGAN (pix2pix NLayerDiscriminator): ``n_down`` 4x4 stride-2 convs, one 4x4
    stride-1 conv, then a 4x4 conv to one channel; LeakyReLU 0.2 after all but the last; optional
    BatchNorm after convs 2..n_down+1. Outputs one unbounded score per (70x70 for n_down 3) patch.
    """

    def __init__(self, cfg: NetworkConfig) -> None:
        super().__init__()
        self.conditional = cfg.in_channels > 0
        w = _widths(cfg.width, cfg.n_down + 1)
        bias = cfg.norm == "none"
        layers: list[nn.Module] = [
            nn.Conv2d(cfg.in_channels + cfg.out_channels, w[0], 4, stride=2, padding=1),
            nn.LeakyReLU(0.2),
        ]
        for i in range(1, cfg.n_down + 1):
            stride = 2 if i < cfg.n_down else 1
            layers += [
                nn.Conv2d(w[i - 1], w[i], 4, stride=stride, padding=1, bias=bias),
                *_norm(cfg.norm, w[i]),
                nn.LeakyReLU(0.2),
            ]
        layers.append(nn.Conv2d(w[-1], 1, 4, stride=1, padding=1))
        self.model = nn.Sequential(*layers)

    def forward(self, cond: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        """Patch scores (Bx1xH'xW') of ``image`` given the generator input ``cond`` (which an
        unconditional critic, ``in_channels`` 0, ignores)."""
        return self.model(torch.cat([cond, image], dim=1) if self.conditional else image)


def init_weights(net: nn.Module, gain: float = 0.02) -> nn.Module:
    """pix2pix 'normal' init: conv weights ~ N(0, gain), BatchNorm weights ~ N(1, gain), biases 0."""
    for m in net.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
            nn.init.normal_(m.weight, 0.0, gain)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.normal_(m.weight, 1.0, gain)
            nn.init.zeros_(m.bias)
    return net


def define_G(cfg: NetworkConfig) -> nn.Module:
    """Build and initialise the generator ``cfg.name`` (``unet`` or ``deep_shading``)."""
    if cfg.name == "unet":
        return init_weights(UnetGenerator(cfg))
    if cfg.name == "deep_shading":
        return init_weights(DeepShadingGenerator(cfg))
    raise ValueError(f"{cfg.name!r} is not a generator; choose one of {list(GENERATORS)}")


def define_D(cfg: NetworkConfig) -> PatchCritic:
    """Build and initialise the critic ``cfg.name`` (``patchgan``)."""
    if cfg.name == "patchgan":
        return init_weights(PatchCritic(cfg))
    raise ValueError(f"{cfg.name!r} is not a critic; choose one of {list(CRITICS)}")


def count_parameters(net: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)
