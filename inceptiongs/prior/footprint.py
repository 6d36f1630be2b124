"""How much memory the tiny prior's work needs, estimated before anything of that size is
allocated, so a size no machine can hold (a denoiser a million channels wide, a batch of a
hundred million patches, a MultiDiffusion window of 8192 pixels) is refused with one line
(InputError, exit status 2) instead of a traceback or a process that grows until it is killed.

The denoiser's size is measured, not modelled: it is built on torch's "meta" device (shapes
only, no memory) and run once on a small probe, which gives its parameter count and the floats
its layers output per pixel; both scale exactly with the batch and the pixels, so the estimate
for any patch, batch or window follows without building anything real.
"""

from __future__ import annotations

import functools
from dataclasses import astuple, dataclass

import torch

from ..constants import RENDER_BYTES_PER_PIXEL
from ..io.limits import check_allocation
from .controlnet import ConditionalDenoiser
from .unet import UNetConfig

FLOAT_BYTES = 4
# Training holds each parameter four times (weights, gradients, Adam's two moments) and each
# layer output about three times (the output kept for backward, its gradient, a working copy).
TRAINING_PARAMETER_COPIES = 4
TRAINING_ACTIVATION_COPIES = 3
# Sampling keeps no graph: the widest layer output a few times over (input, output, the UNet's
# skip connections of the level, the condition branch's residual) per window in a batch.
SAMPLING_PEAK_COPIES = 8
# Windows MultiDiffusion denoises at once (multidiffusion_sample's batch_windows).
SAMPLING_WINDOW_BATCH = 16


@dataclass(frozen=True)
class DenoiserSize:
    """parameters: the conditional denoiser's weights; floats_per_pixel: the sum of every
    layer's output per input pixel and batch item; peak_per_pixel: the largest single output."""

    parameters: int
    floats_per_pixel: float
    peak_per_pixel: float


@functools.lru_cache(maxsize=32)
def _measure(unet_fields: tuple, cond_channels: int) -> DenoiserSize:
    unet = UNetConfig(*unet_fields)
    side = 4 * unet.downsample_factor
    with torch.device("meta"):
        net = ConditionalDenoiser(unet, cond_channels)
    outputs: list[int] = []

    def record(module, inputs, output):
        if isinstance(output, torch.Tensor):
            outputs.append(output.numel())

    hooks = [m.register_forward_hook(record) for m in net.modules() if not list(m.children())]
    try:
        x = torch.empty(1, unet.image_channels, side, side, device="meta")
        net(x, torch.zeros(1, dtype=torch.long, device="meta"), torch.empty(1, cond_channels, side, side, device="meta"))
    finally:
        for hook in hooks:
            hook.remove()
    pixels = side * side
    return DenoiserSize(sum(p.numel() for p in net.parameters()), sum(outputs) / pixels,
                        max(outputs, default=0) / pixels)


def denoiser_size(unet: UNetConfig, cond_channels: int) -> DenoiserSize:
    """The measured size of a ConditionalDenoiser(unet, cond_channels) (cached per config)."""
    return _measure(astuple(unet), int(cond_channels))


def training_bytes(unet: UNetConfig, cond_channels: int, patch_size: int, batch_size: int) -> int:
    """Bytes one training step of the tiny prior needs: the denoiser's parameters with their
    gradients and Adam's moments, and per patch pixel the layer outputs kept for backward plus
    the G-buffer render of the patch."""
    size = denoiser_size(unet, cond_channels)
    pixels = int(batch_size) * int(patch_size) ** 2
    per_pixel = size.floats_per_pixel * FLOAT_BYTES * TRAINING_ACTIVATION_COPIES + RENDER_BYTES_PER_PIXEL
    return int(size.parameters * FLOAT_BYTES * TRAINING_PARAMETER_COPIES + pixels * per_pixel)


def sampling_bytes(unet: UNetConfig, cond_channels: int, height: int, width: int, window: int) -> int:
    """Bytes MultiDiffusion needs for a height x width image in windows of ``window``: the
    weights, the canvas (at least window x window) with its condition, noise sums and counts,
    the G-buffer render of the image, and a batch of windows through the denoiser."""
    size = denoiser_size(unet, cond_channels)
    canvas = max(int(height), int(window)) * max(int(width), int(window))
    canvas_floats = cond_channels + 4 * unet.image_channels + 1
    across = -(-max(int(height), int(window)) // max(1, int(window))) + 1
    windows = min(SAMPLING_WINDOW_BATCH, across * across)
    per_window = int(window) ** 2 * size.peak_per_pixel * FLOAT_BYTES * SAMPLING_PEAK_COPIES
    return int(size.parameters * FLOAT_BYTES + canvas * canvas_floats * FLOAT_BYTES
               + int(height) * int(width) * RENDER_BYTES_PER_PIXEL + windows * per_window)


def check_training_fits(unet: UNetConfig, cond_channels: int, patch_size: int, batch_size: int,
                        source: str, device=None, available: int | None = None) -> None:
    """InputError '<source>: training the prior (...) needs about N GiB of memory, only M GiB
    available' when a training step cannot fit on ``device`` (None: the system's memory)."""
    needed = training_bytes(unet, cond_channels, patch_size, batch_size)
    check_allocation(needed, source, f"training the prior (denoiser width {unet.base_width}, batch "
                                     f"{batch_size} of {patch_size}x{patch_size} patches)", available, device)


def check_sampling_fits(unet: UNetConfig, cond_channels: int, height: int, width: int, window: int,
                        source: str, device=None, available: int | None = None) -> None:
    """InputError '<source>: generating a WxH image in windows of N needs about ...' when
    MultiDiffusion cannot fit on ``device``."""
    needed = sampling_bytes(unet, cond_channels, height, width, window)
    check_allocation(needed, source, f"generating a {width}x{height} image in {window}x{window} windows",
                     available, device)
