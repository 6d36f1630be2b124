"""Training hyper-parameters: one dataclass, written to RUN/config.json resolved.

Schedules are in iterations (not seconds) so that a run is reproducible from its seed and
a resumed run follows exactly the schedule of an uninterrupted one; ``minutes`` only stops
the loop early.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

from ..io.config_json import SavedConfig
from ..errors import InputError

PROTOCOLS = ("llff", "unstructured", "none")
# Stage-I strategies sharing the trainer (inceptiongs.train.strategy): the 3DGS adaptive density
# control, 3DGS-MCMC (Kheradmand et al. 2024) and DropGaussian (Park et al. 2025).
STRATEGIES = ("default", "mcmc", "dropgaussian")
# A schedule sized to a time budget (``size_to_minutes``) starts from this many steps a minute
# (the 2-core machine at a 100-200k Gaussian budget); the trainer re-sizes it from the rate it measures.
BUDGET_STEPS_PER_MINUTE_GUESS = 70


@dataclass
class TrainConfig(SavedConfig):
    scene: str = ""
    downscale: int = 1
    max_width: int | None = None
    protocol: str = "none"
    seed: int = 0
    # Unstructured protocol: these views (names) form the scarce cluster instead of a seeded
    # random one (the demo declares the cameras of its thin region).
    scarce_views: list[str] = dataclasses.field(default_factory=list)
    # Photos (names) left out entirely: neither trained on nor held out (e.g. the ones a
    # previous run fitted poorly, inceptiongs.train.view_fit; `train --exclude-photos`).
    exclude_photos: list[str] = dataclasses.field(default_factory=list)
    iterations: int = 30_000
    minutes: float | None = None
    pgsr: bool = True
    strategy: str = "default"
    # --minutes without --iterations: the trainer sizes ``iterations`` (and the schedule) to the
    # time budget from the measured step rate, and re-sizes it when the rate changes a lot.
    size_to_minutes: bool = False
    # Scenes without sparse points (LLFF): triangulate some from the training photos with
    # the known poses (inceptiongs.train.triangulate) instead of starting from random points.
    triangulate_init: bool = True

    # --- Adam learning rates (per parameter) ---------------------------------------------
    # Position lr is multiplied by the scene extent and decays log-linearly to the final value.
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_log_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_opacity: float = 5e-2
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20.0

    # --- photometric ----------------------------------------------------------------------
    lambda_dssim: float = 0.2
    # Each training step renders over a uniform random colour instead of black, so no pixel can
    # match its photo by staying transparent. Off: measured in docs/training.md ("A random
    # background"): +0.2 dB on the courtyard, -0.75 to -1.4 dB scarce on the objects demo.
    random_background: bool = False

    # --- densification ---------------------------------------------------------------------
    densify_from: int = 500
    densify_until: int = 15_000
    densify_every: int = 100
    densify_grad_threshold: float = 2e-4   # |d loss / d mean2d| in NDC units, averaged over views
    percent_dense: float = 0.01            # clone below, split above this fraction of the extent
    prune_opacity: float = 0.005
    # Oversized Gaussians (3DGS's rules, without waiting for an opacity reset): pruned from
    # ``prune_large_from`` on, every ``densify_every`` steps; the screen-size rule while
    # densification can still refill what it removes, the world-size rule until the end of the run.
    # The screen-size rule is off by default (0): it pruned fern's large, legitimate background
    # and leaf Gaussians that a budget-capped short run does not refill (-0.52 dB at step 900 of
    # 2 300; the demo at 600 steps is +0.06 dB without it). 3DGS's value is 20 px.
    prune_screen_radius: float = 0.0       # pixels of footprint radius (the largest over the views); 0 = off
    prune_world_fraction: float = 0.1      # of the extent
    prune_large_from: int = 3_000
    opacity_reset_every: int = 3_000
    max_gaussians: int = 2_000_000

    # --- free space (inceptiongs.train.free_space) ---------------------------------------------
    # Per-camera near bound: this low percentile of the sparse points' depths in that camera,
    # times ``near_margin`` (real content lies at or beyond it; the margin leaves room for the
    # points' own noise and for surfaces between the sparse points).
    # On by default since the camera ball (``camera_ball``): on the demo at 600 steps +0.48 dB on
    # the scarce, covered and all groups against the same run without the rules, no training-view
    # floater pixels; at 2400 steps covered 22.42 dB (18.82 before any rule; docs/training.md).
    free_space: bool = True
    # A shell of Gaussians far beyond the scene where the photos show no sparse point
    # (inceptiongs.train.sky): a place for the sky (or a far backdrop) other than disks beside
    # the cameras. On by default since it measured better on every scene (docs/training.md,
    # session 2026-11-25): demo covered 22.42 -> 28.53 dB at 2400 steps, statuette +1.5 dB.
    sky_shell: bool = True
    # The shell's Gaussians keep every axis at least this fraction of their initial size (half the
    # directions' spacing at the radius) after each step, so that the shell stays closed (0: off;
    # inceptiongs.train.sky.hold_shell_scales). Left free, the photos shrink it to specks with
    # black between them. On since session 2026-11-25 (twelfth; docs/training.md, "A closed
    # shell"): courtyard 330 steps +2.1 / +2.3 dB scarce (seeds 0 / 1), objects demo 600 steps
    # +1.4 / +7.5 dB scarce; 2.0 gains the courtyard more but costs the demo's covered views 0.5 dB.
    sky_min_scale: float = 1.0
    near_percentile: float = 2.0
    near_margin: float = 0.5
    # A Gaussian whose ellipsoid holds a training camera centre within this many sigmas is removed.
    camera_sigmas: float = 3.0
    # A Gaussian whose centre lies within this fraction of a training camera's near bound of the
    # camera centre, in any direction (beside and behind it too), is removed (0: off).
    camera_ball: float = 0.5
    # A Gaussian seen by at least this many training views, in front of the rendered surface
    # (by ``see_through_tolerance`` of its depth) in every one of them, is see-through floater.
    see_through_min_views: int = 3
    see_through_tolerance: float = 0.2

    # --- SH schedule ------------------------------------------------------------------------
    sh_degree_max: int = 3
    sh_increase_every: int = 1_000
    # Per-Gaussian SH degree from the angular spread of the training views that see it: one
    # degree per ``sh_spread_deg_per_degree`` degrees of (half-angle) spread; seen by fewer than
    # ``sh_min_views`` views: degree 0. 0 switches the per-Gaussian limit off.
    sh_spread_deg_per_degree: float = 10.0
    sh_min_views: int = 3

    # --- 3DGS-MCMC (strategy "mcmc"; values from the paper) ------------------------------------
    mcmc_noise_lr: float = 5e5
    mcmc_opacity_reg: float = 0.01
    mcmc_scale_reg: float = 0.01
    mcmc_dead_opacity: float = 0.005
    mcmc_growth: float = 0.05           # budget grows by this fraction per relocation until max_gaussians

    # --- DropGaussian (strategy "dropgaussian") ------------------------------------------------
    drop_rate_max: float = 0.1          # drop rate rises linearly to this over the run

    # --- PGSR terms -------------------------------------------------------------------------
    lambda_flatten: float = 100.0
    lambda_normal: float = 0.015
    normal_from: int = 7_000
    lambda_geo: float = 0.03
    lambda_ncc: float = 0.15
    multiview_from: int = 7_000
    multiview_every: int = 2          # the multi-view terms need a second render
    multiview_scale: float = 0.5      # neighbour depth rendered at this fraction of the size
    multiview_pixel_noise_max: float = 1.0
    ncc_patch_radius: int = 3         # 7x7 patches
    ncc_samples: int = 4096
    neighbours_max: int = 8
    neighbours_max_angle_deg: float = 30.0

    # --- bookkeeping ------------------------------------------------------------------------
    log_every: int = 20
    eval_every: int = 500
    checkpoint_every: int = 500
    keep_checkpoints: int = 2

    # A run's config.json written before the shell's scale floor was trained with a free shell:
    # without this its shell would be raised at the first step of a bootstrap or a resume (on the
    # demo that cost the training views 3.45 dB).
    LEGACY_VALUES: ClassVar[dict] = {"sky_min_scale": 0.0}

    def validate(self, source: str = "config") -> "TrainConfig":
        self.check_types(source)
        if self.strategy not in STRATEGIES:
            raise InputError(f"{source}: strategy must be one of {', '.join(STRATEGIES)}, got {self.strategy!r}")
        if not 0.0 <= self.drop_rate_max < 1.0:
            raise InputError(f"{source}: drop_rate_max must be in [0, 1), got {self.drop_rate_max}")
        if not 0.0 <= self.camera_ball <= 1.0:
            raise InputError(f"{source}: camera_ball must be in [0, 1] (a fraction of the near bound), "
                             f"got {self.camera_ball!r}")
        if not 0.0 < self.near_percentile < 100.0 or not 0.0 < self.near_margin <= 1.0:
            raise InputError(f"{source}: near_percentile must be in (0, 100) and near_margin in (0, 1]")
        if self.protocol not in PROTOCOLS:
            raise InputError(f"{source}: protocol must be one of {', '.join(PROTOCOLS)}, got {self.protocol!r}")
        if self.scarce_views and self.protocol != "unstructured":
            raise InputError(f"{source}: scarce_views need the unstructured protocol, got {self.protocol!r}")
        if self.iterations < 1:
            raise InputError(f"{source}: iterations must be >= 1, got {self.iterations}")
        if self.minutes is not None and self.minutes <= 0:
            raise InputError(f"{source}: minutes must be > 0, got {self.minutes}")
        if self.downscale < 1:
            raise InputError(f"{source}: downscale must be >= 1, got {self.downscale}")
        if not 0.0 <= self.sky_min_scale < math.inf:   # also refuses NaN
            raise InputError(f"{source}: sky_min_scale must be >= 0 (a fraction of the shell's initial size; "
                             f"0 = off), got {self.sky_min_scale!r}")
        if not self.prune_screen_radius >= 0.0:   # also refuses NaN
            raise InputError(f"{source}: prune_screen_radius must be >= 0 pixels (0 = off), got {self.prune_screen_radius!r}")
        if not 0 <= self.sh_degree_max <= 3:
            raise InputError(f"{source}: sh_degree_max must be in 0..3, got {self.sh_degree_max}")
        for name in ("densify_every", "sh_increase_every", "multiview_every", "log_every",
                     "eval_every", "checkpoint_every", "opacity_reset_every"):
            if getattr(self, name) < 1:
                raise InputError(f"{source}: {name} must be >= 1")
        return self


SHORT_RUN_RESET_MIN = 10_000
SHORT_RUN_MIN_GAUSSIANS = 100_000


# The milestones short_run_schedule scales (from the 30k-step defaults).
def schedule_length(iterations: int | None, minutes: float | None) -> tuple[int, bool]:
    """(first schedule length, sized to the budget?) as `inceptiongs train` chooses them: given
    iterations are a fixed schedule; a budget without them starts from
    BUDGET_STEPS_PER_MINUTE_GUESS a minute and is re-sized by the trainer; neither: the
    no-budget default (TrainConfig's)."""
    if iterations is not None:
        return iterations, False
    if minutes is not None:
        return max(1, round(BUDGET_STEPS_PER_MINUTE_GUESS * minutes)), True
    return TrainConfig().iterations, False


SCHEDULE_FIELDS = ("densify_from", "densify_until", "densify_every", "opacity_reset_every", "max_gaussians",
                   "sh_increase_every", "normal_from", "multiview_from", "prune_large_from")


def sized_schedule(config: TrainConfig, iterations: int) -> TrainConfig:
    """``config`` with ``iterations`` steps and the default milestones scaled to that length
    (what the command line builds); for runs sized to a time budget."""
    defaults = TrainConfig()
    base = dataclasses.replace(config, iterations=max(1, int(iterations)),
                               **{name: getattr(defaults, name) for name in SCHEDULE_FIELDS})
    return short_run_schedule(base)


def short_run_schedule(config: TrainConfig) -> TrainConfig:
    """Scale the iteration-based schedules to a run of ``config.iterations`` steps.

    The defaults are the 30k-step 3DGS/PGSR schedule; a CPU run does a few thousand steps,
    so each milestone keeps its fraction of the run (with floors so short runs still
    densify a few times and raise the SH degree).
    """
    fraction = min(1.0, config.iterations / 30_000)
    if fraction >= 1.0:
        return config
    scaled = lambda value, floor: max(floor, int(round(value * fraction)))  # noqa: E731
    return dataclasses.replace(
        config,
        # Densifying before the first photometric fit has settled clones nearly everything
        # (every gradient is large at the start): wait a tenth of the run, at most 100 steps,
        # and average the gradients over at least 25 views.
        densify_from=scaled(config.densify_from, min(100, config.iterations // 10)),
        densify_until=scaled(config.densify_until, 2),
        densify_every=scaled(config.densify_every, min(25, max(1, config.iterations // 20))),
        # Opacities need hundreds of steps to recover from a reset (fern: 14.7 -> 5.6 dB
        # right after one, 13.5 dB 33 steps later), more than a short run can spare; the
        # floaters a reset removes are few when training starts from triangulated points.
        # So runs below SHORT_RUN_RESET_MIN steps never reset.
        # Size pruning starts once densification has had half its window to cover the scene
        # with smaller Gaussians (3DGS: 25 densifications before its first at step 3000). From
        # the first densification, it pruned the demo's early, large sky Gaussians before they
        # were split: a hole no gradient refills (held-out view 025: 21.7 -> 13.7 dB).
        prune_large_from=max(scaled(config.prune_large_from, 1),
                             (scaled(config.densify_from, min(100, config.iterations // 10))
                              + scaled(config.densify_until, 2)) // 2),
        opacity_reset_every=(config.iterations + 1 if config.iterations < SHORT_RUN_RESET_MIN
                             else scaled(config.opacity_reset_every, max(50, config.iterations // 4))),
        # A short run has no time to optimise millions of Gaussians (every step's cost grows
        # with them): the budget shrinks with the run, with a floor that still resolves a
        # photo-sized scene.
        max_gaussians=min(config.max_gaussians, max(SHORT_RUN_MIN_GAUSSIANS,
                                                    int(config.max_gaussians * fraction))),
        sh_increase_every=scaled(config.sh_increase_every, 10),
        normal_from=scaled(config.normal_from, 1),
        multiview_from=scaled(config.multiview_from, 1),
    )
