"""The appearance hint: a per-pixel MLP from the G-buffer to an RGB guess of the photo.

Why it exists: the ControlNet branch joins the denoiser through zero-initialised convolutions,
so at step 0 no gradient reaches the condition embedding or the hash grid, and later only a
trickle does. Measured on statuette (docs/prior.md), the hash features then never became
informative and the samples ignored the G-buffer. The hint is trained by a direct L1 loss
against the photo patch from the first step, which turns the hash grid into a colour field of
the scene's surfaces (a neural texture evaluated at the rendered surface points). The denoiser's
branch receives the hint (detached) beside the G-buffer, and sampling may start from it noised
to part of T (SDEdit), so the generated image follows the geometry even where the denoiser is
still weak.

1x1 convolutions only: a pixel's hint depends on that pixel's G-buffer alone, so the colour has
to live in the hash grid at the surface point (the thing that transfers to unseen views), not
in image-space context the MLP could memorise.
"""

from __future__ import annotations

import torch
from torch import nn

HINT_CHANNELS = 3
HIDDEN = 32


class AppearanceHead(nn.Module):
    """forward(G-buffer [B, Cc, H, W]) -> hint [B, 3, H, W] in (-1, 1) (the model's image range)."""

    def __init__(self, cond_channels: int, hidden: int = HIDDEN):
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(cond_channels, hidden, 1), nn.SiLU(),
                                 nn.Conv2d(hidden, hidden, 1), nn.SiLU(),
                                 nn.Conv2d(hidden, HINT_CHANNELS, 1))

    def forward(self, cond: torch.Tensor) -> torch.Tensor:
        # tanh keeps the hint in the image range with a gradient everywhere (a clamp would stop
        # learning for pixels the head overshoots).
        return torch.tanh(self.net(cond))
