"""The stage-I training loop: run folder, schedule, evaluation, checkpoints, snapshots.

Everything that does not change during training is prepared once before the loop (the
photos as tensors at the training resolution, their grey versions and edge weights, the
neighbour views); one step (:mod:`.step`) renders the sampled view, adds the photometric,
flattening, normal and (every ``multiview_every`` steps) the multi-view terms, steps Adam,
and densifies on schedule.
"""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..errors import InputError
from ..evaluation.protocols import make_split
from ..scene.loader import load_scene
from ..runs.lock import run_folder_lock
from ..io.atomic import atomic_write_text, check_writable_dir, remove_stale_temp_files
from ..gaussians import Gaussians
from ..rasterizer.interface import rasterizer_device
from ..threads import use_torch_threads
from .budget import (BUDGET_CALIBRATION_STEPS, BUDGET_CHECK_FRACTION, BUDGET_COST_RATIO, BUDGET_FREEZE,
                     BUDGET_RESIZE_TOLERANCE,
                     RateWindow, affordable_count, budget_iterations, far_off, fit_step_cost,
                     growing_budget_iterations)
from ..runs.checkpoint import latest_checkpoint, load_newest_checkpoint, save_checkpoint
from ..io.config_json import with_values
from ..runs.config import TrainConfig, sized_schedule
from .loop import SaveAttempts, StepLoop, default_log, out_of_memory_stops, save_model
from ..gaussians import gaussians_from_params
from .sky import fill_shell_behind_scene
from .view_fit import VIEW_FIT_FILE, summary_line, view_fit_report
from ..runs.metrics import append_metrics, logged_iterations, truncate_metrics
from .partition import as_block
from .step import (add_maintenance_counts, data_on, evaluate_held_out, log_once, new_state, prepare_data,
                   restore_state, state_on, supported_sh_degree, train_step)


@dataclass
class TrainResult:
    run_dir: Path
    iteration: int
    finished: bool          # reached the iteration or time budget (False: stopped by request)
    num_gaussians: int
    last_eval: dict = field(default_factory=dict)


def train(config: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True,
          control=None, on_snapshot: Callable[[int, Gaussians, dict], None] | None = None,
          snapshot_every: int = 0, rasterizer=None, log: Callable[[str], None] | None = None,
          after_step: Callable[[int, Gaussians, bool], None] | None = None) -> TrainResult:
    """Train stage I into ``run_dir``; see docs/training.md.

    control: object with ``stop`` / ``pause`` threading.Events (JobControl) or None.
    on_snapshot(iteration, detached Gaussians, metrics) every ``snapshot_every`` steps.
    rasterizer (inceptiongs.rasterizer.interface.Rasterizer) defaults to the one ``config.device``
    selects (resolve_device, the one device rule).
    after_step(iteration, detached Gaussians, checkpointed) after every step (e.g. one
    diffusion-prior step, `inceptiongs train --prior`); its time counts as training time.
    """
    device_note = None
    if rasterizer is None:
        from ..rasterizer.interface import resolve_device
        device = resolve_device(config.device)
        rasterizer, device_note = device.rasterizer, device.note
    config.validate()
    with run_folder_lock(run_dir):   # one writer per run folder (a second gets one line naming the first)
        return _train(config, Path(run_dir), resume, progress, control, on_snapshot, snapshot_every, rasterizer,
                      log or default_log, after_step, device_note)


