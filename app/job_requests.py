"""What the Training panel's job buttons build: stage-I training of the scene into a fresh run
folder, "Resume" of the open run from its newest checkpoint (of the open bootstrap result stopped
before its end: the bootstrap, into the same folder), stage-II bootstrapping of the flagged
views into a fresh folder beside the run, and the same-time baseline of a bootstrap result (folders:
app/runs.py). Built when the user presses the button, so flags made since the viewer opened count;
each comes as a :class:`JobRequest`, the question asked before it runs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from inceptiongs.errors import InputError

from .capabilities import one_line, training_unavailable
from .job_settings import VIEWER_EVAL_EVERY, JobSettings
from .progress import format_duration
from .runs import (bootstrap_resume_refusal, new_baseline_dir, new_bootstrap_dir, new_train_dir,
                   resume_blocked_reason)


def train_job_for(source, settings: JobSettings | None = None):
    """A new stage-I run of the source's scene in a fresh run folder where `inceptiongs train`
    writes (./runs/NAME[_N], or NAME[_N] in the runs folder the user chose: runs.new_train_dir)."""
    from inceptiongs.train.job import TrainJob

    if source.scene is None:
        raise InputError(f"{source.path}: no scene to train (open a scene folder)")
    config = (settings or JobSettings()).train_config(source.scene.root)
    return TrainJob(config=config, run_dir=new_train_dir(source.scene.root, getattr(source, "runs_dir", None)))


def resume_job_for(run_dir: Path | None, settings: JobSettings | None = None):
    """Continue ``run_dir`` from its newest checkpoint with its stored config, its schedule and
    its own time budget, as `inceptiongs train --resume` without --minutes does (the same
    function builds it). ``settings`` is not read: the dialog's budget is for new runs."""
    from inceptiongs.commands.train import resumed_config
    from inceptiongs.runs.checkpoint import latest_checkpoint
    from inceptiongs.train.job import TrainJob

    if run_dir is None or latest_checkpoint(Path(run_dir)) is None:
        raise InputError(f"{run_dir or 'this source'}: no run with a checkpoint to resume")
    blocked = resume_blocked_reason(run_dir)
    if blocked is not None:
        raise InputError(f"{run_dir}: a bootstrap result; {blocked}")
    return TrainJob(config=resumed_config(Path(run_dir)), run_dir=Path(run_dir), resume=True)


def bootstrap_resume_job_for(out_dir: Path | None):
    """Continue the bootstrap stopped in ``out_dir`` from its newest checkpoint into the same
    folder, with the targets and settings it was started with (RUN2/bootstrap/targets.json and
    config.json), as `inceptiongs bootstrap RUN --out RUN2 --resume` does; InputError (one line)
    for what is not continued (runs.bootstrap_resume_refusal) or a stage-I run no longer there."""
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.job import BootstrapJob
    from inceptiongs.bootstrap.runner import BLOCKS_NOT_RESUMED
    from inceptiongs.bootstrap.summary_file import BOOTSTRAP_DIR, read_summary
    from inceptiongs.commands.bootstrap import run_in_blocks

    if out_dir is None:
        raise InputError("no bootstrap result is open to resume")
    out_dir = Path(out_dir)
    refused = bootstrap_resume_refusal(out_dir)
    if refused is not None:
        raise InputError(f"{out_dir}: {refused}")
    stage1 = (read_summary(out_dir) or {}).get("run")
    if not isinstance(stage1, str) or not (Path(stage1) / "config.json").is_file():
        raise InputError(f"{out_dir}: its stage-I run ({stage1}) is not there (moved or deleted)")
    if run_in_blocks(Path(stage1)):    # as the command refuses `--resume` there
        raise InputError(f"{out_dir}: {BLOCKS_NOT_RESUMED}; bootstrap its flagged views again (into a new folder)")
    saved = out_dir / BOOTSTRAP_DIR / "config.json"
    config = BootstrapConfig.load(saved) if saved.is_file() else BootstrapConfig()  # the settings it started with
    return BootstrapJob(run_dir=Path(stage1), out_dir=out_dir, config=config, resume=True)


def baseline_job_for(verdict):
    """The same-time baseline of the bootstrap result ``verdict`` (verdict.Verdict) is about: its
    stage-I run continued on the photos alone for the bootstrap's wall time, into a fresh
    ``RUN_baseline[_N]`` beside the stage-I run (where `inceptiongs demo` puts it, and where
    the verdict looks). Of a run in blocks, the blocks the bootstrap refined are continued, as its
    summary names them."""
    from inceptiongs.bootstrap.job import BaselineJob
    from inceptiongs.bootstrap.summary_file import read_summary

    if verdict is None or verdict.stage1_run is None or not verdict.seconds:
        raise InputError("no bootstrap result with a known time and stage-I run to run a baseline for")
    stage1 = Path(verdict.stage1_run)
    if not (stage1 / "config.json").is_file():
        raise InputError(f"{stage1}: the bootstrap's stage-I run is not there (moved or deleted)")
    refined = (read_summary(verdict.out_dir) or {}).get("blocks_refined")
    blocks = tuple(refined) if isinstance(refined, list) and refined and all(
        isinstance(index, int) and not isinstance(index, bool) for index in refined) else None
    return BaselineJob(run_dir=stage1, out_dir=new_baseline_dir(stage1), seconds=float(verdict.seconds),
                       eval_every=VIEWER_EVAL_EVERY, blocks=blocks)


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


