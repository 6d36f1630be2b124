"""Training hyper-parameters: TrainConfig, a few top-level settings and one section (a nested
dataclass) per concern, written to RUN/config.json resolved, in that nested form.

Every setting carries its meaning, unit, range and choices in its field metadata
(inceptiongs.io.config_json.setting): the strict reader checks a file against them and
docs/train_options.md is generated from them (scripts/gen_train_options.py). Each strategy owns a
section of its options (``mcmc``, ``dropgaussian``; inceptiongs.train.strategies).

Schedules are in iterations (not seconds) so that a run is reproducible from its seed and
a resumed run follows exactly the schedule of an uninterrupted one; ``minutes`` only stops
the loop early.

Run folders written before the sections existed hold a flat config.json (every setting at the top
level: "lambda_dssim", "densify_until", "mcmc_noise_lr", ...): :meth:`TrainConfig.load` moves each
flat key into its section (FLAT_KEYS), with LEGACY_VALUES for the keys such a file lacks.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from ..constants import DEVICES
from ..errors import InputError
from ..io.values import rule as named_rule
from ..io.config_json import (SavedConfig, above, at_least, check_settings, config_from_dict,
                              config_value, flat_values, read_json_object, section, setting, setting_paths,
                              with_values, within)

PROTOCOLS = ("llff", "unstructured", "none")
# A schedule sized to a time budget (``size_to_minutes``) starts from this many steps a minute
# (the 2-core machine at a 100-200k Gaussian budget); the trainer re-sizes it from the rate it measures.
BUDGET_STEPS_PER_MINUTE_GUESS = 70
# The page listing every key (generated from the metadata below).
OPTIONS_PAGE = "docs/train_options.md"


@dataclass(frozen=True)
class LearningRates:
    """Adam's step sizes, in the stored parameter's units (log scale, quaternion component,
    opacity logit, SH coefficient); the position's is in scene extents: multiplied by the
    extent, it decays log-linearly from ``means`` to ``means_final`` over the schedule."""

    # log(means) and log(means_final) are taken: both must be > 0.
    means: float = setting(1.6e-4, "position step size at step 0", "scene extents", above(0))
    means_final: float = setting(1.6e-6, "position step size at the end of the schedule", "scene extents", above(0))
    log_scales: float = setting(5e-3, "step size of the log scales", "log scale", at_least(0))
    quats: float = setting(1e-3, "step size of the rotation quaternions", "quaternion component", at_least(0))
    opacity: float = setting(5e-2, "step size of the opacities", "opacity logit", at_least(0))
    sh_dc: float = setting(2.5e-3, "step size of the base colour (SH band 0)", "SH coefficient", at_least(0))
    sh_rest: float = setting(2.5e-3 / 20.0, "step size of the view-dependent colour (SH bands 1-3)",
                             "SH coefficient", at_least(0))


@dataclass(frozen=True)
class Losses:
    """The photometric loss of a training step."""

    lambda_dssim: float = setting(0.2, "weight of the D-SSIM term against L1: loss = (1 - w) L1 + w (1 - SSIM)",
                                  "weight", within(0, 1))
    random_background: bool = setting(False, "each training step renders over a uniform random colour instead "
                                             "of black, so no pixel can match its photo by staying transparent "
                                             "(docs/tried.md, \"A random background\")")


@dataclass(frozen=True)
class Densification:
    """When and how the model's Gaussians are added and removed. The window (``densify_from``,
    ``densify_until``, ``densify_every``) and the budget (``max_gaussians``) are every
    strategy's (MCMC relocates and grows on the same steps); the thresholds, the size rules and
    the opacity reset are 3DGS's adaptive density control, the ``default`` and ``dropgaussian``
    strategies'."""

    densify_from: int = setting(500, "the first step that densifies (or relocates)", "step", at_least(0))
    densify_until: int = setting(15_000, "densification (or relocation) stops before this step; pruning "
                                         "continues to the end of the schedule", "step", at_least(0))
    densify_every: int = setting(100, "steps between two densifications (relocations), also of the size rules",
                                 "steps", at_least(1))
    max_gaussians: int = setting(2_000_000, "budget: densification stops at it, MCMC grows up to it", "Gaussians",
                                 at_least(1))
    densify_grad_threshold: float = setting(2e-4, "a Gaussian whose view-space position gradient, averaged over "
                                                  "the views that saw it, reaches this is cloned or split "
                                                  "(default, dropgaussian)", "|d loss / d mean2d|, NDC units",
                                            at_least(0))
    percent_dense: float = setting(0.01, "a densified Gaussian is cloned when its largest axis is below this "
                                         "fraction of the scene extent, else split (default, dropgaussian)",
                                   "fraction of the extent", at_least(0))
    prune_opacity: float = setting(0.005, "a Gaussian below this opacity is pruned (default, dropgaussian)",
                                   "opacity", within(0, 1))
    prune_screen_radius: float = setting(0.0, "a Gaussian whose footprint radius (the largest over the views) "
                                              "exceeds this is pruned while densification can still refill "
                                              "what it removes; 0: off (3DGS's value is 20; it removes large, "
                                              "legitimate background Gaussians a budget-capped short run does "
                                              "not refill) (default, dropgaussian)", "pixels", at_least(0))
    prune_world_fraction: float = setting(0.1, "a Gaussian whose largest axis exceeds this fraction of the scene "
                                               "extent is pruned, until the end of the run (default, dropgaussian)",
                                          "fraction of the extent", at_least(0))
    prune_large_from: int = setting(3_000, "the first step of the two size rules above (default, dropgaussian)",
                                    "step", at_least(0))
    opacity_reset_every: int = setting(3_000, "every this many steps of the densification window every opacity "
                                              "is reset low (default, dropgaussian)", "steps", at_least(1))


