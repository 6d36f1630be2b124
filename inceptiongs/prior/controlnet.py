"""The ControlNet-style conditioning branch and the conditional denoiser built from it.

The branch is a copy of the UNet's encoder path (initialised from the UNet's weights, as in
ControlNet). It sees the noised image like the UNet does, plus the G-buffer embedded by a
small conv net, and hands one residual per UNet skip (and one for the middle block) to the
decoder through ZERO-INITIALISED 1x1 convolutions. Zero weights and zero biases make every
residual exactly 0 at step 0, so the conditional denoiser starts as the plain UNet; the zero
convs still receive gradients (their input is non-zero), so the condition is learnt in.
"""

from __future__ import annotations

import copy

import torch
from torch import nn
from torch.nn import functional as F

from .unet import UNet, UNetConfig, check_spatial_size


def zero_conv(in_channels: int, out_channels: int, kernel_size: int = 1) -> nn.Conv2d:
    conv = nn.Conv2d(in_channels, out_channels, kernel_size, padding=kernel_size // 2)
    nn.init.zeros_(conv.weight)
    nn.init.zeros_(conv.bias)
    return conv


class ConditionEmbedding(nn.Module):
    """G-buffer [B, Cc, H, W] -> [B, base_width, H, W]; the last conv is zero-initialised (ControlNet's hint net)."""

    def __init__(self, cond_channels: int, base_width: int):
        super().__init__()
        hidden = max(16, base_width // 2)
        self.conv1 = nn.Conv2d(cond_channels, hidden, 3, padding=1)
        self.conv2 = nn.Conv2d(hidden, hidden, 3, padding=1)
        self.out = zero_conv(hidden, base_width, kernel_size=3)

    def forward(self, cond: torch.Tensor) -> torch.Tensor:
        return self.out(F.silu(self.conv2(F.silu(self.conv1(cond)))))


class ControlBranch(nn.Module):
    """forward(x_t, temb, cond) -> residuals: one per UNet skip (same shapes) plus one for the middle."""

    def __init__(self, unet: UNet, cond_channels: int):
        super().__init__()
        config = unet.config
        self.cond_channels = cond_channels
        self.encoder = copy.deepcopy(unet.encoder)  # ControlNet: the trainable copy starts as the encoder
        self.embed = ConditionEmbedding(cond_channels, config.base_width)
        widths = config.widths()
        self.zero_convs = nn.ModuleList([zero_conv(w, w) for w in widths] + [zero_conv(widths[-1], widths[-1])])

    def forward(self, x: torch.Tensor, temb: torch.Tensor, cond: torch.Tensor) -> list[torch.Tensor]:
        if cond.shape[0] != x.shape[0] or cond.shape[1] != self.cond_channels or cond.shape[-2:] != x.shape[-2:]:
            raise ValueError(f"condition {tuple(cond.shape)} does not match image {tuple(x.shape)} "
                             f"with {self.cond_channels} condition channels")
        skips, middle = self.encoder(x, temb, extra=self.embed(cond))
        return [conv(h) for conv, h in zip(self.zero_convs, skips + [middle])]


class ConditionalDenoiser(nn.Module):
    """eps = UNet(x_t, t) with the ControlBranch's residuals when a condition is given.

    forward(x_t [B,C,H,W], t [B] int, cond [B,Cc,H,W] | None) -> eps [B,C,H,W].
    """

    def __init__(self, unet_config: UNetConfig, cond_channels: int):
        super().__init__()
        self.unet = UNet(unet_config)
        self.control = ControlBranch(self.unet, cond_channels)

    @property
    def config(self) -> UNetConfig:
        return self.unet.config

    @property
    def cond_channels(self) -> int:
        return self.control.cond_channels

    def forward(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor | None = None) -> torch.Tensor:
        check_spatial_size(x, self.unet.config)
        if cond is None:
            return self.unet(x, t)
        residuals = self.control(x, self.unet.time_embedding(t), cond.to(x.dtype))
        return self.unet(x, t, control=residuals)
