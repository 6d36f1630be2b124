"""render(): the differentiable torch reference rasterizer.

Projection (:mod:`inceptiongs.rasterizer.projection`) runs over all N Gaussians; culled ones are
dropped by index before colours are evaluated and before compositing
(:mod:`inceptiongs.rasterizer.composite`), whose value channels are built from the requested outputs
only. Everything is autograd, so gradients reach means, log-scales, quaternions, opacity
logits, SH, features and (through ``world_to_camera``) the camera pose.
"""

from __future__ import annotations

import torch

from ..camera import Camera
from .composite import composite
from ..constants import ALPHA_EPS
from ..gaussians import Gaussians
from .projection import plane_normals, project, view_directions
from .sh import sh_to_color

OUTPUTS = ("rgb", "alpha", "depth", "plane_depth", "normal", "features")


def render(gaussians: Gaussians, camera: Camera, outputs=("rgb",), background=None,
           features: torch.Tensor | None = None, sh_degree: int | None = None,
           world_to_camera: torch.Tensor | None = None, backend: str = "auto") -> dict[str, torch.Tensor]:
    """Render ``gaussians`` from ``camera``.

    outputs: any of "rgb" [H, W, 3] (background blended), "alpha" [H, W, 1], "depth" [H, W, 1]
    (expected camera z, 0 where alpha < ALPHA_EPS), "plane_depth" [H, W, 1] (PGSR),
    "normal" [H, W, 3] (camera space, alpha-blended, not renormalised), "features" [H, W, C]
    (alpha-blended ``features`` [N, C]). Always also "means2d" [N, 2] (grad retained) and
    "radii" [N] int64 (0 = culled). background: [3] (tensor or sequence), default black.
    sh_degree caps the SH degree; world_to_camera [4, 4] overrides the camera's pose.
    """
    outputs = tuple(outputs)
    check_render_args(outputs, features, len(gaussians))
    device, dtype = gaussians.device, gaussians.dtype
    if world_to_camera is None:
        world_to_camera = torch.as_tensor(camera.world_to_camera, dtype=torch.float64, device=device)
    degree = gaussians.sh_degree if sh_degree is None else max(0, min(sh_degree, gaussians.sh_degree))

    proj = project(gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits,
                   world_to_camera, camera, backend=backend)
    means2d = proj.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    keep = torch.nonzero(proj.visible).squeeze(-1)  # [M]
    t = proj.camera_means[keep]

    channels = value_channels(gaussians, keep, t, outputs, features, degree, world_to_camera, backend)
    values = torch.cat([v for _, v in channels], dim=1) if channels else torch.zeros(
        keep.numel(), 0, dtype=dtype, device=device)

    image, alpha = composite(means2d[keep], proj.conics[keep], proj.opacities[keep], values,
                             t[:, 2].detach(), proj.extents[keep].detach(), camera.width, camera.height,
                             backend=backend)

    result = finish_outputs(outputs, split_channels(image, channels), alpha, background, camera,
                             dtype, device)
    result["means2d"] = means2d
    result["radii"] = proj.radii
    return result


def check_render_args(outputs: tuple, features: torch.Tensor | None, n: int) -> None:
    """Raise ValueError for unknown output names or per-Gaussian features that do not fit."""
    unknown = [name for name in outputs if name not in OUTPUTS]
    if unknown:
        raise ValueError(f"render: unknown outputs {unknown}; choose from {OUTPUTS}")
    if "features" in outputs and features is None:
        raise ValueError("render: 'features' requested but no per-Gaussian features given")
    if features is not None and features.shape[0] != n:
        raise ValueError(f"render: features has {features.shape[0]} rows for {n} Gaussians")


