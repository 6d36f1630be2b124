"""Noise schedules, DDIM and MultiDiffusion: analytic oracles, coverage, determinism."""

from __future__ import annotations

import math

import pytest
import torch

from inceptiongs.prior.controlnet import ConditionalDenoiser
from inceptiongs.prior.ddim import ddim_sample, ddim_timesteps
from inceptiongs.prior.multidiffusion import coverage, multidiffusion_sample, window_starts
from inceptiongs.prior.schedule import make_schedule, q_sample
from inceptiongs.prior.unet import UNetConfig


pytestmark = pytest.mark.usefixtures("one_torch_thread")


TINY = UNetConfig(image_channels=3, base_width=8, channel_mults=(1, 2, 2), time_dim=16)


@pytest.mark.parametrize("kind", ["linear", "cosine"])
def test_schedule_is_decreasing_and_strictly_inside_0_1(kind):
    schedule = make_schedule(kind, 1000)
    ab = schedule.alphas_cumprod
    assert ab.shape == (1000,)
    assert bool((ab > 0).all()) and bool((ab < 1).all())
    assert bool((ab[1:] < ab[:-1]).all())
    assert ab[-1] < 0.01 and ab[0] > 0.99  # from almost clean to almost pure noise


def test_cosine_schedule_matches_closed_form_before_clipping():
    schedule = make_schedule("cosine", 200)
    s = 0.008
    f = lambda t: math.cos((t / 200 + s) / (1 + s) * math.pi / 2) ** 2  # noqa: E731
    for t in (0, 10, 100, 150):
        assert schedule.alphas_cumprod[t].item() == pytest.approx(f(t + 1) / f(0), rel=1e-9)


def test_q_sample_is_variance_preserving():
    schedule = make_schedule("linear", 1000)
    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(4000, 1, 4, 4, generator=g)
    noise = torch.randn(4000, 1, 4, 4, generator=g)
    for t in (0, 300, 999):
        xt = q_sample(schedule, x0, torch.full((4000,), t), noise)
        assert xt.var().item() == pytest.approx(1.0, abs=0.03)
    clean = q_sample(schedule, torch.zeros_like(x0), torch.full((4000,), 500), noise)
    expected_std = math.sqrt(1 - schedule.alphas_cumprod[500].item())
    assert clean.std().item() == pytest.approx(expected_std, rel=0.02)


def test_ddim_timesteps():
    schedule = make_schedule("cosine", 1000)
    assert ddim_timesteps(schedule, 1) == [999]
    steps = ddim_timesteps(schedule, 20)
    assert len(steps) == 20 and steps[0] == 999 and steps[-1] == 0
    assert all(a > b for a, b in zip(steps, steps[1:]))
    assert len(ddim_timesteps(make_schedule("cosine", 10), 50)) == 10


def oracle_denoiser(schedule, target):
    """The exact noise prediction for data concentrated on ``target`` (broadcast over batch)."""
    def eps_fn(x, t, cond=None):
        ab = schedule.alphas_cumprod[t].to(x.dtype).view(-1, 1, 1, 1)
        return (x - ab.sqrt() * target) / (1 - ab).sqrt()
    return eps_fn


@pytest.mark.parametrize("kind", ["linear", "cosine"])
@pytest.mark.parametrize("steps", [1, 7, 100])
def test_ddim_with_the_exact_noise_recovers_the_data(kind, steps):
    schedule = make_schedule(kind, 1000)
    # float64: at the cosine schedule's first step sqrt(alpha_bar) ~ 5e-5, so float32 rounding
    # of the oracle's own noise would already move x0 by ~1e-3.
    target = torch.linspace(-0.9, 0.9, 3 * 8 * 8, dtype=torch.float64).reshape(1, 3, 8, 8)
    out = ddim_sample(oracle_denoiser(schedule, target), schedule, (2, 3, 8, 8), steps=steps, seed=4,
                      dtype=torch.float64)
    torch.testing.assert_close(out, target.expand(2, -1, -1, -1), rtol=0, atol=1e-6)


