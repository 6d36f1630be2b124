"""A round's virtual views into the pool, and the pool's I* made again.

Where the views go: for each target, k * l poses on the paths to its k nearest training views
(virtual_views.py), plus the target itself; a chosen variant may place them instead
(``place_views``). Each view's I* is made from the Gaussians as they are when the round's views
are made (view_targets.py) and, every ``regenerate_every`` steps, from the refined ones.
"""

from __future__ import annotations

import math
import time
from typing import Sequence

from .config import BootstrapConfig
from .generation import VirtualTarget
from .plan import RoundPlan
from .pool import ViewPool, evidence_share, on_device, supervised_count
from .probe import photo_until
from .state import LoopState, Setting, model
from .targets import Target
from .variants import PlacedViews, PlacementRequest
from .view_targets import TargetMaker, TargetSetting
from .virtual_views import VirtualView, pool_view_name, virtual_views


def round_virtual_views(goal: Sequence[Target], cameras, train: Sequence[int], config: BootstrapConfig
                        ) -> list[tuple[int, VirtualView]]:
    """[(target index, VirtualView)] for the round's targets, at most config.max_virtual_views."""
    kwargs = {name: getattr(config, name) for name in ("k", "l") if getattr(config, name) is not None}
    views = []
    for index, target in enumerate(goal):
        if config.include_target:
            views.append((index, VirtualView(target.camera.with_pose(target.camera.world_to_camera, name="target"),
                                             -1, 0.0, "target")))
        views.extend((index, view) for view in virtual_views(target.camera, cameras, list(train), **kwargs))
    return views[:config.max_virtual_views]


def target_maker(setting: Setting, state: LoopState, depths: dict | None = None) -> TargetMaker:
    """I* from the Gaussians as they are now, made where the refinement renders: on a GPU the
    renders, warps and splatted depths of a round stay on it (bonsai at 800x533 on an H200:
    13 views in 1.5 s). ``depths``: surface depths kept from earlier makers (ViewPool.depths)."""
    run = setting.run
    made_with = TargetSetting(list(run.scene.cameras), run.split.train, setting.data.images, setting.cache,
                              setting.boot_dir / "views", setting.rasterizer, setting.prior, setting.prior_hash)
    return TargetMaker(made_with, model(state.train), state.train.sky, depths)


def make_view(maker: TargetMaker, camera, round_number: int, save: bool, config: BootstrapConfig,
              pool: ViewPool) -> tuple[VirtualTarget, list[int]]:
    """``maker.make``, then the newest placement's mark (a variant's loss weights and gate)."""
    entry, sources = maker.make(camera, round_number, save, config)
    if pool.mark is not None:
        entry = pool.mark(entry, maker)
    return entry, sources


def open_round(setting: Setting, config: BootstrapConfig, plan: RoundPlan, state: LoopState, pool: ViewPool,
               round_index: int) -> None:
    """The round's record in the summary, and its views and I* (from the round's starting
    Gaussians) into the pool; before the photo-first time they wait (``pool.pending_round``)
    and are made when it has passed, from the Gaussians then."""
    goal = plan.rounds[round_index]
    round_info = {"round": round_index + 1, "targets": [t.name for t in goal], "views": []}
    state.summary["rounds"].append(round_info)
    until = photo_until(plan, state)
    if state.clock.wall_s() < until:
        round_info["deferred"] = ("until the probe has measured the outlook" if state.probe is not None else
                                  "every step on the photos" if math.isinf(until) else f"until {until:.0f} s")
        pool.pending_round = round_index
        return
    add_round_views(setting, config, plan, state, pool, round_index, round_info)


def place_round(setting: Setting, config: BootstrapConfig, goal: Sequence[Target], maker: TargetMaker,
                round_index: int) -> tuple[str, PlacedViews] | None:
    """(the variant's name, its placement of the round) for the first chosen variant that places
    views (None: the default placement)."""
    run = setting.run
    request = PlacementRequest(round_index, goal, maker, list(run.scene.cameras), run.split.train,
                               setting.cpu_photos, config, setting.log)
    for name, variant in config.variants.items():
        placed = variant.place_views(request)
        if placed is not None:
            return name, placed
    return None


