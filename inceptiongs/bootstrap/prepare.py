"""What a bootstrap runs on, made before its first step: RUN2 written ready (or a stopped one kept),
the stage-I state restored on the rasterizer's device, the input evaluated, the round plan (with
the outlook's photo-first time), the fill's prior, the sampler and the conscience
-> (state.Setting, plan.RoundPlan, state.LoopState, pool.ViewPool) for loop.py.
"""

from __future__ import annotations

import copy
import json
import math
import shutil
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import InputError
from ..evaluation.lpips_net import load_lpips
from ..io.atomic import atomic_write_bytes, atomic_write_text, check_writable_dir, ensure_dir, \
    output_error, remove_stale_temp_files
from ..rasterizer.interface import device_record, rasterizer_device
from ..runs.checkpoint import list_checkpoints
from ..runs.config import TrainConfig
from ..runs.metrics import truncate_metrics
from ..train.loop import StepLoop
from ..train.step import data_on, prepare_data, restore_state, state_from_gaussians, state_on, supported_sh_degree
from .config import BootstrapConfig
from .conscience import Conscience
from .generation import GenerationCache, ImagePrior, obtain_prior, prior_version
from .outlook import run_outlook
from .perceptual import perceptual_name
from .plan import RoundPlan, following_line, photo_first_s, plan_rounds
from .probe import can_probe, plan_probe
from .pool import ViewPool
from .refine import ViewSampler, continuation_config, perceptual_tau
from .stage1 import Stage1
from .state import LoopState, Setting, held_out_scores
from .summary_file import BOOTSTRAP_DIR
from .targets import Target, targets_to_json
from .virtual_views import DEFAULT_K, nearest_training_views

TARGETS_FILE = "targets.json"     # in RUN2/bootstrap: what is repaired, so --resume needs no flags

# How the report names each --virtual-depth.
DEPTH_WORDS = {"render": "render", "sources": "training views", "both": "render, else the training views",
               "auto": "render or the training views, whichever places more photos"}


def continued_schedule(run: Stage1, config: BootstrapConfig) -> tuple[int, TrainConfig]:
    """(the iteration stage II starts from, the stage-I config continued for its steps)."""
    start = int(run.payload["iteration"]) if run.payload is not None else run.config.iterations
    return start, continuation_config(run.config, start, config.rounds * config.iterations,
                                      config.variants.values())


def prepare_folder(run: Stage1, out_dir: Path, config: BootstrapConfig, targets: Sequence[Target] | None,
                   train_config: TrainConfig, log: Callable[[str], None]) -> Path:
    """RUN2 made ready for this run -> RUN2/bootstrap. Only reached for a fresh folder or with
    overwrite (the user said so)."""
    check_writable_dir(out_dir)
    if (out_dir / "checkpoints").is_symlink():   # refused before anything is written or discarded
        raise InputError(f"{out_dir / 'checkpoints'}: a symlink inside {out_dir}; InceptionGS never writes or deletes "
                         "through a symlink in a run folder (remove the link or give another --out)")
    remove_stale_temp_files(out_dir, max_age_s=0.0)
    boot_dir = ensure_dir(out_dir / BOOTSTRAP_DIR)
    config.save(boot_dir / "config.json")
    if targets is not None:
        atomic_write_text(boot_dir / TARGETS_FILE, json.dumps(targets_to_json(targets), indent=1) + "\n")
    atomic_write_bytes(out_dir / "split.json", (run.run_dir / "split.json").read_bytes())
    train_config.save(out_dir / "config.json")
    (out_dir / "metrics.jsonl").unlink(missing_ok=True)
    (out_dir / "model.ply").unlink(missing_ok=True)  # a stale model must not pass for this run's
    kept = list_checkpoints(out_dir)
    if kept:
        log(f"{out_dir}: discarding the earlier bootstrap's checkpoints (newest at step {kept[-1][0]}; "
            f"`bootstrap --resume` would have continued it)")
        try:
            shutil.rmtree(out_dir / "checkpoints")
        except OSError as exc:
            raise output_error(out_dir / "checkpoints", exc) from None
    return boot_dir


def resume_folder(out_dir: Path) -> Path:
    """RUN2 of a stopped bootstrap, kept as it is -> RUN2/bootstrap."""
    check_writable_dir(out_dir)
    remove_stale_temp_files(out_dir, max_age_s=0.0)
    return ensure_dir(out_dir / BOOTSTRAP_DIR)


def input_scores(out_dir: Path) -> dict:
    """The held-out scores of the input, as the first metrics line of RUN2 holds them."""
    for record in _metric_records(out_dir):
        if record.get("phase") == "input":
            return _scores_of(record)
    return {}