@pytest.mark.parametrize("steps", [1, 50])
def test_ddim_with_a_network_is_finite_and_seeded(steps):
    torch.manual_seed(0)
    model = ConditionalDenoiser(TINY, cond_channels=4).eval()
    schedule = make_schedule("cosine", 1000)
    cond = torch.rand(1, 4, 16, 16)
    fn = lambda x, t: model(x, t, cond)  # noqa: E731
    a = ddim_sample(fn, schedule, (1, 3, 16, 16), steps=steps, seed=1)
    b = ddim_sample(fn, schedule, (1, 3, 16, 16), steps=steps, seed=1)
    c = ddim_sample(fn, schedule, (1, 3, 16, 16), steps=steps, seed=2)
    assert torch.isfinite(a).all() and a.abs().max() <= 1.0
    assert torch.equal(a, b)
    assert (a - c).abs().max() > 1e-3


@pytest.mark.parametrize("length,window,stride", [(37, 16, 12), (23, 16, 12), (16, 16, 12), (100, 64, 48),
                                                  (17, 16, 16), (5, 4, 1)])
def test_window_starts_cover_everything_and_end_flush(length, window, stride):
    starts = window_starts(length, window, stride)
    covered = torch.zeros(length, dtype=torch.bool)
    for s in starts:
        assert 0 <= s and s + window <= length
        covered[s:s + window] = True
    assert covered.all()
    assert starts[0] == 0 and starts[-1] == length - window
    assert all(b - a <= stride for a, b in zip(starts, starts[1:]))


@pytest.mark.parametrize("height,width", [(23, 37), (7, 10), (16, 5), (1, 1), (33, 16)])
def test_every_pixel_is_covered(height, width):
    assert bool((coverage(height, width, window=16, stride=12) >= 1).all())


@pytest.mark.parametrize("height,width", [(23, 37), (7, 10), (31, 9)])
def test_multidiffusion_updates_every_pixel(height, width):
    # With the exact noise for a constant image, every pixel must end exactly on it; a pixel
    # no window covered would keep its noise (or divide by zero).
    schedule = make_schedule("cosine", 1000)
    target = torch.full((1, 3, 1, 1), 0.3, dtype=torch.float64)
    out = multidiffusion_sample(oracle_denoiser(schedule, target), schedule, height, width, window=16,
                                stride=12, steps=5, seed=0, dtype=torch.float64)
    assert out.shape == (1, 3, height, width)
    torch.testing.assert_close(out, target.expand_as(out), rtol=0, atol=1e-6)


def test_multidiffusion_equals_single_window_ddim_for_one_window():
    torch.manual_seed(0)
    model = ConditionalDenoiser(TINY, cond_channels=4).eval()
    # Make the branch matter, so the condition's windowing is part of what is compared.
    with torch.no_grad():
        for conv in model.control.zero_convs:
            conv.weight.normal_(0, 0.1)
        model.control.embed.out.weight.normal_(0, 0.1)
    schedule = make_schedule("cosine", 1000)
    cond = torch.rand(1, 4, 16, 16, generator=torch.Generator().manual_seed(5))
    single = ddim_sample(lambda x, t: model(x, t, cond), schedule, (1, 3, 16, 16), steps=6, seed=9)
    multi = multidiffusion_sample(model, schedule, 16, 16, cond=cond, window=16, stride=12, steps=6, seed=9)
    torch.testing.assert_close(multi, single, rtol=0, atol=1e-6)


def test_multidiffusion_is_deterministic_for_a_seed():
    torch.manual_seed(0)
    model = ConditionalDenoiser(TINY, cond_channels=4).eval()
    schedule = make_schedule("cosine", 1000)
    cond = torch.rand(1, 4, 23, 37, generator=torch.Generator().manual_seed(5))
    run = lambda seed: multidiffusion_sample(model, schedule, 23, 37, cond=cond, window=16,  # noqa: E731
                                             stride=12, steps=4, seed=seed, batch_windows=4)
    a, b, c = run(3), run(3), run(4)
    assert a.shape == (1, 3, 23, 37) and torch.isfinite(a).all()
    assert torch.equal(a, b)
    assert (a - c).abs().max() > 1e-3
