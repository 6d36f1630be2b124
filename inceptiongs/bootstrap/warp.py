"""Warping real photos into a virtual view, with a conservative trusted-pixel mask.

Backward warp: every destination (virtual-view) pixel is unprojected with the destination's
rendered depth, moved into the source (training) camera, projected, and the source photo is
sampled there bilinearly. A pixel is trusted (mask 1) only when all of these hold:

1. it has depth in the destination (rendered depth > 0: the rasterizer writes 0 where
   nothing was hit);
2. the point is in front of the source camera (z_src > NEAR_PLANE): without this a point
   behind the camera projects, sign-flipped, to a plausible pixel;
3. its projection lies where bilinear sampling reads four real pixels, i.e. the continuous
   coordinate u is in [0.5, W - 0.5] (pixel (i, j) samples (i + 0.5, j + 0.5)), same for v;
4. the source has depth at all four taps (no hole contributes to the sample);
5. visibility: |z_src - d_src| <= delta * z_src, with d_src the source's rendered depth
   sampled bilinearly at the projection and z_src the point's depth in the source camera.
   The test is relative (depth errors grow with distance) and conservative: a point hidden
   behind an occluder in the source reads the occluder's smaller depth and fails. At an
   occlusion edge the bilinear depth mixes both surfaces, so a mixed sample passes only when
   the occluder's weight a satisfies a * (z_bg - z_fg) <= delta * z_bg, which bounds the
   colour contamination by the same small weight;
6. not grazing: the surface normal, estimated from the destination depth (cross product of
   neighbour differences, per axis the side with the smaller depth jump so silhouettes do
   not bend it), makes an angle of at most ``grazing_deg`` with the viewing ray of *both*
   cameras, and both cameras see the same side of the surface. A grazing view stretches a
   pixel over a long strip of surface (resampling blur, unreliable depth) and is rejected.

Depths are camera z (what inceptiongs.rasterizer.rasterize.render's "depth" output holds), not ray
lengths. Images are float in [0, 1]; numpy arrays or torch tensors; results are torch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..camera import Camera
from ..constants import NEAR_PLANE
from ..pinhole import project, relative_pose, unproject

# Relative depth tolerance of the visibility test: 3% of the point's depth. Stage-I depth
# (alpha-blended expected z) is good to about a percent on well reconstructed surfaces;
# 3% leaves room for that and for bilinear depth sampling on slanted surfaces, while an
# occluder must still be nearer than 97% of the point's depth to be missed, i.e. closer
# to the surface than anything that matters for appearance.
DEFAULT_DELTA = 0.03
# Surfaces seen at more than 75 degrees from their normal are grazing: one pixel then covers
# 1 / cos(75 deg) ~ 3.9 times its frontal footprint, sampled detail is smeared and the depth
# slope makes the visibility test unreliable.
DEFAULT_GRAZING_DEG = 75.0
# Normals shorter than this (in squared scene units) come from degenerate neighbourhoods.
_NORMAL_NORM_MIN = 1e-20


@dataclass
class WarpResult:
    """image: [h, w, 3] (0 where rejected); mask: [h, w, 1] float, 1 = trusted pixel."""

    image: torch.Tensor
    mask: torch.Tensor


@dataclass
class WarpGeometry:
    """Where each destination pixel lands in the source camera.

    points_dst: [h, w, 3] destination-camera points; points_src: [h, w, 3] the same points in
    source-camera coordinates; uv: [h, w, 2] continuous source pixel coordinates (valid only
    where points_src z > NEAR_PLANE); has_depth: [h, w] bool (destination depth > 0).
    """

    points_dst: torch.Tensor
    points_src: torch.Tensor
    uv: torch.Tensor
    has_depth: torch.Tensor


def _tensor(x, name: str, dtype=None, device=None) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    if not (t.is_floating_point()):
        raise ValueError(f"{name} must be a float array, got {t.dtype}")
    # Warps build targets; nothing is differentiated through them, so no graph is kept.
    return t.detach().to(dtype=dtype or t.dtype, device=device)


def _check_shape(t: torch.Tensor, shape: tuple, name: str) -> None:
    if tuple(t.shape) != shape:
        raise ValueError(f"{name} has shape {tuple(t.shape)}, expected {shape}")


def warp_geometry(dst_depth, dst_cam: Camera, src_cam: Camera) -> WarpGeometry:
    """Unproject the destination depth [h, w, 1] and map it into the source camera (float64)."""
    depth = _tensor(dst_depth, "dst_depth", torch.float64)
    _check_shape(depth, (dst_cam.height, dst_cam.width, 1), "dst_depth")
    depth = depth[..., 0]
    has_depth = torch.isfinite(depth) & (depth > 0)
    points_dst = unproject(torch.where(has_depth, depth, torch.zeros_like(depth)), dst_cam)
    transform = torch.as_tensor(relative_pose(src_cam, dst_cam), dtype=torch.float64, device=depth.device)
    points_src = points_dst @ transform[:3, :3].T + transform[:3, 3]
    return WarpGeometry(points_dst, points_src, project(points_src, src_cam), has_depth)


def bilinear_taps(uv: torch.Tensor, width: int, height: int):
    """Integer taps and weights of bilinear sampling at continuous coordinates uv [h, w, 2].

    Returns (x0, y0, fx, fy, inside): x0, y0 [h, w] int64 top-left tap (clamped so x0 + 1,
    y0 + 1 are valid indices), fractions fx, fy [h, w], and inside [h, w] bool: all four
    taps are real pixels (u in [0.5, W - 0.5], v in [0.5, H - 0.5]).
    """
    x = uv[..., 0] - 0.5
    y = uv[..., 1] - 0.5
    inside = (x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1)
    x0 = torch.clamp(torch.floor(x), 0, width - 2)
    y0 = torch.clamp(torch.floor(y), 0, height - 2)
    return x0.long(), y0.long(), x - x0, y - y0, inside


def sample_bilinear(image: torch.Tensor, x0, y0, fx, fy) -> tuple[torch.Tensor, torch.Tensor]:
    """image [H, W, C] at the taps of :func:`bilinear_taps` -> (value [h, w, C], taps [h, w, 4, C])."""
    fx, fy = fx[..., None].to(image.dtype), fy[..., None].to(image.dtype)
    t00, t01 = image[y0, x0], image[y0, x0 + 1]
    t10, t11 = image[y0 + 1, x0], image[y0 + 1, x0 + 1]
    value = (t00 * (1 - fx) + t01 * fx) * (1 - fy) + (t10 * (1 - fx) + t11 * fx) * fy
    return value, torch.stack([t00, t01, t10, t11], dim=-2)


def depth_normals(points: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Surface normals from a depth map's camera-space points.

    points: [h, w, 3], valid: [h, w] bool. Per image axis the forward or backward
    difference is used, whichever joins a valid neighbour with the smaller depth jump (so a
    pixel beside a silhouette takes its slope from its own surface). Returns (normals
    [h, w, 3] unit, ok [h, w] bool); ok is False without a valid neighbour on either axis or
    for a degenerate cross product. The normal's sign is arbitrary.
    """
    def axis_difference(dim: int) -> tuple[torch.Tensor, torch.Tensor]:
        forward = torch.zeros_like(points)
        backward = torch.zeros_like(points)
        forward_ok = torch.zeros_like(valid)
        backward_ok = torch.zeros_like(valid)
        n = points.shape[dim]
        head = [slice(None)] * 3
        tail = [slice(None)] * 3
        head[dim], tail[dim] = slice(0, n - 1), slice(1, n)
        head, tail = tuple(head), tuple(tail)
        step = points[tail] - points[head]
        pair_ok = valid[head[:2]] & valid[tail[:2]]
        forward[head], forward_ok[head[:2]] = step, pair_ok
        backward[tail], backward_ok[tail[:2]] = step, pair_ok
        use_forward = forward_ok & (~backward_ok | (forward[..., 2].abs() <= backward[..., 2].abs()))
        diff = torch.where(use_forward[..., None], forward, backward)
        return diff, valid & (forward_ok | backward_ok)

    du, du_ok = axis_difference(1)
    dv, dv_ok = axis_difference(0)
    normal = torch.cross(du, dv, dim=-1)
    squared = (normal * normal).sum(-1)
    ok = du_ok & dv_ok & (squared > _NORMAL_NORM_MIN)
    # Only ok pixels are divided by their norm; the others get 1 (their normal is unused).
    norm = torch.sqrt(torch.where(ok, squared, torch.ones_like(squared)))
    return normal / norm[..., None], ok


