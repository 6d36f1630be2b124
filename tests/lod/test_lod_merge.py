"""Moment matching: known answers for merged pairs and clusters, and the built tree's invariants."""

from __future__ import annotations

import numpy as np
import pytest
from lod_cases import random_gaussians

from inceptiongs.gaussians import Gaussians
from inceptiongs.lod.hierarchy import build_hierarchy, morton_codes
from inceptiongs.lod.moments import (
    LOD_OPACITY_MAX,
    covariance_to_gaussian,
    covariances_of,
    full_matrices,
    merge_groups,
    surface_weights,
)


def merge_all(g: Gaussians) -> dict[str, np.ndarray]:
    """Merge every Gaussian of ``g`` into one parent."""
    a = g.numpy()
    means = a["means"].astype(np.float64)
    covs = covariances_of(a["log_scales"], a["quats"])
    weights = surface_weights(a["log_scales"], a["opacity_logits"])
    return merge_groups(means, covs, weights, a["sh"], np.zeros(len(g)), np.array([0]))


def test_pair_at_plus_minus_d_gives_sigma_plus_d_squared_along_x():
    d = 0.7
    quat = np.array([0.9, 0.2, -0.3, 0.1])
    log_scales = np.log([0.05, 0.2, 0.1])
    pair = Gaussians.from_numpy({"means": [[d, 0, 0], [-d, 0, 0]], "log_scales": [log_scales] * 2,
                                 "quats": [quat] * 2, "opacity_logits": [0.3, 0.3], "sh": np.zeros((2, 1, 3))})
    parent = merge_all(pair)
    sigma = full_matrices(covariances_of(pair.numpy()["log_scales"][:1], pair.numpy()["quats"][:1]))[0]
    expected = sigma + d * d * np.outer([1, 0, 0], [1, 0, 0])
    np.testing.assert_allclose(parent["means"][0], 0.0, atol=1e-7)
    np.testing.assert_allclose(full_matrices(parent["covs"])[0], expected, rtol=1e-6, atol=1e-9)
    # The parent's own scales and rotation give back the same covariance.
    rebuilt = full_matrices(covariances_of(parent["log_scales"], parent["quats"]))[0]
    np.testing.assert_allclose(rebuilt, expected, rtol=1e-6, atol=1e-9)


