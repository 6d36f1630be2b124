"""Noise schedules of the denoising diffusion prior: betas, cumulative alphas and q_sample.

The forward process is x_t = sqrt(alpha_bar_t) * x_0 + sqrt(1 - alpha_bar_t) * eps with
alpha_bar_t = prod_{s <= t} (1 - beta_s); timesteps are integers 0 .. T-1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

# The cosine schedule's last betas approach 1 (alpha_bar -> 0 at t = T); capping them keeps
# every alpha_bar strictly positive, so sqrt(alpha_bar) can be divided by in DDIM.
COSINE_MAX_BETA = 0.999
# Offset s of the cosine schedule (Nichol & Dhariwal): keeps beta_0 from being vanishingly small.
COSINE_OFFSET = 0.008


@dataclass(frozen=True)
class NoiseSchedule:
    """betas, alphas_cumprod: [T] float64, every alpha_bar in (0, 1)."""

    kind: str
    betas: torch.Tensor
    alphas_cumprod: torch.Tensor

    @property
    def num_timesteps(self) -> int:
        return int(self.betas.shape[0])


def linear_betas(num_timesteps: int, beta_start: float = 1e-4, beta_end: float = 0.02) -> torch.Tensor:
    """[T] float64, evenly spaced from beta_start to beta_end (DDPM's schedule, rescaled to T)."""
    scale = 1000.0 / num_timesteps  # keeps the total noise level of DDPM's T=1000 schedule
    return torch.linspace(beta_start * scale, min(beta_end * scale, COSINE_MAX_BETA), num_timesteps,
                          dtype=torch.float64)


def cosine_betas(num_timesteps: int) -> torch.Tensor:
    """[T] float64 from alpha_bar(t) = cos^2(pi/2 (t/T + s) / (1 + s)), betas capped at COSINE_MAX_BETA."""
    steps = torch.arange(num_timesteps + 1, dtype=torch.float64) / num_timesteps
    f = torch.cos((steps + COSINE_OFFSET) / (1.0 + COSINE_OFFSET) * math.pi / 2.0) ** 2
    # f is decreasing and f[:-1] >= f[T-1] = cos^2(pi/2 (1 - 1/T + s)/(1 + s)) > 0, so the ratio is safe.
    betas = 1.0 - f[1:] / f[:-1]
    return betas.clamp(0.0, COSINE_MAX_BETA)


def scaled_linear_betas(num_timesteps: int, beta_start: float = 0.00085, beta_end: float = 0.012) -> torch.Tensor:
    """[T] float64, linear in sqrt(beta) (Stable Diffusion's "scaled_linear" schedule; a frozen SD
    UNet only denoises correctly under the schedule it was trained with)."""
    return torch.linspace(beta_start ** 0.5, beta_end ** 0.5, num_timesteps, dtype=torch.float64) ** 2


def make_schedule(kind: str = "cosine", num_timesteps: int = 1000, beta_start: float | None = None,
                  beta_end: float | None = None) -> NoiseSchedule:
    """kind: "linear" | "cosine" | "scaled_linear"; beta_start/beta_end override the linear kinds' ends."""
    if num_timesteps < 1:
        raise ValueError(f"num_timesteps must be >= 1, got {num_timesteps}")
    ends = {k: v for k, v in (("beta_start", beta_start), ("beta_end", beta_end)) if v is not None}
    if any(not 0.0 < v < 1.0 for v in ends.values()):
        raise ValueError(f"beta_start/beta_end must be in (0, 1), got {ends}")
    if kind == "linear":
        betas = linear_betas(num_timesteps, **ends)
    elif kind == "scaled_linear":
        betas = scaled_linear_betas(num_timesteps, **ends)
    elif kind == "cosine":
        betas = cosine_betas(num_timesteps)
    else:
        raise ValueError(f"unknown beta schedule {kind!r} (linear | cosine | scaled_linear)")
    alphas_cumprod = torch.cumprod(1.0 - betas, dim=0)
    if not bool(alphas_cumprod[-1] > 0.0):
        raise ValueError(f"{kind} schedule with T={num_timesteps} drives alpha_bar to 0")
    return NoiseSchedule(kind, betas, alphas_cumprod)


def q_sample(schedule: NoiseSchedule, x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """Noised images x_t. x0, noise: [B, C, H, W]; t: [B] int64 timesteps."""
    alpha_bar = schedule.alphas_cumprod.to(x0.device)[t].to(x0.dtype).view(-1, 1, 1, 1)
    return alpha_bar.sqrt() * x0 + (1.0 - alpha_bar).sqrt() * noise
