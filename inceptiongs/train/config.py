"""Training hyper-parameters: one dataclass, written to RUN/config.json resolved.

Schedules are in iterations (not seconds) so that a run is reproducible from its seed and
a resumed run follows exactly the schedule of an uninterrupted one; ``minutes`` only stops
the loop early.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from ..io.config_json import load_config, save_config
from ..errors import InputError

PROTOCOLS = ("llff", "unstructured", "none")


@dataclass
class TrainConfig:
    scene: str = ""
    downscale: int = 1
    max_width: int | None = None
    protocol: str = "none"
    seed: int = 0
    # Unstructured protocol: these views (names) form the scarce cluster instead of a seeded
    # random one (the demo declares the cameras of its thin region).
    scarce_views: list[str] = dataclasses.field(default_factory=list)
    iterations: int = 30_000
    minutes: float | None = None
    pgsr: bool = True
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
    random_background: bool = False

    # --- densification ---------------------------------------------------------------------
    densify_from: int = 500
    densify_until: int = 15_000
    densify_every: int = 100
    densify_grad_threshold: float = 2e-4   # |d loss / d mean2d| in NDC units, averaged over views
    percent_dense: float = 0.01            # clone below, split above this fraction of the extent
    prune_opacity: float = 0.005
    prune_screen_radius: float = 20.0      # pixels (after the first opacity reset)
    prune_world_fraction: float = 0.1      # of the extent
    opacity_reset_every: int = 3_000
    max_gaussians: int = 2_000_000

    # --- SH schedule ------------------------------------------------------------------------
    sh_degree_max: int = 3
    sh_increase_every: int = 1_000

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

    def validate(self, source: str = "config") -> "TrainConfig":
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
        if not 0 <= self.sh_degree_max <= 3:
            raise InputError(f"{source}: sh_degree_max must be in 0..3, got {self.sh_degree_max}")
        for name in ("densify_every", "sh_increase_every", "multiview_every", "log_every",
                     "eval_every", "checkpoint_every", "opacity_reset_every"):
            if getattr(self, name) < 1:
                raise InputError(f"{source}: {name} must be >= 1")
        return self

    def to_json_dict(self) -> dict:
        return dataclasses.asdict(self)

    def save(self, path: str | Path) -> None:
        save_config(self, path)

    @staticmethod
    def load(path: str | Path) -> "TrainConfig":
        return load_config(TrainConfig, path, "config")


SHORT_RUN_RESET_MIN = 10_000
SHORT_RUN_MIN_GAUSSIANS = 100_000


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
