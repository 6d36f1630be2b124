"""The photo supervision (the variant "photo_supervision", off by default): what stage II trains on at a
virtual view, built from the photos and the geometry:

1. the stage-I depth refined by photo consistency (:mod:`.photo_depth`);
2. each of the K nearest photos warped in with that depth (:func:`.warp.warp_to_view`: the
   visibility and grazing tests give each warp its trusted pixels);
3. each warp's exposure and white balance matched to the render on confident pixels
   (:mod:`.exposure`);
4. the warps blended with unstructured-lumigraph weights (:mod:`.lumigraph`) instead of a
   uniform mean;
5. a soft trust mask M in [0, 1]: the best witness's lumigraph weight times the depth's trust;
6. what no photo covers (1 - M) filled with the prior's repair, a classical inpainting of the
   blended photos, or the render itself (``fill``);
7. the *informative* mask: the trusted pixels (depth confirmed by the photos) where the photos
   disagree with the render by more than they disagree among themselves (plus a noise floor),
   both compared over the NCC window (a box mean): bilinear resampling blurs every warp alike,
   so at single pixels the photos would "agree" on a blur that a sharp, correct render does
   not show. Only there can a virtual view add information the photo steps do not already
   give; the refinement may restrict its virtual loss to them (the variant "informative").

I* = M * blended + (1 - M) * fill. Every intermediate is returned, so the benchmark
(benchmarks/bench_supervision.py) can score each ingredient on its own.

Measured against the same-time baseline it ends below the blend (docs/bootstrap.md: -0.05 /
-0.08 dB on the scarce / covered views): its soft mask trusts almost none of the scarce pixels
when the witnesses stand far from the view.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Sequence

import numpy as np
import torch

from ...camera import Camera
from ..agreement import agreement_margin_db
from ..view_supervision import ViewContext, ViewSupervision
from ..variants import Variant
from .exposure import apply_affine_colour, fit_affine_colour
from .inpaint import inpaint
from .lumigraph import lumigraph_weights
from .photo_depth import DEFAULT_CONFIDENCE_MIN, DEFAULT_RADIUS, DEFAULT_SEARCH, DEFAULT_STEPS, PhotoDepth, \
    photo_consistent_depth, window_mean
from ..warp import DEFAULT_DELTA, WarpResult, warp_to_view
from ...pinhole import unproject

FILLS = ("prior", "inpaint", "render")
# Depth trust where the sweep found no evidence either way (flat texture, a single source):
# the stage-I depth is kept and its warp half trusted (a flat region warps to a flat colour,
# so depth error costs little there, but nothing confirms it).
TRUST_WITHOUT_EVIDENCE = 0.5
# Informative pixels: the photos' blend must differ from the render (mean absolute difference
# over the channels) by more than this floor -- two 8-bit quantisation steps plus the warp's
# bilinear resampling error on smooth texture -- ...
RESIDUAL_FLOOR = 4.0 / 255.0
# ... and by more than this many times the sources' own spread around their blend (their
# disagreement is what the blend is uncertain by: misplacement, view-dependent colour).
RESIDUAL_SPREAD_FACTOR = 2.0
# Informative pixels are judged on box means over the NCC window (radius 2: 5 x 5): the scale at
# which the sweep matched the photos. On the analytic plane a correct render differs from the
# warps' blend by 0.014 median per pixel (resampling blur), by 0.003 over 5 x 5 means.
SMOOTH_RADIUS = DEFAULT_RADIUS


@dataclass
class Source:
    """A real photo that may be warped in: photo [H, W, 3] in [0, 1], its camera, and its
    stage-I rendered depth [H, W, 1] (the visibility test's occlusion reference)."""

    photo: torch.Tensor
    camera: Camera
    depth: torch.Tensor


@dataclass
class Supervision:
    """target: I* [h, w, 3]; mask: M [h, w, 1] in [0, 1]; blended: the lumigraph blend of the
    corrected warps [h, w, 3] (0 where no source); fill: [h, w, 3]; depth: the refined
    :class:`PhotoDepth`; warps: per source the warp with the refined depth (before exposure
    correction); weights: [S, h, w, 1] lumigraph weights; covered: [h, w, 1] any source trusted;
    informative: [h, w, 1] 0/1, where the photos say something the render does not
    (:func:`informative_mask`); spread: [h, w, 1] the sources' weighted mean absolute
    deviation from the blend over the NCC window (0 where fewer than two)."""

    target: torch.Tensor
    mask: torch.Tensor
    blended: torch.Tensor
    fill: torch.Tensor
    depth: PhotoDepth
    warps: list[WarpResult] = field(default_factory=list)
    weights: torch.Tensor | None = None
    covered: torch.Tensor | None = None
    informative: torch.Tensor | None = None
    spread: torch.Tensor | None = None


def depth_trust(depth: PhotoDepth, confidence_min: float = DEFAULT_CONFIDENCE_MIN) -> torch.Tensor:
    """[h, w, 1] in [0, 1]: 1 where the photos confirm the depth; TRUST_WITHOUT_EVIDENCE where
    they cannot tell (score undefined); below that, in proportion to the confidence, where
    they disagree with every hypothesis."""
    undefined = depth.score <= -1.0
    confirmed = depth.confidence >= confidence_min
    partial = TRUST_WITHOUT_EVIDENCE * (depth.confidence / confidence_min).clamp(0.0, 1.0)
    return torch.where(confirmed, torch.ones_like(partial),
                       torch.where(undefined, torch.full_like(partial, TRUST_WITHOUT_EVIDENCE), partial))


def box_mean(image: torch.Tensor, radius: int = SMOOTH_RADIUS) -> torch.Tensor:
    """[..., h, w, C] -> the same shape, each pixel the mean over its (2 radius + 1)^2 window
    (edges replicate). Differentiable (the informative loss compares renders through it)."""
    lead, (h, w, c) = image.shape[:-3], image.shape[-3:]
    planes = image.reshape(-1, h, w, c).permute(0, 3, 1, 2).reshape(-1, h, w)
    smoothed = window_mean(planes, radius)
    return smoothed.reshape(-1, c, h, w).permute(0, 2, 3, 1).reshape(*lead, h, w, c)


def source_spread(images: torch.Tensor, weights: torch.Tensor, blended: torch.Tensor) -> torch.Tensor:
    """images [S, h, w, 3], weights [S, h, w, 1] (summing to 1 or 0 over S), blended [h, w, 3]
    -> [h, w, 1] the weighted mean absolute deviation of the sources from their blend (channel
    mean). 0 where one source or none is trusted: a lone witness has no measured spread, which
    the depth-confirmation requirement of :func:`informative_mask` makes up for."""
    deviation = (images - blended[None]).abs().mean(dim=-1, keepdim=True)          # [S, h, w, 1]
    return (weights * deviation).sum(0)


def informative_mask(covered: torch.Tensor, confirmed: torch.Tensor, blended: torch.Tensor, render: torch.Tensor,
                     spread: torch.Tensor, floor: float = RESIDUAL_FLOOR,
                     spread_factor: float = RESIDUAL_SPREAD_FACTOR) -> torch.Tensor:
    """[h, w, 1] float, 1 where a source is trusted (``covered``, [h, w, 1] bool), the
    photo-consistent depth is ``confirmed`` ([h, w, 1] bool) and the residual |blended - render|
    (channel mean; give both box-filtered, :func:`box_mean`, see the module doc) exceeds
    ``floor + spread_factor * spread``: the photos agree with each other better than with the
    render, so the render is what is wrong there; else 0. Elsewhere a virtual view would only
    teach the Gaussians what the photo steps teach them anyway (or the warps' own errors).

    Not scaled by the soft mask's lumigraph weight: that says how good the best witness is in
    absolute terms (a source 30 degrees off weighs e^-9), while here the photos are judged
    against the render, which at a poorly observed view is worse still (courtyard, scarce
    views: the photos 16.7 dB, the render 12.9 dB on the pixels where both exist)."""
    residual = (blended - render).abs().mean(dim=-1, keepdim=True)
    disagrees = residual > floor + spread_factor * spread
    return (disagrees & confirmed & covered).float()


def match_exposures(images: list[torch.Tensor], masks: list[torch.Tensor],
                    confidence: torch.Tensor) -> list[torch.Tensor]:
    """Each warp [h, w, 3] mapped by an affine colour fit onto the photos' consensus (the mean
    of all trusted warps at the pixel), on pixels where it and at least one other warp are
    trusted and the depth is confirmed: afterwards all speak the capture's average exposure.
    The reference is the photos, not the render: where stage I is blurred (exactly where stage
    II is needed) a least-squares fit onto the render would flatten the photo's contrast."""
    trusted = [m[..., 0].float() * (confidence[..., 0] >= DEFAULT_CONFIDENCE_MIN).float() for m in masks]
    stacked, weights = torch.stack(images), torch.stack(trusted)[..., None]          # [S, h, w, 3], [S, h, w, 1]
    total_weight = weights.sum(0)
    consensus = (stacked * weights).sum(0) / total_weight.clamp_min(1.0)
    out = []
    for image, weight, mask in zip(images, weights, masks):
        usable = (weight[..., 0] > 0) & (total_weight[..., 0] > weight[..., 0])
        matrix, offset = fit_affine_colour(image.reshape(-1, 3), consensus.reshape(-1, 3),
                                           usable.reshape(-1).float())
        out.append(apply_affine_colour(image, matrix, offset) * mask.float())
    return out


def supervise(camera: Camera, render: torch.Tensor, render_depth: torch.Tensor, sources: Sequence[Source],
              generated: torch.Tensor | None = None, fill: str = "prior", refine_depth: bool = True,
              lumigraph: bool = True, exposure: bool = True, delta: float = DEFAULT_DELTA,
              search: float = DEFAULT_SEARCH, steps: int = DEFAULT_STEPS,
              residual_floor: float = RESIDUAL_FLOOR) -> Supervision:
    """I* and its mask at the virtual ``camera`` (see the module doc).

    render: [h, w, 3] the stage-I render; render_depth: [h, w, 1] its camera z (0 = none);
    generated: [h, w, 3] the prior's repair (``fill="prior"``; the render when None).
    ``refine_depth``, ``lumigraph``, ``exposure`` switch the ingredients (off: stage-I depth,
    a uniform mean, no correction) so each can be measured alone; ``search`` and ``steps`` set
    the depth sweep (relative half-width, hypotheses: photo_depth.py); ``residual_floor`` the
    informative mask's floor (:func:`informative_mask`)."""
    if fill not in FILLS:
        raise ValueError(f"fill must be one of {FILLS}, got {fill!r}")
    render = torch.as_tensor(render).detach().float()
    render_depth = torch.as_tensor(render_depth).detach().float()
    h, w = render.shape[:2]
    if refine_depth:
        depth = photo_consistent_depth(render_depth, camera, [(s.photo, s.camera) for s in sources],
                                       search=search, steps=steps)
    else:
        depth = PhotoDepth(render_depth, torch.zeros(h, w, 1), torch.full((h, w, 1), -1.0))

    warps = [warp_to_view(s.photo, s.depth, s.camera, depth.depth, camera, delta=delta, occlusion_depth=render_depth)
             for s in sources]
    images = [warp.image.float() for warp in warps]
    if exposure and len(warps) > 1:
        images = match_exposures(images, [warp.mask for warp in warps], depth.confidence)
    if sources:
        valid = torch.stack([warp.mask[..., 0] > 0 for warp in warps])                    # [S, h, w]
        covered = valid.any(0)[..., None]
        if lumigraph:
            points_camera = unproject(depth.depth[..., 0].to(torch.float64), camera)
            rotation = torch.as_tensor(camera.world_to_camera[:3, :3], dtype=torch.float64)
            translation = torch.as_tensor(camera.world_to_camera[:3, 3], dtype=torch.float64)
            points = (points_camera - translation) @ rotation                            # R^T (p - t)
            weights, best = lumigraph_weights(points, valid, camera.center,
                                              np.stack([s.camera.center for s in sources]))
            weights, best = weights.float(), best.float()
        else:
            counts = valid.sum(0, keepdim=True).clamp_min(1)[..., None].float()
            weights = valid[..., None].float() / counts
            best = covered.float()
        stacked = torch.stack(images)
        blended = (weights * stacked).sum(0)
        mask = best * depth_trust(depth) * covered.float()
        smooth_blend = box_mean(blended)
        spread = source_spread(box_mean(stacked), weights, smooth_blend)
        informative = informative_mask(covered, depth.confidence >= DEFAULT_CONFIDENCE_MIN, smooth_blend,
                                       box_mean(render), spread, floor=residual_floor)
    else:
        weights, covered = None, torch.zeros(h, w, 1, dtype=torch.bool)
        blended, mask = torch.zeros_like(render), torch.zeros(h, w, 1)
        spread, informative = torch.zeros(h, w, 1), torch.zeros(h, w, 1)

    if fill == "render":
        fill_image = render
    elif fill == "prior":
        fill_image = render if generated is None else torch.as_tensor(generated).detach().float()
    else:
        # Inpaint the blended photos where no source reaches, over the render's pixels elsewhere
        # in the image (so the fill stays continuous with what the photos show).
        fill_image = inpaint(torch.where(covered, blended, render), covered[..., 0] | (render_depth[..., 0] <= 0))
    target = (mask * blended + (1.0 - mask) * fill_image).clamp(0.0, 1.0)
    return Supervision(target, mask, blended, fill_image, depth, warps, weights, covered, informative, spread)


def photo_supervision(context: ViewContext) -> ViewSupervision:
    """:func:`supervise` at a virtual view, the photos placed with ``context.placing_depth()``;
    the fill is the inpainting with the variant "inpaint", else ``config.fill``. With the variant
    "informative": the informative mask (its ``residual_floor``) instead of the trust mask, and
    the blend itself on it (not I*, whose soft mask may give the photos almost no weight where
    the best witness is far off in angle), the fill elsewhere."""
    config = context.config
    informative = config.variants.get("informative")
    floor = None if informative is None else informative.residual_floor
    render = context.render()
    sources = [Source(context.photos[i], context.cameras[i], context.render_depth(context.cameras[i]))
               for i in context.sources]
    out = supervise(context.camera, render, context.placing_depth(), sources,
                    generated=context.fill, fill="inpaint" if "inpaint" in config.variants else config.fill,
                    delta=context.delta, residual_floor=RESIDUAL_FLOOR if floor is None else floor)
    report = {"agreement_db": agreement_margin_db(render, out.warps)}
    if informative is not None:
        target = out.informative * out.blended + (1.0 - out.informative) * out.fill
        return ViewSupervision(target.detach().float().clamp(0.0, 1.0), out.informative.detach().float(), report)
    return ViewSupervision(out.target.detach().float().clamp(0.0, 1.0), out.mask.detach().float(), report)


@dataclass(frozen=True)
class PhotoSupervision(Variant):
    """I* from the photo-consistent depth, exposure-matched warps, lumigraph weights and a soft
    mask instead of the default blend (experimental/photo_supervision.py)."""

    NAME: ClassVar[str] = "photo_supervision"

    def supervise(self, context: ViewContext) -> ViewSupervision:
        return photo_supervision(context)
