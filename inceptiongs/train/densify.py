"""Adaptive density control: clone, split, prune and opacity reset (3DGS), Adam-consistent.

Statistics are gathered after every backward pass from the screen-space mean gradients;
every ``densify_every`` steps Gaussians with a large average gradient are cloned (small
ones) or split in two (large ones), and transparent or oversized ones are removed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..camera import unit_quat_to_rotation
from ..runs.config import Densification
from .free_space import nearest_camera_distance
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
    def zeros(n: int, device: torch.device | str = "cpu") -> "DensifyStats":
        return DensifyStats(*(torch.zeros(n, device=device) for _ in range(3)))

    def to(self, device: torch.device | str) -> "DensifyStats":
        return DensifyStats(*(t.to(device) for t in (self.grad_sum, self.count, self.max_radii)))

    def tensors(self) -> dict[str, torch.Tensor]:
        return {"grad_sum": self.grad_sum, "count": self.count, "max_radii": self.max_radii}


def accumulate(stats: DensifyStats, means2d_grad: torch.Tensor, radii: torch.Tensor,
               width: int, height: int) -> None:
    """Add one view's screen-space gradient norms (in NDC units, so the 3DGS threshold
    applies at any resolution) for the Gaussians that were visible. means2d_grad: [N, 2]
    pixels; radii: [N]."""
    visible = radii > 0
    scale = torch.tensor([width * 0.5, height * 0.5], dtype=means2d_grad.dtype, device=means2d_grad.device)
    norms = (means2d_grad.detach() * scale).norm(dim=-1)
    stats.grad_sum += torch.where(visible, norms, torch.zeros_like(norms)).to(stats.grad_sum.dtype)
    stats.count += visible.to(stats.count.dtype)
    stats.max_radii = torch.maximum(stats.max_radii, radii.detach().to(stats.max_radii.dtype))


def _rotation_matrices(quats: torch.Tensor) -> torch.Tensor:
    """quats [N, 4] (w, x, y, z), non-zero -> [N, 3, 3]."""
    return unit_quat_to_rotation(*torch.nn.functional.normalize(quats, dim=-1).unbind(-1), torch.stack)


def densify_and_prune(params: dict[str, torch.Tensor], optimizer: torch.optim.Adam, stats: DensifyStats,
                      densification: Densification, extent: float, prune_large: bool,
                      generator: torch.Generator, grow: bool = True,
                      carried: dict[str, torch.Tensor] | None = None,
                      background: torch.Tensor | None = None,
                      camera_centers: torch.Tensor | None = None) -> dict[str, int]:
    """Clone / split where the mean gradient exceeds the threshold (only with ``grow``), then
    prune, by the ``densification`` settings. In place on ``params`` and the optimizer; every tensor in ``carried`` (per-row
    statistics, [N, ...]) is re-selected the same way (a clone or split child copies its
    source's row). ``background`` ([N] bool) marks Gaussians the size rules leave alone (the sky
    shell's: large by design); ``camera_centers`` [C, 3] let far Gaussians be as large as their
    distance allows (:func:`oversized`). Returns counts {"cloned", "split", "pruned"}."""
    with torch.no_grad():
        mean_grad = stats.grad_sum / stats.count.clamp_min(1.0)  # never-seen Gaussians: 0
        n = params["means"].shape[0]
        room = max(densification.max_gaussians - n, 0)
        hot = mean_grad >= densification.densify_grad_threshold
        if not grow:
            hot = torch.zeros_like(hot)
        max_scale = params["log_scales"].exp().amax(1)
        small = max_scale <= densification.percent_dense * extent
        clone = hot & small
        split = hot & ~small
        # Respect the Gaussian budget: keep the hottest candidates when over it.
        if int(clone.sum()) + _SPLIT_CHILDREN * int(split.sum()) > room:
            order = torch.argsort(mean_grad * (clone | split), descending=True)
            allowed = torch.zeros(n, dtype=torch.bool, device=hot.device)
            allowed[order[: room // _SPLIT_CHILDREN]] = True
            clone &= allowed
            split &= allowed

        appended = {name: [t.detach()[clone]] for name, t in params.items()}
        if bool(split.any()):
            rotations = _rotation_matrices(params["quats"][split])
            scales = params["log_scales"][split].exp()
            for _ in range(_SPLIT_CHILDREN):
                # Drawn from the (CPU) generator, so a run's draws do not depend on its device.
                local = torch.randn(scales.shape, generator=generator, dtype=scales.dtype,
                                    device=generator.device).to(scales.device) * scales
                offsets = (rotations @ local[..., None])[..., 0]
                for name, t in params.items():
                    value = t.detach()[split]
                    if name == "means":
                        value = value + offsets
                    elif name == "log_scales":
                        value = value - _SPLIT_SHRINK
                    appended[name].append(value)
        replace_rows(optimizer, params, ~split, {name: torch.cat(v) for name, v in appended.items()})
        # Source row of every row now: the kept ones, the clones' sources, the split parents twice.
        split_rows = torch.nonzero(split)[:, 0]
        source = torch.cat([torch.nonzero(~split)[:, 0], torch.nonzero(clone)[:, 0]]
                           + [split_rows] * _SPLIT_CHILDREN)

        opacity = torch.sigmoid(params["opacity_logits"])
        prune = opacity < densification.prune_opacity
        if prune_large:
            # New rows have not been rendered yet: no screen size (as in 3DGS). Past the growth
            # window only the world-size rule: what the screen rule removes (a large background
            # Gaussian, say) no split could cover again.
            radii = torch.cat([stats.max_radii[~split], torch.zeros(len(source) - int((~split).sum()),
                                                                   device=source.device)])
            exempt = (torch.zeros(len(source), dtype=torch.bool, device=source.device) if background is None
                      else background[source])
            prune |= oversized(params, radii if grow else None, densification, extent, camera_centers) & ~exempt
        # Never remove every Gaussian: an empty model cannot recover.
        if bool(prune.all()):
            prune[torch.argmax(opacity)] = False
        replace_rows(optimizer, params, ~prune)
        if carried is not None:
            for name, tensor in carried.items():
                carried[name] = tensor[source[~prune]]
    return {"cloned": int(clone.sum()), "split": int(split.sum()), "pruned": int(prune.sum())}


def oversized(params: dict[str, torch.Tensor], max_radii: torch.Tensor | None, densification: Densification,
              extent: float, camera_centers: torch.Tensor | None = None) -> torch.Tensor:
    """[N] bool, 3DGS's size rules: a footprint radius above ``prune_screen_radius`` pixels in some
    view since the last densification (max_radii [N]; None or a radius of 0, the default, skips
    this rule), or a largest scale above ``prune_world_fraction`` of the scene extent — or, for a
    Gaussian farther than the extent from every training camera (camera_centers [C, 3]), of that
    distance: far background is large in world units and small in every view (fern's hallway,
    beyond a camera spread of 0.3 units, was pruned into black holes: 22.5 -> 19.4 dB over the
    last 1000 steps of a 30-minute run)."""
    scale = params["log_scales"].detach().exp().amax(1)
    reach = torch.full_like(scale, extent)
    if camera_centers is not None and camera_centers.shape[0] > 0:
        reach = torch.maximum(reach, nearest_camera_distance(params["means"].detach(), camera_centers))
    too_big = scale > densification.prune_world_fraction * reach
    if max_radii is None or densification.prune_screen_radius <= 0:   # the screen rule is off
        return too_big
    return too_big | (max_radii > densification.prune_screen_radius)


def remove_rows(params: dict[str, torch.Tensor], optimizer: torch.optim.Adam, remove: torch.Tensor,
                carried: dict[str, torch.Tensor]) -> int:
    """Remove the rows ``remove`` ([N] bool) from the parameters, their Adam moments and every
    per-row tensor in ``carried`` (in place); never the last Gaussian. Returns how many went."""
    with torch.no_grad():
        remove = remove.clone()
        if bool(remove.all()):
            remove[torch.argmax(params["opacity_logits"].detach())] = False
        if not bool(remove.any()):
            return 0
        replace_rows(optimizer, params, ~remove)
        for name, tensor in carried.items():
            carried[name] = tensor[~remove]
    return int(remove.sum())


def reset_opacity(params: dict[str, torch.Tensor], optimizer: torch.optim.Adam) -> None:
    """Clamp every opacity to at most RESET_OPACITY and restart its Adam moments."""
    ceiling = math.log(RESET_OPACITY / (1 - RESET_OPACITY))
    with torch.no_grad():
        params["opacity_logits"].clamp_(max=ceiling)
    reset_moments(optimizer, "opacity_logits")