@dataclass(frozen=True)
class FreeSpace:
    """Space the photos see through stays free (inceptiongs.train.free_space), and the sky shell
    beyond the scene (inceptiongs.train.sky); docs/training.md."""

    enabled: bool = setting(True, "remove Gaussians at and around the training cameras, before their near "
                                  "bounds and those the views look through (the rules below)")
    near_percentile: float = setting(2.0, "per-camera near bound: this low percentile of the sparse points' "
                                          "depths in that camera, times near_margin", "percent",
                                     within(0, 100, "()"))
    near_margin: float = setting(0.5, "real content lies at or beyond the near bound; the margin leaves room for "
                                      "the points' own noise and for surfaces between the sparse points",
                                 "fraction", within(0, 1, "(]"))
    camera_sigmas: float = setting(3.0, "a Gaussian whose ellipsoid holds a training camera centre within this "
                                        "many sigmas is removed", "sigmas", at_least(0))
    camera_ball: float = setting(0.5, "a Gaussian whose centre lies within this fraction of a training camera's "
                                      "near bound of the camera centre, in any direction, is removed; 0: off",
                                 "fraction of the near bound", within(0, 1))
    see_through_min_views: int = setting(3, "a Gaussian seen by at least this many training views, in front of "
                                            "the rendered surface in every one of them, is a see-through floater",
                                         "views", at_least(0))
    see_through_tolerance: float = setting(0.2, "in front of the rendered surface by more than this fraction of "
                                                "its depth", "fraction of the depth", at_least(0))
    sky_shell: bool = setting(True, "a shell of Gaussians far beyond the scene where the photos show no sparse "
                                    "point: a place for the sky (or a far backdrop) other than disks beside the "
                                    "cameras (inceptiongs.train.sky)")
    sky_min_scale: float = setting(1.0, "the shell's Gaussians keep every axis at least this fraction of their "
                                        "initial size (half the directions' spacing at the radius) after each "
                                        "step, so that the shell stays closed; 0: off (left free, the photos "
                                        "shrink it to specks with black between them)",
                                   "fraction of the initial size", at_least(0))


