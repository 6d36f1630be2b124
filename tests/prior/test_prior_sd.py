"""The sd backend (Stable Diffusion + ControlNet through diffusers) end to end on tiny, randomly
initialised diffusers models saved in the layout the loader reads: nothing is downloaded."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

diffusers = pytest.importorskip("diffusers", reason="the sd backend needs the diffusers extra")

from inceptiongs.cli import main  # noqa: E402
from inceptiongs.errors import InputError  # noqa: E402
from inceptiongs.prior.hashgrid import HashGridConfig  # noqa: E402
from inceptiongs.prior.sd_backend import SDPrior, SDPriorConfig  # noqa: E402
from inceptiongs.prior.trainer import PriorTrainer, load_prior, read_prior_checkpoint, save_prior  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")

GRID = HashGridConfig(levels=2, features_per_level=2, table_size=512, base_resolution=4, max_resolution=16)


def write_tiny_sd(root):
    """DIR/unet, DIR/vae (2 blocks: factor 2), DIR/scheduler: a Stable-Diffusion-shaped model with
    a few thousand random weights."""
    torch.manual_seed(0)
    unet = diffusers.UNet2DConditionModel(
        sample_size=8, in_channels=4, out_channels=4, block_out_channels=(16, 32), layers_per_block=1,
        down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"), up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
        cross_attention_dim=16, attention_head_dim=4, norm_num_groups=8)
    vae = diffusers.AutoencoderKL(
        in_channels=3, out_channels=3, down_block_types=("DownEncoderBlock2D",) * 2,
        up_block_types=("UpDecoderBlock2D",) * 2, block_out_channels=(8, 16), latent_channels=4,
        norm_num_groups=8, layers_per_block=1, sample_size=16)
    unet.save_pretrained(root / "unet")
    vae.save_pretrained(root / "vae")
    (root / "scheduler").mkdir()
    (root / "scheduler" / "scheduler_config.json").write_text(json.dumps(
        {"beta_schedule": "scaled_linear", "beta_start": 0.00085, "beta_end": 0.012,
         "num_train_timesteps": 1000, "prediction_type": "epsilon"}))
    return root


@pytest.fixture(scope="module")
def sd_dir(tmp_path_factory):
    return write_tiny_sd(tmp_path_factory.mktemp("sd"))


@pytest.fixture(scope="module")
def scene():
    from inceptiongs.camera import Camera, look_at
    from inceptiongs.gaussians import Gaussians
    from inceptiongs.rasterizer.rasterize import render

    g = torch.Generator().manual_seed(0)
    n = 40
    gaussians = Gaussians((torch.rand(n, 3, generator=g) * 2 - 1) * 0.8, torch.full((n, 3), -2.0),
                          torch.randn(n, 4, generator=g), torch.full((n,), 2.0), torch.rand(n, 1, 3, generator=g))
    cameras = [Camera(f"c{i}", 24, 20, 24.0, 24.0, 12.0, 10.0,
                      look_at(np.array([3 * np.sin(a), 0.3, -3 * np.cos(a)]), np.zeros(3)))
               for i, a in enumerate((0.0, 0.7))]
    with torch.no_grad():
        photos = [render(gaussians, c, background=[0.5, 0.5, 0.5])["rgb"].numpy() for c in cameras]
    return gaussians, cameras, photos


def test_zero_initialised_controlnet_leaves_the_base_unchanged_and_training_moves_only_the_branch(sd_dir, scene):
    gaussians, cameras, photos = scene
    prior = SDPrior.for_gaussians(SDPriorConfig(sd_path=str(sd_dir), patch_size=8, batch_size=2, grid=GRID,
                                                learning_rate=1e-3), gaussians)
    assert prior.vae_factor == 2 and prior.patch_multiple == 4
    x = torch.randn(2, 4, 4, 6, generator=torch.Generator().manual_seed(1))
    t = torch.tensor([10, 700])
    cond = torch.randn(2, prior.controlnet.controlnet_cond_embedding.conv_in.in_channels, 8, 12)
    with torch.no_grad():
        assert torch.equal(prior.eps(x, t, cond), prior.eps(x, t, None))

    base = {k: v.clone() for k, v in prior.unet.state_dict().items()}
    branch = {k: v.clone() for k, v in prior.controlnet.state_dict().items()}
    trainer = PriorTrainer(prior, gaussians, cameras, lambda i: photos[i])
    losses = [trainer.step() for _ in range(2)]
    assert all(np.isfinite(losses))
    assert all(torch.equal(v, prior.unet.state_dict()[k]) for k, v in base.items())  # frozen
    changed = [k for k, v in branch.items() if not torch.equal(v, prior.controlnet.state_dict()[k])]
    assert any("controlnet_down_blocks" in k for k in changed)  # the zero convs learn first
    with torch.no_grad():
        assert not torch.equal(prior.eps(x, t, cond), prior.eps(x, t, None))


def test_checkpoint_holds_only_trained_weights_and_reloads_the_same_generator(sd_dir, scene, tmp_path):
    gaussians, cameras, photos = scene
    prior = SDPrior.for_gaussians(SDPriorConfig(sd_path=str(sd_dir), patch_size=8, batch_size=1, grid=GRID),
                                  gaussians)
    trainer = PriorTrainer(prior, gaussians, cameras, lambda i: photos[i])
    trainer.step()
    save_prior(tmp_path, trainer)
    payload = read_prior_checkpoint(tmp_path)
    assert payload["backend"] == "sd"
    assert not [k for k in payload["model"] if k.startswith(("unet.", "vae."))]
    loaded = load_prior(tmp_path)
    # 23x19: odd sizes, not multiples of the VAE factor nor of the window
    camera = cameras[0].scaled(24 / 23)
    a, cond = prior.generate(gaussians, camera, steps=2, seed=4, window=8, stride=4)
    b, _ = loaded.generate(gaussians, camera, steps=2, seed=4, window=8, stride=4)
    assert a.shape == (camera.height, camera.width, 3) and cond.shape[1:] == (camera.height, camera.width)
    assert torch.isfinite(a).all() and 0.0 <= float(a.min()) and float(a.max()) <= 1.0
    torch.testing.assert_close(a, b, rtol=0, atol=1e-5)  # same seed, same image, after reload
    c, _ = prior.generate(gaussians, camera, steps=2, seed=5, window=8, stride=4)
    assert not torch.equal(a, c)


def test_bad_sd_folders_raise_input_errors(tmp_path, sd_dir):
    with pytest.raises(InputError, match="does not exist"):
        SDPrior(SDPriorConfig(sd_path=str(tmp_path / "nowhere")))
    (tmp_path / "unet").mkdir()
    (tmp_path / "unet" / "config.json").write_text("{not json")
    with pytest.raises(InputError, match="unet"):
        SDPrior(SDPriorConfig(sd_path=str(tmp_path)))


@pytest.mark.slow
def test_prior_and_generate_commands_with_the_sd_backend(sd_dir, tmp_path, capsys):
    from prior_cases import make_stand_in_run

    run = make_stand_in_run(tmp_path)
    assert main(["prior", str(run), "--steps", "2", "--backend", "sd"]) == 2  # no --sd-path
    assert main(["prior", str(run), "--steps", "2", "--backend", "sd", "--sd-path", str(sd_dir),
                 "--patch-size", "16", "--batch-size", "1", "--checkpoint-every", "1"]) == 0
    assert read_prior_checkpoint(run)["backend"] == "sd"
    records = [json.loads(line) for line in (run / "prior" / "metrics.jsonl").read_text().splitlines()]
    assert records[-1]["step"] == 2 and records[-1]["train_s"] > 0
    assert main(["prior", str(run), "--steps", "1", "--backend", "tiny"]) == 2  # checkpoint is sd
    capsys.readouterr()
    assert main(["prior", str(run), "--steps", "1", "--unet-width", "64"]) == 2
    assert "holds a sd prior; --unet-width is for the tiny backend" in capsys.readouterr().err
    out = tmp_path / "g.png"
    from inceptiongs.scene.loader import load_scene
    from inceptiongs.runs.config import TrainConfig
    view = load_scene(TrainConfig.load(run / "config.json").scene, downscale=4).cameras[1]
    assert main(["generate", str(run), "--view", view.name, "--out", str(out), "--steps", "2", "--window", "16"]) == 0
    import cv2
    assert cv2.imread(str(out)).shape == (view.height, view.width, 3)
