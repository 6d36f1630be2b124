"""The bootstrap loop: a stage-I run folder in, a repaired run folder out.

Per round: virtual views around the round's targets (A's virtual_views), I* at each (the prior's
image, cached, blended with warped real photos), then refinement steps alternating real photos
and virtual views (Langevin-chosen). Round r+1 starts from round r's Gaussians and keeps round
r's virtual views in the pool, so what round r repaired stays supervised.

RUN2 is a run folder (docs/training.md): config.json (the stage-I config, extended schedule),
split.json (copied, so evaluations are comparable), checkpoints/, model.ply, metrics.jsonl
(wall_s counted from the start of the bootstrap); plus RUN2/bootstrap/ (config.json,
summary.json, cache/, views/*.png) and RUN2/prior/ when a prior was trained here.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
from tqdm import tqdm

from ..io.atomic import atomic_write_bytes, atomic_write_text, check_writable_dir, ensure_dir, \
    remove_stale_temp_files
from ..errors import InputError
from ..gaussians import Gaussians
from ..live import wait_while_paused
from ..threads import use_torch_threads
from .config import BootstrapConfig
from .conscience import Conscience, photo_loss
from .virtual_views import DEFAULT_K, nearest_training_views
from .generation import GenerationCache, VirtualTarget, blend_target, gaussians_version, generate_cached, \
    obtain_prior, prior_version
from ..io.flags import FLAGS_FILE_NAME
from .stage1 import Stage1, as_stage1, load_stage1  # noqa: F401 (load_stage1: re-exported)
from .targets import Target, flag_targets, named_target, round_targets, split_targets

BOOTSTRAP_DIR = "bootstrap"


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


def default_out_dir(run_dir: str | Path) -> Path:
    run_dir = Path(run_dir)
    return run_dir.with_name(run_dir.name + "_bootstrap")


def check_output_folder(out_dir: Path, overwrite: bool) -> None:
    """InputError (one line) when ``out_dir`` holds a result and the user did not ask to replace it."""
    from ..train.run_folder import holds_result, next_free_folder

    if holds_result(out_dir) and not overwrite:
        raise InputError(f"{out_dir}: already holds a result; give --overwrite to replace it, or another "
                         f"--out (e.g. {next_free_folder(out_dir)})")


# --- inputs ----------------------------------------------------------------------------------------
def default_flag_files(scene, run_dir: str | Path | None = None) -> list[Path]:
    """Where the viewer's flags.json may be, first found wins: the run folder, the scene's
    cache folder, then (read-only) the scene folder's .inceptiongs/ written by older versions."""
    found = [Path(run_dir) / FLAGS_FILE_NAME] if run_dir is not None else []
    with contextlib.suppress(InputError):
        found.append(Path(scene.work_dir) / FLAGS_FILE_NAME)
    return found + [Path(scene.legacy_work_dir) / FLAGS_FILE_NAME]


def resolve_targets(scene, split, targets_file: str | Path | None, target_view: str | None,
                    rounds: int, run_dir: str | Path | None = None) -> list[Target]:
    """--targets FILE, else --target-view NAME, else the viewer's flags.json when it exists
    (:func:`default_flag_files`), else j*."""
    train_cameras = [scene.cameras[i] for i in split.train]
    if targets_file is not None and target_view is not None:
        raise InputError("give either --targets or --target-view, not both")
    if targets_file is not None:
        return flag_targets(Path(targets_file), train_cameras)
    if target_view is not None:
        return [named_target(scene, target_view)]
    for default_flags in default_flag_files(scene, run_dir):
        if default_flags.is_file():
            return flag_targets(default_flags, train_cameras)
    return split_targets(split, scene, rounds)


