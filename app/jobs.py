"""The jobs the viewer runs on a thread, built from the job dialog's settings: stage-I training
of the scene into a fresh run folder, "Resume" of the open run from its newest checkpoint, and
stage-II bootstrapping of the flagged views into a fresh folder beside the run (app/runs.py).
Built when the user presses the button, so flags made since the viewer opened count.
:class:`Jobs` is the Training panel's object: the live job, its hand-off and the open run."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path

from inceptiongs.errors import InputError
from inceptiongs.train.view_fit import read_poorly_fit

from .capabilities import one_line, training_unavailable
from .live_training import LiveTraining
from .progress import closing_line, final_scores, format_duration, plan_of, replan_line, resume_line, run_scores
from .runs import (describe_model, new_baseline_dir, new_bootstrap_dir, new_train_dir, resume_blocked_reason,
                   run_dir_of, runs_folder)
from .sources import open_scene_run
from .verdict import read_verdict, verdict_line

# The dialog's "schedule iterations" when the schedule is sized to the time budget, as
# `inceptiongs train --minutes M` without --iterations (a typed length is a fixed schedule).
SIZED_TO_BUDGET = 0
# While a job trains, its snapshots replace the model at most this often: each one costs a
# re-render, and the job publishes faster than software GL can draw them.
TRAINING_REFRESH_SECONDS = 0.3
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


def baseline_job_for(verdict):
    """The same-time baseline of the bootstrap result ``verdict`` (verdict.Verdict) is about: its
    stage-I run continued on the photos alone for the bootstrap's wall time, into a fresh
    ``RUN_baseline[_N]`` beside the stage-I run (where `inceptiongs demo` puts it, and where
    the verdict looks)."""
    from inceptiongs.bootstrap.job import BaselineJob

    if verdict is None or verdict.stage1_run is None or not verdict.seconds:
        raise InputError("no bootstrap result with a known time and stage-I run to run a baseline for")
    stage1 = Path(verdict.stage1_run)
    if not (stage1 / "config.json").is_file():
        raise InputError(f"{stage1}: the bootstrap's stage-I run is not there (moved or deleted)")
    return BaselineJob(run_dir=stage1, out_dir=new_baseline_dir(stage1), seconds=float(verdict.seconds),
                       eval_every=VIEWER_EVAL_EVERY)


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
    "do not start" (panels._job_question) and nothing runs before the first is pressed (a
    mis-click never starts minutes of work). ``job``: built when asked (what could not be built
    was said at once); ``out_dir``: where it writes; ``message``: the status once it starts."""

    kind: str       # "training", "resume", "bootstrap", "baseline"
    job: object
    out_dir: Path | None
    message: str
    question: str


def budget_text(minutes: float | None, iterations: int | None = None) -> str:
    """"for at most 3 min 00 s", "for 2000 iterations" or "" (what a job's question says of its length)."""
    if minutes is not None:
        return f"for at most {format_duration(60.0 * minutes)}"
    return f"for {iterations} iterations" if iterations else ""


