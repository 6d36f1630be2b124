"""Pinhole camera maths on torch tensors: pixel centres, depth -> camera-space points, points ->
pixels, the pose between two cameras. OpenCV axes; pixel (i, j) samples (i + 0.5, j + 0.5)."""

from __future__ import annotations

import numpy as np
import torch

from .camera import Camera
from .constants import NEAR_PLANE


def pixel_centres(width: int, height: int, dtype=torch.float64, device=None) -> torch.Tensor:
    """[h, w, 2] continuous (u, v) of pixel centres: pixel (i, j) is (i + 0.5, j + 0.5)."""
    v, u = torch.meshgrid(torch.arange(height, dtype=dtype, device=device) + 0.5,
                          torch.arange(width, dtype=dtype, device=device) + 0.5, indexing="ij")
    return torch.stack([u, v], dim=-1)


def unproject(depth: torch.Tensor, camera: Camera) -> torch.Tensor:
    """depth: [h, w] camera z -> camera-space points [h, w, 3] (z = depth; fx, fy > 0)."""
    uv = pixel_centres(camera.width, camera.height, depth.dtype, depth.device)
    x = (uv[..., 0] - camera.cx) / camera.fx * depth
    y = (uv[..., 1] - camera.cy) / camera.fy * depth
    return torch.stack([x, y, depth], dim=-1)


def relative_pose(src_cam: Camera, dst_cam: Camera) -> np.ndarray:
    """[4, 4] float64 taking destination-camera points to source-camera points."""
    return src_cam.world_to_camera @ dst_cam.camera_to_world


def project(points: torch.Tensor, camera: Camera) -> torch.Tensor:
    """Camera-space points [..., 3] -> continuous pixel coordinates [..., 2].

    Where z <= NEAR_PLANE the result is a placeholder (the divide uses 1 there so nothing is
    inf/NaN); callers must mask those points out.
    """
    z = points[..., 2]
    safe_z = torch.where(z > NEAR_PLANE, z, torch.ones_like(z))
    u = camera.fx * points[..., 0] / safe_z + camera.cx
    v = camera.fy * points[..., 1] / safe_z + camera.cy
    return torch.stack([u, v], dim=-1)
