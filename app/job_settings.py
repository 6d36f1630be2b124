"""The job dialog's settings (:class:`JobSettings`) and the run configurations they make: the
command lines' main settings, with the held-out views evaluated often enough for the Training
panel's curve."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

# The dialog's "schedule iterations" when the schedule is sized to the time budget, as
# `inceptiongs train --minutes M` without --iterations (a typed length is a fixed schedule).
SIZED_TO_BUDGET = 0
# The viewer's jobs evaluate the held-out views this often (the command lines: every 500 steps
# for stage I, only per round for stage II), so the panel's PSNR curve has points within a
# few-minute budget. Evaluation time does not count against the training budget.
VIEWER_EVAL_EVERY = 50


@dataclass
class JobSettings:
    """The job dialog: the command lines' main settings. minutes: the time budget (None: run
    the whole schedule); iterations: the stage-I schedule length, SIZED_TO_BUDGET (0) to size it
    to the budget from the measured step rate (no budget: the command line's default length);
    bootstrap_iterations: refinement steps per round (stage II)."""

    minutes: float | None = 3.0
    iterations: int = SIZED_TO_BUDGET
    downscale: int = 2
    protocol: str = "unstructured"  # held-out views, so the panel can plot their PSNR
    strategy: str = "default"       # inceptiongs.runs.config.STRATEGY_NAMES
    sky_shell: bool | None = None   # None: TrainConfig's default (free_space.sky_shell, as `inceptiongs train`)
    # Photos the next run leaves out (--exclude-photos): the Training panel fills it with the open
    # run's poorly fit photos when the user asks.
    exclude_photos: list[str] = dataclasses.field(default_factory=list)
    # Stage II.
    bootstrap_minutes: float | None = 4.0
    bootstrap_iterations: int = 300
    k: int = 0                      # 0: the bootstrap's own default
    l: int = 0
    prior_minutes: float = 2.0
    # Photo steps only where the outlook says nothing to repair, first while stage I still rises fast
    # (BootstrapConfig.follow_outlook); off: virtual views from the first step.
    follow_outlook: bool = True

    def train_config(self, scene_root: Path):
        """The stage-I config as `inceptiongs train` builds it: a typed length is a fixed schedule
        (--iterations); 0 with a budget starts from the command line's first guess and lets the
        trainer re-size it to the budget (--minutes alone); 0 without one: the default length."""
        from inceptiongs.io.config_json import with_values
        from inceptiongs.runs.config import FreeSpace, TrainConfig, schedule_length, short_run_schedule

        iterations, sized = schedule_length(self.iterations or None, self.minutes)
        sky_shell = FreeSpace.sky_shell if self.sky_shell is None else self.sky_shell
        config = TrainConfig(scene=str(Path(scene_root).resolve()), downscale=self.downscale,
                             protocol=self.protocol, iterations=iterations, minutes=self.minutes,
                             strategy=self.strategy, size_to_minutes=sized,
                             exclude_photos=list(self.exclude_photos))
        config = short_run_schedule(with_values(config, {"free_space.sky_shell": sky_shell}).validate("job settings"))
        return with_values(config, {"output.eval_every": VIEWER_EVAL_EVERY,
                                    "output.log_every": math.gcd(config.output.log_every, VIEWER_EVAL_EVERY)})

    def bootstrap_config(self):
        from inceptiongs.bootstrap.config import BootstrapConfig

        defaults = BootstrapConfig()
        return BootstrapConfig(iterations=self.bootstrap_iterations, minutes=self.bootstrap_minutes,
                               k=self.k or None, l=self.l or None, prior_minutes=self.prior_minutes,
                               follow_outlook=self.follow_outlook, eval_every=VIEWER_EVAL_EVERY,
                               log_every=math.gcd(defaults.log_every, VIEWER_EVAL_EVERY)).validate()
