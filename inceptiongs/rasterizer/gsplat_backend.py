"""The gsplat rasterizer: gsplat's fused CUDA kernels behind the project's interface.

One ``gsplat.rasterization`` call composites every requested value channel at once: colour
from SH (evaluated with the project's ``sh_to_color``, so the +0.5 offset and clamp are ours),
camera z for depth, the PGSR normal and plane offset, and per-Gaussian features; the outputs are
then finished exactly as the reference finishes them (background, depth / alpha, plane depth).
Scales and opacities go in post-activation with the reference's clamps; quaternions are
w, x, y, z as gsplat expects; the near/far planes and the 2-D dilation come from
:mod:`inceptiongs.constants`.

Gaussians on the CPU are moved to the GPU for the call and the outputs moved back (autograd
flows through both moves); ``means2d`` is a leaf on the Gaussians' device whose ``.grad`` a hook
fills from gsplat's means2d gradient, so the densifiers read it as they read the reference's.

This module imports gsplat at import time: :mod:`.interface` imports it only when gsplat is
chosen.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from gsplat import rasterization

from ..camera import Camera
from ..constants import DILATION_PX, FAR_PLANE, NEAR_PLANE
from ..gaussians import Gaussians
from .result import RenderResult
from .projection import camera_space_means, opacities_from_logits, scales_from_log
from .rasterize import check_render_args, finish_outputs, split_channels, value_channels


@dataclass(frozen=True)
class GsplatRasterizer:
    """gsplat on ``device`` (CUDA); same call and result as the reference (module docstring)."""

    name: str = "gsplat"
    device: str = "cuda"

    def __call__(self, gaussians: Gaussians, camera: Camera, outputs: Sequence[str] = ("rgb",),
                 background=None, features: torch.Tensor | None = None, sh_degree: int | None = None,
                 world_to_camera: torch.Tensor | None = None) -> RenderResult:
        outputs = tuple(outputs)
        check_render_args(outputs, features, len(gaussians))
        home, dtype = gaussians.device, gaussians.dtype
        target = home if home.type == torch.device(self.device).type else torch.device(self.device)
        g = _to_device(gaussians, target)
        if world_to_camera is None:
            world_to_camera = torch.as_tensor(camera.world_to_camera, dtype=torch.float64, device=target)
        pose = world_to_camera.to(target)
        degree = g.sh_degree if sh_degree is None else max(0, min(sh_degree, g.sh_degree))
        t = camera_space_means(g.means, pose).to(dtype)
        every = torch.arange(len(g), device=target)
        channels = value_channels(g, every, t, outputs, None if features is None else features.to(target),
                                   degree, pose, backend="torch")
        image, alpha, meta = _composite(g, pose, camera, channels, dtype)
        out = finish_outputs(outputs, split_channels(image, channels), alpha, background, camera, dtype, target)
        result = {name: value.to(home) for name, value in out.items()}
        return RenderResult(means2d=_means2d_on(meta["means2d"], home),
                            radii=meta["radii"][0].amax(-1).to(torch.int64).to(home), **result)


def _to_device(gaussians: Gaussians, device: torch.device) -> Gaussians:
    if gaussians.device == device:
        return gaussians
    return Gaussians(*(t.to(device) for t in (gaussians.means, gaussians.log_scales, gaussians.quats,
                                               gaussians.opacity_logits, gaussians.sh)))


def gsplat_inputs(g: Gaussians, pose: torch.Tensor, camera: Camera) -> dict[str, torch.Tensor]:
    """gsplat's scene and camera arguments, float32 on the Gaussians' device: means [N, 3], quats
    [N, 4] (w, x, y, z; gsplat normalises), scales [N, 3] and opacities [N] post-activation with
    the reference's clamps, viewmats [1, 4, 4] world-to-camera, Ks [1, 3, 3] (pixel centres at
    i + 0.5 in both)."""
    return {"means": g.means.float(), "quats": g.quats.float(),
            "scales": scales_from_log(g.log_scales).float(),
            "opacities": opacities_from_logits(g.opacity_logits).float(),
            "viewmats": pose.float()[None],
            "Ks": torch.tensor(camera.intrinsics, dtype=torch.float32, device=g.device)[None]}


def _composite(g: Gaussians, pose: torch.Tensor, camera: Camera, channels: list[tuple[str, torch.Tensor]],
               dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """gsplat's unpacked rasterization of the value channels [N, C] -> (image [H, W, C],
    alpha [H, W, 1], gsplat's meta). With no channel, one zero channel is composited for alpha."""
    values = torch.cat([v for _, v in channels], dim=1) if channels else torch.zeros(
        len(g), 1, dtype=dtype, device=g.device)
    colors, alphas, meta = rasterization(
        colors=values.float(), width=camera.width, height=camera.height, render_mode="RGB",
        near_plane=NEAR_PLANE, far_plane=FAR_PLANE, eps2d=DILATION_PX, packed=False,
        **gsplat_inputs(g, pose, camera))
    image = colors[0].to(dtype)
    if not channels:
        image = image[..., :0]
    return image, alphas[0].to(dtype), meta


def _means2d_on(means2d: torch.Tensor, home: torch.device) -> torch.Tensor:
    """gsplat's means2d [1, N, 2] as [N, 2] on ``home``: a leaf whose ``.grad`` a hook fills from
    gsplat's means2d gradient (accumulated like a leaf's), since neither a slice of gsplat's
    tensor nor a copy on another device lies on the path to the loss."""
    proxy = means2d.detach()[0].to(home)
    if not means2d.requires_grad:
        return proxy
    proxy.requires_grad_(True)

    def copy_grad(grad: torch.Tensor) -> None:
        grad = grad[0].to(home)
        proxy.grad = grad if proxy.grad is None else proxy.grad + grad

    means2d.register_hook(copy_grad)
    return proxy