@dataclass(frozen=True)
class SHSchedule:
    """How much view-dependent colour (spherical harmonics) the Gaussians get, and when."""

    degree_max: int = setting(3, "highest SH degree, raised by one every increase_every steps (fewer training "
                                 "views cap it lower: train.step.supported_sh_degree)", "degree", within(0, 3))
    increase_every: int = setting(1_000, "steps between two raises of the SH degree", "steps", at_least(1))
    spread_deg_per_degree: float = setting(10.0, "per-Gaussian SH degree from the angular (half-angle) spread of "
                                                 "the training views that see it: one degree per this many "
                                                 "degrees of spread; 0: no per-Gaussian limit", "degrees",
                                           at_least(0))
    min_views: int = setting(3, "a Gaussian seen by fewer training views keeps SH degree 0 (with the "
                                "per-Gaussian limit on)", "views", at_least(0))


@dataclass(frozen=True)
class PGSRTerms:
    """PGSR's planar terms (used when ``pgsr`` is on): flattening, single-view normal and
    multi-view geometric and photometric consistency."""

    lambda_flatten: float = setting(100.0, "weight of the smallest scale axis (flattened Gaussians)", "weight",
                                    at_least(0))
    lambda_normal: float = setting(0.015, "weight of the single-view term: the rendered normal against the "
                                          "normal of the rendered depth", "weight", at_least(0))
    normal_from: int = setting(7_000, "the first step of the normal term", "step", at_least(0))
    lambda_geo: float = setting(0.03, "weight of the multi-view geometric consistency (reprojection error)",
                                "weight", at_least(0))
    lambda_ncc: float = setting(0.15, "weight of the multi-view photometric consistency (NCC of patches)",
                                "weight", at_least(0))
    multiview_from: int = setting(7_000, "the first step of the multi-view terms", "step", at_least(0))
    multiview_every: int = setting(2, "steps between two multi-view terms (each needs a second render)",
                                   "steps", at_least(1))
    multiview_scale: float = setting(0.5, "the neighbour's depth is rendered at this fraction of its size",
                                     "fraction", within(0, 1, "(]"))
    multiview_pixel_noise_max: float = setting(1.0, "reprojection errors above this are not trusted", "pixels",
                                               above(0))
    ncc_patch_radius: int = setting(3, "radius of the NCC patches (3: 7x7)", "pixels", at_least(1))
    ncc_samples: int = setting(4096, "pixels sampled per multi-view step", "pixels", at_least(1))
    neighbours_max: int = setting(8, "neighbour views per training view", "views", at_least(1))
    neighbours_max_angle_deg: float = setting(30.0, "a neighbour's viewing direction is at most this far from the "
                                                    "view's", "degrees", within(0, 180))


@dataclass(frozen=True)
class Output:
    """Bookkeeping: never changes the model."""

    log_every: int = setting(20, "steps between two lines of RUN/metrics.jsonl", "steps", at_least(1))
    eval_every: int = setting(500, "steps between two evaluations of the held-out views", "steps", at_least(1))
    eval_views: int = setting(32, "held-out views per group (scarce, covered) those evaluations score, evenly "
                                  "spaced; `inceptiongs eval` scores all", "views", at_least(1))
    checkpoint_every: int = setting(500, "steps between two checkpoints", "steps", at_least(1))
    keep_checkpoints: int = setting(2, "checkpoints kept in RUN/checkpoints (the newest; at least one)",
                                    "checkpoints", at_least(0))


@dataclass(frozen=True)
class MCMCOptions:
    """3DGS-MCMC's options (strategy "mcmc", inceptiongs.train.strategies.MCMCStrategy); the
    defaults are the paper's."""

    noise_lr: float = setting(5e5, "position noise gain: the noise is Sigma eta * noise_lr * (position learning "
                                   "rate), Sigma the Gaussian's covariance, gated to nearly transparent Gaussians",
                              "gain", at_least(0))
    opacity_reg: float = setting(0.01, "loss weight of the mean opacity", "weight", at_least(0))
    scale_reg: float = setting(0.01, "loss weight of the mean scale (scene units)", "weight", at_least(0))
    dead_opacity: float = setting(0.005, "a Gaussian at or below this opacity is dead: relocated, or removed past "
                                         "the densification window", "opacity", within(0, 1, "[)"))
    growth: float = setting(0.05, "least growth of the count per relocation, until max_gaussians",
                            "fraction of the count", at_least(0))


