"""Photo-consistent depth at a virtual view: refine the stage-I depth by multi-view agreement
of the real photos, so a warped photo lands within a pixel of where it belongs.

A virtual view has no photo of its own, so consistency is measured *among its sources*: for
each depth hypothesis every source photo is warped into the virtual view, and the hypothesis
is good where the warped sources agree. Hypotheses scale the stage-I depth per pixel,
d_k = s_k d_render with s_k on a grid around 1, so the surface keeps the planar G-buffer's
shape (its normals) while it slides along the rays: the plane sweep of a multi-view stereo
initialised from the render. Agreement is the normalised cross-correlation (NCC, the measure
of PGSR's multi-view term) of the grey warped sources over small windows in the virtual view,
averaged over the source pairs that are valid there. The best hypothesis is refined to
sub-step precision by a parabola through its neighbours' scores.

Confidence says how much to trust the result per pixel: it is 0 where fewer than two sources
see the pixel, where a source window has no contrast (NCC of a flat patch is undefined, so
there is no evidence either way), and otherwise the best NCC times how much it stands out of
the hypotheses' mean (a flat score curve is ambiguous). Pixels below ``confidence_min`` keep
the stage-I depth: the render is the prior of the search, photo evidence only moves it.

Images are float in [0, 1], [H, W, 3]; depths are camera z, [h, w, 1], 0 = none.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
import torch.nn.functional as F

from ...camera import Camera
from ...constants import NEAR_PLANE
from ..warp import bilinear_taps, sample_bilinear
from ...pinhole import relative_pose, unproject

# Hypotheses span +-10 % of the stage-I depth: the render's depth passes a 3 % visibility
# test yet misplaces photos by pixels, and surfaces stage I got badly wrong are not what this
# refinement can rescue (a wider search finds more repeated-texture false matches).
DEFAULT_SEARCH = 0.10
DEFAULT_STEPS = 21
# NCC windows of 5 x 5 pixels (radius 2): the size PGSR's multi-view term uses at its patch
# radius, small enough to follow depth edges at the renders' resolutions.
DEFAULT_RADIUS = 2
# A window whose grey-level standard deviation is below 1/255 has no usable texture.
VARIANCE_MIN = (1.0 / 255.0) ** 2
DEFAULT_CONFIDENCE_MIN = 0.3


@dataclass
class PhotoDepth:
    """depth: [h, w, 1] refined camera z (stage-I depth where not confident); confidence:
    [h, w, 1] in [0, 1]; score: [h, w, 1] best mean NCC (-1 where undefined)."""

    depth: torch.Tensor
    confidence: torch.Tensor
    score: torch.Tensor


def grey(image: torch.Tensor) -> torch.Tensor:
    """[H, W, 3] -> [H, W, 1] (mean of the channels: no colour weighting, exposure-agnostic NCC)."""
    return image.mean(dim=-1, keepdim=True)


def warp_at_depth(source: torch.Tensor, source_camera: Camera, depth: torch.Tensor,
                  camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample ``source`` [H, W, C] at the projections of the virtual view's pixels placed at
    ``depth`` [h, w] (camera z). -> (values [h, w, C], valid [h, w] bool: depth > 0, in front
    of the source, all four bilinear taps inside)."""
    depth64 = depth.to(torch.float64)
    has_depth = torch.isfinite(depth64) & (depth64 > 0)
    points = unproject(torch.where(has_depth, depth64, torch.zeros_like(depth64)), camera)
    transform = torch.as_tensor(relative_pose(source_camera, camera), dtype=torch.float64, device=depth.device)
    points_src = points @ transform[:3, :3].T + transform[:3, 3]
    z = points_src[..., 2]
    in_front = has_depth & (z > NEAR_PLANE)
    # Points behind the source get z = 1 in the division (masked out below): nothing is inf.
    safe_z = torch.where(in_front, z, torch.ones_like(z))
    uv = torch.stack([source_camera.fx * points_src[..., 0] / safe_z + source_camera.cx,
                      source_camera.fy * points_src[..., 1] / safe_z + source_camera.cy], dim=-1)
    x0, y0, fx, fy, inside = bilinear_taps(uv, source_camera.width, source_camera.height)
    values, _ = sample_bilinear(source, x0, y0, fx, fy)
    return values, in_front & inside


def window_mean(x: torch.Tensor, radius: int) -> torch.Tensor:
    """Box mean over (2 radius + 1)^2 windows of a [B, h, w] stack (edges replicate)."""
    size = 2 * radius + 1
    padded = F.pad(x[:, None], (radius, radius, radius, radius), mode="replicate")
    return F.avg_pool2d(padded, size, stride=1)[:, 0]


