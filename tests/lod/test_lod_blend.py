"""Parent/child blending of a cut (inceptiongs/lod/blend.py): weights, known answers at t = 0 and
t = 1, stiff inputs, and that a cut changing with the granularity changes the picture less."""

from __future__ import annotations

import numpy as np
import pytest

from inceptiongs.gaussians import Gaussians
from inceptiongs.lod.blend import (BLEND_RATIO, blend_weights, blended_arrays, effective_granularity,
                                   sibling_counts)
from inceptiongs.lod.cut import cut_nodes, greedy_budget_cut_nodes, node_sizes
from inceptiongs.lod.hierarchy import build_hierarchy
from inceptiongs.lod.moments import opacities_of
from inceptiongs.rasterizer.interface import cpu_rasterizer, render_rgb

from lod_cases import orbit_camera, psnr, random_gaussians


@pytest.fixture(scope="module")
def scene():
    gaussians = random_gaussians(3000, seed=21, degree=0)
    gaussians.log_scales.sub_(1.0)
    return gaussians, build_hierarchy(gaussians), orbit_camera(gaussians.means.numpy())


def test_weights_follow_the_parents_size_between_g_and_the_blend_ratio(scene):
    _, tree, camera = scene
    nodes = cut_nodes(tree, camera, 8.0)
    weights = blend_weights(tree, camera, nodes, 8.0)
    parent_sizes, _ = node_sizes(tree, camera, tree.parent[nodes].astype(np.int64))
    expected = np.clip((parent_sizes / 8.0 - 1.0) / (BLEND_RATIO - 1.0), 0.0, 1.0)
    np.testing.assert_allclose(weights, expected, rtol=1e-6)
    assert 0 < (weights < 1).sum() < len(nodes) and weights.min() >= 0.0
    # Parents drawn at g were expanded, so none is below g: no weight is clipped at 0 from below.
    assert parent_sizes.min() >= 8.0
    assert np.all(blend_weights(tree, camera, cut_nodes(tree, camera, 0.0), 0.0) == 1.0)   # the exact model
    assert np.all(blend_weights(tree, camera, tree.roots, np.inf) == 1.0)


def test_full_weight_draws_each_node_as_it_is(scene):
    _, tree, camera = scene
    nodes = cut_nodes(tree, camera, 8.0)
    arrays = blended_arrays(tree, nodes, np.ones(len(nodes), np.float32))
    for name, values in tree.node_arrays(nodes).items():
        assert np.array_equal(arrays[name], values), name


def test_zero_weight_children_are_shares_of_their_parent(scene):
    _, tree, _ = scene
    parent = int(tree.parent[0])
    children = np.arange(tree.child_start[parent], tree.child_start[parent] + tree.child_count[parent])
    assert len(children) == tree.branching
    arrays = blended_arrays(tree, children, np.zeros(len(children), np.float32))
    parent_arrays = tree.node_arrays(np.array([parent]))
    for name in ("means", "log_scales", "sh"):
        np.testing.assert_allclose(arrays[name], np.repeat(parent_arrays[name], len(children), axis=0),
                                   rtol=1e-6, atol=1e-6, err_msg=name)
    unit = parent_arrays["quats"][0] / np.linalg.norm(parent_arrays["quats"][0])
    np.testing.assert_allclose(np.abs(arrays["quats"] @ unit), 1.0, atol=1e-6)
    # k overlapping copies cover what the parent covered at its centre.
    shares = opacities_of(arrays["opacity_logits"])
    covered = 1.0 - np.prod(1.0 - shares)
    np.testing.assert_allclose(covered, opacities_of(parent_arrays["opacity_logits"])[0], rtol=1e-5)
    np.testing.assert_array_equal(sibling_counts(tree, children), len(children))


