"""Image quality metrics: PSNR and SSIM (differentiable, torch).

Images are either one ``[H, W, C]`` image (channels last, what the rasterizer returns) or a
batch ``[B, C, H, W]`` (channels first). Values are in [0, 1]; the peak signal is 1.

Reductions: a single image gives a scalar; a batch gives one value per image, ``[B]``.

SSIM follows Wang et al. (2004): an 11-tap Gaussian window with sigma 1.5, constants
C1 = (0.01 L)^2 and C2 = (0.03 L)^2 with L = 1, statistics from the window without
padding ("valid" filtering, as the reference implementation and scikit-image do; zero
padding would bias the border statistics), averaged over channels and positions.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

# Stabilising constants of SSIM for a dynamic range of 1 (Wang et al. 2004, K1 = 0.01,
# K2 = 0.03). They are also what keeps both SSIM denominators strictly positive.
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


def _as_tensor(image) -> torch.Tensor:
    if isinstance(image, torch.Tensor):
        return image
    return torch.as_tensor(np.asarray(image))


def _to_batch(pred, target) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """[H, W, C] or [B, C, H, W] pairs -> ([B, C, H, W], [B, C, H, W], was_single)."""
    pred, target = _as_tensor(pred), _as_tensor(target)
    if pred.shape != target.shape:
        raise ValueError(f"pred {tuple(pred.shape)} and target {tuple(target.shape)} differ in shape")
    if pred.ndim == 3:
        return pred.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None], True
    if pred.ndim == 4:
        return pred, target, False
    raise ValueError(f"expected an image [H, W, C] or a batch [B, C, H, W], got {tuple(pred.shape)}")


def _mask_to_batch(mask, shape: torch.Size, single: bool) -> torch.Tensor:
    """mask [H, W] / [H, W, 1] (single image) or [B, H, W] / [B, 1, H, W] -> [B, 1, H, W]."""
    mask = _as_tensor(mask)
    if single:
        if mask.ndim == 3:
            mask = mask[..., 0]
        mask = mask[None, None]
    elif mask.ndim == 3:
        mask = mask[:, None]
    batch, _, height, width = shape
    if tuple(mask.shape) != (batch, 1, height, width):
        raise ValueError(f"mask shape {tuple(mask.shape)} does not match the images")
    return mask


def mse(pred, target, mask=None) -> torch.Tensor:
    """Mean squared error over pixels (and channels); with ``mask`` (bool or weights >= 0)
    only where the mask is set. Scalar for one image, [B] for a batch."""
    pred_b, target_b, single = _to_batch(pred, target)
    squared = (pred_b - target_b) ** 2
    if mask is None:
        out = squared.mean(dim=(1, 2, 3))
    else:
        weights = _mask_to_batch(mask, pred_b.shape, single).to(squared.dtype)
        total = weights.sum(dim=(1, 2, 3)) * pred_b.shape[1]
        # An empty mask has no error to average; refuse rather than divide by zero.
        if bool((total <= 0).any()):
            raise ValueError("mask selects no pixels")
        out = (squared * weights).sum(dim=(1, 2, 3)) / total
    return out[0] if single else out


def psnr(pred, target, mask=None) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB for a peak of 1: 10 log10(1 / MSE).

    pred, target: [H, W, C] or [B, C, H, W] in [0, 1]; mask: [H, W] / [H, W, 1] or
    [B, H, W] / [B, 1, H, W]. Identical images give +inf (an MSE of exactly 0 is an exact
    reconstruction, not an error). Scalar for one image, [B] for a batch.
    """
    error = mse(pred, target, mask)
    # log10(0) = -inf, so an exact match yields +inf without a special case or a fake epsilon.
    return -10.0 * torch.log10(error)


def gaussian_window(window: int, sigma: float, dtype=torch.float32, device=None) -> torch.Tensor:
    """Normalised 1-D Gaussian taps: [window]. Sums to 1 (the sum is >= 1 tap, never 0)."""
    if window < 1 or window % 2 == 0:
        raise ValueError(f"SSIM window must be a positive odd number, got {window}")
    if sigma <= 0:
        raise ValueError(f"SSIM sigma must be positive, got {sigma}")
    offsets = torch.arange(window, dtype=torch.float64) - (window - 1) / 2.0
    taps = torch.exp(-(offsets ** 2) / (2.0 * sigma * sigma))
    return (taps / taps.sum()).to(dtype=dtype, device=device)


