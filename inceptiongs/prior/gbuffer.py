"""The G-buffer the prior is conditioned on, rendered by the torch rasterizer.

Channels, in order: planar normal (3, camera space, alpha-blended, not renormalised, so its
length fades with coverage), alpha (1), hash features (Z), computed one of two ways
(``hash_at``):

- "surface" (default): the hash grid evaluated at each pixel's surface point (the rendered
  depth unprojected), times the pixel's alpha. The rasterizer only renders geometry (normal,
  alpha, depth), which does not depend on the hash grid, so with fixed Gaussians it can be
  rendered once per view and cropped (the prior trainer caches it) and a training step costs
  one hash lookup per patch pixel instead of a feature splat and its backward.
- "centres": the hash grid evaluated at the Gaussian centres and splatted as per-Gaussian
  feature channels (needs the rasterizer's feature pass, forward and backward, every step).

Gradients reach the hash grid's tables; the Gaussians are detached by default so the prior
does not move geometry.
"""

from __future__ import annotations

import math

import torch

from ..camera import Camera
from ..constants import (ALPHA_MIN, DILATION_PX, FAR_PLANE, FRUSTUM_CLAMP_MARGIN, LOG_SCALE_MAX, LOG_SCALE_MIN,
                         NEAR_PLANE)
from ..gaussians import Gaussians
from ..pinhole import unproject
from ..rasterizer.interface import rasterizer_for
from .hashgrid import HashGrid

HASH_AT = ("surface", "centres")

NORMAL_CHANNELS = slice(0, 3)
ALPHA_CHANNEL = 3
FEATURES_START = 4


def gbuffer_channels(hash_grid: HashGrid) -> int:
    """3 (normal) + 1 (alpha) + Z (hash features)."""
    return FEATURES_START + hash_grid.num_features


# Slack of the conservative pre-cull: a pixel of footprint and half the near plane, so float32
# rounding inside the rasterizer can never keep a Gaussian that the pre-cull dropped.
_CULL_SLACK_PX = 1.0
_CULL_NEAR_FACTOR = 0.5


def crop_candidates(gaussians: Gaussians, camera: Camera) -> torch.Tensor:
    """Indices [M] of the Gaussians that can touch ``camera``'s image (a superset of those the
    rasterizer keeps), so a small patch does not pay for projecting the whole scene.

    Bound (the shared projection rules): the footprint half-extent along x is
    sqrt(2 log(opacity / ALPHA_MIN) cov_xx) with cov_xx = |J_x W R S|^2 + DILATION_PX and
    |J_x W R S| <= (fx / z) sqrt(1 + L_x^2) max(scale), L_x the frustum clamp limit on x / z;
    opacity <= 1 bounds the log. Same along y.
    """
    means = gaussians.means.detach().to(torch.float64)
    pose = torch.as_tensor(camera.world_to_camera, dtype=torch.float64, device=means.device)
    t = means @ pose[:3, :3].T + pose[:3, 3]
    z = t[:, 2]
    in_range = (z >= _CULL_NEAR_FACTOR * NEAR_PLANE) & (z <= FAR_PLANE)
    z = torch.where(in_range, z, torch.ones_like(z))  # out-of-range rows are dropped; keep them finite
    fx, fy, cx, cy, width, height = camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height
    limit_x = max(abs(cx / fx), abs((width - cx) / fx)) + (FRUSTUM_CLAMP_MARGIN - 1.0) * 0.5 * width / fx
    limit_y = max(abs(cy / fy), abs((height - cy) / fy)) + (FRUSTUM_CLAMP_MARGIN - 1.0) * 0.5 * height / fy
    max_scale = torch.exp(gaussians.log_scales.detach().to(torch.float64).clamp(LOG_SCALE_MIN, LOG_SCALE_MAX)
                          .amax(dim=-1))
    level = 2.0 * math.log(1.0 / ALPHA_MIN)
    extent_x = torch.sqrt(level * ((fx / z) ** 2 * (1.0 + limit_x ** 2) * max_scale ** 2 + DILATION_PX))
    extent_y = torch.sqrt(level * ((fy / z) ** 2 * (1.0 + limit_y ** 2) * max_scale ** 2 + DILATION_PX))
    u = fx * t[:, 0] / z + cx
    v = fy * t[:, 1] / z + cy
    keep = in_range & torch.isfinite(u) & torch.isfinite(v)
    keep &= (u + extent_x + _CULL_SLACK_PX > 0) & (u - extent_x - _CULL_SLACK_PX < width)
    keep &= (v + extent_y + _CULL_SLACK_PX > 0) & (v - extent_y - _CULL_SLACK_PX < height)
    return torch.nonzero(keep).squeeze(-1)


