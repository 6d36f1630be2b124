"""Depth at a virtual view from the training views' own depths (forward splatting).

Stage II warps photos into a virtual view with a depth at that view. The render's depth there
is the model's guess exactly where the model is worst: a view the photos saw from far away or
not at all. The training views' depths are the model where it was fitted. Each training view's
surface depth is unprojected, moved into the virtual camera and splatted into a z-buffer
(nearest point per pixel) whose small holes (a far source covers a near view's pixels
sparsely) are closed from the nearest splatted depth within a few pixels; the sources are
combined by their median, so one view's floater or hole does not decide a pixel.

On the README courtyard's close views of its north facade (stage I of the demo, 442 steps),
the photos warped with the splatted depth scored 16.10 dB against 15.54 with the view's own
surface depth (render 14.88): the splatted depth is no more accurate (34 % of the pixels within
5 % of the ray-traced truth, against 36 %), but its warps are trusted on 73 % of the pixels
against 49 %. On bonsai it is the other way round (docs/bootstrap.md, 2026-11-26), hence
``--virtual-depth auto``.
"""

from __future__ import annotations

from typing import Callable, Sequence

import torch

from ..camera import Camera
from ..constants import NEAR_PLANE
from .virtual_views import nearest_training_views
from ..pinhole import project, relative_pose, unproject

# Holes are closed from splatted pixels at most this far away (pixels): a source ~4x farther
# from the surface than the virtual camera lands one point per ~4 x 4 virtual pixels.
DEFAULT_CLOSE_RADIUS = 4


def splat_into(depth: torch.Tensor, camera: Camera, target: Camera) -> torch.Tensor:
    """One source's depth [H, W, 1] (camera z, 0 = none) at ``camera``, forward-projected into
    ``target``: -> [h, w] float64 z-buffer of the nearest splatted point (inf = none)."""
    z_src = depth[..., 0].to(torch.float64)
    valid = (z_src > 0) & torch.isfinite(z_src)
    points = unproject(torch.where(valid, z_src, torch.zeros_like(z_src)), camera)[valid]       # [P, 3]
    to_target = torch.as_tensor(relative_pose(target, camera), dtype=torch.float64, device=depth.device)
    in_target = points @ to_target[:3, :3].T + to_target[:3, 3]
    in_target = in_target[in_target[:, 2] > NEAR_PLANE]     # in front only: project's divide is safe
    uv = project(in_target, target)
    x, y = torch.floor(uv[:, 0]), torch.floor(uv[:, 1])
    inside = (x >= 0) & (x < target.width) & (y >= 0) & (y < target.height)
    index = (y[inside].long() * target.width + x[inside].long())
    zbuffer = torch.full((target.height * target.width,), float("inf"), dtype=torch.float64, device=depth.device)
    zbuffer.scatter_reduce_(0, index, in_target[inside, 2], reduce="amin")
    return zbuffer.reshape(target.height, target.width)


def close_holes(zbuffer: torch.Tensor, radius: int) -> torch.Tensor:
    """[h, w] z-buffer (inf = none) -> the same with each empty pixel given the nearest (smallest)
    depth within ``radius`` pixels, growing the window one pixel at a time so the closest
    splats fill first; still inf where none is that near."""
    out = zbuffer
    for r in range(1, radius + 1):
        empty = torch.isinf(out)
        if not empty.any():
            break
        # A min filter is max_pool of the negation; inf stays inf (-inf under negation).
        nearest = -torch.nn.functional.max_pool2d(-out[None, None], 2 * r + 1, 1, r)[0, 0]
        out = torch.where(empty, nearest, out)
    return out


def splatted_depth(target: Camera, sources: Sequence[tuple[torch.Tensor, Camera]],
                   close_radius: int = DEFAULT_CLOSE_RADIUS) -> torch.Tensor:
    """Depth at ``target`` from the sources' depths: sources = [(depth [H, W, 1] camera z, 0 =
    none, camera), ...] -> [h, w, 1] float32 camera z of ``target``, 0 where no source reaches.

    Each source's z-buffer has its holes closed (:func:`close_holes`), then per pixel the median
    over the sources that reach it (torch's lower median for an even count: the nearer of the
    middle two)."""
    if close_radius < 0:
        raise ValueError(f"close_radius must be >= 0, got {close_radius}")
    if not sources:
        return torch.zeros(target.height, target.width, 1)      # (no source, no device to follow)
    # Each source's holes closed first, so a pixel's median is over every source that reaches
    # it, not only those whose points happened to land in that pixel.
    stacked = torch.stack([close_holes(splat_into(torch.as_tensor(depth), camera, target), close_radius)
                           for depth, camera in sources])
    median = torch.nanmedian(torch.where(torch.isinf(stacked), torch.nan, stacked), dim=0).values
    return torch.where(torch.isnan(median), 0.0, median).to(torch.float32)[..., None]      # NaN: no source


def depth_from_training_views(target: Camera, cameras: Sequence[Camera], train: Sequence[int], views: int,
                              depth_of: Callable[[Camera], torch.Tensor]) -> torch.Tensor:
    """:func:`splatted_depth` at ``target`` from its ``views`` nearest training views
    (virtual_views.nearest_training_views), each one's depth [H, W, 1] from ``depth_of``."""
    nearest = nearest_training_views(target, cameras, list(train), views)
    return splatted_depth(target, [(depth_of(cameras[i]), cameras[i]) for i in nearest])