def test_stiff_inputs_stay_finite():
    """Opaque and transparent extremes (logits +-50), zero and huge quaternions, opposite signs."""
    gaussians = random_gaussians(400, seed=3, degree=0)
    gaussians.opacity_logits[::2] = 50.0
    gaussians.opacity_logits[1::2] = -50.0
    gaussians.quats[:100] = 0.0
    gaussians.quats[100:200] *= 1e12
    tree = build_hierarchy(gaussians)
    nodes = np.arange(tree.leaf_count)   # every leaf, each blended half way to its parent
    arrays = blended_arrays(tree, nodes, np.full(len(nodes), 0.5, np.float32))
    for name, values in arrays.items():
        assert np.all(np.isfinite(values)), name
    assert np.abs(arrays["opacity_logits"]).max() <= 30.0 + 1e-4
    np.testing.assert_allclose(np.linalg.norm(arrays["quats"], axis=1), 1.0, rtol=1e-5)
    # A child's quaternion negated is the same rotation: the blend is the same up to its sign
    # (without aligning the signs, q and -q would cancel half way).
    tree.quats[: tree.leaf_count] *= -1.0
    flipped = blended_arrays(tree, nodes, np.full(len(nodes), 0.5, np.float32))
    np.testing.assert_allclose(np.abs((flipped["quats"] * arrays["quats"]).sum(axis=1)), 1.0, atol=1e-6)


def test_effective_granularity_of_a_budget_cut(scene):
    _, tree, camera = scene
    nodes = cut_nodes(tree, camera, 8.0)
    assert effective_granularity(tree, camera, nodes) >= 8.0   # a cut at g expanded nodes >= g only
    for budget in (100, 300, 1000):
        greedy = greedy_budget_cut_nodes(tree, camera, budget)
        g = effective_granularity(tree, camera, greedy)
        weights = blend_weights(tree, camera, greedy, g)
        np.testing.assert_array_equal(blend_weights(tree, camera, greedy), weights)   # g left to the cut
        # Few of the drawn nodes are left as mere shares of their parents (t = 0), some blend.
        assert (weights == 0.0).mean() <= 0.2 and (weights < 1.0).mean() > 0.2, (budget, g)
    assert effective_granularity(tree, camera, tree.roots) == 0.0


def test_a_node_crossing_the_granularity_does_not_pop_when_blended(scene):
    """Just above the largest drawn node's size it is drawn; just below, its children are.
    Drawn as they are, the picture jumps there; blended, the children start as the node's shares."""
    _, tree, camera = scene
    rasterizer = cpu_rasterizer()
    drawn = cut_nodes(tree, camera, 8.0)
    sizes, culled = node_sizes(tree, camera, drawn[tree.child_count[drawn] > 0])
    crossing = float(sizes[~culled].max())

    def render(g, blend):
        nodes = cut_nodes(tree, camera, g)
        weights = blend_weights(tree, camera, nodes, g) if blend else np.ones(len(nodes), np.float32)
        image = render_rgb(Gaussians.from_numpy(blended_arrays(tree, nodes, weights)), camera, rasterizer)
        return len(nodes), image.numpy()

    above, below = crossing * 1.0001, crossing * 0.9999
    (count_above, plain_above), (count_below, plain_below) = render(above, False), render(below, False)
    (_, blended_above), (_, blended_below) = render(above, True), render(below, True)
    assert count_below > count_above   # the cut did change
    plain_jump = float(np.abs(plain_below - plain_above).max())
    blended_jump = float(np.abs(blended_below - blended_above).max())
    assert plain_jump > 0.02   # a visible pop: the test can tell
    assert blended_jump < 0.1 * plain_jump, (blended_jump, plain_jump)   # measured: 0.005 against 0.139


def test_the_blended_fine_cut_still_matches_the_full_render(scene):
    gaussians, tree, camera = scene
    rasterizer = cpu_rasterizer()
    nodes = cut_nodes(tree, camera, 1.0)
    blended = blended_arrays(tree, nodes, blend_weights(tree, camera, nodes, 1.0))
    score = psnr(render_rgb(Gaussians.from_numpy(blended), camera, rasterizer), render_rgb(gaussians, camera, rasterizer))
    assert score >= 40.0, score
