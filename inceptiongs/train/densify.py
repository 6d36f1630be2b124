"""Adaptive density control: clone, split, prune and opacity reset (3DGS), Adam-consistent.

Statistics are gathered after every backward pass from the screen-space mean gradients;
every ``densify_every`` steps Gaussians with a large average gradient are cloned (small
ones) or split in two (large ones), and transparent or oversized ones are removed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .config import TrainConfig
from .optim import replace_rows, reset_moments

# Split children are 1/1.6 the parent's size (the 3DGS factor for two children).
_SPLIT_SHRINK = math.log(1.6)
_SPLIT_CHILDREN = 2
# Opacity after a reset: low enough that floaters must earn their opacity back.
RESET_OPACITY = 0.01


@dataclass
class DensifyStats:
    """grad_sum, count, max_radii: [N] running statistics since the last densification."""

    grad_sum: torch.Tensor
    count: torch.Tensor
    max_radii: torch.Tensor

    @staticmethod
    def zeros(n: int) -> "DensifyStats":
        return DensifyStats(torch.zeros(n), torch.zeros(n), torch.zeros(n))

    def tensors(self) -> dict[str, torch.Tensor]:
        return {"grad_sum": self.grad_sum, "count": self.count, "max_radii": self.max_radii}


def accumulate(stats: DensifyStats, means2d_grad: torch.Tensor, radii: torch.Tensor,
               width: int, height: int) -> None:
    """Add one view's screen-space gradient norms (in NDC units, so the 3DGS threshold
    applies at any resolution) for the Gaussians that were visible. means2d_grad: [N, 2]
    pixels; radii: [N]."""
    visible = radii > 0
    scale = torch.tensor([width * 0.5, height * 0.5], dtype=means2d_grad.dtype)
    norms = (means2d_grad.detach() * scale).norm(dim=-1)
    stats.grad_sum += torch.where(visible, norms, torch.zeros_like(norms)).to(stats.grad_sum.dtype)
    stats.count += visible.to(stats.count.dtype)
    stats.max_radii = torch.maximum(stats.max_radii, radii.detach().to(stats.max_radii.dtype))


def _rotation_matrices(quats: torch.Tensor) -> torch.Tensor:
    """quats [N, 4] (w, x, y, z), non-zero -> [N, 3, 3]."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(-1, 3, 3)


def densify_and_prune(params: dict[str, torch.Tensor], optimizer: torch.optim.Adam, stats: DensifyStats,
                      config: TrainConfig, extent: float, prune_large: bool,
                      generator: torch.Generator) -> dict[str, int]:
    """Clone / split where the mean gradient exceeds the threshold, then prune. In place on
    ``params`` and the optimizer. Returns counts {"cloned", "split", "pruned"}."""
    with torch.no_grad():
        mean_grad = stats.grad_sum / stats.count.clamp_min(1.0)  # never-seen Gaussians: 0
        n = params["means"].shape[0]
        room = max(config.max_gaussians - n, 0)
        hot = mean_grad >= config.densify_grad_threshold
        max_scale = params["log_scales"].exp().amax(1)
        small = max_scale <= config.percent_dense * extent
        clone = hot & small
        split = hot & ~small
        # Respect the Gaussian budget: keep the hottest candidates when over it.
        if int(clone.sum()) + _SPLIT_CHILDREN * int(split.sum()) > room:
            order = torch.argsort(mean_grad * (clone | split), descending=True)
            allowed = torch.zeros(n, dtype=torch.bool)
            allowed[order[: room // _SPLIT_CHILDREN]] = True
            clone &= allowed
            split &= allowed

        appended = {name: [t.detach()[clone]] for name, t in params.items()}
        if bool(split.any()):
            rotations = _rotation_matrices(params["quats"][split])
            scales = params["log_scales"][split].exp()
            for _ in range(_SPLIT_CHILDREN):
                local = torch.randn(scales.shape, generator=generator, dtype=scales.dtype) * scales
                offsets = (rotations @ local[..., None])[..., 0]
                for name, t in params.items():
                    value = t.detach()[split]
                    if name == "means":
                        value = value + offsets
                    elif name == "log_scales":
                        value = value - _SPLIT_SHRINK
                    appended[name].append(value)
        replace_rows(optimizer, params, ~split, {name: torch.cat(v) for name, v in appended.items()})

        opacity = torch.sigmoid(params["opacity_logits"])
        prune = opacity < config.prune_opacity
        if prune_large:
            n_new = params["means"].shape[0]
            radii = torch.cat([stats.max_radii[~split],
                               torch.zeros(n_new - int((~split).sum()))])
            prune |= radii > config.prune_screen_radius
            prune |= params["log_scales"].exp().amax(1) > config.prune_world_fraction * extent
        # Never remove every Gaussian: an empty model cannot recover.
        if bool(prune.all()):
            prune[torch.argmax(opacity)] = False
        replace_rows(optimizer, params, ~prune)
    return {"cloned": int(clone.sum()), "split": int(split.sum()), "pruned": int(prune.sum())}


def reset_opacity(params: dict[str, torch.Tensor], optimizer: torch.optim.Adam) -> None:
    """Clamp every opacity to at most RESET_OPACITY and restart its Adam moments."""
    ceiling = math.log(RESET_OPACITY / (1 - RESET_OPACITY))
    with torch.no_grad():
        params["opacity_logits"].clamp_(max=ceiling)
    reset_moments(optimizer, "opacity_logits")
