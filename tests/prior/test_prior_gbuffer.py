"""G-buffer: channel layout, hash features at surface points or splatted from centres, crops,
gradients to the hash grid, and the prior trainer's cached geometry."""

from __future__ import annotations

import numpy as np
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.prior.gbuffer import (ALPHA_CHANNEL, FEATURES_START, NORMAL_CHANNELS, crop_candidates,
                                        gaussian_features, render_gbuffer, world_points)
from inceptiongs.prior.hashgrid import HashGrid, HashGridConfig, vertex_index
from inceptiongs.rasterizer.rasterize import render
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


MODES = pytest.mark.parametrize("hash_at", ["surface", "centres"])


@MODES
def test_layout_matches_the_rasterizer_outputs(hash_at):
    gaussians, camera = _blob_scene()
    grid = HashGrid(GRID)
    gbuffer = render_gbuffer(gaussians, camera, grid, hash_at=hash_at)
    assert gbuffer.shape == (3 + 1 + 4, 24, 32)
    reference = render(gaussians, camera, outputs=("normal", "alpha"))
    torch.testing.assert_close(gbuffer[NORMAL_CHANNELS].permute(1, 2, 0), reference["normal"], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(gbuffer[ALPHA_CHANNEL], reference["alpha"][..., 0], rtol=1e-5, atol=1e-6)
    assert gbuffer[ALPHA_CHANNEL].max() > 0.5  # the blob is in view


@MODES
def test_constant_hash_grid_gives_alpha_times_the_constant(hash_at):
    # Trilinear weights sum to one, so a grid holding c everywhere gives every Gaussian (or
    # surface point) c, and the feature image is alpha * c (the splat: alpha-blended c; the
    # surface mode multiplies by alpha; pixels without depth have alpha < ALPHA_EPS = 1e-6).
    gaussians, camera = _blob_scene()
    grid = HashGrid(GRID)
    constants = torch.tensor([0.5, -1.0])
    with torch.no_grad():
        for table in grid.tables:
            table.copy_(constants.expand_as(table))
    gbuffer = render_gbuffer(gaussians, camera, grid, hash_at=hash_at)
    alpha = gbuffer[ALPHA_CHANNEL]
    for k in range(4):
        torch.testing.assert_close(gbuffer[FEATURES_START + k], alpha * constants[k % 2], rtol=1e-5, atol=1e-6)


@MODES
def test_crop_renders_the_same_pixels_as_the_full_image(hash_at):
    # The blob projects well inside the crop, so culling and the frustum clamp do not differ.
    gaussians, camera = _blob_scene(spread=0.15)
    grid = HashGrid(GRID)
    with torch.no_grad():  # a non-constant grid, so the crop's surface points must line up
        for table in grid.tables:
            table.copy_(torch.randn(table.shape, generator=torch.Generator().manual_seed(3)))
    full = render_gbuffer(gaussians, camera, grid, hash_at=hash_at)
    crop = render_gbuffer(gaussians, camera, grid, crop=(6, 4, 20, 16), hash_at=hash_at)
    assert crop.shape == (8, 16, 20)
    torch.testing.assert_close(crop, full[:, 4:20, 6:26], rtol=1e-5, atol=1e-5)


@MODES
def test_gradients_reach_the_hash_grid_not_the_gaussians(hash_at):
    gaussians, camera = _blob_scene()
    gaussians = gaussians.map(lambda t: t.clone().requires_grad_(True))
    grid = HashGrid(GRID)
    gbuffer = render_gbuffer(gaussians, camera, grid, crop=(4, 4, 16, 16), hash_at=hash_at)
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
        culled = render_gbuffer(gaussians, camera, grid, crop=crop, features=features, hash_at="centres")
        reference = render(gaussians, patch, outputs=("normal", "alpha", "features"), features=features)
        visible = torch.nonzero(reference["radii"] > 0).squeeze(-1)
        assert set(visible.tolist()) <= set(kept.tolist())
        expected = torch.cat([reference["normal"], reference["alpha"], reference["features"]], -1).permute(2, 0, 1)
        torch.testing.assert_close(culled, expected, rtol=1e-5, atol=1e-6)


def _wall_scene():
    """An opaque wall of flat Gaussians in the plane z = 0.2, seen head-on from z = -3."""
    xs = torch.linspace(-2.2, 2.2, 41)
    grid_x, grid_y = torch.meshgrid(xs, xs, indexing="ij")
    n = grid_x.numel()
    gaussians = Gaussians(
        means=torch.stack([grid_x.reshape(-1), grid_y.reshape(-1), torch.full((n,), 0.2)], -1),
        log_scales=torch.log(torch.tensor([0.1, 0.1, 1e-4])).expand(n, 3).clone(),
        quats=torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).clone(),
        opacity_logits=torch.full((n,), 6.0),
        sh=torch.full((n, 1, 3), 0.5),
    )
    camera = Camera("cam", 32, 24, 30.0, 30.0, 16.0, 12.0, look_at(np.array([0.1, -0.1, -3.0]),
                                                                np.array([0.1, -0.1, 0.2])))
    return gaussians, camera


