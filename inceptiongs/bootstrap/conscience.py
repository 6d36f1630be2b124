"""The refinement's conscience: the real photos nearest the targets must not get worse.

Virtual views pull the Gaussians towards I*, which is only as good as the photos and the
prior behind it. The training photos nearest the flagged views see much of the same surface
and are ground truth, so their photometric loss is the check: measured at the start of stage
II (the baseline) and every few steps after. When it rises above the baseline by more than
``tolerance`` (relative), the virtual views' weight is halved; when it is back within half the
tolerance, the weight recovers (x1.25 per check, at most 1). Every check is logged, so the
curve can be plotted next to the held-out scores.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import torch

from ..camera import Camera

# A 5 % rise of the nearest photos' L1 is well above the step-to-step noise of a converged
# stage I (~1 % on the demo) and well below what a contradicting target does within 25 steps.
DEFAULT_TOLERANCE = 0.05
BACKOFF = 0.5
RECOVERY = 1.25
# The weight never reaches 0: the virtual views keep a voice, so the loss can recover and the
# weight with it.
MIN_SCALE = 1.0 / 64.0


@dataclass
class Conscience:
    """The virtual-view weight ``scale`` in [MIN_SCALE, 1] driven by the photo loss; ``history``
    holds (step, loss, scale) of every check."""

    tolerance: float = DEFAULT_TOLERANCE
    baseline: float | None = None
    scale: float = 1.0
    history: list[tuple[int, float, float]] = field(default_factory=list)

    def update(self, step: int, loss: float) -> float:
        """Record the photo loss at ``step``; -> the new virtual-view scale."""
        if self.baseline is None:
            self.baseline = loss
        elif loss > self.baseline * (1.0 + self.tolerance):
            self.scale = max(MIN_SCALE, self.scale * BACKOFF)
        elif loss <= self.baseline * (1.0 + 0.5 * self.tolerance):
            self.scale = min(1.0, self.scale * RECOVERY)
        self.history.append((step, loss, self.scale))
        return self.scale


def photo_loss(rasterizer: Callable, gaussians, cameras: Sequence[Camera], photos: dict[int, torch.Tensor],
               views: Sequence[int], sh_degree: int | None = None) -> float:
    """Mean L1 between the renders of ``views`` and their photos [H, W, 3] (no gradient)."""
    if not views:
        return 0.0
    total = 0.0
    with torch.no_grad():
        for view in views:
            rgb = rasterizer(gaussians, cameras[view], outputs=("rgb",), sh_degree=sh_degree)["rgb"]
            total += float((rgb.float() - photos[view].float()).abs().mean())
    return total / len(views)
