"""World -> screen for every Gaussian: covariance, EWA splatting, culling, footprints.

Pure vectorised torch over Gaussians (O(N), no loops), differentiable w.r.t. the model
parameters and the world-to-camera pose. The rules are the shared projection rules of
docs/design.md, with every constant read from :mod:`inceptiongs.constants`:

- t = R mean + T; culled unless NEAR_PLANE <= t.z <= FAR_PLANE.
- Sigma = R(q) diag(exp(2 clamp(log_scales))) R(q)^T, q normalised (zero -> identity).
- EWA Jacobian at t with t.x/t.z (t.y/t.z) clamped to the image's field of view widened on
  each side by (FRUSTUM_CLAMP_MARGIN - 1) * half the image's angular width,
  cov2d = J W Sigma W^T J^T + DILATION_PX I; culled when det(cov2d) < DET_MIN (or not finite).
- opacity = sigmoid(clamp(logit)); culled when opacity < ALPHA_MIN.
- footprint half-extents sqrt(2 log(opacity / ALPHA_MIN) cov2d_xx) (and yy); culled when the
  footprint box lies entirely outside the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .backend import use_numba
from ..camera import Camera, unit_quat_to_rotation
from ..constants import (
    ALPHA_MIN,
    DET_MIN,
    DILATION_PX,
    FAR_PLANE,
    FRUSTUM_CLAMP_MARGIN,
    LOG_SCALE_MAX,
    LOG_SCALE_MIN,
    NEAR_PLANE,
    OPACITY_LOGIT_ABS_MAX,
    QUAT_NORM_MIN,
)


@dataclass
class Projection:
    """Per-Gaussian screen-space quantities for all N Gaussians (culled ones included;
    ``visible`` says which survive).

    camera_means: [N, 3] camera-space centres t; means2d: [N, 2] pixel coordinates
    (x = column); cov2d: [N, 3] (xx, xy, yy); conics: [N, 3] (a, b, c) of the inverse;
    opacities: [N]; extents: [N, 2] footprint half-sizes; visible: [N] bool;
    radii: [N] int64 (ceil of the larger extent, 0 when culled).
    """

    camera_means: torch.Tensor
    means2d: torch.Tensor
    cov2d: torch.Tensor
    conics: torch.Tensor
    opacities: torch.Tensor
    extents: torch.Tensor
    visible: torch.Tensor
    radii: torch.Tensor


def quat_to_rotation(quats: torch.Tensor) -> torch.Tensor:
    """quats: [N, 4] (w, x, y, z), any norm -> rotation matrices [N, 3, 3].

    Quaternions whose norm is below QUAT_NORM_MIN (zero, denormal) become the identity:
    normalising them would divide by ~0. The swap happens before the division, so neither
    the value nor the gradient can be NaN.
    """
    norm = torch.linalg.vector_norm(quats.detach(), dim=-1, keepdim=True)
    degenerate = ~(norm >= QUAT_NORM_MIN)  # also catches NaN norms
    identity = torch.zeros_like(quats)
    identity[:, 0] = 1.0
    safe = torch.where(degenerate, identity, quats)
    # safe's norm is >= QUAT_NORM_MIN (or exactly 1), so the division is bounded.
    unit = safe / torch.linalg.vector_norm(safe, dim=-1, keepdim=True).clamp_min(QUAT_NORM_MIN)
    w, x, y, z = unit.unbind(-1)
    return unit_quat_to_rotation(w, x, y, z, torch.stack)


def scales_from_log(log_scales: torch.Tensor) -> torch.Tensor:
    """[N, 3] log scales -> scales, clamped so squared scales stay inside float32 range."""
    return torch.exp(torch.clamp(log_scales, LOG_SCALE_MIN, LOG_SCALE_MAX))


def opacities_from_logits(logits: torch.Tensor) -> torch.Tensor:
    """[N] logits -> opacities in (0, 1); the clamp keeps exp() in the backward finite."""
    return torch.sigmoid(torch.clamp(logits, -OPACITY_LOGIT_ABS_MAX, OPACITY_LOGIT_ABS_MAX))


def camera_space_means(means: torch.Tensor, world_to_camera: torch.Tensor) -> torch.Tensor:
    """means: [N, 3], world_to_camera: [4, 4] -> t = R mean + T: [N, 3] float64.

    float64 because a scene far from the origin (1e6 units) with a camera beside it would
    otherwise lose the mean-to-camera offset to float32 cancellation.
    """
    pose = world_to_camera.to(torch.float64)
    return means.to(torch.float64) @ pose[:3, :3].T + pose[:3, 3]


def camera_centre(world_to_camera: torch.Tensor) -> torch.Tensor:
    """[4, 4] -> camera centre in world coordinates [3] (float64), c = -R^T T."""
    pose = world_to_camera.to(torch.float64)
    return -pose[:3, :3].T @ pose[:3, 3]


def view_directions(means: torch.Tensor, world_to_camera: torch.Tensor) -> torch.Tensor:
    """Unit directions from the camera centre to each mean: [N, 3] in means' dtype.

    A mean exactly at the centre has no direction; its norm is clamped (tiny, positive) so
    the result is the zero vector instead of NaN, and SH then gives the DC colour.
    """
    offset = means.to(torch.float64) - camera_centre(world_to_camera)
    norm = torch.linalg.vector_norm(offset, dim=-1, keepdim=True).clamp_min(1e-300)
    return (offset / norm).to(means.dtype)


def depth_in_range(z: torch.Tensor) -> torch.Tensor:
    """[N] camera z (any float dtype) -> [N] bool: the near/far rule shared with the GLSL
    preprocess shader, NEAR_PLANE <= float32(z) <= FAR_PLANE (NaN is out of range)."""
    z32 = z.to(torch.float32)
    return (z32 >= NEAR_PLANE) & (z32 <= FAR_PLANE)


def footprint_level(opacities: torch.Tensor) -> torch.Tensor:
    """[M] opacities -> the power log(opacity / ALPHA_MIN) at which alpha falls to ALPHA_MIN."""
    return torch.clamp_min(torch.log(opacities / ALPHA_MIN), 0.0)


def project(
    means: torch.Tensor,
    log_scales: torch.Tensor,
    quats: torch.Tensor,
    opacity_logits: torch.Tensor,
    world_to_camera: torch.Tensor,
    intrinsics: Camera,
    backend: str = "auto",
) -> Projection:
    """Project N Gaussians (means [N, 3], log_scales [N, 3], quats [N, 4], opacity_logits [N])
    through world_to_camera [4, 4] (any float dtype; may require grad) and the pinhole
    intrinsics and image size of the camera ``intrinsics`` (its own pose is not read).

    The per-Gaussian geometry is computed in float64 whatever the model's dtype (it is O(N)
    and cheap next to compositing): squared pixel covariances of huge or very close Gaussians
    (1e5-unit scales at the near plane) overflow float32, and far-from-origin scenes cancel.
    Results are returned in the model's dtype.

    backend: "torch" (this function's vectorised reference), "numba" (the fused CPU kernels of
    :mod:`.projection_numba`: same rules, but ``cov2d`` and ``extents`` carry no gradient and the
    pose must not require one) or "auto" (numba when it imports, the tensors are on the CPU and
    neither of those gradients can be needed, i.e. the pose does not require grad).
    """
    pose_needs_grad = isinstance(world_to_camera, torch.Tensor) and world_to_camera.requires_grad
    if use_numba(backend, "projection", means, auto_allowed=not pose_needs_grad):
        if pose_needs_grad:
            raise ValueError("projection backend 'numba' does not differentiate the pose; use 'torch' or 'auto'")
        return _project_numba(means, log_scales, quats, opacity_logits, world_to_camera, intrinsics)
    dtype = means.dtype
    f64 = torch.float64
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    width, height = intrinsics.width, intrinsics.height

    # A non-finite centre is culled. It enters the arithmetic as the origin, so that no 0 x NaN
    # reaches a gradient: its own scale and rotation, and above all the pose, which every row
    # shares (one NaN centre would otherwise make Langevin's pose gradient NaN). Its outputs are
    # set back to NaN below, as the numba path gives them.
    finite_mean = torch.isfinite(means).all(-1)
    t = camera_space_means(torch.where(finite_mean[:, None], means, torch.zeros_like(means)), world_to_camera)
    tz = t[:, 2]
    in_depth_range = depth_in_range(tz)
    # Culled Gaussians still flow through the arithmetic below; a safe depth keeps their
    # values finite so no NaN can leak into gradients through torch.where.
    z = torch.where(in_depth_range, tz, torch.ones_like(tz))
    ratio_x, ratio_y = t[:, 0] / z, t[:, 1] / z
    means2d = torch.stack([fx * ratio_x + cx, fy * ratio_y + cy], dim=-1)

    lo_x, hi_x, lo_y, hi_y = view_ratio_bounds(intrinsics)
    clamped_x = torch.clamp(ratio_x, lo_x, hi_x)
    clamped_y = torch.clamp(ratio_y, lo_y, hi_y)
    zeros = torch.zeros_like(z)
    jacobian = torch.stack([
        torch.stack([fx / z, zeros, -fx * clamped_x / z], -1),
        torch.stack([zeros, fy / z, -fy * clamped_y / z], -1),
    ], -2)  # [N, 2, 3]

    rotation_cam = world_to_camera[:3, :3].to(f64)
    scaled_axes = quat_to_rotation(quats.to(f64)) * scales_from_log(log_scales.to(f64))[:, None, :]  # R diag(s): [N, 3, 3]
    # M = J W R diag(s), so cov2d (before dilation) = M M^T exactly and symmetric.
    m = jacobian @ (rotation_cam @ scaled_axes)  # [N, 2, 3]
    row0, row1 = m[:, 0], m[:, 1]
    xx = (row0 * row0).sum(-1)
    xy = (row0 * row1).sum(-1)
    yy = (row1 * row1).sum(-1)
    # det(M M^T) = |row0 x row1|^2 (Lagrange identity): never negative and free of the
    # xx*yy - xy^2 cancellation that destroys it for needle-like Gaussians in float32.
    det_core = (torch.linalg.cross(row0, row1) ** 2).sum(-1)
    det = det_core + DILATION_PX * (xx + yy) + DILATION_PX * DILATION_PX
    xx = xx + DILATION_PX
    yy = yy + DILATION_PX
    cov2d = torch.stack([xx, xy, yy], -1)

    opacities = opacities_from_logits(opacity_logits)
    extents = torch.sqrt(2.0 * footprint_level(opacities.to(f64))[:, None] * torch.stack([xx, yy], -1))

    visible = finite_mean & in_depth_range & (det >= DET_MIN) & torch.isfinite(det) & (opacities >= ALPHA_MIN)
    visible &= torch.isfinite(means2d).all(-1) & torch.isfinite(extents).all(-1)
    ext = extents.detach()
    mean = means2d.detach()
    visible &= (mean[:, 0] + ext[:, 0] > 0) & (mean[:, 0] - ext[:, 0] < width)
    visible &= (mean[:, 1] + ext[:, 1] > 0) & (mean[:, 1] - ext[:, 1] < height)

    # det >= DET_MIN > 0 on visible Gaussians; the others get 1 so the inverse stays finite.
    safe_det = torch.where(visible, det, torch.ones_like(det))
    conics = torch.stack([yy / safe_det, -xy / safe_det, xx / safe_det], -1)
    radii = torch.where(visible, torch.ceil(ext.max(-1).values.nan_to_num(0.0)), torch.zeros_like(det))

    def nan_where_not_finite(values: torch.Tensor) -> torch.Tensor:
        # A constant branch: no gradient reaches the culled row through it.
        return torch.where(finite_mean[:, None], values, torch.full_like(values, float("nan"))).to(dtype)

    return Projection(
        camera_means=nan_where_not_finite(t),
        means2d=nan_where_not_finite(means2d),
        cov2d=nan_where_not_finite(cov2d),
        conics=nan_where_not_finite(conics),
        opacities=opacities,
        extents=nan_where_not_finite(extents),
        visible=visible,
        radii=radii.to(torch.int64),
    )


def view_ratio_bounds(intrinsics: Camera) -> tuple[float, float, float, float]:
    """(lo_x, hi_x, lo_y, hi_y): the range of t.x / z and t.y / z the EWA Jacobian is evaluated
    within, the field of view widened on each side by (FRUSTUM_CLAMP_MARGIN - 1) x half the
    image's angular width."""
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    widen_x = (FRUSTUM_CLAMP_MARGIN - 1.0) * 0.5 * intrinsics.width / fx
    widen_y = (FRUSTUM_CLAMP_MARGIN - 1.0) * 0.5 * intrinsics.height / fy
    return (-cx / fx - widen_x, (intrinsics.width - cx) / fx + widen_x,
            -cy / fy - widen_y, (intrinsics.height - cy) / fy + widen_y)