# --- small pieces ------------------------------------------------------------------------------------
def _view_png(generated: torch.Tensor, mask: torch.Tensor, target: torch.Tensor, render: torch.Tensor) -> np.ndarray:
    """generated | mask | I* | stage-I render, side by side: [H, 4W, 3] uint8."""
    panels = [generated, mask.expand(-1, -1, 3), target, render]
    image = torch.cat([p.detach().float().clamp(0, 1).cpu() for p in panels], dim=1).numpy()
    return np.round(image * 255.0).astype(np.uint8)


def _write_summary(path: Path, summary: dict) -> None:
    from ..io.config_json import json_safe

    atomic_write_text(path, json.dumps(json_safe(summary), indent=1) + "\n")


def expected_total_steps(done: int, spent_s: float, left_s: float, cap: int, min_steps: int = 5) -> int | None:
    """Steps a time-budgeted run will have made when its time runs out: ``done`` so far in
    ``spent_s`` seconds of stepping, at the same rate for the ``left_s`` seconds left, at most
    ``cap``. None (not yet known) before ``min_steps``: the first steps build caches and their
    rate is noise, and the cap (the demo's baseline: 100 000) would be a wrong total to show."""
    if done < min_steps or spent_s <= 0.0:
        return None
    return int(min(cap, done + max(left_s, 0.0) * done / spent_s))


