"""Training hyper-parameters: one dataclass, written to RUN/config.json resolved.

Schedules are in iterations (not seconds) so that a run is reproducible from its seed and
a resumed run follows exactly the schedule of an uninterrupted one; ``minutes`` only stops
the loop early.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from ..io.config_json import SavedConfig, dataclass_from_dict, read_json_object
from ..constants import DEVICES
from ..errors import InputError

PROTOCOLS = ("llff", "unstructured", "none")
# A schedule sized to a time budget (``size_to_minutes``) starts from this many steps a minute
# (the 2-core machine at a 100-200k Gaussian budget); the trainer re-sizes it from the rate it measures.
BUDGET_STEPS_PER_MINUTE_GUESS = 70


@dataclass(frozen=True)
class MCMCOptions:
    """3DGS-MCMC's options (strategy "mcmc", inceptiongs.train.strategies.MCMCStrategy); the
    defaults are the paper's."""

    # Position noise gain: the noise is Sigma eta * noise_lr * (position learning rate), Sigma the
    # Gaussian's covariance (scene units squared), gated to nearly transparent Gaussians.
    noise_lr: float = 5e5
    # Loss weight of the mean opacity (opacity in [0, 1]).
    opacity_reg: float = 0.01
    # Loss weight of the mean scale (scene units).
    scale_reg: float = 0.01
    # A Gaussian at or below this opacity (in [0, 1]) is dead: relocated, or removed past the
    # densification window.
    dead_opacity: float = 0.005
    # Least growth of the count per relocation (a fraction of the count), until ``max_gaussians``.
    growth: float = 0.05

    def validate(self, source: str) -> None:
        for name in ("noise_lr", "opacity_reg", "scale_reg", "growth"):
            if not getattr(self, name) >= 0.0:   # also refuses NaN
                raise InputError(f"{source}: mcmc.{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.dead_opacity < 1.0:
            raise InputError(f"{source}: mcmc.dead_opacity must be in [0, 1), got {self.dead_opacity!r}")


@dataclass(frozen=True)
class DropGaussianOptions:
    """DropGaussian's options (strategy "dropgaussian",
    inceptiongs.train.strategies.DropGaussianStrategy)."""

    # Drop probability reached at the last step of the schedule (a fraction in [0, 1)); the rate
    # at step t is rate_max * t / iterations.
    rate_max: float = 0.1

    def validate(self, source: str) -> None:
        if not 0.0 <= self.rate_max < 1.0:
            raise InputError(f"{source}: dropgaussian.rate_max must be in [0, 1), got {self.rate_max}")


# The stage-I strategies by name (inceptiongs.train.strategies.STRATEGIES holds their objects) and
# the class of each one's options: a TrainConfig field of the strategy's name (None: no options).
STRATEGY_OPTIONS: dict[str, type | None] = {"default": None, "mcmc": MCMCOptions,
                                             "dropgaussian": DropGaussianOptions}
STRATEGY_NAMES = tuple(STRATEGY_OPTIONS)
# Flat keys of older config.json files -> (strategy, option): the loader moves them into the
# strategy's options.
FLAT_STRATEGY_KEYS = {
    "mcmc_noise_lr": ("mcmc", "noise_lr"),
    "mcmc_opacity_reg": ("mcmc", "opacity_reg"),
    "mcmc_scale_reg": ("mcmc", "scale_reg"),
    "mcmc_dead_opacity": ("mcmc", "dead_opacity"),
    "mcmc_growth": ("mcmc", "growth"),
    "drop_rate_max": ("dropgaussian", "rate_max"),
}


@dataclass
class TrainConfig(SavedConfig):
    # Scene folder (absolute path).
    scene: str = ""
    # Photos are read at 1/downscale of their size (integer factor >= 1).
    downscale: int = 1
    # Pixels: every photo is scaled down further so that the widest is at most this wide (None: no cap).
    max_width: int | None = None
    # Which views are held out for evaluation (inceptiongs.evaluation.protocols): "llff" (every
    # 8th), "unstructured" (most of one scarce cluster of views, a few of every other), "none".
    protocol: str = "none"
    # Seeds the view order, the initial points and every random draw of the strategies.
    seed: int = 0
    # Unstructured protocol: these views (names) form the scarce cluster instead of a seeded
    # random one (the demo declares the cameras of its thin region).
    scarce_views: list[str] = dataclasses.field(default_factory=list)
    # Photos (names) left out entirely: neither trained on nor held out (e.g. the ones a
    # previous run fitted poorly, inceptiongs.train.view_fit; `train --exclude-photos`).
    exclude_photos: list[str] = dataclasses.field(default_factory=list)
    # Length of the schedule in steps.
    iterations: int = 30_000
    # Wall-clock budget in minutes: stops the loop early (None: no budget).
    minutes: float | None = None
    # PGSR planar terms (flatten, normal, multi-view); off: plain 3DGS.
    pgsr: bool = True
    # Densification strategy by name (STRATEGY_NAMES); its options are the field of the same
    # name below, when it has any.
    strategy: str = "default"
    # --minutes without --iterations: the trainer sizes ``iterations`` (and the schedule) to the
    # time budget from the measured step rate, and re-sizes it when the rate changes a lot.
    size_to_minutes: bool = False
    # Scenes without sparse points (LLFF): triangulate some from the training photos with
    # the known poses (inceptiongs.train.triangulate) instead of starting from random points.
    triangulate_init: bool = True
    # Where training runs (inceptiongs.rasterizer.interface.resolve_device): "cpu" (numba),
    # "cuda" (gsplat) or "auto" (cuda when a GPU, gsplat and a CUDA compiler are all there).
    # Stage II reads the stage-I run's value.
    device: str = "auto"

    # --- Adam learning rates -------------------------------------------------------------------
    # Step sizes in the stored parameter's units (log scale, quaternion component, opacity logit,
    # SH coefficient); the position lr is in scene extents: multiplied by the extent, it decays
    # log-linearly to ``lr_means_final``.
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_log_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_opacity: float = 5e-2
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20.0

    # --- photometric ----------------------------------------------------------------------
    # Weight of the D-SSIM term against L1: loss = (1 - w) L1 + w (1 - SSIM).
    lambda_dssim: float = 0.2
    # Each training step renders over a uniform random colour instead of black, so no pixel can
    # match its photo by staying transparent (docs/tried.md, "A random background").
    random_background: bool = False

    # --- densification (every strategy's window: MCMC relocates on the same steps) -----------
    # Steps: densify (or relocate) every ``densify_every`` steps from ``densify_from`` until
    # ``densify_until``; pruning continues to the end of the run.
    densify_from: int = 500
    densify_until: int = 15_000
    densify_every: int = 100
    densify_grad_threshold: float = 2e-4   # |d loss / d mean2d| in NDC units, averaged over views
    percent_dense: float = 0.01            # clone below, split above this fraction of the extent
    prune_opacity: float = 0.005           # opacity in [0, 1] at or below which a Gaussian is pruned
    # Oversized Gaussians (3DGS's rules, without waiting for an opacity reset): pruned from
    # ``prune_large_from`` on, every ``densify_every`` steps; the screen-size rule while
    # densification can still refill what it removes, the world-size rule until the end of the run.
    # The screen-size rule is off by default: it removes large, legitimate background Gaussians
    # that a budget-capped short run does not refill. 3DGS's value is 20 px.
    prune_screen_radius: float = 0.0       # pixels of footprint radius (the largest over the views); 0 = off
    prune_world_fraction: float = 0.1      # of the extent
    prune_large_from: int = 3_000          # step
    opacity_reset_every: int = 3_000       # steps (default strategy only)
    max_gaussians: int = 2_000_000         # count: densification stops, MCMC grows up to it

    # --- free space (inceptiongs.train.free_space) ---------------------------------------------
    # Remove Gaussians at and around the training cameras, before their near bounds and those the
    # views look through (docs/training.md).
    free_space: bool = True
    # A shell of Gaussians far beyond the scene where the photos show no sparse point
    # (inceptiongs.train.sky): a place for the sky (or a far backdrop) other than disks beside
    # the cameras (docs/training.md).
    sky_shell: bool = True
    # The shell's Gaussians keep every axis at least this fraction of their initial size (half the
    # directions' spacing at the radius) after each step, so that the shell stays closed (0: off;
    # inceptiongs.train.sky.hold_shell_scales). Left free, the photos shrink it to specks with
    # black between them (docs/training_reference.md, "The sky shell").
    sky_min_scale: float = 1.0
    # Per-camera near bound: this low percentile (percent) of the sparse points' depths in that
    # camera, times ``near_margin`` (a fraction: real content lies at or beyond it; the margin
    # leaves room for the points' own noise and for surfaces between the sparse points).
    near_percentile: float = 2.0
    near_margin: float = 0.5
    # A Gaussian whose ellipsoid holds a training camera centre within this many sigmas is removed.
    camera_sigmas: float = 3.0
    # A Gaussian whose centre lies within this fraction of a training camera's near bound of the
    # camera centre, in any direction (beside and behind it too), is removed (0: off).
    camera_ball: float = 0.5
    # A Gaussian seen by at least this many training views, in front of the rendered surface
    # (by ``see_through_tolerance``, a fraction of its depth) in every one of them, is see-through floater.
    see_through_min_views: int = 3
    see_through_tolerance: float = 0.2

    # --- SH schedule ------------------------------------------------------------------------
    # Highest SH degree (0..3), raised by one every ``sh_increase_every`` steps.
    sh_degree_max: int = 3
    sh_increase_every: int = 1_000
    # Per-Gaussian SH degree from the angular spread of the training views that see it: one
    # degree per ``sh_spread_deg_per_degree`` degrees of (half-angle) spread; seen by fewer than
    # ``sh_min_views`` views: degree 0. 0 switches the per-Gaussian limit off.
    sh_spread_deg_per_degree: float = 10.0
    sh_min_views: int = 3

    # --- the strategies' own options (inceptiongs.train.strategies) -----------------------------
    mcmc: MCMCOptions = dataclasses.field(default_factory=MCMCOptions)
    dropgaussian: DropGaussianOptions = dataclasses.field(default_factory=DropGaussianOptions)

    # --- PGSR terms (loss weights are dimensionless; "_from" fields are steps) -----------------
    lambda_flatten: float = 100.0       # weight of the smallest scale axis (flattened Gaussians)
    lambda_normal: float = 0.015        # single-view normal vs the normal of the rendered depth
    normal_from: int = 7_000
    lambda_geo: float = 0.03            # multi-view geometric consistency (reprojection, pixels)
    lambda_ncc: float = 0.15            # multi-view photometric consistency (NCC of patches)
    multiview_from: int = 7_000
    multiview_every: int = 2          # steps; the multi-view terms need a second render
    multiview_scale: float = 0.5      # neighbour depth rendered at this fraction of the size
    multiview_pixel_noise_max: float = 1.0   # pixels: reprojection errors above it are not trusted
    ncc_patch_radius: int = 3         # pixels (7x7 patches)
    ncc_samples: int = 4096           # pixels sampled per step
    neighbours_max: int = 8           # neighbour views per training view
    neighbours_max_angle_deg: float = 30.0   # degrees between viewing directions

    # --- bookkeeping (steps, and a count of checkpoints kept) -------------------------------
    log_every: int = 20
    eval_every: int = 500
    checkpoint_every: int = 500
    keep_checkpoints: int = 2

    # A run's config.json written before the shell's scale floor was trained with a free shell:
    # without this its shell would be raised at the first step of a bootstrap or a resume.
    LEGACY_VALUES: ClassVar[dict] = {"sky_min_scale": 0.0}

    def __post_init__(self) -> None:
        # A strategy's options given as a dict (``TrainConfig(**config.to_json_dict())``) become
        # its dataclass; strict: an unknown option is a TypeError.
        for name, options in STRATEGY_OPTIONS.items():
            value = getattr(self, name, None) if options is not None else None
            if isinstance(value, dict):
                setattr(self, name, options(**value))

    @classmethod
    def load(cls, path: str | Path) -> "TrainConfig":
        """The config in ``path``, strictly, with a file that lacks a key getting its
        ``LEGACY_VALUES`` and the strategies' flat keys (FLAT_STRATEGY_KEYS) moved into their
        strategy's options."""
        data = {**cls.LEGACY_VALUES, **read_json_object(path, cls.CONFIG_KIND)}
        return cls.from_json_dict(data, str(path))

    @classmethod
    def from_json_dict(cls, data: dict, source: str) -> "TrainConfig":
        """A validated config from a config.json's object (nested or flat strategy options)."""
        data = migrate_flat_strategy_keys(data, source)
        for name, options in STRATEGY_OPTIONS.items():
            if options is not None and name in data:
                if not isinstance(data[name], dict):
                    raise InputError(f"{source}: {name} must be an object of the {name} strategy's options")
                data[name] = dataclass_from_dict(options, data[name], source, f"{name} options")
        return dataclass_from_dict(cls, data, source, cls.CONFIG_KIND).validate(source)

    def validate(self, source: str = "config") -> "TrainConfig":
        self.check_types(source)
        if self.strategy not in STRATEGY_NAMES:
            raise InputError(f"{source}: strategy must be one of {', '.join(STRATEGY_NAMES)}, "
                             f"got {self.strategy!r}")
        for name, options in STRATEGY_OPTIONS.items():
            if options is not None:
                if not isinstance(getattr(self, name), options):
                    raise InputError(f"{source}: {name} must hold the {name} strategy's options, "
                                     f"got {getattr(self, name)!r}")
                getattr(self, name).validate(source)
        if not 0.0 <= self.camera_ball <= 1.0:
            raise InputError(f"{source}: camera_ball must be in [0, 1] (a fraction of the near bound), "
                             f"got {self.camera_ball!r}")
        if not 0.0 < self.near_percentile < 100.0 or not 0.0 < self.near_margin <= 1.0:
            raise InputError(f"{source}: near_percentile must be in (0, 100) and near_margin in (0, 1]")
        if self.device not in DEVICES:
            raise InputError(f"{source}: device must be one of {', '.join(DEVICES)}, got {self.device!r}")
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


def migrate_flat_strategy_keys(data: dict, source: str) -> dict:
    """``data`` (a config.json's object) with the flat strategy keys (FLAT_STRATEGY_KEYS) moved
    into their strategy's options (a new dict); a key given both ways is an InputError."""
    data = dict(data)
    for flat, (strategy, option) in FLAT_STRATEGY_KEYS.items():
        if flat not in data:
            continue
        options = dict(data.get(strategy, {}))
        if option in options:
            raise InputError(f"{source}: {flat} and {strategy}.{option} both given")
        options[option] = data.pop(flat)
        data[strategy] = options
    return data


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
        # (every gradient is large at the start): wait 10 % of the run, at most 100 steps,
        # and average the gradients over at least 25 views.
        densify_from=scaled(config.densify_from, min(100, config.iterations // 10)),
        densify_until=scaled(config.densify_until, 2),
        densify_every=scaled(config.densify_every, min(25, max(1, config.iterations // 20))),
        # Opacities need hundreds of steps to recover from a reset, more than a short run can
        # spare; the floaters a reset removes are few when training starts from triangulated points.
        # So runs below SHORT_RUN_RESET_MIN steps never reset.
        # Size pruning starts once densification has had half its window to cover the scene
        # with smaller Gaussians (3DGS: 25 densifications before its first at step 3000). From
        # the first densification, it prunes early, large sky Gaussians before they are split:
        # a hole no gradient refills.
        prune_large_from=max(scaled(config.prune_large_from, 1),
                             (scaled(config.densify_from, min(100, config.iterations // 10))
                              + scaled(config.densify_until, 2)) // 2),
        opacity_reset_every=(config.iterations + 1 if config.iterations < SHORT_RUN_RESET_MIN
                             else scaled(config.opacity_reset_every, max(50, config.iterations // 4))),
        # A short run on the CPU has no time to optimise millions of Gaussians (every step's
        # cost grows with them): the budget shrinks with the run, with a floor that still
        # resolves a photo-sized scene. On CUDA a step at 2M Gaussians costs milliseconds, so
        # the budget stays.
        max_gaussians=(config.max_gaussians if config.device == "cuda" else
                       min(config.max_gaussians, max(SHORT_RUN_MIN_GAUSSIANS, int(config.max_gaussians * fraction)))),
        sh_increase_every=scaled(config.sh_increase_every, 10),
        normal_from=scaled(config.normal_from, 1),
        multiview_from=scaled(config.multiview_from, 1),
    )
