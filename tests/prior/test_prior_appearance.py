"""The appearance hint (a per-pixel G-buffer -> RGB head) and sampling that starts from it (SDEdit)."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from inceptiongs.prior.ddim import ddim_timesteps, initial_noise, initial_state
from inceptiongs.prior.model import Prior, PriorConfig
from inceptiongs.prior.multidiffusion import multidiffusion_sample
from inceptiongs.prior.schedule import make_schedule
from inceptiongs.prior.trainer import PriorTrainer, load_prior, save_prior
from test_prior_sampling import oracle_denoiser
from prior_cases import TINY, prior_scene

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_timesteps_start_at_the_given_fraction_of_T():
    schedule = make_schedule("cosine", 1000)
    assert ddim_timesteps(schedule, 20, start=1.0) == ddim_timesteps(schedule, 20)
    steps = ddim_timesteps(schedule, 6, start=0.4)
    assert steps[0] == round(0.4 * 999) and steps[-1] == 0 and len(steps) == 6
    assert ddim_timesteps(schedule, 1, start=0.25) == [round(0.25 * 999)]
    for bad in (0.0, -0.1, 1.01):
        with pytest.raises(ValueError, match="start"):
            ddim_timesteps(schedule, 4, start=bad)


def test_initial_state_is_the_forward_marginal_of_the_init():
    schedule = make_schedule("cosine", 1000)
    init = torch.linspace(-1, 1, 2 * 3 * 5 * 4).reshape(2, 3, 5, 4)
    ab = schedule.alphas_cumprod[round(0.3 * 999)].item()
    want = ab ** 0.5 * init + (1 - ab) ** 0.5 * initial_noise(init.shape, 7)
    torch.testing.assert_close(initial_state(schedule, init.shape, 7, 0.3, init), want, rtol=0, atol=1e-6)
    assert torch.equal(initial_state(schedule, init.shape, 7), initial_noise(init.shape, 7))
    with pytest.raises(ValueError, match="does not match"):
        initial_state(schedule, (1, 3, 5, 4), 7, 0.3, init)


@pytest.mark.parametrize("height,width", [(23, 37), (9, 7)])
def test_sampling_from_an_init_with_the_exact_noise_ends_on_the_data(height, width):
    # The init is wrong on purpose: an exact denoiser must still land on its data, from any
    # start, on every pixel (the canvas padding of the small image included).
    schedule = make_schedule("cosine", 1000)
    target = torch.full((1, 3, 1, 1), -0.35, dtype=torch.float64)
    init = torch.rand(1, 3, height, width, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    out = multidiffusion_sample(oracle_denoiser(schedule, target), schedule, height, width, window=16, stride=12,
                                steps=4, seed=2, dtype=torch.float64, init=init, start=0.5)
    torch.testing.assert_close(out, target.expand_as(out), rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="init must be"):
        multidiffusion_sample(oracle_denoiser(schedule, target), schedule, height, width, window=16, stride=12,
                              steps=4, init=init[..., :-1], start=0.5)


def _prior_and_batch(config: PriorConfig = TINY):
    """A new prior on the synthetic scene and one training batch (photos, G-buffers)."""
    gaussians, cameras, photos = prior_scene()
    prior = Prior.for_gaussians(config, gaussians)
    return prior, PriorTrainer(prior, gaussians, cameras, photos.__getitem__).sample_batch()


@pytest.mark.parametrize("weight,expect_gradient", [(1.0, True), (0.0, False)])
def test_the_hint_gives_the_hash_grid_a_gradient_from_the_first_step(weight, expect_gradient):
    # Without the hint the only path from the loss to the hash grid runs through the branch's
    # zero-initialised joins, so at step 0 the grid gets exactly no gradient: the dead start
    # the hint exists to break.
    start = 1.0 if weight == 0 else TINY.sample_start  # no hint: sampling from pure noise
    prior, (photos, conds) = _prior_and_batch(replace(TINY, appearance_weight=weight, sample_start=start))
    prior.diffusion_loss(photos, conds, generator=torch.Generator().manual_seed(3)).backward()
    touched = [bool(table.grad.abs().sum() > 0) for table in prior.hash_grid.tables if table.grad is not None]
    assert any(touched) == expect_gradient


def test_the_hint_learns_the_colours_of_the_scene():
    gaussians, cameras, photos = prior_scene()
    prior = Prior.for_gaussians(replace(TINY, hash_learning_rate=3e-2), gaussians)
    trainer = PriorTrainer(prior, gaussians, cameras, photos.__getitem__)
    fixed = [trainer.sample_batch() for _ in range(3)]

    def hint_error() -> float:
        with torch.no_grad():
            return sum(float((prior.hint(c) - p).abs().mean()) for p, c in fixed) / len(fixed)

    before = hint_error()
    trainer.train(steps=150, progress=False)
    after = hint_error()
    assert after < 0.5 * before, (before, after)


def test_the_hint_does_not_change_the_denoiser_at_step_zero():
    prior, (photos, conds) = _prior_and_batch()
    x = torch.randn(photos.shape, generator=torch.Generator().manual_seed(4))
    t = torch.tensor([10, 300, 600, 199])
    with torch.no_grad():
        torch.testing.assert_close(prior.eps(x, t, conds), prior.denoiser.unet(x, t), rtol=0, atol=0)
    assert prior.denoiser.cond_channels == conds.shape[1] + 3


def test_generation_from_a_low_start_keeps_the_hint_and_is_seeded(tmp_path):
    gaussians, cameras, photos = prior_scene()
    prior = Prior.for_gaussians(replace(TINY, sample_init="hint"), gaussians)
    trainer = PriorTrainer(prior, gaussians, cameras, photos.__getitem__)
    trainer.train(steps=20, progress=False)
    camera = cameras[1]
    with torch.no_grad():
        hint = ((prior.hint(prior.gbuffer(gaussians, camera)[None])[0].permute(1, 2, 0) + 1) / 2).clamp(0, 1)
    low, _ = prior.generate(gaussians, camera, steps=3, seed=5, start=0.02)
    again, _ = prior.generate(gaussians, camera, steps=3, seed=5, start=0.02)
    other_seed, _ = prior.generate(gaussians, camera, steps=3, seed=6, start=0.02)
    noise, _ = prior.generate(gaussians, camera, steps=3, seed=5, start=1.0)
    assert torch.equal(low, again) and not torch.equal(low, other_seed)
    near, far = float((low - hint).abs().mean()), float((noise - hint).abs().mean())
    assert near < 0.05 and far > 3 * near, (near, far)
    # The start is part of the config, so a saved prior samples the same way after loading.
    trainer.prior = prior = replace_start(prior, 0.02)
    save_prior(tmp_path, trainer)
    loaded = load_prior(tmp_path)
    assert loaded.config.sample_start == 0.02
    assert torch.equal(loaded.generate(gaussians, camera, steps=3, seed=5)[0], low)


def test_generation_from_the_render_repairs_the_render_not_the_hint():
    # init "render": SDEdit of what the Gaussians show (the bootstrap's repair step). From a low
    # start the sample stays on the render; the hint, which the render is not, stays far.
    from inceptiongs.rasterizer.rasterize import render

    gaussians, cameras, photos = prior_scene()
    prior = Prior.for_gaussians(TINY, gaussians)
    PriorTrainer(prior, gaussians, cameras, photos.__getitem__).train(steps=20, progress=False)
    camera = cameras[1]
    with torch.no_grad():
        rendered = render(gaussians, camera, outputs=("rgb",))["rgb"].float().clamp(0, 1)
        hint = ((prior.hint(prior.gbuffer(gaussians, camera)[None])[0].permute(1, 2, 0) + 1) / 2).clamp(0, 1)
    from_render, _ = prior.generate(gaussians, camera, steps=3, seed=5, start=0.02, init="render")
    from_hint, _ = prior.generate(gaussians, camera, steps=3, seed=5, start=0.02, init="hint")
    assert torch.equal(from_render, prior.generate(gaussians, camera, steps=3, seed=5, start=0.02, init="render")[0])
    to_render, hint_to_render = float((from_render - rendered).abs().mean()), float((hint - rendered).abs().mean())
    assert to_render < 0.05 and hint_to_render > 3 * to_render, (to_render, hint_to_render)
    assert float((from_hint - rendered).abs().mean()) > 3 * to_render
    with pytest.raises(ValueError, match="init must be one of"):
        prior.generate(gaussians, camera, steps=2, start=0.5, init="photo")
    # A prior without a hint can still repair renders (only the hint start needs the head).
    Prior(replace(TINY, appearance_weight=0.0, sample_start=0.5, sample_init="render"))
    with pytest.raises(ValueError, match="sample_init"):
        Prior(replace(TINY, sample_init="photo"))


def replace_start(prior: Prior, start: float) -> Prior:
    other = Prior(replace(prior.config, sample_start=start))
    other.load_state_dict(prior.state_dict())
    return other


def test_priors_from_before_the_option_have_no_hint():
    old = PriorConfig().to_dict()
    del old["appearance_weight"], old["sample_start"], old["sample_init"]
    config = PriorConfig.from_dict(old)
    assert config.appearance_weight == 0.0 and config.sample_start == 1.0 and config.sample_init == "hint"
    assert PriorConfig().sample_init == "render"
    gaussians, cameras, _ = prior_scene()
    prior = Prior.for_gaussians(replace(TINY, appearance_weight=0.0, sample_start=1.0), gaussians)
    assert prior.appearance is None and prior.denoiser.cond_channels == 4 + prior.hash_grid.num_features
    with pytest.raises(ValueError, match="no appearance hint"):
        prior.generate(gaussians, cameras[0], steps=2, start=0.5, init="hint")
    with pytest.raises(ValueError, match="needs appearance_weight"):
        Prior(replace(TINY, appearance_weight=0.0, sample_start=0.5, sample_init="hint"))
    with pytest.raises(ValueError, match="sample_start"):
        Prior(replace(TINY, sample_start=0.0))
