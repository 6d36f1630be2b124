"""The bootstrap loop: rounds of refinement steps over the pool of virtual views, then the
finish (model, config, summary, checkpoint). prepare.py makes what it runs on; runner.py runs
prepare -> :func:`run_rounds` -> :func:`finish`.

Per round: virtual views around the round's targets and their I* (round_views.py), then
refinement steps alternating real photos and virtual views (Langevin-chosen, refine.py). Round
r+1 starts from round r's Gaussians and keeps round r's virtual views in the pool, so what round
r repaired stays supervised. Every function takes the config, the round plan, the fixed setting
and the state it changes as arguments (state.py, plan.py, pool.py).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..io.atomic import atomic_write_text
from ..io.config_json import json_safe
from ..runs.checkpoint import save_checkpoint
from ..runs.metrics import append_metrics
from ..train.loop import SaveAttempts, out_of_memory_stops, save_model
from ..train.step import evaluate_held_out, sh_degree_at, train_step
from .config import BootstrapConfig
from .conscience import photo_loss
from .plan import RoundPlan, photo_first_s
from .pool import ViewPool, in_use, supervised_count
from .probe import measured_outlook, photo_until
from .refine import active_views, render_l1, virtual_loss, virtual_step
from .round_views import add_round_views, open_round, regenerate_pool, remade_if_stale
from .state import LoopState, Setting, evaluate, model
from .summary_file import SUMMARY_FILE, virtual_step_count


@dataclass
class BootstrapResult:
    out_dir: Path
    start_iteration: int
    iteration: int
    finished: bool                  # False: stopped by request or out of time before the last round ended
    rounds_done: int
    num_gaussians: int
    virtual_views: int
    cache_hits: int
    cache_misses: int
    wall_s: float
    prior: str
    initial_eval: dict = field(default_factory=dict)
    last_eval: dict = field(default_factory=dict)
    # Virtual views that took part in the refinement at the end (agreement.py; None: unknown).
    supervised_views: int | None = None
    # Refinement steps that carried a virtual loss, over the whole run (None: unknown).
    virtual_steps: int | None = None


# --- rounds ----------------------------------------------------------------------------------------
def run_rounds(setting: Setting, config: BootstrapConfig, plan: RoundPlan, state: LoopState, pool: ViewPool,
               first_round: int = 0, steps_left: int | None = None) -> None:
    """The plan's rounds from ``first_round`` (0-based; ``steps_left`` of it after a resume,
    None: all), each: its views, its refinement, a checkpoint between rounds. A resumed run
    first remakes the finished rounds' views (the pool keeps them). Stops early, with
    ``state.finished`` False, on the user's stop or the time budget."""
    for earlier in range(first_round if first_round < len(plan.rounds) else 0):
        open_round(setting, config, plan, state, pool, earlier)
    for round_index in range(first_round, len(plan.rounds)):
        if state.clock.wait_or_stop() or state.clock.out_of_time():
            state.finished = False
            break
        state.current_round = round_index + 1
        open_round(setting, config, plan, state, pool, round_index)
        if not refine_round(setting, config, plan, state, pool, round_index,
                            steps_left if round_index == first_round else None):
            state.finished = False
            break
        state.rounds_done += 1
        if round_index + 1 < len(plan.rounds):
            checkpoint(setting, config, state, pool, round_index + 1)


def refine_round(setting: Setting, config: BootstrapConfig, plan: RoundPlan, state: LoopState, pool: ViewPool,
                 round_index: int, steps: int | None = None) -> bool:
    """The round's refinement steps (``steps``: those left of it, after a resume) and its
    evaluation -> False when stopped (by the user or the time budget) before its last step."""
    began = time.perf_counter()
    stopped = False
    steps = plan.steps if steps is None else steps
    state.current_round = round_index + 1
    train = state.train
    round_end = train.iteration + steps
    with out_of_memory_stops(setting.out_dir, lambda: (train.iteration + 1, train.params["means"].shape[0]),
                             "--resume"):
        for _ in range(steps):
            if state.clock.wait_or_stop() or state.clock.out_of_time():
                stopped = True
                break
            refine_step(setting, config, plan, state, pool, train.iteration + 1, round_index, round_end)
    round_info = state.summary["rounds"][-1]
    round_info["refine_s"] = time.perf_counter() - began
    state.last_eval = round_info["eval"] = evaluate(setting, state, {"phase": "round", "round": round_index + 1})
    return not stopped


