"""Loss terms of the PGSR-style planar 3DGS objective.

All images are channels-last tensors: colour [H, W, 3], depth [H, W, 1], normals [H, W, 3]
in camera space (OpenCV axes). Pixel (i, j) is the continuous point (j + 0.5, i + 0.5) as
(x, y). Multi-view terms take a reference view r and a neighbour view n with the relative
pose ``ref_to_nb`` = world_to_camera_n @ camera_to_world_r ([4, 4]).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..constants import ALPHA_EPS, NEAR_PLANE
from ..evaluation.metrics import ssim

# Guards for normalising vectors / dividing by projected z or plane offsets: below these
# the geometry is degenerate (a ray parallel to the plane, a point at the camera centre)
# and the pixel is masked out instead of divided by.
_NORM_EPS = 1e-8
_PLANE_OFFSET_MIN = 1e-6
# NCC variance floor: a flat patch has no texture to correlate, its NCC is undefined.
_NCC_VAR_MIN = 1e-6


# --- photometric --------------------------------------------------------------------------

def photometric_loss(rendered: torch.Tensor, target: torch.Tensor, lambda_dssim: float
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """rendered, target: [H, W, 3] -> ((1 - lambda) L1 + lambda (1 - SSIM), L1)."""
    l1 = (rendered - target).abs().mean()
    if lambda_dssim <= 0:
        return l1, l1
    return (1.0 - lambda_dssim) * l1 + lambda_dssim * (1.0 - ssim(rendered, target)), l1


def flatten_loss(log_scales: torch.Tensor) -> torch.Tensor:
    """PGSR flattening: the smallest of each Gaussian's three scales pushed to 0.

    log_scales: [N, 3] (N > 0) -> mean over Gaussians of min(exp(log_scales)).
    """
    return torch.exp(log_scales.min(dim=1).values).mean()


# --- geometry helpers ---------------------------------------------------------------------

def pixel_grid(height: int, width: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """Pixel centres (x, y): [H, W, 2]."""
    ys = torch.arange(height, dtype=dtype, device=device) + 0.5
    xs = torch.arange(width, dtype=dtype, device=device) + 0.5
    grid_y, grid_x = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([grid_x, grid_y], -1)


def unproject(pixels: torch.Tensor, depth: torch.Tensor, intrinsics: torch.Tensor) -> torch.Tensor:
    """pixels: [..., 2] (x, y); depth (camera z): [...]; intrinsics [3, 3] -> points [..., 3]."""
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    x = (pixels[..., 0] - cx) / fx * depth
    y = (pixels[..., 1] - cy) / fy * depth
    return torch.stack([x, y, depth], -1)


def project(points: torch.Tensor, intrinsics: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """points: [..., 3] camera space -> (pixels [..., 2], in_front [...] bool).

    Points behind the near plane are flagged and divided by the near plane instead, so the
    result stays finite; callers mask them out.
    """
    z = points[..., 2]
    in_front = z > NEAR_PLANE
    safe_z = torch.where(in_front, z, torch.full_like(z, NEAR_PLANE))
    u = intrinsics[0, 0] * points[..., 0] / safe_z + intrinsics[0, 2]
    v = intrinsics[1, 1] * points[..., 1] / safe_z + intrinsics[1, 2]
    return torch.stack([u, v], -1), in_front


def transform(pose: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """pose [4, 4] applied to points [..., 3]."""
    return points @ pose[:3, :3].T + pose[:3, 3]


def sample_image(image: torch.Tensor, pixels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Bilinear lookup. image: [H, W, C]; pixels: [..., 2] (x, y) -> ([..., C], inside [...]).

    ``inside`` is True where the sample point lies within the outer pixel centres, i.e.
    every bilinear tap is a real pixel.
    """
    height, width = image.shape[:2]
    lead = pixels.shape[:-1]
    flat = pixels.reshape(1, 1, -1, 2)
    # align_corners=False maps -1/+1 to the image border, i.e. pixel centres at (i + 0.5).
    normalised = torch.stack([flat[..., 0] * (2.0 / width) - 1.0, flat[..., 1] * (2.0 / height) - 1.0], -1)
    values = F.grid_sample(image.permute(2, 0, 1)[None], normalised.to(image.dtype), mode="bilinear",
                           padding_mode="border", align_corners=False)
    values = values[0, :, 0].T.reshape(*lead, image.shape[2])
    x, y = pixels[..., 0], pixels[..., 1]
    inside = (x >= 0.5) & (x <= width - 0.5) & (y >= 0.5) & (y <= height - 0.5)
    return values, inside


def safe_normalize(vectors: torch.Tensor) -> torch.Tensor:
    """[..., 3] -> unit vectors; zero vectors stay zero (norm clamped at _NORM_EPS)."""
    return vectors / vectors.norm(dim=-1, keepdim=True).clamp_min(_NORM_EPS)


