"""The stage-I training loop: run folder, schedule, evaluation, checkpoints, snapshots.

Everything that does not change during training is prepared once before the loop (the
photos as tensors at the training resolution, their grey versions and edge weights, the
neighbour views); one step (:mod:`.step`) renders the sampled view, adds the photometric,
flattening, normal and (every ``multiview_every`` steps) the multi-view terms, steps Adam,
and densifies on schedule.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from tqdm import tqdm

from ..errors import InputError
from ..io.atomic import OutputError, atomic_write_text, check_writable_dir, remove_stale_temp_files
from ..gaussians import Gaussians
from ..live import wait_while_paused
from ..threads import use_torch_threads
from .budget import (BUDGET_CALIBRATION_STEPS, BUDGET_CHECK_FRACTION, BUDGET_COST_RATIO, BUDGET_FREEZE,
                     RateWindow, affordable_count, budget_iterations, far_off, fit_step_cost,
                     growing_budget_iterations)
from .checkpoint import latest_checkpoint, load_newest_checkpoint, save_checkpoint
from .config import TrainConfig, sized_schedule
from .optim import gaussians_from_params
from .sky import fill_shell_behind_scene
from .view_fit import VIEW_FIT_FILE, summary_line, view_fit_report
from .run_folder import append_metrics, logged_iterations, to_original_frame, truncate_metrics
from .step import (add_maintenance_counts, evaluate_held_out, log_once, new_state, prepare_data, restore_state,
                   sh_degree_at, supported_sh_degree, train_step, trim_sh)


@dataclass
class TrainResult:
    run_dir: Path
    iteration: int
    finished: bool          # reached the iteration or time budget (False: stopped by request)
    num_gaussians: int
    last_eval: dict = field(default_factory=dict)


def train(config: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True,
          control=None, on_snapshot: Callable[[int, Gaussians, dict], None] | None = None,
          snapshot_every: int = 0, render_fn=None, log: Callable[[str], None] | None = None,
          after_step: Callable[[int, Gaussians, bool], None] | None = None) -> TrainResult:
    """Train stage I into ``run_dir``; see docs/training.md.

    control: object with ``stop`` / ``pause`` threading.Events (JobControl) or None.
    on_snapshot(iteration, detached Gaussians, metrics) every ``snapshot_every`` steps.
    render_fn defaults to inceptiongs.rasterizer.rasterize.render (backend "auto").
    after_step(iteration, detached Gaussians, checkpointed) after every step (e.g. one
    diffusion-prior step, `inceptiongs train --prior`); its time counts as training time.
    """
    from ..evaluation.protocols import make_split
    from ..scene.loader import load_scene

    if render_fn is None:
        from ..rasterizer.rasterize import render as render_fn
    log = log or (lambda message: tqdm.write(message, file=sys.stderr))
    use_torch_threads()
    run_dir = Path(run_dir)
    config.validate()
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
        if not split.train:
            raise InputError(f"{config.scene}: the {config.protocol} split leaves no training views")
        if split.excluded:
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
    config.save(run_dir / "config.json")
    split.save(run_dir / "split.json")
    sh_max = supported_sh_degree(len(data.train), config.sh_degree_max)

    if payload is not None:
        state = restore_state(payload, data, config)
        truncate_metrics(run_dir, state.iteration)
        log(f"resumed from {checkpoint.name} (iteration {state.iteration})")
    else:
        state = new_state(scene, data, config, sh_max, log)
        (run_dir / "metrics.jsonl").unlink(missing_ok=True)
        # Iteration 0: the initial model's scores, the start of every PSNR-vs-time curve.
        initial_eval = evaluate_held_out(gaussians_from_params(state.params).detach(), scene, split, data)
        if initial_eval:
            append_metrics(run_dir, {"iteration": 0, "wall_s": 0.0, "train_s": 0.0,
                                     "num_gaussians": int(state.params["means"].shape[0]), **initial_eval})
    if config.pgsr and not any(data.neighbours.values()):
        log_once(state, "no-neighbours", "multi-view terms skipped: no training view has a neighbour", log)

    budget_s = None if config.minutes is None else config.minutes * 60.0
    last_eval: dict = {}
    last_eval_iteration = -1
    finished = True
    bar = tqdm(total=config.iterations, initial=state.iteration, desc="train", file=sys.stderr,
               dynamic_ncols=True, disable=not progress, unit="it")
    session_start = time.perf_counter() - state.wall_s
    train_clock = time.perf_counter() - state.train_s

    def stop_clocks() -> None:
        state.wall_s = time.perf_counter() - session_start
        state.train_s = time.perf_counter() - train_clock

    def checkpoint_now() -> None:
        stop_clocks()
        save_checkpoint(run_dir, state.iteration, state.payload(config), config.keep_checkpoints)

    sizing = config.size_to_minutes and budget_s is not None
    rate_mark = (state.iteration, time.perf_counter() - train_clock)   # (step, train seconds) of the last check
    # (step, train seconds) from which the next check is due: both must have passed.
    next_check = (state.iteration + BUDGET_CALIBRATION_STEPS, 0.0)

    cost_points: list[tuple[float, float]] = []   # (mean Gaussians, s/step) of each check's window
    window = RateWindow()                          # the steps since the last check

    def plan(step: int, rate: float, remaining_s: float) -> tuple[int | None, int | None]:
        """(new schedule length or None, new Gaussian budget or None) at this check."""
        count = state.params["means"].shape[0]
        cost_points.append((window.mean_count(count), 1.0 / rate))
        if step >= config.densify_until:
            return budget_iterations(step, config.iterations, rate, remaining_s), None
        # The model still grows: size the schedule at the mean cost of growing to the budget (MCMC
        # does, on its plan; densification may), with the budget where a step costs
        # BUDGET_COST_RATIO times one of the session's first model.
        cost = fit_step_cost(cost_points)
        first_count = cost_points[0][0]
        limit = sized_schedule(config, config.iterations).max_gaussians
        budget = min(limit, max(count, affordable_count(
            cost, BUDGET_COST_RATIO * (cost[0] + cost[1] * first_count))))
        growth_fraction = config.densify_until / max(config.iterations, 1)
        wanted = growing_budget_iterations(step, cost, count, budget, growth_fraction, remaining_s)
        return far_off(step, config.iterations, wanted), budget

    def resize(step: int) -> None:
        nonlocal config, rate_mark, next_check, window
        elapsed = time.perf_counter() - train_clock
        steps, seconds = step - rate_mark[0], elapsed - rate_mark[1]
        if steps > 0 and seconds > 0 and elapsed < (1.0 - BUDGET_FREEZE) * budget_s:  # a rate needs both
            wanted, grow_budget = plan(step, steps / seconds, budget_s - elapsed)
            before = config
            if wanted is not None:
                log(f"time budget: {steps / seconds:.2f} steps/s at {state.params['means'].shape[0]} Gaussians, "
                    f"schedule re-sized from {config.iterations} to {wanted} iterations")
                # A budget the time set stays (past the growth window it is not re-planned).
                resized = sized_schedule(config, wanted)
                config = dataclasses.replace(resized, max_gaussians=min(resized.max_gaussians, config.max_gaussians))
            if grow_budget is not None and grow_budget != config.max_gaussians:
                config = dataclasses.replace(config, max_gaussians=grow_budget)
                if abs(grow_budget - before.max_gaussians) > 0.1 * before.max_gaussians:   # >= 1: validated
                    log(f"time budget: the model grows to at most {grow_budget} Gaussians (a step at most "
                        f"{BUDGET_COST_RATIO:g}x the cost of the first model's)")
            if config is not before:   # each change above built a new config
                config.save(run_dir / "config.json")
                bar.total = config.iterations
        rate_mark = (step, elapsed)
        window = RateWindow()
        # The next look once another slice of the budget has passed, in training time: counted
        # in steps at this rate it came 25 minutes late on fern (3.3 steps/s at 30k Gaussians
        # became 0.35 at 300k), and the schedule never shrank to what the budget could finish.
        next_check = (step + BUDGET_CALIBRATION_STEPS, elapsed + BUDGET_CHECK_FRACTION * budget_s)

    shell_filled = False

    def fill_shell() -> bool:
        """At the end of training: the sky shell no training view saw takes its seen neighbours'
        colour (:func:`fill_shell_behind_scene`). -> whether the model changed."""
        nonlocal shell_filled
        shell_filled = True
        if state.sky is None:
            return False
        filled = fill_shell_behind_scene(state.params, state.sky, [data.cameras[i] for i in data.train], render_fn)
        if filled:
            log(f"sky shell: {filled} Gaussians no training view saw (behind the scene) take the colour "
                f"of their seen neighbours")
        return filled > 0

    pending_counts: dict[str, int] = {}
    try:
        while state.iteration < config.iterations:
            if budget_s is not None and time.perf_counter() - train_clock >= budget_s:
                break
            if (sizing and state.iteration >= next_check[0]
                    and time.perf_counter() - train_clock >= next_check[1]):
                resize(state.iteration)
            stop, paused_s = wait_while_paused(control)
            session_start += paused_s
            train_clock += paused_s
            if stop:
                finished = False
                break
            step = state.iteration + 1
            record = train_step(step, state, data, config, sh_max, render_fn, log)
            state.iteration = step
            window.add(record["num_gaussians"])
            bar.update(1)
            if step == config.iterations:   # the schedule's end: the last step's evaluation sees the fill
                fill_shell()
            pending_counts = add_maintenance_counts(pending_counts, record)

            if step % config.log_every == 0 or step == config.iterations:
                record.update(pending_counts)  # every densification since the last logged line
                pending_counts = {}
                record.update(iteration=step, wall_s=time.perf_counter() - session_start,
                              train_s=time.perf_counter() - train_clock)
                if step % config.eval_every == 0 or step == config.iterations:
                    eval_start = time.perf_counter()
                    gaussians = gaussians_from_params(state.params).detach()
                    last_eval = evaluate_held_out(gaussians, scene, split, data)
                    last_eval_iteration = step
                    record.update(last_eval)
                    train_clock += time.perf_counter() - eval_start  # evaluation is not training time
                append_metrics(run_dir, record)
                bar.set_postfix(loss=f"{record['loss']:.4f}", n=record["num_gaussians"],
                                **({"psnr": f"{last_eval['all_psnr']:.2f}"} if "all_psnr" in last_eval else {}))
            if on_snapshot is not None and snapshot_every > 0 and step % snapshot_every == 0:
                on_snapshot(step, gaussians_from_params(state.params).detach(), record)
            # The last step's checkpoint is the final save's, written after the model (below).
            if step % config.checkpoint_every == 0 and step < config.iterations:
                checkpoint_now()
            if after_step is not None:
                after_step(step, gaussians_from_params(state.params).detach(),
                           step % config.checkpoint_every == 0)
    finally:
        bar.close()

    stop_clocks()  # the checkpoint holds the clocks as they stood when training stopped
    # A time budget ended the run before its schedule's last step: fill now, evaluate again.
    if finished and not shell_filled and fill_shell():
        last_eval_iteration = -1
    gaussians = gaussians_from_params(state.params).detach()
    # Final save: the small model first, then its log line, then the (large) checkpoint. Each
    # is attempted even when an earlier one fails (a full disk), and each is atomic, so what
    # fails leaves the previous version: the newest complete checkpoint stays resumable.
    failures: list[InputError] = []

    def attempt(write) -> None:
        try:
            write()
        except OutputError as exc:
            failures.append(exc)

    from ..io.ply import write_ply
    # A stopped run saves its model too (stop means save: Ctrl+C, SIGTERM, the viewer's stop);
    # `--resume` continues from the checkpoint written beside it.
    attempt(lambda: write_ply(to_original_frame(
        trim_sh(gaussians, sh_degree_at(max(state.iteration, 1), config, sh_max)), scene.normalization),
        run_dir / "model.ply"))
    if finished:
        if last_eval_iteration != state.iteration:
            last_eval = evaluate_held_out(gaussians, scene, split, data)
        if state.view_mse:
            report = view_fit_report(state.view_mse, {i: data.cameras[i].name for i in state.view_mse})
            attempt(lambda: atomic_write_text(run_dir / VIEW_FIT_FILE, json.dumps(report, indent=1)))
            line = summary_line(report, str(run_dir / VIEW_FIT_FILE))
            if line:
                log(line)
        # A resumed finished run logs nothing twice.
        if last_eval and state.iteration not in logged_iterations(run_dir):
            attempt(lambda: append_metrics(run_dir, {
                "iteration": state.iteration, "wall_s": state.wall_s, "train_s": state.train_s,
                "num_gaussians": len(gaussians), **last_eval}))
    attempt(lambda: save_checkpoint(run_dir, state.iteration, state.payload(config), config.keep_checkpoints))
    if failures:
        for later in failures[1:]:  # one line each; the first is raised (the CLI prints it)
            log(f"error: {later}")
        raise failures[0]
    return TrainResult(run_dir, state.iteration, finished, len(gaussians), last_eval)


