"""The geometry term at a virtual view (bootstrap.multiview) on an analytic textured plane."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.bootstrap.experimental.multiview import GeometrySource, multiview_consistency, patch_ncc
from plane_cases import FOCAL, HEIGHT, PLANE_Z, WIDTH, camera_at, plane_grey


def source_of_plane(camera, depth: float = PLANE_Z) -> GeometrySource:
    """The plane z = PLANE_Z photographed by an axis-aligned camera, with its true depth."""
    return GeometrySource(torch.as_tensor(plane_grey(camera)[..., None], dtype=torch.float32), camera,
                          torch.full((HEIGHT, WIDTH, 1), depth - camera.center[2]))


VIRTUAL = camera_at("v", (0.08, 0.1, 0.0))
SOURCES = [source_of_plane(camera_at("a", (-0.5, 0.0, 0.0))), source_of_plane(camera_at("b", (0.5, 0.05, 0.0)))]
# Pixels of the virtual view that see the textured part of the plane, away from the flat half.
TEXTURED = torch.as_tensor(np.broadcast_to(
    (0.08 + (np.arange(WIDTH) + 0.5 - WIDTH / 2) / FOCAL * PLANE_Z < 0.2)[None, :, None], (HEIGHT, WIDTH, 1)).copy())


def term_at(scale: float, normal=None, sources=SOURCES, weights=TEXTURED):
    """The term with the rendered depth PLANE_Z * scale everywhere -> (term, d term / d scale)."""
    s = torch.tensor(scale, dtype=torch.float64, requires_grad=True)
    depth = (s * PLANE_Z) * torch.ones(HEIGHT, WIDTH, 1, dtype=torch.float64)
    term = multiview_consistency(depth, normal, VIRTUAL, sources, samples=None, weights=weights.double())
    if term.loss is None:
        return term, None
    term.loss.backward()
    return term, float(s.grad)


def test_the_term_is_near_zero_at_the_true_depth_and_larger_at_a_wrong_one():
    right, _ = term_at(1.0)
    assert right.pairs > 300 and float(right.loss.detach()) < 0.01
    for wrong in (0.975, 1.025):  # inside the visibility test's 3 %
        term, _ = term_at(wrong)
        # 2.5 % of depth is ~0.3 px of disparity between the sources here: NCC drops by a few %.
        assert float(term.loss.detach()) > max(0.02, 20.0 * float(right.loss.detach()))


@pytest.mark.parametrize("scale", [0.98, 0.99, 1.01, 1.02])
def test_its_gradient_points_towards_the_true_depth(scale):
    _, gradient = term_at(scale)
    # Descent moves the scale by -gradient: towards 1.
    assert gradient is not None and np.sign(-gradient) == np.sign(1.0 - scale) and abs(gradient) > 1e-3


def test_the_normal_is_supervised_too():
    """A plane tilted against the truth correlates worse than the true (fronto-parallel) normal,
    and the gradient flows into the normal."""
    true_normal = torch.zeros(HEIGHT, WIDTH, 3, dtype=torch.float64)
    true_normal[..., 2] = -1.0
    tilted = true_normal.clone()
    tilted[..., 0] = 1.0                     # 45 degrees
    tilted.requires_grad_(True)
    right, _ = term_at(1.0, true_normal)
    wrong, _ = term_at(1.0, tilted)
    assert float(wrong.loss.detach()) > max(0.005, 20.0 * float(right.loss.detach()))
    assert tilted.grad is not None and float(tilted.grad.abs().sum()) > 0


def test_zero_weight_where_a_source_does_not_see_the_pixel():
    # A source far to the right sees only the right part of the virtual view's plane: where
    # its patches fall outside its image the pair carries no weight (and no gradient).
    far = source_of_plane(camera_at("far", (4.5, 0.0, 0.0)))
    left = torch.zeros(HEIGHT, WIDTH, 1, dtype=torch.bool)
    left[:, :12] = True                      # these pixels project left of far's image
    term, gradient = term_at(1.02, sources=[SOURCES[0], far], weights=left & TEXTURED)
    assert term.loss is None and term.pairs == 0 and gradient is None
    # Hidden: the source's depth says an occluder stands in front of the plane.
    occluded = GeometrySource(SOURCES[1].grey, SOURCES[1].camera, torch.full((HEIGHT, WIDTH, 1), 0.7 * PLANE_Z))
    term, _ = term_at(1.0, sources=[SOURCES[0], occluded])
    assert term.loss is None and term.pairs == 0
    # A single source has nothing to agree with.
    assert term_at(1.0, sources=SOURCES[:1])[0].loss is None


def test_flat_texture_carries_no_term():
    term, _ = term_at(1.02, weights=~TEXTURED & torch.as_tensor(
        np.broadcast_to((0.08 + (np.arange(WIDTH) + 0.5 - WIDTH / 2) / FOCAL * PLANE_Z > 0.8)[None, :, None],
                        (HEIGHT, WIDTH, 1)).copy()))
    assert term.loss is None


def test_patch_ncc_is_affine_invariant_and_undefined_on_flat_patches():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(4, 25, generator=g, dtype=torch.float64)
    ncc, textured = patch_ncc(a, 0.4 * a + 0.3)
    assert bool(textured.all()) and torch.allclose(ncc, torch.ones(4, dtype=torch.float64))
    ncc, textured = patch_ncc(a, torch.full_like(a, 0.5))
    assert not bool(textured.any()) and bool(torch.isfinite(ncc).all())
