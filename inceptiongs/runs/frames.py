"""A model between the scene's normalised frame (training) and the user's original one (exports)."""

from __future__ import annotations

import math

import torch

from ..gaussians import Gaussians


def _log_scale_factor(scale: float) -> float:
    if not scale > 0 or not math.isfinite(scale):
        raise ValueError(f"scene normalisation scale must be positive and finite, got {scale}")
    return math.log(scale)


def to_original_frame(gaussians: Gaussians, normalization) -> Gaussians:
    """Normalised frame (x_n = (x - c) s) -> original: x = x_n / s + c; log scales - log s.

    Uses ``normalization.gaussians_to_original`` when the scene module provides it.
    """
    if hasattr(normalization, "gaussians_to_original"):
        return normalization.gaussians_to_original(gaussians)
    scale = float(normalization.scale)
    center = torch.as_tensor(normalization.center, dtype=gaussians.dtype)
    return Gaussians(gaussians.means / scale + center, gaussians.log_scales - _log_scale_factor(scale),
                     gaussians.quats, gaussians.opacity_logits, gaussians.sh)


def to_normalized_frame(gaussians: Gaussians, normalization) -> Gaussians:
    if hasattr(normalization, "gaussians_to_normalized"):
        return normalization.gaussians_to_normalized(gaussians)
    scale = float(normalization.scale)
    center = torch.as_tensor(normalization.center, dtype=gaussians.dtype)
    return Gaussians((gaussians.means - center) * scale, gaussians.log_scales + _log_scale_factor(scale),
                     gaussians.quats, gaussians.opacity_logits, gaussians.sh)
