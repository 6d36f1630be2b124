"""Where a run's tensors live: ``state_on`` / ``data_on`` move every tensor a step reads to the
rasterizer's device (checked with torch's "meta" device, which any machine has: a tensor left
behind stays on the CPU and is caught), and a checkpoint payload is CPU tensors only, so a run
trained on CUDA resumes on the CPU."""

from __future__ import annotations

import math

import numpy as np
import torch

from inceptiongs.gaussians import Gaussians
from inceptiongs.runs.config import TrainConfig
from inceptiongs.train.densify import DensifyStats
from inceptiongs.train.free_space import ViewStats
from inceptiongs.train.optim import make_optimizer, params_from_gaussians
from inceptiongs.train.step import TrainData, TrainState, data_on, on_cpu, state_on


def _state(n: int = 6) -> TrainState:
    g = torch.Generator().manual_seed(0)
    model = Gaussians(torch.randn(n, 3, generator=g), torch.full((n, 3), math.log(0.05)),
                      torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
                      torch.zeros(n), torch.randn(n, 4, 3, generator=g))
    params = params_from_gaussians(model)
    optimizer = make_optimizer(params, TrainConfig(), 1.0)
    sum(p.square().sum() for p in params.values()).backward()
    optimizer.step()   # Adam now holds moments and a step count for every parameter
    stats = DensifyStats(torch.rand(n), torch.ones(n), torch.rand(n))
    return TrainState(params, optimizer, stats, 7, 1.5, 1.0, np.random.default_rng(0), torch.Generator().manual_seed(3),
                      [0, 1], 1, {"x"}, ViewStats.zeros(n), torch.tensor([0.1, 0.2]), torch.tensor([0.0, 0.0, 0.0, 9.0]))


def _tensors(value, path="state"):
    """Every tensor reachable from ``value`` (dataclass fields, dicts, lists), with where it is."""
    if isinstance(value, torch.Tensor):
        yield path, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _tensors(item, f"{path}[{key!r}]")
    elif isinstance(value, (list, tuple)):
        for index, item in enumerate(value):
            yield from _tensors(item, f"{path}[{index}]")
    elif hasattr(value, "__dataclass_fields__"):
        for name in value.__dataclass_fields__:
            yield from _tensors(getattr(value, name), f"{path}.{name}")


def test_state_on_moves_every_tensor_a_step_reads_and_keeps_the_adam_moments():
    state = _state()
    moved = state_on(state, "meta", TrainConfig(), 1.0)
    found = list(_tensors({"params": moved.params, "stats": moved.stats, "view_stats": moved.view_stats,
                           "near": moved.near, "sky": moved.sky}))
    assert len(found) == len(state.params) + 3 + 5 + 2
    assert [path for path, t in found if t.device.type != "meta"] == []
    for name, param in moved.params.items():
        assert param.is_leaf and param.requires_grad
        moments = moved.optimizer.state[param]
        assert {"exp_avg", "exp_avg_sq"} <= set(moments)
        assert moments["exp_avg"].device.type == "meta" and moments["exp_avg"].shape == param.shape
    # The learning rates and groups carry over; the generator stays on the CPU (device-independent draws).
    assert ([g["lr"] for g in moved.optimizer.param_groups] == [g["lr"] for g in state.optimizer.param_groups])
    assert moved.generator is state.generator and moved.generator.device.type == "cpu"
    assert (moved.iteration, moved.order, moved.logged) == (state.iteration, state.order, state.logged)


def test_state_on_its_own_device_is_the_same_state():
    state = _state()
    assert state_on(state, "cpu", TrainConfig(), 1.0) is state


def test_data_on_moves_the_photos_and_per_view_tensors():
    images = {0: torch.rand(4, 5, 3), 3: torch.rand(4, 5, 3)}
    data = TrainData([], [0], images, {0: torch.rand(4, 5, 1)}, {0: torch.rand(4, 5)},
                     {0: torch.eye(3), 3: torch.eye(3)}, {0: []}, 2.0)
    moved = data_on(data, "meta")
    found = list(_tensors({"images": moved.images, "grey": moved.grey, "edges": moved.edge_weights,
                           "intrinsics": moved.intrinsics}))
    assert len(found) == 6 and all(t.device.type == "meta" for _, t in found)
    assert moved.extent == data.extent and moved.train == data.train
    assert all(t.device.type == "cpu" for t in data.images.values())   # the CPU copy is left as it was


def test_a_checkpoint_payload_holds_cpu_tensors_only():
    state = _state()
    payload = state.payload(TrainConfig())
    tensors = list(_tensors(payload, "payload"))
    assert len(tensors) > 20
    assert [path for path, t in tensors if t.device.type != "cpu" or t.requires_grad] == []
    nested = on_cpu({"a": [torch.ones(2, requires_grad=True), (3, "x")], "b": None})
    assert nested["a"][1] == (3, "x") and nested["b"] is None and not nested["a"][0].requires_grad


def test_a_short_schedule_keeps_the_gaussian_budget_on_cuda_only():
    from inceptiongs.runs.config import short_run_schedule

    full = TrainConfig().densification.max_gaussians
    cpu = short_run_schedule(TrainConfig(iterations=7000, device="cpu")).densification
    auto = short_run_schedule(TrainConfig(iterations=7000)).densification
    cuda = short_run_schedule(TrainConfig(iterations=7000, device="cuda")).densification
    assert cpu.max_gaussians == auto.max_gaussians < full     # a CPU step's cost grows with the count
    assert cuda.max_gaussians == full
    assert (cuda.densify_until, cuda.densify_every) == (cpu.densify_until, cpu.densify_every)
