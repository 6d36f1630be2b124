"""One stage-I training step and what it needs, as public pieces: the data prepared once
(:class:`TrainData`), the optimiser state (:class:`TrainState`, new, restored from a checkpoint
or built from a model), :func:`train_step` (render one view, the photometric and PGSR terms, Adam,
densification) and :func:`optimizer_step`. The stage-I loop (:mod:`.trainer`) and the stage-II
refinement (:mod:`inceptiongs.bootstrap`) both drive these.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass
from collections.abc import Iterable, Iterator
from typing import Callable

import numpy as np
import torch

from ..camera import Camera
from ..gaussians import Gaussians
from ..scene.photo_store import PREFETCH_DEPTH, DerivedPhotos, PhotoStore, check_photo_files
from . import losses
from .block_start import block_start
from ..runs.config import TrainConfig
from .densify import DensifyStats, accumulate
from .free_space import (ViewStats, accumulate_views, allowed_sh_degree, before_near_bound, contains_camera,
                         near_a_camera, near_bounds, seen_through, sh_rest_mask, surface_depth,
                         surface_depth_features)
from .init_gaussians import gaussians_from_points, gaussians_from_sparse_depth, initial_gaussians, scene_extent
from .neighbours import neighbour_views
from .sky import SKY_OPACITY, hold_shell_scales, in_background, shell_log_scale_floor, sky_shell
from .strategies import strategy_for
from ..gaussians import gaussians_from_params
from .optim import make_optimizer, params_from_gaussians, position_learning_rate, set_learning_rate
from .triangulate import training_points


def supported_sh_degree(num_train_views: int, cap: int) -> int:
    """View-dependent colour needs views to be fitted from: a degree-d band has (2d+1)
    coefficients per channel, so few views support only low degrees."""
    by_views = 0 if num_train_views < 4 else 1 if num_train_views < 8 else 2 if num_train_views < 16 else 3
    return min(cap, by_views)


def sh_degree_at(step: int, config: TrainConfig, max_degree: int) -> int:
    return min(max_degree, (step - 1) // config.sh.increase_every)


@dataclass
class TrainData:
    """Training data prepared once. Images: index -> tensor at the training resolution."""

    cameras: list[Camera]
    train: list[int]
    images: dict[int, torch.Tensor]           # [H, W, 3]
    grey: dict[int, torch.Tensor]             # [H, W, 1] (train views, PGSR only)
    edge_weights: dict[int, torch.Tensor]     # [H, W]    (train views, PGSR only)
    intrinsics: dict[int, torch.Tensor]       # [3, 3]
    neighbours: dict[int, list[int]]
    extent: float


def prepare_data(scene, split, config: TrainConfig, log: Callable[[str], None]) -> TrainData:
    cameras = list(scene.cameras)
    used = sorted(set(split.train) | set(split.test))
    check_photo_files(scene, used)   # a missing photo: one line now, not at its first step
    # Photos are read through a store (decoded once into the cache folder, at most the photo
    # budget held, the sampler's next views prefetched): memory does not grow with their number.
    images = PhotoStore(scene, used)
    grey, edges = {}, {}
    if config.pgsr:
        grey = DerivedPhotos(images, split.train, lambda image: image.mean(-1, keepdim=True))
        edges = DerivedPhotos(images, split.train, losses.edge_aware_weight)
    intrinsics = {i: torch.tensor(cameras[i].intrinsics, dtype=torch.float32) for i in used}
    neighbours = {}
    if config.pgsr:
        neighbours = neighbour_views(cameras, list(split.train), config.pgsr_terms.neighbours_max,
                                     config.pgsr_terms.neighbours_max_angle_deg)
        with_nb = sum(1 for v in neighbours.values() if v)
        log(f"multi-view terms: {with_nb}/{len(split.train)} training views have neighbours "
            f"within {config.pgsr_terms.neighbours_max_angle_deg:g} degrees")
    return TrainData(cameras, list(split.train), images, grey, edges, intrinsics, neighbours,
                 scene_extent([cameras[i] for i in split.train]))


@dataclass
class TrainState:
    params: dict[str, torch.Tensor]
    optimizer: torch.optim.Adam
    stats: DensifyStats
    iteration: int
    wall_s: float
    train_s: float
    view_rng: np.random.Generator
    generator: torch.Generator
    order: list[int]
    order_pos: int
    logged: set[str]
    # Per-Gaussian view statistics (free space, SH limits) and the training cameras' near
    # bounds [len(train)]; None in a state built without them (a stage-II state from a model).
    view_stats: ViewStats | None = None
    near: torch.Tensor | None = None
    # The sky shell's sphere [4] (centre, radius); None without one.
    sky: torch.Tensor | None = None
    # view -> MSE of its latest training render (inceptiongs.train.view_fit: photos the model
    # cannot fit are reported at the end of the run).
    view_mse: dict[int, float] = dataclasses.field(default_factory=dict)
    # The sky shell's log-scale floor (sky.shell_log_scale_floor): fixed for a run, so computed
    # once rather than read back from the device every step; not checkpointed (derived).
    shell_floor: float | None = None

    def payload(self, config: TrainConfig) -> dict:
        extra = {}
        if self.view_stats is not None:
            extra["view_stats"] = {k: v.clone() for k, v in self.view_stats.tensors().items()}
        if self.near is not None:
            extra["near"] = self.near.clone()
        if self.sky is not None:
            extra["sky"] = self.sky.clone()
        # On the CPU whatever the device trained on: a checkpoint resumes on either.
        return on_cpu({**extra,
            "iteration": self.iteration, "wall_s": self.wall_s, "train_s": self.train_s,
            "params": {k: v.detach().clone() for k, v in self.params.items()},
            "optimizer": self.optimizer.state_dict(),
            "stats": {k: v.clone() for k, v in self.stats.tensors().items()},
            "view_rng": self.view_rng.bit_generator.state,
            "generator": self.generator.get_state(),
            "order": list(self.order), "order_pos": self.order_pos,
            "logged": sorted(self.logged), "config": config.to_json_dict(),
            "view_mse": dict(self.view_mse),
        })


def on_cpu(value):
    """``value`` (nested dicts, lists and tuples) with every tensor copied to the CPU."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, dict):
        return {k: on_cpu(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(on_cpu(v) for v in value)
    return value


def data_on(data: TrainData, device: torch.device | str) -> TrainData:
    """``data`` with its photos and per-view tensors on ``device``: the small per-view tensors
    uploaded once, the photos one per read."""
    def move(tensors):   # a photo store uploads one photo per read
        return tensors.on(device) if hasattr(tensors, "on") else {k: v.to(device) for k, v in tensors.items()}
    return dataclasses.replace(data, images=move(data.images), grey=move(data.grey),
                               edge_weights=move(data.edge_weights), intrinsics=move(data.intrinsics))


def state_on(state: TrainState, device: torch.device | str, config: TrainConfig, extent: float) -> TrainState:
    """``state`` with its parameters, Adam moments and statistics on ``device`` (a new optimiser
    holding the same moments and learning rates). The random generator stays on the CPU, so a
    run draws the same numbers on any device and resumes across devices."""
    device = torch.device(device)
    if state.params["means"].device == device:
        return state
    params = {k: v.detach().to(device).requires_grad_(True) for k, v in state.params.items()}
    optimizer = make_optimizer(params, config, extent)
    optimizer.load_state_dict(state.optimizer.state_dict())   # moments follow their parameters' device
    move = lambda t: None if t is None else t.to(device)      # noqa: E731
    view_stats = None if state.view_stats is None else state.view_stats.to(device)
    return dataclasses.replace(state, params=params, optimizer=optimizer, stats=state.stats.to(device),
                               view_stats=view_stats, near=move(state.near), sky=move(state.sky))


def new_state(scene, data: TrainData, config: TrainConfig, sh_degree: int, log) -> TrainState:
    cameras = [data.cameras[i] for i in data.train]
    points, colors, triangulated = training_points(scene, data.train, data.images, config.triangulate_init, log)
    sky = None
    free_space = config.free_space
    if config.block.start:   # a block of a run in blocks: the global stage's Gaussians and its sky shell
        gaussians, sky, message = block_start(config.block, cameras, sh_degree, log)
        log(message)
    else:
        if triangulated:
            gaussians, message = gaussians_from_sparse_depth(cameras, train_photos(data),
                                                             points, sh_degree, config.seed)
        else:
            gaussians, message = initial_gaussians(cameras, points, colors, sh_degree, config.seed)
        log(message)
        if free_space.sky_shell:
            gaussians, sky = with_sky_shell(gaussians, cameras, train_photos(data), points, log)
    params = params_from_gaussians(gaussians)
    optimizer = make_optimizer(params, config, data.extent)
    generator = torch.Generator().manual_seed(config.seed)
    near = torch.tensor(near_bounds(cameras, points, free_space.near_percentile, free_space.near_margin))
    if free_space.enabled:
        log(f"free space: near bounds = {free_space.near_margin:g} x percentile {free_space.near_percentile:g} of the "
            f"sparse points' depths per camera: median {float(near.median()):.3g}, range {float(near.min()):.3g}.."
            f"{float(near.max()):.3g} (scene units)")
    return TrainState(params, optimizer, DensifyStats.zeros(len(gaussians)), 0, 0.0, 0.0,
                      np.random.default_rng(config.seed), generator, [], 0, set(),
                      ViewStats.zeros(len(gaussians)), near, sky)


def train_photos(data: TrainData) -> Iterator[np.ndarray]:
    """The training views' photos [H, W, 3] one at a time, in data.train's order: a pass over
    them never holds more than the photo store does."""
    return (data.images[i].numpy() for i in data.train)


def with_sky_shell(gaussians: Gaussians, cameras: list[Camera], images: Iterable[np.ndarray], points: np.ndarray,
                   log) -> tuple[Gaussians, torch.Tensor]:
    """``gaussians`` and the sky shell's after them, and the shell's sphere [4]."""
    means, colours, scales, sphere = sky_shell(cameras, images, points)
    shell = gaussians_from_points(means, colours, gaussians.sh_degree, dtype=gaussians.dtype, scales=scales)
    shell.opacity_logits.fill_(math.log(SKY_OPACITY / (1.0 - SKY_OPACITY)))   # 0 < SKY_OPACITY < 1
    log(f"sky shell: {len(shell)} Gaussians at radius {sphere[3]:.3g} where the training photos show no "
        f"sparse point")
    merged = Gaussians(**{name: torch.cat([getattr(gaussians, name), getattr(shell, name)])
                          for name in gaussians.tensors()})
    return merged, torch.as_tensor(sphere, dtype=torch.float64)


def restore_state(payload: dict, data: TrainData, config: TrainConfig) -> TrainState:
    params = {k: v.clone().requires_grad_(True) for k, v in payload["params"].items()}
    optimizer = make_optimizer(params, config, data.extent)
    optimizer.load_state_dict(payload["optimizer"])
    view_rng = np.random.default_rng()
    view_rng.bit_generator.state = payload["view_rng"]
    generator = torch.Generator()
    generator.set_state(payload["generator"])
    stats = DensifyStats(**payload["stats"])
    # Checkpoints written before the view statistics existed restore without them (rules off).
    view_stats = ViewStats(**payload["view_stats"]) if "view_stats" in payload else None
    near = payload.get("near")
    sky = payload.get("sky")
    return TrainState(params, optimizer, stats, int(payload["iteration"]), float(payload["wall_s"]),
                      float(payload["train_s"]), view_rng, generator, list(payload["order"]),
                      int(payload["order_pos"]), set(payload["logged"]), view_stats, near, sky,
                      dict(payload.get("view_mse", {})))


def upcoming_views(state: TrainState, data: TrainData, count: int) -> list[int]:
    """The ``count`` views next_view returns next: the rest of this epoch's order, then the
    next epoch's, drawn from a copy of the sampler's generator (the run's own is untouched)."""
    views = list(state.order[state.order_pos:state.order_pos + count])
    if len(views) < count and data.train:
        rng = copy.deepcopy(state.view_rng)
        while len(views) < count:
            views += [data.train[i] for i in rng.permutation(len(data.train))][:count - len(views)]
    return views


def next_view(state: TrainState, data: TrainData) -> int:
    """Views in random order, every view once per epoch."""
    if state.order_pos >= len(state.order):
        state.order = [data.train[i] for i in state.view_rng.permutation(len(data.train))]
        state.order_pos = 0
    view = state.order[state.order_pos]
    state.order_pos += 1
    if hasattr(data.images, "prefetch"):
        data.images.prefetch(upcoming_views(state, data, PREFETCH_DEPTH))
    return view


def log_once(state: TrainState, key: str, message: str, log) -> None:
    if key not in state.logged:
        state.logged.add(key)
        log(message)


def multiview_terms(rasterizer, gaussians: Gaussians, out: dict, view: int, data: TrainData,
                     config: TrainConfig, state: TrainState, sh_degree: int, log) -> dict[str, torch.Tensor]:
    """Geometric and NCC terms against one random neighbour of ``view`` (may be empty)."""
    neighbours = data.neighbours.get(view, [])
    if not neighbours:
        log_once(state, "no-neighbours", "multi-view terms skipped for views without neighbours "
                  f"(first: {data.cameras[view].name})", log)
        return {}
    nb = neighbours[int(state.view_rng.integers(len(neighbours)))]
    ref_cam, nb_cam = data.cameras[view], data.cameras[nb]
    planar = config.pgsr_terms
    small = nb_cam.scaled(1.0 / planar.multiview_scale)
    with torch.no_grad():
        # The neighbour's depth is a fixed target: its gradient would double the backward cost.
        nb_depth = rasterizer(gaussians.detach(), small, outputs=("plane_depth",), sh_degree=sh_degree)["plane_depth"]
    device = nb_depth.device
    ref_to_nb = torch.tensor(nb_cam.world_to_camera @ ref_cam.camera_to_world, dtype=torch.float32, device=device)
    k_ref = data.intrinsics[view]
    k_small = torch.tensor(small.intrinsics, dtype=torch.float32, device=device)
    error, valid = losses.reprojection_error(out["plane_depth"], k_ref, nb_depth, k_small, ref_to_nb)
    terms = {}
    geo = losses.geometric_consistency_loss(error, valid, planar.multiview_pixel_noise_max)
    if geo is None:
        log_once(state, "geo-empty", "geometric consistency skipped on a step: no pixel reprojects "
                  "consistently yet (logged once)", log)
        return terms
    terms["geo"] = geo
    mask = (valid & (error < planar.multiview_pixel_noise_max)).reshape(-1)
    candidates = torch.nonzero(mask)[:, 0]
    pick = candidates[torch.randint(len(candidates), (min(planar.ncc_samples, len(candidates)),),
                                    generator=state.generator).to(device)]
    width = ref_cam.width
    pixels = torch.stack([(pick % width).float() + 0.5, (pick // width).float() + 0.5], -1)
    depth = out["plane_depth"].reshape(-1)[pick]
    normals = losses.safe_normalize(out["normal"].reshape(-1, 3)[pick])
    weights = torch.exp(-error.detach().reshape(-1)[pick])
    ncc = losses.ncc_loss(data.grey[view], data.grey[nb], pixels, depth, normals, k_ref,
                          data.intrinsics[nb], ref_to_nb, planar.ncc_patch_radius, weights)
    if ncc is not None:
        terms["ncc"] = ncc
    return terms


def evaluate_held_out(gaussians: Gaussians, scene, split, data: TrainData, rasterizer=None,
                      per_group: int | None = None) -> dict[str, float]:
    """PSNR / SSIM over the held-out views (rendered with ``rasterizer``, default the CPU's),
    flat keys ("all_psnr", "scarce_ssim", ...); {} when the split holds nothing out.
    ``per_group``: score at most that many views of each group (Split.scored_during_training;
    None: every one)."""
    if not split.test:
        return {}
    from ..evaluation.scoring import evaluate_views, flat_scores
    if per_group is not None:
        split = split.scored_during_training(per_group)
    return flat_scores(evaluate_views(gaussians, scene, split, photos=data.images, rasterizer=rasterizer)["groups"])


def trim_sh(gaussians: Gaussians, degree: int) -> Gaussians:
    """Drop SH bands the schedule never switched on (they are all zero and unused)."""
    keep = (degree + 1) ** 2
    if gaussians.sh.shape[1] == keep:
        return gaussians
    return dataclasses.replace(gaussians, sh=gaussians.sh[:, :keep].contiguous())


def train_step(step: int, state: TrainState, data: TrainData, config: TrainConfig, sh_max: int, rasterizer,
               log) -> dict:
    """One optimisation step on one view; returns the log record of its terms."""
    set_learning_rate(state.optimizer, "means", position_learning_rate(step, config, data.extent))
    sh_degree = sh_degree_at(step, config, sh_max)
    view = next_view(state, data)
    camera = data.cameras[view]
    planar = config.pgsr_terms
    want_normal = config.pgsr and step >= planar.normal_from
    want_multiview = (config.pgsr and step >= planar.multiview_from and step % planar.multiview_every == 0)
    outputs = ("rgb",) + (("alpha", "normal", "plane_depth") if (want_normal or want_multiview) else ())
    gaussians = gaussians_from_params(state.params)
    features = None
    if wants_view_stats(step, state, config):
        if state.sky is None:
            outputs += ("depth",)
        else:   # the surface without the shell behind it (free_space.surface_depth_features)
            outputs += ("features",)
            features = surface_depth_features(gaussians.means, in_background(gaussians.means.detach(), state.sky),
                                              camera)
    strategy = strategy_for(config)
    rendered = strategy.prepare_render(step, gaussians, state, config.iterations)
    # Black (the renderer's default), or with random_background a colour the model cannot predict
    # behind any pixel it leaves partly transparent, so no edge or sky can be fitted by letting
    # the black show through (a transparent shell Gaussian behind a silhouette is otherwise a free
    # way to darken edge pixels).
    background = torch.rand(3, generator=state.generator) if config.losses.random_background else None
    extra = {} if features is None else {"features": features}
    out = rasterizer(rendered, camera, outputs=outputs, background=background, sh_degree=sh_degree, **extra)
    if features is not None:
        # What the view statistics read as "depth" (optimizer_step): the scene's, without the shell.
        out["depth"] = surface_depth(out["features"])

    loss, l1 = losses.photometric_loss(out["rgb"], data.images[view], config.losses.lambda_dssim)
    with torch.no_grad():
        mse = (out["rgb"] - data.images[view]).square().mean()
    terms: dict[str, torch.Tensor] = {"l1": l1, "photometric": loss}
    loss = strategy.add_loss_terms(loss, terms, state)
    if config.pgsr:
        terms["flatten"] = losses.flatten_loss(state.params["log_scales"])
        loss = loss + planar.lambda_flatten * terms["flatten"]
    if want_normal:
        normal = losses.normal_consistency_loss(out["normal"], out["plane_depth"], out["alpha"],
                                                data.intrinsics[view], data.edge_weights[view])
        if normal is None:
            log_once(state, "normal-empty", "normal consistency skipped on a step: the render covers "
                      "no pixel (logged once)", log)
        else:
            terms["normal"] = normal
            loss = loss + planar.lambda_normal * normal
    if want_multiview:
        mv = multiview_terms(rasterizer, gaussians, out, view, data, config, state, sh_degree, log)
        if "geo" in mv:
            terms["geo"] = mv["geo"]
            loss = loss + planar.lambda_geo * mv["geo"]
        if "ncc" in mv:
            terms["ncc"] = mv["ncc"]
            loss = loss + planar.lambda_ncc * mv["ncc"]
    terms["loss"] = loss

    # Every logged number in one read from the device (each read makes the host wait for the GPU).
    values = torch.stack([value.detach().double() for value in [*terms.values(), mse]]).tolist()
    record = dict(zip(terms, values[:-1]))
    if math.isfinite(values[-1]):  # a non-finite render says nothing about the photo
        state.view_mse[view] = values[-1]
    record["sh_degree"] = sh_degree
    record.update(optimizer_step(step, loss, out, camera, state, data, config))
    return record


def wants_view_stats(step: int, state: TrainState, config: TrainConfig) -> bool:
    """Whether this step's training render feeds the view statistics (it then renders depth too):
    within stage I's schedule, when a rule needs them."""
    return (state.view_stats is not None and step <= config.iterations
            and (config.free_space.enabled or config.sh.spread_deg_per_degree > 0))


# The counts maintain() reports: they happen on steps that are rarely logging steps, so the
# trainer sums them until the next logged line (else most of them never reach metrics.jsonl).
MAINTENANCE_COUNTS = ("free_space", "cloned", "split", "pruned", "relocated", "added")


def add_maintenance_counts(pending: dict[str, int], record: dict) -> dict[str, int]:
    """``pending`` plus the maintenance counts in one step's ``record`` (a new dict)."""
    total = dict(pending)
    for key in MAINTENANCE_COUNTS:
        if key in record:
            total[key] = total.get(key, 0) + int(record[key])
    return total


def maintenance_due(step: int, config: TrainConfig) -> bool:
    """Densification (or relocation) and pruning run every ``densify_every`` steps from
    ``densify_from``: growing until ``densify_until``, pruning until the end of the run (so a
    short run ends pruned). Stage-II continuations (steps past ``iterations``) only densify
    within their own window."""
    window = config.densification
    if step < window.densify_from or step % window.densify_every != 0:
        return False
    return step < window.densify_until or step <= config.iterations


def optimizer_step(step: int, loss: torch.Tensor, out: dict, camera: Camera, state: TrainState, data: TrainData,
                   config: TrainConfig) -> dict:
    """Backward ``loss`` of the render ``out`` of ``camera``, one Adam step, then the strategy's
    densification / relocation, the free-space and size rules, and the opacity reset on schedule.
    Shared with the stage-II refinement (inceptiongs.bootstrap), whose virtual-view steps feed the
    same statistics. Returns densification counts and ``num_gaussians``."""
    loss.backward()
    tracking = step < config.densification.densify_until or step <= config.iterations
    if tracking and out["means2d"].grad is not None:
        accumulate(state.stats, out["means2d"].grad, out["radii"], camera.width, camera.height)
    if state.view_stats is not None and "depth" in out:
        accumulate_views(state.view_stats, state.params["means"], camera, out["depth"], out["radii"],
                         config.free_space.see_through_tolerance)
    limit_sh = (state.view_stats is not None and config.sh.spread_deg_per_degree > 0
                and "sh_rest" in state.params)
    if limit_sh and state.params["sh_rest"].grad is not None:
        # Bands above a Gaussian's allowed degree get no gradient (they are held at 0).
        state.params["sh_rest"].grad.mul_(sh_rest_mask(state.view_stats.sh_degree,
                                                       state.params["sh_rest"].shape[1]))
    state.optimizer.step()
    state.optimizer.zero_grad(set_to_none=True)
    if state.sky is not None and config.free_space.sky_min_scale > 0:
        if state.shell_floor is None:
            state.shell_floor = shell_log_scale_floor(state.sky, [data.cameras[i] for i in data.train],
                                                      config.free_space.sky_min_scale)
        hold_shell_scales(state.params["log_scales"], in_background(state.params["means"].detach(), state.sky),
                          state.shell_floor)
    strategy = strategy_for(config)
    strategy.after_optimizer_step(step, state, config.iterations, position_learning_rate(step, config, data.extent))

    record: dict = {}
    if maintenance_due(step, config):
        record.update(maintain(step, state, data, config))
        state.stats = DensifyStats.zeros(state.params["means"].shape[0], state.params["means"].device)
        if state.view_stats is not None:
            state.view_stats.reset_window()
            if limit_sh:
                update_sh_limits(state, config)
    strategy.after_maintenance(step, state)
    record["num_gaussians"] = int(state.params["means"].shape[0])
    return record


def free_space_flags(state: TrainState, data: TrainData, config: TrainConfig, centers: torch.Tensor) -> torch.Tensor:
    """[N] bool: Gaussians in space the training cameras (centres [C, 3]) see through
    (inceptiongs.train.free_space)."""
    params = state.params
    flags = torch.zeros(params["means"].shape[0], dtype=torch.bool, device=params["means"].device)
    rules = config.free_space
    if not rules.enabled:
        return flags
    cameras = [data.cameras[i] for i in data.train]
    flags |= contains_camera(params["means"], params["log_scales"], params["quats"], centers, rules.camera_sigmas)
    if state.near is not None:
        flags |= before_near_bound(params["means"], cameras, state.near)
        if rules.camera_ball > 0:
            flags |= near_a_camera(params["means"], centers, rules.camera_ball * state.near)
    if state.view_stats is not None:
        flags |= seen_through(state.view_stats, rules.see_through_min_views)
    return flags


def maintain(step: int, state: TrainState, data: TrainData, config: TrainConfig) -> dict:
    """The periodic edit of the model: the free-space rules flag Gaussians (within stage I's
    schedule), the strategy removes or relocates them and densifies; returns the counts."""
    in_schedule = step <= config.iterations    # stage-II continuations: no new pruning rules
    carried = state.view_stats.tensors() if state.view_stats is not None else {}
    centers = torch.tensor(np.stack([data.cameras[i].center for i in data.train]),
                           device=state.params["means"].device)                                 # [C, 3]
    flags = free_space_flags(state, data, config, centers) if in_schedule else torch.zeros(
        state.params["means"].shape[0], dtype=torch.bool, device=state.params["means"].device)
    counts: dict = {"free_space": int(flags.sum())}
    counts.update(strategy_for(config).maintenance(step, state, data.extent, config.iterations, flags, carried,
                                                   centers))
    if state.view_stats is not None:
        state.view_stats = ViewStats(**carried)
    return counts


def update_sh_limits(state: TrainState, config: TrainConfig) -> None:
    """Re-derive every Gaussian's allowed SH degree from its viewing directions and hold the
    bands above it at 0 (values and Adam moments)."""
    stats = state.view_stats
    stats.sh_degree = allowed_sh_degree(stats, config.sh.spread_deg_per_degree, config.sh.min_views)
    sh_rest = state.params["sh_rest"]
    mask = sh_rest_mask(stats.sh_degree, sh_rest.shape[1]).to(sh_rest.dtype)
    with torch.no_grad():
        sh_rest.mul_(mask)
        moments = state.optimizer.state.get(sh_rest)
        if moments:
            moments["exp_avg"].mul_(mask)
            moments["exp_avg_sq"].mul_(mask)


def state_from_gaussians(gaussians: Gaussians, data: TrainData, config: TrainConfig) -> TrainState:
    """A state for a run that has a model but no checkpoint (fresh Adam moments), at the end of
    ``config``'s schedule."""
    params = params_from_gaussians(gaussians)
    optimizer = make_optimizer(params, config, data.extent)
    return TrainState(params, optimizer, DensifyStats.zeros(len(gaussians)), config.iterations, 0.0, 0.0,
                      np.random.default_rng(config.seed), torch.Generator().manual_seed(config.seed), [], 0, set())