def pairwise_ncc(warped: torch.Tensor, valid: torch.Tensor, radius: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean NCC over source pairs of warped grey images.

    warped: [S, h, w] grey, valid: [S, h, w] bool. A pair counts at a pixel when both sources
    are valid over the whole window and both windows have contrast (variance >= VARIANCE_MIN).
    -> (score [h, w] mean NCC of the counted pairs, -1 where none; pairs [h, w] their number).
    """
    count = warped.shape[0]
    h, w = warped.shape[1:]
    window_valid = window_mean(valid.to(warped.dtype), radius) > 1.0 - 1e-6
    mean = window_mean(warped, radius)
    variance = (window_mean(warped * warped, radius) - mean * mean).clamp_min(0.0)
    textured = window_valid & (variance >= VARIANCE_MIN)
    total = torch.zeros(h, w, dtype=warped.dtype, device=warped.device)
    pairs = torch.zeros(h, w, dtype=warped.dtype, device=warped.device)
    for a in range(count):
        for b in range(a + 1, count):
            covariance = window_mean(warped[a:a + 1] * warped[b:b + 1], radius)[0] - mean[a] * mean[b]
            both = textured[a] & textured[b]
            # Both variances are >= VARIANCE_MIN where counted: the root is bounded away from 0.
            denominator = torch.sqrt(torch.where(both, variance[a] * variance[b], torch.ones_like(variance[a])))
            ncc = (covariance / denominator).clamp(-1.0, 1.0)
            total = total + torch.where(both, ncc, torch.zeros_like(ncc))
            pairs = pairs + both.to(pairs.dtype)
    score = torch.where(pairs > 0, total / pairs.clamp_min(1.0), torch.full_like(total, -1.0))
    return score, pairs


def subpixel_offset(left: torch.Tensor, centre: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
    """Vertex of the parabola through (-1, left), (0, centre), (1, right), in [-0.5, 0.5]; 0
    where the three are not strictly concave (a flat or rising curve has no interior peak)."""
    curvature = left - 2.0 * centre + right
    concave = curvature < -1e-12
    offset = 0.5 * (left - right) / torch.where(concave, curvature, -torch.ones_like(curvature))
    return torch.where(concave, offset.clamp(-0.5, 0.5), torch.zeros_like(offset))


def photo_consistent_depth(prior_depth, camera: Camera, sources: Sequence[tuple[torch.Tensor, Camera]],
                           search: float = DEFAULT_SEARCH, steps: int = DEFAULT_STEPS,
                           radius: int = DEFAULT_RADIUS,
                           confidence_min: float = DEFAULT_CONFIDENCE_MIN) -> PhotoDepth:
    """Refine ``prior_depth`` [h, w, 1] (stage-I camera z, 0 = none) of the virtual ``camera``
    by the agreement of ``sources`` (photo [H, W, 3] in [0, 1], its camera); see the module doc."""
    if not (0.0 < search < 1.0) or steps < 3 or radius < 1:
        raise ValueError(f"search must be in (0, 1), steps >= 3 and radius >= 1 (got {search}, {steps}, {radius})")
    prior = torch.as_tensor(prior_depth).detach()[..., 0].to(torch.float64)
    h, w = prior.shape
    if (h, w) != (camera.height, camera.width):
        raise ValueError(f"prior_depth is {h}x{w}, the camera {camera.height}x{camera.width}")
    has_depth = torch.isfinite(prior) & (prior > 0)
    prior = torch.where(has_depth, prior, torch.zeros_like(prior))
    unknown = PhotoDepth(prior[..., None].float(), torch.zeros(h, w, 1), torch.full((h, w, 1), -1.0))
    if len(sources) < 2 or not bool(has_depth.any()):
        return unknown
    greys = [(grey(torch.as_tensor(image).detach().to(torch.float32)), cam) for image, cam in sources]
    scales = torch.linspace(1.0 - search, 1.0 + search, steps, dtype=torch.float64)
    scores = torch.empty(steps, h, w)
    for k, scale in enumerate(scales):
        depth = prior * scale
        warped, valid = [], []
        for image, cam in greys:
            values, ok = warp_at_depth(image, cam, depth, camera)
            warped.append(values[..., 0].float())
            valid.append(ok)
        scores[k], _ = pairwise_ncc(torch.stack(warped), torch.stack(valid), radius)
    best_score, best = scores.max(dim=0)
    defined = (best_score > -1.0) & has_depth
    inner = best.clamp(1, steps - 2)
    neighbour = lambda offset: scores.gather(0, (inner + offset)[None])[0]  # noqa: E731
    offset = subpixel_offset(neighbour(-1), neighbour(0), neighbour(1))
    offset = torch.where((best == inner) & (neighbour(-1) > -1) & (neighbour(1) > -1), offset, torch.zeros_like(offset))
    step_size = float(scales[1] - scales[0])
    scale = scales[best] + offset.to(torch.float64) * step_size
    # Peakedness: how far the best stands above the mean of the defined hypotheses. A flat
    # curve (repeated or faint texture) gives no preference, hence no confidence.
    defined_k = scores > -1.0
    mean_score = torch.where(defined_k, scores, torch.zeros_like(scores)).sum(0) / defined_k.sum(0).clamp_min(1)
    peak = ((best_score - mean_score) / 0.2).clamp(0.0, 1.0)
    confidence = torch.where(defined, best_score.clamp(0.0, 1.0) * peak, torch.zeros_like(best_score))
    use = confidence >= confidence_min
    depth = torch.where(use, prior * scale, prior)
    return PhotoDepth(depth[..., None].float(), confidence[..., None].float(),
                      torch.where(defined, best_score, torch.full_like(best_score, -1.0))[..., None].float())
