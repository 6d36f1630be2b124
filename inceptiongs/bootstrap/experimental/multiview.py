"""The geometry term (the variant "geometry", geometry.py; off by default): multi-view geometric consistency
at a virtual view; the photos supervise *where* the surface is, never what colour it has.
Measured against the same-time baseline: +0.08 / +0.15 dB (scarce / covered) on the objects
demo, -0.40 / -0.54 on the courtyard (docs/bootstrap.md), so it stays off.

At a virtual view no photo exists, so PGSR's multi-view NCC term (reference photo against a
neighbour photo through the rendered plane) has no reference. Here the virtual view only
carries the geometry: the Gaussians' rendered depth d and planar normal n at a pixel p define
a local plane {X : n . X = n . X_p} (virtual camera frame), which induces for every source
photo s the homography H_s = K_s (R_s + t_s n^T / (n . X_p)) K_v^-1 (train.losses
.plane_homographies). The (2r+1)^2 patch around p is mapped by H_s into each source and
sampled bilinearly (differentiable in the coordinates, hence in d and n); where the surface
is right, the K source patches show the same piece of surface and correlate. The loss is the
mean of 1 - NCC over the source pairs valid at the pixel, so its gradient moves the rendered
depth and normal (and through the rasterizer the Gaussians) to where the photos agree.

No warped colour is ever a target: resampling blur and misplaced photos, which made the
colour supervision lose to a converged render (docs/bootstrap.md), cannot be taught. NCC is
invariant to an affine change of the grey level, so exposure differences between the sources
do not matter either.

A pair counts at a pixel only where both sources see the point:
* the plane does not pass through the virtual camera (|n . X_p| > PLANE_OFFSET_MIN) and the
  rendered depth is positive;
* every patch sample projects in front of the source (z > NEAR_PLANE) and inside it (all four
  bilinear taps are real pixels);
* visibility: the centre point's source-camera z agrees with the source's stage-I depth at its
  projection within ``delta`` (relative; warp.DEFAULT_DELTA): a point hidden behind an
  occluder in a source would correlate that source's occluder with the other's surface;
* both patches have contrast (variance >= VARIANCE_MIN): a flat patch's NCC is undefined.
Elsewhere the weight is zero (no gradient, no value).

Images: grey [H, W, 1] in [0, 1]; depths camera z [H, W, 1] (0 = none); normals camera space.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch

from ...camera import Camera
from ...constants import NEAR_PLANE
from ...train.losses import patch_offsets, plane_homographies, safe_normalize, sample_image
from ..generation import VirtualTarget
from .photo_depth import VARIANCE_MIN
from ..warp import DEFAULT_DELTA

# Patch radius 2 (5 x 5): the window of the plane sweep (photo_depth.DEFAULT_RADIUS). Stage I's
# 7 x 7 would straddle the demo objects' silhouettes at 96 x 72 on more pixels.
DEFAULT_RADIUS = 2
# Pixels per evaluation: a random subset bounds the cost at large images (each pixel costs
# (2r+1)^2 bilinear samples per source); 4096 is stage I's ncc_samples.
DEFAULT_SAMPLES = 4096
# A rendered normal shorter than this is mostly background (the blended normal is not
# renormalised: its length is about the alpha of the surface that wrote it).
NORMAL_LENGTH_MIN = 0.5
# The plane offset n . X_p divides in the homography: a plane through the camera centre is
# seen edge-on and says nothing about the patch.
PLANE_OFFSET_MIN = 1e-6


@dataclass
class GeometrySource:
    """A real photo for the geometry term: grey [H, W, 1] in [0, 1], its camera, and its
    stage-I rendered depth [H, W, 1] (camera z; the visibility reference, never differentiated)."""

    grey: torch.Tensor
    camera: Camera
    depth: torch.Tensor


def patch_ncc(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """a, b: [S, P] grey patches -> (NCC [S] in [-1, 1], textured [S] bool: both variances
    >= VARIANCE_MIN). Where a patch is flat the denominator is replaced by 1 (its NCC is
    undefined and masked out): the square root is bounded away from 0 where it is used, so
    neither the value nor its gradient can blow up."""
    ca = a - a.mean(1, keepdim=True)
    cb = b - b.mean(1, keepdim=True)
    var_a, var_b = (ca * ca).mean(1), (cb * cb).mean(1)
    textured = (var_a >= VARIANCE_MIN) & (var_b >= VARIANCE_MIN)
    product = torch.where(textured, var_a * var_b, torch.ones_like(var_a))
    ncc = (ca * cb).mean(1) / torch.sqrt(product)
    return ncc.clamp(-1.0, 1.0), textured


def intrinsics_matrix(camera: Camera, dtype=torch.float32) -> torch.Tensor:
    """[3, 3] K of a camera."""
    return torch.tensor([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]], dtype=dtype)


def source_patches(source: GeometrySource, camera: Camera, pixels: torch.Tensor, depth: torch.Tensor,
                   normals: torch.Tensor, radius: int, delta: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The (2r+1)^2 patches around virtual ``pixels`` [S, 2] mapped into ``source`` through the
    planes (depth [S], unit normals [S, 3], virtual camera frame) -> (patches [S, P], valid [S]:
    plane usable, all samples in front and inside, centre visible in the source)."""
    dtype = depth.dtype
    k_virtual, k_source = intrinsics_matrix(camera, dtype), intrinsics_matrix(source.camera, dtype)
    to_source = torch.as_tensor(source.camera.world_to_camera @ camera.camera_to_world, dtype=dtype)
    homographies, plane_ok = plane_homographies(pixels, depth, normals, k_virtual, k_source, to_source)
    offsets = patch_offsets(radius, dtype)
    points = pixels[:, None, :] + offsets[None]                                      # [S, P, 2]
    mapped = torch.cat([points, torch.ones_like(points[..., :1])], -1) @ homographies.transpose(1, 2)
    in_front = mapped[..., 2] > NEAR_PLANE
    # Behind the source the division uses 1 (those patches are masked out): nothing is inf.
    safe_w = torch.where(in_front, mapped[..., 2], torch.ones_like(mapped[..., 2]))
    source_points = mapped[..., :2] / safe_w[..., None]
    patches, inside = sample_image(source.grey.to(dtype), source_points)
    # Visibility of the patch centre: its z in the source against the source's stage-I depth.
    with torch.no_grad():
        fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
        centre = torch.stack([(pixels[:, 0] - cx) / fx * depth, (pixels[:, 1] - cy) / fy * depth, depth], -1)
        z_source = (centre @ to_source[:3, :3].T + to_source[:3, 3])[:, 2]
        centre_index = offsets.shape[0] // 2                                      # offset (0, 0)
        seen_depth, _ = sample_image(source.depth.to(dtype), source_points[:, centre_index].detach())
        seen_depth = seen_depth[:, 0]
        visible = (seen_depth > 0) & ((z_source - seen_depth).abs() <= delta * z_source.clamp_min(NEAR_PLANE))
    valid = plane_ok & in_front.all(1) & inside.all(1) & visible
    return patches[..., 0], valid