def test_surface_points_lie_on_the_rendered_wall():
    gaussians, camera = _wall_scene()
    depth = render(gaussians, camera, outputs=("depth",))["depth"][..., 0]
    points = world_points(depth, camera)
    # Every pixel sees the wall, whose expected depth is its plane's: z = 0.2 up to the
    # rasterizer's float32 accumulation.
    assert bool((depth > 0).all())
    torch.testing.assert_close(points[..., 2], torch.full_like(depth, 0.2), rtol=0, atol=1e-4)
    # The centre pixel's ray runs along the optical axis, which hits the wall at (0.1, -0.1).
    centre = points[12, 16]  # pixel (16.5, 12.5): half a pixel off the principal point
    assert abs(float(centre[0]) - 0.1) < 0.6 * 3.2 / 30.0 and abs(float(centre[1]) + 0.1) < 0.6 * 3.2 / 30.0


def test_surface_features_are_the_grid_at_the_surface_points():
    # A dense grid holding an affine function f reproduces it exactly (trilinear), so each
    # pixel's feature must be alpha * f(its surface point) - a wrong unprojection, frame or
    # crop offset would move the points and change f.
    gaussians, camera = _wall_scene()
    config = HashGridConfig(bound=2.5, levels=1, features_per_level=2, table_size=4096, base_resolution=8,
                            max_resolution=8)
    grid = HashGrid(config)
    side = 9
    ijk = torch.stack(torch.meshgrid(*[torch.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)
    vertices = ijk.float() / 8 * 5.0 - 2.5  # the box holds every surface point: no clamping
    matrix = torch.tensor([[0.7, -0.4, 0.2], [0.1, 0.9, -0.5]])
    with torch.no_grad():
        grid.tables[0][vertex_index(ijk, 8, config.table_size)] = vertices @ matrix.T
    for crop in (None, (5, 3, 16, 12)):
        gbuffer = render_gbuffer(gaussians, camera, grid, crop=crop, hash_at="surface")
        view = camera if crop is None else camera.cropped(*crop)
        depth = render(gaussians, view, outputs=("depth",))["depth"][..., 0]
        expected = (world_points(depth, view) @ matrix.T).permute(2, 0, 1) * gbuffer[ALPHA_CHANNEL]
        torch.testing.assert_close(gbuffer[FEATURES_START:], expected, rtol=1e-4, atol=1e-5)
        assert float(expected.detach().abs().mean()) > 0.05  # f is not ~0 over the view


def test_trainer_cached_geometry_is_the_full_view_cropped():
    # A finished run's fixed Gaussians: from the second step on, patches are cropped from
    # cached full-view renders, so they must equal the full view's G-buffer at those windows
    # (a patch rendered on its own differs slightly near its border: the frustum clamp
    # follows the rendered window).
    from inceptiongs.prior.model import Prior, PriorConfig
    from inceptiongs.prior.trainer import PriorTrainer
    from inceptiongs.prior.unet import UNetConfig
    gaussians, camera = _blob_scene(spread=0.15)
    config = PriorConfig(patch_size=8, batch_size=3, unet=UNetConfig(base_width=8, channel_mults=(1, 2), time_dim=16),
                         grid=GRID)
    prior = Prior(config)
    with torch.no_grad():
        for table in prior.hash_grid.tables:
            table.copy_(torch.randn(table.shape, generator=torch.Generator().manual_seed(5)))
    photo = np.full((camera.height, camera.width, 3), 0.5, np.float32)
    trainer = PriorTrainer(prior, gaussians, [camera], lambda i: photo)
    patches = [(0, 0, 0), (0, 13, 9), (0, 24, 16)]
    first = trainer._surface_conds(gaussians, patches)  # first call: renders the patches
    assert not trainer._geometry
    cached = trainer._surface_conds(gaussians, patches)
    assert set(trainer._geometry) == {0}
    full = render_gbuffer(gaussians, camera, prior.hash_grid, hash_at="surface")
    expected = torch.stack([full[:, y:y + 8, x:x + 8] for _, x, y in patches])
    torch.testing.assert_close(cached, expected, rtol=0, atol=1e-6)
    torch.testing.assert_close(first, expected, rtol=0, atol=2e-2)  # the clamp's small border change
    trainer.gaussians = gaussians.map(lambda t: t.clone())  # a new model object: the cache is dropped
    trainer._surface_conds(trainer.gaussians, patches)
    assert not trainer._geometry