def gaussian_features(gaussians: Gaussians, hash_grid: HashGrid) -> torch.Tensor:
    """Hash features at the Gaussian centres: [N, Z] in the Gaussians' dtype (grad to the grid only)."""
    means = gaussians.means.detach().to(hash_grid.tables[0].dtype)
    return hash_grid(means).to(gaussians.dtype)


def render_geometry(gaussians: Gaussians, camera: Camera, rasterizer=None) -> tuple[torch.Tensor, torch.Tensor]:
    """The hash-free part of the G-buffer: (normal and alpha [4, H, W], depth [H, W]: expected
    camera z, 0 where nothing covers the pixel). Only the Gaussians that can touch the image
    are rendered (by ``rasterizer``, default the one for the Gaussians' device)."""
    rasterizer = rasterizer_for(gaussians.means.device) if rasterizer is None else rasterizer
    keep = crop_candidates(gaussians, camera)
    out = rasterizer(gaussians.subset(keep), camera, outputs=("normal", "alpha", "depth"))
    geometry = torch.cat([out["normal"], out["alpha"]], dim=-1).permute(2, 0, 1).contiguous()
    return geometry, out["depth"][..., 0]


def world_points(depth: torch.Tensor, camera: Camera) -> torch.Tensor:
    """depth [H, W] (camera z) -> the pixels' surface points in the world frame [H, W, 3]."""
    points = unproject(depth, camera)
    camera_to_world = torch.as_tensor(camera.camera_to_world, dtype=depth.dtype, device=depth.device)
    return points @ camera_to_world[:3, :3].T + camera_to_world[:3, 3]


def surface_features(hash_grid: HashGrid, geometry: torch.Tensor, depth: torch.Tensor,
                     camera: Camera) -> torch.Tensor:
    """Hash features at the surface points, times alpha: [Z, H, W] (0 where depth is 0).

    geometry: [4, H, W] normal + alpha and depth [H, W] from render_geometry for ``camera``.
    Multiplying by alpha makes a constant grid c give alpha x c, as the "centres" splat does,
    and fades the features out at silhouettes, where the surface point is least certain."""
    height, width = depth.shape
    dtype = hash_grid.tables[0].dtype
    points = world_points(depth.detach(), camera).to(dtype).reshape(-1, 3)
    features = hash_grid(points).reshape(height, width, -1).permute(2, 0, 1).to(geometry.dtype)
    alpha = geometry[ALPHA_CHANNEL:ALPHA_CHANNEL + 1].detach()
    return torch.where(depth[None] > 0.0, features * alpha, torch.zeros_like(features))


def render_gbuffer(gaussians: Gaussians, camera: Camera, hash_grid: HashGrid,
                   crop: tuple[int, int, int, int] | None = None, detach_gaussians: bool = True,
                   features: torch.Tensor | None = None, rasterizer=None,
                   hash_at: str = "surface") -> torch.Tensor:
    """G-buffer [4 + Z, H, W] of ``camera``, or only of the window ``crop`` = (x0, y0, width, height)
    of its image (rendered through Camera.cropped: a shifted principal point, so only the
    patch's pixels are computed). hash_at: "surface" | "centres" (module docstring).

    features ("centres" only): optional [N, Z] = gaussian_features(gaussians, hash_grid),
    computed once and shared by several patches of one training step (the hash lookup of
    every centre costs more than rendering a small patch)."""
    if hash_at not in HASH_AT:
        raise ValueError(f"hash_at must be one of {HASH_AT}, got {hash_at!r}")
    if crop is not None:
        x0, y0, width, height = crop
        if width < 1 or height < 1:
            raise ValueError(f"empty crop {crop}")
        camera = camera.cropped(x0, y0, width, height)
    if detach_gaussians:
        gaussians = gaussians.detach()
    if hash_at == "surface":
        if features is not None:
            raise ValueError("features= are per-Gaussian: only for hash_at='centres'")
        geometry, depth = render_geometry(gaussians, camera, rasterizer)
        return torch.cat([geometry, surface_features(hash_grid, geometry, depth, camera)], dim=0)
    if features is None:
        features = gaussian_features(gaussians, hash_grid)
    keep = crop_candidates(gaussians, camera)
    gaussians, features = gaussians.subset(keep), features[keep]
    rasterizer = rasterizer_for(gaussians.means.device) if rasterizer is None else rasterizer
    out = rasterizer(gaussians, camera, outputs=("normal", "alpha", "features"), features=features)
    image = torch.cat([out["normal"], out["alpha"], out["features"]], dim=-1)  # [H, W, 4 + Z]
    return image.permute(2, 0, 1).contiguous()