@dataclass(frozen=True)
class DropGaussianOptions:
    """DropGaussian's options (strategy "dropgaussian",
    inceptiongs.train.strategies.DropGaussianStrategy)."""

    rate_max: float = setting(0.1, "drop probability reached at the last step of the schedule; the rate at step "
                                   "t is rate_max * t / iterations", "probability", within(0, 1, "[)"))


# The stage-I strategies by name (inceptiongs.train.strategies.STRATEGIES holds their objects) and
# the class of each one's own options: a TrainConfig section of the strategy's name (None: none).
STRATEGY_OPTIONS: dict[str, type | None] = {"default": None, "mcmc": MCMCOptions,
                                             "dropgaussian": DropGaussianOptions}
STRATEGY_NAMES = tuple(STRATEGY_OPTIONS)


BLOCK_START_KEEP = ("seen", "cell")
BLOCK_SCHEDULES = ("restart", "continue")


@dataclass(frozen=True)
class Block:
    """A run in blocks (`train --blocks`, inceptiongs.train.blocks). The whole run's config sets
    global_share and start_keep; a block's (count > 0) says which block it is: it trains on the
    photos that see its cell of the ground plane and holds out the whole run's held-out views
    among them, starting from the whole run's global stage (start) or, without one, from the
    sparse points those photos see and the cell and its margin hold."""

    count: int = setting(0, "blocks of the whole run; 0: this run is not a block", "blocks", at_least(0))
    index: int = setting(0, "this block's index, 0 .. count - 1", "-", at_least(0))
    photos: list[str] = setting([], "the photos (names) this block trains on or holds out; every other photo "
                                    "is left out")
    origin: list[float] = setting([], "the ground plane's origin (3 numbers, the scene's normalised frame)",
                                  "scene units")
    u: list[float] = setting([], "the ground plane's first axis (3 numbers, unit length)")
    v: list[float] = setting([], "the ground plane's second axis (3 numbers, unit length)")
    cell: list[float] = setting([], "the cell [u0, u1, v0, v1] in plane coordinates (+-1e9: unbounded); the merge "
                                    "keeps the block's Gaussians inside it", "scene units")
    margin: float = setting(0.0, "the cell is widened by this for the sparse points the block starts from",
                            "scene units", at_least(0))
    global_share: float = setting(1.0 / 3.0, "this share of the whole run's iterations first trains one global "
                                             "stage on every photo (RUN/blocks/global); the blocks fine-tune "
                                             "from its Gaussians with the rest, shared equally; 0: no global "
                                             "stage, the blocks start from the sparse points", "fraction",
                                  within(0, 1, "[)"))
    start_keep: str = setting("seen", "which of the global stage's Gaussians a block starts from: \"seen\" (those "
                                      "inside its cell widened by its margin, the sky shell's and every one its "
                                      "training photos see), \"cell\" (those inside the widened cell and the sky "
                                      "shell's)",
                              choices=BLOCK_START_KEEP)
    schedule: str = setting("restart", "a block's schedule after the global stage: \"restart\" (a run of its own "
                                       "steps: the full position step size, its own densification window), "
                                       "\"continue\" (the rest of the whole run's schedule after the global "
                                       "stage's steps, compressed into the block's: the step size the whole run "
                                       "would have there, its remaining densification window, the SH degree "
                                       "already reached)", choices=BLOCK_SCHEDULES)
    start: str = setting("", "the run folder (the whole run's global stage) whose last checkpoint this block "
                             "starts from; empty: the sparse points", "path")


