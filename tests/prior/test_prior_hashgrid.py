"""Hash grid: trilinear interpolation against analytic cases, hashing, gradient flow."""

from __future__ import annotations

import torch

from inceptiongs.prior.hashgrid import HashGrid, HashGridConfig, vertex_index
import pytest


pytestmark = pytest.mark.usefixtures("one_torch_thread")



def _dense_grid(resolution: int = 6) -> HashGrid:
    # One level whose (R+1)^3 vertices fit the table: indexed densely, no collisions.
    config = HashGridConfig(bound=2.0, levels=1, features_per_level=3, table_size=4096,
                            base_resolution=resolution, max_resolution=resolution)
    return HashGrid(config, seed=1)


def test_dense_level_reproduces_linear_functions_exactly():
    # Trilinear interpolation reproduces any affine function sampled at the vertices.
    grid = _dense_grid()
    resolution, bound = grid.resolutions[0], grid.config.bound
    side = resolution + 1
    ijk = torch.stack(torch.meshgrid(*[torch.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)
    world = ijk.double() / resolution * 2 * bound - bound
    matrix = torch.tensor([[0.3, -1.2, 0.5], [2.0, 0.1, -0.7], [0.0, 0.4, 1.1]], dtype=torch.float64)
    offset = torch.tensor([0.25, -0.5, 1.0], dtype=torch.float64)
    grid = grid.double()
    with torch.no_grad():
        grid.tables[0][vertex_index(ijk, resolution, grid.config.table_size)] = world @ matrix.T + offset
    points = (torch.rand(500, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 2 - 1) * bound
    expected = points @ matrix.T + offset
    torch.testing.assert_close(grid(points), expected, rtol=0, atol=1e-12)


def test_points_outside_the_box_take_the_boundary_value():
    grid = _dense_grid()
    inside = torch.tensor([[2.0, -2.0, 0.3]])
    outside = torch.tensor([[5.0, -9.0, 0.3]])
    torch.testing.assert_close(grid(outside), grid(inside), rtol=0, atol=0)


def test_hashed_level_returns_the_hashed_slot_at_vertices():
    config = HashGridConfig(bound=1.0, levels=1, features_per_level=2, table_size=64,
                            base_resolution=16, max_resolution=16)
    grid = HashGrid(config, seed=3)
    ijk = torch.tensor([[0, 0, 0], [3, 7, 11], [15, 2, 9], [16, 16, 16]])
    points = ijk.float() / 16 * 2 - 1
    slots = vertex_index(ijk, 16, 64)
    assert int(slots.max()) < 64 and int(slots.min()) >= 0
    torch.testing.assert_close(grid(points), grid.tables[0][slots], rtol=0, atol=1e-6)


def test_feature_count_and_levels_follow_config():
    config = HashGridConfig()
    grid = HashGrid(config)
    assert grid.num_features == 8
    resolutions = grid.resolutions
    assert resolutions[0] == config.base_resolution and resolutions[-1] == config.max_resolution
    assert all(a < b for a, b in zip(resolutions, resolutions[1:]))
    out = grid(torch.zeros(7, 3))
    assert out.shape == (7, 8)


def test_gradients_reach_only_the_touched_vertices():
    grid = _dense_grid(resolution=4)
    points = torch.tensor([[0.1, 0.2, -0.3], [1.7, -1.9, 0.05]])
    weights = torch.randn(2, 3, generator=torch.Generator().manual_seed(2))
    (grid(points) * weights).sum().backward()
    grad = grid.tables[0].grad
    touched = (grad.abs().sum(1) > 0).sum().item()
    assert 0 < touched <= 16  # two points, 8 vertices each
    # Gradient w.r.t. the table equals the interpolation weights times the upstream weights:
    # summing over slots, each point's trilinear weights sum to 1.
    torch.testing.assert_close(grad.sum(0), weights.sum(0), rtol=1e-5, atol=1e-6)


def test_contraction_keeps_the_core_and_squeezes_the_rest_into_twice_its_size():
    from inceptiongs.prior.hashgrid import contract
    radius = 0.8
    g = torch.Generator().manual_seed(3)
    core = (torch.rand(200, 3, generator=g, dtype=torch.float64) * 2 - 1) * radius
    assert torch.equal(contract(core, radius), core)
    directions = torch.randn(300, 3, generator=g, dtype=torch.float64)
    directions /= directions.abs().amax(-1, keepdim=True)      # ||d||_inf = 1
    norms = torch.tensor([radius, radius * (1 + 1e-9), 1.0, 3.0, 50.0, 1e6, 1e30], dtype=torch.float64)
    far = contract(directions[:, None, :] * norms[None, :, None], radius)   # [300, 7, 3]
    out_norm = far.abs().amax(-1)
    want = 2 * radius - radius ** 2 / norms                           # the closed form per norm
    torch.testing.assert_close(out_norm, want.expand_as(out_norm), rtol=1e-12, atol=1e-12)
    assert bool((out_norm <= 2 * radius).all()) and bool((out_norm[:, 1:] > radius).all())
    # The direction is kept, the map is continuous at the core's face and monotone outwards.
    torch.testing.assert_close(far / out_norm[..., None], directions[:, None, :].expand_as(far))
    assert bool((out_norm[:, 1:] > out_norm[:, :-1]).all())
    points = (directions[:20] * 5.0).clone().requires_grad_()
    contract(points, radius).sum().backward()
    assert torch.isfinite(points.grad).all()


def test_a_contracted_grid_spends_its_cells_on_the_core():
    config = HashGridConfig(bound=2.0, contract_radius=1.0, levels=1, features_per_level=1, table_size=2 ** 15,
                            base_resolution=16, max_resolution=16)
    grid = HashGrid(config)
    with torch.no_grad():
        grid.tables[0].copy_(torch.arange(grid.tables[0].shape[0], dtype=torch.float32)[:, None])
    # Inside the core a point moves through cells as without contraction (0.25 = one cell);
    # a background point 1000 units out lands on the box's last cell row, not off the grid.
    line = torch.stack([torch.linspace(-0.99, 0.99, 9), torch.zeros(9), torch.zeros(9)], -1)
    assert len(torch.unique(grid(line))) == 9
    assert torch.isfinite(grid(torch.tensor([[1000.0, -3e4, 2.0]]))).all()
    with pytest.raises(ValueError, match="contract_radius"):
        HashGrid(HashGridConfig(bound=1.5, contract_radius=1.0))