def _train(config: TrainConfig, run_dir: Path, resume: bool, progress: bool, control, on_snapshot,
           snapshot_every: int, rasterizer, log, after_step, device_note: str | None) -> TrainResult:
    use_torch_threads()
    checkpoint, payload, scene, split, data = _start(config, run_dir, resume, log)
    if device_note:   # once the start has succeeded: an error before it stays the only line
        log(device_note)
    config.save(run_dir / "config.json")
    split.save(run_dir / "split.json")
    sh_max = supported_sh_degree(len(data.train), config.sh.degree_max)
    state = _first_state(config, run_dir, checkpoint, payload, scene, split, data, sh_max, log, rasterizer)
    # The photos, parameters and statistics live where the rasterizer runs: no per-step copies.
    device = rasterizer_device(rasterizer)
    data, state = data_on(data, device), state_on(state, device, config, data.extent)
    if config.pgsr and not any(data.neighbours.values()):
        log_once(state, "no-neighbours", "multi-view terms skipped: no training view has a neighbour", log)

    loop = StepLoop(control, total=config.iterations, desc="train", progress=progress, initial=state.iteration,
                    wall_start_s=state.wall_s, train_start_s=state.train_s, on_snapshot=on_snapshot,
                    snapshot_every=snapshot_every)
    run = StageOne(config, run_dir, scene, split, data, state, sh_max, rasterizer, log, loop, after_step)
    try:
        with out_of_memory_stops(run_dir, lambda: (run.state.iteration + 1, run.state.params["means"].shape[0]),
                                 "--resume"):
            run.steps()
    finally:
        loop.close()
        getattr(data.images, "close", lambda: None)()   # the prefetch thread ends with the run (a stop, Ctrl+C or an error too)
    return run.finish()


def _start(config: TrainConfig, run_dir: Path, resume: bool, log):
    """Everything that can fail before the run writes anything -> (checkpoint path or None,
    its payload or None, scene, split, prepared data)."""
    created = not run_dir.exists()
    check_writable_dir(run_dir)  # before any work: one line now, not a traceback hours later
    remove_stale_temp_files(run_dir, max_age_s=0.0)  # this run owns the folder: its temp files are dead
    try:
        checkpoint, payload = None, None
        if resume and latest_checkpoint(run_dir) is not None:
            checkpoint, payload = load_newest_checkpoint(run_dir, warn=log)
        elif resume:
            log(f"{run_dir}: no checkpoint to resume from, starting a new run")
        scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
        split = make_split(scene, config.protocol, config.seed, config.scarce_views, config.exclude_photos)
        if config.block.count:   # one block of a larger run: its photos and the points of its cell
            scene, split = as_block(scene, split, config.block)
        if not split.train:
            raise InputError(f"{config.scene}: the {config.protocol} split leaves no training views")
        if config.block.count:
            log(f"block {config.block.index + 1} of {config.block.count}: {len(split.train)} training and "
                f"{len(split.test)} held-out photos see its cell; the other {len(split.excluded)} are left out")
        elif split.excluded:
            log(f"left out: {len(split.excluded)} of {split.num_views} photos (exclude_photos), neither trained "
                f"on nor held out")
        data = prepare_data(scene, split, config, log)
    except BaseException:
        # A failed start leaves no half run: nothing was written yet, and a folder this call
        # created is removed again when it is still empty.
        if created:
            with contextlib.suppress(OSError):
                run_dir.rmdir()
        raise
    return checkpoint, payload, scene, split, data


def _first_state(config: TrainConfig, run_dir: Path, checkpoint, payload, scene, split, data, sh_max: int, log,
                 rasterizer):
    """The resumed state (metrics after it dropped), or a new one with its iteration-0 scores logged."""
    if payload is not None:
        state = restore_state(payload, data, config)
        truncate_metrics(run_dir, state.iteration)
        log(f"resumed from {checkpoint.name} (iteration {state.iteration})")
        return state
    state = new_state(scene, data, config, sh_max, log)
    (run_dir / "metrics.jsonl").unlink(missing_ok=True)
    # Iteration 0: the initial model's scores, the start of every PSNR-vs-time curve.
    initial_eval = evaluate_held_out(gaussians_from_params(state.params).detach(), scene, split, data, rasterizer,
                                     config.output.eval_views)
    if initial_eval:
        append_metrics(run_dir, {"iteration": 0, "wall_s": 0.0, "train_s": 0.0,
                                 "num_gaussians": int(state.params["means"].shape[0]), **initial_eval})
    return state


