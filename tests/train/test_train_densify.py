"""Densification and opacity reset keep every Adam moment attached to its own Gaussian."""

from __future__ import annotations

import math

import pytest
import torch

from inceptiongs.gaussians import Gaussians
from inceptiongs.runs.config import Densification, TrainConfig
from inceptiongs.train.densify import DensifyStats, RESET_OPACITY, densify_and_prune, reset_opacity
from inceptiongs.train.optim import make_optimizer, params_from_gaussians

EXTENT = 1.0


def _model(n: int = 6) -> Gaussians:
    g = torch.Generator().manual_seed(0)
    means = torch.randn(n, 3, generator=g)
    means[:, 0] = torch.arange(n, dtype=torch.float32)  # x identifies the Gaussian
    log_scales = torch.full((n, 3), math.log(0.001))
    log_scales[3:] = math.log(0.05)                    # 3.. are "large": split, not clone
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1)
    opacity = torch.full((n,), 2.0)
    opacity[5] = -10.0                                  # nearly transparent: pruned
    sh = torch.randn(n, 4, 3, generator=g)
    return Gaussians(means, log_scales, quats, opacity, sh)


def _stepped_optimizer(params, config):
    optimizer = make_optimizer(params, config, EXTENT)
    loss = sum((t * torch.arange(1, t.numel() + 1, dtype=t.dtype).reshape(t.shape)).sum() for t in params.values())
    loss.backward()
    optimizer.step()
    return optimizer


def test_densify_clones_splits_prunes_and_keeps_adam_moments_with_their_rows():
    config = TrainConfig(densification=Densification(densify_grad_threshold=1e-3, percent_dense=0.01,
                                                     prune_opacity=0.005))
    params = params_from_gaussians(_model())
    optimizer = _stepped_optimizer(params, config)
    before = {name: (t.detach().clone(), optimizer.state[t]["exp_avg"].clone(),
                     optimizer.state[t]["exp_avg_sq"].clone()) for name, t in params.items()}
    # Gaussians 0 (small) and 3 (large) are hot; the others are not.
    stats = DensifyStats(torch.tensor([5e-3, 0, 0, 5e-3, 0, 0]), torch.ones(6), torch.zeros(6))
    counts = densify_and_prune(params, optimizer, stats, config.densification, EXTENT, prune_large=False,
                               generator=torch.Generator().manual_seed(1))
    assert counts == {"cloned": 1, "split": 1, "pruned": 1}
    # Kept: 0, 1, 2, 4 (3 was split, 5 pruned); appended: clone of 0, two children of 3.
    assert params["means"].shape[0] == 7
    for name, tensor in params.items():
        assert optimizer.state[tensor]["exp_avg"].shape == tensor.shape
        assert optimizer.state[tensor]["exp_avg_sq"].shape == tensor.shape
        values, m1, m2 = before[name]
        kept = torch.tensor([0, 1, 2, 4])
        assert torch.equal(tensor.detach()[:4], values[kept])
        assert torch.equal(tensor.detach()[4], values[0])  # the clone copies its source
        assert torch.equal(optimizer.state[tensor]["exp_avg"][:4], m1[kept])
        assert torch.equal(optimizer.state[tensor]["exp_avg_sq"][:4], m2[kept])
        assert torch.all(optimizer.state[tensor]["exp_avg"][4:] == 0)
        assert torch.all(optimizer.state[tensor]["exp_avg_sq"][4:] == 0)
        assert tensor.requires_grad and tensor.is_leaf
    # Split children are smaller by 1.6 and placed around the parent.
    children = params["log_scales"].detach()[5:]
    assert torch.allclose(children, before["log_scales"][0][3].expand(2, 3) - math.log(1.6))
    parent_mean = before["means"][0][3]
    assert torch.all((params["means"].detach()[5:] - parent_mean).norm(dim=-1) < 0.5)
    # The optimizer still steps with the new tensors.
    sum(t.sum() for t in params.values()).backward()
    optimizer.step()


def test_densify_never_removes_every_gaussian():
    config = TrainConfig(densification=Densification(prune_opacity=0.99))
    params = params_from_gaussians(_model())
    optimizer = _stepped_optimizer(params, config)
    densify_and_prune(params, optimizer, DensifyStats.zeros(6), config.densification, EXTENT, prune_large=True,
                      generator=torch.Generator().manual_seed(0))
    assert params["means"].shape[0] == 1


def test_opacity_reset_clamps_and_restarts_moments():
    config = TrainConfig()
    params = params_from_gaussians(_model())
    optimizer = _stepped_optimizer(params, config)
    reset_opacity(params, optimizer)
    assert torch.all(torch.sigmoid(params["opacity_logits"]) <= RESET_OPACITY + 1e-6)
    assert float(torch.sigmoid(params["opacity_logits"].detach()[5])) < RESET_OPACITY  # lower ones stay lower
    state = optimizer.state[params["opacity_logits"]]
    assert torch.all(state["exp_avg"] == 0) and torch.all(state["exp_avg_sq"] == 0)
    assert torch.any(optimizer.state[params["means"]]["exp_avg"] != 0)


def test_the_world_size_rule_lets_far_gaussians_be_as_large_as_their_distance():
    from inceptiongs.train.densify import oversized
    from inceptiongs.train.free_space import nearest_camera_distance

    config = Densification(prune_world_fraction=0.1)
    # Three Gaussians 0.5 wide: in the rig (distance 1), and far beyond it (distance 20 and 4).
    means = torch.tensor([[1.0, 0, 0], [20.0, 0, 0], [0.0, 4.0, 0]])
    params = {"means": means, "log_scales": torch.full((3, 3), math.log(0.5))}
    centers = torch.tensor([[0.0, 0, 0], [0.0, 0.5, 0]])
    assert torch.allclose(nearest_camera_distance(means, centers), torch.tensor([1.0, 20.0, 3.5]))
    # Extent 1: limit 0.1 near the cameras, 0.1 x distance beyond.
    assert oversized(params, None, config, 1.0, centers).tolist() == [True, False, True]
    # Without the cameras the old rule prunes all three.
    assert oversized(params, None, config, 1.0).tolist() == [True, True, True]
    assert nearest_camera_distance(torch.zeros(0, 3), centers).shape == (0,)


def test_the_screen_size_rule_is_off_by_default_and_prunes_wide_footprints_when_set():
    from inceptiongs.errors import InputError
    from inceptiongs.train.densify import oversized

    # Two Gaussians small in the world (0.01 wide, extent 1); footprints of 5 and 30 pixels.
    params = {"means": torch.zeros(2, 3), "log_scales": torch.full((2, 3), math.log(0.01))}
    radii = torch.tensor([5.0, 30.0])
    assert TrainConfig().densification.prune_screen_radius == 0.0
    assert oversized(params, radii, Densification(), 1.0).tolist() == [False, False]
    on = Densification(prune_screen_radius=20.0)
    assert oversized(params, radii, on, 1.0).tolist() == [False, True]
    assert oversized(params, None, on, 1.0).tolist() == [False, False]   # no radii: no screen rule
    for bad in (-1.0, float("nan")):
        with pytest.raises(InputError, match="densification.prune_screen_radius must be (>= 0|a finite number)"):
            TrainConfig(densification=Densification(prune_screen_radius=bad)).validate()
