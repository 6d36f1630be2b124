"""Shared pieces of the prior tests (and of the stage-II and evaluation tests that need a prior):
a tiny prior configuration, a tiny scene with its photos, and a stand-in stage-I run folder."""

from __future__ import annotations

import numpy as np
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.io.ply import write_ply
from inceptiongs.prior.hashgrid import HashGridConfig
from inceptiongs.prior.model import PriorConfig
from inceptiongs.prior.unet import UNetConfig
from inceptiongs.rasterizer.rasterize import render
from demo_cases import copy_of_demo_scene
from inceptiongs.scene.loader import load_scene
from inceptiongs.runs.config import TrainConfig
from inceptiongs.runs.frames import to_original_frame

TINY = PriorConfig(patch_size=16, batch_size=4, learning_rate=2e-3, num_timesteps=200,
                   unet=UNetConfig(base_width=8, channel_mults=(1, 2), time_dim=16),
                   grid=HashGridConfig(levels=2, features_per_level=2, table_size=512,
                                       base_resolution=4, max_resolution=16))


def prior_scene(n=60, seed=0):
    """Gaussians around the origin, three 32x32 cameras and the photos they render."""
    g = torch.Generator().manual_seed(seed)
    gaussians = Gaussians(
        means=(torch.rand(n, 3, generator=g) * 2 - 1) * 0.8,
        log_scales=torch.full((n, 3), -2.2) + 0.5 * torch.rand(n, 3, generator=g),
        quats=torch.randn(n, 4, generator=g),
        opacity_logits=torch.full((n,), 2.0),
        sh=torch.rand(n, 1, 3, generator=g) * 2 - 0.5,
    )
    cameras = [Camera(f"c{i}", 32, 32, 32.0, 32.0, 16.0, 16.0,
                      look_at(np.array([3 * np.sin(a), 0.3, -3 * np.cos(a)]), np.zeros(3)))
               for i, a in enumerate((0.0, 0.6, 1.2))]
    with torch.no_grad():
        photos = [render(gaussians, c, background=[0.5, 0.5, 0.5])["rgb"].numpy() for c in cameras]
    return gaussians, cameras, photos


def make_stand_in_run(root, protocol: str | None = None):
    """A run folder as stage I leaves it (config.json + model.ply, and split.json when a
    protocol is given), with Gaussians standing in for a trained model: the demo scene's points
    as small isotropic splats."""
    scene_dir = copy_of_demo_scene(root / "scene")
    config = TrainConfig(scene=str(scene_dir), downscale=4, protocol=protocol or "none")
    run = root / "run"
    run.mkdir()
    config.save(run / "config.json")
    scene = load_scene(scene_dir, downscale=4)
    if protocol is not None:
        from inceptiongs.evaluation.protocols import make_split
        make_split(scene, protocol, 0).save(run / "split.json")
    points = torch.as_tensor(scene.points[::4], dtype=torch.float32)
    n = points.shape[0]
    colors = torch.as_tensor(scene.point_colors[::4], dtype=torch.float32) / 255.0
    gaussians = Gaussians(points, torch.full((n, 3), -3.5), torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4).clone(),
                          torch.full((n,), 2.0), ((colors - 0.5) / 0.28209479177387814)[:, None, :])
    write_ply(to_original_frame(gaussians, scene.normalization), run / "model.ply")
    return run
