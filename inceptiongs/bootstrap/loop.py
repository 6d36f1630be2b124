"""The bootstrap loop's steps: prepare RUN2, make a round's virtual views and their I*, refine,
finish (model, config, summary). ``runner.run_bootstrap`` runs them in that order.

Per round: virtual views around the round's targets (virtual_views), I* at each (view_targets:
the fill blended with warped real photos), then refinement steps alternating real photos and
virtual views (Langevin-chosen). Round r+1 starts from round r's Gaussians and keeps round r's
virtual views in the pool, so what round r repaired stays supervised.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..evaluation.networks import load_torchscript
from ..io.atomic import atomic_write_bytes, atomic_write_text, check_writable_dir, ensure_dir, \
    remove_stale_temp_files
from ..io.config_json import json_safe
from ..rasterizer.interface import device_record, rasterizer_device
from ..runs.checkpoint import list_checkpoints, save_checkpoint
from ..runs.config import TrainConfig
from ..train.loop import SaveAttempts, StepLoop, out_of_memory_stops, save_model
from ..gaussians import gaussians_from_params
from ..runs.metrics import append_metrics, truncate_metrics
from ..train.step import (data_on, evaluate_held_out, prepare_data, restore_state, sh_degree_at,
                          state_from_gaussians, state_on, supported_sh_degree, train_step)
from .config import BootstrapConfig
from .conscience import Conscience, photo_loss
from .generation import GenerationCache, VirtualTarget, obtain_prior, prior_version
from .outlook import run_outlook
from .perceptual import perceptual_name
from .placement import candidate_views, evidence_share, place_by_evidence, with_evidence
from .refine import ViewSampler, active_views, continuation_config, render_l1, virtual_step
from .stage1 import Stage1
from .summary_file import BOOTSTRAP_DIR, SUMMARY_FILE, virtual_step_count
from .targets import Target, round_targets, targets_to_json
from .validation import EvidenceGrid, measure_evidence, seen_cells, validation_photos
from .view_targets import TargetMaker, TargetSetting
from .virtual_views import DEFAULT_K, DEFAULT_L, VirtualView, nearest_training_views, virtual_views

TARGETS_FILE = "targets.json"     # in RUN2/bootstrap: what is repaired, so --resume needs no flags

# How the report names each --virtual-depth.
DEPTH_WORDS = {"render": "render", "sources": "training views", "both": "render, else the training views",
               "auto": "render or the training views, whichever places more photos"}


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


def round_virtual_views(goal: Sequence[Target], cameras, train: Sequence[int], config: BootstrapConfig):
    """[(target index, VirtualView)] for the round's targets, at most config.max_virtual_views."""
    kwargs = {name: getattr(config, name) for name in ("k", "l") if getattr(config, name) is not None}
    views = []
    for index, target in enumerate(goal):
        if config.include_target:
            views.append((index, VirtualView(target.camera.with_pose(target.camera.world_to_camera, name="target"),
                                             -1, 0.0, "target")))
        views.extend((index, view) for view in virtual_views(target.camera, cameras, list(train), **kwargs))
    return views[:config.max_virtual_views]


def continued_schedule(run: Stage1, config: BootstrapConfig) -> tuple[int, TrainConfig]:
    """(the iteration stage II starts from, the stage-I config continued for its steps)."""
    start = int(run.payload["iteration"]) if run.payload is not None else run.config.iterations
    return start, continuation_config(run.config, start, config.rounds * config.iterations, config.densify)


