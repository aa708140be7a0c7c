"""The checkerboard and critic-conditioning diagnosis: the checkerboard metric against hand-computed
cases, the U-Net's resize up-sampling (which cannot print a tile pattern) and the unconditional critic."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gicore.metrics import SHADOW_DI, SHADOW_LIT, checker_error, lf_error, shadow_tint, ssim
from gigan_local.config import NetworkConfig, TrainConfig
from gigan_local.networks import define_D, define_G


def _checkerboard(n: int, h: float) -> np.ndarray:
    y, x = np.mgrid[:n, :n]
    return np.where((x + y) % 2 == 0, h, -h)[..., None].repeat(3, axis=2)


@pytest.mark.parametrize("h", [0.01, 0.05])
def test_a_checkerboard_scores_its_amplitude_and_lf_error_barely_sees_it(h: float) -> None:
    base = np.full((64, 64, 3), 0.5)
    board = base + _checkerboard(64, h)
    assert checker_error(board, base) == pytest.approx(h, abs=1e-12)
    assert lf_error(board, base) < 0.05 * h  # the blur averages it away


@pytest.mark.parametrize("period", [2, 4])
def test_stripes_of_period_two_or_four_score_their_amplitude(period: int) -> None:
    x = np.arange(64)
    stripes = np.where((x // (period // 2)) % 2 == 0, 0.03, -0.03)[None, :, None] * np.ones((64, 1, 3))
    assert checker_error(0.5 + stripes, np.full((64, 64, 3), 0.5)) == pytest.approx(0.03, abs=1e-12)


def test_a_constant_offset_is_not_a_checkerboard() -> None:
    base = np.random.default_rng(0).uniform(0.2, 0.7, (32, 32, 3))
    assert checker_error(base + 0.1, base) == pytest.approx(0.0, abs=1e-12)


def test_noise_and_a_ramp_stay_within_the_documented_bounds() -> None:
    rng = np.random.default_rng(1)
    s, n = 0.05, 256
    base = np.full((n, n, 3), 0.5)
    noisy = base + rng.normal(0.0, s, base.shape)
    # deviation of a tile-position mean: s / sqrt(tiles) = s * 4 / n; E|N(0, v)| = v * sqrt(2 / pi)
    assert checker_error(noisy, base) < 1.5 * s * 4 / n
    g = 0.1 / n
    ramp = base + g * np.arange(n)[None, :, None]
    assert checker_error(ramp, base) <= g * 4 / 2 + 1e-12


def test_checker_error_refuses_bad_periods_and_tiny_images() -> None:
    a = np.zeros((8, 8))
    with pytest.raises(ValueError, match="period must be an integer >= 2"):
        checker_error(a, a, period=1)
    with pytest.raises(ValueError, match="hold no 4x4 tile"):
        checker_error(np.zeros((3, 8)), np.zeros((3, 8)))


def test_resize_upsampling_prints_no_tile_pattern_where_transposed_convolutions_do() -> None:
    """A constant input: the transposed convs' overlapping taps make a period-2/4 pattern, the resize
    layers none (away from the border, whose padding is not periodic)."""
    scores = {}
    for upsample in ("transposed", "resize"):
        torch.manual_seed(0)
        g = define_G(NetworkConfig("unet", 3, 3, 8, 4, upsample=upsample)).eval()
        with torch.no_grad():
            out = (g(torch.full((1, 3, 64, 64), 0.3))[0].permute(1, 2, 0).numpy() + 1.0) / 2.0
        inner = out[8:-8, 8:-8].astype(np.float64)
        scores[upsample] = checker_error(inner, np.full_like(inner, inner.mean()))
    assert scores["transposed"] > 1e-4
    assert scores["resize"] < 1e-6


def test_an_unconditional_critic_ignores_the_condition() -> None:
    torch.manual_seed(0)
    critic = define_D(NetworkConfig("patchgan", 0, 3, 8, 3, norm="none"))
    image = torch.rand(2, 3, 64, 64)
    a, b = critic(torch.rand(2, 10, 64, 64), image), critic(torch.zeros(2, 10, 64, 64), image)
    assert torch.equal(a, b)
    conditional = define_D(NetworkConfig("patchgan", 10, 3, 8, 3, norm="none"))
    assert not torch.equal(
        conditional(torch.rand(2, 10, 64, 64), image), conditional(torch.zeros(2, 10, 64, 64), image)
    )


def test_train_config_builds_the_diagnosis_variants_and_refuses_what_does_not_apply() -> None:
    cfg = TrainConfig(model="gigan", resolution=128, depth_scale=1.0, ngf=8, upsample="resize", critic_condition=False)
    nets = cfg.network_configs()
    assert nets["G"].upsample == "resize"
    assert nets["D"].in_channels == 0
    with pytest.raises(ValueError, match="upsample applies to the unet generators"):
        TrainConfig(model="deep_shading", upsample="resize")
    with pytest.raises(ValueError, match="upsample must be one of"):
        TrainConfig(upsample="bilinear")
    with pytest.raises(ValueError, match="in_channels must be >= 1"):
        NetworkConfig("unet", 0, 3, 8, 4)


def test_ssim_barely_moves_under_a_checkerboard_that_checker_error_reports() -> None:
    base = np.random.default_rng(2).uniform(0.3, 0.7, (64, 64, 3))
    board = np.clip(base + _checkerboard(64, 0.01), 0, 1)
    assert checker_error(board, base) == pytest.approx(0.01, abs=1e-9)
    assert ssim(board, base) > 0.9


def _shadow_scene() -> tuple[np.ndarray, np.ndarray]:
    """A 16x16 reference lit at 0.3 with a DI that is dark on the left half (indirect light only) and
    bright on the right."""
    reference = np.full((16, 16, 3), 0.3)
    di = np.full((16, 16, 3), 0.6)
    di[:, :8] = SHADOW_DI / 2
    assert reference.mean() > SHADOW_LIT
    return reference, di


def test_shadow_tint_is_the_red_excess_of_the_error_where_only_indirect_light_arrives() -> None:
    reference, di = _shadow_scene()
    redder = reference.copy()
    redder[:, :8] += [0.06, 0.02, 0.0]  # R - (G + B) / 2 = 0.05 in the shadow
    redder[:, 8:] += [0.0, 0.3, 0.3]  # a cyan error where direct light arrives does not count
    assert shadow_tint(redder, reference, di) == pytest.approx(0.05, abs=1e-12)
    assert shadow_tint(reference + 0.1, reference, di) == pytest.approx(0.0, abs=1e-12)  # grey: no tint
    bluer = reference.copy()
    bluer[:, :8, 2] += 0.08
    assert shadow_tint(bluer, reference, di) == pytest.approx(-0.04, abs=1e-12)


def test_shadow_tint_is_zero_without_shadow_and_refuses_grey_images() -> None:
    reference, _ = _shadow_scene()
    assert shadow_tint(reference + [0.1, 0.0, 0.0], reference, np.full_like(reference, 0.6)) == 0.0
    with pytest.raises(ValueError, match="needs RGB images"):
        shadow_tint(reference[..., 0], reference[..., 0], reference[..., 0])
