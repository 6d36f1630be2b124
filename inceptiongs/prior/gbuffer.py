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


def render_gbuffer(gaussians: Gaussians, camera: Camera, hash_grid: HashGrid,
                   crop: tuple[int, int, int, int] | None = None, detach_gaussians: bool = True,
                   backend: str = "auto") -> torch.Tensor:
    """G-buffer [4 + Z, H, W] of ``camera``, or only of the window ``crop`` = (x0, y0, width, height)
    of its image (rendered through Camera.cropped: a shifted principal point, so only the
    patch's pixels are computed)."""
    if crop is not None:
        x0, y0, width, height = crop
        if width < 1 or height < 1:
            raise ValueError(f"empty crop {crop}")
        camera = camera.cropped(x0, y0, width, height)
    if detach_gaussians:
        gaussians = gaussians.detach()
    grid_dtype = hash_grid.tables[0].dtype
    features = hash_grid(gaussians.means.to(grid_dtype)).to(gaussians.dtype)  # [N, Z]
    out = render(gaussians, camera, outputs=("normal", "alpha", "features"), features=features,
                 backend=backend)
    image = torch.cat([out["normal"], out["alpha"], out["features"]], dim=-1)  # [H, W, 4 + Z]
    return image.permute(2, 0, 1).contiguous()
