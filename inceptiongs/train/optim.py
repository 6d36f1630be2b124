"""Parameters and Adam with one learning rate per parameter group.

The optimised tensors live in a dict ``params`` (name -> leaf tensor with grad):
means [N, 3], log_scales [N, 3], quats [N, 4], opacity_logits [N], sh_dc [N, 1, 3] and,
only when the model has higher SH bands, sh_rest [N, K-1, 3] (a separate, smaller lr).
"""

from __future__ import annotations

import math

import torch

from ..gaussians import Gaussians
from ..runs.config import TrainConfig

PARAM_NAMES = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")


def params_from_gaussians(gaussians: Gaussians) -> dict[str, torch.Tensor]:
    """Gaussians -> dict of fresh leaf tensors requiring grad (SH split into dc / rest)."""
    raw = {
        "means": gaussians.means, "log_scales": gaussians.log_scales, "quats": gaussians.quats,
        "opacity_logits": gaussians.opacity_logits, "sh_dc": gaussians.sh[:, :1],
    }
    if gaussians.sh.shape[1] > 1:
        raw["sh_rest"] = gaussians.sh[:, 1:]
    return {name: t.detach().clone().contiguous().requires_grad_(True) for name, t in raw.items()}


def base_learning_rates(config: TrainConfig, extent: float) -> dict[str, float]:
    rates = config.learning_rates
    return {
        "means": rates.means * extent,
        "log_scales": rates.log_scales,
        "quats": rates.quats,
        "opacity_logits": rates.opacity,
        "sh_dc": rates.sh_dc,
        "sh_rest": rates.sh_rest,
    }


def make_optimizer(params: dict[str, torch.Tensor], config: TrainConfig, extent: float) -> torch.optim.Adam:
    """One Adam group per parameter, named so densification can find its state."""
    rates = base_learning_rates(config, extent)
    groups = [{"params": [tensor], "lr": rates[name], "name": name} for name, tensor in params.items()]
    # eps 1e-15 as in 3DGS: the SH and position gradients are tiny and a larger eps would
    # silently scale their steps down.
    # fused: one kernel per parameter instead of ~10 elementwise passes; at 150k Gaussians
    # a step measured 19 ms instead of 172 ms on the 2-core CPU (same update rule).
    return torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=True)


def position_learning_rate(step: int, config: TrainConfig, extent: float) -> float:
    """Log-linear decay from learning_rates.means to .means_final over the schedule, times the extent.

    Both rates are positive (their range), so the logs are defined.
    """
    t = min(max(step / max(config.iterations, 1), 0.0), 1.0)
    rates = config.learning_rates
    log_lr = (1 - t) * math.log(rates.means) + t * math.log(rates.means_final)
    return math.exp(log_lr) * extent


def set_learning_rate(optimizer: torch.optim.Optimizer, name: str, lr: float) -> None:
    for group in optimizer.param_groups:
        if group["name"] == name:
            group["lr"] = lr


def replace_rows(optimizer: torch.optim.Adam, params: dict[str, torch.Tensor],
                 keep: torch.Tensor, appended: dict[str, torch.Tensor] | None = None) -> None:
    """Keep the rows selected by ``keep`` ([N] bool) and append new rows, in place.

    Every parameter and its Adam moments get the same edit, so row i of the moments always
    belongs to row i of the parameter: kept rows keep their moments, appended rows start
    with zero moments (as a fresh Gaussian would). ``appended``: name -> [M, ...] for every
    parameter name (or None for a pure removal).
    """
    for group in optimizer.param_groups:
        name = group["name"]
        old = group["params"][0]
        extra = None if appended is None else appended[name].detach().to(old.dtype)
        new_data = old.detach()[keep] if extra is None else torch.cat([old.detach()[keep], extra])
        new_param = new_data.contiguous().requires_grad_(True)
        state = optimizer.state.pop(old, None)
        if state is not None:
            for key in ("exp_avg", "exp_avg_sq"):
                moment = state[key][keep]
                if extra is not None:
                    moment = torch.cat([moment, torch.zeros_like(extra)])
                state[key] = moment.contiguous()
            optimizer.state[new_param] = state
        group["params"][0] = new_param
        params[name] = new_param


def reset_moments(optimizer: torch.optim.Adam, name: str) -> None:
    """Zero the Adam moments of one parameter (after its values were overwritten)."""
    for group in optimizer.param_groups:
        if group["name"] == name:
            state = optimizer.state.get(group["params"][0])
            if state:
                state["exp_avg"].zero_()
                state["exp_avg_sq"].zero_()