def regeneration_due(config: BootstrapConfig, plan: RoundPlan, pool: ViewPool, step: int, round_end: int) -> bool:
    """A regeneration pays off over the steps after it: none for a round's last few. Nor when
    every view was left out (agreement.py): the photos' steps are worth more than re-judging
    views the render already agrees with better."""
    every = config.regenerate_every
    return bool(pool.entries and every and (step - plan.start) % every == 0
                and round_end - step + 1 >= max(1, every // 2) and in_use(pool))


# --- one step --------------------------------------------------------------------------------------
def refine_step(setting: Setting, config: BootstrapConfig, plan: RoundPlan, state: LoopState, pool: ViewPool,
                step: int, round_index: int, round_end: int) -> None:
    """One refinement step (a virtual view's every ``virtual_every``-th, else a photo's) and
    its bookkeeping: metrics, snapshot, checkpoint."""
    clock, conscience = state.clock, state.conscience
    clock.mark_first_step()
    if state.probe is not None and state.probe.over(step, clock.wall_s()):
        end_probe(setting, state)
    if pool.pending_round is not None and clock.wall_s() >= photo_until(plan, state):
        pending, pool.pending_round = pool.pending_round, None
        add_round_views(setting, config, plan, state, pool, pending, state.summary["rounds"][-1])
    if regeneration_due(config, plan, pool, step, round_end):
        regenerate_pool(setting, config, state, pool)
    # (A resumed run's conscience starts again: its first step takes the baseline.)
    # (No view in use yet, or every view left out: nothing for the conscience to restrain, so
    # its photo renders are skipped and the time goes to photo steps.)
    check_due = (step - plan.start - 1) % config.conscience_every == 0
    if conscience is not None and in_use(pool) and (check_due or not conscience.history):
        loss = photo_loss(setting.rasterizer, model(state.train), list(setting.run.scene.cameras),
                          setting.data.images, list(setting.conscience_views),
                          sh_degree_at(step, setting.train_config, setting.sh_max))
        conscience.update(step, loss)
    record = virtual_or_photo_step(setting, config, state, pool, step)
    state.train.iteration = step
    clock.advance()
    if step % config.log_every == 0:
        record.update(iteration=step, **clock.clocks(), round=round_index + 1)
        if conscience is not None and conscience.history:
            record.update(conscience_loss=conscience.history[-1][1], virtual_scale=conscience.scale)
        if config.eval_every and step % config.eval_every == 0:
            run = setting.run
            record.update(evaluate_held_out(model(state.train), run.scene, run.split, setting.data,
                                            setting.rasterizer, run.config.output.eval_views))
        append_metrics(setting.out_dir, record)
    clock.snapshot(step, state.train.params, record)
    if (step - plan.start) % config.checkpoint_every == 0:
        checkpoint(setting, config, state, pool, round_index + 1)


def end_probe(setting: Setting, state: LoopState) -> None:
    """The probe's photo steps are done: score the held-out views again and read the outlook from
    the two scorings (probe.py); from now on the loop follows it."""
    clock, probe = state.clock, state.probe
    scores = evaluate(setting, state, {"phase": "probe"})
    outlook = measured_outlook(setting.initial_eval, scores, clock.train_s() - probe.start_train_s)
    wait = photo_first_s(outlook)
    state.probe, state.last_eval = None, scores
    state.photo_until_s = clock.wall_s() + wait            # inf stays inf: every step on the photos
    state.summary["outlook"] = {**outlook.to_json(), "measured": True}
    state.summary["photo_first_s"] = None if math.isinf(wait) else state.photo_until_s
    setting.log(outlook.line)


def virtual_or_photo_step(setting: Setting, config: BootstrapConfig, state: LoopState, pool: ViewPool,
                          step: int) -> dict:
    """On a virtual slot a view chosen by the sampler when one may be sampled (the step: a
    variant's ``take_step``, else refine.virtual_step), else a photo step -> the step's record."""
    s, counts = setting, state.counts
    numbers = active_views(pool.entries, config) if pool.entries else []
    active = [pool.entries[i] for i in numbers]
    virtual_slot = step % config.virtual_every == 0
    if pool.entries and virtual_slot and not active:
        counts["idle"] += 1
    elif pool.pending_round is not None and virtual_slot:
        counts["photo_first"] += 1

    def photo_step() -> dict:
        return train_step(step, state.train, s.data, s.train_config, s.sh_max, s.rasterizer, s.log)

    def real_step() -> dict:
        record = photo_step()
        record["kind"] = "real"
        counts["real"] += 1
        return record

    if not (active and virtual_slot):
        return real_step()
    sh_degree = sh_degree_at(step, s.train_config, s.sh_max)
    frozen = model(state.train)
    choice = pool.sampler.choose(active, lambda i, w2c: render_l1(s.rasterizer, frozen, active[i], sh_degree, w2c),
                                 config)
    view = remade_if_stale(setting, config, state, pool, numbers[choice.index])
    if not active_views([view], config):
        counts["idle"] += 1       # made again, the gate left it out: the slot goes to the photos
        return real_step()
    scale = state.conscience.scale if state.conscience is not None else 1.0
    record = None
    for variant in config.variants.values():
        record = variant.take_step(lambda: virtual_loss(step, state.train, s.train_config, s.sh_max, view, choice,
                                                        config, s.rasterizer, s.lpips, scale=scale), photo_step)
        if record is not None:
            counts[record["kind"]] += 1
            break
    if record is None:
        record = virtual_step(step, state.train, s.data, s.train_config, s.sh_max, view, choice, config,
                              s.rasterizer, s.lpips, scale=scale)
    counts[record["virtual_branch"]] += 1
    return record


# --- saving ----------------------------------------------------------------------------------------
def checkpoint(setting: Setting, config: BootstrapConfig, state: LoopState, pool: ViewPool, round_number: int) -> None:
    """The stage-I checkpoint of the state now, plus the bootstrap's entry: the round, the
    config and the sampler's Langevin pose and visits (what `--resume` continues from)."""
    train = state.train
    train.wall_s, train.train_s = state.clock.wall_s(), state.clock.train_s()
    body = train.payload(setting.train_config)
    pose = pool.sampler.pose
    body["bootstrap"] = {"round": round_number, "config": config.to_json_dict(),
                         "pose": None if pose is None else pose.tolist(), "visits": dict(pool.sampler.visits)}
    save_checkpoint(setting.out_dir, train.iteration, body, setting.train_config.output.keep_checkpoints)


def finish(setting: Setting, config: BootstrapConfig, plan: RoundPlan, state: LoopState,
           pool: ViewPool) -> BootstrapResult:
    """The final save, in the order that keeps the result: model.ply (a stopped run's too:
    stop means save), then the final config.json and summary.json, then the checkpoint
    `--resume` continues from. Each is attempted even when an earlier one fails (a full
    disk) and each is atomic; the first failure is raised once all were tried."""
    saves = SaveAttempts()
    attempt = saves.attempt
    gaussians = model(state.train)
    run, train = setting.run, state.train
    attempt(lambda: save_model(setting.out_dir, gaussians, train.iteration, setting.train_config, setting.sh_max,
                               run.scene.normalization))
    attempt(lambda: write_summary(setting, plan, state, pool))
    if state.current_round or not state.finished:   # stopped before round 1 too: `--resume` starts it
        attempt(lambda: checkpoint(setting, config, state, pool, max(state.current_round, 1)))
    saves.raise_first(setting.log)
    cache = setting.cache
    return BootstrapResult(setting.out_dir, plan.start, train.iteration, state.finished, state.rounds_done,
                           len(gaussians), len(pool.entries), cache.hits, cache.misses, state.clock.wall_s(),
                           setting.prior_text, setting.initial_eval, state.last_eval,
                           supervised_views=supervised_count(pool), virtual_steps=virtual_step_count(state.counts))


def write_summary(setting: Setting, plan: RoundPlan, state: LoopState, pool: ViewPool) -> None:
    """RUN2/config.json with the steps made, and RUN2/bootstrap/summary.json."""
    train, clock, conscience = state.train, state.clock, state.conscience
    final_config = dataclasses.replace(setting.train_config, iterations=max(train.iteration, plan.start + 1))
    final_config.save(setting.out_dir / "config.json")
    state.summary.update(
        iteration=train.iteration, finished=state.finished, stopped=clock.stopped_by_user(),
        rounds_done=state.rounds_done, wall_s=clock.wall_s(),
        cache_hits=setting.cache.hits, cache_misses=setting.cache.misses, virtual_views=len(pool.entries),
        last_eval=state.last_eval, steps=state.counts, view_use=pool.sampler.visits,
        regenerations=pool.regenerations,
        conscience=None if conscience is None else {
            "views": [setting.run.scene.cameras[i].name for i in setting.conscience_views],
            "tolerance": conscience.tolerance, "baseline": conscience.baseline,
            "checks": [list(c) for c in conscience.history]})
    atomic_write_text(setting.out_dir / SUMMARY_FILE, json.dumps(json_safe(state.summary), indent=1) + "\n")