@dataclass
class TrainConfig(SavedConfig):
    CONFIG_KIND = "train config"

    scene: str = setting("", "scene folder (absolute path); `train` takes it from its SCENE argument", "path")
    downscale: int = setting(1, "photos are read at 1/downscale of their size", "factor",
                             rule=named_rule("factor"))
    max_width: int | None = setting(None, "every photo is scaled down further so that the widest is at most this "
                                          "wide; null: no cap", "pixels", at_least(1))
    protocol: str = setting("none", "which views are held out for evaluation (inceptiongs.evaluation.protocols): "
                                    "\"llff\" (every 8th), \"unstructured\" (most of one scarce cluster of views, "
                                    "a few of every other), \"none\"; `train` defaults to \"llff\"",
                            choices=PROTOCOLS)
    seed: int = setting(0, "seeds the view order, the initial points and every random draw of the strategies",
                        rule=named_rule("seed"))
    scarce_views: list[str] = setting([], "unstructured protocol: these views (names) form the scarce cluster "
                                          "instead of a seeded random one")
    exclude_photos: list[str] = setting([], "photos (names) left out entirely: neither trained on nor held out "
                                            "(`train --exclude-photos`, inceptiongs.train.view_fit)")
    iterations: int = setting(30_000, "length of the schedule; the milestones (steps) not given scale with it "
                                      "(short_run_schedule)", rule=named_rule("steps"))
    minutes: float | None = setting(None, "wall-clock budget: stops the loop early; given without iterations, "
                                          "the schedule is sized to it; null: no budget", rule=named_rule("minutes"))
    size_to_minutes: bool = setting(False, "the trainer sizes iterations (and the schedule) to the time budget "
                                           "from the measured step rate, and re-sizes it when the rate changes "
                                           "a lot; `train` sets it when minutes is given without iterations")
    device: str = setting("auto", "where training runs (inceptiongs.rasterizer.interface.resolve_device): \"cpu\" "
                                  "(numba), \"cuda\" (gsplat) or \"auto\" (cuda when a GPU, gsplat and a CUDA "
                                  "compiler are all there); stage II reads the stage-I run's", choices=DEVICES)
    strategy: str = setting("default", "densification strategy: \"default\" (3DGS adaptive density control), "
                                       "\"mcmc\" (3DGS-MCMC), \"dropgaussian\"; its own options are the section of "
                                       "its name", choices=STRATEGY_NAMES)
    pgsr: bool = setting(True, "PGSR's planar terms (the pgsr_terms section); false: plain 3DGS")
    blocks: int = setting(0, "train the scene in this many blocks on the ground plane, each an ordinary run in "
                             "RUN/blocks/, merged into RUN (`train --blocks`); 0: one run", "blocks", at_least(0))
    triangulate_init: bool = setting(True, "scenes without sparse points (LLFF): triangulate some from the "
                                           "training photos with the known poses (inceptiongs.train.triangulate) "
                                           "instead of starting from random points")

    learning_rates: LearningRates = section(LearningRates, LearningRates.__doc__)
    losses: Losses = section(Losses, Losses.__doc__)
    densification: Densification = section(Densification, Densification.__doc__)
    free_space: FreeSpace = section(FreeSpace, FreeSpace.__doc__)
    sh: SHSchedule = section(SHSchedule, SHSchedule.__doc__)
    pgsr_terms: PGSRTerms = section(PGSRTerms, PGSRTerms.__doc__)
    output: Output = section(Output, Output.__doc__)
    mcmc: MCMCOptions = section(MCMCOptions, MCMCOptions.__doc__)
    dropgaussian: DropGaussianOptions = section(DropGaussianOptions, DropGaussianOptions.__doc__)
    block: Block = section(Block, Block.__doc__)

    # A run's config.json written before the shell's scale floor was trained with a free shell:
    # without this its shell would be raised at the first step of a bootstrap or a resume.
    LEGACY_VALUES: ClassVar[dict] = {"free_space.sky_min_scale": 0.0}
    LEGACY_REASONS: ClassVar[dict] = {"free_space.sky_min_scale": "such a run's sky shell trained without "
                                                                  "the scale floor"}

    def __post_init__(self) -> None:
        # A section given as a dict (``TrainConfig(**config.to_json_dict())``) becomes its
        # dataclass; strict: an unknown key is a TypeError.
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, dict):
                setattr(self, f.name, f.default_factory(**value))

    @classmethod
    def load(cls, path: str | Path) -> "TrainConfig":
        """A run's config.json, strictly: nested (sections) or flat (every setting at the top
        level, as run folders were written before the sections: FLAT_KEYS); a setting the file
        lacks gets its LEGACY_VALUES entry, else its default."""
        return cls.from_json_dict(read_json_object(path, cls.CONFIG_KIND), str(path))

    @classmethod
    def from_json_dict(cls, data: dict, source: str) -> "TrainConfig":
        """A validated config from a run's config.json object (nested or flat, see :meth:`load`)."""
        data = nested_from_flat(data, source)
        for path, value in cls.LEGACY_VALUES.items():
            head, name = path.split(".")
            if isinstance(data.get(head, {}), dict):   # else the reader names the misfit
                data[head] = {name: value, **data.get(head, {})}
        return config_from_dict(cls, data, source, OPTIONS_PAGE).validate(source)

    def check_types(self, source: str) -> None:
        check_settings(self, source)

    def validate(self, source: str = "config") -> "TrainConfig":
        """Every setting's type, range and choices (check_settings), then the rules between settings."""
        self.check_types(source)
        if self.scarce_views and self.protocol != "unstructured":
            raise InputError(f"{source}: scarce_views need the unstructured protocol, got {self.protocol!r}")
        block = self.block
        if block.count:
            if self.blocks:
                raise InputError(f"{source}: a block (block.count {block.count}) is not itself split into blocks")
            if not block.index < block.count:
                raise InputError(f"{source}: block.index must be below block.count ({block.count}), got {block.index}")
            for name, size in (("origin", 3), ("u", 3), ("v", 3), ("cell", 4)):
                if len(getattr(block, name)) != size:
                    raise InputError(f"{source}: block.{name} must hold {size} numbers, got {getattr(block, name)}")
            if not block.photos:
                raise InputError(f"{source}: block.photos names no photo")
        elif block.start:
            raise InputError(f"{source}: block.start is for a block of a run in blocks (block.count > 0)")
        return self


