"""The scene-adaptive fixer as a variant ("fixer", off by default): before the first round's
views are made, a small network (bootstrap/fixer.py) is trained on this scene's pairs -- the
render of the model with its least visible Gaussians dropped at a training pose, and the photo
there -- with the most isolated training poses held out. Its held-out check (fixed render
against the render, on photos it never trained on) decides whether the loop uses it; the check
is logged. Where it passed, the fixed render is the fill (``target`` "fill": what I* keeps where
the photos' blend does not reach) or the whole of I* (``target`` "whole": every pixel, the
warped photos left out, so the warps' agreement does not judge the view: the held-out check is
its gate). ``target`` "guided" is "whole" with a fixer that also sees the nearest photos: its
input is the render, the blend of the K nearest training photos warped into the view with the
render's depth, and that blend's mask (at a training pose the pose's own photo is left out of the
blend, so the fixer learns where the warps beat the render rather than copying the answer). Its
training runs inside the loop's clock, so its time is the bootstrap's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
import torch

from ...errors import InputError
from ...io.photo_memory import default_budget, photo_memory
from ..fixer import CHECK_MARGIN_DB, FixerSettings, KeptPairs, build_pairs, fewer_gaussians, \
    fix_where_check_says, held_out_check, held_out_views, train_fixer
from ..options import VARIANT, option
from ..supervise import blend_supervision, placed_blend
from ..view_supervision import ViewContext, ViewSupervision
from ..view_targets import ModelRenders, blend_sources
from ..virtual_views import DEFAULT_ROTATION_WEIGHT
from ...camera import pose_distance
from ..variants import PlacementRequest, Variant


# The guide's channels: the nearest photos' blend [3] and its mask [1].
GUIDE_CHANNELS = 4


def guided_input(context) -> torch.Tensor:
    """[H, W, 7]: the render, the blend of the context's source photos warped into its view with
    the render's depth (over the render where none reaches), and the blend's mask."""
    render = context.render().float().clamp(0.0, 1.0)
    placed = placed_blend(context, render, context.own_depth())
    return torch.cat([render, placed.image.float().clamp(0.0, 1.0), placed.mask.float()], dim=-1)


@dataclass
class FixerState:
    """What the first round trains: the network and its check (None until then)."""

    net: object = None
    check: object = None


@dataclass(frozen=True)
class Fixer(Variant):
    """The fill, or all of I* (``target``), made by a per-scene fixer where its held-out check passed."""

    NAME: ClassVar[str] = "fixer"

    keep_fraction: float = option(0.5, "share of Gaussians (the most visible: opacity x footprint) the degraded "
                                       "renders keep", "-", VARIANT)
    steps: int = option(300, "the fixer's training steps (charged to the bootstrap's clock)", "-", VARIANT)
    held_out: int = option(2, "isolated training poses held out of its training for its check", "-", VARIANT)
    margin_db: float = option(CHECK_MARGIN_DB, "the held-out gain over the render it must reach to be used",
                              "dB", VARIANT)
    width: int = option(16, "the fixer UNet's base width", "-", VARIANT)
    guide_sources: str = option("nearest", "\"guided\": the photos a training pose's guide is blended from: "
                                           "\"nearest\" (its K nearest others) or \"far\" (its K nearest among "
                                           "those at least half the targets' median distance to their nearest "
                                           "photo away, so the warps are as far as at the virtual views)", "-",
                                VARIANT)
    target: str = option("fill", "what the fixed render is at a virtual view: \"fill\" (where no photo's warp "
                                 "reaches), \"whole\" (all of I*, no warps) or \"guided\" (all of I*, made from "
                                 "the render and the nearest photos' warps)", "-", VARIANT)

    @property
    def state(self) -> FixerState:
        """The run's trained fixer: set once on this (frozen) options object, not an option."""
        if "_state" not in self.__dict__:
            object.__setattr__(self, "_state", FixerState())
        return self.__dict__["_state"]

    def check(self, source: str, config) -> None:
        if config.fill != "render":
            raise InputError(f"{source}: the fixer makes the fill from the render: it needs fill \"render\", "
                             f"got {config.fill!r}")
        if not 0.0 < self.keep_fraction <= 1.0:
            raise InputError(f"{source}: variants.fixer.keep_fraction must be in (0, 1], got {self.keep_fraction}")
        if self.guide_sources not in ("nearest", "far"):
            raise InputError(f"{source}: variants.fixer.guide_sources must be \"nearest\" or \"far\", "
                             f"got {self.guide_sources!r}")
        if self.target not in ("fill", "whole", "guided"):
            raise InputError(f"{source}: variants.fixer.target must be \"fill\", \"whole\" or \"guided\", "
                             f"got {self.target!r}")
        if self.steps < 1 or self.held_out < 1 or self.width < 2:
            raise InputError(f"{source}: variants.fixer: steps and held_out must be >= 1 and width >= 2")

    def place_views(self, request: PlacementRequest):
        if self.state.check is None:
            self.state.net, self.state.check = self.trained(request)
            request.log(f"fixer {'used' if self.state.check.passes else 'not used'} at the virtual views")
        return None

    def trained(self, request: PlacementRequest):
        """(network, check) from the request's model, photos and training views."""
        maker, cameras, train = request.maker, request.cameras, list(request.train)
        reduced = fewer_gaussians(maker.current.detach(), self.keep_fraction)
        rasterizer = maker.setting.rasterizer

        degraded_renders = ModelRenders(reduced, rasterizer, maker.renders.sky)

        gap = 0.0
        if self.guide_sources == "far" and request.goal:
            gap = 0.5 * float(np.median([min(pose_distance(t.camera.world_to_camera, cameras[v].world_to_camera,
                                                           DEFAULT_ROTATION_WEIGHT) for v in train)
                                         for t in request.goal]))
            request.log(f"fixer guides blended from photos at least {gap:.3f} away (pose distance)")

        def fixer_input_at(view: int, renders: ModelRenders) -> torch.Tensor:
            """The fixer's input at training view ``view`` from ``renders``' model; its own photo is
            left out of the guide's blend. The renders are dropped after each view, so a large
            capture's pairs stay within the photo budget."""
            camera = cameras[view]
            sources = []
            if self.target == "guided":          # only a guided fixer's input warps photos in
                others = [v for v in train if v != view]
                far = [v for v in others if pose_distance(cameras[v].world_to_camera, camera.world_to_camera,
                                                          DEFAULT_ROTATION_WEIGHT) >= gap] if gap > 0.0 else others
                sources = blend_sources(camera, cameras, far or others, request.config)
            with torch.no_grad():
                context = ViewContext(request.config, camera, renders.rgb(camera), sources, cameras,
                                      request.photos, renders.depth, renders.rgb)
                made = self.fixer_input(context).float().cpu()
            renders.forget()
            return made

        def degraded(view: int) -> torch.Tensor:
            return fixer_input_at(view, degraded_renders)

        centres = np.array([camera.center for camera in cameras])
        held = held_out_views(centres, train, self.held_out)
        fit = [v for v in train if v not in held]
        device = maker.current.means.device
        # Its training set within the photo budget: a pair that went is rendered again when drawn.
        channels = 3 + (GUIDE_CHANNELS if self.target == "guided" else 0) + 3
        pair_bytes = [channels * 4 * cameras[v].width * cameras[v].height for v in fit]
        budget = photo_memory()
        budget = default_budget(sum(pair_bytes)) if budget is None else budget
        trained = train_fixer(KeptPairs(degraded, request.photos, fit, budget),
                              FixerSettings(steps=self.steps, width=self.width, seed=request.config.seed),
                              device=device, log=request.log)
        # The check: at the held-out poses the degraded render stands in for a scarce view's
        # render (it must be beaten by margin_db); the plain render there is already fitted to
        # its photo, and the fixer must not harm it by more than |margin_db|.
        check = held_out_check(trained.net, build_pairs(degraded, request.photos, held), self.margin_db)
        fitted_renders = ModelRenders(maker.current.detach(), rasterizer, maker.renders.sky)
        fitted = held_out_check(trained.net, build_pairs(lambda v: fixer_input_at(v, fitted_renders),
                                                         request.photos, held), -abs(self.margin_db))
        request.log(f"{check.words()}; on the fitted render there {fitted.gain_db:+.2f} dB")
        if not fitted.passes:
            check.margin_db = float("inf")        # refused: it harms a fitted render
        return trained.net, check

    def fixer_input(self, context) -> torch.Tensor:
        """[H, W, 3 + G]: the render at the context's view, and for "guided" its guide channels."""
        if self.target == "guided":
            return guided_input(context)
        return context.render()

    def supervise(self, context):
        fixed = fix_where_check_says(self.state.net, self.state.check, self.fixer_input(context))
        if fixed is None:
            return None
        fixed = fixed.to(context.fill.device)
        if self.target in ("whole", "guided"):
            # Every pixel trusted; no warps, so no agreement margin to judge the view by.
            return ViewSupervision(fixed.detach().float().clamp(0.0, 1.0), torch.ones_like(fixed[..., :1]),
                                   {"agreement_db": None})
        return blend_supervision(replace(context, fill=fixed))
