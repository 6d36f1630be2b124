"""The stage-I strategies as objects, found by name in :data:`STRATEGIES` (``TrainConfig.strategy``).

A strategy is a frozen dataclass: its own options (the fields of its options class in
:mod:`.config`, which a run's config.json holds nested under the strategy's name:
``TrainConfig.mcmc``, ``TrainConfig.dropgaussian``) and the hooks one training step calls
(:mod:`.step`), in this order:

* ``prepare_render(step, gaussians, state, config)`` -> the Gaussians the training render draws;
* ``add_loss_terms(loss, terms, state)`` -> the loss with the strategy's regularisers added right
  after the photometric term (each also recorded in ``terms`` by name);
* ``after_optimizer_step(step, state, data, config)``: after Adam and the shell's scale floor;
* ``maintenance(step, state, data, config, flags, carried, centers)`` -> counts: the periodic
  edit of the model (every ``densify_every`` steps, :func:`.step.maintenance_due`), given the
  Gaussians the free-space rules flag;
* ``after_maintenance(step, state, config)``: the end of the step (the opacity reset).

What every strategy shares stays in TrainConfig: the densification window (``densify_from``,
``densify_until``, ``densify_every``, also MCMC's relocation window), the budget
(``max_gaussians``), the free-space, sky-shell and per-Gaussian SH rules, the PGSR terms. The
math lives in :mod:`.strategy` and :mod:`.densify`; the hooks work on the tensors of whatever
device the state's parameters are on. ``state`` is a :class:`.step.TrainState`, ``data`` a
:class:`.step.TrainData` (the step module imports this one, so they go unannotated here).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import ClassVar

import torch

from ..gaussians import Gaussians
from ..runs.config import STRATEGY_NAMES, STRATEGY_OPTIONS, DropGaussianOptions, MCMCOptions, TrainConfig
from .densify import DensifyStats, densify_and_prune, remove_rows, reset_opacity
from .optim import position_learning_rate
from .sky import in_background
from .strategy import drop_gaussians, drop_rate, grow, growth_rate, mcmc_noise, mcmc_regularisers, relocate


def density_control(step: int, state, data, config: TrainConfig, flags: torch.Tensor,
                    carried: dict[str, torch.Tensor], centers: torch.Tensor) -> dict:
    """3DGS's periodic edit: remove the ``flags`` ([N] bool) Gaussians (never all of them), then
    clone / split (while ``densify_until`` allows growth) and prune. ``carried``: per-row tensors
    kept in step with the rows; ``centers`` [C, 3]: the training cameras. Returns {"cloned",
    "split", "pruned"}."""
    prune_large = step <= config.iterations and step >= config.prune_large_from
    if bool(flags.all()):
        flags[torch.argmax(state.params["opacity_logits"].detach())] = False  # never empty the model
    keep_stats = ~flags
    removed = remove_rows(state.params, state.optimizer, flags, carried)
    if removed:
        state.stats = DensifyStats(*(t[keep_stats] for t in state.stats.tensors().values()))
    return densify_and_prune(state.params, state.optimizer, state.stats, config, data.extent,
                             prune_large=prune_large, generator=state.generator,
                             grow=step < config.densify_until, carried=carried,
                             background=in_background(state.params["means"].detach(), state.sky),
                             camera_centers=centers)


def reset_opacity_on_schedule(step: int, state, config: TrainConfig) -> None:
    """3DGS's opacity reset every ``opacity_reset_every`` steps of the densification window."""
    if step < config.densify_until and step % config.opacity_reset_every == 0:
        reset_opacity(state.params, state.optimizer)


@dataclass(frozen=True)
class DefaultStrategy:
    """3DGS adaptive density control: clone small and split large Gaussians where the view-space
    gradient is large, prune transparent and oversized ones, reset opacities on schedule
    (:mod:`.densify`; its thresholds and schedule are TrainConfig's densification fields)."""

    NAME: ClassVar[str] = "default"

    def prepare_render(self, step: int, gaussians: Gaussians, state, config: TrainConfig) -> Gaussians:
        return gaussians

    def add_loss_terms(self, loss: torch.Tensor, terms: dict[str, torch.Tensor], state) -> torch.Tensor:
        return loss

    def after_optimizer_step(self, step: int, state, data, config: TrainConfig) -> None:
        return None

    def maintenance(self, step: int, state, data, config: TrainConfig, flags: torch.Tensor,
                    carried: dict[str, torch.Tensor], centers: torch.Tensor) -> dict:
        return density_control(step, state, data, config, flags, carried, centers)

    def after_maintenance(self, step: int, state, config: TrainConfig) -> None:
        reset_opacity_on_schedule(step, state, config)


