"""Placement by evidence (the variant "evidence", off by default): a round's virtual views go
where the leave-one-out estimate says the blend beats the render (validation.py measures it,
placement.py ranks the candidates), and a view's pixels without that evidence carry no virtual
loss; this replaces the agreement gate. Figures: docs/bootstrap.md, "Placement by evidence".
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

from ...errors import InputError
from ..generation import VirtualTarget
from ..options import VARIANT, option
from ..variants import PlacedViews, PlacementRequest, Variant
from ..virtual_views import DEFAULT_K, DEFAULT_L, nearest_training_views
from .placement import DEFAULT_MIN_FRACTION, candidate_views, place_by_evidence, with_evidence
from .validation import EvidenceGrid, measure_evidence, seen_cells, validation_photos

LEFT_OUT = "too few of their pixels lie where the blend is validated to beat the render"


def mark_view(grid: EvidenceGrid | None, min_fraction: float, entry: VirtualTarget, maker) -> VirtualTarget:
    """``entry`` with its loss weights from the round's estimate and ``supervised`` by their share
    (placement.with_evidence), the depth the model's at the view (``maker``: a view_targets.TargetMaker)."""
    return with_evidence(entry, grid, maker.renders.depth(entry.camera).cpu(), min_fraction)


@dataclass(frozen=True)
class EvidencePlacement(Variant):
    """Virtual views where the leave-one-out estimate says the blend beats the render (validation.py,
    placement.py); a view's pixels without that evidence carry no virtual loss, and this replaces
    the agreement gate."""

    NAME: ClassVar[str] = "evidence"

    min_fraction: float = option(DEFAULT_MIN_FRACTION, "a virtual view is used when at least this share of its "
                                                       "pixels with depth lie on regions of positive evidence",
                                 "fraction, in (0, 1]", VARIANT)
    photos: int = option(6, "training photos near the targets at which the leave-one-out estimate is measured "
                            "each round", "views", VARIANT)

    def check(self, source: str, config) -> None:
        if not 0 < self.min_fraction <= 1:
            raise InputError(f"{source}: min_fraction must be in (0, 1], got {self.min_fraction}")
        if self.photos < 1:
            raise InputError(f"{source}: photos must be >= 1, got {self.photos}")

    def place_views(self, request: PlacementRequest) -> PlacedViews:
        """The round's views where the estimate, measured now at the training photos nearest the
        targets, says the blend beats the render; the estimate and every candidate's score are
        the round's record."""
        config, cameras, train, goal = request.config, list(request.cameras), request.train, request.goal
        k = config.k or DEFAULT_K
        photos = nearest_training_views(goal[0].camera, cameras, sorted({
            i for target in goal for i in validation_photos(target.camera, cameras, train, k)}),
            self.photos) if goal else []
        # The estimate and its voxel grid stay on the CPU.
        depth_of = lambda camera: request.maker.renders.depth(camera).cpu()     # noqa: E731
        grid = measure_evidence(photos, cameras, train, request.photos, config, depth_of,
                                lambda camera: request.maker.renders.rgb(camera).cpu())
        record = {"validation_photos": [cameras[i].name for i in photos],
                  "estimate": None if grid is None else grid.summary(), "targets": []}
        views = []
        for index, target in enumerate(goal):
            candidates = candidate_views(target.camera, cameras, train, config.k, config.l, config.include_target)
            region = seen_cells(grid, target.camera, depth_of(target.camera))
            # As many views as the default placement makes: the virtual steps are not spread thinner.
            limit = (config.k or DEFAULT_K) * (config.l or DEFAULT_L) + int(config.include_target)
            placement = place_by_evidence(candidates, grid, depth_of, self.min_fraction, limit=limit, region=region)
            views.extend((index, view) for view in placement.views)
            record["targets"].append({"target": target.name, "placed": [view.name for view in placement.views],
                                      "reason": placement.reason,
                                      "candidates": [score.to_json() for score in placement.scores]})
            if placement.reason:
                request.log(f"round {request.round_index + 1}: {target.name}: {placement.reason}")
        return PlacedViews(views[:config.max_virtual_views], record,
                           functools.partial(mark_view, grid, self.min_fraction), LEFT_OUT)
