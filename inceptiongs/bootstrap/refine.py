"""Refinement: the stage-I optimiser continued on the real photos plus the virtual views.

Real-photo steps are the stage-I trainer's own step (photometric + PGSR terms); virtual-view
steps render the virtual camera and compare it with I*: a perceptual distance when the view's
SSIM loss (1 - SSIM) is at most tau (the render already has the right structure, so only the
appearance is pulled towards I*), else L1 + D-SSIM. Both kinds of step go through the trainer's
``optimizer_step`` (Adam, densification statistics and schedule), so nothing is duplicated.

Which virtual view comes next is chosen by :class:`ViewSampler`: Langevin steps on the 7-D pose
(the paper's Algorithm 1; inceptiongs.bootstrap.langevin) or uniformly (ablation).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

import numpy as np
import torch

from ..evaluation.metrics import ssim
from ..train import losses
from ..runs.config import TrainConfig
from ..gaussians import gaussians_from_params
from ..train.optim import position_learning_rate, set_learning_rate
from ..train.step import optimizer_step, sh_degree_at
from .config import BootstrapConfig
from .generation import VirtualTarget
from .langevin import DEFAULT_NOISE_SCALE, DEFAULT_STEP_SIZE, langevin_step, pose_gradient, pose_to_vector, \
    snap_to_nearest
from .perceptual import perceptual_distance
from .variants import Variant
from .virtual_views import flag_of

# Opacity resets wipe every Gaussian's opacity; in a refinement of a few hundred steps the
# covered regions would not recover, so the continuation never resets (a step count no run reaches).
NO_RESET = 10**12
# P = exp(L1) with L1 of images in [0, 1] is in [1, e]: exp never overflows and 1/P is in
# [1/e, 1]. The clamp guards renders outside [0, 1] (black background, SH overshoot).
L1_MAX_FOR_P = 10.0
# The tau test's divisor never goes below this (a view with no weighted pixel is not sampled).
MIN_WEIGHTED_SHARE = 1e-3
# The paper's tau, used when tau is not given and LPIPS weights are (perceptual_tau).
LPIPS_TAU = 0.2
# A Langevin step moves the pose by ~0.03 scene units, while the virtual views of several
# flags lie units apart: left alone the chain stays among the first flags' views for hundreds
# of steps (bonsai, 23 flags: 10 of them refined in 150 virtual steps, the other 13 never, and
# those lost 0.2-0.7 dB to the photo steps they gave up). A flag whose views were refined more
# than this many times as often as the least refined flag's (plus one) restarts the chain at
# that flag: every flag is refined, and the chain may still prefer the worse ones up to this
# ratio. Among one flag's views the chain moves freely: balancing those too cost the demo's
# single flag 0.14-0.18 dB (its steps spread over views the gate then left out).
RESTART_RATIO = 2


def continuation_config(stage1: TrainConfig, start: int, steps: int, variants: Iterable[Variant] = ()) -> TrainConfig:
    """The stage-I config continued for ``steps`` iterations after ``start`` (stage I's last).

    ``iterations`` stays stage I's, so the position learning rate stays at the value stage I
    ended with (a re-spread decay raised it and cost the covered views ~0.2 dB within 180 demo
    steps, measured with the same-time baseline). Opacity resets and densification are off (the
    variant "densify" opens a window over the middle of the extension: ``continued_schedule``).
    The bootstrap and the same-time baseline both use this, so their comparison isolates the
    virtual views.
    """
    steps = max(int(steps), 1)
    densification = dataclasses.replace(stage1.densification, opacity_reset_every=NO_RESET,
                                        densify_until=min(stage1.densification.densify_until, start))
    config = dataclasses.replace(stage1, iterations=max(stage1.iterations, start), minutes=None,
                                 densification=densification)
    for variant in variants:
        config = variant.continued_schedule(config, stage1, start, steps)
    return config


def probability(l1: float) -> float:
    """P = exp(L1(render, I*)) (the paper's sampling density; log P = L1)."""
    return math.exp(min(max(l1, 0.0), L1_MAX_FOR_P))


@dataclass
class ViewChoice:
    index: int          # into the pool of virtual views
    # Langevin: the view's update is divided by P = exp(L1(render, I*)), read from the step's own
    # render (virtual_loss; a render of its own would be the same image); uniform: weight 1.
    weighted: bool


class ViewSampler:
    """Chooses the next virtual view: Langevin on the 7-D pose snapped to the pool, or uniform.

    The pose state starts at the first view of the pool; after each Langevin step it is
    snapped to the nearest virtual view and continues from that view's pose (the state stays
    on the pool, so it cannot drift away from the views that have an I*). A chain sitting on a
    flag refined more than RESTART_RATIO times as often as the least refined flag (plus one)
    restarts at that flag's least refined view, which is refined next (:func:`restart_view`;
    a view's flag: virtual_views.flag_of). Its state is the random
    generator, the pose and ``visits`` (view name -> times chosen; a checkpoint keeps the
    pose and the visits).
    """

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.pose: np.ndarray | None = None
        self.visits: dict[str, int] = {}
        self._poses: np.ndarray | None = None
        self._pool_names: tuple[str, ...] = ()

    def _pool_poses(self, pool: Sequence[VirtualTarget]) -> np.ndarray:
        # Keyed on the members, not the size: the views that may be sampled change as a view's
        # informative pixels come and go.
        names = tuple(v.name for v in pool)
        if self._pool_names != names:
            self._poses = np.stack([pose_to_vector(v.camera.world_to_camera) for v in pool])
            self._pool_names = names
        return self._poses

    def choose(self, pool: Sequence[VirtualTarget], loss_at: Callable[[int, torch.Tensor], torch.Tensor],
               config: BootstrapConfig) -> ViewChoice:
        """loss_at(index, world_to_camera [4, 4] float64 tensor) -> L1(render at that pose, I*[index]);
        ``config``: the sampling and its Langevin step and noise."""
        if config.sampling == "uniform":
            return self._chose(pool, ViewChoice(int(self.rng.integers(len(pool))), weighted=False))
        poses = self._pool_poses(pool)
        if self.pose is None:
            self.pose = poses[0].copy()
        current = int(snap_to_nearest(self.pose, poses))
        restart = restart_view(current, [self.visits.get(v.name, 0) for v in pool], [flag_of(v.name) for v in pool])
        if restart != current:
            # The restart view itself is refined: a Langevin step from it may drift straight back
            # to the view refined too often (bonsai: one view took 88 of 150 virtual steps).
            self.pose = poses[restart].copy()
            return self._chose(pool, ViewChoice(restart, weighted=True))
        camera = pool[current].camera
        # log P = L1: ascend it, towards the views the model renders worst (grad of L1 w.r.t. the
        # pose through the differentiable rasterizer, chained to the 7-D pose by langevin.py).
        grad = pose_gradient(lambda w2c: loss_at(current, w2c), camera.world_to_camera)
        step = DEFAULT_STEP_SIZE if config.langevin_step is None else config.langevin_step
        noise = DEFAULT_NOISE_SCALE if config.langevin_noise is None else config.langevin_noise
        moved = langevin_step(self.pose, np.asarray(grad, np.float64), step, noise, self.rng)
        chosen = int(snap_to_nearest(moved, poses))
        self.pose = poses[chosen].copy()
        return self._chose(pool, ViewChoice(chosen, weighted=True))

    def _chose(self, pool: Sequence[VirtualTarget], choice: ViewChoice) -> ViewChoice:
        name = pool[choice.index].name
        self.visits[name] = self.visits.get(name, 0) + 1
        return choice


def restart_view(current: int, visits: Sequence[int], flags: Sequence[str] | None = None) -> int:
    """The view a Langevin step starts from: ``current``, or, when the flag of ``current`` was
    refined more than RESTART_RATIO times as often as the least refined flag plus one, that
    flag's least refined view (the first of ties, flags by their first view).
    visits: [V] times each pool view was chosen; flags: [V] each view's flag (None: every view
    its own)."""
    flags = list(range(len(visits))) if flags is None else list(flags)
    per_flag: dict = {}
    for flag, count in zip(flags, visits):
        per_flag[flag] = per_flag.get(flag, 0) + count
    least_flag = min(per_flag, key=per_flag.get)     # dicts keep first-seen order: the first of ties
    if per_flag[flags[current]] <= RESTART_RATIO * per_flag[least_flag] + 1:
        return current
    members = [i for i, flag in enumerate(flags) if flag == least_flag]
    return min(members, key=lambda i: visits[i])


def pixel_weights(mask: torch.Tensor, generated_weight: float) -> torch.Tensor | None:
    """[H, W, 1] confidence: 1 on pixels trusted from warped photos, ``generated_weight`` on
    generated ones (None when that is 1: the paper's unweighted loss)."""
    if generated_weight == 1.0:
        return None
    return mask + generated_weight * (1.0 - mask)


def view_weights(mask: torch.Tensor, config: BootstrapConfig) -> torch.Tensor | None:
    """:func:`pixel_weights`, as the chosen variants change them (``pixel_weights`` hook)."""
    weights = pixel_weights(mask, config.generated_weight)
    for variant in config.variants.values():
        weights = variant.pixel_weights(mask, weights)
    return weights


def active_views(pool: Sequence[VirtualTarget], config: BootstrapConfig) -> list[int]:
    """Indices of the pool's views that can take a virtual step: those whose photos were not
    outvoted by the render (``VirtualTarget.supervised``, agreement.py) and that every chosen
    variant lets be sampled (``may_sample``)."""
    variants = list(config.variants.values())
    return [i for i, view in enumerate(pool) if view.supervised and all(v.may_sample(view) for v in variants)]


def perceptual_tau(config: BootstrapConfig, lpips=None) -> float:
    """The SSIM loss up to which a virtual view's loss is perceptual: config.tau when given, else
    LPIPS_TAU with LPIPS weights and 0 without (never the weight-free stand-in unless asked for:
    on bonsai, with 118 of 150 virtual steps on it, it halved what the flagged views gained)."""
    if config.tau is not None:
        return config.tau
    return LPIPS_TAU if lpips is not None else 0.0


def virtual_view_loss(rgb: torch.Tensor, target: torch.Tensor, config: BootstrapConfig,
                      lambda_dssim: float, lpips=None, weights: torch.Tensor | None = None,
                      weighted_share: float = 1.0) -> tuple[torch.Tensor, dict]:
    """rgb, target: [H, W, 3] -> (loss, record). Perceptual when 1 - SSIM <= tau, else L1 + D-SSIM.
    weights: optional [H, W, 1] per-pixel confidence (view_weights). A chosen variant may supply
    the loss instead (``colour_loss``). weighted_share in (0, 1]: the share of pixels that carry
    loss at all (evidence weights); the SSIM loss of the others is 0, so the tau test divides by
    it to judge the structure where the loss is."""
    for variant in config.variants.values():
        replaced = variant.colour_loss(rgb, target, weights)
        if replaced is not None:
            return replaced
    if weights is not None:
        # Scaling the residual by the per-pixel confidence W gives L1 = mean(W |r - I*|) and an
        # SSIM of the same down-weighted residual; W = 1 everywhere is the plain loss.
        rgb = target + weights * (rgb - target)
    l1 = (rgb - target).abs().mean()
    ssim_loss = 1.0 - ssim(rgb, target)
    record = {"virtual_l1": float(l1.detach()), "virtual_ssim_loss": float(ssim_loss.detach())}
    if float(ssim_loss.detach()) / weighted_share <= perceptual_tau(config, lpips):
        loss = perceptual_distance(rgb, target, lpips=lpips)
        record["virtual_branch"] = "perceptual"
    else:
        loss = (1.0 - lambda_dssim) * l1 + lambda_dssim * ssim_loss
        record["virtual_branch"] = "l1_ssim"
    record["virtual_loss"] = float(loss.detach())
    return loss, record


def virtual_loss(step: int, state, train_config: TrainConfig, sh_max: int, view: VirtualTarget,
                 choice: ViewChoice, config: BootstrapConfig, rasterizer, lpips=None, scale: float = 1.0
                 ) -> tuple[torch.Tensor, dict, dict]:
    """A virtual view's weighted loss (1/P when the choice is weighted, the conscience's ``scale``, lambda_virtual),
    plus the chosen variants' terms (``extra_loss``, scaled by the conscience too)
    -> (loss, the render's outputs, log record); no backward, no optimiser step."""
    sh_degree = sh_degree_at(step, train_config, sh_max)
    gaussians = gaussians_from_params(state.params)
    variants = list(config.variants.values())
    outputs = ("rgb",) + tuple(output for variant in variants for output in variant.render_outputs(view))
    out = rasterizer(gaussians, view.camera, outputs=outputs, sh_degree=sh_degree)
    p = probability(float(view_l1(out["rgb"].detach(), view))) if choice.weighted else 1.0
    weight = 1.0 / p  # p >= 1: the division is safe
    if config.colour_target():
        weights = view_weights(view.mask, config)
        share = 1.0
        if view.evidence is not None:   # regions without positive evidence get no virtual gradient
            weights = view.evidence if weights is None else weights * view.evidence
            share = max(float(view.evidence.mean()), MIN_WEIGHTED_SHARE)
        loss, record = virtual_view_loss(out["rgb"], view.target, config, train_config.losses.lambda_dssim, lpips, weights,
                                         share)
        total = config.lambda_virtual * weight * scale * loss
    else:
        # No colour target (only a variant's term): the rgb output still enters the graph (at
        # zero weight) so the trainer's densification statistics see the same render as on any
        # other step.
        total = 0.0 * out["rgb"].sum()
        record = {"virtual_loss": 0.0, "virtual_branch": "geometry"}
    for variant in variants:
        extra = variant.extra_loss(out, view, config.seed, step, scale)
        if extra is not None:
            term, extra_record = extra
            record.update(extra_record)
            if term is not None:
                total = total + term
    record.update(view=view.name, weight=weight, p=p, sh_degree=sh_degree)
    return total, out, record


def virtual_step(step: int, state, data, train_config: TrainConfig, sh_max: int, view: VirtualTarget,
                 choice: ViewChoice, config: BootstrapConfig, rasterizer, lpips=None, scale: float = 1.0) -> dict:
    """One optimisation step on a virtual view (weighted by 1/P for a weighted choice and the conscience's
    ``scale``); the log record."""
    set_learning_rate(state.optimizer, "means", position_learning_rate(step, train_config, data.extent))
    total, out, record = virtual_loss(step, state, train_config, sh_max, view, choice, config, rasterizer, lpips,
                                      scale)
    if train_config.pgsr:
        total = total + train_config.pgsr_terms.lambda_flatten * losses.flatten_loss(state.params["log_scales"])
    record.update(kind="virtual", loss=float(total.detach()))
    record.update(optimizer_step(step, total, out, view.camera, state, data, train_config))
    return record


def render_l1(rasterizer, gaussians, view: VirtualTarget, sh_degree: int,
              world_to_camera: torch.Tensor) -> torch.Tensor:
    """L1(render of the detached ``gaussians`` at ``world_to_camera``, I*) (differentiable in the pose);
    with the view's evidence weights, only where they are set (the Langevin energy then follows
    the evidence too)."""
    out = rasterizer(gaussians, view.camera, outputs=("rgb",), sh_degree=sh_degree,
                    world_to_camera=world_to_camera)
    return view_l1(out["rgb"], view)


def view_l1(rgb: torch.Tensor, view: VirtualTarget) -> torch.Tensor:
    """rgb: [H, W, 3] -> mean |rgb - I*|, only where the view's evidence weights are set (if any)."""
    residual = (rgb - view.target).abs()
    if view.evidence is not None:
        residual = residual * view.evidence
    return residual.mean()
