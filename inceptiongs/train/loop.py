"""What stage I's and stage II's step loops share: pause and stop, the clocks that pauses move
forward, the progress bar (with a time-budgeted run's expected total), metrics lines, snapshots
and the final model file.

A loop owns a :class:`StepLoop`; each step it calls :meth:`StepLoop.wait_or_stop`, makes its
step, then :meth:`StepLoop.advance` (the bar), :meth:`StepLoop.clocks` (a metrics line's times) and
:meth:`StepLoop.snapshot` (the viewer's copy) as its cadences say.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import torch
from tqdm import tqdm

from ..errors import DeviceMemoryError
from ..gaussians import Gaussians
from ..io.atomic import OutputError
from ..io.ply import write_ply
from ..live import wait_while_paused
from ..runs.config import TrainConfig
from ..gaussians import gaussians_from_params
from ..runs.frames import to_original_frame
from .step import sh_degree_at, trim_sh


@contextlib.contextmanager
def out_of_memory_stops(run_dir: Path, where: Callable[[], tuple[int, int]], resume: str):
    """Steps inside raise :class:`DeviceMemoryError` (one line) instead of torch's out-of-memory
    traceback. ``where()`` -> (the step being made, the Gaussians it had); ``resume``: the command
    that continues the run. Nothing is saved after it: a step cut short may have changed part of
    the model, so the newest checkpoint is what the run keeps."""
    try:
        yield
    except torch.OutOfMemoryError:
        if torch.cuda.is_available():
            torch.cuda.empty_cache()   # the memory goes back before anything else is tried
        from ..runs.checkpoint import latest_checkpoint

        step, count = where()
        kept = latest_checkpoint(Path(run_dir))
        raise DeviceMemoryError(
            f"{run_dir}: the GPU ran out of memory at step {step} with {count} Gaussians; "
            + (f"kept: {kept.name} ({resume} continues from it)" if kept is not None else "no checkpoint yet")
            + "; train at a larger --downscale (fewer pixels per step) or with --strategy mcmc "
              "(a fixed Gaussian budget), or free the GPU's memory") from None


def default_log(message: str) -> None:
    """A log line that does not tear the progress bar."""
    tqdm.write(message, file=sys.stderr)


def expected_total_steps(done: int, spent_s: float, left_s: float, cap: int, min_steps: int = 5) -> int | None:
    """Steps a time-budgeted run will have made when its time runs out: ``done`` so far in
    ``spent_s`` seconds of stepping, at the same rate for the ``left_s`` seconds left, at most
    ``cap``. None (not yet known) before ``min_steps``: the first steps build caches and their
    rate is noise, and the cap (the demo's baseline: 100 000) would be a wrong total to show."""
    if done < min_steps or spent_s <= 0.0:
        return None
    return int(min(cap, done + max(left_s, 0.0) * done / spent_s))


@dataclass
class StepLoop:
    """The clocks, the pause/stop control and the progress bar of one training loop.

    Two clocks, in seconds since the loop's start (a resumed run starts them at its saved
    values): ``wall_s()`` counts everything but pauses, ``train_s()`` also leaves out what
    :meth:`exclude` was given (evaluation). ``budget_s`` (wall seconds, or None): the bar's total
    is the steps the measured rate fits into it, at most ``total`` (the step cap)."""

    control: object = None
    total: int | None = None
    desc: str = "train"
    progress: bool = True
    initial: int = 0
    wall_start_s: float = 0.0
    train_start_s: float = 0.0
    budget_s: float | None = None
    on_snapshot: Callable[[int, Gaussians, dict], None] | None = None
    snapshot_every: int = 0
    bar: tqdm = field(init=False)
    _wall_clock: float = field(init=False)
    _train_clock: float = field(init=False)
    _first_step_at: float | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        now = time.perf_counter()
        self._wall_clock = now - self.wall_start_s
        self._train_clock = now - self.train_start_s
        # A time-budgeted run's total is unknown until a rate is measured (advance sets it).
        shown = None if self.budget_s is not None else self.total
        self.bar = tqdm(total=shown, initial=self.initial, desc=self.desc, file=sys.stderr, dynamic_ncols=True,
                        disable=not self.progress, unit="it")

    # --- clocks ------------------------------------------------------------------------------------
    def wall_s(self) -> float:
        return time.perf_counter() - self._wall_clock

    def train_s(self) -> float:
        return time.perf_counter() - self._train_clock

    def exclude(self, seconds: float) -> None:
        """``seconds`` just spent were not training (an evaluation): the train clock skips them."""
        self._train_clock += seconds

    def out_of_time(self) -> bool:
        """The wall budget is spent (never, without one)."""
        return self.budget_s is not None and self.wall_s() >= self.budget_s

    def wait_or_stop(self) -> bool:
        """Honour a pause (both clocks move forward by it: paused time is nobody's) -> True when
        asked to stop."""
        if self.control is not None:
            self.control.listening.set()
        stop, paused_s = wait_while_paused(self.control)
        self._wall_clock += paused_s
        self._train_clock += paused_s
        return stop

    def stopped_by_user(self) -> bool:
        return self.control is not None and self.control.stop.is_set()

    # --- per step --------------------------------------------------------------------------------
    def advance(self) -> None:
        """One step done. A time-budgeted run ends when its time is spent, usually long before
        its step cap (the demo's baseline: 100 000): the bar's total is the steps the measured
        rate fits into the time left, so its count and ETA are the run's, not the cap's."""
        if self._first_step_at is None:
            # The rate is measured from the first step on (loading and generation are not steps).
            self._first_step_at = self.wall_s()
        self.bar.update(1)
        if self.budget_s is not None:
            now = self.wall_s()
            total = expected_total_steps(self.bar.n, now - self._first_step_at, self.budget_s - now, self.total)
            if total is not None and total != self.bar.total:
                self.bar.total = total
                self.bar.refresh()

    def mark_first_step(self) -> None:
        """The first step begins now (its own time counts towards the rate)."""
        if self._first_step_at is None:
            self._first_step_at = self.wall_s()

    def clocks(self) -> dict[str, float]:
        """Both clocks now, as a metrics line holds them."""
        return {"wall_s": self.wall_s(), "train_s": self.train_s()}

    def snapshot(self, step: int, params: dict, record: dict) -> None:
        """The viewer's copy of the model every ``snapshot_every`` steps."""
        if self.on_snapshot is not None and self.snapshot_every > 0 and step % self.snapshot_every == 0:
            self.on_snapshot(step, gaussians_from_params(params).detach().to("cpu"), record)

    def close(self) -> None:
        self.bar.close()


def save_model(run_dir: Path, gaussians: Gaussians, iteration: int, config: TrainConfig, sh_max: int,
               normalization) -> None:
    """RUN/model.ply: the model in the user's frame, at the SH degree its schedule reached."""
    degree = sh_degree_at(max(iteration, 1), config, sh_max)
    write_ply(to_original_frame(trim_sh(gaussians.to("cpu"), degree), normalization), Path(run_dir) / "model.ply")


class SaveAttempts:
    """The parts of a final save, each attempted even when an earlier one failed (a full disk):
    ``attempt(write)`` keeps an OutputError for later; ``raise_first(log)`` logs every failure
    but the first, one line each, and raises the first (the command prints it)."""

    def __init__(self) -> None:
        self.failures: list[OutputError] = []

    def attempt(self, write: Callable[[], object]) -> None:
        try:
            write()
        except OutputError as exc:
            self.failures.append(exc)

    def raise_first(self, log: Callable[[str], None]) -> None:
        for later in self.failures[1:]:
            log(f"error: {later}")
        if self.failures:
            raise self.failures[0]
