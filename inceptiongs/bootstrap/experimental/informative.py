"""Informative virtual pixels (the variant "informative", with the variant photo_supervision
only; off by default): a virtual view's loss only where the photos contradict the render by more than they
disagree among themselves (photo_supervision.informative_mask).

Measured against the same-time baseline: +0.02 / -0.35 dB (scarce / covered) on the courtyard in
the alternating loop, up to +0.16 / -0.12 with the additive mode, and about +0.07 / -0.01 on the
objects demo (docs/bootstrap.md): below the default blend, so it stays off.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from ...errors import InputError
from ..options import VARIANT, option
from ..variants import Variant
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


@dataclass(frozen=True)
class Informative(Variant):
    """A virtual view's loss only where the photos contradict the render by more than they disagree
    among themselves: the photo supervision returns that informative mask as the view's mask
    (photo_supervision.informative_mask), a view with fewer than 16 such pixels is not sampled,
    and the loss is the mask-weighted L1 of 5 x 5 box means (informative.informative_loss)."""

    NAME: ClassVar[str] = "informative"
    REQUIRES: ClassVar[tuple[str, ...]] = ("photo_supervision",)

    residual_floor: float | None = option(None, "the smallest photo - render residual that counts (null: "
                                                "photo_supervision.RESIDUAL_FLOOR, 4/255); higher keeps only "
                                                "grossly wrong pixels", "colour, in [0, 1]", VARIANT)

    def check(self, source: str, config) -> None:
        if self.residual_floor is not None and not self.residual_floor >= 0:
            raise InputError(f"{source}: residual_floor must be >= 0, got {self.residual_floor}")

    def may_sample(self, view) -> bool:
        return float(view.mask.sum()) >= MIN_INFORMATIVE_PIXELS

    def pixel_weights(self, mask: torch.Tensor, weights: torch.Tensor | None) -> torch.Tensor:
        return mask        # the informative mask itself: no weight elsewhere

    def colour_loss(self, rgb: torch.Tensor, target: torch.Tensor, weights: torch.Tensor) -> tuple[torch.Tensor, dict]:
        return informative_loss(rgb, target, weights)
