"""Photo-consistent depth: the plane sweep over the stage-I depth on an analytic textured plane."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.bootstrap.experimental.photo_depth import pairwise_ncc, photo_consistent_depth, subpixel_offset
from plane_cases import FOCAL, HEIGHT, PLANE_Z, WIDTH, camera_at, plane_grey


def photo_of_plane(camera) -> torch.Tensor:
    """The plane as a colour photo [H, W, 3] (grey in every channel)."""
    grey = plane_grey(camera)
    return torch.as_tensor(np.repeat(grey[..., None], 3, axis=2), dtype=torch.float32)


@pytest.fixture(scope="module")
def sweep():
    sources = [(photo_of_plane(c), c) for c in (camera_at("a", (-0.5, 0.0, 0.0)), camera_at("b", (0.5, 0.05, 0.0)),
                                                   camera_at("c", (0.0, 0.45, 0.0)))]
    virtual = camera_at("v", (0.08, 0.1, 0.0))
    true_depth = np.full((HEIGHT, WIDTH, 1), PLANE_Z)
    prior = torch.as_tensor(true_depth * 1.05, dtype=torch.float32)  # stage I 5 % too far
    result = photo_consistent_depth(prior, virtual, sources)
    # Where the virtual view sees textured plane: x of the plane point < 0.4 - window margin.
    u = np.arange(WIDTH) + 0.5
    plane_x = 0.08 + (u - WIDTH / 2) / FOCAL * PLANE_Z
    textured = np.broadcast_to((plane_x < 0.25)[None, :], (HEIGHT, WIDTH))
    flat = np.broadcast_to((plane_x > 0.75)[None, :], (HEIGHT, WIDTH))
    return result, prior, textured, flat


def test_sweep_recovers_the_plane_where_it_has_texture(sweep):
    result, _, textured, _ = sweep
    depth = result.depth[..., 0].numpy()
    confident = result.confidence[..., 0].numpy() >= 0.3
    # Away from the image border every source sees the textured part.
    inner = textured.copy()
    inner[:6], inner[-6:], inner[:, :6] = False, False, False
    assert confident[inner].mean() > 0.9
    error = np.abs(depth[inner & confident] / PLANE_Z - 1.0)
    assert np.median(error) < 0.005 and np.quantile(error, 0.9) < 0.005


def test_flat_texture_gives_no_confidence_and_keeps_the_prior(sweep):
    result, prior, _, flat = sweep
    assert result.confidence[..., 0].numpy()[flat].max() == 0.0
    np.testing.assert_array_equal(result.depth[..., 0].numpy()[flat], prior[..., 0].numpy()[flat])


def test_without_two_sources_nothing_changes():
    camera = camera_at("v", (0.0, 0.0, 0.0))
    prior = torch.full((HEIGHT, WIDTH, 1), PLANE_Z)
    result = photo_consistent_depth(prior, camera, [(photo_of_plane(camera), camera)])
    assert torch.equal(result.depth, prior) and float(result.confidence.max()) == 0.0


def test_ncc_of_identical_windows_is_one_and_of_a_flat_window_undefined():
    g = torch.Generator().manual_seed(0)
    image = torch.rand(1, 16, 16, generator=g)
    warped = torch.cat([image, 0.5 * image + 0.2, torch.full((1, 16, 16), 0.3)])  # affine copies agree
    valid = torch.ones(3, 16, 16, dtype=torch.bool)
    score, pairs = pairwise_ncc(warped[:2], valid[:2], 2)
    assert torch.allclose(score, torch.ones_like(score), atol=1e-4) and bool((pairs == 1).all())
    score, pairs = pairwise_ncc(warped[1:], valid[1:], 2)  # the flat one has no contrast
    assert bool((pairs == 0).all()) and bool((score == -1).all())


def test_subpixel_offset_finds_a_parabola_vertex_and_ignores_flat_curves():
    x0 = 0.3
    f = lambda x: -(x - x0) ** 2  # noqa: E731
    offset = subpixel_offset(torch.tensor([f(-1.0)]), torch.tensor([f(0.0)]), torch.tensor([f(1.0)]))
    assert float(offset) == pytest.approx(x0)
    assert float(subpixel_offset(torch.tensor([1.0]), torch.tensor([1.0]), torch.tensor([1.0]))) == 0.0
