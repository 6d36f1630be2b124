"""Informative virtual pixels (``virtual_pixels="informative"``, photo supervision only; off by
default): a virtual view's loss only where the photos contradict the render by more than they
disagree among themselves (photo_supervision.informative_mask).

Measured against the same-time baseline: +0.02 / -0.35 dB (scarce / covered) on the courtyard in
the alternating loop, up to +0.16 / -0.12 with the additive mode, and about +0.07 / -0.01 on the
objects demo (docs/bootstrap.md): below the default blend, so it stays off.
"""

from __future__ import annotations

import torch

from .photo_supervision import box_mean

# A virtual view whose informative mask sums to less than this many pixels has nothing to teach.
MIN_INFORMATIVE_PIXELS = 16.0


def informative_loss(rgb: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, dict]:
    """rgb, target [H, W, 3], mask [H, W, 1] (informative) -> (loss, record): the L1 of the box
    means (photo_supervision.box_mean, the scale the informative mask was judged at) weighted by the
    mask, averaged over all pixels like a photo's L1, so an informative pixel is pulled as a
    photo would pull it. The warps' resampling blur below that scale is not taught; SSIM and
    the perceptual branch are left out (the residual is zero outside a few pixels)."""
    l1 = (mask * (box_mean(rgb) - box_mean(target)).abs()).mean()
    value = float(l1.detach())
    return l1, {"virtual_l1": value, "virtual_loss": value, "virtual_branch": "informative_l1"}
