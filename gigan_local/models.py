"""The three trainable models: GIGAN, Deep Shading and Deep Illumination (pix2pix-style classes).

Each model owns its networks and optimizers, names the losses it logs (``loss_names``) and performs
one training iteration in ``optimize(batch)``. ``create_model`` builds one from a :class:`TrainConfig`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch
from torch import nn

from gigan_local.config import MODELS, TrainConfig
from gigan_local.losses import (
    bce_gan_loss,
    critic_score,
    gradient_penalty,
    l1_loss,
    ssim_loss,
    wgan_critic_loss,
    wgan_generator_loss,
)
from gigan_local.networks import NetworkConfig, define_D, define_G

Batch = tuple[torch.Tensor, torch.Tensor]


def _set_requires_grad(net: nn.Module, flag: bool) -> None:
    for p in net.parameters():
        p.requires_grad_(flag)


class BaseModel:
    """Common parts: the generator, Adam optimizers, train/eval switching and state for checkpoints."""

    loss_names: ClassVar[tuple[str, ...]]

    def __init__(self, cfg: TrainConfig) -> None:
        self.cfg = cfg
        self.net_configs: dict[str, NetworkConfig] = cfg.network_configs()
        self.nets: dict[str, nn.Module] = {"G": define_G(self.net_configs["G"])}
        if "D" in self.net_configs:
            self.nets["D"] = define_D(self.net_configs["D"])
        self.optimizers = {
            name: torch.optim.Adam(net.parameters(), lr=cfg.lr, betas=(cfg.beta1, cfg.beta2))
            for name, net in self.nets.items()
        }

    @property
    def generator(self) -> nn.Module:
        return self.nets["G"]

    def to(self, device: str) -> None:
        """Move the networks to ``device``; the optimizers keep them (the parameters move in place)."""
        for net in self.nets.values():
            net.to(device)

    def train(self) -> None:
        for net in self.nets.values():
            net.train()

    def eval(self) -> None:
        for net in self.nets.values():
            net.eval()

    def optimize(self, batch: Batch) -> dict[str, float]:
        """One training iteration on ``(input, target)``; returns the logged losses."""
        raise NotImplementedError

    def parameters_finite(self) -> bool:
        """Whether every weight of every network is finite (divergence check)."""
        checks = [torch.isfinite(p).all() for net in self.nets.values() for p in net.parameters()]
        return bool(torch.stack(checks).all())  # one device sync per step, not one per tensor

    def state_dict(self) -> dict[str, Any]:
        return {
            "nets": {k: v.state_dict() for k, v in self.nets.items()},
            "optimizers": {k: v.state_dict() for k, v in self.optimizers.items()},
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for k, net in self.nets.items():
            net.load_state_dict(state["nets"][k])
        for k, opt in self.optimizers.items():
            opt.load_state_dict(state["optimizers"][k])


class GIGAN(BaseModel):
    """Conditional WGAN-GP + lambda_L1 * L1 (paper eq. 4) with a normalisation-free PatchGAN critic.

    Every ``optimize`` call takes a critic step (with the gradient penalty); after the first
    ``critic_warmup`` calls, every ``n_critic``-th call also takes a generator step. ``G_L1`` is logged
    on every call (as a plain value between generator steps); ``D_W`` is the critic's Wasserstein
    estimate E[D(real)] - E[D(fake)].
    """

    loss_names = ("G_GAN", "G_L1", "D_real", "D_fake", "D_GP", "D_W")

    def __init__(self, cfg: TrainConfig) -> None:
        super().__init__(cfg)
        self.critic_steps = 0

    def optimize(self, batch: Batch) -> dict[str, float]:
        cond, real = batch
        G, D = self.nets["G"], self.nets["D"]
        warm = self.critic_steps >= self.cfg.critic_warmup
        generator_step = warm and (self.critic_steps - self.cfg.critic_warmup + 1) % self.cfg.n_critic == 0
        with torch.set_grad_enabled(generator_step):  # critic-only calls need no graph through G
            fake = G(cond)

        _set_requires_grad(D, True)
        self.optimizers["D"].zero_grad(set_to_none=True)
        real_out, fake_out = D(cond, real), D(cond, fake.detach())
        gp = gradient_penalty(D, cond, real, fake, self.cfg.lambda_gp)
        (wgan_critic_loss(real_out, fake_out) + gp).backward()
        self.optimizers["D"].step()
        self.critic_steps += 1
        d_real, d_fake = critic_score(real_out).mean().item(), critic_score(fake_out).mean().item()
        logs = {"D_real": d_real, "D_fake": d_fake, "D_GP": gp.item(), "D_W": d_real - d_fake}

        if generator_step:
            _set_requires_grad(D, False)  # the generator step must not accumulate critic gradients
            self.optimizers["G"].zero_grad(set_to_none=True)
            g_gan = wgan_generator_loss(D(cond, fake))
            g_l1 = l1_loss(fake, real)
            (g_gan + self.cfg.lambda_L1 * g_l1).backward()
            self.optimizers["G"].step()
            logs["G_GAN"] = g_gan.item()
        else:
            g_l1 = l1_loss(fake.detach(), real)
        logs["G_L1"] = g_l1.item()
        return logs

    def state_dict(self) -> dict[str, Any]:
        return super().state_dict() | {"critic_steps": self.critic_steps}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.critic_steps = int(state["critic_steps"])


class DeepShading(BaseModel):
    """Deep Shading baseline: CNN U-Net trained on lambda_L1 * L1 + lambda_ssim * (1 - SSIM), no adversary."""

    loss_names = ("G_L1", "G_SSIM")

    def optimize(self, batch: Batch) -> dict[str, float]:
        cond, real = batch
        self.optimizers["G"].zero_grad(set_to_none=True)
        fake = self.nets["G"](cond)
        g_l1, g_ssim = l1_loss(fake, real), ssim_loss(fake, real)
        (self.cfg.lambda_L1 * g_l1 + self.cfg.lambda_ssim * g_ssim).backward()
        self.optimizers["G"].step()
        return {"G_L1": g_l1.item(), "G_SSIM": g_ssim.item()}


class DeepIllumination(BaseModel):
    """Deep Illumination baseline: U-Net + BatchNorm PatchGAN, vanilla (BCE) GAN + lambda_L1 * L1 (pix2pix)."""

    loss_names = ("G_GAN", "G_L1", "D_real", "D_fake")

    def optimize(self, batch: Batch) -> dict[str, float]:
        cond, real = batch
        G, D = self.nets["G"], self.nets["D"]
        fake = G(cond)

        _set_requires_grad(D, True)
        self.optimizers["D"].zero_grad(set_to_none=True)
        d_real, d_fake = bce_gan_loss(D(cond, real), True), bce_gan_loss(D(cond, fake.detach()), False)
        (0.5 * (d_real + d_fake)).backward()
        self.optimizers["D"].step()

        _set_requires_grad(D, False)
        self.optimizers["G"].zero_grad(set_to_none=True)
        g_gan, g_l1 = bce_gan_loss(D(cond, fake), True), l1_loss(fake, real)
        (g_gan + self.cfg.lambda_L1 * g_l1).backward()
        self.optimizers["G"].step()
        return {"G_GAN": g_gan.item(), "G_L1": g_l1.item(), "D_real": d_real.item(), "D_fake": d_fake.item()}


#: The class of each name in :data:`gigan_local.config.MODELS`, in that order.
MODEL_CLASSES: dict[str, type[BaseModel]] = dict(zip(MODELS, (GIGAN, DeepShading, DeepIllumination), strict=True))


def create_model(cfg: TrainConfig) -> BaseModel:
    """Build the model ``cfg.model`` with freshly initialised networks (seed torch first)."""
    return MODEL_CLASSES[cfg.model](cfg)