class Jobs:
    """The viewer's job: the dialog's settings, the live job (training: a LiveTraining, None
    before the first), the open run (what Resume continues and Bootstrap repairs) with the
    training photos it fits poorly, and the hand-off of the job's snapshots to the view.

    ``view``: the view.View whose model the job's snapshots replace; ``flags``: the
    flags.FlagBook the bootstrap repairs; ``status``: the status line; ``retitle``: called when
    what the window title names changes (window_title); ``factory``: source -> job for "train"
    (None: the dialog's stage-I training)."""

    def __init__(self, view, flags, status, retitle, factory=None) -> None:
        self.view, self.flags, self.status, self.retitle = view, flags, status, retitle
        self.factory = factory
        self.settings = JobSettings()
        self.training: LiveTraining | None = None
        self.run_dir = run_dir_of(view.source)  # the open run: what Resume continues, Bootstrap repairs
        # The open run's training photos it fits poorly (image name -> PSNR, worst first): their
        # frustums are drawn apart and the Training panel steps through them.
        self.poorly_fit: dict[str, float] = {}
        self.poorly_fit_shown = -1  # which of them "next poorly fit photo" went to last
        self.out_dir: Path | None = None  # where the current (or last) job writes
        self.reported = False  # the closing line of the last job has replaced the status
        self.fold_settings = False  # panels.py closes the job dialog once a job has started
        self.last_snapshot_time = -1e9  # when a job's snapshot last replaced the model
        self.title_state: str | None = None  # the job state the window title names
        self.run_labels: dict = {}  # (run, its log's mtime) -> the panel's line for it (run_label)
        # While a job trains, the share of the time the viewer leaves to it: after a frame that
        # took t seconds the viewer waits t * u / (1 - u) for input before drawing the next (as
        # nerfview's "train util"). 0.9: the viewer draws about 10 % of the time.
        self.training_utilisation = 0.95
        # The bootstrap's verdict (verdict.Verdict: scores before / after / same-time baseline,
        # the flagged views' images); what the live bootstrap started from, for its images.
        self.verdict = read_verdict(self.run_dir)
        self.bootstrap_base: dict | None = None  # the Gaussians shown when it started (stage I)
        self.bootstrap_views: list = []           # [(flag name, Camera)] it repairs
        self.verdict_images_due = self.verdict is not None  # the viewer renders them on its next frame
        self.pending: JobRequest | None = None  # a job asked for, waiting for the user's "start"
        self.baseline_of: Path | None = None  # the bootstrap result a running baseline was asked for
        self.read_view_fit()

    @property
    def alive(self) -> bool:
        """A job has started and not ended (paused counts)."""
        return self.training is not None and self.training.alive

    def running(self) -> bool:
        """A job is training now (started, not paused, not ended)."""
        return self.alive and not self.training.control.pause.is_set()

    def window_title(self) -> str:
        """The window's title: the model shown, the file or the job folder it comes from."""
        if self.training is not None and self.out_dir is not None:
            shown = f"{self.out_dir} ({self.training.state})"
        else:
            shown = describe_model(self.view.source, self.run_dir)
        self.title_state = None if self.training is None else self.training.state
        return f"InceptionGS — {shown}"

    # --- starting --------------------------------------------------------------------------------
    def training_unavailable(self) -> str | None:
        """Why "train (new run)" is greyed out, or None (a job factory decides for itself)."""
        return None if self.factory is not None else training_unavailable(self.view.source)

    def training_request(self) -> JobRequest | None:
        """A new stage-I run (the job dialog's settings) in a fresh run folder; None (said in the
        status line) when it cannot be built."""
        try:
            job = (self.factory(self.view.source) if self.factory is not None
                   else train_job_for(self.view.source, self.settings))
        except Exception as exc:  # noqa: BLE001 - a job that cannot be built is shown, not fatal
            self.status.text = f"training could not start: {one_line(exc)}"
            return None
        out_dir = getattr(job, "run_dir", None)
        config = getattr(job, "config", None)
        length = budget_text(getattr(config, "minutes", None), getattr(config, "iterations", None))
        where = f" into {out_dir}" if out_dir else ""
        return JobRequest("training", job, out_dir, f"training into {out_dir}" if out_dir else "training",
                          f"Train a new run{where}{' ' + length if length else ''}?")

    def resume_request(self) -> JobRequest | None:
        """Continue the open run from its newest checkpoint; None (said) when it cannot."""
        try:
            job = resume_job_for(self.run_dir, self.settings)
        except Exception as exc:  # noqa: BLE001 - shown in the status line
            self.status.text = f"resume could not start: {exc}"
            return None
        return JobRequest("resume", job, job.run_dir, f"resuming {job.run_dir}",
                          f"Resume {job.run_dir} from its newest checkpoint with its saved plan?")

    def bootstrap_request(self, config=None) -> JobRequest | None:
        """Stage II on the flagged views of the open run (config: default the job dialog's
        settings); None (said) when it cannot."""
        try:
            config = config or self.settings.bootstrap_config()
            job = bootstrap_job_for(self.run_dir, self.flags.file, config)
        except Exception as exc:  # noqa: BLE001 - shown in the status line, never fatal
            self.status.text = f"bootstrap could not start: {exc}"
            return None
        count = len(self.flags.items)
        length = budget_text(getattr(config, "minutes", None), None)
        return JobRequest("bootstrap", job, job.out_dir,
                          f"bootstrapping {count} flagged view(s) of {job.run_dir}",
                          f"Bootstrap {count} flagged view(s) of {job.run_dir} into {job.out_dir}"
                          f"{' ' + length if length else ''}?")

    def baseline_request(self) -> JobRequest | None:
        """The same-time baseline of the verdict's bootstrap; None (said) when it cannot run."""
        try:
            job = baseline_job_for(self.verdict)
        except Exception as exc:  # noqa: BLE001 - shown in the status line
            self.status.text = f"baseline could not start: {one_line(exc)}"
            return None
        return JobRequest("baseline", job, job.out_dir,
                          f"baseline: {job.run_dir} continued on the photos alone for {format_duration(job.seconds)}",
                          f"Run the same-time baseline: {job.run_dir} continued on the photos alone for "
                          f"{format_duration(job.seconds)} (the bootstrap's time) into {job.out_dir}?")

    def ask(self, kind: str) -> None:
        """A job button was pressed: build the job and ask before it runs (the question shows until
        "start the job" or "do not start"). Nothing when a job is alive or a question is open."""
        if self.alive:
            self.status.text = "a job is running: stop it first"
            return
        if self.pending is not None:
            return
        build = {"training": self.training_request, "resume": self.resume_request,
                 "bootstrap": self.bootstrap_request, "baseline": self.baseline_request}[kind]
        self.pending = build()

    def confirm(self) -> None:
        """The user's "start the job": the asked job runs."""
        request, self.pending = self.pending, None
        if request is not None and not self.alive:
            self.start_request(request)

    def cancel(self) -> None:
        """The user's "do not start"."""
        if self.pending is not None:
            self.status.text = f"not started: {self.pending.kind}"
        self.pending = None

    def start_request(self, request: JobRequest | None) -> None:
        """Run a built request's job now (confirm, or the start_* calls below)."""
        if request is None or self.alive:
            return
        if request.kind == "bootstrap":
            self.bootstrap_base = self.view.edit.visible_arrays()
            self.bootstrap_views = [(flag.name, flag.camera) for flag in self.flags.items]
        verdict = self.verdict if request.kind == "baseline" else None
        self.start_job(request.job, request.out_dir, request.message)
        if request.kind == "resume":
            self.status.text = resume_line(request.job.run_dir, self.training.plan, request.job.config.minutes)
        if verdict is not None:
            self.baseline_of = verdict.out_dir   # its verdict is read again when the baseline ends

    def start_training(self) -> None:
        """A new stage-I run (the job dialog's settings) in a fresh run folder, at once."""
        if not self.alive:
            self.start_request(self.training_request())

    def resume_training(self) -> None:
        """Continue the open run from its newest checkpoint, at once."""
        if not self.alive:
            self.start_request(self.resume_request())

    def start_bootstrap(self, config=None) -> None:
        """Stage II on the flagged views of the open run as the live job, at once (config:
        default the job dialog's settings)."""
        if self.alive:
            self.status.text = "a job is running: stop it before bootstrapping"
            return
        self.start_request(self.bootstrap_request(config))

    def start_job(self, job, out_dir: Path | None, message: str) -> None:
        """Run ``job`` live; its folder becomes the open run (Resume and Bootstrap use it)."""
        self.training = LiveTraining(job, plan=plan_of(job))
        self.training.start()
        self.set_verdict(None)     # the open result's verdict says nothing about the new job's folder
        self.fold_settings = True  # the dialog closes: the job's progress is what to watch
        self.reported = False
        self.out_dir = Path(out_dir) if out_dir is not None else None
        source = self.view.source
        if self.out_dir is not None:
            self.run_dir = self.out_dir
            if source.kind == "scene" and self.out_dir not in source.runs:
                source.runs.append(self.out_dir)  # the panel's list of the scene's runs
        self.status.text = message
        self.retitle()

    # --- while it runs ---------------------------------------------------------------------------
    def take_snapshot(self) -> None:
        """Once a frame: the job's newest model replaces the shown one (throttled), and the
        closing line replaces the status once the job has ended."""
        run = self.training
        if run is None:
            return
        if run.state != self.title_state:
            self.retitle()  # running -> paused -> finished shows in the title
        run.refresh_scores()
        before = run.plan.end_iteration
        run.refresh_plan()  # the end of a schedule the trainer re-sized to its budget
        if run.plan.end_iteration != before and run.alive:
            self.status.text = replan_line(run.plan, before)  # a changed plan is said, not only drawn
        now = time.perf_counter()
        # Throttled while the job runs; once it has ended its last snapshot is taken at once.
        if now - self.last_snapshot_time < TRAINING_REFRESH_SECONDS and run.alive:
            return
        ended = not run.alive  # read before the poll: the job's last publish is then in
        gaussians = run.poll_gaussians()
        if gaussians is not None:
            self.last_snapshot_time = now
            self.view.show_model(gaussians)
        if ended and not self.reported:
            self.report_job_end()

    def report_job_end(self) -> None:
        """Replace the running status with the closing line: time, iteration, final scores."""
        run = self.training
        run.refresh_scores(force=True)
        run.refresh_plan()
        self.reported = True
        if run.error:
            self.status.text = f"{run.plan.kind} failed after {format_duration(run.elapsed_s)}: {run.error}"
            return
        self.status.text = closing_line(run.plan.kind, run.state, run.elapsed_s, run.progress.iteration,
                                        final_scores(run.progress.psnr), self.out_dir)
        if self.baseline_of is not None:
            # A same-time baseline ended: the verdict of the bootstrap it was run for, now with it.
            self.set_verdict(read_verdict(self.baseline_of))
            self.baseline_of = None
            if self.verdict is not None:
                self.status.text += f"; the bootstrap's verdict: {verdict_line(self.verdict)}"
        elif self.out_dir is not None and self.out_dir == self.run_dir:
            self.read_view_fit()  # a finished run has just written its report
            self.set_verdict(read_verdict(self.out_dir))
            self.verdict_images_due = self.verdict is not None
            if self.verdict is not None:
                self.status.text += f"; {verdict_line(self.verdict)}"

    def set_verdict(self, verdict) -> None:
        """The verdict the panel shows (None: none); the previous one's images are let go."""
        from .verdict import release_textures  # noqa: PLC0415

        release_textures(self.verdict)
        self.verdict = verdict

    # --- the scene's runs --------------------------------------------------------------------------
    def open_run(self, run_dir: Path) -> None:
        """Show another run of the open scene (the Training panel's list): its model replaces the
        shown one, and it becomes the open run (Resume, Bootstrap). Not while a job runs."""
        if self.alive:
            self.status.text = "a job is running: stop it before opening another run"
            return
        source = self.view.source
        try:
            opened = open_scene_run(source.path, source.work_dir, source.runs, Path(run_dir), source.runs_dir)
        except (InputError, OSError) as exc:
            self.status.text = f"run not opened: {exc}"
            return
        self.training, self.out_dir = None, None
        self.view.show_source(opened)
        self.run_dir = run_dir_of(opened)
        self.set_verdict(read_verdict(self.run_dir))
        self.bootstrap_base, self.bootstrap_views = None, []  # a result opened: its own run's model
        self.verdict_images_due = self.verdict is not None
        self.status.text = f"opened run {run_dir}"
        self.read_view_fit()
        self.retitle()
        self.view.moved()

    def run_label(self, run: Path) -> str:
        """A run in the Training panel's list: when it was last written, its last held-out scores
        and its folder in full (re-read only when its metrics log changes)."""
        metrics = Path(run) / "metrics.jsonl"
        try:
            stamp = metrics.stat().st_mtime_ns if metrics.is_file() else Path(run).stat().st_mtime_ns
        except OSError:
            return f"{run} (gone)"
        key = (Path(run), stamp)
        if key not in self.run_labels:
            when = time.strftime("%Y-%m-%d %H:%M", time.localtime(stamp / 1e9))
            # Time and scores first: the list's closed preview shows the start of a line.
            self.run_labels[key] = f"{when}  {run_scores(run)}  {run}"
        return self.run_labels[key]

    def choose_runs_folder(self, folder: Path) -> None:
        """Where the next runs go (the Training panel's field, as --runs): its runs of the scene
        join the list."""
        from .sources import oldest_first, scene_runs  # noqa: PLC0415

        source = self.view.source
        source.runs_dir = runs_folder(folder)
        if source.scene is not None and source.kind == "scene":
            source.runs = oldest_first([*source.runs, *scene_runs(source.scene, source.runs_dir)])
        self.status.text = f"new runs go to {source.runs_dir}"

    def read_view_fit(self) -> None:
        """The open run's poorly fit training photos (RUN/view_fit.json; none without one)."""
        self.poorly_fit, self.poorly_fit_shown = {}, -1
        if self.run_dir is None:
            return
        try:
            self.poorly_fit = read_poorly_fit(self.run_dir)
        except InputError as exc:
            self.status.text = f"photo fit report not read: {exc}"

    def next_poorly_fit_photo(self) -> None:
        """Stand at the next poorly fit training photo's camera (worst first, then around)."""
        view = self.view
        indices = {camera.name: i for i, camera in enumerate(view.cameras)}
        names = [name for name in self.poorly_fit if name in indices]
        if not names:
            return
        self.poorly_fit_shown = (self.poorly_fit_shown + 1) % len(names)
        name = names[self.poorly_fit_shown]
        view.snap_to_camera(indices[name])
        self.status.text = (f"{name}: training photo {self.poorly_fit_shown + 1} of {len(names)} the model fits "
                            f"poorly ({self.poorly_fit[name]:.1f} dB)")
