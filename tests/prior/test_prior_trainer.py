"""Prior training: the diffusion loss goes down, the hash grid learns, checkpoints round-trip."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from inceptiongs.errors import InputError
from inceptiongs.gaussians import Gaussians
from inceptiongs.prior.ddim import start_timestep
from inceptiongs.prior.model import Prior, PriorConfig, fit_bound
from inceptiongs.prior.trainer import (PriorTrainer, load_prior, prior_dir, resume_trainer, save_prior)

from prior_cases import TINY, prior_scene


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_fit_bound_ignores_a_far_floater():
    means = torch.rand(1000, 3) * 2 - 1
    means[0] = torch.tensor([500.0, 0.0, 0.0])
    assert 0.9 < fit_bound(means) < 1.1


def test_diffusion_training_lowers_the_loss_on_a_synthetic_dataset():
    # Patches whose colour is a function of the condition: a few hundred steps of the
    # conditional denoiser alone (no rendering) must lower the seeded diffusion loss.
    torch.manual_seed(0)
    prior = Prior(TINY)
    g = torch.Generator().manual_seed(1)
    optimizer = torch.optim.Adam(prior.parameters(), lr=2e-3)
    losses = []
    for _ in range(300):
        cond = torch.zeros(8, 8, 8, 8)
        split = torch.randint(2, 7, (8,), generator=g)
        columns = torch.arange(8)[None, :] < split[:, None]  # [B, 8]: left part is "surface"
        cond[:, 3] = columns[:, None, :].float()            # alpha channel
        images = torch.where(columns[:, None, None, :], 0.6, -0.6).expand(8, 3, 8, 8).clone()
        images[:, 1] *= -1.0
        loss = prior.diffusion_loss(images, cond, generator=g)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    first, last = np.mean(losses[:50]), np.mean(losses[-50:])
    assert last < 0.6 * first, (first, last)


@pytest.mark.slow
def test_trainer_on_rendered_patches_lowers_the_loss_and_trains_the_hash_grid():
    gaussians, cameras, photos = prior_scene()
    prior = Prior.for_gaussians(replace(TINY, patch_size=8), gaussians)
    tables_before = [t.detach().clone() for t in prior.hash_grid.tables]
    trainer = PriorTrainer(prior, gaussians, cameras, lambda i: photos[i])
    losses = trainer.train(steps=30, progress=False)
    assert len(losses) == 30 and trainer.step_count == 30
    assert np.mean(losses[-10:]) < np.mean(losses[:10]), losses
    changed = [not torch.equal(a, b) for a, b in zip(tables_before, prior.hash_grid.tables)]
    assert all(changed)


def test_checkpoint_resumes_exactly_and_generates_the_same_image(tmp_path):
    gaussians, cameras, photos = prior_scene()
    trainer = PriorTrainer(Prior.for_gaussians(replace(TINY, patch_size=8), gaussians), gaussians, cameras,
                           lambda i: photos[i])
    trainer.train(steps=3, run_dir=tmp_path, checkpoint_every=2, progress=False)
    assert (prior_dir(tmp_path) / "prior.pt").is_file()
    assert not [p for p in prior_dir(tmp_path).iterdir() if p.name not in ("prior.pt", "metrics.jsonl")]  # no temp files

    resumed = resume_trainer(tmp_path, gaussians, cameras, lambda i: photos[i])
    assert resumed.step_count == 3 and resumed.losses == trainer.losses
    assert resumed.step() == pytest.approx(trainer.step(), rel=1e-5, abs=1e-7)

    save_prior(tmp_path, trainer)
    loaded = load_prior(tmp_path)
    camera = cameras[0].scaled(32 / 20)  # 20x20: not a multiple of the window
    image_a, cond_a = trainer.prior.generate(gaussians, camera, steps=3, seed=5)
    image_b, cond_b = loaded.generate(gaussians, camera, steps=3, seed=5)
    assert image_a.shape == (20, 20, 3) and cond_a.shape == (8, 20, 20)
    assert float(image_a.min()) >= 0.0 and float(image_a.max()) <= 1.0
    torch.testing.assert_close(image_a, image_b, rtol=0, atol=1e-5)


def test_bad_inputs_raise_input_errors(tmp_path):
    gaussians, cameras, photos = prior_scene(n=5)
    with pytest.raises(InputError, match="prior.pt"):
        load_prior(tmp_path)
    (tmp_path / "prior").mkdir()
    (tmp_path / "prior" / "prior.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a readable prior checkpoint"):
        load_prior(tmp_path)
    trainer = PriorTrainer(Prior(TINY), gaussians, cameras, lambda i: photos[i][:10])
    with pytest.raises(InputError, match="c"):
        trainer.step()
    tiny_cameras = [c.scaled(32) for c in cameras]  # 1x1 images
    with pytest.raises(InputError, match="too small"):
        PriorTrainer(Prior(TINY), gaussians, tiny_cameras, lambda i: photos[i])


def test_patch_size_shrinks_to_small_images():
    gaussians, cameras, photos = prior_scene(n=5)
    small = [c.scaled(32 / 13) for c in cameras]  # 13x13 -> patches of 12 (multiple of 2)
    trainer = PriorTrainer(Prior(TINY), gaussians, small, lambda i: np.zeros((13, 13, 3), np.float32))
    assert trainer.patch_size == 12
    photos_batch, conds = trainer.sample_batch()
    assert photos_batch.shape == (4, 3, 12, 12) and conds.shape == (4, 8, 12, 12)


def test_v_prediction_with_the_exact_v_gives_the_exact_noise_and_zero_loss():
    # A stand-in UNet that returns the true v of the batch: eps() must turn it into the exact
    # noise (so DDIM's x0 is the image) and the v-loss must be 0; a wrong sign or swapped
    # sqrt(alpha_bar) / sqrt(1 - alpha_bar) in either formula breaks both.
    prior = Prior(replace(TINY, prediction="v"))
    g = torch.Generator().manual_seed(4)
    images = torch.rand(3, 3, 16, 16, generator=g) * 2 - 1
    t = torch.tensor([0, 97, 199])
    noise = torch.randn(images.shape, generator=g)
    alpha_bar = prior.schedule.alphas_cumprod[t].float().view(-1, 1, 1, 1)
    v = alpha_bar.sqrt() * noise - (1 - alpha_bar).sqrt() * images
    noisy = alpha_bar.sqrt() * images + (1 - alpha_bar).sqrt() * noise

    class ExactV(torch.nn.Module):
        def forward(self, x, steps, cond):
            return v

    prior.denoiser = ExactV()
    torch.testing.assert_close(prior.eps(noisy, t, None), noise, rtol=0, atol=1e-5)
    # diffusion_loss draws its own t and noise: replay them to build the matching exact v.
    generator = torch.Generator().manual_seed(9)
    t = torch.randint(0, start_timestep(prior.schedule, prior.config.sample_start) + 1, (3,), generator=generator)
    noise = torch.randn(images.shape, generator=generator)
    alpha_bar = prior.schedule.alphas_cumprod[t].float().view(-1, 1, 1, 1)
    v = alpha_bar.sqrt() * noise - (1 - alpha_bar).sqrt() * images
    loss = prior.diffusion_loss(images, None, generator=torch.Generator().manual_seed(9))
    assert float(loss) < 1e-10
    with torch.no_grad():  # and a real (untrained) UNet is far from v
        assert float(Prior(TINY).diffusion_loss(images, None, generator=torch.Generator().manual_seed(9))) > 0.1


def test_old_checkpoint_configs_read_as_epsilon_and_centre_splats():
    data = TINY.to_dict()
    del data["prediction"], data["hash_at"]
    config = PriorConfig.from_dict(data)
    assert (config.prediction, config.hash_at) == ("epsilon", "centres")
    with pytest.raises(ValueError, match="prediction"):
        Prior(replace(TINY, prediction="x0"))


def test_prior_configs_load_strictly():
    from inceptiongs.prior.sd_backend import SDPriorConfig

    data = TINY.to_dict()
    assert PriorConfig.from_dict(data) == TINY
    with pytest.raises(InputError, match="ckpt: unknown prior config keys learning_rat$"):
        PriorConfig.from_dict({**data, "learning_rat": 1.0}, "ckpt")
    with pytest.raises(InputError, match="unknown prior hash grid config keys levls"):
        PriorConfig.from_dict({**data, "grid": {**data["grid"], "levls": 3}})
    sd = SDPriorConfig().to_dict()
    assert SDPriorConfig.from_dict(sd) == SDPriorConfig()
    with pytest.raises(InputError, match="unknown sd prior config keys extra"):
        SDPriorConfig.from_dict({**sd, "extra": 1})


def test_high_noise_share_draws_that_part_of_each_batch_from_high_timesteps():
    gaussians, cameras, photos = prior_scene()
    # Sampling from pure noise (sample_start 1): the share is taken from the top of all of [0, T).
    prior = Prior.for_gaussians(replace(TINY, prediction="v", high_noise_share=0.5, high_noise_t=0.8,
                                        sample_start=1.0), gaussians)
    seen = []
    prior.denoiser.register_forward_pre_hook(lambda module, args: seen.append(args[1].clone()))
    trainer = PriorTrainer(prior, gaussians, cameras, photos.__getitem__)
    for _ in range(8):
        trainer.step()
    draws = torch.stack(seen)  # [steps, B = 4]
    assert int(draws[:, :2].min()) >= 160 and int(draws.max()) < 200  # [0.8 T, T), T = 200
    assert int(draws[:, 2:].min()) < 160  # the rest of the batch: the whole range (16 draws)
    with pytest.raises(ValueError, match="high_noise"):
        Prior(replace(TINY, high_noise_t=1.0))


def test_the_default_grid_is_contracted_around_the_object_not_the_background():
    g = torch.Generator().manual_seed(0)
    obj = (torch.rand(600, 3, generator=g) * 2 - 1) * 0.5          # the object: |x| <= 0.5
    background = torch.randn(400, 3, generator=g) * 40.0           # a far background shell
    prior = Prior.for_gaussians(replace(TINY, grid=PriorConfig().grid), _gaussians_at(torch.cat([obj, background])))
    grid = prior.config.grid
    assert 0.5 <= grid.contract_radius <= 1.0 and grid.bound == pytest.approx(2 * grid.contract_radius)
    # Without contraction the box would hold the background, and the object one coarse cell.
    assert fit_bound(torch.cat([obj, background])) > 40


def _gaussians_at(means: torch.Tensor) -> Gaussians:
    n = means.shape[0]
    return Gaussians(means=means, log_scales=torch.full((n, 3), -3.0), quats=torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4),
                     opacity_logits=torch.zeros(n), sh=torch.zeros(n, 1, 3))


def test_sampling_from_part_of_T_trains_only_on_that_part():
    gaussians, cameras, photos = prior_scene()
    prior = Prior.for_gaussians(replace(TINY, sample_start=0.3), gaussians)
    seen = []
    prior.denoiser.register_forward_pre_hook(lambda module, args: seen.append(args[1].clone()))
    trainer = PriorTrainer(prior, gaussians, cameras, photos.__getitem__)
    for _ in range(12):
        trainer.step()
    draws = torch.stack(seen)
    assert int(draws.max()) <= round(0.3 * 199) and int(draws.max()) > 40  # [0, 60], 48 draws


def test_the_trainer_moves_a_model_to_the_priors_device_once_not_every_step():
    gaussians, cameras, photos = prior_scene(n=5)
    trainer = PriorTrainer(Prior.for_gaussians(replace(TINY, patch_size=8), gaussians), gaussians, cameras,
                           lambda i: photos[i])
    first = trainer._gaussians_on_device()
    assert trainer._gaussians_on_device() is first          # the same copy on the next step
    torch.testing.assert_close(first.means, gaussians.means)
    trainer.gaussians = gaussians.map(lambda t: t + 0.0)    # new geometry (joint training): a new copy
    assert trainer._gaussians_on_device() is not first


def test_the_bootstraps_prior_is_made_and_loaded_on_the_runs_device(tmp_path):
    # "meta" stands in for a GPU: a prior left on the host would say "cpu" here.
    from inceptiongs.bootstrap.generation import obtain_prior

    gaussians, cameras, photos = prior_scene(n=5)
    untrained, _ = obtain_prior(tmp_path, tmp_path, gaussians, cameras, lambda i: photos[i], "untrained", 0,
                                None, 1, print, device="meta")
    assert untrained.device.type == "meta"
    trainer = PriorTrainer(Prior.for_gaussians(replace(TINY, patch_size=8), gaussians), gaussians, cameras,
                           lambda i: photos[i])
    trainer.train(steps=1, run_dir=tmp_path / "run", progress=False)
    loaded, text = obtain_prior(tmp_path / "run", tmp_path / "out", gaussians, cameras, lambda i: photos[i],
                                "trained", 0, None, 1, print, device="meta")
    assert "stage-I run's trained prior" in text and loaded.device.type == "meta"
    on_host, _ = obtain_prior(tmp_path / "run", tmp_path / "out", gaussians, cameras, lambda i: photos[i],
                              "trained", 0, None, 1, print)
    assert on_host.device.type == "cpu"


def test_the_trainer_keeps_photos_within_the_budget_and_trains_the_same():
    # 40 training views, a budget of 2 photos: between steps at most 2 converted photos are
    # alive (every photo drawn so far would be with every photo kept), and the losses are those of a trainer
    # that keeps every photo (a photo read again converts to the same values).
    from inceptiongs.camera import Camera, look_at
    from photo_counting import AliveCount, tensors_of_shape

    gaussians, _, _ = prior_scene()
    cameras = [Camera(f"c{i}", 24, 20, 24.0, 24.0, 12.0, 10.0,
                      look_at(np.array([3 * np.sin(a), 0.3, -3 * np.cos(a)]), np.zeros(3)))
               for i, a in enumerate(np.linspace(0.0, 6.0, 40))]
    photos = np.random.default_rng(0).random((len(cameras), 20, 24, 3), dtype=np.float32)
    config = replace(TINY, patch_size=8, batch_size=4)

    def losses(budget, count):
        torch.manual_seed(0)
        trainer = PriorTrainer(Prior.for_gaussians(config, gaussians), gaussians, cameras,
                               count.counting(lambda i: photos[i]), photo_budget=budget)
        held = []
        for step in range(6):
            trainer.step()
            if step % 2:
                held.append(tensors_of_shape((3, 20, 24)))
        return trainer.losses, max(held)

    small, everything = AliveCount(), AliveCount()
    bounded, held = losses(2 * 3 * 4 * 24 * 20, small)
    kept_all, held_all = losses(10 ** 9, everything)
    assert held <= 2, held
    assert held_all > 10                       # the count sees photos kept between steps
    assert small.peak <= config.batch_size + 2   # photos read in one batch, beside the 2 kept
    assert small.reads > everything.reads
    assert bounded == kept_all
