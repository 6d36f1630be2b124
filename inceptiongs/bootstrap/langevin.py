"""View-adaptive sampling (the paper's Algorithm 1): Langevin steps over a 7-D camera pose.

The pose vector is ``[c_x, c_y, c_z, q_w, q_x, q_y, q_z]``: the camera centre in world
coordinates and the unit quaternion (w >= 0) of the world-to-camera rotation. The chain
climbs log P with P = exp(L1(render, I*)), i.e. log P is the L1 error between the current
render and the blended target image I* of a virtual view, so it drifts towards the views
that are still worst; exploration noise keeps it moving. Each sample is snapped to the
nearest virtual view, which is the one refined next; that view's update is divided by P
(weight exp(-L1) in (0, 1]) so that being sampled often does not also mean being pushed hard.

Update (unadjusted Langevin):  x <- x + step * grad log P + sqrt(2 * step) * noise_scale * xi,
xi ~ N(0, I_7); the quaternion part is then renormalised and put back on the w >= 0
hemisphere (q and -q are the same rotation). The stationary density of this chain is
proportional to P^(1 / noise_scale^2) = exp(L1 / noise_scale^2): noise_scale^2 is the
temperature.

The pose gradient comes from autograd through inceptiongs.rasterizer.rasterize.render(world_to_camera=...)
(:func:`pose_gradient`) or from central finite differences (:func:`pose_gradient_fd`), which
the tests check against each other.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import torch

from ..camera import quat_normalize, rotation_to_quat, unit_quat_to_rotation

# Step size of the drift, in (scene units)^2 per unit of log P. Normalised scenes have a rig
# radius of 1, and the L1 pose gradient is of order 0.1 - 1 per unit, so one step drifts by
# ~1e-3 - 1e-2: small next to the virtual views' spacing (tenths of a unit), as Langevin
# needs for the discretisation to follow the density.
DEFAULT_STEP_SIZE = 0.01
# Temperature noise_scale^2 = 0.04: an L1 difference of 0.05 between two views (a repaired
# vs a broken one) then makes the worse one exp(0.05 / 0.04) ~ 3.5 times as likely, a clear
# preference that still visits every view. Per step the noise moves ~0.03 units / ~3 degrees.
DEFAULT_NOISE_SCALE = 0.2
# Central-difference step for pose_gradient_fd. The rasterizer is only piecewise smooth in
# the pose (a Gaussian's alpha crossing the 1/255 skip threshold at a pixel is a jump of
# ~1/255 there), so a larger step straddles more jumps; a smaller one loses digits to
# rounding (~1e-16 / eps relative in float64, ~1e-7 / eps in float32). 1e-4 is usable for
# float32 scenes (the gradient is then good to a few percent); the float64 check in the
# tests uses 1e-7.
DEFAULT_FD_EPS = 1e-4
# Radians weigh like scene units, as in camera.pose_distance's default.
DEFAULT_ROTATION_WEIGHT = 1.0

RenderLossFn = Callable[[torch.Tensor], torch.Tensor]


def pose_to_vector(world_to_camera) -> np.ndarray:
    """world_to_camera [4, 4] (numpy or torch) -> [7] float64: centre + quaternion (w >= 0)."""
    pose = world_to_camera.detach().cpu().numpy() if isinstance(world_to_camera, torch.Tensor) \
        else np.asarray(world_to_camera)
    pose = pose.astype(np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"world_to_camera must be [4, 4], got {pose.shape}")
    rotation = pose[:3, :3]
    centre = -rotation.T @ pose[:3, 3]
    return np.concatenate([centre, rotation_to_quat(rotation)])


def quat_to_rotation_differentiable(q: torch.Tensor) -> torch.Tensor:
    """q: [4] (w, x, y, z), any non-zero norm -> [3, 3], differentiable."""
    norm = torch.linalg.vector_norm(q)
    # A zero quaternion is no rotation; refuse it instead of dividing by 0.
    if float(norm.detach()) < 1e-12:
        raise ValueError("pose vector has a zero quaternion")
    w, x, y, z = q / norm
    return unit_quat_to_rotation(w, x, y, z, torch.stack)


def vector_to_pose(vector):
    """[7] -> world_to_camera [4, 4]. A torch input gives a differentiable torch output (the
    quaternion is normalised inside, so any non-zero quaternion is accepted); numpy gives
    numpy float64."""
    if isinstance(vector, torch.Tensor):
        if vector.shape != (7,):
            raise ValueError(f"pose vector must be [7], got {tuple(vector.shape)}")
        rotation = quat_to_rotation_differentiable(vector[3:])
        top = torch.cat([rotation, (-rotation @ vector[:3])[:, None]], dim=1)
        bottom = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=vector.dtype, device=vector.device)
        return torch.cat([top, bottom], dim=0)
    return vector_to_pose(torch.as_tensor(np.asarray(vector, dtype=np.float64))).numpy()


def _canonical_quaternion(q: np.ndarray) -> np.ndarray:
    """Unit quaternion [4] on the w >= 0 hemisphere."""
    q = quat_normalize(q)
    return -q if q[0] < 0 else q


def langevin_step(pose7, grad_log_p, step_size: float = DEFAULT_STEP_SIZE,
                  noise_scale=DEFAULT_NOISE_SCALE, rng: np.random.Generator | None = None) -> np.ndarray:
    """One Langevin ascent step on log P: [7] -> [7] (see the module doc).

    noise_scale: a scalar or [7] (e.g. different scales for centre and quaternion);
    rng: numpy Generator (required when any noise scale is non-zero). If the step would land
    on a zero quaternion (probability zero, but possible by hand) the previous rotation is kept.
    """
    pose = np.asarray(pose7, dtype=np.float64)
    grad = np.asarray(grad_log_p, dtype=np.float64)
    if pose.shape != (7,) or grad.shape != (7,):
        raise ValueError(f"pose and gradient must be [7], got {pose.shape} and {grad.shape}")
    if not (math.isfinite(step_size) and step_size > 0):
        raise ValueError(f"step_size must be positive, got {step_size}")
    scale = np.broadcast_to(np.asarray(noise_scale, dtype=np.float64), (7,))
    if np.any(scale < 0) or not np.all(np.isfinite(scale)):
        raise ValueError(f"noise_scale must be finite and >= 0, got {noise_scale}")
    if not np.all(np.isfinite(grad)):
        raise ValueError("grad_log_p is not finite")
    noise = np.zeros(7)
    if np.any(scale > 0):
        if rng is None:
            raise ValueError("langevin_step needs an rng when noise_scale > 0")
        noise = rng.standard_normal(7) * scale
    moved = pose + step_size * grad + math.sqrt(2.0 * step_size) * noise
    quat = moved[3:]
    if np.linalg.norm(quat) < 1e-12:
        quat = pose[3:]
    return np.concatenate([moved[:3], _canonical_quaternion(quat)])


def pose_vector_distance(pose7, poses, rotation_weight: float = DEFAULT_ROTATION_WEIGHT) -> np.ndarray:
    """camera.pose_distance on pose vectors: |c - c_v| + w * angle, [7] x [V, 7] -> [V].

    The geodesic angle between rotations is 2 acos(|<q, q_v>|) (|.| because q ~ -q).
    """
    pose = np.asarray(pose7, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
    q = quat_normalize(pose[3:])
    qs = quat_normalize(poses[:, 3:])
    # Rounding can push |<q, q_v>| a hair above 1; clip before acos.
    angle = 2.0 * np.arccos(np.clip(np.abs(qs @ q), 0.0, 1.0))
    return np.linalg.norm(poses[:, :3] - pose[:3], axis=1) + rotation_weight * angle


def snap_to_nearest(pose7, virtual_poses, rotation_weight: float = DEFAULT_ROTATION_WEIGHT) -> int:
    """Index of the virtual pose [V, 7] nearest to pose7 [7] (ties -> lowest index)."""
    poses = np.asarray(virtual_poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 7 or len(poses) == 0:
        raise ValueError(f"virtual_poses must be a non-empty [V, 7], got {poses.shape}")
    return int(np.argmin(pose_vector_distance(pose7, poses, rotation_weight)))


def l1_log_p(render_rgb: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """log P = mean |render - I*| (P = exp(L1), the paper's choice): scalar, differentiable."""
    if render_rgb.shape != target.shape:
        raise ValueError(f"render {tuple(render_rgb.shape)} and target {tuple(target.shape)} differ")
    return (render_rgb - target.to(render_rgb)).abs().mean()


def sampling_weight(log_p: float) -> float:
    """1 / P = exp(-log P), the factor on a sampled view's update; log P = L1 >= 0, so the
    weight is in (0, 1] and exp cannot overflow."""
    return math.exp(-max(0.0, float(log_p)))


def pose_value_and_gradient(render_loss_fn: RenderLossFn, world_to_camera) -> tuple[float, np.ndarray]:
    """(log P, d log P / d pose7 [7]) by autograd through the pose.

    render_loss_fn: world_to_camera [4, 4] float64 torch tensor -> scalar tensor (e.g. the L1
    of render(gaussians, camera, world_to_camera=pose)["rgb"] against I*).
    """
    vector = torch.tensor(pose_to_vector(world_to_camera), dtype=torch.float64, requires_grad=True)
    with torch.enable_grad():
        value = render_loss_fn(vector_to_pose(vector))
        if value.ndim != 0:
            raise ValueError("render_loss_fn must return a scalar")
        (grad,) = torch.autograd.grad(value, vector, allow_unused=True)
    grad = torch.zeros(7, dtype=torch.float64) if grad is None else grad
    return float(value.detach()), grad.detach().cpu().numpy().astype(np.float64)


def pose_gradient(render_loss_fn: RenderLossFn, world_to_camera) -> np.ndarray:
    """d render_loss / d pose7: [7] float64, by autograd (see :func:`pose_value_and_gradient`)."""
    return pose_value_and_gradient(render_loss_fn, world_to_camera)[1]


def pose_gradient_fd(render_loss_fn: RenderLossFn, world_to_camera, eps: float = DEFAULT_FD_EPS) -> np.ndarray:
    """The same gradient by central finite differences over the 7 pose components: [7].

    14 loss evaluations, no autograd: the fallback where the renderer in use has no pose
    gradient. The quaternion is normalised inside vector_to_pose, so its radial component is 0.
    """
    if not (math.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be positive, got {eps}")
    base = pose_to_vector(world_to_camera)
    grad = np.zeros(7)
    with torch.no_grad():
        for k in range(7):
            step = np.zeros(7)
            step[k] = eps
            plus = float(render_loss_fn(vector_to_pose(torch.as_tensor(base + step))))
            minus = float(render_loss_fn(vector_to_pose(torch.as_tensor(base - step))))
            grad[k] = (plus - minus) / (2.0 * eps)
    return grad
