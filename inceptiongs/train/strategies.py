"""The stage-I strategies as objects, found by name in :data:`STRATEGIES` (``TrainConfig.strategy``).

A strategy is a frozen dataclass of its own settings, built from a TrainConfig by
:func:`strategy_for`: the ``densification`` section (every strategy's window and budget; the
3DGS thresholds, size rules and opacity reset of ``default`` and ``dropgaussian``) and its options
section when it has one (``mcmc``, ``dropgaussian``). One training step (:mod:`.step`) calls its
hooks, in this order, with what they need beside the strategy's own settings (``iterations``: the
schedule's length, steps past it are a stage-II continuation):

* ``prepare_render(step, gaussians, state, iterations)`` -> the Gaussians the training render draws;
* ``add_loss_terms(loss, terms, state)`` -> the loss with the strategy's regularisers added right
  after the photometric term (each also recorded in ``terms`` by name);
* ``after_optimizer_step(step, state, iterations, position_lr)``: after Adam and the shell's scale
  floor (``position_lr``: the step's position learning rate);
* ``maintenance(step, state, extent, iterations, flags, carried, centers)`` -> counts: the
  periodic edit of the model (every ``densify_every`` steps, :func:`.step.maintenance_due`), given
  the Gaussians the free-space rules flag;
* ``after_maintenance(step, state)``: the end of the step (the opacity reset).

The free-space, sky-shell and per-Gaussian SH rules and the PGSR terms are the step's, not a
strategy's. The math lives in :mod:`.strategy` and :mod:`.densify`; the hooks work on the tensors
of whatever device the state's parameters are on. ``state`` is a :class:`.step.TrainState` (the
step module imports this one, so it goes unannotated here).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import ClassVar

import torch

from ..gaussians import Gaussians
from ..runs.config import (STRATEGY_NAMES, STRATEGY_OPTIONS, Densification, DropGaussianOptions, MCMCOptions,
                           TrainConfig)
from .densify import DensifyStats, densify_and_prune, remove_rows, reset_opacity
from .sky import in_background
from .strategy import drop_gaussians, drop_rate, grow, growth_rate, mcmc_noise, mcmc_regularisers, relocate


def density_control(step: int, state, densification: Densification, extent: float, iterations: int,
                    flags: torch.Tensor, carried: dict[str, torch.Tensor], centers: torch.Tensor) -> dict:
    """3DGS's periodic edit: remove the ``flags`` ([N] bool) Gaussians (never all of them), then
    clone / split (while ``densify_until`` allows growth) and prune. ``carried``: per-row tensors
    kept in step with the rows; ``centers`` [C, 3]: the training cameras; ``extent``: the scene's.
    Returns {"cloned", "split", "pruned"}."""
    prune_large = step <= iterations and step >= densification.prune_large_from
    if bool(flags.all()):
        flags[torch.argmax(state.params["opacity_logits"].detach())] = False  # never empty the model
    keep_stats = ~flags
    removed = remove_rows(state.params, state.optimizer, flags, carried)
    if removed:
        state.stats = DensifyStats(*(t[keep_stats] for t in state.stats.tensors().values()))
    return densify_and_prune(state.params, state.optimizer, state.stats, densification, extent,
                             prune_large=prune_large, generator=state.generator,
                             grow=step < densification.densify_until, carried=carried,
                             background=in_background(state.params["means"].detach(), state.sky),
                             camera_centers=centers)


def reset_opacity_on_schedule(step: int, state, densification: Densification) -> None:
    """3DGS's opacity reset every ``opacity_reset_every`` steps of the densification window."""
    if step < densification.densify_until and step % densification.opacity_reset_every == 0:
        reset_opacity(state.params, state.optimizer)


@dataclass(frozen=True)
class DefaultStrategy:
    """3DGS adaptive density control: clone small and split large Gaussians where the view-space
    gradient is large, prune transparent and oversized ones, reset opacities on schedule
    (:mod:`.densify`; its thresholds and schedule are its ``densification`` settings)."""

    NAME: ClassVar[str] = "default"
    densification: Densification = field(default_factory=Densification)

    def prepare_render(self, step: int, gaussians: Gaussians, state, iterations: int) -> Gaussians:
        return gaussians

    def add_loss_terms(self, loss: torch.Tensor, terms: dict[str, torch.Tensor], state) -> torch.Tensor:
        return loss

    def after_optimizer_step(self, step: int, state, iterations: int, position_lr: float) -> None:
        return None

    def maintenance(self, step: int, state, extent: float, iterations: int, flags: torch.Tensor,
                    carried: dict[str, torch.Tensor], centers: torch.Tensor) -> dict:
        return density_control(step, state, self.densification, extent, iterations, flags, carried, centers)

    def after_maintenance(self, step: int, state) -> None:
        reset_opacity_on_schedule(step, state, self.densification)