def _filter_valid(images: torch.Tensor, taps: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian filtering without padding: [B, C, H, W] -> [B, C, H-w+1, W-w+1]."""
    channels = images.shape[1]
    w = taps.shape[0]
    # Contiguous weights: expanded (stride-0) ones send conv2d down a much slower path.
    horizontal = taps.view(1, 1, 1, w).expand(channels, 1, 1, w).contiguous()
    vertical = taps.view(1, 1, w, 1).expand(channels, 1, w, 1).contiguous()
    out = F.conv2d(images, horizontal, groups=channels)
    return F.conv2d(out, vertical, groups=channels)


def ssim_map(pred, target, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Per-channel SSIM at every valid window position.

    pred, target: [H, W, C] or [B, C, H, W] in [0, 1]. Returns [C, H-w+1, W-w+1] for one image
    or [B, C, H-w+1, W-w+1] for a batch. Differentiable. Images smaller than the window are
    rejected: SSIM has no defined value there.
    """
    pred_b, target_b, single = _to_batch(pred, target)
    height, width = pred_b.shape[-2:]
    if height < window or width < window:
        raise ValueError(f"image {height}x{width} is smaller than the SSIM window {window}")
    taps = gaussian_window(window, sigma, dtype=pred_b.dtype, device=pred_b.device)
    # One grouped convolution over the five stacked moments is several times faster on a
    # CPU than five separate ones (the per-call overhead dominates at photo sizes).
    # Contiguous NCHW: a permuted [H, W, C] image is channels-last, another slow conv path.
    moments = torch.cat([pred_b, target_b, pred_b * pred_b, target_b * target_b, pred_b * target_b],
                        1).contiguous()
    mu_x, mu_y, e_xx, e_yy, e_xy = _filter_valid(moments, taps).chunk(5, dim=1)
    # Variances as E[x^2] - E[x]^2 (Wang's population form); rounding can make them a hair
    # negative, which C2 > 0 absorbs in the denominator.
    var_x = e_xx - mu_x * mu_x
    var_y = e_yy - mu_y * mu_y
    cov_xy = e_xy - mu_x * mu_y
    numerator = (2.0 * mu_x * mu_y + SSIM_C1) * (2.0 * cov_xy + SSIM_C2)
    # Both factors are >= C1 resp. >= C2 - rounding > 0: the division is safe.
    denominator = (mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (var_x + var_y + SSIM_C2)
    out = numerator / denominator
    return out[0] if single else out


def ssim(pred, target, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM (Wang et al. 2004) over channels and window positions; 1 for identical
    images. Differentiable (use ``1 - ssim`` as a loss). Scalar for [H, W, C], [B] for
    [B, C, H, W]."""
    values = ssim_map(pred, target, window, sigma)
    if values.ndim == 3:
        return values.mean()
    return values.mean(dim=(1, 2, 3))


def psnr_from_mse(value: float) -> float:
    """PSNR in dB from an MSE for a peak of 1 (math floats; +inf for 0)."""
    return math.inf if value <= 0 else -10.0 * math.log10(value)


def frechet_distance(features_a: torch.Tensor, features_b: torch.Tensor) -> float:
    """Fréchet distance between Gaussians fitted to two feature sets (the FID formula):
    |mu_a - mu_b|^2 + tr(S_a + S_b - 2 (S_a^1/2 S_b S_a^1/2)^1/2).

    features_a: [N, D], features_b: [M, D], N, M >= 2 (a covariance needs two samples).
    Computed in float64 with symmetric eigendecompositions only; eigenvalues that rounding
    pushes below zero are clamped to 0 before the square roots.
    """
    a = torch.as_tensor(features_a, dtype=torch.float64)
    b = torch.as_tensor(features_b, dtype=torch.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(f"feature sets must be [N, D] and [M, D], got {tuple(a.shape)}, {tuple(b.shape)}")
    if a.shape[0] < 2 or b.shape[0] < 2:
        raise ValueError("the Fréchet distance needs at least two samples per set")
    mean_a, mean_b = a.mean(0), b.mean(0)
    cov_a, cov_b = torch.cov(a.T).reshape(a.shape[1], -1), torch.cov(b.T).reshape(b.shape[1], -1)
    eigvals_a, eigvecs_a = torch.linalg.eigh(cov_a)
    sqrt_a = (eigvecs_a * eigvals_a.clamp_min(0).sqrt()) @ eigvecs_a.T
    middle = sqrt_a @ cov_b @ sqrt_a
    # middle is symmetric PSD; its eigenvalues' roots sum to tr(sqrt(S_a S_b)).
    trace_sqrt = torch.linalg.eigvalsh((middle + middle.T) / 2).clamp_min(0).sqrt().sum()
    value = (mean_a - mean_b).square().sum() + torch.trace(cov_a) + torch.trace(cov_b) - 2 * trace_sqrt
    return float(value)
