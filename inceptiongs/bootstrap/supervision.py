"""What stage II trains on at a virtual view, built from the photos and the geometry:

1. the stage-I depth refined by photo consistency (:mod:`.photo_depth`);
2. each of the K nearest photos warped in with that depth (:func:`.warp.warp_to_view`: the
   visibility and grazing tests give each warp its trusted pixels);
3. each warp's exposure and white balance matched to the render on confident pixels
   (:mod:`.exposure`);
4. the warps blended with unstructured-lumigraph weights (:mod:`.lumigraph`) instead of a
   uniform mean;
5. a soft trust mask M in [0, 1]: the best witness's lumigraph weight times the depth's trust;
6. what no photo covers (1 - M) filled with the prior's repair, a classical inpainting of the
   blended photos, or the render itself (``fill``).

I* = M * blended + (1 - M) * fill. Every intermediate is returned, so the benchmark
(benchmarks/bench_supervision.py) can score each ingredient on its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from ..camera import Camera
from .exposure import apply_affine_colour, fit_affine_colour
from .lumigraph import lumigraph_weights
from .photo_depth import DEFAULT_CONFIDENCE_MIN, PhotoDepth, photo_consistent_depth
from .warp import DEFAULT_DELTA, WarpResult, unproject, warp_to_view

FILLS = ("prior", "inpaint", "render")
# Depth trust where the sweep found no evidence either way (flat texture, a single source):
# the stage-I depth is kept and its warp half trusted (a flat region warps to a flat colour,
# so depth error costs little there, but nothing confirms it).
TRUST_WITHOUT_EVIDENCE = 0.5
# Inpainting radius in pixels (OpenCV Telea): the neighbourhood a missing pixel is filled from.
INPAINT_RADIUS = 3


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
    correction); weights: [S, h, w, 1] lumigraph weights; covered: [h, w, 1] any source trusted."""

    target: torch.Tensor
    mask: torch.Tensor
    blended: torch.Tensor
    fill: torch.Tensor
    depth: PhotoDepth
    warps: list[WarpResult] = field(default_factory=list)
    weights: torch.Tensor | None = None
    covered: torch.Tensor | None = None


def depth_trust(depth: PhotoDepth, confidence_min: float = DEFAULT_CONFIDENCE_MIN) -> torch.Tensor:
    """[h, w, 1] in [0, 1]: 1 where the photos confirm the depth; TRUST_WITHOUT_EVIDENCE where
    they cannot tell (score undefined); below that, in proportion to the confidence, where
    they disagree with every hypothesis."""
    undefined = depth.score <= -1.0
    confirmed = depth.confidence >= confidence_min
    partial = TRUST_WITHOUT_EVIDENCE * (depth.confidence / confidence_min).clamp(0.0, 1.0)
    return torch.where(confirmed, torch.ones_like(partial),
                       torch.where(undefined, torch.full_like(partial, TRUST_WITHOUT_EVIDENCE), partial))


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


def inpaint(image: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """Fill the pixels where ``known`` [h, w] is False from their known neighbours (OpenCV's
    Telea inpainting). image [h, w, 3] in [0, 1] -> [h, w, 3] float32; unchanged if nothing is
    known (nothing to propagate) or nothing is missing."""
    import cv2

    known_np = known.cpu().numpy().astype(bool)
    if known_np.all() or not known_np.any():
        return image.float().clone()
    rgb = (image.detach().float().clamp(0, 1).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
    filled = cv2.inpaint(rgb, (~known_np).astype(np.uint8), INPAINT_RADIUS, cv2.INPAINT_TELEA)
    return torch.as_tensor(filled.astype(np.float32) / 255.0)


def supervise(camera: Camera, render: torch.Tensor, render_depth: torch.Tensor, sources: Sequence[Source],
              generated: torch.Tensor | None = None, fill: str = "prior", refine_depth: bool = True,
              lumigraph: bool = True, exposure: bool = True, delta: float = DEFAULT_DELTA) -> Supervision:
    """I* and its mask at the virtual ``camera`` (see the module doc).

    render: [h, w, 3] the stage-I render; render_depth: [h, w, 1] its camera z (0 = none);
    generated: [h, w, 3] the prior's repair (``fill="prior"``; the render when None).
    ``refine_depth``, ``lumigraph``, ``exposure`` switch the ingredients (off: stage-I depth,
    a uniform mean, no correction) so each can be measured alone."""
    if fill not in FILLS:
        raise ValueError(f"fill must be one of {FILLS}, got {fill!r}")
    render = torch.as_tensor(render).detach().float()
    render_depth = torch.as_tensor(render_depth).detach().float()
    h, w = render.shape[:2]
    if refine_depth:
        depth = photo_consistent_depth(render_depth, camera, [(s.photo, s.camera) for s in sources])
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
        blended = (weights * torch.stack(images)).sum(0)
        mask = best * depth_trust(depth) * covered.float()
    else:
        weights, covered = None, torch.zeros(h, w, 1, dtype=torch.bool)
        blended, mask = torch.zeros_like(render), torch.zeros(h, w, 1)

    if fill == "render":
        fill_image = render
    elif fill == "prior":
        fill_image = render if generated is None else torch.as_tensor(generated).detach().float()
    else:
        # Inpaint the blended photos where no source reaches, over the render's pixels elsewhere
        # in the image (so the fill stays continuous with what the photos show).
        fill_image = inpaint(torch.where(covered, blended, render), covered[..., 0] | (render_depth[..., 0] <= 0))
    target = (mask * blended + (1.0 - mask) * fill_image).clamp(0.0, 1.0)
    return Supervision(target, mask, blended, fill_image, depth, warps, weights, covered)