def normals_from_depth(depth: torch.Tensor, intrinsics: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-space normals of the surface a depth map describes, facing the camera.

    depth: [H, W, 1] (0 = no surface); intrinsics: [3, 3] ->
    (normals [H, W, 3], valid [H, W] bool). Central differences of the unprojected points;
    border pixels and pixels next to a missing depth are invalid (normal 0).
    """
    height, width = depth.shape[:2]
    points = unproject(pixel_grid(height, width, depth.dtype, depth.device), depth[..., 0], intrinsics)
    dx = torch.zeros_like(points)
    dy = torch.zeros_like(points)
    dx[:, 1:-1] = points[:, 2:] - points[:, :-2]
    dy[1:-1] = points[2:] - points[:-2]
    # x right, y down, z forward: cross(dy, dx) points towards the camera (-z for a
    # fronto-parallel plane), the side the rasterizer's normals face.
    normals = safe_normalize(torch.cross(dy, dx, dim=-1))
    has_depth = depth[..., 0] > 0
    valid = torch.zeros_like(has_depth)
    valid[1:-1, 1:-1] = (has_depth[1:-1, 1:-1] & has_depth[1:-1, 2:] & has_depth[1:-1, :-2]
                         & has_depth[2:, 1:-1] & has_depth[:-2, 1:-1])
    return normals * valid[..., None], valid


def edge_aware_weight(image: torch.Tensor) -> torch.Tensor:
    """image: [H, W, 3] -> [H, W] weight in [0, 1], small on image edges.

    (1 - g)^2 with g the grey-level gradient magnitude scaled to [0, 1] over the image; a
    flat image (max gradient 0) has weight 1 everywhere.
    """
    grey = image.mean(-1)
    grad = torch.zeros_like(grey)
    gx = (grey[1:-1, 2:] - grey[1:-1, :-2]).abs()
    gy = (grey[2:, 1:-1] - grey[:-2, 1:-1]).abs()
    grad[1:-1, 1:-1] = torch.maximum(gx, gy)
    span = (grad.max() - grad.min()).clamp_min(_NORM_EPS)
    grad = (grad - grad.min()) / span
    return (1.0 - grad).clamp(0.0, 1.0) ** 2


# --- single view --------------------------------------------------------------------------

def normal_consistency_loss(rendered_normal: torch.Tensor, plane_depth: torch.Tensor,
                            alpha: torch.Tensor, intrinsics: torch.Tensor,
                            weight: torch.Tensor) -> torch.Tensor | None:
    """PGSR single-view term: rendered normal vs the normal of the rendered plane depth.

    rendered_normal: [H, W, 3] (alpha-blended, renormalised here); plane_depth, alpha:
    [H, W, 1]; weight: [H, W] edge-aware weight of the photo. Returns the weighted mean
    L1 difference over covered pixels, or None when no pixel is covered.
    """
    depth_normal, valid = normals_from_depth(plane_depth, intrinsics)
    valid = valid & (alpha[..., 0] > ALPHA_EPS)
    if not bool(valid.any()):
        return None
    normal = safe_normalize(rendered_normal)
    difference = (depth_normal - normal).abs().sum(-1)
    return (weight * difference)[valid].mean()


# --- multi view ---------------------------------------------------------------------------

def reprojection_error(ref_depth: torch.Tensor, ref_intrinsics: torch.Tensor,
                       nb_depth: torch.Tensor, nb_intrinsics: torch.Tensor,
                       ref_to_nb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward-backward reprojection through rendered depth.

    Each reference pixel is lifted with its depth, projected into the neighbour, lifted
    again with the neighbour's depth there and projected back. For consistent depth maps
    it lands where it started.
    ref_depth: [H, W, 1]; nb_depth: [h, w, 1] (0 = no surface; any size, with matching
    intrinsics) -> (pixel distance [H, W], valid [H, W] bool).
    """
    height, width = ref_depth.shape[:2]
    pixels = pixel_grid(height, width, ref_depth.dtype, ref_depth.device)
    depth = ref_depth[..., 0]
    in_nb, front_1 = project(transform(ref_to_nb, unproject(pixels, depth, ref_intrinsics)), nb_intrinsics)
    depth_nb, inside = sample_image(nb_depth, in_nb)
    depth_nb = depth_nb[..., 0]
    back = transform(torch.linalg.inv(ref_to_nb), unproject(in_nb, depth_nb, nb_intrinsics))
    in_ref, front_2 = project(back, ref_intrinsics)
    error = (in_ref - pixels).norm(dim=-1)
    valid = (depth > 0) & front_1 & inside & (depth_nb > 0) & front_2
    return error, valid


def geometric_consistency_loss(error: torch.Tensor, valid: torch.Tensor,
                               max_error: float) -> torch.Tensor | None:
    """PGSR multi-view geometric term: mean of error * exp(-error) (weight detached) over
    valid pixels with error < max_error; None when there are none. error, valid: [H, W]."""
    mask = valid & (error < max_error)
    if not bool(mask.any()):
        return None
    weight = torch.exp(-error.detach())
    return (weight * error)[mask].mean()


def patch_offsets(radius: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """Integer offsets of a (2r+1)^2 patch: [P, 2] (x, y)."""
    steps = torch.arange(-radius, radius + 1, dtype=dtype, device=device)
    oy, ox = torch.meshgrid(steps, steps, indexing="ij")
    return torch.stack([ox.reshape(-1), oy.reshape(-1)], -1)


def plane_homographies(pixels: torch.Tensor, depth: torch.Tensor, normals: torch.Tensor,
                       ref_intrinsics: torch.Tensor, nb_intrinsics: torch.Tensor,
                       ref_to_nb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Homographies induced by each pixel's local plane, reference -> neighbour pixels.

    A plane {X : n.X = delta} (reference camera frame) maps through x_nb ~
    K_nb (R + t n^T / delta) K_ref^-1 x_ref. pixels: [S, 2]; depth: [S]; normals: [S, 3]
    (unit) -> (H [S, 3, 3], valid [S]: the plane does not pass through the camera centre).
    """
    points = unproject(pixels, depth, ref_intrinsics)
    delta = (normals * points).sum(-1)
    valid = delta.abs() > _PLANE_OFFSET_MIN
    safe_delta = torch.where(valid, delta, torch.full_like(delta, _PLANE_OFFSET_MIN))
    rotation, translation = ref_to_nb[:3, :3], ref_to_nb[:3, 3]
    plane_term = translation[None, :, None] * (normals / safe_delta[:, None])[:, None, :]
    return nb_intrinsics @ (rotation[None] + plane_term) @ torch.linalg.inv(ref_intrinsics), valid


def normalized_cross_correlation(ref: torch.Tensor, nb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """ref, nb: [S, P] grey patches -> (NCC [S] in [-1, 1], valid [S]: both patches textured)."""
    ref_centered = ref - ref.mean(1, keepdim=True)
    nb_centered = nb - nb.mean(1, keepdim=True)
    var_ref = (ref_centered ** 2).mean(1)
    var_nb = (nb_centered ** 2).mean(1)
    valid = (var_ref > _NCC_VAR_MIN) & (var_nb > _NCC_VAR_MIN)
    denominator = torch.sqrt((var_ref * var_nb).clamp_min(_NCC_VAR_MIN ** 2))
    ncc = (ref_centered * nb_centered).mean(1) / denominator
    return ncc.clamp(-1.0, 1.0), valid


def ncc_loss(ref_grey: torch.Tensor, nb_grey: torch.Tensor, pixels: torch.Tensor, depth: torch.Tensor,
             normals: torch.Tensor, ref_intrinsics: torch.Tensor, nb_intrinsics: torch.Tensor,
             ref_to_nb: torch.Tensor, radius: int, weights: torch.Tensor | None = None
             ) -> torch.Tensor | None:
    """PGSR multi-view photometric term: 1 - NCC of photo patches related by the rendered plane.

    ref_grey: [H, W, 1] reference photo; nb_grey: [h, w, 1] neighbour photo; pixels: [S, 2]
    reference pixel centres; depth [S] and normals [S, 3] (unit, camera space) from the
    reference render; weights [S] optional. Gradients flow into depth and normals through
    the homographies. Returns the weighted mean of (1 - NCC) over valid patches, or None.
    """
    offsets = patch_offsets(radius, pixels.dtype, pixels.device)
    ref_points = pixels[:, None, :] + offsets[None]                         # [S, P, 2]
    ref_patches, ref_inside = sample_image(ref_grey, ref_points)
    homographies, plane_ok = plane_homographies(pixels, depth, normals, ref_intrinsics,
                                                nb_intrinsics, ref_to_nb)
    homogeneous = torch.cat([ref_points, torch.ones_like(ref_points[..., :1])], -1)
    warped = homogeneous @ homographies.transpose(1, 2)                     # [S, P, 3]
    in_front = warped[..., 2] > _PLANE_OFFSET_MIN
    safe_w = torch.where(in_front, warped[..., 2], torch.ones_like(warped[..., 2]))
    nb_points = warped[..., :2] / safe_w[..., None]
    nb_patches, nb_inside = sample_image(nb_grey, nb_points)
    ncc, textured = normalized_cross_correlation(ref_patches[..., 0], nb_patches[..., 0])
    valid = (plane_ok & textured & ref_inside.all(1) & nb_inside.all(1) & in_front.all(1))
    if not bool(valid.any()):
        return None
    loss = 1.0 - ncc
    if weights is None:
        return loss[valid].mean()
    w = weights[valid]
    # Weights are exp(-error) > 0 for every valid pixel, so the sum is positive.
    return (loss[valid] * w).sum() / w.sum().clamp_min(_NORM_EPS)
