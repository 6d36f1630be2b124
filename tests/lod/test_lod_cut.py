"""Cuts: the extremes (root, every leaf), culling, the budget, and agreement of the two routes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.lod.cut import (budget_cut_nodes, children_of, cut_intervals, cut_nodes, lod_gaussians, node_sizes,
                                 walk_cut_nodes)
from inceptiongs.lod.hierarchy import build_hierarchy

from lod_cases import random_gaussians


def camera_at(eye, target=(0.0, 0.0, 0.0), size=(96, 72), focal=80.0) -> Camera:
    w, h = size
    return Camera("test", w, h, focal, focal, w / 2, h / 2, look_at(np.asarray(eye, float), np.asarray(target, float)))


@pytest.fixture(scope="module")
def tree():
    return build_hierarchy(random_gaussians(700, seed=11), branching=4)


def assert_is_cut(h, nodes):
    """No drawn node is an ancestor of another drawn node."""
    drawn = np.zeros(len(h), bool)
    drawn[nodes] = True
    node = np.asarray(nodes)
    while node.size:
        node = h.parent[node]
        node = node[node >= 0]
        assert not drawn[node].any(), "a node and its ancestor are both in the cut"


def test_infinite_granularity_draws_the_root_and_zero_every_leaf(tree):
    far = camera_at((0.0, 0.0, -60.0), focal=200.0)   # the whole model inside the view
    np.testing.assert_array_equal(cut_nodes(tree, far, np.inf), tree.roots)
    np.testing.assert_array_equal(cut_nodes(tree, far, 0.0), np.arange(tree.leaf_count))
    coarse_to_fine = [len(cut_nodes(tree, far, g)) for g in (1e3, 100.0, 30.0, 10.0, 3.0, 1.0)]
    assert coarse_to_fine == sorted(coarse_to_fine) and coarse_to_fine[0] < coarse_to_fine[-1]


def test_cut_is_a_cut_and_matches_the_interval_route(tree):
    camera = camera_at((1.0, -2.0, -7.0))
    lower, upper, kept = cut_intervals(tree, camera)
    for g in (0.0, 0.5, 2.0, 8.0, 40.0, np.inf):
        nodes = cut_nodes(tree, camera, g)
        assert_is_cut(tree, nodes)
        np.testing.assert_array_equal(nodes, np.flatnonzero(kept & (lower < g) & (g <= upper)))


@pytest.mark.parametrize("eye, target", [((1.0, -2.0, -7.0), (0.0, 0.0, 0.0)),     # the model in view
                                         ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),      # inside the root's sphere
                                         ((0.3, 0.1, -1.5), (2.0, 0.0, 0.0)),     # partly beside the view
                                         ((0.0, 0.0, -30.0), (0.0, 0.0, -60.0))])  # the model behind
def test_the_numba_pass_equals_the_numpy_walk(tree, eye, target):
    camera = camera_at(eye, target)
    for g in (0.0, 0.25, 1.0, 3.0, 9.5, 40.0, 1e6, np.inf):
        np.testing.assert_array_equal(cut_nodes(tree, camera, g), walk_cut_nodes(tree, camera, g))
    # Far from the origin (float32 means of 1e4), a camera beside the model.
    shifted = random_gaussians(300, seed=5)
    shifted.means.add_(torch.tensor([1e4, -2e4, 3e4]))
    far = build_hierarchy(shifted)
    camera = camera_at(np.array([1e4, -2e4, 3e4]) + [0.5, -1.0, -6.0], target=np.array([1e4, -2e4, 3e4]))
    for g in (0.0, 2.0, 20.0):
        np.testing.assert_array_equal(cut_nodes(far, camera, g), walk_cut_nodes(far, camera, g))
    with pytest.raises(ValueError, match="granularity"):
        cut_nodes(tree, camera, float("nan"))


def test_nodes_behind_or_beside_the_camera_are_dropped(tree):
    away = camera_at((0.0, 0.0, -30.0), target=(0.0, 0.0, -60.0))   # the model is behind it
    assert cut_nodes(tree, away, 0.0).size == 0
    aside = camera_at((0.0, 0.0, -30.0), target=(60.0, 0.0, -30.0), focal=500.0)
    assert cut_nodes(tree, aside, 0.0).size == 0


def test_a_node_holding_the_camera_is_expanded(tree):
    inside = camera_at((0.0, 0.0, 0.0), target=(0.0, 0.0, 1.0))
    sizes, culled = node_sizes(tree, inside, tree.roots)
    assert np.isinf(sizes[0]) and not culled[0]
    nodes = cut_nodes(tree, inside, np.inf)
    assert tree.roots[0] not in nodes and nodes.size > 0


def brute_force_finest(h, camera, budget):
    """The finest cut within ``budget`` by trying every granularity where a cut can change."""
    sizes, _ = node_sizes(h, camera, np.arange(len(h)))
    for g in np.unique(np.concatenate([[0.0], sizes[np.isfinite(sizes)], [np.inf]])):
        nodes = cut_nodes(h, camera, g)
        if len(nodes) <= budget:
            return nodes
    return None


@pytest.mark.parametrize("budget", [1, 7, 50, 333, 699, 700, 5000])
def test_budget_cut_is_the_finest_within_the_budget(tree, budget):
    camera = camera_at((0.5, -1.0, -9.0))
    nodes, granularity = budget_cut_nodes(tree, camera, budget)
    assert len(nodes) <= budget
    np.testing.assert_array_equal(nodes, cut_nodes(tree, camera, granularity))
    np.testing.assert_array_equal(nodes, brute_force_finest(tree, camera, budget))


def test_budget_is_a_hard_limit_even_when_the_coarsest_cut_is_over_it(tree):
    inside = camera_at((0.0, 0.0, 0.0), target=(0.0, 0.0, 1.0))
    for budget in (0, 1, 2):
        nodes, _ = budget_cut_nodes(tree, inside, budget)
        assert len(nodes) <= budget


def test_lod_gaussians_is_the_subset_of_the_cut(tree):
    camera = camera_at((0.0, 0.0, -9.0))
    nodes = cut_nodes(tree, camera, 4.0)
    subset = lod_gaussians(tree, camera, granularity_px=4.0)
    assert len(subset) == len(nodes)
    np.testing.assert_array_equal(subset.means.numpy(), tree.means[nodes])
    with pytest.raises(ValueError):
        lod_gaussians(tree, camera)


def test_empty_model_gives_empty_cuts():
    h = build_hierarchy(random_gaussians(0))
    camera = camera_at((0.0, 0.0, -5.0))
    assert len(h) == 0 and cut_nodes(h, camera, 0.0).size == 0
    assert budget_cut_nodes(h, camera, 10)[0].size == 0


@pytest.mark.parametrize("budget", [0, 1, 3, 40, 300, 699, 5000])
def test_greedy_budget_cut_fills_the_budget_without_passing_it(tree, budget):
    from inceptiongs.lod.cut import greedy_budget_cut_nodes

    camera = camera_at((0.0, 0.0, -60.0), focal=200.0)   # every leaf visible: no culling
    nodes = greedy_budget_cut_nodes(tree, camera, budget)
    assert len(nodes) <= budget
    assert_is_cut(tree, nodes)
    # It covers the model: every leaf has exactly one drawn ancestor-or-self (when any is drawn).
    covered = np.zeros(tree.leaf_count, int)
    for node in nodes:
        below = np.array([node])
        while tree.child_count[below].any():
            below = children_of(tree, below)   # one level at a time: all of ``below`` share it
        covered[below] += 1
    assert np.all(covered == (1 if budget >= 1 else 0))
    # It stops only when the next expansion would not fit (at most branching - 1 more nodes).
    assert len(nodes) >= min(tree.leaf_count, budget - (tree.branching - 2))


def test_greedy_budget_cut_is_close_to_the_exact_one(tree):
    from inceptiongs.lod.cut import greedy_budget_cut_nodes

    camera = camera_at((0.5, -1.0, -9.0))
    for budget in (50, 200, 500):
        greedy = greedy_budget_cut_nodes(tree, camera, budget)
        exact, _ = budget_cut_nodes(tree, camera, budget)
        # Both stay within the budget; greedy stops only when the next expansion (at most
        # branching - 1 more nodes) does not fit, so it is never much coarser than the exact cut.
        assert len(exact) - (tree.branching - 2) <= len(greedy) <= budget


def test_node_arrays_are_the_gaussians_arrays(tree):
    nodes = np.array([0, 5, len(tree) - 1])
    arrays = tree.node_arrays(nodes)
    for name, tensor in tree.gaussians(nodes).tensors().items():
        np.testing.assert_array_equal(arrays[name], tensor.numpy())
        np.testing.assert_array_equal(arrays[name], getattr(tree, name)[nodes])