def prepare_folder(run: Stage1, out_dir: Path, config: BootstrapConfig, targets: Sequence[Target] | None,
                   log: Callable[[str], None]) -> tuple[Path, int, TrainConfig]:
    """RUN2 made ready for this run -> (RUN2/bootstrap, the start iteration, the continued
    stage-I config). Only reached for a fresh folder or with overwrite (the user said so)."""
    check_writable_dir(out_dir)
    remove_stale_temp_files(out_dir, max_age_s=0.0)
    boot_dir = ensure_dir(out_dir / BOOTSTRAP_DIR)
    config.save(boot_dir / "config.json")
    if targets is not None:
        atomic_write_text(boot_dir / TARGETS_FILE, json.dumps(targets_to_json(targets), indent=1) + "\n")
    atomic_write_bytes(out_dir / "split.json", (run.run_dir / "split.json").read_bytes())
    start, train_config = continued_schedule(run, config)
    train_config.save(out_dir / "config.json")
    (out_dir / "metrics.jsonl").unlink(missing_ok=True)
    (out_dir / "model.ply").unlink(missing_ok=True)  # a stale model must not pass for this run's
    kept = list_checkpoints(out_dir)
    if kept:
        log(f"{out_dir}: discarding the earlier bootstrap's checkpoints (newest at step {kept[-1][0]}; "
            f"`bootstrap --resume` would have continued it)")
        shutil.rmtree(out_dir / "checkpoints")
    return boot_dir, start, train_config


def resume_folder(run: Stage1, out_dir: Path, config: BootstrapConfig) -> tuple[Path, int, TrainConfig]:
    """RUN2 of a stopped bootstrap, kept as it is -> the same as :func:`prepare_folder`."""
    check_writable_dir(out_dir)
    remove_stale_temp_files(out_dir, max_age_s=0.0)
    start, train_config = continued_schedule(run, config)
    return ensure_dir(out_dir / BOOTSTRAP_DIR), start, train_config


def input_scores(out_dir: Path) -> dict:
    """The held-out scores of the input, as the first metrics line of RUN2 holds them."""
    path = out_dir / "metrics.jsonl"
    for line in (path.read_text(encoding="utf-8", errors="replace").splitlines() if path.is_file() else []):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(record, dict) and record.get("phase") == "input":
            return {k: v for k, v in record.items() if k.endswith(("_psnr", "_ssim"))}
    return {}