def not_grazing(normals: torch.Tensor, rays_a: torch.Tensor, rays_b: torch.Tensor,
                grazing_deg: float) -> torch.Tensor:
    """[h, w] bool: both rays (camera to point, [h, w, 3], same frame as the unit normals)
    are within ``grazing_deg`` of the normal's line and on the same side of the surface."""
    cos_min = math.cos(math.radians(grazing_deg))
    dot_a = (normals * rays_a).sum(-1)
    dot_b = (normals * rays_b).sum(-1)
    # Rays of points in front of a camera have length >= z > 0; clamp only guards masked ones.
    len_a = rays_a.norm(dim=-1).clamp_min(1e-300)
    len_b = rays_b.norm(dim=-1).clamp_min(1e-300)
    same_side = dot_a * dot_b > 0
    return same_side & (dot_a.abs() >= cos_min * len_a) & (dot_b.abs() >= cos_min * len_b)


def warp_to_view(src_image, src_depth, src_cam: Camera, dst_depth, dst_cam: Camera,
                 delta: float = DEFAULT_DELTA, grazing_deg: float = DEFAULT_GRAZING_DEG,
                 occlusion_depth=None) -> WarpResult:
    """Backward-warp a source photo into the destination view (see the module doc).

    src_image: [H, W, 3] float in [0, 1]; src_depth: [H, W, 1] source camera z (0 = none);
    dst_depth: [h, w, 1] destination camera z (0 = none). H, W and h, w must match the
    cameras (H, W >= 2). Returns image [h, w, 3] in src_image's dtype (0 where rejected)
    and mask [h, w, 1] in {0, 1}.

    occlusion_depth: [h, w, 1] the destination depth the visibility test (5) uses instead of
    dst_depth. A photo-refined dst_depth places the photo, while the occlusion test must
    compare depths of one kind: the stage-I depths of both views, which share their errors.
    """
    if not (math.isfinite(delta) and delta > 0):
        raise ValueError(f"delta must be a positive number, got {delta}")
    if not 0 < grazing_deg <= 90:
        raise ValueError(f"grazing_deg must be in (0, 90], got {grazing_deg}")
    image = _tensor(src_image, "src_image")
    device = image.device
    src_z = _tensor(src_depth, "src_depth", torch.float64, device)
    _check_shape(image, (src_cam.height, src_cam.width, 3), "src_image")
    _check_shape(src_z, (src_cam.height, src_cam.width, 1), "src_depth")
    if src_cam.width < 2 or src_cam.height < 2:
        raise ValueError("the source image must be at least 2 x 2 pixels for bilinear sampling")
    geometry = warp_geometry(_tensor(dst_depth, "dst_depth", torch.float64, device), dst_cam, src_cam)

    z = geometry.points_src[..., 2]
    in_front = geometry.has_depth & (z > NEAR_PLANE)
    x0, y0, fx, fy, inside = bilinear_taps(geometry.uv, src_cam.width, src_cam.height)
    src_z = torch.where(torch.isfinite(src_z), src_z, torch.zeros_like(src_z))
    occlusion = geometry if occlusion_depth is None else warp_geometry(
        _tensor(occlusion_depth, "occlusion_depth", torch.float64, device), dst_cam, src_cam)
    occ_z = occlusion.points_src[..., 2]
    ox0, oy0, ofx, ofy, occ_inside = bilinear_taps(occlusion.uv, src_cam.width, src_cam.height)
    sampled_z, z_taps = sample_bilinear(src_z, ox0, oy0, ofx, ofy)
    taps_have_depth = (z_taps[..., 0] > 0).all(dim=-1) & occlusion.has_depth & (occ_z > NEAR_PLANE) & occ_inside
    visible = (occ_z - sampled_z[..., 0]).abs() <= delta * occ_z

    normals, normal_ok = depth_normals(geometry.points_dst, geometry.has_depth)
    transform = torch.as_tensor(relative_pose(src_cam, dst_cam), dtype=torch.float64, device=device)
    # Source ray (source centre -> point) expressed in destination coordinates: the normal's frame.
    src_centre_in_dst = -transform[:3, :3].T @ transform[:3, 3]
    facing = normal_ok & not_grazing(normals, geometry.points_dst, geometry.points_dst - src_centre_in_dst,
                                     grazing_deg)

    trusted = in_front & inside & taps_have_depth & visible & facing
    colour, _ = sample_bilinear(image, x0, y0, fx, fy)
    mask = trusted[..., None].to(image.dtype)
    return WarpResult(image=colour * mask, mask=mask)