@dataclass
class ScheduleSizer:
    """``size_to_minutes``: every slice of the time budget, the schedule (and, while the model
    grows, its Gaussian budget) is re-sized to what the measured step rate can finish."""

    config: TrainConfig
    budget_s: float
    rate_mark: tuple[int, float]          # (step, train seconds) of the last check
    next_check: tuple[int, float]         # (step, train seconds) from which the next check is due: both must pass
    cost_points: list[tuple[float, float]] = field(default_factory=list)   # (mean Gaussians, s/step) per check
    window: RateWindow = field(default_factory=RateWindow)                 # the steps since the last check

    @classmethod
    def starting(cls, config: TrainConfig, budget_s: float, iteration: int, train_s: float) -> "ScheduleSizer":
        return cls(config, budget_s, (iteration, train_s), (iteration + BUDGET_CALIBRATION_STEPS, 0.0))

    def due(self, step: int, train_s: float) -> bool:
        """Whether to re-plan now: a slice of the budget has passed since the last check, or the
        schedule ended early (ended_early)."""
        return (step >= self.next_check[0] and train_s >= self.next_check[1]) or self.ended_early(step, train_s)

    def ended_early(self, step: int, train_s: float) -> bool:
        """Whether the schedule has ended with more than BUDGET_RESIZE_TOLERANCE of the budget
        left (a rate measured while the kernels compiled sized a 3-minute run to 26 steps, over
        after 39 s): the budget is looked at again. A plan fills BUDGET_FILL of the time left, so
        a schedule that ends within the tolerance simply ends."""
        return step >= self.config.iterations and train_s < (1.0 - BUDGET_RESIZE_TOLERANCE) * self.budget_s

    def warmed_up(self, step: int, train_s: float) -> None:
        """After the process's first step: the rate is measured from its end. The first step
        compiles the CPU kernels when their cache is cold (seconds each) and fills the photo
        cache, which no later step pays."""
        self.rate_mark = (step, train_s)
        self.next_check = (step + BUDGET_CALIBRATION_STEPS, self.next_check[1])

    def plan(self, step: int, count: int, rate: float, remaining_s: float) -> tuple[int | None, int | None]:
        """(new schedule length or None, new Gaussian budget or None) at this check."""
        config = self.config
        self.cost_points.append((self.window.mean_count(count), 1.0 / rate))
        if step >= config.densification.densify_until:
            return budget_iterations(step, config.iterations, rate, remaining_s), None
        # The model still grows: size the schedule at the mean cost of growing to the budget (MCMC
        # does, on its plan; densification may), with the budget where a step costs
        # BUDGET_COST_RATIO times one of the run's first model.
        cost = fit_step_cost(self.cost_points)
        first_count = self.cost_points[0][0]
        limit = sized_schedule(config, config.iterations).densification.max_gaussians
        budget = min(limit, max(count, affordable_count(
            cost, BUDGET_COST_RATIO * (cost[0] + cost[1] * first_count))))
        growth_fraction = config.densification.densify_until / max(config.iterations, 1)
        wanted = growing_budget_iterations(step, cost, count, budget, growth_fraction, remaining_s)
        return far_off(step, config.iterations, wanted), budget

    def resize(self, step: int, count: int, elapsed: float, log) -> bool:
        """Re-plan at ``step`` (``elapsed`` training seconds, ``count`` Gaussians) -> whether
        ``self.config`` changed."""
        steps, seconds = step - self.rate_mark[0], elapsed - self.rate_mark[1]
        before = self.config
        if steps > 0 and seconds > 0 and elapsed < (1.0 - BUDGET_FREEZE) * self.budget_s:  # a rate needs both
            wanted, grow_budget = self.plan(step, count, steps / seconds, self.budget_s - elapsed)
            if wanted is not None:
                log(f"time budget: {steps / seconds:.2f} steps/s at {count} Gaussians, "
                    f"schedule re-sized from {self.config.iterations} to {wanted} iterations")
                # A budget the time set stays (past the growth window it is not re-planned).
                resized = sized_schedule(self.config, wanted)
                budget = min(resized.densification.max_gaussians, self.config.densification.max_gaussians)
                self.config = with_values(resized, {"densification.max_gaussians": budget})
            if grow_budget is not None and grow_budget != self.config.densification.max_gaussians:
                self.config = with_values(self.config, {"densification.max_gaussians": grow_budget})
                before_budget = before.densification.max_gaussians
                if abs(grow_budget - before_budget) > 0.1 * before_budget:   # >= 1: its range
                    log(f"time budget: the model grows to at most {grow_budget} Gaussians (a step at most "
                        f"{BUDGET_COST_RATIO:g}x the cost of the first model's)")
        self.rate_mark = (step, elapsed)
        self.window = RateWindow()
        # The next look once another slice of the budget has passed, in training time: counted
        # in steps at this rate it came 25 minutes late on fern (3.3 steps/s at 30k Gaussians
        # became 0.35 at 300k), and the schedule never shrank to what the budget could finish.
        self.next_check = (step + BUDGET_CALIBRATION_STEPS, elapsed + BUDGET_CHECK_FRACTION * self.budget_s)
        return self.config is not before   # each change above built a new config


