"""G-buffer: channel layout, splatted hash features, crops, gradients to the hash grid."""

from __future__ import annotations

import numpy as np
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.prior.gbuffer import (ALPHA_CHANNEL, FEATURES_START, NORMAL_CHANNELS, crop_candidates,
                                        gaussian_features, render_gbuffer)
from inceptiongs.prior.hashgrid import HashGrid, HashGridConfig
from inceptiongs.rasterize import render
import pytest


pytestmark = pytest.mark.usefixtures("one_torch_thread")


GRID = HashGridConfig(bound=1.0, levels=2, features_per_level=2, table_size=512, base_resolution=4,
                      max_resolution=16)


def _blob_scene(n=40, seed=0, spread=0.3):
    """Flat-ish Gaussians around the origin, seen by a 32x24 camera from z = -3."""
    g = torch.Generator().manual_seed(seed)
    gaussians = Gaussians(
        means=(torch.rand(n, 3, generator=g) * 2 - 1) * spread,
        log_scales=torch.log(torch.tensor([0.12, 0.08, 0.01])).expand(n, 3) + 0.2 * torch.rand(n, 3, generator=g),
        quats=torch.randn(n, 4, generator=g),
        opacity_logits=torch.full((n,), 1.5),
        sh=torch.rand(n, 1, 3, generator=g),
    )
    camera = Camera("cam", 32, 24, 30.0, 30.0, 16.0, 12.0, look_at(np.array([0.0, 0.0, -3.0]), np.zeros(3)))
    return gaussians, camera


def test_layout_matches_the_rasterizer_outputs():
    gaussians, camera = _blob_scene()
    grid = HashGrid(GRID)
    gbuffer = render_gbuffer(gaussians, camera, grid)
    assert gbuffer.shape == (3 + 1 + 4, 24, 32)
    reference = render(gaussians, camera, outputs=("normal", "alpha"))
    torch.testing.assert_close(gbuffer[NORMAL_CHANNELS].permute(1, 2, 0), reference["normal"], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(gbuffer[ALPHA_CHANNEL], reference["alpha"][..., 0], rtol=1e-5, atol=1e-6)
    assert gbuffer[ALPHA_CHANNEL].max() > 0.5  # the blob is in view


def test_constant_hash_grid_splats_to_alpha_times_the_constant():
    # Trilinear weights sum to one, so a grid holding c everywhere gives every Gaussian c, and
    # the alpha-blended feature image is alpha * c.
    gaussians, camera = _blob_scene()
    grid = HashGrid(GRID)
    constants = torch.tensor([0.5, -1.0])
    with torch.no_grad():
        for table in grid.tables:
            table.copy_(constants.expand_as(table))
    gbuffer = render_gbuffer(gaussians, camera, grid)
    alpha = gbuffer[ALPHA_CHANNEL]
    for k in range(4):
        torch.testing.assert_close(gbuffer[FEATURES_START + k], alpha * constants[k % 2], rtol=1e-5, atol=1e-6)


def test_crop_renders_the_same_pixels_as_the_full_image():
    # The blob projects well inside the crop, so culling and the frustum clamp do not differ.
    gaussians, camera = _blob_scene(spread=0.15)
    grid = HashGrid(GRID)
    full = render_gbuffer(gaussians, camera, grid)
    crop = render_gbuffer(gaussians, camera, grid, crop=(6, 4, 20, 16))
    assert crop.shape == (8, 16, 20)
    torch.testing.assert_close(crop, full[:, 4:20, 6:26], rtol=1e-5, atol=1e-5)


def test_gradients_reach_the_hash_grid_not_the_gaussians():
    gaussians, camera = _blob_scene()
    gaussians = gaussians.map(lambda t: t.clone().requires_grad_(True))
    grid = HashGrid(GRID)
    gbuffer = render_gbuffer(gaussians, camera, grid, crop=(4, 4, 16, 16))
    (gbuffer[FEATURES_START:] * torch.randn_like(gbuffer[FEATURES_START:])).sum().backward()
    assert all(float(table.grad.abs().sum()) > 0 for table in grid.tables)
    assert gaussians.means.grad is None


def test_pre_cull_keeps_every_gaussian_that_touches_the_patch():
    # A wide scene (centres behind, beside and in front of the camera, some large splats):
    # the pre-culled G-buffer of a patch equals rendering every Gaussian into that patch.
    g = torch.Generator().manual_seed(7)
    n = 400
    gaussians = Gaussians(
        means=(torch.rand(n, 3, generator=g) * 2 - 1) * 3.0,
        log_scales=torch.log(torch.rand(n, 3, generator=g) * 0.4 + 0.01),
        quats=torch.randn(n, 4, generator=g),
        opacity_logits=torch.randn(n, generator=g) * 3.0,
        sh=torch.rand(n, 1, 3, generator=g),
    )
    camera = Camera("cam", 64, 48, 50.0, 50.0, 30.0, 26.0, look_at(np.array([0.0, 0.0, -3.5]), np.zeros(3)))
    grid = HashGrid(GRID)
    features = gaussian_features(gaussians, grid)
    for crop in [(0, 0, 16, 16), (40, 30, 24, 18), (20, 10, 12, 20)]:
        patch = camera.cropped(*crop)
        kept = crop_candidates(gaussians, patch)
        assert 0 < kept.numel() < n
        culled = render_gbuffer(gaussians, camera, grid, crop=crop, features=features)
        reference = render(gaussians, patch, outputs=("normal", "alpha", "features"), features=features)
        visible = torch.nonzero(reference["radii"] > 0).squeeze(-1)
        assert set(visible.tolist()) <= set(kept.tolist())
        expected = torch.cat([reference["normal"], reference["alpha"], reference["features"]], -1).permute(2, 0, 1)
        torch.testing.assert_close(culled, expected, rtol=1e-5, atol=1e-6)
