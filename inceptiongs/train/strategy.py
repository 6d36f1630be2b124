"""The math of the 3DGS-MCMC and DropGaussian strategies (:mod:`.strategies` holds the strategy
objects and calls these); the trainer, the checkpoints, the PGSR terms, the free-space and size
rules are shared.

* 3DGS-MCMC (Kheradmand et al. 2024). Gaussians are samples of a distribution: after every Adam
  step positions get noise scaled by the covariance and by how transparent the Gaussian is
  (:func:`mcmc_noise`); instead of pruning, dead Gaussians are relocated onto live ones sampled
  by opacity, with the opacity and scale of the N copies corrected so that together they render
  like the source (:func:`relocation_correction`); the count grows by at least a minimum
  fraction per relocation up to a fixed budget (``max_gaussians``), faster in a short run so
  that it still reaches the budget (:func:`growth_rate`; a run sized to a time budget gets the
  budget its time affords, train/budget.py); an L1 regulariser on opacities and scales
  (:func:`mcmc_regularisers`) keeps Gaussians from hiding unused.
* DropGaussian (Park et al. 2025): 3DGS, but each training render drops Gaussians at random
  with rate r_t = r_max t / T and renders the kept ones with opacity o / (1 - r), so every
  pixel's expected contribution stays the same (:func:`drop_gaussians`). Evaluation renders
  every Gaussian with its own opacity.

Random draws come from the CPU or device generator given; results land on the parameters' device.
"""

from __future__ import annotations

import math

import torch

from ..camera import unit_quat_to_rotation
from ..constants import LOG_SCALE_MAX, LOG_SCALE_MIN, OPACITY_LOGIT_ABS_MAX
from ..gaussians import Gaussians
from .optim import replace_rows

# Relocation copies per source are capped (the paper's table holds 51 binomial rows); the
# alternating sums below stay accurate in float64 at that size.
MCMC_MAX_COPIES = 51
# Noise gate: sigmoid(k (1 - o - x0)) is ~1 for o below 1 - x0 = 0.005 and ~0 for opaque ones.
MCMC_NOISE_K = 100.0
MCMC_NOISE_X0 = 0.995
# At most this fractional growth per relocation: a growth window shortened late (a re-sized
# schedule) would otherwise multiply the count, and the step cost, several times at once,
# where no budget check can react.
MCMC_MAX_GROWTH = 0.5
# A corrected opacity stays inside (dead threshold, 1): its logit must be finite.
_OPACITY_CEIL = 1.0 - 1e-6


def logit(p: torch.Tensor) -> torch.Tensor:
    """p in (0, 1) (callers clamp away from 0 and 1) -> log(p / (1 - p))."""
    return torch.log(p) - torch.log1p(-p)


# --- DropGaussian -------------------------------------------------------------------------------

def drop_rate(step: int, iterations: int, rate_max: float) -> float:
    """r_t = rate_max * t / T, in [0, rate_max] (the paper's progressive schedule)."""
    return rate_max * min(max(step / max(iterations, 1), 0.0), 1.0)


def drop_gaussians(gaussians: Gaussians, rate: float, generator: torch.Generator) -> Gaussians:
    """A training copy of ``gaussians`` with each one dropped with probability ``rate`` (its
    opacity pushed below the renderer's alpha cut, so it is culled) and the kept ones' opacity
    divided by (1 - rate); differentiable in the kept opacities. rate in [0, 1)."""
    if rate <= 0.0:
        return gaussians
    n = len(gaussians)
    kept = torch.rand(n, generator=generator, device=generator.device).to(gaussians.opacity_logits.device) >= rate
    # 1 - rate > 0 (rate < 1, validated); the ceiling keeps the logit finite where o / (1 - r) >= 1
    # (there the renderer's alpha cap would clip the centre anyway).
    scaled = (torch.sigmoid(gaussians.opacity_logits) / (1.0 - rate)).clamp(max=_OPACITY_CEIL)
    logits = torch.where(kept, logit(scaled), torch.full_like(scaled, -OPACITY_LOGIT_ABS_MAX))
    return Gaussians(gaussians.means, gaussians.log_scales, gaussians.quats, logits, gaussians.sh)


# --- 3DGS-MCMC ----------------------------------------------------------------------------------

