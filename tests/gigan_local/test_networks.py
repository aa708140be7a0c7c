"""Architectures (GIGAN U-Net, PatchGAN critic, Deep Shading) and losses of gigan_local."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch
from torch import nn

from gicore.metrics import ssim as metric_ssim
from gigan_local.config import NetworkConfig, TrainConfig
from gigan_local.losses import bce_gan_loss, gradient_penalty, ssim, ssim_loss, wgan_critic_loss, wgan_generator_loss
from gigan_local.networks import count_parameters, define_D, define_G

NORM_TYPES = (nn.BatchNorm2d, nn.InstanceNorm2d, nn.GroupNorm, nn.LayerNorm)


def test_unet_256_has_pix2pix_parameter_count():
    g = define_G(NetworkConfig("unet", in_channels=3, out_channels=3, width=64, n_down=8))
    assert count_parameters(g) == 54_413_955


@pytest.mark.parametrize(("side", "width", "n_down"), [(64, 8, 6), (128, 4, 7), (256, 2, 8)])
def test_unet_output_shape(side, width, n_down):
    g = define_G(NetworkConfig("unet", in_channels=10, width=width, n_down=n_down))
    with torch.no_grad():
        y = g(torch.rand(2, 10, side, side) * 2 - 1)
    assert y.shape == (2, 3, side, side)
    assert y.abs().max() <= 1.0


def test_unet_layout_norms_dropout_and_skips():
    g = define_G(NetworkConfig("unet", in_channels=10, width=4, n_down=8))

    def has(seq, kind):
        return any(isinstance(m, kind) for m in seq)

    # Down: no norm after the first and the innermost (index 7) layer; no activation before the first.
    assert [has(d, nn.BatchNorm2d) for d in g.downs] == [False] + [True] * 6 + [False]
    assert not has(g.downs[0], nn.LeakyReLU) and all(has(d, nn.LeakyReLU) for d in g.downs[1:])
    # Up (ups[7] is the innermost, ups[0] the output): BN on all but the last, tanh out,
    # dropout exactly in the three up layers after the innermost.
    assert [has(u, nn.BatchNorm2d) for u in g.ups] == [False] + [True] * 7
    assert isinstance(g.ups[0][-1], nn.Tanh)
    assert [i for i, u in enumerate(g.ups) if has(u, nn.Dropout)] == [4, 5, 6]
    assert all(isinstance(u[0], nn.ReLU) for u in g.ups)
    # Skips: every up layer but the innermost takes [skip, previous up] (twice the channels).
    assert g.ups[7][1].in_channels == g.downs[7][-1].out_channels
    for i in range(7):
        conv = next(m for m in g.downs[i] if isinstance(m, nn.Conv2d))
        assert g.ups[i][1].in_channels == 2 * conv.out_channels


def test_dropout_is_active_in_train_mode_only():
    torch.manual_seed(0)
    g = define_G(NetworkConfig("unet", in_channels=10, width=4, n_down=5))
    x = torch.rand(2, 10, 32, 32)
    with torch.no_grad():
        g.train()
        assert not torch.equal(g(x), g(x))
        g.eval()
        assert torch.equal(g(x), g(x))


def test_gigan_critic_is_a_five_conv_patchgan_without_normalisation():
    d = define_D(TrainConfig(model="gigan", resolution=64, depth_scale=1.0, ndf=8).network_configs()["D"])
    assert not any(isinstance(m, NORM_TYPES) for m in d.modules())
    convs = [m for m in d.modules() if isinstance(m, nn.Conv2d)]
    assert len(convs) == 5
    assert [c.stride[0] for c in convs] == [2, 2, 2, 1, 1]
    assert convs[0].in_channels == 10 + 3  # conditioned on the generator input
    assert sum(isinstance(m, nn.LeakyReLU) for m in d.modules()) == 4
    assert isinstance(d.model[-1], nn.Conv2d)  # no activation after the last conv
    out = d(torch.rand(2, 10, 64, 64), torch.rand(2, 3, 64, 64))
    assert out.shape == (2, 1, 6, 6)


def test_deep_illumination_critic_keeps_batch_norm():
    d = define_D(TrainConfig(model="deep_illumination", resolution=64, depth_scale=1.0, ndf=8).network_configs()["D"])
    assert sum(isinstance(m, nn.BatchNorm2d) for m in d.modules()) == 3


def test_deep_shading_generator():
    cfg = TrainConfig(model="deep_shading", resolution=64, depth_scale=1.0, ngf=4)
    nets = cfg.network_configs()
    assert set(nets) == {"G"} and nets["G"].name == "deep_shading" and nets["G"].n_down == 4
    g = define_G(nets["G"])
    assert not any(isinstance(m, (*NORM_TYPES, nn.Dropout)) for m in g.modules())
    with torch.no_grad():
        assert g(torch.rand(1, 10, 64, 64)).shape == (1, 3, 64, 64)


def test_input_channels_come_from_the_buffer_list():
    assert TrainConfig(resolution=32, depth_scale=1.0).network_configs()["G"].in_channels == 10
    nets = TrainConfig(resolution=32, depth_scale=1.0, buffers=["di", "normal"]).network_configs()
    assert nets["G"].in_channels == 6 and nets["D"].in_channels == 6


def test_network_config_json_round_trip_and_errors():
    cfg = NetworkConfig("unet", in_channels=10, width=16, n_down=6)
    assert NetworkConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match="unknown network config field"):
        NetworkConfig.from_dict(cfg.to_dict() | {"bogus": 1})
    with pytest.raises(ValueError, match="unknown network"):
        NetworkConfig("resnet", in_channels=3)
    with pytest.raises(ValueError, match="divisible by 64"):
        cfg.check_size(96)
    with pytest.raises(ValueError, match="divisible by 256"):
        TrainConfig(resolution=256, crop=64, n_down=8, depth_scale=1.0).network_configs()


def test_gradient_penalty_of_a_linear_critic_is_analytic():
    torch.manual_seed(0)
    real, fake = torch.randn(4, 3, 8, 8), torch.randn(4, 3, 8, 8)
    for scale in (0.3, 1.0, 2.5):
        w = torch.randn(3 * 8 * 8)
        w = w / w.norm() * scale

        def critic(cond, y, w=w):
            return (y.flatten(1) * w).sum(1)

        gp = gradient_penalty(critic, None, real, fake, lambda_gp=10.0)
        assert gp.item() == pytest.approx(10.0 * (scale - 1.0) ** 2, rel=1e-5, abs=1e-6)


def test_gradient_penalty_reaches_the_critic_weights():
    torch.manual_seed(0)
    d = define_D(NetworkConfig("patchgan", in_channels=2, width=4, n_down=3, norm="none"))
    cond, real, fake = torch.rand(2, 2, 32, 32), torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
    gp = gradient_penalty(d, cond, real, fake)
    gp.backward()
    assert gp.item() > 0
    # Every conv weight shapes the input gradient (biases only move LeakyReLU kinks, so they get none).
    assert all(m.weight.grad.abs().sum() > 0 for m in d.modules() if isinstance(m, nn.Conv2d))


def test_gan_losses():
    real, fake = torch.full((2, 1, 4, 4), 3.0), torch.full((2, 1, 4, 4), -1.0)
    assert wgan_critic_loss(real, fake).item() == pytest.approx(-4.0)
    assert wgan_generator_loss(fake).item() == pytest.approx(1.0)
    assert bce_gan_loss(torch.full((2, 1, 4, 4), 20.0), True).item() < 1e-6
    assert bce_gan_loss(torch.zeros(2, 1, 4, 4), False).item() == pytest.approx(np.log(2.0))


def test_ssim_loss_matches_the_metric_and_is_differentiable():
    rng = np.random.default_rng(0)
    a = rng.random((24, 30, 3)).astype(np.float32)
    b = np.clip(a + 0.2 * rng.standard_normal(a.shape), 0, 1).astype(np.float32)

    def t(z):
        return torch.from_numpy(z).permute(2, 0, 1)[None]

    assert ssim(t(a), t(b)).item() == pytest.approx(metric_ssim(a, b), abs=1e-5)
    pred = (t(b) * 2 - 1).requires_grad_(True)
    loss = ssim_loss(pred, t(a) * 2 - 1)
    loss.backward()
    assert loss.item() == pytest.approx(1 - metric_ssim(a, b), abs=1e-5)
    assert torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0


def test_importing_the_configs_does_not_load_torch():
    """One config mechanism (gicore.config.strict_from_dict) without torch: reading a run's config.json, a
    model.json or a dataset's meta.json must not pay for (or need) torch."""
    code = (
        "import sys\n"
        "import gicore.config, gicore.dataset, gigan_local.config, gigan_local.preprocess\n"
        "from gigan_local.config import NetworkConfig, TrainConfig\n"
        "TrainConfig.from_dict(TrainConfig().to_dict()); NetworkConfig.from_dict(NetworkConfig('unet', 8).to_dict())\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


@pytest.mark.parametrize(
    "doc,message",
    [
        pytest.param({"name": "unet"}, r"lacks field\(s\) \['in_channels'\]", id="missing"),
        pytest.param(
            {"name": "unet", "in_channels": 8, "depth": 3},
            r"unknown network config field\(s\) \['depth'\]",
            id="unknown",
        ),
        pytest.param(["unet", 8], "must be a JSON object, got list", id="not_an_object"),
    ],
)
def test_strict_from_dict_names_the_field(doc, message):
    with pytest.raises(ValueError, match=message):
        NetworkConfig.from_dict(doc)
