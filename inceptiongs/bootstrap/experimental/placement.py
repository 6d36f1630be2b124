"""Virtual views where the leave-one-out evidence says the blend beats the render
(the variant "evidence", evidence.py; the estimate itself: validation.py).

Candidates are poses in the target's neighbourhood: the target itself and the poses on the
paths from it towards its ``2 k`` nearest training photos (twice the loop's sources, so the
neighbourhood is wider than the k paths of the default placement). Each candidate's pixels are
looked up in the evidence grid with the model's depth there, counting only those on cells the
target itself sees (the surface to repair: a view of well covered surroundings would otherwise
rank first and take the virtual steps); a candidate is kept when at least ``min_fraction`` of its
pixels with depth fall on such cells of positive margin and the mean margin over them is
positive. Kept views are ranked by the share of positive pixels.
In the loss, a kept view's pixels without positive evidence carry no weight
(validation.evidence_weights), so a region the estimate knows nothing about gets no virtual
gradient.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import torch

from ...camera import Camera
from ..generation import VirtualTarget
from .validation import EvidenceGrid, evidence_weights, view_margins, world_points
from ..virtual_views import DEFAULT_K, DEFAULT_L, VirtualView, virtual_views

# A candidate needs at least this share of its pixels with depth on positive evidence.
DEFAULT_MIN_FRACTION = 0.05


@dataclass
class CandidateScore:
    """One candidate's evidence: the share of its pixels with depth that lie on positive,
    negative and no evidence, and the mean margin (dB) over those with evidence (None: none)."""

    name: str
    positive: float
    negative: float
    unknown: float
    mean_margin_db: float | None

    def to_json(self) -> dict:
        return {"name": self.name, "positive": self.positive, "negative": self.negative,
                "unknown": self.unknown, "mean_margin_db": self.mean_margin_db}


@dataclass
class Placement:
    """The kept views (best first), every candidate's score, and ``reason`` when none is kept."""

    views: list[VirtualView]
    scores: list[CandidateScore] = field(default_factory=list)
    reason: str | None = None


def candidate_views(target: Camera, cameras: Sequence[Camera], train: Sequence[int], k: int | None = None,
                    l: int | None = None, include_target: bool = True) -> list[VirtualView]:
    """The target (when ``include_target``) and the poses towards its 2 k nearest training photos."""
    k, l = k or DEFAULT_K, l or DEFAULT_L
    views = [VirtualView(target.with_pose(target.world_to_camera, name="target"), -1, 0.0, "target")] \
        if include_target else []
    return views + virtual_views(target, cameras, list(train), k=2 * k, l=l)


def score_view(name: str, margins: torch.Tensor) -> CandidateScore:
    """margins [N] float64 of the candidate's pixels with depth (NaN: no evidence) -> its score."""
    total = max(int(margins.numel()), 1)
    known = ~torch.isnan(margins)
    positive = int((margins > 0).sum())
    negative = int((known & (margins <= 0)).sum())
    mean = float(margins[known].mean()) if bool(known.any()) else None
    return CandidateScore(name, positive / total, negative / total, 1.0 - (positive + negative) / total, mean)


def place_by_evidence(candidates: Sequence[VirtualView], grid: EvidenceGrid | None,
                      depth_of: Callable[[Camera], torch.Tensor], min_fraction: float = DEFAULT_MIN_FRACTION,
                      limit: int | None = None, region: torch.Tensor | None = None) -> Placement:
    """The candidates whose pixels lie on positive evidence (module doc), best first, at most
    ``limit``; no grid, or no candidate passing -> no views and the reason. region: [V] bool, the
    cells the target sees (validation.seen_cells); when given, only a candidate's pixels in them
    count, so the views kept are those that see the target's own surface where the blend wins."""
    if not 0 < min_fraction <= 1 or not math.isfinite(min_fraction):
        raise ValueError(f"min_fraction must be in (0, 1], got {min_fraction}")
    if grid is None:
        return Placement([], [], "no evidence: no training photo near the target is covered by the blend "
                                 "of the others, so no region is known to gain from virtual views")
    scores, kept = [], []
    for view in candidates:
        depth = torch.as_tensor(depth_of(view.camera))
        margins = view_margins(grid, view.camera, depth)
        has_depth = torch.isfinite(depth[..., 0]) & (depth[..., 0] > 0)
        if region is not None:
            index, inside = grid.cells(world_points(depth, view.camera))
            margins = torch.where(inside & region[index], margins, torch.full_like(margins, float("nan")))
        score = score_view(view.name, margins[has_depth])
        scores.append(score)
        if score.positive >= min_fraction and score.mean_margin_db is not None and score.mean_margin_db > 0:
            kept.append((score.positive, view))
    kept.sort(key=lambda pair: -pair[0])   # stable: ties keep the candidates' order
    views = [view for _, view in kept][:limit]
    reason = None if views else (f"no candidate pose has {min_fraction:.0%} of its pixels on regions where the "
                                 f"blend is validated to beat the render")
    return Placement(views, scores, reason)


def with_evidence(entry: VirtualTarget, grid: EvidenceGrid | None, depth: torch.Tensor,
                  min_fraction: float = DEFAULT_MIN_FRACTION) -> VirtualTarget:
    """``entry`` with its loss weights from the evidence (depth [H, W, 1]: the model's at the view)
    and ``supervised`` when at least ``min_fraction`` of its pixels with depth carry weight (this
    replaces the agreement gate)."""
    depth = torch.as_tensor(depth)
    weights = evidence_weights(view_margins(grid, entry.camera, depth))
    with_depth = int((torch.isfinite(depth[..., 0]) & (depth[..., 0] > 0)).sum())
    share = float(weights.sum()) / max(with_depth, 1)
    return dataclasses.replace(entry, evidence=weights, supervised=share >= min_fraction)