# --- the loop --------------------------------------------------------------------------------------
def run_bootstrap(run: Stage1 | str | Path, out_dir: str | Path, targets: Sequence[Target] | None,
                  config: BootstrapConfig, control=None,
                  on_snapshot: Callable[[int, Gaussians, dict], None] | None = None, snapshot_every: int = 0,
                  log: Callable[[str], None] | None = None, progress: bool = True,
                  render_fn=None, overwrite: bool = False) -> BootstrapResult:
    """Bootstrap RUN (a loaded :class:`Stage1`, or its folder) into RUN2 (see the module doc). ``targets=None`` with an empty pool is the
    same-time baseline: the stage-I loop continued on the photos alone (``baseline_run``).
    An ``out_dir`` that already holds a result is refused (InputError) unless ``overwrite``
    (see ``inceptiongs.train.run_folder.next_free_folder`` for a fresh name instead)."""
    from ..io.images import write_png
    from ..io.ply import write_ply
    from ..train.checkpoint import save_checkpoint
    from ..train.free_space import render_surface_depth
    from .source_depth import depth_from_training_views
    from ..train.optim import gaussians_from_params
    from ..train.run_folder import append_metrics, to_original_frame
    from ..train.step import (evaluate_held_out, prepare_data, restore_state, sh_degree_at, state_from_gaussians,
                              supported_sh_degree, train_step, trim_sh)
    from .refine import ViewSampler, active_views, additive_step, continuation_config, render_l1, virtual_step

    if render_fn is None:
        from ..rasterizer.rasterize import render as render_fn
    log = log or (lambda message: tqdm.write(message, file=sys.stderr))
    config.validate()
    use_torch_threads()
    clock_start = time.perf_counter()   # moved forward by pauses: paused time is nobody's time
    out_dir = Path(out_dir)
    if out_dir.resolve() == Path(run if not isinstance(run, Stage1) else run.run_dir).resolve():
        raise InputError(f"{out_dir}: the output folder must differ from the input run")
    check_output_folder(out_dir, overwrite)
    run = as_stage1(run)
    run_dir, stage1, scene, split, payload, gaussians0 = (run.run_dir, run.config, run.scene, run.split, run.payload,
                                                          run.gaussians)
    baseline = targets is None
    rounds = round_targets(targets, config.rounds) if not baseline else [[] for _ in range(config.rounds)]

    check_writable_dir(out_dir)
    remove_stale_temp_files(out_dir, max_age_s=0.0)
    boot_dir = ensure_dir(out_dir / BOOTSTRAP_DIR)
    config.save(boot_dir / "config.json")
    atomic_write_bytes(out_dir / "split.json", (run_dir / "split.json").read_bytes())
    start = int(payload["iteration"]) if payload is not None else stage1.iterations
    train_config = continuation_config(stage1, start, config.rounds * config.iterations, config.densify)
    train_config.save(out_dir / "config.json")
    # Only reached for a fresh folder or with overwrite=True (the user said so).
    (out_dir / "metrics.jsonl").unlink(missing_ok=True)
    (out_dir / "model.ply").unlink(missing_ok=True)  # a stale model must not pass for this run's
    if (out_dir / "checkpoints").is_dir():
        shutil.rmtree(out_dir / "checkpoints")

    data = prepare_data(scene, split, train_config, log)
    sh_max = supported_sh_degree(len(data.train), train_config.sh_degree_max)
    # A copy: the optimiser adopts the payload's moment tensors and updates them in place, and
    # the same Stage1 may start another run (the demo's baseline).
    state = (restore_state(copy.deepcopy(payload), data, train_config) if payload is not None
             else state_from_gaussians(gaussians0, data, train_config))
    state.iteration = start
    cameras = list(scene.cameras)

    def now() -> float:
        return time.perf_counter() - clock_start

    def out_of_time() -> bool:
        return config.minutes is not None and now() >= 60.0 * config.minutes

    def wait_or_stop() -> bool:
        """Honour pause; True when asked to stop."""
        nonlocal clock_start
        stop, paused_s = wait_while_paused(control)
        clock_start += paused_s
        return stop

    eval_s = 0.0

    def evaluate_now(extra: dict) -> dict:
        nonlocal eval_s
        began = time.perf_counter()
        scores = evaluate_held_out(gaussians_from_params(state.params).detach(), scene, split, data)
        eval_s += time.perf_counter() - began
        append_metrics(out_dir, {"iteration": state.iteration, "wall_s": now(), "train_s": now() - eval_s,
                                 "num_gaussians": int(state.params["means"].shape[0]), **extra, **scores})
        return scores

    initial_eval = evaluate_now({"phase": "input", "round": 0})
    summary: dict = {"run": str(run_dir.resolve()), "baseline": baseline, "start_iteration": start,
                     "targets": [{"name": t.name, "origin": t.origin} for r in rounds for t in r],
                     "rounds": [], "initial_eval": initial_eval}

    prior, prior_text, prior_hash = None, "none (baseline: no virtual views)", ""
    if not baseline and not config.needs_prior():
        prior_text = (f"none: I* is made from the photos and the render (supervision {config.supervision}, "
                      f"fill {config.fill}, depth from the "
                      f"{DEPTH_WORDS[config.virtual_depth]}), nothing is generated")
        summary["prior"] = {"description": prior_text, "version": "", "seconds": 0.0}
        log(prior_text)
    elif not baseline:
        began = time.perf_counter()
        train_cams = [cameras[i] for i in split.train]
        # The budget covers the whole job: a short prior training may take at most half of what
        # is left of it when the prior starts (loading and the first evaluation have already
        # spent some), in wall-clock seconds, so generation and refinement keep the rest. A stop
        # (or pause) from the user is honoured between the prior's steps too.
        prior_s = 60.0 * config.prior_minutes
        if config.minutes is not None:
            prior_s = min(prior_s, max(60.0 * config.minutes - now(), 0.0) / 2.0)
        prior_end = now() + prior_s

        def prior_should_stop() -> bool:
            return wait_or_stop() or now() >= prior_end

        prior, prior_text = obtain_prior(
            run_dir, out_dir, gaussians0, train_cams, lambda k: data.images[split.train[k]].numpy(),
            config.prior, config.seed, prior_s / 60.0, config.prior_steps, log, should_stop=prior_should_stop)
        prior.eval()
        prior_hash = prior_version(prior)
        summary["prior"] = {"description": prior_text, "version": prior_hash,
                            "seconds": time.perf_counter() - began}
        log(prior_text)
    lpips = None
    if config.lpips_weights:
        from ..evaluation.run import load_torchscript
        lpips = load_torchscript(config.lpips_weights, "LPIPS")
    from .perceptual import perceptual_name
    summary["perceptual"] = perceptual_name(lpips) + (f" ({config.lpips_weights})" if lpips is not None else "")

    cache = GenerationCache(boot_dir / "cache")
    pool: list[VirtualTarget] = []
    sampler = ViewSampler(config, config.seed)
    # The conscience watches the training photos nearest the targets (none for the baseline,
    # which has no virtual views to restrain).
    conscience_views = sorted({i for r in rounds for t in r
                               for i in nearest_training_views(t.camera, cameras, list(split.train), config.k or DEFAULT_K)})
    conscience = Conscience(config.conscience_tolerance) if (config.conscience_tolerance is not None
                                                             and conscience_views) else None
    # What each refinement step was ("additive": a photo step carrying a virtual loss, also
    # counted by its virtual branch; "idle": a virtual slot with no informative view, a photo step).
    step_counts = {"real": 0, "perceptual": 0, "l1_ssim": 0, "informative_l1": 0, "geometry": 0, "additive": 0,
                   "idle": 0}
    view_use: dict[str, int] = {}                               # how often each virtual view was chosen
    finished = True
    last_eval = initial_eval
    rounds_done = 0
    step_cap = config.rounds * config.iterations
    # A time-budgeted run's total is unknown until a rate is measured (advance_bar sets it).
    bar = tqdm(total=None if config.minutes is not None else step_cap, desc="baseline" if baseline else "bootstrap",
               file=sys.stderr, dynamic_ncols=True, disable=not progress, unit="it")
    first_step_at: list[float] = []                             # when the first refinement step began

    def advance_bar() -> None:
        """One step done. A time-budgeted run ends when its minutes are spent, usually long before
        its step cap (the demo's baseline: 100 000): the bar's total is the steps the measured
        rate fits into the time left, so its count and ETA are the run's, not the cap's."""
        bar.update(1)
        if config.minutes is not None and first_step_at:
            total = expected_total_steps(bar.n, now() - first_step_at[0], 60.0 * config.minutes - now(), step_cap)
            if total is not None and total != bar.total:
                bar.total = total
                bar.refresh()

    def checkpoint_now(round_index: int) -> None:
        state.wall_s, state.train_s = now(), now() - eval_s
        body = state.payload(train_config)
        body["bootstrap"] = {"round": round_index, "config": config.to_json_dict(),
                             "pose": None if sampler.pose is None else sampler.pose.tolist()}
        save_checkpoint(out_dir, state.iteration, body, train_config.keep_checkpoints)

    def target_maker(current: Gaussians):
        """-> make(camera, round, save) -> (VirtualTarget, blend sources): I* at a virtual view
        from ``current`` (its G-buffer, its render for the prior's start, its depth for warping)."""
        gaussians_hash = gaussians_version(current)
        # One render per (camera, output) for this model: the warps' depths, the fill, the PNGs.
        render_cache: dict[tuple[str, str], torch.Tensor] = {}

        def cached(camera, output: str, compute: Callable[[], torch.Tensor]) -> torch.Tensor:
            key = (camera.name + str(camera.world_to_camera.tobytes()), output)
            if key not in render_cache:
                with torch.no_grad():
                    render_cache[key] = compute()
            return render_cache[key]

        def rendered(camera, output: str) -> torch.Tensor:
            return cached(camera, output, lambda: render_fn(current, camera, outputs=(output,))[output])

        def render_depth(camera) -> torch.Tensor:
            # The scene's own surface: the sky shell blended in pulls a faint surface's depth
            # far behind it, and the warps then place the photos wrongly and reject them.
            return cached(camera, "surface_depth",
                          lambda: render_surface_depth(current, camera, state.sky, render_fn))

        def render_rgb(camera) -> torch.Tensor:
            return rendered(camera, "rgb").float().clamp(0.0, 1.0)

        def make(camera, round_number: int, save: bool):
            if prior is not None:
                generated, hit = generate_cached(prior, current, camera, config.seed, config.ddim_steps,
                                                 cache, prior_hash, gaussians_hash)
            else:  # the fill is the render itself (or inpainted around it): nothing to generate
                generated, hit = render_rgb(camera).numpy(), False
            sources = _blend_sources(camera, cameras, split.train, config)
            report: dict = {}
            if config.virtual_colour:
                target_depth = None
                if config.virtual_depth != "render" and sources:
                    target_depth = depth_from_training_views(camera, cameras, split.train, config.splat_views,
                                                             render_depth)
                image, mask = blend_target(generated, camera, sources, cameras, data.images, render_depth,
                                           config.blending, config.delta, config.supervision, config.fill,
                                           render_rgb, config.virtual_pixels, config.residual_floor,
                                           target_depth, report,
                                           config.virtual_depth if config.virtual_depth in ("both", "auto") else "none",
                                           config.align_px)
            else:
                # No colour target: I* (depth sweep, warps; ~2.3 s per courtyard view) would be
                # built for nothing. The render stands in for the PNGs, with an empty mask.
                image, mask = torch.as_tensor(generated, dtype=torch.float32), torch.zeros(camera.height, camera.width, 1)
            geometry = []
            if config.geometry_weight > 0:
                from .multiview import GeometrySource

                # Grey photos (NCC ignores colour balance) and the current depth of each source
                # (the geometry term's visibility reference).
                geometry = [GeometrySource(data.images[i].float().mean(-1, keepdim=True), cameras[i],
                                           render_depth(cameras[i])) for i in sources]
            agreement = report.get("agreement_db")
            # Only the photos' colour is gated: a geometry-only view has no warped colour to judge.
            supervised = (config.agreement_min_db is None or agreement is None or not config.virtual_colour
                          or agreement >= config.agreement_min_db)
            entry = VirtualTarget(camera.name, camera, image, mask, torch.as_tensor(generated), hit, round_number,
                                  geometry, agreement, supervised, report.get("depth", "render"))
            if save:
                write_png(boot_dir / "views" / f"{camera.name}.png",
                          _view_png(entry.generated, mask, image, render_rgb(camera)))
            return entry, sources

        return make

    def regenerate_pool() -> None:
        """I* of every pool view again, from the Gaussians as they are now: the prior then repairs
        the refined render rather than the stage-I one (the bootstrap's feedback loop)."""
        began = time.perf_counter()
        make_target = target_maker(gaussians_from_params(state.params).detach())
        for number, entry in enumerate(pool):
            if wait_or_stop() or out_of_time():
                break  # the views not reached keep their I*
            pool[number], _ = make_target(entry.camera, entry.round, save=False)
        regenerations.append({"iteration": state.iteration, "views": len(pool),
                              "supervised": sum(entry.supervised for entry in pool),
                              "seconds": time.perf_counter() - began})
        log(f"step {state.iteration}: regenerated {len(pool)} virtual views in {regenerations[-1]['seconds']:.1f} s")

    regenerations: list[dict] = []
    try:
        for round_index, round_goal in enumerate(rounds):
            if wait_or_stop() or out_of_time():
                finished = False
                break
            round_info = {"round": round_index + 1, "targets": [t.name for t in round_goal], "views": []}
            # --- virtual views and their I* (from this round's starting Gaussians) ---------------
            began = time.perf_counter()
            new_views = _round_virtual_views(round_goal, cameras, split.train, config)
            if new_views:
                make_target = target_maker(gaussians_from_params(state.params).detach())
                for number, (target_index, view) in enumerate(new_views):
                    if wait_or_stop() or out_of_time():
                        break
                    name = f"r{round_index + 1}_t{target_index}_{view.name}"
                    entry, sources = make_target(view.camera.with_pose(view.camera.world_to_camera, name=name),
                                                 round_index + 1, save=number < config.save_views)
                    pool.append(entry)
                    round_info["views"].append({"name": name, "source": int(view.source), "t": float(view.t),
                                                "cache_hit": entry.cache_hit,
                                                "mask_fraction": float(entry.mask.mean()),
                                                "agreement_db": entry.agreement_db, "supervised": entry.supervised,
                                                "depth": entry.depth,
                                                "blend_sources": [int(s) for s in sources]})
                round_info["generation_s"] = time.perf_counter() - began
                log(f"round {round_index + 1}: {len(round_info['views'])} virtual views "
                    f"({sum(v['cache_hit'] for v in round_info['views'])} from the cache) in "
                    f"{round_info['generation_s']:.1f} s")
                left_out = [v for v in round_info["views"] if not v["supervised"]]
                if left_out:
                    log(f"round {round_index + 1}: {len(left_out)} of {len(round_info['views'])} virtual views left "
                        f"out: the render agrees with their warped photos better than the photos agree with "
                        f"each other (by more than {-config.agreement_min_db:g} dB)")
            # --- refinement ------------------------------------------------------------------
            began = time.perf_counter()
            stopped = False
            round_end = state.iteration + config.iterations
            for _ in range(config.iterations):
                if wait_or_stop() or out_of_time():
                    stopped = True
                    break
                step = state.iteration + 1
                if not first_step_at:
                    first_step_at.append(now())
                # A regeneration pays off over the steps after it: none for a round's last few.
                # Nor when every view was left out (agreement.py): the photos' steps are worth more
                # than re-judging views the render already agrees with better.
                if (pool and config.regenerate_every and (step - start) % config.regenerate_every == 0
                        and round_end - step + 1 >= max(1, config.regenerate_every // 2)
                        and any(entry.supervised for entry in pool)):
                    regenerate_pool()
                if conscience is not None and (step - start - 1) % config.conscience_every == 0:
                    loss = photo_loss(render_fn, gaussians_from_params(state.params).detach(), cameras, data.images,
                                      conscience_views, sh_degree_at(step, train_config, sh_max))
                    conscience.update(step, loss)
                active = [pool[i] for i in active_views(pool, config.virtual_pixels)] if pool else []
                if pool and step % config.virtual_every == 0 and not active:
                    step_counts["idle"] += 1
                if active and step % config.virtual_every == 0:
                    sh_degree = sh_degree_at(step, train_config, sh_max)
                    frozen = gaussians_from_params(state.params).detach()
                    choice = sampler.choose(active, lambda i, w2c: render_l1(render_fn, frozen, active[i], sh_degree, w2c))
                    scale = conscience.scale if conscience is not None else 1.0
                    if config.virtual_mode == "additive":
                        record = additive_step(step, state, data, train_config, sh_max, active[choice.index], choice,
                                               config, render_fn,
                                               lambda: train_step(step, state, data, train_config, sh_max, render_fn,
                                                                  log),
                                               lpips, scale=scale)
                        step_counts["additive"] += 1
                    else:
                        record = virtual_step(step, state, data, train_config, sh_max, active[choice.index], choice,
                                              config, render_fn, lpips, scale=scale)
                    step_counts[record["virtual_branch"]] += 1
                    view_use[active[choice.index].name] = view_use.get(active[choice.index].name, 0) + 1
                else:
                    record = train_step(step, state, data, train_config, sh_max, render_fn, log)
                    record["kind"] = "real"
                    step_counts["real"] += 1
                state.iteration = step
                advance_bar()
                if step % config.log_every == 0:
                    record.update(iteration=step, wall_s=now(), train_s=now() - eval_s, round=round_index + 1)
                    if conscience is not None:
                        record.update(conscience_loss=conscience.history[-1][1], virtual_scale=conscience.scale)
                    if config.eval_every and step % config.eval_every == 0:
                        record.update(evaluate_held_out(gaussians_from_params(state.params).detach(), scene, split, data))
                    append_metrics(out_dir, record)
                if on_snapshot is not None and snapshot_every > 0 and step % snapshot_every == 0:
                    on_snapshot(step, gaussians_from_params(state.params).detach(), record)
                if (step - start) % config.checkpoint_every == 0:
                    checkpoint_now(round_index + 1)
            round_info["refine_s"] = time.perf_counter() - began
            last_eval = evaluate_now({"phase": "round", "round": round_index + 1})
            round_info["eval"] = last_eval
            summary["rounds"].append(round_info)
            checkpoint_now(round_index + 1)
            if stopped:
                finished = False
                break
            rounds_done += 1
    finally:
        bar.close()

    gaussians = gaussians_from_params(state.params).detach()
    # Like stage I, a run that stopped early leaves its checkpoint; model.ply marks the end of the
    # run (load_run reads the checkpoint otherwise). A time budget that ran out is an end too.
    stopped_by_user = control is not None and control.stop.is_set()
    if not stopped_by_user:
        write_ply(to_original_frame(trim_sh(gaussians, sh_degree_at(max(state.iteration, 1), train_config, sh_max)),
                                    scene.normalization), out_dir / "model.ply")
    train_config = dataclasses.replace(train_config, iterations=max(state.iteration, start + 1))
    train_config.save(out_dir / "config.json")
    summary.update(iteration=state.iteration, finished=finished, rounds_done=rounds_done,
                   wall_s=now(), cache_hits=cache.hits, cache_misses=cache.misses,
                   virtual_views=len(pool), last_eval=last_eval, steps=step_counts,
                   view_use=view_use, regenerations=regenerations,
                   conscience=None if conscience is None else {
                       "views": [cameras[i].name for i in conscience_views], "tolerance": conscience.tolerance,
                       "baseline": conscience.baseline, "checks": [list(c) for c in conscience.history]})
    _write_summary(boot_dir / "summary.json", summary)
    return BootstrapResult(out_dir, start, state.iteration, finished, rounds_done, len(gaussians), len(pool),
                           cache.hits, cache.misses, now(), prior_text, initial_eval, last_eval,
                           supervised_views=sum(entry.supervised for entry in pool))


def _round_virtual_views(goal: Sequence[Target], cameras, train: Sequence[int], config: BootstrapConfig):
    """[(target index, VirtualView)] for the round's targets, at most config.max_virtual_views."""
    from .virtual_views import VirtualView, virtual_views

    kwargs = {name: getattr(config, name) for name in ("k", "l") if getattr(config, name) is not None}
    views = []
    for index, target in enumerate(goal):
        if config.include_target:
            views.append((index, VirtualView(target.camera.with_pose(target.camera.world_to_camera, name="target"),
                                             -1, 0.0, "target")))
        views.extend((index, view) for view in virtual_views(target.camera, cameras, list(train), **kwargs))
    return views[:config.max_virtual_views]


# How the report names each --virtual-depth.
DEPTH_WORDS = {"render": "render", "sources": "training views", "both": "render, else the training views",
               "auto": "render or the training views, whichever places more photos"}


def _blend_sources(camera, cameras, train: Sequence[int], config: BootstrapConfig) -> list[int]:
    """The K training photos nearest the virtual view (warped into it for blending)."""
    if not config.blending:
        return []
    return nearest_training_views(camera, cameras, list(train), config.k or DEFAULT_K)


def baseline_run(run: Stage1 | str | Path, out_dir: str | Path, minutes: float | None, iterations: int,
                 seed: int = 0, progress: bool = True, log=None, eval_every: int = 0,
                 overwrite: bool = False) -> BootstrapResult:
    """Stage I continued on the photos alone, with the same continuation schedule the bootstrap
    uses, for ``minutes`` (the bootstrap's total time) or ``iterations``: the comparison baseline."""
    config = BootstrapConfig(seed=seed, iterations=iterations, minutes=minutes, rounds=1, log_every=1,
                             eval_every=eval_every)
    return run_bootstrap(run, out_dir, None, config, progress=progress, log=log, overwrite=overwrite)