def blend_views(generated, warps: list[WarpResult]) -> tuple[torch.Tensor, torch.Tensor]:
    """I* = M * warped + (1 - M) * generated.

    generated: [h, w, 3]; warps: WarpResults of the same size. ``warped`` is the per-pixel
    mask-weighted mean of the warps, M = the largest mask value at the pixel (1 where any
    warp is trusted, for {0, 1} masks). Returns (image [h, w, 3], M [h, w, 1]).
    """
    generated = _tensor(generated, "generated")
    if not warps:
        return generated.clone(), torch.zeros_like(generated[..., :1])
    images = torch.stack([w.image.to(generated) for w in warps])   # [n, h, w, 3]
    masks = torch.stack([w.mask.to(generated) for w in warps])     # [n, h, w, 1]
    if images.shape[1:] != generated.shape or masks.shape[1:] != generated.shape[:2] + (1,):
        raise ValueError(f"warps {tuple(images.shape[1:])} do not match the generated image "
                         f"{tuple(generated.shape)}")
    weight = masks.sum(0)
    # Where no warp is trusted the weight is 0 and the mean is unused; divide by 1 there.
    warped = (masks * images).sum(0) / torch.where(weight > 0, weight, torch.ones_like(weight))
    trust = masks.amax(0)
    return trust * warped + (1 - trust) * generated, trust
