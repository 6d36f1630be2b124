"""G-buffer: channel layout, splatted hash features, crops, gradients to the hash grid."""

from __future__ import annotations

import numpy as np
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.prior.gbuffer import ALPHA_CHANNEL, FEATURES_START, NORMAL_CHANNELS, render_gbuffer
from inceptiongs.prior.hashgrid import HashGrid, HashGridConfig
from inceptiongs.rasterize import render
import pytest


@pytest.fixture(autouse=True)
def _one_thread():
    # These models are tiny: per-op threading overhead dominates, and on a busy 2-core
    # machine two spinning OpenMP threads make each step ~15x slower than one.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


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