# Keys of a flat config.json (run folders written before the sections) -> their dotted path: a
# setting keeps its name in its section, except the ones listed in _RENAMED.
_RENAMED = {
    "free_space": "free_space.enabled",
    **{f"lr_{name}": f"learning_rates.{name}" for name in
       ("means", "means_final", "log_scales", "quats", "opacity", "sh_dc", "sh_rest")},
    **{f"sh_{name}": f"sh.{name}" for name in ("degree_max", "increase_every", "spread_deg_per_degree", "min_views")},
    "mcmc_noise_lr": "mcmc.noise_lr",
    "mcmc_opacity_reg": "mcmc.opacity_reg",
    "mcmc_scale_reg": "mcmc.scale_reg",
    "mcmc_dead_opacity": "mcmc.dead_opacity",
    "mcmc_growth": "mcmc.growth",
    "drop_rate_max": "dropgaussian.rate_max",
}


def _flat_keys() -> dict[str, str]:
    renamed_to = set(_RENAMED.values())
    keys = {path.rsplit(".", 1)[-1]: path for path in setting_paths(TrainConfig)
            if "." in path and path not in renamed_to}
    return {**keys, **_RENAMED}


FLAT_KEYS: dict[str, str] = _flat_keys()
SECTION_NAMES = tuple(path.split(".")[0] for path in setting_paths(TrainConfig) if "." in path)


def nested_from_flat(data: dict, source: str) -> dict:
    """A config.json object with every flat key (FLAT_KEYS) moved to its section (a new dict;
    a nested file comes back as it is). A setting given both ways is an InputError."""
    data = {key: dict(value) if isinstance(value, dict) else value for key, value in data.items()}
    # A flat key that is also a section's name ("free_space": true, the switch) moves first, so
    # that its section is there for the other flat keys.
    for flat in sorted(FLAT_KEYS, key=lambda key: key not in SECTION_NAMES):
        if flat not in data or isinstance(data[flat], dict):   # "free_space": {...} is the section
            continue
        head, name = FLAT_KEYS[flat].split(".")
        value = data.pop(flat)
        inner = data.setdefault(head, {})
        if not isinstance(inner, dict):
            raise InputError(f"{source}: {head} must be an object (the {head} section's keys), got {inner!r}")
        if name in inner:
            raise InputError(f"{source}: {flat} and {head}.{name} both given")
        inner[name] = value
    return data


