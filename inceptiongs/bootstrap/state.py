"""The values a bootstrap runs on: :class:`Setting` (fixed from its first step) and
:class:`LoopState` (what a step changes besides the pool of views, pool.py); with the round plan
(plan.py) and the config they are all the loop's functions (loop.py, round_views.py) take.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import torch

from ..gaussians import Gaussians, gaussians_from_params
from ..runs.config import TrainConfig
from ..runs.metrics import append_metrics
from ..train.loop import StepLoop
from ..train.step import TrainData, TrainState, evaluate_held_out
from .conscience import Conscience
from .generation import GenerationCache, ImagePrior
from .probe import Probe
from .stage1 import Stage1

# What each refinement step was, as summary.json counts them ("additive": a photo step carrying
# a virtual loss, also counted by its virtual branch; "idle": a virtual slot with no view to
# sample, a photo step; "photo_first": a virtual slot before the round's views are made, a photo step).
STEP_KINDS = ("real", "perceptual", "l1_ssim", "informative_l1", "geometry", "additive", "idle", "photo_first")


@dataclass(frozen=True)
class Setting:
    """run: the stage-I run; out_dir: RUN2 (boot_dir: RUN2/bootstrap); train_config: the
    stage-I config continued for the refinement; data: the photos and cameras on the rasterizer's
    device (cpu_photos: the photos on the host, for the prior's training and a placement's
    estimate); sh_max: the SH degree the views support; cache, prior (None: no fill is
    generated), prior_hash, prior_text: what I* is generated with and how the summary names it;
    lpips: the perceptual network (None: MS-SSIM-G); conscience_views: the training photos the
    conscience watches; initial_eval: the input's held-out scores."""

    run: Stage1
    out_dir: Path
    boot_dir: Path
    train_config: TrainConfig
    data: TrainData
    cpu_photos: dict[int, torch.Tensor]
    sh_max: int
    rasterizer: Callable
    log: Callable[[str], None]
    cache: GenerationCache
    prior: ImagePrior | None
    prior_hash: str
    prior_text: str
    lpips: Callable | None
    conscience_views: tuple[int, ...]
    initial_eval: dict


@dataclass
class LoopState:
    """train: the stage-I optimiser state (parameters, Adam, densification statistics, RNGs);
    clock: the clocks, pause/stop control and progress bar; counts: steps per kind (STEP_KINDS);
    conscience: the photos' watch (None: off); summary: what summary.json will say;
    last_eval: the newest held-out scores; current_round: the (1-based) round being refined (0:
    none yet); rounds_done; finished: False once stopped or out of time; probe, photo_until_s: the
    outlook measured while the bootstrap runs (probe.py)."""

    train: TrainState
    clock: StepLoop
    conscience: Conscience | None
    summary: dict
    last_eval: dict
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STEP_KINDS, 0))
    current_round: int = 0
    rounds_done: int = 0
    finished: bool = True
    probe: Probe | None = None              # the outlook being measured (probe.py); None: known
    photo_until_s: float | None = None      # the photo-first time a probe measured (None: the plan's)


def model(state: TrainState) -> Gaussians:
    """The current Gaussians, detached."""
    return gaussians_from_params(state.params).detach()


def held_out_scores(run: Stage1, data: TrainData, rasterizer: Callable, out_dir: Path, clock: StepLoop,
                    state: TrainState, extra: dict) -> dict:
    """Held-out scores now, logged as a metrics line with ``extra``; their time is not training."""
    began = time.perf_counter()
    scores = evaluate_held_out(model(state), run.scene, run.split, data, rasterizer, run.config.output.eval_views)
    clock.exclude(time.perf_counter() - began)
    append_metrics(out_dir, {"iteration": state.iteration, **clock.clocks(),
                             "num_gaussians": int(state.params["means"].shape[0]), **extra, **scores})
    return scores


def evaluate(setting: Setting, state: LoopState, extra: dict) -> dict:
    """:func:`held_out_scores` of the bootstrap in progress."""
    return held_out_scores(setting.run, setting.data, setting.rasterizer, setting.out_dir, state.clock, state.train,
                           extra)