@dataclass
class ConsistencyTerm:
    """loss: scalar tensor (mean 1 - NCC over the valid pixel pairs; None where no pair is
    valid); pairs: how many (pixel, pair) terms it averages; ncc: their mean NCC (diagnostic)."""

    loss: torch.Tensor | None
    pairs: int
    ncc: float


def multiview_consistency(depth: torch.Tensor, normal: torch.Tensor | None, camera: Camera,
                          sources: Sequence[GeometrySource], radius: int = DEFAULT_RADIUS,
                          samples: int | None = DEFAULT_SAMPLES, delta: float = DEFAULT_DELTA,
                          weights: torch.Tensor | None = None,
                          generator: torch.Generator | None = None) -> ConsistencyTerm:
    """The geometry term at a virtual view (see the module doc).

    depth: [h, w, 1] rendered camera z (differentiable; 0 = none); normal: [h, w, 3] rendered
    camera-space planar normal (differentiable; None: the plane is fronto-parallel to the
    virtual view, so only depth is supervised); sources: at least two :class:`GeometrySource`
    (fewer: no term); weights: optional [h, w, 1] per-pixel weight (e.g. a trust mask);
    samples: evaluate at most this many random pixels (None: all). -> :class:`ConsistencyTerm`.
    """
    h, w = depth.shape[:2]
    if len(sources) < 2:
        return ConsistencyTerm(None, 0, 0.0)
    dtype = depth.dtype
    flat_depth = depth.reshape(-1)
    if normal is None:
        normals = torch.zeros(h * w, 3, dtype=dtype, device=depth.device)
        normals[:, 2] = -1.0                        # facing the camera (the rasterizer's convention)
        usable = flat_depth.detach() > 0
    else:
        flat_normal = normal.reshape(-1, 3)
        usable = (flat_depth.detach() > 0) & (flat_normal.detach().norm(dim=-1) >= NORMAL_LENGTH_MIN)
        normals = safe_normalize(flat_normal)
    # Patches must stay inside the virtual image (they are its pixels' neighbourhoods).
    rows = torch.arange(h, device=depth.device)[:, None].expand(h, w).reshape(-1)
    cols = torch.arange(w, device=depth.device)[None, :].expand(h, w).reshape(-1)
    usable &= (rows >= radius) & (rows < h - radius) & (cols >= radius) & (cols < w - radius)
    if weights is not None:
        usable &= weights.reshape(-1).detach() > 0
    index = usable.nonzero()[:, 0]
    if samples is not None and index.numel() > samples:
        index = index[torch.randperm(index.numel(), generator=generator)[:samples]]
    if index.numel() == 0:
        return ConsistencyTerm(None, 0, 0.0)
    pixels = torch.stack([cols[index], rows[index]], -1).to(dtype) + 0.5
    d, n = flat_depth[index], normals[index]
    patches, valid = zip(*(source_patches(s, camera, pixels, d, n, radius, delta) for s in sources))
    pixel_weight = (weights.reshape(-1)[index].to(dtype) if weights is not None
                    else torch.ones(index.numel(), dtype=dtype, device=depth.device))
    total = torch.zeros((), dtype=dtype, device=depth.device)
    weight_sum = torch.zeros((), dtype=dtype, device=depth.device)
    ncc_sum, pairs = 0.0, 0
    for a in range(len(sources)):
        for b in range(a + 1, len(sources)):
            ncc, textured = patch_ncc(patches[a], patches[b])
            both = (valid[a] & valid[b] & textured).to(dtype) * pixel_weight
            total = total + (both * (1.0 - ncc)).sum()
            weight_sum = weight_sum + both.sum()
            counted = both > 0
            pairs += int(counted.sum())
            ncc_sum += float(ncc.detach()[counted].sum())
    if pairs == 0:
        return ConsistencyTerm(None, 0, 0.0)
    # weight_sum > 0: at least one counted term with a positive weight.
    return ConsistencyTerm(total / weight_sum, pairs, ncc_sum / pairs)


def geometry_loss(out: dict, view: VirtualTarget, seed: int, samples: int, step: int
                  ) -> tuple[torch.Tensor | None, dict]:
    """The geometry term (this module) of a virtual view's render ``out`` (with "depth" and
    "normal") against its source photos, on ``samples`` pixels -> (1 - NCC or None where no pair
    is valid, record). The pixel subset is drawn from a generator seeded by the run's ``seed``
    and the step: reproducible, and the trainer's own random stream (view order, photo steps) is
    left as the baseline has it."""
    generator = torch.Generator().manual_seed(seed * 1_000_003 + step)
    term = multiview_consistency(out["depth"], out["normal"], view.camera, view.geometry,
                                 samples=samples, generator=generator)
    record = {"geometry_pairs": term.pairs, "geometry_ncc": term.ncc,
              "geometry_loss": None if term.loss is None else float(term.loss.detach())}
    return term.loss, record