SHORT_RUN_RESET_MIN = 10_000
SHORT_RUN_MIN_GAUSSIANS = 100_000


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


# The milestones short_run_schedule scales (from the 30k-step defaults), as dotted paths.
SCHEDULE_FIELDS = ("densification.densify_from", "densification.densify_until", "densification.densify_every",
                   "densification.opacity_reset_every", "densification.max_gaussians", "sh.increase_every",
                   "pgsr_terms.normal_from", "pgsr_terms.multiview_from", "densification.prune_large_from")


def sized_schedule(config: TrainConfig, iterations: int) -> TrainConfig:
    """``config`` with ``iterations`` steps and the default milestones scaled to that length
    (what the command line builds); for runs sized to a time budget."""
    defaults = TrainConfig()
    base = with_values(dataclasses.replace(config, iterations=max(1, int(iterations))),
                       {path: config_value(defaults, path) for path in SCHEDULE_FIELDS})
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
    iterations, d = config.iterations, config.densification
    return with_values(config, {
        # Densifying before the first photometric fit has settled clones nearly everything
        # (every gradient is large at the start): wait 10 % of the run, at most 100 steps,
        # and average the gradients over at least 25 views.
        "densification.densify_from": scaled(d.densify_from, min(100, iterations // 10)),
        "densification.densify_until": scaled(d.densify_until, 2),
        "densification.densify_every": scaled(d.densify_every, min(25, max(1, iterations // 20))),
        # Opacities need hundreds of steps to recover from a reset, more than a short run can
        # spare; the floaters a reset removes are few when training starts from triangulated points.
        # So runs below SHORT_RUN_RESET_MIN steps never reset.
        # Size pruning starts once densification has had half its window to cover the scene
        # with smaller Gaussians (3DGS: 25 densifications before its first at step 3000). From
        # the first densification, it prunes early, large sky Gaussians before they are split:
        # a hole no gradient refills.
        "densification.prune_large_from": max(scaled(d.prune_large_from, 1),
                                              (scaled(d.densify_from, min(100, iterations // 10))
                                               + scaled(d.densify_until, 2)) // 2),
        "densification.opacity_reset_every": (iterations + 1 if iterations < SHORT_RUN_RESET_MIN
                                              else scaled(d.opacity_reset_every, max(50, iterations // 4))),
        # A short run on the CPU has no time to optimise millions of Gaussians (every step's
        # cost grows with them): the budget shrinks with the run, with a floor that still
        # resolves a photo-sized scene. On CUDA a step at 2M Gaussians costs milliseconds, so
        # the budget stays.
        "densification.max_gaussians": (d.max_gaussians if config.device == "cuda" else
                                        min(d.max_gaussians, max(SHORT_RUN_MIN_GAUSSIANS,
                                                                 int(d.max_gaussians * fraction)))),
        "sh.increase_every": scaled(config.sh.increase_every, 10),
        "pgsr_terms.normal_from": scaled(config.pgsr_terms.normal_from, 1),
        "pgsr_terms.multiview_from": scaled(config.pgsr_terms.multiview_from, 1),
    })


# Settings a settings file (`train --config`) may not give: the command line sets them.
COMMAND_LINE_SETTINGS = {"scene": "the SCENE argument of `train` names the scene",
                         "size_to_minutes": "the schedule is sized to the time budget when minutes is given "
                                            "without iterations"}


def read_settings(path: str | Path) -> dict:
    """The settings a `train --config` file gives, {dotted path: value}: a JSON object of any
    subset of TrainConfig's keys, sections nested ({"losses": {"lambda_dssim": 0.3}}), read
    strictly (config_from_dict; a flat key of a run's older config.json is unknown here, with
    its section's path as the hint)."""
    data = read_json_object(path, "train settings")
    for key, why in COMMAND_LINE_SETTINGS.items():
        if key in data:
            raise InputError(f"{path}: {key} is not a settings key ({why})")
    config = config_from_dict(TrainConfig, data, str(path), OPTIONS_PAGE, aliases=FLAT_KEYS)
    return {key: config_value(config, key) for key in flat_values(data)}
