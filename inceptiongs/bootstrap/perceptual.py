"""The perceptual branch of the virtual-view loss.

With user-given LPIPS weights (plain tensors in the project's own AlexNet-LPIPS network,
inceptiongs.evaluation.lpips_net.load_lpips) the distance is LPIPS. Without them no learned
perceptual metric exists here (no weights can be downloaded), so the fallback is a
weight-free distance named for what it is, "MS-SSIM-G":

    d = 0.5 * (1 - mean_s SSIM_s(a, b)) + 0.5 * (1 - mean GMS(a, b))

- SSIM_s: SSIM (inceptiongs.evaluation.metrics, 11-tap Gaussian window) at scales s = 0, 1, 2 (2x2 average
  pooling between scales, only while the image still holds a window), equal weights. Coarse
  scales compare structure rather than exact pixels, which is what a generated image and a
  render can share.
- GMS: the gradient-magnitude similarity of Xue et al. (GMSD, 2014), (2 g_a g_b + c) /
  (g_a^2 + g_b^2 + c) per pixel and channel, g the central-difference gradient magnitude, so
  blur (lost edges) and noise (false edges) are both penalised.

Both terms are 0 for identical images and at most 1 (SSIM and GMS are in [-1, 1] resp.
[0, 1]); d is differentiable with finite gradients everywhere. It is *not* LPIPS and the
docs and outputs never call it that: :func:`perceptual_name` says which one ran.
"""

from __future__ import annotations

from typing import Callable

import torch
import torch.nn.functional as F

from ..evaluation.metrics import ssim

PERCEPTUAL_NAME = "MS-SSIM-G"   # the weight-free distance
LPIPS_NAME = "LPIPS"
# Scales of the SSIM term (full, 1/2, 1/4 resolution): three octaves reach structures of
# ~40 px, enough for the patch-level agreement the loss asks of generated images.
MS_SCALES = 3
SSIM_WINDOW = 11
# GMS stabiliser: GMSD's T = 170 for 8-bit images, rescaled to [0, 1] intensities (170 / 255^2).
# It keeps the ratio defined where both gradients vanish and damps differences between
# gradients far below visible contrast.
GMS_C = 170.0 / 255.0 ** 2
# Added under the square root of the gradient magnitude so it is differentiable at 0
# (d g / d grad = grad / g stays bounded by 1).
_GRAD_EPS = 1e-12


def perceptual_name(lpips: Callable | None = None) -> str:
    """'LPIPS' when an LPIPS callable is given, else 'MS-SSIM-G'."""
    return LPIPS_NAME if lpips is not None else PERCEPTUAL_NAME


def _to_batch(image: torch.Tensor) -> torch.Tensor:
    """[H, W, 3] -> [1, 3, H, W]."""
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"expected an image [H, W, 3], got {tuple(image.shape)}")
    return image.permute(2, 0, 1)[None]


def ms_ssim_dissimilarity(a: torch.Tensor, b: torch.Tensor, scales: int = MS_SCALES) -> torch.Tensor:
    """1 - mean over scales of SSIM: a, b [1, 3, H, W] -> scalar. Needs H, W >= SSIM_WINDOW."""
    if min(a.shape[-2:]) < SSIM_WINDOW:
        raise ValueError(f"image {tuple(a.shape[-2:])} is smaller than the SSIM window {SSIM_WINDOW}")
    values = []
    for level in range(scales):
        if level > 0:
            if min(a.shape[-2:]) < 2 * SSIM_WINDOW:
                break
            a, b = F.avg_pool2d(a, 2), F.avg_pool2d(b, 2)
        values.append(ssim(a, b, window=SSIM_WINDOW)[0])
    return 1.0 - torch.stack(values).mean()


def gradient_magnitude(x: torch.Tensor) -> torch.Tensor:
    """Central-difference gradient magnitude on the interior: [B, C, H, W] -> [B, C, H-2, W-2]."""
    gx = 0.5 * (x[..., 1:-1, 2:] - x[..., 1:-1, :-2])
    gy = 0.5 * (x[..., 2:, 1:-1] - x[..., :-2, 1:-1])
    return torch.sqrt(gx * gx + gy * gy + _GRAD_EPS)


def gradient_dissimilarity(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """1 - mean GMS: a, b [1, 3, H, W] (H, W >= 3) -> scalar in [0, 1]."""
    ga, gb = gradient_magnitude(a), gradient_magnitude(b)
    # Denominator >= GMS_C > 0.
    similarity = (2.0 * ga * gb + GMS_C) / (ga * ga + gb * gb + GMS_C)
    return 1.0 - similarity.mean()


def perceptual_distance(a: torch.Tensor, b: torch.Tensor, lpips: Callable | None = None) -> torch.Tensor:
    """Perceptual distance between two images a, b [H, W, 3] in [0, 1]: scalar tensor,
    differentiable in both.

    lpips: a callable (pred, target) on [1, 3, H, W] in [-1, 1] -> distance (the convention of
    inceptiongs.evaluation.run); without it the weight-free MS-SSIM-G (module doc).
    """
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {tuple(a.shape)} vs {tuple(b.shape)}")
    a_b, b_b = _to_batch(a), _to_batch(b.to(a))
    if lpips is not None:
        out = lpips(a_b * 2.0 - 1.0, b_b * 2.0 - 1.0)
        out = torch.as_tensor(out)
        return out.reshape(()) if out.numel() == 1 else out.mean()
    return 0.5 * ms_ssim_dissimilarity(a_b, b_b) + 0.5 * gradient_dissimilarity(a_b, b_b)
