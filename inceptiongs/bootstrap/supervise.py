"""I* at one virtual view (what a supervision works on and returns: view_supervision.py).

The default is the blend (:func:`blend_supervision`): the K nearest photos warped in with the
model's depth (or the training views' depth splatted into the view, ``virtual_depth``), their
binary-masked mean over the fill: I* = M * warped + (1 - M) * fill, the paper's blending. A
chosen variant may supply another supervision, or move the warps and finish the blend (the
hooks ``supervise``, ``adjust_warps``, ``finish_blend``: variants.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .agreement import agreement_margin_db
from .view_supervision import ViewContext, ViewSupervision
from .warp import WarpResult, blend_views, warp_to_view


def supervise_view(context: ViewContext) -> ViewSupervision:
    """I* of the view: a chosen variant's supervision, else the blend; without blending
    (ablation) or photos: the fill and an all-zero mask."""
    if not context.config.blending or not context.sources:
        return ViewSupervision(context.fill, torch.zeros((*context.fill.shape[:2], 1), device=context.fill.device))
    for variant in context.config.variants.values():
        supervision = variant.supervise(context)
        if supervision is not None:
            return supervision
    return blend_supervision(context)


# --- the default: the paper's blend --------------------------------------------------------------
def warp_sources(context: ViewContext, depth: torch.Tensor) -> list[WarpResult]:
    """Each source photo warped into the view placed with ``depth`` [H, W, 1] (then moved by
    the chosen variants, ``adjust_warps``)."""
    warps = [warp_to_view(context.photos[i], context.render_depth(context.cameras[i]), context.cameras[i], depth,
                          context.camera, delta=context.delta)
             for i in context.sources]
    for variant in context.config.variants.values():
        warps = variant.adjust_warps(context, warps)
    return warps


@dataclass
class PlacedBlend:
    """The warps placed with one depth and their blend over the fill."""

    warps: list[WarpResult]
    image: torch.Tensor
    mask: torch.Tensor
    depth: torch.Tensor


def placed_blend(context: ViewContext, fill: torch.Tensor, depth: torch.Tensor) -> PlacedBlend:
    warps = warp_sources(context, depth)
    image, mask = blend_views(fill, warps)
    return PlacedBlend(warps, image, mask, depth)


def both_depths(own: PlacedBlend, splatted: PlacedBlend) -> PlacedBlend:
    """``virtual_depth="both"``: per pixel the blend placed with the view's own depth where it is
    trusted, else the one placed with the splatted depth (per source for the warps, so the
    agreement is judged on the photos as they enter the blend)."""
    warps = [WarpResult(torch.where(a.mask > 0, a.image, b.image), torch.maximum(a.mask, b.mask))
             for a, b in zip(own.warps, splatted.warps)]
    return PlacedBlend(warps, torch.where(own.mask > 0, own.image, splatted.image),
                       torch.maximum(own.mask, splatted.mask),
                       torch.where(own.depth > 0, own.depth, splatted.depth))


def choose_placement(context: ViewContext, fill: torch.Tensor) -> tuple[PlacedBlend, str | None]:
    """The blend by ``virtual_depth`` -> (it, the depth's name for the report, None: the render's
    alone). "auto" keeps whichever depth's blend trusts more pixels."""
    mode = context.config.virtual_depth
    if mode == "render" or context.source_depth is None:
        return placed_blend(context, fill, context.own_depth()), None
    splatted = placed_blend(context, fill, context.source_depth())
    if mode == "sources":
        return splatted, "sources"
    own = placed_blend(context, fill, context.own_depth())
    if mode == "both":
        return both_depths(own, splatted), "both"
    if float(own.mask.sum()) > float(splatted.mask.sum()):
        return own, "render"
    return splatted, "sources"


def blend_supervision(context: ViewContext) -> ViewSupervision:
    """The uniform mean of the binary-masked warps over the fill (the paper's blending)."""
    placed, depth_name = choose_placement(context, context.fill)
    report = {} if depth_name is None else {"depth": depth_name}
    report["agreement_db"] = agreement_margin_db(context.render(), placed.warps)
    image = placed.image
    for variant in context.config.variants.values():
        image = variant.finish_blend(image, placed.mask, placed.depth)
    return ViewSupervision(image.detach().float().clamp(0.0, 1.0), placed.mask.detach().float(), report)
