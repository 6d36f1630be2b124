"""Full-resolution sampling by MultiDiffusion: overlapping windows denoised at every step, averaged.

At every DDIM step each window of the current x_t is denoised on its own (with the matching
window of the condition) and the per-pixel average of the windows' noise predictions drives
the step. With eta = 0 a DDIM step is affine in eps for a fixed x_t, so averaging the
predictions equals averaging the windows' x_{t-1} (MultiDiffusion's least-squares fuse).

Windows start at 0, stride, 2*stride, ... and a last one flush with the far border, so every
pixel is covered for any size. An image smaller than the window is sampled on a canvas of
the window's size, whose extra area is conditioned on an empty G-buffer (zeros: no surface),
and cropped at the end.
"""

from __future__ import annotations

from typing import Callable

import torch
from tqdm import tqdm

from .ddim import ddim_step, ddim_timesteps, initial_state
from .schedule import NoiseSchedule

# denoiser(x_t [B,C,h,w], t [B] int64, cond [B,Cc,h,w] | None) -> eps [B,C,h,w]
Denoiser = Callable[[torch.Tensor, torch.Tensor, "torch.Tensor | None"], torch.Tensor]


def window_starts(length: int, window: int, stride: int) -> list[int]:
    """Start offsets of windows of size ``window`` covering [0, length) (length >= window)."""
    if window < 1 or stride < 1 or stride > window:
        raise ValueError(f"need 1 <= stride <= window, got window={window} stride={stride}")
    if length < window:
        raise ValueError(f"length {length} is smaller than the window {window}; pad to a canvas first")
    starts = list(range(0, length - window + 1, stride))
    if starts[-1] + window < length:
        starts.append(length - window)  # flush with the border so the last pixels are covered
    return starts


def window_boxes(height: int, width: int, window: int, stride: int) -> list[tuple[int, int]]:
    """(y0, x0) of every window on a canvas of at least window x window."""
    return [(y0, x0) for y0 in window_starts(height, window, stride) for x0 in window_starts(width, window, stride)]


def coverage(height: int, width: int, window: int, stride: int) -> torch.Tensor:
    """How many windows cover each pixel of the image: [H, W] int64 (canvas padding excluded)."""
    canvas_h, canvas_w = max(height, window), max(width, window)
    count = torch.zeros(canvas_h, canvas_w, dtype=torch.long)
    for y0, x0 in window_boxes(canvas_h, canvas_w, window, stride):
        count[y0:y0 + window, x0:x0 + window] += 1
    return count[:height, :width]


@torch.no_grad()
def multidiffusion_sample(denoiser: Denoiser, schedule: NoiseSchedule, height: int, width: int,
                          cond: torch.Tensor | None = None, channels: int = 3, window: int = 64,
                          stride: int = 48, steps: int = 20, seed: int = 0, batch_windows: int = 16,
                          device=None, dtype=torch.float32, progress: bool = False, cond_scale: int = 1,
                          clip_sample: bool = True, init: torch.Tensor | None = None,
                          start: float = 1.0) -> torch.Tensor:
    """Sample one image [1, channels, height, width] in [-1, 1] (clip_sample=False: unclipped, for latents).

    cond: [1, Cc, height * cond_scale, width * cond_scale] G-buffer or None; cond_scale > 1 when
    the sample is a latent image cond_scale times smaller than the G-buffer (the sd backend's
    VAE), so a window (y0, x0, window) takes the condition's window scaled by cond_scale.
    Deterministic for a given seed (the initial noise comes from a CPU generator; the rest is a
    fixed sequence of network evaluations). init [1, channels, height, width] and start < 1:
    start from init noised to round(start (T - 1)) instead of pure noise (SDEdit); the canvas
    padding of a small image starts from a noised zero (grey) image.
    """
    if height < 1 or width < 1:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    canvas_h, canvas_w = max(height, window), max(width, window)
    scale = int(cond_scale)
    if scale < 1:
        raise ValueError(f"cond_scale must be >= 1, got {cond_scale}")
    if cond is not None:
        if cond.ndim != 4 or cond.shape[0] != 1 or tuple(cond.shape[-2:]) != (height * scale, width * scale):
            raise ValueError(f"condition must be [1, Cc, {height * scale}, {width * scale}], got {tuple(cond.shape)}")
        cond = torch.nn.functional.pad(cond.to(device, dtype), (0, (canvas_w - width) * scale, 0, (canvas_h - height) * scale))
    boxes = window_boxes(canvas_h, canvas_w, window, stride)
    count = torch.zeros(1, 1, canvas_h, canvas_w, device=device, dtype=dtype)
    for y0, x0 in boxes:
        count[..., y0:y0 + window, x0:x0 + window] += 1.0
    # Every canvas pixel lies in >= 1 window (window_starts ends flush with the border), so the
    # average below never divides by zero.
    assert bool((count > 0).all())

    if init is not None:
        if tuple(init.shape) != (1, channels, height, width):
            raise ValueError(f"init must be [1, {channels}, {height}, {width}], got {tuple(init.shape)}")
        init = torch.nn.functional.pad(init.to(device, dtype), (0, canvas_w - width, 0, canvas_h - height))
    x = initial_state(schedule, (1, channels, canvas_h, canvas_w), seed, start, init, device, dtype)
    timesteps = ddim_timesteps(schedule, steps, start)
    for i in tqdm(range(len(timesteps)), desc="MultiDiffusion", disable=not progress, leave=False):
        t, t_prev = timesteps[i], (timesteps[i + 1] if i + 1 < len(timesteps) else None)
        eps_sum = torch.zeros_like(x)
        for first in range(0, len(boxes), batch_windows):
            chunk = boxes[first:first + batch_windows]
            x_windows = torch.cat([x[..., y0:y0 + window, x0:x0 + window] for y0, x0 in chunk])
            cond_windows = None if cond is None else torch.cat(
                [cond[..., y0 * scale:(y0 + window) * scale, x0 * scale:(x0 + window) * scale] for y0, x0 in chunk])
            t_batch = torch.full((len(chunk),), t, dtype=torch.long, device=x.device)
            eps = denoiser(x_windows, t_batch, cond_windows)
            for k, (y0, x0) in enumerate(chunk):
                eps_sum[..., y0:y0 + window, x0:x0 + window] += eps[k:k + 1]
        x = ddim_step(schedule, x, eps_sum / count, t, t_prev, clip_sample=clip_sample)
    return x[..., :height, :width]
