"""Training losses: conditional WGAN-GP (paper eq. 2), vanilla GAN (BCE), L1 (eq. 3) and SSIM.

A PatchGAN critic returns one score per patch; a sample's critic value D(c, y) is the mean of its patch
scores (:func:`critic_score`). The Wasserstein losses and the gradient penalty both use that same
per-sample value, so the penalty constrains exactly the function whose expectation the loss takes
(pix2pix's ``cal_gradient_penalty`` differentiates the patch *sum*, which scales the penalty's gradient
by the number of patches).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

Critic = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def critic_score(out: torch.Tensor) -> torch.Tensor:
    """Per-sample critic value (B,): the mean over everything but the batch dimension."""
    return out.reshape(out.shape[0], -1).mean(1)


def gradient_penalty(
    critic: Critic, cond: torch.Tensor, real: torch.Tensor, fake: torch.Tensor, lambda_gp: float = 10.0
) -> torch.Tensor:
    """WGAN-GP penalty ``lambda * E[(||grad_y D(c, y_hat)||_2 - 1)^2]`` (paper eq. 2, second line).

    ``y_hat = a * real + (1 - a) * fake`` with one uniform ``a`` per sample. The result keeps its graph
    (``create_graph``), so backpropagating it reaches the critic's weights.
    """
    alpha = torch.rand(real.shape[0], *([1] * (real.dim() - 1)), device=real.device, dtype=real.dtype)
    interp = (alpha * real.detach() + (1.0 - alpha) * fake.detach()).requires_grad_(True)
    score = critic_score(critic(cond, interp))
    (grad,) = torch.autograd.grad(score.sum(), interp, create_graph=True)
    # The norm's gradient is undefined at 0; the epsilon keeps a zero gradient (e.g. a dead critic) finite.
    norm = torch.sqrt(grad.flatten(1).pow(2).sum(1) + 1e-12)
    return lambda_gp * ((norm - 1.0) ** 2).mean()


def wgan_critic_loss(real_out: torch.Tensor, fake_out: torch.Tensor) -> torch.Tensor:
    """Critic loss E[D(c, G(c))] - E[D(c, y)] (the negated Wasserstein estimate; add the penalty)."""
    return critic_score(fake_out).mean() - critic_score(real_out).mean()


def wgan_generator_loss(fake_out: torch.Tensor) -> torch.Tensor:
    """Generator adversarial loss -E[D(c, G(c))]."""
    return -critic_score(fake_out).mean()


def bce_gan_loss(logits: torch.Tensor, target_is_real: bool) -> torch.Tensor:
    """Vanilla GAN loss on raw patch logits (pix2pix 'vanilla'): BCE against all-ones or all-zeros."""
    target = torch.ones_like(logits) if target_is_real else torch.zeros_like(logits)
    return F.binary_cross_entropy_with_logits(logits, target)


def l1_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean absolute error (paper eq. 3)."""
    return F.l1_loss(pred, target)


def _gaussian_window(
    sigma: float, truncate: float, channels: int, device: torch.device, dtype: torch.dtype
) -> torch.Tensor:
    radius = int(truncate * sigma + 0.5)
    x = torch.arange(-radius, radius + 1, device=device, dtype=dtype)
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(channels, 1, -1, -1).contiguous()


def ssim(x: torch.Tensor, y: torch.Tensor, sigma: float = 1.5, data_range: float = 1.0) -> torch.Tensor:
    """Differentiable mean SSIM of BxCxHxW images, matching ``gicore.metrics.ssim`` (scikit-image).

    Same settings as the metric: Gaussian window sigma 1.5 truncated at 3.5 sigma (11x11), population
    covariance, K1 = 0.01, K2 = 0.03, mean over the valid (un-padded) window positions and channels.
    Images must be at least 11 pixels on a side.
    """
    c = x.shape[1]
    win = _gaussian_window(sigma, 3.5, c, x.device, x.dtype)
    if min(x.shape[-2:]) < win.shape[-1]:
        raise ValueError(
            f"SSIM needs images of at least {win.shape[-1]}x{win.shape[-1]} pixels, got {tuple(x.shape[-2:])}"
        )

    def blur(t: torch.Tensor) -> torch.Tensor:
        return F.conv2d(t, win, groups=c)

    mx, my = blur(x), blur(y)
    vx = blur(x * x) - mx * mx
    vy = blur(y * y) - my * my
    cxy = blur(x * y) - mx * my
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return s.mean()


def ssim_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 - SSIM of two network outputs in [-1, 1], measured on the [0, 1] display values the metrics use."""
    return 1.0 - ssim((pred + 1.0) * 0.5, (target + 1.0) * 0.5)
