"""A small convolutional UNet that predicts the noise (epsilon) of a noised image.

Sized to train on two CPU cores: one residual block per resolution level, GroupNorm + SiLU,
base width ~32, 2-3 levels (``channel_mults``). The encoder path (input conv, down levels,
middle block) is its own module so the ControlNet-style branch can be an exact copy of it.
Spatial sizes must be divisible by 2^(levels - 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F


@dataclass(frozen=True)
class UNetConfig:
    image_channels: int = 3
    base_width: int = 32
    channel_mults: tuple[int, ...] = (1, 2, 2)
    time_dim: int = 128

    @property
    def downsample_factor(self) -> int:
        """Spatial sizes must be multiples of this."""
        return 2 ** (len(self.channel_mults) - 1)

    def widths(self) -> list[int]:
        return [self.base_width * mult for mult in self.channel_mults]


def group_count(channels: int) -> int:
    """GroupNorm groups: the largest of 8, 4, 2, 1 dividing ``channels``."""
    return next(g for g in (8, 4, 2, 1) if channels % g == 0)


def timestep_embedding(t: torch.Tensor, dim: int, max_period: float = 10000.0) -> torch.Tensor:
    """Sinusoidal embedding of integer timesteps. t: [B] -> [B, dim] (dim even)."""
    half = dim // 2
    # Frequencies from 1 down to 1/max_period, geometric (the Transformer's positional code).
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    angles = t.float()[:, None] * freqs[None]
    return torch.cat([torch.cos(angles), torch.sin(angles)], dim=-1)


class ResBlock(nn.Module):
    """GroupNorm-SiLU-conv twice, with the timestep embedding added in between. [B,Ci,H,W] -> [B,Co,H,W]."""

    def __init__(self, in_channels: int, out_channels: int, time_dim: int):
        super().__init__()
        self.norm1 = nn.GroupNorm(group_count(in_channels), in_channels)
        self.conv1 = nn.Conv2d(in_channels, out_channels, 3, padding=1)
        self.time_proj = nn.Linear(time_dim, out_channels)
        self.norm2 = nn.GroupNorm(group_count(out_channels), out_channels)
        self.conv2 = nn.Conv2d(out_channels, out_channels, 3, padding=1)
        self.skip = nn.Conv2d(in_channels, out_channels, 1) if in_channels != out_channels else nn.Identity()

    def forward(self, x: torch.Tensor, temb: torch.Tensor) -> torch.Tensor:
        h = self.conv1(F.silu(self.norm1(x)))
        h = h + self.time_proj(F.silu(temb))[:, :, None, None]
        h = self.conv2(F.silu(self.norm2(h)))
        return h + self.skip(x)


class UNetEncoder(nn.Module):
    """Input conv, one ResBlock per level (stride-2 conv between levels), middle ResBlock.

    forward(x [B,C,H,W], temb [B,D], extra=None) -> (skips: one [B,w_l,H/2^l,W/2^l] per level, middle).
    ``extra`` (same shape as the input conv's output) is added right after the input conv:
    this is where the ControlNet branch injects the embedded condition.
    """

    def __init__(self, config: UNetConfig):
        super().__init__()
        widths = config.widths()
        self.conv_in = nn.Conv2d(config.image_channels, config.base_width, 3, padding=1)
        blocks, downs = [], []
        channels = config.base_width
        for level, width in enumerate(widths):
            blocks.append(ResBlock(channels, width, config.time_dim))
            channels = width
            if level < len(widths) - 1:
                downs.append(nn.Conv2d(channels, channels, 3, stride=2, padding=1))
        self.blocks = nn.ModuleList(blocks)
        self.downs = nn.ModuleList(downs)
        self.middle = ResBlock(channels, channels, config.time_dim)

    def forward(self, x: torch.Tensor, temb: torch.Tensor, extra: torch.Tensor | None = None):
        h = self.conv_in(x)
        if extra is not None:
            h = h + extra
        skips = []
        for level, block in enumerate(self.blocks):
            h = block(h, temb)
            skips.append(h)
            if level < len(self.downs):
                h = self.downs[level](h)
        return skips, self.middle(h, temb)


class UNetDecoder(nn.Module):
    """Coarse-to-fine: concat the level's skip, ResBlock, nearest upsample + conv to the finer
    level's width. -> [B, C, H, W]."""

    def __init__(self, config: UNetConfig):
        super().__init__()
        widths = config.widths()
        blocks, ups = [], []
        channels = widths[-1]
        for level in reversed(range(len(widths))):
            blocks.append(ResBlock(channels + widths[level], widths[level], config.time_dim))
            channels = widths[level]
            if level > 0:
                # The up conv already narrows to the finer level's width: at the finest
                # resolution every channel costs the most.
                ups.append(nn.Conv2d(channels, widths[level - 1], 3, padding=1))
                channels = widths[level - 1]
        self.blocks = nn.ModuleList(blocks)
        self.ups = nn.ModuleList(ups)
        self.norm_out = nn.GroupNorm(group_count(channels), channels)
        self.conv_out = nn.Conv2d(channels, config.image_channels, 3, padding=1)

    def forward(self, skips: list[torch.Tensor], middle: torch.Tensor, temb: torch.Tensor) -> torch.Tensor:
        h = middle
        for i, block in enumerate(self.blocks):
            h = block(torch.cat([h, skips[-1 - i]], dim=1), temb)
            if i < len(self.ups):
                h = self.ups[i](F.interpolate(h, scale_factor=2.0, mode="nearest"))
        return self.conv_out(F.silu(self.norm_out(h)))


class UNet(nn.Module):
    """Epsilon predictor: forward(x_t [B,C,H,W], t [B] int) -> eps [B,C,H,W]."""

    def __init__(self, config: UNetConfig = UNetConfig()):
        super().__init__()
        if config.time_dim % 2:
            raise ValueError("time_dim must be even (cos and sin halves)")
        self.config = config
        self.time_mlp = nn.Sequential(nn.Linear(config.time_dim, config.time_dim), nn.SiLU(),
                                      nn.Linear(config.time_dim, config.time_dim))
        self.encoder = UNetEncoder(config)
        self.decoder = UNetDecoder(config)

    def time_embedding(self, t: torch.Tensor) -> torch.Tensor:
        """t: [B] -> [B, time_dim]."""
        return self.time_mlp(timestep_embedding(t, self.config.time_dim))

    def forward(self, x: torch.Tensor, t: torch.Tensor,
                control: list[torch.Tensor] | None = None) -> torch.Tensor:
        """control: optional residuals, one per skip plus one for the middle (ControlNet's output)."""
        check_spatial_size(x, self.config)
        temb = self.time_embedding(t)
        skips, middle = self.encoder(x, temb)
        if control is not None:
            skips = [skip + residual for skip, residual in zip(skips, control[:-1])]
            middle = middle + control[-1]
        return self.decoder(skips, middle, temb)


def check_spatial_size(x: torch.Tensor, config: UNetConfig) -> None:
    factor = config.downsample_factor
    if x.ndim != 4 or x.shape[-1] % factor or x.shape[-2] % factor:
        raise ValueError(f"UNet input must be [B, C, H, W] with H, W multiples of {factor}, got {tuple(x.shape)}")