@dataclass
class Bootstrap:
    """One bootstrap in progress: the stage-I run, RUN2, the optimiser state, the pool of
    virtual views and what the summary will say about them."""

    run: Stage1
    out_dir: Path
    boot_dir: Path
    config: BootstrapConfig
    train_config: TrainConfig
    rounds: list[list[Target]]
    loop: StepLoop
    rasterizer: Callable
    log: Callable[[str], None]
    data: object
    state: object
    sh_max: int
    start: int
    prior: object = None
    prior_text: str = "none (baseline: no virtual views)"
    prior_hash: str = ""
    lpips: object = None
    summary: dict = field(default_factory=dict)
    initial_eval: dict = field(default_factory=dict)    # the input's held-out scores
    last_eval: dict = field(default_factory=dict)       # the newest held-out scores
    cache: GenerationCache | None = None
    pool: list[VirtualTarget] = field(default_factory=list)
    sampler: ViewSampler | None = None
    conscience_views: list[int] = field(default_factory=list)
    conscience: Conscience | None = None
    # What each refinement step was ("additive": a photo step carrying a virtual loss, also
    # counted by its virtual branch; "idle": a virtual slot with no informative view, a photo step;
    # "photo_first": a virtual slot before the round's views are made (follow_outlook), a photo step).
    step_counts: dict = field(default_factory=lambda: dict.fromkeys(
        ("real", "perceptual", "l1_ssim", "informative_l1", "geometry", "additive", "idle", "photo_first"), 0))
    view_use: dict = field(default_factory=dict)            # how often each virtual view was chosen
    regenerations: list = field(default_factory=list)
    finished: bool = True
    rounds_done: int = 0
    # The photos on the CPU, for the leave-one-out estimate (placement "evidence") and the prior's
    # training; ``data`` holds them on the rasterizer's device, where a round's virtual views are
    # made and refined.
    cpu_photos: dict = field(default_factory=dict)
    current_round: int = 0          # 1-based: the round being refined (0: none yet)
    # placement "evidence": the newest round's leave-one-out estimate (validation.py; None: no evidence).
    evidence: EvidenceGrid | None = None
    # follow_outlook: the bootstrap's wall second before which every step is a photo step (0: none;
    # inf: all). A round whose views wait for it is made then (pending_round).
    photo_until_s: float = 0.0
    pending_round: int | None = None

    # --- prepare ---------------------------------------------------------------------------------
    @classmethod
    def prepare(cls, run: Stage1, out_dir: Path, targets: Sequence[Target] | None, config: BootstrapConfig,
                loop: StepLoop, rasterizer, log, resume: dict | None = None) -> "Bootstrap":
        """RUN2 written ready, the state restored, the input evaluated, the prior obtained.
        ``resume``: the newest checkpoint of a stopped bootstrap in RUN2, continued from."""
        rounds = round_targets(targets, config.rounds) if targets is not None else [[] for _ in range(config.rounds)]
        boot_dir, start, train_config = (prepare_folder(run, out_dir, config, targets, log) if resume is None
                                         else resume_folder(run, out_dir, config))
        data = prepare_data(run.scene, run.split, train_config, log)
        sh_max = supported_sh_degree(len(data.train), train_config.sh.degree_max)
        if resume is not None:
            state = restore_state(resume, data, train_config)
            truncate_metrics(out_dir, state.iteration)   # the steps after it run (and are logged) again
        else:
            # A copy: the optimiser adopts the payload's moment tensors and updates them in place,
            # and the same Stage1 may start another run (the demo's baseline).
            state = (restore_state(copy.deepcopy(run.payload), data, train_config) if run.payload is not None
                     else state_from_gaussians(run.gaussians, data, train_config))
            state.iteration = start
        cpu_photos = data.images
        device = rasterizer_device(rasterizer)
        data, state = data_on(data, device), state_on(state, device, train_config, data.extent)
        boot = cls(run, out_dir, boot_dir, config, train_config, rounds, loop, rasterizer, log, data, state, sh_max,
                   start, cpu_photos=cpu_photos)
        boot.initial_eval = boot.last_eval = (boot.evaluate({"phase": "input", "round": 0}) if resume is None
                                              else input_scores(out_dir))
        boot.summary = {"run": str(run.run_dir.resolve()), "baseline": targets is None, "start_iteration": start,
                        "targets": [{"name": t.name, "origin": t.origin} for r in rounds for t in r],
                        "rounds": [], "initial_eval": boot.initial_eval, "device": device_record(rasterizer)}
        if resume is not None:
            boot.summary["resumed_at"] = state.iteration
        if targets is not None:
            outlook = run_outlook(run.run_dir)   # what stage I's curve says before any work is spent
            log(outlook.line)
            boot.summary["outlook"] = outlook.to_json()
            if config.follow_outlook:
                boot.follow(outlook)
            boot.obtain_prior()
        if config.lpips_weights:
            boot.lpips = load_torchscript(config.lpips_weights, "LPIPS")
        boot.summary["perceptual"] = (perceptual_name(boot.lpips)
                                      + (f" ({config.lpips_weights})" if boot.lpips is not None else ""))
        boot.cache = GenerationCache(boot_dir / "cache")
        boot.sampler = ViewSampler(config, config.seed)
        pose = (resume or {}).get("bootstrap", {}).get("pose")
        if pose is not None:
            boot.sampler.pose = np.asarray(pose, dtype=np.float64)
        boot.watch_conscience()
        return boot

    def follow(self, outlook) -> None:
        """The step plan the outlook asks for (outlook.py): none of the virtual views' work when
        there is nothing to repair, photo steps first while stage I's curve still rises fast."""
        if outlook.verdict == "nothing to repair":
            self.photo_until_s = math.inf
        elif outlook.verdict == "train longer":
            wait = outlook.photo_first_min
            # On the bootstrap's own clock (0 at its start, carried through a resume).
            self.photo_until_s = math.inf if wait is None else 60.0 * wait
        self.summary["photo_first_s"] = None if math.isinf(self.photo_until_s) else self.photo_until_s
        if self.photo_until_s > 0.0:
            self.log("the loop follows the outlook: " + (
                "no virtual views, every step on the photos" if math.isinf(self.photo_until_s) else
                f"photo steps until {self.photo_until_s / 60.0:.1f} min, then virtual views")
                + " (follow_outlook: false makes virtual views from the start)")

    def obtain_prior(self) -> None:
        """The prior that generates the fill, when the supervision needs one (else none is
        trained or loaded, and the summary says what I* is made of instead)."""
        config, began = self.config, time.perf_counter()
        if math.isinf(self.photo_until_s):
            self.prior_text = "none: no virtual views (the loop follows the outlook: nothing to repair)"
            self.summary["prior"] = {"description": self.prior_text, "version": "", "seconds": 0.0}
            return
        if not config.needs_prior():
            self.prior_text = (f"none: I* is made from the photos and the render (supervision {config.supervision}, "
                               f"fill {config.fill}, depth from the "
                               f"{DEPTH_WORDS[config.virtual_depth]}), nothing is generated")
            self.summary["prior"] = {"description": self.prior_text, "version": "", "seconds": 0.0}
            self.log(self.prior_text)
            return
        # The budget covers the whole job: a short prior training may take at most half of what
        # is left of it when the prior starts (loading and the first evaluation have already
        # spent some), in wall-clock seconds, so generation and refinement keep the rest. A stop
        # (or pause) from the user is honoured between the prior's steps too.
        prior_s = 60.0 * config.prior_minutes
        if config.minutes is not None:
            prior_s = min(prior_s, max(60.0 * config.minutes - self.loop.wall_s(), 0.0) / 2.0)
        prior_end = self.loop.wall_s() + prior_s
        # The photos from the host copy (the prior's trainer keeps them there and moves each
        # batch), the prior on the run's device, where the virtual views are made.
        train, images = self.run.split.train, self.cpu_photos
        self.prior, self.prior_text = obtain_prior(
            self.run.run_dir, self.out_dir, self.run.gaussians, self.run.train_cameras,
            lambda k: images[train[k]].numpy(), config.prior, config.seed, prior_s / 60.0, config.prior_steps,
            self.log, should_stop=lambda: self.loop.wait_or_stop() or self.loop.wall_s() >= prior_end,
            device=rasterizer_device(self.rasterizer))
        self.prior.eval()
        self.prior_hash = prior_version(self.prior)
        self.summary["prior"] = {"description": self.prior_text, "version": self.prior_hash,
                                 "seconds": time.perf_counter() - began}
        self.log(self.prior_text)

    def watch_conscience(self) -> None:
        """The conscience watches the training photos nearest the targets (none for the
        baseline, which has no virtual views to restrain)."""
        cameras, train, config = list(self.run.scene.cameras), list(self.run.split.train), self.config
        k = config.k or DEFAULT_K
        self.conscience_views = sorted({i for r in self.rounds for t in r
                                        for i in nearest_training_views(t.camera, cameras, train, k)})
        if config.conscience_tolerance is not None and self.conscience_views:
            self.conscience = Conscience(config.conscience_tolerance)

    def evaluate(self, extra: dict) -> dict:
        """Held-out scores now, logged as a metrics line with ``extra``."""
        began = time.perf_counter()
        scores = evaluate_held_out(self.model(), self.run.scene, self.run.split, self.data, self.rasterizer)
        self.loop.exclude(time.perf_counter() - began)
        append_metrics(self.out_dir, {"iteration": self.state.iteration, **self.loop.clocks(),
                                      "num_gaussians": int(self.state.params["means"].shape[0]), **extra, **scores})
        return scores

    def model(self):
        """The current Gaussians, detached."""
        return gaussians_from_params(self.state.params).detach()

    # --- a round's virtual views -------------------------------------------------------------------
    def target_maker(self) -> TargetMaker:
        """I* from the Gaussians as they are now, made where the refinement renders: on a GPU the
        renders, warps and splatted depths of a round stay on it (bonsai at 800x533 on an H200:
        13 views in 1.5 s)."""
        setting = TargetSetting(self.config, list(self.run.scene.cameras), self.run.split.train, self.data.images,
                                self.cache, self.boot_dir / "views", self.rasterizer, self.prior, self.prior_hash)
        return TargetMaker(setting, self.model(), self.state.sky)

    def on_device(self, entry: VirtualTarget) -> VirtualTarget:
        """``entry`` with its I* and mask where the refinement renders (moved once, used many steps)."""
        device = self.state.params["means"].device
        moved = {} if entry.evidence is None else {"evidence": entry.evidence.to(device)}
        return dataclasses.replace(entry, target=entry.target.to(device), mask=entry.mask.to(device), **moved)

    def make_round_targets(self, round_index: int) -> None:
        """The round's virtual views and their I* (from the round's starting Gaussians) join the pool."""
        goal = self.rounds[round_index]
        round_info = {"round": round_index + 1, "targets": [t.name for t in goal], "views": []}
        self.summary["rounds"].append(round_info)
        if self.loop.wall_s() < self.photo_until_s:
            # Photo steps first (follow): the views are made when they are due, from the Gaussians then.
            round_info["deferred"] = "every step on the photos" if math.isinf(self.photo_until_s) else \
                f"until {self.photo_until_s:.0f} s"
            self.pending_round = round_index
            return
        self.add_round_views(round_index, round_info)

    def add_round_views(self, round_index: int, round_info: dict) -> None:
        """The round's virtual views and I* into the pool, their records into ``round_info``."""
        goal, config = self.rounds[round_index], self.config
        began = time.perf_counter()
        maker = None
        if config.placement == "evidence":
            maker = self.target_maker()
            new_views = self.evidence_views(round_index, goal, maker, round_info)
        else:
            new_views = round_virtual_views(goal, list(self.run.scene.cameras), self.run.split.train, config)
        if not new_views:
            return
        maker = maker or self.target_maker()
        for number, (target_index, view) in enumerate(new_views):
            if self.loop.wait_or_stop() or self.loop.out_of_time():
                break
            name = f"r{round_index + 1}_t{target_index}_{view.name}"
            entry, sources = self.make_target(maker, view.camera.with_pose(view.camera.world_to_camera, name=name),
                                              round_index + 1, save=number < config.save_views)
            self.pool.append(self.on_device(entry))
            round_info["views"].append({"name": name, "source": int(view.source), "t": float(view.t),
                                        "cache_hit": entry.cache_hit, "mask_fraction": float(entry.mask.mean()),
                                        "agreement_db": entry.agreement_db, "supervised": entry.supervised,
                                        "depth": entry.depth, "blend_sources": [int(s) for s in sources]})
            if entry.evidence is not None:
                round_info["views"][-1]["evidence_share"] = evidence_share(entry)
        round_info["generation_s"] = time.perf_counter() - began
        views = round_info["views"]
        self.log(f"round {round_index + 1}: {len(views)} virtual views "
                 f"({sum(v['cache_hit'] for v in views)} from the cache) in {round_info['generation_s']:.1f} s")
        left_out = [v for v in views if not v["supervised"]]
        if left_out and config.placement == "evidence":
            self.log(f"round {round_index + 1}: {len(left_out)} of {len(views)} virtual views left out: too few "
                     f"of their pixels lie where the blend is validated to beat the render")
        elif left_out:
            self.log(f"round {round_index + 1}: {len(left_out)} of {len(views)} virtual views left "
                     f"out: the render agrees with their warped photos better than the photos agree with "
                     f"each other (by more than {-config.agreement_min_db:g} dB)")

    def make_target(self, maker: TargetMaker, camera, round_number: int, save: bool) -> tuple[VirtualTarget, list]:
        """``maker.make``, with placement "evidence" the view's loss weights and gate from the estimate."""
        entry, sources = maker.make(camera, round_number, save)
        if self.config.placement == "evidence":
            entry = with_evidence(entry, self.evidence, maker.renders.depth(camera).cpu(),
                                  self.config.evidence_min_fraction)
        return entry, sources

    def evidence_views(self, round_index: int, goal: Sequence[Target], maker: TargetMaker, round_info: dict) -> list:
        """[(target index, VirtualView)] where the leave-one-out estimate, measured now at the
        training photos nearest the targets (validation.py), says the blend beats the render
        (placement.py); the estimate and every candidate's score go into the round's summary."""
        config, cameras, train = self.config, list(self.run.scene.cameras), self.run.split.train
        k = config.k or DEFAULT_K
        photos = nearest_training_views(goal[0].camera, cameras, sorted({
            i for target in goal for i in validation_photos(target.camera, cameras, train, k)}),
            config.evidence_photos) if goal else []
        # The estimate and its voxel grid stay on the CPU (placement "evidence" is experimental).
        depth_of = lambda camera: maker.renders.depth(camera).cpu()     # noqa: E731
        self.evidence = measure_evidence(photos, cameras, train, self.cpu_photos, config, depth_of,
                                         lambda camera: maker.renders.rgb(camera).cpu())
        record = {"validation_photos": [cameras[i].name for i in photos],
                  "estimate": None if self.evidence is None else self.evidence.summary(), "targets": []}
        views = []
        for index, target in enumerate(goal):
            candidates = candidate_views(target.camera, cameras, train, config.k, config.l, config.include_target)
            region = seen_cells(self.evidence, target.camera, depth_of(target.camera))
            # As many views as the default placement makes: the virtual steps are not spread thinner.
            limit = (config.k or DEFAULT_K) * (config.l or DEFAULT_L) + int(config.include_target)
            placement = place_by_evidence(candidates, self.evidence, depth_of, config.evidence_min_fraction,
                                          limit=limit, region=region)
            views.extend((index, view) for view in placement.views)
            record["targets"].append({"target": target.name, "placed": [view.name for view in placement.views],
                                      "reason": placement.reason,
                                      "candidates": [score.to_json() for score in placement.scores]})
            if placement.reason:
                self.log(f"round {round_index + 1}: {target.name}: {placement.reason}")
        round_info["evidence"] = record
        return views[:config.max_virtual_views]

    def regenerate_pool(self) -> None:
        """I* of every pool view again, from the Gaussians as they are now: the prior then repairs
        the refined render rather than the stage-I one (the bootstrap's feedback loop)."""
        began = time.perf_counter()
        maker = self.target_maker()
        for number, entry in enumerate(self.pool):
            if self.loop.wait_or_stop() or self.loop.out_of_time():
                break  # the views not reached keep their I*
            self.pool[number] = self.on_device(self.make_target(maker, entry.camera, entry.round, save=False)[0])
        self.regenerations.append({"iteration": self.state.iteration, "views": len(self.pool),
                                   "supervised": sum(entry.supervised for entry in self.pool),
                                   "seconds": time.perf_counter() - began})
        self.log(f"step {self.state.iteration}: regenerated {len(self.pool)} virtual views in "
                 f"{self.regenerations[-1]['seconds']:.1f} s")

    # --- refinement --------------------------------------------------------------------------------
    def refine(self, round_index: int, steps: int | None = None) -> bool:
        """The round's refinement steps (``steps``: those left of it, after a resume) and its
        evaluation -> False when stopped (by the user or the time budget) before its last step."""
        began = time.perf_counter()
        stopped = False
        steps = self.config.iterations if steps is None else steps
        self.current_round = round_index + 1
        round_end = self.state.iteration + steps
        with out_of_memory_stops(self.out_dir, lambda: (self.state.iteration + 1,
                                                        self.state.params["means"].shape[0]), "--resume"):
            for _ in range(steps):
                if self.loop.wait_or_stop() or self.loop.out_of_time():
                    stopped = True
                    break
                self.refine_step(self.state.iteration + 1, round_index, round_end)
        round_info = self.summary["rounds"][-1]
        round_info["refine_s"] = time.perf_counter() - began
        self.last_eval = round_info["eval"] = self.evaluate({"phase": "round", "round": round_index + 1})
        return not stopped

    def regeneration_due(self, step: int, round_end: int) -> bool:
        """A regeneration pays off over the steps after it: none for a round's last few. Nor when
        every view was left out (agreement.py): the photos' steps are worth more than re-judging
        views the render already agrees with better."""
        every = self.config.regenerate_every
        return bool(self.pool and every and (step - self.start) % every == 0
                    and round_end - step + 1 >= max(1, every // 2) and self.views_in_use())

    def views_in_use(self) -> bool:
        """Any pool view the gate kept (agreement.py; placement "evidence": validated)."""
        return any(entry.supervised for entry in self.pool)

    def refine_step(self, step: int, round_index: int, round_end: int) -> None:
        """One refinement step (a virtual view's every ``virtual_every``-th, else a photo's) and
        its bookkeeping: metrics, snapshot, checkpoint."""
        config = self.config
        self.loop.mark_first_step()
        if self.pending_round is not None and self.loop.wall_s() >= self.photo_until_s:
            pending, self.pending_round = self.pending_round, None
            self.add_round_views(pending, self.summary["rounds"][-1])
        if self.regeneration_due(step, round_end):
            self.regenerate_pool()
        # (A resumed run's conscience starts again: its first step takes the baseline.)
        # (No view in use yet, or every view left out: nothing for the conscience to restrain, so
        # its photo renders are skipped and the time goes to photo steps.)
        check_due = (step - self.start - 1) % config.conscience_every == 0
        if self.conscience is not None and self.views_in_use() and (check_due or not self.conscience.history):
            loss = photo_loss(self.rasterizer, self.model(), list(self.run.scene.cameras), self.data.images,
                              self.conscience_views, sh_degree_at(step, self.train_config, self.sh_max))
            self.conscience.update(step, loss)
        record = self.virtual_or_photo_step(step)
        self.state.iteration = step
        self.loop.advance()
        if step % config.log_every == 0:
            record.update(iteration=step, **self.loop.clocks(), round=round_index + 1)
            if self.conscience is not None and self.conscience.history:
                record.update(conscience_loss=self.conscience.history[-1][1], virtual_scale=self.conscience.scale)
            if config.eval_every and step % config.eval_every == 0:
                record.update(evaluate_held_out(self.model(), self.run.scene, self.run.split, self.data, self.rasterizer))
            append_metrics(self.out_dir, record)
        self.loop.snapshot(step, self.state.params, record)
        if (step - self.start) % config.checkpoint_every == 0:
            self.checkpoint(round_index + 1)

    def virtual_or_photo_step(self, step: int) -> dict:
        """A virtual view chosen by the sampler on a virtual slot when one is active, else a photo step."""
        config, pool = self.config, self.pool
        active = [pool[i] for i in active_views(pool, config.virtual_pixels)] if pool else []
        virtual_slot = step % config.virtual_every == 0
        if pool and virtual_slot and not active:
            self.step_counts["idle"] += 1
        elif self.pending_round is not None and virtual_slot:
            self.step_counts["photo_first"] += 1
        if not (active and virtual_slot):
            record = train_step(step, self.state, self.data, self.train_config, self.sh_max, self.rasterizer, self.log)
            record["kind"] = "real"
            self.step_counts["real"] += 1
            return record
        sh_degree = sh_degree_at(step, self.train_config, self.sh_max)
        frozen = self.model()
        choice = self.sampler.choose(active,
                                     lambda i, w2c: render_l1(self.rasterizer, frozen, active[i], sh_degree, w2c))
        scale = self.conscience.scale if self.conscience is not None else 1.0
        view = active[choice.index]
        if config.virtual_mode == "additive":
            from .experimental.additive import additive_step

            record = additive_step(step, self.state, self.data, self.train_config, self.sh_max, view, choice, config,
                                   self.rasterizer,
                                   lambda: train_step(step, self.state, self.data, self.train_config, self.sh_max,
                                                      self.rasterizer, self.log),
                                   self.lpips, scale=scale)
            self.step_counts["additive"] += 1
        else:
            record = virtual_step(step, self.state, self.data, self.train_config, self.sh_max, view, choice, config,
                                  self.rasterizer, self.lpips, scale=scale)
        self.step_counts[record["virtual_branch"]] += 1
        self.view_use[view.name] = self.view_use.get(view.name, 0) + 1
        return record

    def checkpoint(self, round_number: int) -> None:
        state = self.state
        state.wall_s, state.train_s = self.loop.wall_s(), self.loop.train_s()
        body = state.payload(self.train_config)
        body["bootstrap"] = {"round": round_number, "config": self.config.to_json_dict(),
                             "pose": None if self.sampler.pose is None else self.sampler.pose.tolist()}
        save_checkpoint(self.out_dir, state.iteration, body, self.train_config.output.keep_checkpoints)

    # --- finish ------------------------------------------------------------------------------------
    def finish(self) -> BootstrapResult:
        """The final save, in the order that keeps the result: model.ply (a stopped run's too:
        stop means save), then the final config.json and summary.json, then the checkpoint
        `--resume` continues from. Each is attempted even when an earlier one fails (a full
        disk) and each is atomic; the first failure is raised once all were tried."""
        saves = SaveAttempts()
        attempt = saves.attempt
        gaussians = self.model()
        attempt(lambda: save_model(self.out_dir, gaussians, self.state.iteration, self.train_config, self.sh_max,
                                   self.run.scene.normalization))
        attempt(self.write_summary)
        if self.current_round:
            attempt(lambda: self.checkpoint(self.current_round))
        saves.raise_first(self.log)
        return BootstrapResult(self.out_dir, self.start, self.state.iteration, self.finished, self.rounds_done,
                               len(gaussians), len(self.pool), self.cache.hits, self.cache.misses,
                               self.loop.wall_s(), self.prior_text, self.initial_eval, self.last_eval,
                               supervised_views=sum(entry.supervised for entry in self.pool),
                               virtual_steps=virtual_step_count(self.step_counts))

    def write_summary(self) -> None:
        """RUN2/config.json with the steps made, and RUN2/bootstrap/summary.json."""
        state, loop = self.state, self.loop
        final_config = dataclasses.replace(self.train_config, iterations=max(state.iteration, self.start + 1))
        final_config.save(self.out_dir / "config.json")
        conscience = self.conscience
        self.summary.update(
            iteration=state.iteration, finished=self.finished, stopped=loop.stopped_by_user(),
            rounds_done=self.rounds_done, wall_s=loop.wall_s(),
            cache_hits=self.cache.hits, cache_misses=self.cache.misses, virtual_views=len(self.pool),
            last_eval=self.last_eval, steps=self.step_counts, view_use=self.view_use,
            regenerations=self.regenerations,
            conscience=None if conscience is None else {
                "views": [self.run.scene.cameras[i].name for i in self.conscience_views],
                "tolerance": conscience.tolerance, "baseline": conscience.baseline,
                "checks": [list(c) for c in conscience.history]})
        atomic_write_text(self.out_dir / SUMMARY_FILE, json.dumps(json_safe(self.summary), indent=1) + "\n")