def add_round_views(setting: Setting, config: BootstrapConfig, plan: RoundPlan, state: LoopState, pool: ViewPool,
                    round_index: int, round_info: dict) -> None:
    """The round's virtual views and I* into the pool, their records into ``round_info``."""
    goal, run = plan.rounds[round_index], setting.run
    began = time.perf_counter()
    maker = target_maker(setting, state)
    placement = place_round(setting, config, goal, maker, round_index)
    placed = None if placement is None else placement[1]
    if placement is not None:
        new_views, pool.mark = placed.views, placed.mark
        round_info[placement[0]] = placed.record       # "evidence": the estimate, every candidate's score
    else:
        new_views = round_virtual_views(goal, list(run.scene.cameras), run.split.train, config)
    if not new_views:
        return
    device = state.train.params["means"].device
    for number, (target_index, view) in enumerate(new_views):
        if state.clock.wait_or_stop() or state.clock.out_of_time():
            break
        name = pool_view_name(round_index + 1, target_index, view.name)
        entry, sources = make_view(maker, view.camera.with_pose(view.camera.world_to_camera, name=name),
                                   round_index + 1, number < config.save_views, config, pool)
        pool.entries.append(on_device(entry, device))
        round_info["views"].append({"name": name, "source": int(view.source), "t": float(view.t),
                                    "cache_hit": entry.cache_hit, "mask_fraction": float(entry.mask.mean()),
                                    "agreement_db": entry.agreement_db, "supervised": entry.supervised,
                                    "depth": entry.depth, "blend_sources": [int(s) for s in sources]})
        if entry.evidence is not None:
            round_info["views"][-1]["evidence_share"] = evidence_share(entry)
    round_info["generation_s"] = time.perf_counter() - began
    views = round_info["views"]
    setting.log(f"round {round_index + 1}: {len(views)} virtual views "
                f"({sum(v['cache_hit'] for v in views)} from the cache) in {round_info['generation_s']:.1f} s")
    left_out = [v for v in views if not v["supervised"]]
    if left_out:
        reason = placed.left_out if placed is not None else (
            f"the render agrees with their warped photos better than the photos agree with each other "
            f"(by more than {-config.agreement_min_db:g} dB)")
        setting.log(f"round {round_index + 1}: {len(left_out)} of {len(views)} virtual views left out: {reason}")


def regenerate_pool(setting: Setting, config: BootstrapConfig, state: LoopState, pool: ViewPool) -> None:
    """I* of the pool's views again, from the Gaussians as they are now: the fill then repairs
    the refined render rather than the stage-I one (the bootstrap's feedback loop). A view the
    gate left out is made again now, so that it is judged again; a supervised one is marked
    stale and made again when the sampler next chooses it (:func:`remade_if_stale`). Between two
    regenerations the sampler chooses about regenerate_every / virtual_every views, often far
    fewer than the pool holds (bonsai with 23 flags: 12 of 46), and a view made again but not
    chosen before the next regeneration was time taken from the photo steps."""
    began = time.perf_counter()
    pool.depths.clear()     # from here on the depths are the Gaussians' as they are now
    maker = target_maker(setting, state, pool.depths)
    device = state.train.params["means"].device
    remade = 0
    for number, entry in enumerate(pool.entries):
        if entry.supervised:
            pool.stale.add(number)
            continue
        if state.clock.wait_or_stop() or state.clock.out_of_time():
            break  # the views not reached keep their I*
        pool.entries[number] = on_device(make_view(maker, entry.camera, entry.round, False, config, pool)[0], device)
        remade += 1
    iteration = state.train.iteration
    pool.regenerations.append({"iteration": iteration, "views": remade, "when_chosen": len(pool.stale),
                               "supervised": supervised_count(pool), "seconds": time.perf_counter() - began})
    setting.log(f"step {iteration}: regenerated {remade} left-out virtual views in "
                f"{pool.regenerations[-1]['seconds']:.1f} s; {len(pool.stale)} others when next chosen")


def remade_if_stale(setting: Setting, config: BootstrapConfig, state: LoopState, pool: ViewPool,
                    number: int) -> VirtualTarget:
    """The pool's view ``number``, its I* made again first when a regeneration marked it stale
    (the gate judges it again: the result may be left out)."""
    if number not in pool.stale:
        return pool.entries[number]
    pool.stale.discard(number)
    entry = pool.entries[number]
    remade = make_view(target_maker(setting, state, pool.depths), entry.camera, entry.round, False, config, pool)[0]
    pool.entries[number] = on_device(remade, state.train.params["means"].device)
    return pool.entries[number]