def _project_numba(means, log_scales, quats, opacity_logits, world_to_camera, intrinsics: Camera) -> Projection:
    """The same projection by the numba kernels of :mod:`.projection_numba` (pose without grad)."""
    from .projection_numba import project_numba
    opacities = opacities_from_logits(opacity_logits)
    pose = torch.as_tensor(world_to_camera).detach().cpu().to(torch.float64).numpy()
    t, means2d, conics, cov2d, extents, visible, radii = project_numba(
        means, log_scales, quats, opacities, pose, intrinsics, view_ratio_bounds(intrinsics))
    return Projection(camera_means=t, means2d=means2d, cov2d=cov2d, conics=conics, opacities=opacities,
                      extents=extents, visible=visible, radii=radii)


def plane_normals(quats: torch.Tensor, log_scales: torch.Tensor, world_to_camera: torch.Tensor,
                  camera_means: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """PGSR planar normal and plane offset per Gaussian.

    quats [N, 4], log_scales [N, 3], world_to_camera [4, 4], camera_means t [N, 3] ->
    (normals [N, 3] camera-space unit axis of the smallest scale, flipped so n . t <= 0,
    i.e. facing the camera; offsets [N] = n . t, the plane n . x = offset through the mean).
    A pixel ray x = z * K^-1 [u, v, 1] meets that plane at z = offset / (n . K^-1 [u, v, 1]).
    """
    dtype = camera_means.dtype
    rotation = quat_to_rotation(quats)  # [N, 3, 3], columns are the local axes
    smallest = torch.argmin(log_scales.detach(), dim=-1)  # [N]
    axis = torch.gather(rotation, 2, smallest[:, None, None].expand(-1, 3, 1))[..., 0]  # [N, 3]
    normal = axis @ world_to_camera[:3, :3].to(dtype).T
    facing = (normal * camera_means).sum(-1, keepdim=True)
    normal = torch.where(facing > 0, -normal, normal)
    return normal, (normal * camera_means).sum(-1)