@dataclass(frozen=True)
class DropGaussianStrategy(DefaultStrategy, DropGaussianOptions):
    """DropGaussian (Park et al. 2025): 3DGS density control, but each training render drops
    Gaussians at random with a rate rising linearly over the run and renders the kept ones with
    their opacity divided by (1 - rate) (:func:`.strategy.drop_gaussians`). Evaluation renders
    every Gaussian."""

    NAME: ClassVar[str] = "dropgaussian"

    def prepare_render(self, step: int, gaussians: Gaussians, state, config: TrainConfig) -> Gaussians:
        return drop_gaussians(gaussians, drop_rate(step, config.iterations, self.rate_max), state.generator)


@dataclass(frozen=True)
class MCMCStrategy(MCMCOptions):
    """3DGS-MCMC (Kheradmand et al. 2024): Gaussians are samples whose positions get
    covariance-shaped noise after each Adam step; dead ones are relocated onto live ones instead
    of pruned; the count grows to ``max_gaussians`` over the densification window; L1
    regularisers on opacity and scale. No opacity reset and no size rule: the scale regulariser
    is the paper's answer to large Gaussians, and relocation (by opacity) never refills what a
    size rule removes."""

    NAME: ClassVar[str] = "mcmc"

    def prepare_render(self, step: int, gaussians: Gaussians, state, config: TrainConfig) -> Gaussians:
        return gaussians

    def add_loss_terms(self, loss: torch.Tensor, terms: dict[str, torch.Tensor], state) -> torch.Tensor:
        terms["opacity_reg"], terms["scale_reg"] = mcmc_regularisers(state.params)
        return loss + self.opacity_reg * terms["opacity_reg"] + self.scale_reg * terms["scale_reg"]

    def after_optimizer_step(self, step: int, state, data, config: TrainConfig) -> None:
        if step <= config.iterations:   # stage-II continuations add no noise
            mcmc_noise(state.params, position_learning_rate(step, config, data.extent), self.noise_lr,
                       state.generator)

    def maintenance(self, step: int, state, data, config: TrainConfig, flags: torch.Tensor,
                    carried: dict[str, torch.Tensor], centers: torch.Tensor) -> dict:
        """Within the growth window relocate the dead and the ``flags`` ([N] bool) Gaussians and
        grow the count; past it remove them (a relocated copy would have no time to be fitted).
        Returns {"relocated", "added"} or {"pruned"}."""
        dead = torch.sigmoid(state.params["opacity_logits"].detach()) <= self.dead_opacity
        dead |= flags
        if step >= config.densify_until:
            return {"pruned": remove_rows(state.params, state.optimizer, dead, carried)}
        counts = {"relocated": relocate(state.params, state.optimizer, dead, state.generator, carried)}
        n = state.params["means"].shape[0]
        rate = growth_rate(n, config.max_gaussians, self.growth, relocations_left(step, config))
        room = min(config.max_gaussians, int(n * (1.0 + rate))) - n
        counts["added"] = grow(state.params, state.optimizer, room, state.generator, carried)
        return counts

    def after_maintenance(self, step: int, state, config: TrainConfig) -> None:
        return None


def relocations_left(step: int, config: TrainConfig) -> int:
    """Maintenance steps from ``step`` (included) to the end of the densification window (>= 1)."""
    return max(1, (config.densify_until - 1 - step) // config.densify_every + 1)


# Name -> strategy class: the one registry of strategy objects (`train --strategy` and the viewer
# offer exactly these names; TrainConfig validates them against config.STRATEGY_NAMES).
STRATEGIES: dict[str, type] = {cls.NAME: cls for cls in (DefaultStrategy, MCMCStrategy, DropGaussianStrategy)}
if tuple(STRATEGIES) != STRATEGY_NAMES:
    raise ImportError(f"strategies {tuple(STRATEGIES)} differ from the config's {STRATEGY_NAMES}")


def strategy_for(config: TrainConfig):
    """The strategy object ``config.strategy`` names (a registered name: a validated config),
    with its options from ``config``."""
    options = getattr(config, config.strategy) if STRATEGY_OPTIONS[config.strategy] is not None else None
    return _strategy(config.strategy, options)


@functools.lru_cache(maxsize=16)
def _strategy(name: str, options):
    """One object per (name, options) (frozen, so hashable): a step asks for it several times."""
    cls = STRATEGIES[name]
    return cls() if options is None else cls(**dataclasses.asdict(options))
