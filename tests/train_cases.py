"""A tiny synthetic capture for stage-I rule tests: a ring of cameras around a ball of Gaussians,
its photos rendered from those Gaussians (so a model that equals them is exact)."""

from __future__ import annotations

import math

import numpy as np
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.io.config_json import flat_values, with_values
from inceptiongs.rasterizer.rasterize import render
from inceptiongs.runs.config import TrainConfig
from inceptiongs.train.free_space import ViewStats, near_bounds
from inceptiongs.train.init_gaussians import scene_extent
from inceptiongs.train.step import TrainData, state_from_gaussians, train_step

WIDTH, HEIGHT, FOCAL = 32, 24, 30.0
RING_RADIUS = 3.0
BALL_RADIUS = 1.0


def ring_cameras(count: int = 8, spread_deg: float = 360.0, height: float = 0.3) -> list[Camera]:
    """``count`` cameras on a circle of RING_RADIUS around the origin, looking at it, over
    ``spread_deg`` degrees of azimuth."""
    cameras = []
    for k in range(count):
        azimuth = math.radians(spread_deg * k / count if spread_deg >= 360 else
                               spread_deg * (k / max(count - 1, 1) - 0.5))
        eye = np.array([RING_RADIUS * math.cos(azimuth), RING_RADIUS * math.sin(azimuth), height])
        cameras.append(Camera(f"cam{k:02d}", WIDTH, HEIGHT, FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2,
                              look_at(eye, np.zeros(3), up=np.array([0.0, 0.0, 1.0]))))
    return cameras


def ball(count: int = 500, seed: int = 0, sh_degree: int = 3) -> Gaussians:
    """Small opaque Gaussians on the sphere of BALL_RADIUS, random colours, higher SH bands 0."""
    g = torch.Generator().manual_seed(seed)
    directions = torch.nn.functional.normalize(torch.randn(count, 3, generator=g), dim=-1)
    means = directions * BALL_RADIUS
    log_scales = torch.full((count, 3), math.log(0.12))
    quats = torch.zeros(count, 4)
    quats[:, 0] = 1.0
    opacity = torch.full((count,), 3.0)  # sigmoid 0.95
    sh = torch.zeros(count, (sh_degree + 1) ** 2, 3)
    sh[:, 0] = torch.rand(count, 3, generator=g) * 2.0 - 1.0
    return Gaussians(means, log_scales, quats, opacity, sh)


def blob(mean, scale: float, opacity: float = 0.9, colour=(1.0, 1.0, 1.0), sh_degree: int = 3) -> Gaussians:
    """One isotropic Gaussian."""
    sh = torch.zeros(1, (sh_degree + 1) ** 2, 3)
    sh[0, 0] = (torch.tensor(colour) - 0.5) / 0.28209479177387814
    return Gaussians(torch.tensor([mean], dtype=torch.float32), torch.full((1, 3), math.log(scale)),
                     torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.tensor([math.log(opacity / (1 - opacity))]), sh)


def concat(*parts: Gaussians) -> Gaussians:
    return Gaussians(*(torch.cat([getattr(p, name) for p in parts]) for name in
                       ("means", "log_scales", "quats", "opacity_logits", "sh")))


def photos(truth: Gaussians, cameras: list[Camera]) -> dict[int, torch.Tensor]:
    with torch.no_grad():
        return {i: render(truth, cam)["rgb"].clamp(0, 1) for i, cam in enumerate(cameras)}


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a - b) ** 2).mean())
    return 10 * math.log10(1.0 / max(mse, 1e-12))  # the floor: an exact match reads 120 dB


def overridden(config: TrainConfig, **overrides) -> TrainConfig:
    """``config`` with ``overrides``: top-level settings by name, a section's as a dict of the
    settings it changes (``free_space={"enabled": False}``; the section's others stay)."""
    return with_values(config, flat_values(overrides))


def config(**overrides) -> TrainConfig:
    """A stage-I config for these tiny captures: plain 3DGS terms, every rule on a short schedule;
    ``overrides`` as :func:`overridden` takes them."""
    base = overridden(TrainConfig(pgsr=False, iterations=40),
                      densification={"densify_from": 5, "densify_every": 5, "densify_until": 30,
                                     "prune_large_from": 5, "opacity_reset_every": 10_000, "max_gaussians": 5_000},
                      sh={"increase_every": 5}, output={"log_every": 10_000})
    return overridden(base, **overrides)


def setup(model: Gaussians, cameras: list[Camera], images: dict[int, torch.Tensor], cfg: TrainConfig,
          points: np.ndarray):
    """(TrainData, TrainState at iteration 0 with view statistics and near bounds) for ``model``."""
    data = TrainData(cameras, list(range(len(cameras))), images, {}, {}, {}, {}, scene_extent(cameras))
    state = state_from_gaussians(model, data, cfg)
    state.iteration = 0
    state.view_stats = ViewStats.zeros(len(model))
    state.near = torch.tensor(near_bounds(cameras, points, cfg.free_space.near_percentile, cfg.free_space.near_margin))
    return data, state


def run_steps(state, data, cfg: TrainConfig, steps: int) -> list[dict]:
    records = []
    for step in range(state.iteration + 1, state.iteration + steps + 1):
        records.append(train_step(step, state, data, cfg, 3, render, lambda message: None))
        state.iteration = step
    return records


def tiny_demo_run(root, **overrides):
    """ROOT/run: a short stage I on the demo scene (written to ROOT/scene) at 48x36 with the
    unstructured protocol (so j* exists); ``overrides`` as :func:`overridden` takes them."""
    from pathlib import Path

    from demo_cases import copy_of_demo_scene
    from inceptiongs.train.trainer import train

    root = Path(root)
    scene = copy_of_demo_scene(root / "scene")
    base = overridden(TrainConfig(scene=str(scene), downscale=4, protocol="unstructured", seed=1, iterations=20),
                      densification={"densify_from": 10, "densify_every": 10, "densify_until": 15,
                                     "opacity_reset_every": 1000},
                      sh={"increase_every": 10}, pgsr_terms={"normal_from": 10, "multiview_from": 1000},
                      output={"log_every": 10, "eval_every": 20, "checkpoint_every": 20})
    train(overridden(base, **overrides), root / "run", progress=False)
    return root / "run"
