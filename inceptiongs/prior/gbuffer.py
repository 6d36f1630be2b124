"""The G-buffer the prior is conditioned on, rendered by the torch rasterizer.

Channels, in order: planar normal (3, camera space, alpha-blended, not renormalised, so its
length fades with coverage), alpha (1), hash features (Z): the hash grid evaluated at the
Gaussian centres and splatted as per-Gaussian feature channels. Gradients reach the hash
grid's tables; the Gaussians are detached by default so the prior does not move geometry.
"""

from __future__ import annotations

import torch

from ..camera import Camera
from ..gaussians import Gaussians
from ..rasterize import render
from .hashgrid import HashGrid

NORMAL_CHANNELS = slice(0, 3)
ALPHA_CHANNEL = 3
FEATURES_START = 4


def gbuffer_channels(hash_grid: HashGrid) -> int:
    """3 (normal) + 1 (alpha) + Z (hash features)."""
    return FEATURES_START + hash_grid.num_features


def gaussian_features(gaussians: Gaussians, hash_grid: HashGrid) -> torch.Tensor:
    """Hash features at the Gaussian centres: [N, Z] in the Gaussians' dtype (grad to the grid only)."""
    means = gaussians.means.detach().to(hash_grid.tables[0].dtype)
    return hash_grid(means).to(gaussians.dtype)


def render_gbuffer(gaussians: Gaussians, camera: Camera, hash_grid: HashGrid,
                   crop: tuple[int, int, int, int] | None = None, detach_gaussians: bool = True,
                   features: torch.Tensor | None = None, backend: str = "auto") -> torch.Tensor:
    """G-buffer [4 + Z, H, W] of ``camera``, or only of the window ``crop`` = (x0, y0, width, height)
    of its image (rendered through Camera.cropped: a shifted principal point, so only the
    patch's pixels are computed).

    features: optional [N, Z] = gaussian_features(gaussians, hash_grid), computed once and
    shared by several patches of one training step (the hash lookup of every centre costs
    more than rendering a small patch)."""
    if crop is not None:
        x0, y0, width, height = crop
        if width < 1 or height < 1:
            raise ValueError(f"empty crop {crop}")
        camera = camera.cropped(x0, y0, width, height)
    if detach_gaussians:
        gaussians = gaussians.detach()
    if features is None:
        features = gaussian_features(gaussians, hash_grid)
    out = render(gaussians, camera, outputs=("normal", "alpha", "features"), features=features,
                 backend=backend)
    image = torch.cat([out["normal"], out["alpha"], out["features"]], dim=-1)  # [H, W, 4 + Z]
    return image.permute(2, 0, 1).contiguous()
