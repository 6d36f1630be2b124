"""Deterministic DDIM sampling (eta = 0) with a configurable number of steps.

One step from timestep t to the previous sampled timestep s (alpha_bar_s = 1 after the last):
    x0_hat = (x_t - sqrt(1 - ab_t) eps) / sqrt(ab_t), clipped to the image range [-1, 1]
    eps'   = (x_t - sqrt(ab_t) x0_hat) / sqrt(1 - ab_t)       (the noise consistent with the clip)
    x_s    = sqrt(ab_s) x0_hat + sqrt(1 - ab_s) eps'
"""

from __future__ import annotations

from typing import Callable

import torch
from tqdm import tqdm

from .schedule import NoiseSchedule

# Lower bound on sqrt(alpha_bar) before dividing by it. make_schedule guarantees alpha_bar > 0
# (the cosine schedule's smallest, T = 1000, is 2.4e-9: sqrt 4.9e-5, above this floor); the
# floor only stops a schedule with a still smaller alpha_bar from amplifying eps errors without
# bound. x0 is clipped to the image range right after, so the estimate stays bounded anyway.
SQRT_ALPHA_BAR_MIN = 1e-6
# Lower bound on sqrt(1 - alpha_bar): 1 - alpha_bar >= beta_0 > 0 for every schedule here,
# but float32 rounding of 1 - alpha_bar near t = 0 can reach 0.
SQRT_ONE_MINUS_ALPHA_BAR_MIN = 1e-6

# eps_fn(x_t [B,C,H,W], t [B] int64) -> eps [B,C,H,W]
EpsFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def start_timestep(schedule: NoiseSchedule, start: float = 1.0) -> int:
    """The timestep sampling starts at for ``start`` in (0, 1], a fraction of T: round(start (T - 1))."""
    if not 0.0 < start <= 1.0:
        raise ValueError(f"the sampling start must be in (0, 1], got {start}")
    return int(round(start * (schedule.num_timesteps - 1)))


def ddim_timesteps(schedule: NoiseSchedule, steps: int, start: float = 1.0) -> list[int]:
    """Decreasing timesteps, evenly spaced from start_timestep(start) (T-1 for start = 1) to 0;
    ``steps`` of them (fewer only if there are fewer timesteps than steps)."""
    if steps < 1:
        raise ValueError(f"DDIM needs at least 1 step, got {steps}")
    first = start_timestep(schedule, start)
    if steps == 1:
        return [first]
    values = torch.linspace(first, 0, steps, dtype=torch.float64).round().long().tolist()
    return sorted(set(values), reverse=True)


def ddim_step(schedule: NoiseSchedule, x: torch.Tensor, eps: torch.Tensor, t: int, t_prev: int | None,
              clip_sample: bool = True) -> torch.Tensor:
    """One deterministic step from t to t_prev (None = to the clean image). x, eps: [B,C,H,W].
    clip_sample: clip x0 to the image range [-1, 1] (off for VAE latents, which have no fixed range)."""
    ab = schedule.alphas_cumprod[t].item()
    ab_prev = 1.0 if t_prev is None else schedule.alphas_cumprod[t_prev].item()
    sqrt_ab = max(ab ** 0.5, SQRT_ALPHA_BAR_MIN)
    sqrt_one_minus_ab = max((1.0 - ab) ** 0.5, SQRT_ONE_MINUS_ALPHA_BAR_MIN)
    x0 = (x - sqrt_one_minus_ab * eps) / sqrt_ab
    if not clip_sample:
        return ab_prev ** 0.5 * x0 + (1.0 - ab_prev) ** 0.5 * eps
    x0 = x0.clamp(-1.0, 1.0)
    eps = (x - sqrt_ab * x0) / sqrt_one_minus_ab
    return ab_prev ** 0.5 * x0 + (1.0 - ab_prev) ** 0.5 * eps


def initial_noise(shape: tuple[int, ...], seed: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """x_T for a seed: drawn on the CPU so a seed gives the same image on every device."""
    generator = torch.Generator().manual_seed(int(seed))
    return torch.randn(shape, generator=generator, dtype=torch.float32).to(device=device, dtype=dtype)


def initial_state(schedule: NoiseSchedule, shape: tuple[int, ...], seed: int, start: float = 1.0,
                  init: torch.Tensor | None = None, device=None, dtype=torch.float32) -> torch.Tensor:
    """The first x_t of sampling: noise for a seed, or with ``init`` [same shape] (SDEdit) the
    init noised to the start timestep, sqrt(ab) init + sqrt(1 - ab) noise (the forward process's
    own marginal, so the denoiser sees what it was trained on)."""
    noise = initial_noise(shape, seed, device, dtype)
    if init is None:
        return noise
    if tuple(init.shape) != tuple(shape):
        raise ValueError(f"init {tuple(init.shape)} does not match the sample shape {tuple(shape)}")
    ab = schedule.alphas_cumprod[start_timestep(schedule, start)].item()  # in (0, 1)
    return ab ** 0.5 * init.to(device=device, dtype=dtype) + (1.0 - ab) ** 0.5 * noise


@torch.no_grad()
def ddim_sample(eps_fn: EpsFn, schedule: NoiseSchedule, shape: tuple[int, int, int, int], steps: int,
                seed: int = 0, device=None, dtype=torch.float32, progress: bool = False) -> torch.Tensor:
    """Sample images [B, C, H, W] in [-1, 1]. Deterministic: same seed, same image."""
    x = initial_noise(shape, seed, device, dtype)
    timesteps = ddim_timesteps(schedule, steps)
    for i in tqdm(range(len(timesteps)), desc="DDIM", disable=not progress, leave=False):
        t = timesteps[i]
        t_prev = timesteps[i + 1] if i + 1 < len(timesteps) else None
        eps = eps_fn(x, torch.full((shape[0],), t, dtype=torch.long, device=x.device))
        x = ddim_step(schedule, x, eps, t, t_prev)
    return x