def newest_scores(out_dir: Path) -> dict:
    """The newest held-out scores RUN2's metrics hold ({} when none): where a resumed bootstrap
    stands before its first step. Started from the input's instead, a resume that made no step
    (its budget already spent) wrote the input's scores as its result."""
    scored = [_scores_of(record) for record in _metric_records(out_dir)]
    return next((scores for scores in reversed(scored) if scores), {})


def _metric_records(out_dir: Path) -> list[dict]:
    """RUN2/metrics.jsonl's records, oldest first (a torn or foreign line skipped)."""
    path = out_dir / "metrics.jsonl"
    records = []
    for line in (path.read_text(encoding="utf-8", errors="replace").splitlines() if path.is_file() else []):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(record, dict):
            records.append(record)
    return records


def _scores_of(record: dict) -> dict:
    return {k: v for k, v in record.items() if k.endswith(("_psnr", "_ssim"))}


def fill_words(config: BootstrapConfig) -> str:
    """What I* is made of when nothing is generated, for the summary and the log."""
    made = f"variants {', '.join(config.variants)};" if config.variants else "supervision blend,"
    return (f"none: I* is made from the photos and the render ({made} fill {config.fill}, depth from the "
            f"{DEPTH_WORDS[config.virtual_depth]}), nothing is generated")


def obtain_fill(run: Stage1, out_dir: Path, config: BootstrapConfig, plan: RoundPlan, clock: StepLoop,
                rasterizer, cpu_photos: dict, log: Callable[[str], None]
                ) -> tuple[ImagePrior | None, str, str, dict]:
    """The prior that generates the fill, when the supervision needs one (else none is trained
    or loaded, and the summary says what I* is made of instead) -> (the prior or None, its
    version, its description, the summary's "prior" record)."""
    began = time.perf_counter()
    if math.isinf(plan.photo_until_s):
        text = "none: no virtual views (the loop follows the outlook: nothing to repair)"
        return None, "", text, {"description": text, "version": "", "seconds": 0.0}
    if not config.needs_prior():
        text = fill_words(config)
        log(text)
        return None, "", text, {"description": text, "version": "", "seconds": 0.0}
    # The budget covers the whole job: a short prior training may take at most half of what
    # is left of it when the prior starts (loading and the first evaluation have already
    # spent some), in wall-clock seconds, so generation and refinement keep the rest. A stop
    # (or pause) from the user is honoured between the prior's steps too.
    prior_s = 60.0 * config.prior_minutes
    if config.minutes is not None:
        prior_s = min(prior_s, max(60.0 * config.minutes - clock.wall_s(), 0.0) / 2.0)
    prior_end = clock.wall_s() + prior_s
    # The photos from the host copy (the prior's trainer keeps them there and moves each
    # batch), the prior on the run's device, where the virtual views are made.
    train = run.split.train
    prior, text = obtain_prior(
        run.run_dir, out_dir, run.gaussians, run.train_cameras,
        lambda k: cpu_photos[train[k]].numpy(), config.prior, config.seed, prior_s / 60.0, config.prior_steps,
        log, should_stop=lambda: clock.wait_or_stop() or clock.wall_s() >= prior_end,
        device=rasterizer_device(rasterizer))
    prior.eval()
    version = prior_version(prior)
    record = {"description": text, "version": version, "seconds": time.perf_counter() - began}
    log(text)
    return prior, version, text, record


def conscience_views(run: Stage1, plan: RoundPlan, config: BootstrapConfig) -> tuple[int, ...]:
    """The training photos nearest the targets: the conscience watches them (none for the
    baseline, which has no virtual views to restrain)."""
    cameras, train = list(run.scene.cameras), list(run.split.train)
    k = config.k or DEFAULT_K
    return tuple(sorted({i for goal in plan.rounds for t in goal
                         for i in nearest_training_views(t.camera, cameras, train, k)}))


