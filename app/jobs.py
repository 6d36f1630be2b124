"""The Training panel's object, :class:`Jobs`: the live job the viewer runs on a thread (built
and asked for in job_requests.py from the dialog's settings, job_settings.py), the hand-off of its
snapshots to the view, and the open run: what Resume continues and Bootstrap repairs, its verdict
and the training photos it fits poorly."""

from __future__ import annotations

import time
from pathlib import Path

from inceptiongs.errors import InputError

from .job_requests import (JobRequest, baseline_request, bootstrap_request, bootstrap_resume_request, resume_request,
                           training_request)
from .job_settings import JobSettings
from .live_training import LiveTraining
from .poorly_fit import read_poorly_fit_photos
from .progress import closing_line, final_scores, format_duration, plan_of, replan_line, resume_line
from .run_list import RunLabels
from .runs import is_bootstrap_result, run_dir_of
from .sources import open_scene_run
from .verdict import read_verdict, verdict_line

# While a job trains, its snapshots replace the model at most this often: each one costs a
# re-render, and the job publishes faster than software GL can draw them.
TRAINING_REFRESH_SECONDS = 0.3


class Jobs:
    """The viewer's job: the dialog's settings, the live job (training: a LiveTraining, None
    before the first), the open run (what Resume continues and Bootstrap repairs) with the
    training photos it fits poorly, and the hand-off of the job's snapshots to the view.

    ``view``: the view.View whose model the job's snapshots replace; ``flags``: the
    flags.FlagBook the bootstrap repairs; ``status``: the status line; ``retitle``: called when
    what the window title names changes (runs.window_title); ``factory``: source -> job for "train"
    (None: the dialog's stage-I training)."""

    def __init__(self, view, flags, status, retitle, factory=None) -> None:
        self.view, self.flags, self.status, self.retitle = view, flags, status, retitle
        self.factory = factory
        self.settings = JobSettings()
        self.training: LiveTraining | None = None
        self.run_dir = run_dir_of(view.source)  # the open run: what Resume continues, Bootstrap repairs
        self.out_dir: Path | None = None  # where the current (or last) job writes
        self.reported = False  # the closing line of the last job has replaced the status
        # That closing line, which the Training panel keeps under the job while the status line
        # moves on to later actions ("video saved to ..." read as the job's result there).
        self.closing = ""
        self.fold_settings = False  # panels.py closes the job dialog once a job has started
        self.last_snapshot_time = -1e9  # when a job's snapshot last replaced the model
        self.run_labels = RunLabels()  # the panel's line for each of the scene's runs
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
        self.retired_textures: list = []  # a replaced verdict's textures, released after the frame (verdict.py)
        self.pending: JobRequest | None = None  # a job asked for, waiting for the user's "start"
        self.baseline_of: Path | None = None  # the bootstrap result a running baseline was asked for
        # The open run's training photos it fits poorly: drawn apart, stepped through by the panel.
        self.poorly_fit = read_poorly_fit_photos(self.run_dir, status)

    @property
    def alive(self) -> bool:
        """A job has started and not ended (paused counts)."""
        return self.training is not None and self.training.alive

    def running(self) -> bool:
        """A job is training now (started, not paused, not ended)."""
        return self.alive and not self.training.control.pause.is_set()

    # --- starting --------------------------------------------------------------------------------
    def request(self, kind: str, config=None) -> JobRequest | None:
        """The ``kind`` job ("training", "resume", "bootstrap", "baseline") built for the open source
        and run from the dialog's settings (``config``: the bootstrap's, default the dialog's);
        None (said in the status line) when it cannot be built. "resume" of a bootstrap result
        continues the bootstrap stopped there (a "bootstrap resume" request)."""
        build = {"training": lambda: training_request(self.view.source, self.settings, self.factory, self.status),
                 "resume": lambda: (bootstrap_resume_request(self.run_dir, self.status)
                                    if is_bootstrap_result(self.run_dir)   # a stopped bootstrap goes on as one
                                    else resume_request(self.run_dir, self.settings, self.status)),
                 "bootstrap": lambda: bootstrap_request(self.run_dir, self.flags, self.settings, self.status, config),
                 "baseline": lambda: baseline_request(self.verdict, self.status)}[kind]
        return build()

    def ask(self, kind: str) -> None:
        """A job button was pressed: build the job and ask before it runs (the question shows until
        "start the job" or "do not start"). Nothing when a job is alive or a question is open."""
        if self.alive:
            self.status.text = "a job is running: stop it first"
            return
        if self.pending is not None:
            return
        self.pending = self.request(kind)

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
        """Run a built request's job now (confirm, or the start_* calls below); its folder becomes
        the open run (Resume and Bootstrap use it)."""
        if request is None or self.alive:
            return
        if request.kind == "bootstrap":
            self.bootstrap_base = self.view.edit.visible_arrays()
            self.bootstrap_views = [(flag.name, flag.camera) for flag in self.flags.items]
        verdict = self.verdict if request.kind == "baseline" else None
        self.training = LiveTraining(request.job, plan=plan_of(request.job))
        self.training.start()
        self.set_verdict(None)     # the open result's verdict says nothing about the new job's folder
        self.fold_settings = True  # the dialog closes: the job's progress is what to watch
        self.reported = False
        self.out_dir = Path(request.out_dir) if request.out_dir is not None else None
        source = self.view.source
        if self.out_dir is not None:
            self.run_dir = self.out_dir
            if source.kind == "scene" and self.out_dir not in source.runs:
                source.runs.append(self.out_dir)  # the panel's list of the scene's runs
        self.status.text = request.message
        self.retitle()
        if request.kind == "resume":
            self.status.text = resume_line(request.job.run_dir, self.training.plan, request.job.config.minutes)
        if verdict is not None:
            self.baseline_of = verdict.out_dir   # its verdict is read again when the baseline ends

    def start_training(self) -> None:
        """A new stage-I run (the job dialog's settings) in a fresh run folder, at once."""
        if not self.alive:
            self.start_request(self.request("training"))

    def resume_training(self) -> None:
        """Continue the open run from its newest checkpoint (a stopped bootstrap: the bootstrap), at once."""
        if not self.alive:
            self.start_request(self.request("resume"))

    def start_bootstrap(self, config=None) -> None:
        """Stage II on the flagged views of the open run as the live job, at once (config:
        default the job dialog's settings)."""
        if self.alive:
            self.status.text = "a job is running: stop it before bootstrapping"
            return
        self.start_request(self.request("bootstrap", config))

    # --- while it runs ---------------------------------------------------------------------------
    def take_snapshot(self) -> None:
        """Once a frame: the job's newest model replaces the shown one (throttled), and the
        closing line replaces the status once the job has ended."""
        run = self.training
        if run is None:
            return
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
            self.closing = self.status.text
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
            self.poorly_fit = read_poorly_fit_photos(self.run_dir, self.status)  # its report is just written
            self.set_verdict(read_verdict(self.out_dir))
            self.verdict_images_due = self.verdict is not None
            if self.verdict is not None:
                self.status.text += f"; {verdict_line(self.verdict)}"
        self.closing = self.status.text

    def set_verdict(self, verdict) -> None:
        """The verdict the panel shows (None: none); the previous one's images are let go once the
        frame is rendered (verdict.retire_textures)."""
        from .verdict import retire_textures  # noqa: PLC0415

        retire_textures(self.verdict, self.retired_textures)
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
        self.poorly_fit = read_poorly_fit_photos(self.run_dir, self.status)
        self.retitle()
        self.view.moved()