@dataclass
class StageOne:
    """Stage I's loop over a prepared run: :meth:`steps` until the schedule, the budget or a
    stop ends it, then :meth:`finish` (model, view fit, last metrics line, checkpoint)."""

    config: TrainConfig
    run_dir: Path
    scene: object
    split: object
    data: object
    state: object
    sh_max: int
    rasterizer: "Rasterizer"
    log: Callable[[str], None]
    loop: StepLoop
    after_step: Callable[[int, Gaussians, bool], None] | None = None
    last_eval: dict = field(default_factory=dict)
    last_eval_iteration: int = -1
    finished: bool = True
    shell_filled: bool = False
    pending_counts: dict = field(default_factory=dict)

    def steps(self) -> None:
        budget_s = None if self.config.minutes is None else self.config.minutes * 60.0
        sizer = (ScheduleSizer.starting(self.config, budget_s, self.state.iteration, self.loop.train_s())
                 if self.config.size_to_minutes and budget_s is not None else None)
        first = self.state.iteration
        while self.state.iteration < self.config.iterations or (sizer is not None and sizer.ended_early(
                self.state.iteration, self.loop.train_s())):   # the re-plan below may extend it
            if budget_s is not None and self.loop.train_s() >= budget_s:
                break
            if sizer is not None and sizer.due(self.state.iteration, self.loop.train_s()):
                if sizer.resize(self.state.iteration, self.state.params["means"].shape[0], self.loop.train_s(),
                                self.log):
                    self.config = sizer.config
                    self.config.save(self.run_dir / "config.json")
                    self.loop.bar.total = self.config.iterations
                if self.state.iteration >= self.config.iterations:
                    break
            if self.loop.wait_or_stop():
                self.finished = False
                break
            record = self.step()
            if sizer is not None:
                if self.state.iteration == first + 1:
                    sizer.warmed_up(self.state.iteration, self.loop.train_s())
                else:
                    sizer.window.add(record["num_gaussians"])

    def step(self) -> dict:
        """One training step with its metrics line, snapshot, checkpoint and ``after_step``."""
        config, state = self.config, self.state
        step = state.iteration + 1
        record = train_step(step, state, self.data, config, self.sh_max, self.rasterizer, self.log)
        state.iteration = step
        self.loop.advance()
        if step == config.iterations:   # the schedule's end: the last step's evaluation sees the fill
            self.fill_shell()
        self.pending_counts = add_maintenance_counts(self.pending_counts, record)
        if step % config.output.log_every == 0 or step == config.iterations:
            self.log_step(step, record)
        self.loop.snapshot(step, state.params, record)
        # The last step's checkpoint is the final save's, written after the model (below).
        if step % config.output.checkpoint_every == 0 and step < config.iterations:
            self.stop_clocks()
            save_checkpoint(self.run_dir, state.iteration, state.payload(config), config.output.keep_checkpoints)
        if self.after_step is not None:
            self.after_step(step, gaussians_from_params(state.params).detach(), step % config.output.checkpoint_every == 0)
        return record

    def log_step(self, step: int, record: dict) -> None:
        """The metrics line of ``step`` (with every densification since the last one), evaluated on cadence."""
        record.update(self.pending_counts)
        self.pending_counts = {}
        record.update(iteration=step, **self.loop.clocks())
        if step % self.config.output.eval_every == 0 or step == self.config.iterations:
            eval_start = time.perf_counter()
            self.last_eval = evaluate_held_out(gaussians_from_params(self.state.params).detach(), self.scene,
                                               self.split, self.data, self.rasterizer, self.config.output.eval_views)
            self.last_eval_iteration = step
            record.update(self.last_eval)
            self.loop.exclude(time.perf_counter() - eval_start)  # evaluation is not training time
        append_metrics(self.run_dir, record)
        self.loop.bar.set_postfix(loss=f"{record['loss']:.4f}", n=record["num_gaussians"],
                                  **({"psnr": f"{self.last_eval['all_psnr']:.2f}"} if "all_psnr" in self.last_eval
                                     else {}))

    def stop_clocks(self) -> None:
        self.state.wall_s, self.state.train_s = self.loop.wall_s(), self.loop.train_s()

    def fill_shell(self) -> bool:
        """At the end of training: the sky shell no training view saw takes its seen neighbours'
        colour (:func:`fill_shell_behind_scene`). -> whether the model changed."""
        self.shell_filled = True
        if self.state.sky is None:
            return False
        train_cameras = [self.data.cameras[i] for i in self.data.train]
        filled = fill_shell_behind_scene(self.state.params, self.state.sky, train_cameras, self.rasterizer,
                                         progress=self.loop.progress)
        if filled:
            self.log(f"sky shell: {filled} Gaussians no training view saw (behind the scene) take the colour "
                     f"of their seen neighbours")
        return filled > 0

    def finish(self) -> TrainResult:
        """Final save: the small model first, then its log line, then the (large) checkpoint. Each
        is attempted even when an earlier one fails (a full disk), and each is atomic, so what
        fails leaves the previous version: the newest complete checkpoint stays resumable."""
        state, config, run_dir = self.state, self.config, self.run_dir
        self.stop_clocks()  # the checkpoint holds the clocks as they stood when training stopped
        # A time budget ended the run before its schedule's last step: fill now, evaluate again.
        if self.finished and not self.shell_filled and self.fill_shell():
            self.last_eval_iteration = -1
        gaussians = gaussians_from_params(state.params).detach()
        saves = SaveAttempts()
        attempt = saves.attempt

        if self.finished and self.last_eval_iteration != state.iteration:
            self.last_eval = evaluate_held_out(gaussians, self.scene, self.split, self.data, self.rasterizer,
                                               self.config.output.eval_views)
        # A stopped run saves its model too (stop means save: Ctrl+C, SIGTERM, the viewer's stop);
        # `--resume` continues from the checkpoint written after it.
        attempt(lambda: save_model(run_dir, gaussians, state.iteration, config, self.sh_max,
                                   self.scene.normalization))
        if self.finished:
            if state.view_mse:
                report = view_fit_report(state.view_mse, {i: self.data.cameras[i].name for i in state.view_mse})
                attempt(lambda: atomic_write_text(run_dir / VIEW_FIT_FILE, json.dumps(report, indent=1)))
                line = summary_line(report, str(run_dir / VIEW_FIT_FILE))
                if line:
                    self.log(line)
            # A resumed finished run logs nothing twice.
            if self.last_eval and state.iteration not in logged_iterations(run_dir):
                attempt(lambda: append_metrics(run_dir, {
                    "iteration": state.iteration, "wall_s": state.wall_s, "train_s": state.train_s,
                    "num_gaussians": len(gaussians), **self.last_eval}))
        attempt(lambda: save_checkpoint(run_dir, state.iteration, state.payload(config),
                                        config.output.keep_checkpoints))
        saves.raise_first(self.log)
        return TrainResult(run_dir, state.iteration, self.finished, len(gaussians), self.last_eval)