@dataclass(frozen=True)
class DropGaussianStrategy(DefaultStrategy):
    """DropGaussian (Park et al. 2025): 3DGS density control, but each training render drops
    Gaussians at random with a rate rising linearly over the run and renders the kept ones with
    their opacity divided by (1 - rate) (:func:`.strategy.drop_gaussians`). Evaluation renders
    every Gaussian."""

    NAME: ClassVar[str] = "dropgaussian"
    options: DropGaussianOptions = field(default_factory=DropGaussianOptions)

    def prepare_render(self, step: int, gaussians: Gaussians, state, iterations: int) -> Gaussians:
        return drop_gaussians(gaussians, drop_rate(step, iterations, self.options.rate_max), state.generator)


@dataclass(frozen=True)
class MCMCStrategy:
    """3DGS-MCMC (Kheradmand et al. 2024): Gaussians are samples whose positions get
    covariance-shaped noise after each Adam step; dead ones are relocated onto live ones instead
    of pruned; the count grows to ``max_gaussians`` over the densification window; L1
    regularisers on opacity and scale. No opacity reset and no size rule: the scale regulariser
    is the paper's answer to large Gaussians, and relocation (by opacity) never refills what a
    size rule removes. Of ``densification`` it reads the window and the budget only."""

    NAME: ClassVar[str] = "mcmc"
    densification: Densification = field(default_factory=Densification)
    options: MCMCOptions = field(default_factory=MCMCOptions)

    def prepare_render(self, step: int, gaussians: Gaussians, state, iterations: int) -> Gaussians:
        return gaussians

    def add_loss_terms(self, loss: torch.Tensor, terms: dict[str, torch.Tensor], state) -> torch.Tensor:
        terms["opacity_reg"], terms["scale_reg"] = mcmc_regularisers(state.params)
        return loss + self.options.opacity_reg * terms["opacity_reg"] + self.options.scale_reg * terms["scale_reg"]

    def after_optimizer_step(self, step: int, state, iterations: int, position_lr: float) -> None:
        if step <= iterations:   # stage-II continuations add no noise
            mcmc_noise(state.params, position_lr, self.options.noise_lr, state.generator)

    def maintenance(self, step: int, state, extent: float, iterations: int, flags: torch.Tensor,
                    carried: dict[str, torch.Tensor], centers: torch.Tensor) -> dict:
        """Within the growth window relocate the dead and the ``flags`` ([N] bool) Gaussians and
        grow the count; past it remove them (a relocated copy would have no time to be fitted).
        Returns {"relocated", "added"} or {"pruned"}."""
        window = self.densification
        dead = torch.sigmoid(state.params["opacity_logits"].detach()) <= self.options.dead_opacity
        dead |= flags
        if step >= window.densify_until:
            return {"pruned": remove_rows(state.params, state.optimizer, dead, carried)}
        counts = {"relocated": relocate(state.params, state.optimizer, dead, state.generator, carried)}
        n = state.params["means"].shape[0]
        rate = growth_rate(n, window.max_gaussians, self.options.growth, relocations_left(step, window))
        room = min(window.max_gaussians, int(n * (1.0 + rate))) - n
        counts["added"] = grow(state.params, state.optimizer, room, state.generator, carried)
        return counts

    def after_maintenance(self, step: int, state) -> None:
        return None


def relocations_left(step: int, densification: Densification) -> int:
    """Maintenance steps from ``step`` (included) to the end of the densification window (>= 1)."""
    return max(1, (densification.densify_until - 1 - step) // densification.densify_every + 1)


# Name -> strategy class: the one registry of strategy objects (`train --strategy` and the viewer
# offer exactly these names; TrainConfig validates them against config.STRATEGY_NAMES).
STRATEGIES: dict[str, type] = {cls.NAME: cls for cls in (DefaultStrategy, MCMCStrategy, DropGaussianStrategy)}
if tuple(STRATEGIES) != STRATEGY_NAMES:
    raise ImportError(f"strategies {tuple(STRATEGIES)} differ from the config's {STRATEGY_NAMES}")


def strategy_for(config: TrainConfig):
    """The strategy object ``config.strategy`` names (a registered name: a validated config),
    holding its settings: the ``densification`` section and its own options section."""
    options = getattr(config, config.strategy) if STRATEGY_OPTIONS[config.strategy] is not None else None
    return _strategy(config.strategy, config.densification, options)


@functools.lru_cache(maxsize=16)
def _strategy(name: str, densification: Densification, options):
    """One object per (name, settings) (frozen, so hashable): a step asks for it several times."""
    cls = STRATEGIES[name]
    return cls(densification) if options is None else cls(densification, options)