@dataclass
class JobRequest:
    """A job asked for and not yet confirmed: the panel shows ``question`` with "start the job" /
    "do not start" (panels.draw_job_question) and nothing runs before the first is pressed (a
    mis-click never starts minutes of work). ``job``: built when asked (what could not be built
    was said at once); ``out_dir``: where it writes; ``message``: the status once it starts."""

    kind: str       # "training", "resume", "bootstrap resume", "bootstrap", "baseline"
    job: object
    out_dir: Path | None
    message: str
    question: str


def budget_text(minutes: float | None, iterations: int | None = None) -> str:
    """"for at most 3 min 00 s", "for 2000 iterations" or "" (what a job's question says of its length)."""
    if minutes is not None:
        return f"for at most {format_duration(60.0 * minutes)}"
    return f"for {iterations} iterations" if iterations else ""


def why_no_training(source, factory) -> str | None:
    """Why "train (new run)" is greyed out, or None (a job ``factory`` decides for itself)."""
    return None if factory is not None else training_unavailable(source)


def training_request(source, settings: JobSettings, factory, status) -> JobRequest | None:
    """A new stage-I run of ``source`` (``settings``: the job dialog's; ``factory``: source -> job,
    None: train_job_for) in a fresh run folder; None (said in ``status``) when it cannot be built."""
    try:
        job = factory(source) if factory is not None else train_job_for(source, settings)
    except Exception as exc:  # noqa: BLE001 - a job that cannot be built is shown, not fatal
        status.text = f"training could not start: {one_line(exc)}"
        return None
    out_dir = getattr(job, "run_dir", None)
    config = getattr(job, "config", None)
    length = budget_text(getattr(config, "minutes", None), getattr(config, "iterations", None))
    where = f" into {out_dir}" if out_dir else ""
    return JobRequest("training", job, out_dir, f"training into {out_dir}" if out_dir else "training",
                      f"Train a new run{where}{' ' + length if length else ''}?")


def resume_request(run_dir: Path | None, settings: JobSettings, status) -> JobRequest | None:
    """Continue ``run_dir`` from its newest checkpoint; None (said in ``status``) when it cannot."""
    try:
        job = resume_job_for(run_dir, settings)
    except Exception as exc:  # noqa: BLE001 - shown in the status line
        status.text = f"resume could not start: {exc}"
        return None
    return JobRequest("resume", job, job.run_dir, f"resuming {job.run_dir}",
                      f"Resume {job.run_dir} from its newest checkpoint with its saved plan?")


def bootstrap_resume_request(out_dir: Path | None, status) -> JobRequest | None:
    """Continue the bootstrap stopped in ``out_dir`` (the open result) into the same folder; None
    (said in ``status``, one line) when it is not continued."""
    from inceptiongs.runs.checkpoint import list_checkpoints

    try:
        job = bootstrap_resume_job_for(out_dir)
    except Exception as exc:  # noqa: BLE001 - shown in the status line
        status.text = f"bootstrap resume could not start: {one_line(exc)}"
        return None
    step = list_checkpoints(job.out_dir)[-1][0]   # there: bootstrap_resume_job_for refuses a folder without one
    length = budget_text(job.config.minutes, None)
    return JobRequest("bootstrap resume", job, job.out_dir,
                      f"resuming the bootstrap in {job.out_dir} at iteration {step} with its saved targets and "
                      f"settings",
                      f"Resume the bootstrap stopped in {job.out_dir} at iteration {step}, into the same folder, with "
                      f"its saved targets and settings{' (' + length + ' in all)' if length else ''}?")


def bootstrap_request(run_dir: Path | None, flags, settings: JobSettings, status, config=None) -> JobRequest | None:
    """Stage II of ``run_dir`` on the views flagged in ``flags`` (a flags.FlagBook; config: a
    BootstrapConfig, default ``settings``'); None (said in ``status``) when it cannot."""
    try:
        config = config or settings.bootstrap_config()
        job = bootstrap_job_for(run_dir, flags.file, config)
    except Exception as exc:  # noqa: BLE001 - shown in the status line, never fatal
        status.text = f"bootstrap could not start: {exc}"
        return None
    count = len(flags.items)
    length = budget_text(getattr(config, "minutes", None), None)
    return JobRequest("bootstrap", job, job.out_dir,
                      f"bootstrapping {count} flagged view(s) of {job.run_dir}",
                      f"Bootstrap {count} flagged view(s) of {job.run_dir} into {job.out_dir}"
                      f"{' ' + length if length else ''}?")


def baseline_request(verdict, status) -> JobRequest | None:
    """The same-time baseline of the bootstrap ``verdict`` (verdict.Verdict) is about; None (said
    in ``status``) when it cannot run."""
    try:
        job = baseline_job_for(verdict)
    except Exception as exc:  # noqa: BLE001 - shown in the status line
        status.text = f"baseline could not start: {one_line(exc)}"
        return None
    return JobRequest("baseline", job, job.out_dir,
                      f"baseline: {job.run_dir} continued on the photos alone for {format_duration(job.seconds)}",
                      f"Run the same-time baseline: {job.run_dir} continued on the photos alone for "
                      f"{format_duration(job.seconds)} (the bootstrap's time) into {job.out_dir}?")