def mcmc_regularisers(params: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """(mean opacity, mean scale): the paper's L1 terms on sigmoid(opacity) and exp(log scale)."""
    scales = torch.exp(params["log_scales"].clamp(LOG_SCALE_MIN, LOG_SCALE_MAX))
    return torch.sigmoid(params["opacity_logits"]).mean(), scales.mean()


def _rotations(quats: torch.Tensor) -> torch.Tensor:
    """quats [N, 4] (w, x, y, z), non-zero -> [N, 3, 3]."""
    return unit_quat_to_rotation(*torch.nn.functional.normalize(quats, dim=-1).unbind(-1), torch.stack)


def mcmc_noise(params: dict[str, torch.Tensor], position_lr: float, noise_lr: float,
               generator: torch.Generator) -> None:
    """In place: means += Sigma eta * sigmoid(k (1 - o - x0)) * noise_lr * position_lr, eta ~ N(0, I);
    Sigma = R S^2 R^T, the Gaussian's covariance (so the noise follows its shape)."""
    with torch.no_grad():
        means = params["means"]
        opacity = torch.sigmoid(params["opacity_logits"])
        gate = torch.sigmoid(MCMC_NOISE_K * ((1.0 - opacity) - MCMC_NOISE_X0))
        scales = torch.exp(params["log_scales"].clamp(LOG_SCALE_MIN, LOG_SCALE_MAX))
        rotations = _rotations(params["quats"])
        eta = torch.randn(means.shape, generator=generator, dtype=means.dtype,
                          device=generator.device).to(means.device)
        # Sigma eta = R (s^2 (R^T eta)) as broadcast sums: no [N, 3, 3] covariance and no
        # batched 3x3 matmuls (three of them took ~25 ms a step at 100k Gaussians).
        local = (rotations * eta[:, :, None]).sum(1) * (scales * scales)                  # s^2 R^T eta
        noise = (rotations * local[:, None, :]).sum(2) * (gate * noise_lr * position_lr)[:, None]
        means.add_(noise)


def relocation_correction(opacity: torch.Tensor, scales: torch.Tensor, copies: torch.Tensor
                          ) -> tuple[torch.Tensor, torch.Tensor]:
    """The paper's correction for N copies of one Gaussian (N = ``copies`` [M] >= 1, the source
    included): o' = 1 - (1 - o)^(1/N), so N stacked copies have the source's opacity, and
    s' = s o / sum_{i=1}^{N} sum_{k=0}^{i-1} C(i-1, k) (-1)^k o'^(k+1) / sqrt(k+1), so their summed
    footprint keeps its integral. opacity [M] in (0, 1), scales [M, 3] -> (o' [M], s' [M, 3])."""
    o = opacity.to(torch.float64)
    n = copies.clamp(1, MCMC_MAX_COPIES).to(torch.float64)
    new_o = 1.0 - torch.pow(1.0 - o, 1.0 / n)
    denominator = torch.zeros_like(o)
    for i in range(1, int(n.max().item()) + 1):
        inner = sum(math.comb(i - 1, k) * (-1) ** k * new_o ** (k + 1) / math.sqrt(k + 1) for k in range(i))
        denominator = denominator + torch.where(n >= i, inner, torch.zeros_like(inner))
    # Each i-term is E[o'(1 - o')^j ...] > 0 for o' in (0, 1): the sum is positive; the floor
    # guards o' underflowing to 0 for a nearly transparent source.
    coefficient = o / denominator.clamp_min(1e-30)
    return new_o.to(opacity.dtype), scales * coefficient.to(scales.dtype)[:, None]


def growth_rate(count: int, budget: int, minimum: float, relocations_left: int) -> float:
    """Fractional growth for this relocation: the paper's ``minimum`` (5 % per 100 steps, which
    reaches the budget within its 25k-step window), or faster when that cannot reach ``budget``
    from ``count`` in the ``relocations_left`` a short run has: geometric, arriving at the end
    of the growth window; never above MCMC_MAX_GROWTH. count, budget >= 1."""
    if count >= budget:
        return 0.0
    needed = (budget / max(count, 1)) ** (1.0 / max(relocations_left, 1)) - 1.0
    return min(MCMC_MAX_GROWTH, max(minimum, needed))


def _sample_by_opacity(opacity: torch.Tensor, candidates: torch.Tensor, count: int,
                       generator: torch.Generator) -> torch.Tensor:
    """``count`` indices drawn with replacement from ``candidates`` [C] with probability ~ opacity."""
    weights = opacity[candidates].to(generator.device, torch.float64).clamp_min(1e-12)  # a positive sum
    picked = torch.multinomial(weights, count, replacement=True, generator=generator)
    return candidates[picked.to(candidates.device)]


def _zero_moments(optimizer: torch.optim.Adam, rows: torch.Tensor) -> None:
    for group in optimizer.param_groups:
        state = optimizer.state.get(group["params"][0])
        if state:
            state["exp_avg"][rows] = 0
            state["exp_avg_sq"][rows] = 0


def _corrected_sources(params, sources: torch.Tensor, copies: torch.Tensor):
    """Corrected (opacity logit, log scale) rows for ``sources`` [M], each shared by copies[M] Gaussians."""
    opacity = torch.sigmoid(params["opacity_logits"].detach()[sources])
    scales = torch.exp(params["log_scales"].detach()[sources].clamp(LOG_SCALE_MIN, LOG_SCALE_MAX))
    new_o, new_s = relocation_correction(opacity, scales, copies)
    # Clamp into (dead threshold, 1): a copy must not be born dead nor have an infinite logit.
    new_o = new_o.clamp(1e-4, _OPACITY_CEIL)
    return logit(new_o), torch.log(new_s.clamp_min(math.exp(LOG_SCALE_MIN)))


def relocate(params: dict[str, torch.Tensor], optimizer: torch.optim.Adam, dead: torch.Tensor,
             generator: torch.Generator, carried: dict[str, torch.Tensor] | None = None) -> int:
    """Move every ``dead`` ([N] bool) Gaussian onto a live one drawn by opacity (in place): it takes
    the source's parameters (and its rows of the ``carried`` per-row tensors), and the source and
    its copies take the corrected opacity and scale; their Adam moments restart. The count does
    not change. Returns how many moved."""
    with torch.no_grad():
        dead_rows = torch.nonzero(dead)[:, 0]
        alive_rows = torch.nonzero(~dead)[:, 0]
        if dead_rows.numel() == 0 or alive_rows.numel() == 0:
            return 0
        opacity = torch.sigmoid(params["opacity_logits"].detach())
        sources = _sample_by_opacity(opacity, alive_rows, dead_rows.numel(), generator)
        copies = torch.bincount(sources, minlength=dead.numel())[sources] + 1    # copies + the source
        new_logit, new_log_scale = _corrected_sources(params, sources, copies)
        for name, tensor in params.items():
            tensor.data[dead_rows] = tensor.data[sources]
        for tensor in (carried or {}).values():
            tensor[dead_rows] = tensor[sources]
        for rows in (sources, dead_rows):
            params["opacity_logits"].data[rows] = new_logit.to(params["opacity_logits"].dtype)
            params["log_scales"].data[rows] = new_log_scale.to(params["log_scales"].dtype)
        _zero_moments(optimizer, torch.cat([sources, dead_rows]))
    return int(dead_rows.numel())


def grow(params: dict[str, torch.Tensor], optimizer: torch.optim.Adam, count: int, generator: torch.Generator,
         carried: dict[str, torch.Tensor]) -> int:
    """Append ``count`` copies of live Gaussians drawn by opacity, with the relocation correction
    on them and their sources (in place; ``carried`` per-row tensors copy their source's rows).
    Returns how many were added."""
    if count <= 0:
        return 0
    with torch.no_grad():
        n = params["means"].shape[0]
        opacity = torch.sigmoid(params["opacity_logits"].detach())
        sources = _sample_by_opacity(opacity, torch.arange(n, device=opacity.device), count, generator)
        copies = torch.bincount(sources, minlength=n)[sources] + 1
        new_logit, new_log_scale = _corrected_sources(params, sources, copies)
        params["opacity_logits"].data[sources] = new_logit.to(params["opacity_logits"].dtype)
        params["log_scales"].data[sources] = new_log_scale.to(params["log_scales"].dtype)
        _zero_moments(optimizer, sources)
        appended = {name: t.detach()[sources].clone() for name, t in params.items()}
        replace_rows(optimizer, params, torch.ones(n, dtype=torch.bool, device=opacity.device), appended)
        for name, tensor in carried.items():
            carried[name] = torch.cat([tensor, tensor[sources]])
    return count
