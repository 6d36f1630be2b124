"""The inpainting fill (the variant "inpaint", off by default): the photos' blend carried into the
pixels no photo reaches, by classical inpainting (OpenCV Telea).

Measured: +0.76 / -0.12 dB (scarce / covered) on the courtyard against the same-time baseline,
but -6 dB on the objects demo (bench_supervision: 25.69 -> 19.54), where it smears the photos
over large uncovered areas (docs/bootstrap.md), so the render fills by default.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from ...errors import InputError
from ..variants import Variant

# Inpainting radius in pixels (OpenCV Telea): the neighbourhood a missing pixel is filled from.
INPAINT_RADIUS = 3


def inpaint(image: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """Fill the pixels where ``known`` [h, w] is False from their known neighbours (OpenCV's
    Telea inpainting). image [h, w, 3] in [0, 1] -> [h, w, 3] float32; unchanged if nothing is
    known (nothing to propagate) or nothing is missing."""
    import cv2

    known_np = known.cpu().numpy().astype(bool)
    if known_np.all() or not known_np.any():
        return image.float().clone()
    rgb = (image.detach().float().clamp(0, 1).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
    filled = cv2.inpaint(rgb, (~known_np).astype(np.uint8), INPAINT_RADIUS, cv2.INPAINT_TELEA)
    return torch.as_tensor(filled.astype(np.float32) / 255.0)


def inpaint_fill(image: torch.Tensor, mask: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """The blend ``image`` [H, W, 3] carried into the pixels no photo reaches (mask [H, W, 1] 0)
    where the view has depth (``depth`` [H, W, 1] > 0)."""
    return inpaint(image, (mask[..., 0] > 0) | (depth[..., 0] <= 0))


@dataclass(frozen=True)
class Inpaint(Variant):
    """The photos' blend inpainted where no photo reaches, over the render's fill (with the
    variant photo_supervision: its inpainting fill)."""

    NAME: ClassVar[str] = "inpaint"

    def check(self, source: str, config) -> None:
        if config.fill != "render":
            raise InputError(f"{source}: the inpainting is the fill: it needs fill \"render\", got {config.fill!r}")

    def finish_blend(self, image: torch.Tensor, mask: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        return inpaint_fill(image, mask, depth)
