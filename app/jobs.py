"""The jobs the viewer runs on a thread, built from the job dialog's settings: stage-I training
of the scene into a fresh run folder, "Resume" of the open run from its newest checkpoint, and
stage-II bootstrapping of the flagged views into a fresh folder beside the run (app/runs.py).
Built when the user presses the button, so flags made during the session count."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

from inceptiongs.errors import InputError

from .runs import new_bootstrap_dir, new_train_dir, resume_blocked_reason

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
    strategy: str = "default"       # inceptiongs.train.config.STRATEGY_NAMES
    sky_shell: bool | None = None   # None: TrainConfig's default (as `inceptiongs train` without the flag)
    # Photos the next run leaves out (--exclude-photos): the Training panel fills it with the open
    # run's poorly fit photos when the user asks.
    exclude_photos: list[str] = dataclasses.field(default_factory=list)
    # Stage II.
    bootstrap_minutes: float | None = 4.0
    bootstrap_iterations: int = 300
    k: int = 0                      # 0: the bootstrap's own default
    l: int = 0
    prior_minutes: float = 2.0

    def train_config(self, scene_root: Path):
        """The stage-I config as `inceptiongs train` builds it: a typed length is a fixed schedule
        (--iterations); 0 with a budget starts from the command line's first guess and lets the
        trainer re-size it to the budget (--minutes alone); 0 without one: the default length."""
        from inceptiongs.train.config import TrainConfig, schedule_length, short_run_schedule

        iterations, sized = schedule_length(self.iterations or None, self.minutes)
        sky_shell = TrainConfig.sky_shell if self.sky_shell is None else self.sky_shell
        config = TrainConfig(scene=str(Path(scene_root).resolve()), downscale=self.downscale,
                             protocol=self.protocol, iterations=iterations, minutes=self.minutes,
                             strategy=self.strategy, size_to_minutes=sized, sky_shell=sky_shell,
                             exclude_photos=list(self.exclude_photos))
        config = short_run_schedule(config.validate("job settings"))
        return dataclasses.replace(config, eval_every=VIEWER_EVAL_EVERY,
                                   log_every=math.gcd(config.log_every, VIEWER_EVAL_EVERY))

    def bootstrap_config(self):
        from inceptiongs.bootstrap.config import BootstrapConfig

        defaults = BootstrapConfig()
        return BootstrapConfig(iterations=self.bootstrap_iterations, minutes=self.bootstrap_minutes,
                               k=self.k or None, l=self.l or None, prior_minutes=self.prior_minutes,
                               eval_every=VIEWER_EVAL_EVERY,
                               log_every=math.gcd(defaults.log_every, VIEWER_EVAL_EVERY)).validate()


def train_job_for(source, settings: JobSettings | None = None):
    """A new stage-I run of the source's scene in a fresh <scene work dir>/runs/train[_N]."""
    from inceptiongs.train.job import TrainJob

    if source.scene is None:
        raise InputError(f"{source.path}: no scene to train (open a scene folder)")
    config = (settings or JobSettings()).train_config(source.scene.root)
    return TrainJob(config=config, run_dir=new_train_dir(source.work_dir))


def resume_job_for(run_dir: Path | None, settings: JobSettings | None = None):
    """Continue ``run_dir`` from its newest checkpoint with its stored config (only the time
    budget may change, as with `inceptiongs train --resume`)."""
    from inceptiongs.train.checkpoint import latest_checkpoint
    from inceptiongs.train.config import TrainConfig
    from inceptiongs.train.job import TrainJob

    if run_dir is None or latest_checkpoint(Path(run_dir)) is None:
        raise InputError(f"{run_dir or 'this source'}: no run with a checkpoint to resume")
    blocked = resume_blocked_reason(run_dir)
    if blocked is not None:
        raise InputError(f"{run_dir}: a bootstrap result; {blocked}")
    config = TrainConfig.load(Path(run_dir) / "config.json")
    config = dataclasses.replace(config, minutes=(settings or JobSettings()).minutes)
    return TrainJob(config=config, run_dir=Path(run_dir), resume=True)


def bootstrap_job_for(run_dir: Path | None, flags_file: Path, config=None):
    """Stage II of ``run_dir`` on the views flagged in ``flags_file`` into a fresh folder
    (config: a BootstrapConfig, default the command line's defaults)."""
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.job import BootstrapJob
    from inceptiongs.io.flags import read_flag_cameras

    if run_dir is None:
        raise InputError("bootstrapping needs a trained run (train first)")
    if not Path(flags_file).is_file() or not read_flag_cameras(flags_file):
        raise InputError("no flagged views: flag the bad views first (F or right-click)")
    return BootstrapJob(run_dir=Path(run_dir), out_dir=new_bootstrap_dir(run_dir), targets_file=Path(flags_file),
                        config=config or BootstrapConfig())


def start_bootstrap(viewer, config=None) -> None:
    """The viewer's "Bootstrap" action: stage II on the flagged views of the open run as the
    live job (config: default the job dialog's settings)."""
    if viewer.training is not None and viewer.training.alive:
        viewer.status = "a job is running: stop it before bootstrapping"
        return
    try:
        job = bootstrap_job_for(viewer.run_dir, viewer.flags_file, config or viewer.job_settings.bootstrap_config())
    except Exception as exc:  # noqa: BLE001 - shown in the status line, never fatal
        viewer.status = f"bootstrap could not start: {exc}"
        return
    viewer.start_job(job, job.out_dir, f"bootstrapping {len(viewer.flags)} flagged view(s) of {job.run_dir}")