def prepare(run: Stage1, out_dir: Path, targets: Sequence[Target] | None, config: BootstrapConfig,
            clock: StepLoop, rasterizer, log: Callable[[str], None], resume: dict | None = None
            ) -> tuple[Setting, RoundPlan, LoopState, ViewPool]:
    """RUN2 written ready, the state restored, the input evaluated, the plan made, the prior
    obtained. ``resume``: the newest checkpoint of a stopped bootstrap in RUN2, continued from."""
    start, train_config = continued_schedule(run, config)
    plan = plan_rounds(targets, config.rounds, config.iterations, start)
    boot_dir = (prepare_folder(run, out_dir, config, targets, train_config, log) if resume is None
                else resume_folder(out_dir))
    data = prepare_data(run.scene, run.split, train_config, log)
    sh_max = supported_sh_degree(len(data.train), train_config.sh.degree_max)
    if resume is not None:
        train = restore_state(resume, data, train_config)
        truncate_metrics(out_dir, train.iteration)   # the steps after it run (and are logged) again
    else:
        # A copy: the optimiser adopts the payload's moment tensors and updates them in place,
        # and the same Stage1 may start another run (the demo's baseline).
        train = (restore_state(copy.deepcopy(run.payload), data, train_config) if run.payload is not None
                 else state_from_gaussians(run.gaussians, data, train_config))
        train.iteration = start
    cpu_photos = data.images
    device = rasterizer_device(rasterizer)
    data, train = data_on(data, device), state_on(train, device, train_config, data.extent)
    initial = (held_out_scores(run, data, rasterizer, out_dir, clock, train, {"phase": "input", "round": 0})
               if resume is None else input_scores(out_dir))
    summary = {"run": str(run.run_dir.resolve()), "baseline": plan.baseline, "start_iteration": start,
               "targets": [{"name": t.name, "origin": t.origin} for goal in plan.rounds for t in goal],
               "rounds": [], "initial_eval": initial, "device": device_record(rasterizer)}
    if resume is not None:
        summary["resumed_at"] = train.iteration
    prior, prior_hash, prior_text = None, "", "none (baseline: no virtual views)"
    probe = None
    if targets is not None:
        outlook = run_outlook(run.run_dir)   # what stage I's curve says before any work is spent
        log(outlook.line)
        summary["outlook"] = outlook.to_json()
        probing = config.follow_outlook and outlook.verdict == "unknown" and can_probe(initial)
        if config.follow_outlook and not probing:
            plan = plan_following(plan, within_budget(photo_first_s(outlook), config), summary, log)
        prior, prior_hash, prior_text, summary["prior"] = obtain_fill(run, out_dir, config, plan, clock, rasterizer,
                                                                      cpu_photos, log)
        if probing:
            probe = plan_probe(train.iteration, plan.start + len(plan.rounds) * plan.steps - train.iteration,
                               None if config.minutes is None else 60.0 * config.minutes, clock.wall_s(),
                               clock.train_s())
            summary["probe"] = {"until_step": probe.until_step,
                                "until_s": None if math.isinf(probe.until_s) else probe.until_s}
            log(f"measuring the repair outlook instead: photo steps up to step {probe.until_step}"
                + ("" if math.isinf(probe.until_s) else f" or {probe.until_s:.0f} s") +
                ", then the held-out views are scored again (follow_outlook: false makes virtual views from the start)")
    # The one place the LPIPS weights are loaded (plain tensors, lpips_net; null: MS-SSIM-G, perceptual.py).
    lpips = load_lpips(config.lpips_weights) if config.lpips_weights else None
    summary["perceptual"] = (perceptual_name(lpips) + (f" ({config.lpips_weights})" if lpips is not None else "")
                             if perceptual_tau(config, lpips) > 0 else "none (tau 0: every virtual loss is L1 + D-SSIM)")
    cache = GenerationCache(boot_dir / "cache")
    sampler = ViewSampler(config.seed)
    saved = (resume or {}).get("bootstrap", {})
    if saved.get("pose") is not None:
        sampler.pose = np.asarray(saved["pose"], dtype=np.float64)
    sampler.visits = {str(name): int(count) for name, count in (saved.get("visits") or {}).items()}
    watched = conscience_views(run, plan, config)
    conscience = Conscience(config.conscience_tolerance) if config.conscience_tolerance is not None and watched \
        else None
    setting = Setting(run, out_dir, boot_dir, train_config, data, cpu_photos, sh_max, rasterizer, log, cache, prior,
                      prior_hash, prior_text, lpips, watched, initial)
    last = initial if resume is None else (newest_scores(out_dir) or initial)
    return setting, plan, LoopState(train, clock, conscience, summary, last, probe=probe), ViewPool(sampler)


def within_budget(photo_until_s: float, config: BootstrapConfig) -> float:
    """``photo_until_s``, or math.inf when it reaches past the time budget: then no virtual view
    could be used, and making them (and a fill) would only take time from the photo steps."""
    if config.minutes is not None and photo_until_s >= 60.0 * config.minutes:
        return math.inf
    return photo_until_s


def plan_following(plan: RoundPlan, photo_until_s: float, summary: dict, log: Callable[[str], None]) -> RoundPlan:
    """``plan`` with the outlook's photo-first time (outlook.py), recorded in the summary
    ("photo_first_s"; null: every step) and said in one line when it holds any step back."""
    plan = RoundPlan(plan.rounds, plan.steps, plan.start, plan.baseline, photo_until_s)
    summary["photo_first_s"] = None if math.isinf(photo_until_s) else photo_until_s
    if photo_until_s > 0.0:
        log(following_line(photo_until_s))
    return plan
