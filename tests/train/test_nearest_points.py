"""The grid search for the k nearest points against every pairwise distance, on the clouds a
capture gives: even, clustered with far outliers, flat (a facade), on a line, with duplicates."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.train.init_gaussians import mean_neighbour_distance
from inceptiongs.train.nearest_points import grid_cell_size, mean_nearest_distance


def brute_force(points: np.ndarray, k: int) -> np.ndarray:
    d = np.sqrt(((points[:, None, :] - points[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    return np.sort(d, axis=1)[:, :k].mean(1)


def clouds(rng: np.random.Generator) -> dict[str, np.ndarray]:
    even = rng.uniform(-5, 5, (1500, 3))
    clusters = np.concatenate([rng.normal(c, 0.05, (300, 3)) for c in rng.uniform(-20, 20, (4, 3))])
    outliers = rng.uniform(-1e4, 1e4, (6, 3))                   # COLMAP's stray far points
    facade = np.column_stack([rng.uniform(0, 30, 1200), np.zeros(1200), rng.uniform(0, 12, 1200)])
    line = np.column_stack([np.linspace(0, 1, 400) ** 3, np.zeros(400), np.zeros(400)])
    duplicates = np.repeat(rng.uniform(0, 1, (200, 3)), 3, axis=0)
    return {"even": even, "clustered with outliers": np.concatenate([clusters, outliers]), "facade": facade,
            "line": line, "duplicates": duplicates, "two points": np.array([[0.0, 0, 0], [3.0, 4.0, 0]]),
            "one place": np.zeros((50, 3))}


@pytest.mark.parametrize("k", [1, 3])
def test_the_grid_gives_every_pairwise_distance_s_answer(k):
    for name, cloud in clouds(np.random.default_rng(0)).items():
        if len(cloud) <= k:
            continue
        got = mean_nearest_distance(torch.from_numpy(cloud), k).numpy()
        np.testing.assert_allclose(got, brute_force(cloud, k), rtol=1e-12, atol=1e-12, err_msg=name)


def test_the_grid_is_bounded_and_positive_for_degenerate_clouds():
    for cloud in (np.zeros((10, 3)), np.array([[0.0, 0, 0], [1e-30, 0, 0]]), np.full((5, 3), 1e20)):
        size = grid_cell_size(cloud)
        assert np.isfinite(size) and size > 0


def test_large_clouds_take_the_grid_with_the_dense_path_s_result_in_float32():
    """Initial scales above the grid threshold agree with the dense path to float32 rounding."""
    rng = np.random.default_rng(1)
    points = torch.from_numpy(rng.uniform(-10, 10, (25_000, 3))).float()
    grid = mean_neighbour_distance(points)
    sample = torch.arange(0, 25_000, 997)
    dense = torch.cdist(points[sample].double(), points.double()).topk(4, dim=1, largest=False).values[:, 1:].mean(1)
    torch.testing.assert_close(grid[sample].double(), dense, rtol=1e-5, atol=1e-7)