def test_cluster_mean_covariance_and_colour_are_the_weighted_moments():
    g = random_gaussians(9, seed=1)
    parent = merge_all(g)
    a = g.numpy()
    w = surface_weights(a["log_scales"], a["opacity_logits"])
    w = w / w.sum()
    mu = a["means"].astype(np.float64)
    sigmas = full_matrices(covariances_of(a["log_scales"], a["quats"]))
    mean = (w[:, None] * mu).sum(0)
    # Second moment minus the outer product of the mean: another route to the same covariance.
    second = sum(wi * (s + np.outer(m, m)) for wi, s, m in zip(w, sigmas, mu))
    np.testing.assert_allclose(parent["means"][0], mean, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(full_matrices(parent["covs"])[0], second - np.outer(mean, mean), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(parent["sh"][0], (w[:, None, None] * a["sh"]).sum(0), rtol=1e-4, atol=1e-5)


def test_parent_keeps_the_childrens_total_weight_when_not_clamped():
    g = random_gaussians(6, seed=2, logit=-6.0)   # faint children: no clamp
    parent = merge_all(g)
    total = surface_weights(g.numpy()["log_scales"], g.numpy()["opacity_logits"]).sum()
    own = surface_weights(parent["log_scales"], parent["opacity_logits"])[0]
    assert parent["opacity_logits"][0] < np.log(LOD_OPACITY_MAX / (1 - LOD_OPACITY_MAX)) - 1.0
    np.testing.assert_allclose(own, total, rtol=1e-6)
    np.testing.assert_allclose(parent["weights"][0], total, rtol=1e-9)


def test_opaque_overlapping_children_clamp_the_parent_below_one():
    g = random_gaussians(8, seed=3, logit=8.0)
    g.means.mul_(1e-3)                              # all at one place: the sum asks for o >> 1
    parent = merge_all(g)
    opacity = 1.0 / (1.0 + np.exp(-parent["opacity_logits"][0]))
    assert np.isfinite(parent["opacity_logits"][0])
    np.testing.assert_allclose(opacity, LOD_OPACITY_MAX, rtol=1e-9)


def test_covariance_round_trip_through_scales_and_quaternions():
    a = random_gaussians(500, seed=4).numpy()
    covs = covariances_of(a["log_scales"], a["quats"])
    log_scales, quats = covariance_to_gaussian(covs)
    np.testing.assert_allclose(covariances_of(log_scales, quats), covs, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-12)


def test_degenerate_input_stays_finite():
    g = Gaussians.from_numpy({"means": np.zeros((5, 3)), "log_scales": np.full((5, 3), -80.0),
                              "quats": np.zeros((5, 4)), "opacity_logits": np.full(5, -80.0),
                              "sh": np.zeros((5, 1, 3))})
    h = build_hierarchy(g, branching=2)
    for name, array in h.arrays().items():
        assert np.all(np.isfinite(array)), name


@pytest.mark.parametrize("n, branching", [(1, 4), (2, 2), (37, 4), (300, 8)])
def test_tree_links_levels_and_leaves(n, branching):
    g = random_gaussians(n, seed=5)
    h = build_hierarchy(g, branching=branching)
    assert h.leaf_count == n and len(h.roots) == 1 and h.roots[0] == len(h) - 1
    # The leaves are the model's Gaussians, bit for bit, in Morton order.
    order = np.argsort(morton_codes(g.numpy()["means"]), kind="stable")
    for name, array in g.numpy().items():
        np.testing.assert_array_equal(getattr(h, name)[:n], array[order])
    for node in range(len(h) - 1):
        p = h.parent[node]
        assert h.child_start[p] <= node < h.child_start[p] + h.child_count[p]
    assert np.all(h.child_count[:n] == 0) and np.all(h.child_count[n:] >= 1)


def test_root_is_the_moment_match_of_all_leaves_and_spheres_nest():
    g = random_gaussians(200, seed=6, logit=-9.0)   # faint: weights pass up the tree unclamped
    h = build_hierarchy(g, branching=3)
    whole = merge_all(g)
    root = h.roots[0]
    np.testing.assert_allclose(h.means[root], whole["means"][0], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(covariances_of(h.log_scales[root:root + 1], h.quats[root:root + 1]),
                               whole["covs"], rtol=1e-3, atol=1e-6)
    # Every leaf's footprint sphere lies inside every ancestor's sphere.
    leaf = np.arange(h.leaf_count)
    node = leaf.copy()
    while True:
        node = h.parent[node]
        if node[0] < 0:
            break
        reach = np.linalg.norm(h.means[leaf] - h.means[node], axis=1) + h.radii[leaf]
        assert np.all(reach <= h.radii[node] * (1 + 1e-5) + 1e-6)


def test_progress_rises_to_one():
    seen = []
    build_hierarchy(random_gaussians(100, seed=7), branching=2, progress=seen.append)
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) == 7   # ceil(log2(100)) levels


def test_any_sh_degree_passes_through_the_tree():
    g = random_gaussians(50, seed=8, degree=3)
    h = build_hierarchy(g)
    assert h.sh.shape == (len(h), 16, 3)
    subset = h.gaussians(h.roots)
    assert subset.sh_degree == 3 and len(subset) == 1


def test_a_non_finite_gaussian_does_not_poison_its_ancestors():
    g = random_gaussians(100, seed=9)
    g.means[3, 0], g.means[4, 1] = float("nan"), float("inf")
    g.log_scales[5, 2], g.quats[6, 0], g.sh[7, 0, 1] = float("nan"), float("nan"), float("inf")
    with np.errstate(invalid="raise", divide="raise", over="raise"):   # no NaN made on the way
        h = build_hierarchy(g)
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh", "radii"):
        assert np.all(np.isfinite(getattr(h, name)[h.leaf_count:])), name   # every parent is finite
    assert np.isnan(h.means[:h.leaf_count]).any()              # the leaves stay as they were
