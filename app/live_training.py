"""Runs a training job in a background thread and feeds the UI from its SnapshotBox.

A job is anything with ``run(box: SnapshotBox, control) -> None`` (the stage-I trainer's job
class, later the bootstrap loop). ``control`` has two threading.Events: ``pause`` (set =
paused) and ``stop`` (set = finish soon, keep the checkpoint). The job's exception is caught
on its thread and shown by the UI; the app never dies with it.
"""

from __future__ import annotations

import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from inceptiongs.live import JobControl, Snapshot, SnapshotBox

from .capabilities import one_line
from .progress import JobPlan, followed_plan, planned_iterations, psnr_series

# The job's metrics log is re-read at most this often (a few hundred short JSON lines).
METRICS_REFRESH_SECONDS = 2.0


@dataclass
class TrainingProgress:
    """What the panel shows. history: metric name -> ([iterations], [values])."""

    iteration: int = 0
    gaussian_count: int = 0
    iterations_per_second: float = 0.0
    message: str = ""
    history: dict = field(default_factory=dict)
    psnr: dict = field(default_factory=dict)  # held-out group -> ([iterations], [dB]), from the log
    plot_limits: dict = field(default_factory=dict)  # plot title -> the axes' ranges last drawn
    bar_text: str = ""  # what the progress bar reads (panels.py), as the status counts: iterations


class LiveTraining:
    """One job run: start / pause / resume / stop, and :meth:`poll` for the newest snapshot."""

    def __init__(self, job, control=None, box: SnapshotBox | None = None, plan: JobPlan | None = None) -> None:
        self.job = job
        self.plan = plan or JobPlan()
        self.box = box or SnapshotBox()
        self.control = control if control is not None else JobControl()
        self.progress = TrainingProgress()
        self.error: str | None = None
        self._thread: threading.Thread | None = None
        self._seen_version = 0
        self._seen_gaussians_version = 0
        self._rate_anchor: tuple[float, int] | None = None  # (time, iteration) of the last rate sample
        self._started: float | None = None
        self._ended: float | None = None
        self._paused_at: float | None = None
        self._paused_s = 0.0
        self._metrics_read = -1e9
        self._config_seen: tuple[int, int] | None = None  # (mtime ns, size) of the config last read

    # --- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("a job run can be started once")
        self._thread = threading.Thread(target=self._run, name="inceptiongs-training", daemon=True)
        self._started = time.perf_counter()
        self._thread.start()

    def _run(self) -> None:
        try:
            self.job.run(self.box, self.control)
        except BaseException as exc:  # noqa: BLE001 - anything the job raises is shown, not fatal
            self.error = one_line(exc)
            self.traceback = traceback.format_exc()
        finally:
            self._ended = time.perf_counter()

    @property
    def elapsed_s(self) -> float:
        """Seconds the job has run, its pauses left out (frozen once it has ended)."""
        if self._started is None:
            return 0.0
        end = self._ended if self._ended is not None else time.perf_counter()
        paused = self._paused_s
        if self._paused_at is not None and self._ended is None:
            paused += end - self._paused_at
        return max(end - self._started - paused, 0.0)

    @property
    def state(self) -> str:
        """"not started" | "running" | "paused" | "stopping" | "failed" | "stopped" | "finished"."""
        if self._thread is None:
            return "not started"
        if self._thread.is_alive():
            if self.control.stop.is_set():
                return "stopping"
            return "paused" if self.control.pause.is_set() else "running"
        if self.error is not None:
            return "failed"
        return "stopped" if self.control.stop.is_set() else "finished"

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def pause(self) -> None:
        if self._paused_at is None:
            self._paused_at = time.perf_counter()
        self.control.pause.set()

    def resume(self) -> None:
        if self._paused_at is not None:
            self._paused_s += time.perf_counter() - self._paused_at
            self._paused_at = None
        self.control.pause.clear()

    def stop(self, timeout: float | None = 30.0) -> bool:
        """Ask the job to finish (it writes its checkpoint) and wait; True if it ended."""
        self.control.stop.set()
        self.resume()  # a paused job must wake up to see the stop
        if self._thread is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def join(self, timeout: float | None = None) -> None:
        """Wait up to ``timeout`` seconds for the job's thread to end."""
        if self._thread is not None:
            self._thread.join(timeout)

    # --- data ------------------------------------------------------------------------------
    def poll(self) -> Snapshot | None:
        """The newest unseen snapshot (its metrics folded into :attr:`progress`), or None."""
        snapshot = self.box.latest(self._seen_version)
        if snapshot is None:
            return None
        self._seen_version = snapshot.version
        self._record(snapshot)
        return snapshot

    def refresh_scores(self, force: bool = False) -> None:
        """Re-read the held-out PSNR series from the job's metrics log (throttled)."""
        now = time.perf_counter()
        if force or now - self._metrics_read >= METRICS_REFRESH_SECONDS:
            self._metrics_read = now
            self.progress.psnr = psnr_series(self.plan.metrics)

    def refresh_plan(self) -> None:
        """Follow the schedule the trainer re-sized to the budget: re-read the run's config.json
        when it changed (a stat a frame; read only on a new mtime or size)."""
        config = self.plan.config
        if config is None:
            return
        try:
            info = Path(config).stat()
        except OSError:  # not written yet
            return
        seen = (info.st_mtime_ns, info.st_size)
        if seen == self._config_seen:
            return
        iterations = planned_iterations(config)
        if iterations is not None:  # a half-written file is read again on its next change
            self._config_seen = seen
            self.plan = followed_plan(self.plan, iterations)

    def poll_gaussians(self) -> dict | None:
        """Like :meth:`poll`, but returns the newest Gaussians only when they are new to this
        reader (a log line carries the last model on; that model is not returned twice)."""
        snapshot = self.poll()
        if snapshot is None or snapshot.gaussians_version <= self._seen_gaussians_version:
            return None
        self._seen_gaussians_version = snapshot.gaussians_version
        return snapshot.gaussians

    def _record(self, snapshot: Snapshot) -> None:
        progress = self.progress
        now = time.perf_counter()
        # A log line before the first step carries iteration 0: a resumed job's rate is measured
        # from its first step past the checkpoint, not from 0 (it read 92 it/s instead of 4).
        if self._rate_anchor is None or self._rate_anchor[1] < self.plan.start_iteration:
            self._rate_anchor = (now, snapshot.iteration)
        else:
            then, iteration = self._rate_anchor
            # Rate over at least half a second, so one quick snapshot does not spike it.
            if now - then >= 0.5 and snapshot.iteration > iteration:
                progress.iterations_per_second = (snapshot.iteration - iteration) / (now - then)
                self._rate_anchor = (now, snapshot.iteration)
        progress.iteration = snapshot.iteration
        progress.message = snapshot.message
        if snapshot.gaussians is not None:
            progress.gaussian_count = len(snapshot.gaussians["means"])
        for name, value in snapshot.metrics.items():
            if isinstance(value, (int, float)):
                iterations, values = progress.history.setdefault(name, ([], []))
                iterations.append(float(snapshot.iteration))
                values.append(float(value))