def value_channels(gaussians: Gaussians, keep: torch.Tensor, t: torch.Tensor, outputs: tuple,
                    features: torch.Tensor | None, degree: int, world_to_camera: torch.Tensor,
                    backend: str) -> list[tuple[str, torch.Tensor]]:
    """The per-Gaussian value channels to composite, in order, as (name, [M, C]) pairs.

    keep [M] indexes the visible Gaussians, t [M, 3] their camera-space centres; only what a
    requested output needs is computed ("plane_offset" rides along with "normal" for plane depth).
    """
    channels: list[tuple[str, torch.Tensor]] = []
    if "rgb" in outputs:
        directions = view_directions(gaussians.means[keep], world_to_camera) if degree > 0 else t
        channels.append(("rgb", sh_to_color(gaussians.sh[keep], directions, degree, backend=backend)))
    if "depth" in outputs:
        channels.append(("depth", t[:, 2:3]))
    if "normal" in outputs or "plane_depth" in outputs:
        normals, offsets = plane_normals(gaussians.quats[keep], gaussians.log_scales[keep],
                                         world_to_camera, t)
        channels.append(("normal", normals))
        if "plane_depth" in outputs:
            channels.append(("plane_offset", offsets[:, None]))
    if "features" in outputs:
        channels.append(("features", features[keep].to(gaussians.dtype)))
    return channels


def split_channels(image: torch.Tensor, channels: list[tuple[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Cut the composited image [H, W, C_total] back into one [H, W, C] slice per named channel."""
    blended: dict[str, torch.Tensor] = {}
    start = 0
    for name, v in channels:
        blended[name] = image[..., start:start + v.shape[1]]
        start += v.shape[1]
    return blended


def finish_outputs(outputs: tuple, blended: dict[str, torch.Tensor], alpha: torch.Tensor,
                    background, camera: Camera, dtype: torch.dtype,
                    device: torch.device) -> dict[str, torch.Tensor]:
    """Turn blended channels and alpha [H, W, 1] into the requested outputs, in request order;
    the background [3] is made a tensor of the Gaussians' ``dtype`` on ``device``."""
    result: dict[str, torch.Tensor] = {}
    covered = alpha >= ALPHA_EPS
    for name in outputs:
        if name == "rgb":
            rgb = blended["rgb"]
            if background is not None:
                bg = torch.as_tensor(background, dtype=dtype, device=device).reshape(1, 1, 3)
                rgb = rgb + (1.0 - alpha) * bg
            result["rgb"] = rgb
        elif name == "alpha":
            result["alpha"] = alpha
        elif name == "depth":
            # Dividing by alpha >= ALPHA_EPS is safe; uncovered pixels report 0 (no surface).
            result["depth"] = torch.where(covered, blended["depth"] / alpha.clamp_min(ALPHA_EPS),
                                          torch.zeros_like(alpha))
        elif name == "normal":
            result["normal"] = blended["normal"]
        elif name == "plane_depth":
            result["plane_depth"] = _plane_depth(blended["plane_offset"], blended["normal"], covered, camera)
        elif name == "features":
            result["features"] = blended["features"]
    return result


def _plane_depth(offset: torch.Tensor, normal: torch.Tensor, covered: torch.Tensor,
                 camera: Camera) -> torch.Tensor:
    """PGSR plane depth: blended offset [H, W, 1] / (blended normal [H, W, 3] . K^-1 [u, v, 1]).

    A surface facing the camera has n . ray < 0 (and so does its offset); pixels whose
    denominator is not safely negative (uncovered, edge-on, back-facing blends) report 0.
    """
    height, width = normal.shape[:2]
    u = (torch.arange(width, dtype=normal.dtype, device=normal.device) + 0.5 - camera.cx) / camera.fx
    v = (torch.arange(height, dtype=normal.dtype, device=normal.device) + 0.5 - camera.cy) / camera.fy
    rays = torch.stack([u[None, :].expand(height, width), v[:, None].expand(height, width),
                        torch.ones(height, width, dtype=normal.dtype, device=normal.device)], -1)
    denominator = (normal * rays).sum(-1, keepdim=True)
    # The denominator scales with the blended alpha, so the same ALPHA_EPS bounds it away from 0.
    safe = covered & (denominator <= -ALPHA_EPS)
    return torch.where(safe, offset / torch.where(safe, denominator, -torch.ones_like(denominator)),
                       torch.zeros_like(offset))
