"""Bootstrapping as a job the viewer runs on a thread (an :class:`inceptiongs.live.Job`, like train.job.TrainJob)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError
from ..live import JobControl, JobPublisher, SnapshotBox
from .config import BootstrapConfig


@dataclass
class BootstrapJob:
    """Stage II on ``run_dir`` into ``out_dir`` for the views flagged in ``targets_file`` (None:
    the scene's flags.json, else the split's j*), publishing a snapshot (numpy copies) every
    ``snapshot_every`` refinement steps. ``resume``: continue the stopped bootstrap in ``out_dir``
    from its newest checkpoint with the targets it was started with (RUN2/bootstrap/targets.json;
    ``targets_file`` is not read), as `inceptiongs bootstrap RUN --out RUN2 --resume` does."""

    run_dir: Path
    out_dir: Path | None = None
    targets_file: Path | None = None
    config: BootstrapConfig = field(default_factory=BootstrapConfig)
    snapshot_every: int = 5
    overwrite: bool = False  # replace a result already in out_dir (else refused)
    resume: bool = False

    def run(self, box: SnapshotBox, control: JobControl) -> None:
        from ..runs.folder import next_free_folder
        from .runner import default_out_dir, run_bootstrap
        from .stage1 import load_stage1

        out = JobPublisher(box)
        if self.resume and self.out_dir is None:
            raise InputError(f"{self.run_dir}: resuming a bootstrap needs the folder it wrote (out_dir)")
        # No folder given: a fresh one, never an earlier result.
        out_dir = Path(self.out_dir) if self.out_dir is not None else next_free_folder(default_out_dir(self.run_dir))
        stage1 = load_stage1(self.run_dir)
        targets = self.targets(stage1, out_dir)
        resumed = "resumed, " if self.resume else ""
        out.log(f"bootstrap: {resumed}{len(targets)} target view(s) ({', '.join(t.name for t in targets)}) "
                f"-> {out_dir}")
        if stage1.config.blocks:
            self.run_blocks(stage1, out_dir, targets, control, out)
            return
        result = run_bootstrap(stage1, out_dir, targets, self.config, control=control,
                               on_snapshot=out.snapshot, snapshot_every=self.snapshot_every, log=out.log,
                               progress=False, overwrite=self.overwrite, resume=self.resume)
        used = (f"{result.virtual_views} virtual views" if result.supervised_views in (None, result.virtual_views)
                else f"{result.supervised_views} of {result.virtual_views} virtual views used (the others' photos "
                     f"agree with the render better than with each other)")
        out.finish("bootstrap", result.iteration, result.finished, result.last_eval, f"{used}, {out_dir}")

    def targets(self, stage1, out_dir: Path) -> list:
        """The views this job repairs: those flagged (``targets_file``, resolved as the command
        resolves --targets), or a resumed bootstrap's own; InputError (one line) for a resume of
        what no bootstrap job continues (a run in blocks, a same-time baseline)."""
        from .runner import BLOCKS_NOT_RESUMED, resolve_targets, saved_targets

        if not self.resume:
            return resolve_targets(stage1.scene, stage1.split, self.targets_file, None, self.config.rounds,
                                   run_dir=self.run_dir)
        if stage1.config.blocks:
            raise InputError(f"{out_dir}: {BLOCKS_NOT_RESUMED}; bootstrap its flagged views again")
        saved = saved_targets(out_dir)
        if not saved:
            raise InputError(f"{out_dir}: no bootstrap targets saved (a same-time baseline is not a bootstrap to "
                             f"resume)")
        return saved

    def run_blocks(self, stage1, out_dir: Path, targets, control: JobControl, out: JobPublisher) -> None:
        """A run trained in blocks: only the blocks the flagged views see are refined, as `inceptiongs
        bootstrap` refines them (blocks.bootstrap_blocks; the viewer's job refined the whole merged
        model). A block's own model is not the scene, so no snapshot is shown while it is refined:
        the merged result is, once written."""
        from ..runs.load import load_run
        from .blocks import bootstrap_blocks
        from .runner import run_bootstrap

        result = bootstrap_blocks(stage1, out_dir, targets, self.config,
                                  lambda run, block_out, block_targets, block_config: run_bootstrap(
                                      run, block_out, block_targets, block_config, control=control, log=out.log,
                                      progress=False, overwrite=self.overwrite), out.log, progress=False)
        iteration = max((block.iteration for block in result.results), default=stage1.config.iterations)
        out.snapshot(iteration, load_run(out_dir, warn=out.log)[0], {})
        refined = ", ".join(str(index + 1) for index in result.refined)
        out.finish("bootstrap", iteration, result.finished, result.last_eval,
                   f"block(s) {refined} refined, the others kept, {out_dir}")


# A baseline job runs for its time, not for a number of steps: its step cap is out of reach.
BASELINE_STEP_CAP = 100_000


@dataclass
class BaselineJob:
    """The same-time baseline of a bootstrap as a job: stage I (``run_dir``) continued on the
    photos alone (runner.baseline_run's loop: the bootstrap's continuation schedule, no virtual
    view) for ``seconds`` of wall time (the bootstrap's: its summary's wall_s) into ``out_dir``,
    publishing a snapshot every ``snapshot_every`` steps."""

    run_dir: Path
    out_dir: Path
    seconds: float
    eval_every: int = 0
    log_every: int = 1
    snapshot_every: int = 5
    # A run in blocks: the blocks the bootstrap refined (its summary's blocks_refined), continued
    # here, the others kept, so the baseline starts where the bootstrap did.
    blocks: tuple | None = None

    def run(self, box: SnapshotBox, control: JobControl) -> None:
        from .runner import run_bootstrap
        from .stage1 import load_stage1

        out = JobPublisher(box)
        config = BootstrapConfig(iterations=BASELINE_STEP_CAP, minutes=self.seconds / 60.0, rounds=1,
                                 log_every=self.log_every, eval_every=self.eval_every).validate()
        out.log(f"baseline: stage I continued on the photos alone for {self.seconds:.0f} s -> {self.out_dir}")
        stage1 = load_stage1(self.run_dir)
        if stage1.config.blocks:
            self.run_blocks(stage1, config, control, out)
            return
        result = run_bootstrap(stage1, Path(self.out_dir), None, config, control=control,
                               on_snapshot=out.snapshot, snapshot_every=self.snapshot_every, log=out.log,
                               progress=False)
        out.finish("baseline", result.iteration, result.finished, result.last_eval, str(self.out_dir))

    def run_blocks(self, stage1, config: BootstrapConfig, control: JobControl, out: JobPublisher) -> None:
        """A run trained in blocks: the bootstrap's blocks continued on their photos alone, sharing
        its time, and merged with the others (blocks.bootstrap_blocks without targets), as
        :meth:`BootstrapJob.run_blocks` shows the merged result once written."""
        from ..runs.load import load_run
        from .blocks import bootstrap_blocks
        from .runner import run_bootstrap

        out_dir = Path(self.out_dir)
        result = bootstrap_blocks(stage1, out_dir, None, config,
                                  lambda run, block_out, _targets, block_config: run_bootstrap(
                                      run, block_out, None, block_config, control=control, log=out.log,
                                      progress=False), out.log, blocks=self.blocks, progress=False)
        iteration = max((block.iteration for block in result.results), default=stage1.config.iterations)
        out.snapshot(iteration, load_run(out_dir, warn=out.log)[0], {})
        out.finish("baseline", iteration, result.finished, result.last_eval, str(out_dir))
