"""Unstructured-lumigraph blending weights (Buehler et al. 2001): per virtual-view pixel, how
much each warped source photo should count.

A source is the better witness of a surface point the closer its ray to the point is to the
virtual ray (view-dependent effects and residual depth error both grow with that angle) and
the nearer it stands compared with the virtual camera (a far source saw the point with fewer
pixels). Per source i and pixel:

    penalty_i = angle_i / angle_scale + resolution_weight * max(0, dist_i / dist_v - 1)
    w_i       = valid_i * exp(-penalty_i^2)

normalised over the valid sources so they sum to 1 (all 0 where no source is valid). The raw
best ``exp(-penalty^2)`` is also returned: it says how good the best witness is, which the
soft trust mask uses (a pixel seen only at a steep angle is blended in weakly).
"""

from __future__ import annotations

import math

import torch

# An angle of 10 degrees between the source and virtual rays costs one unit of penalty
# (weight e^-1 before normalisation): the nearest training views of a flagged view are
# typically 5-20 degrees away, so this separates them without starving any.
DEFAULT_ANGLE_SCALE_DEG = 10.0
# A source twice as far as the virtual camera costs one unit too.
DEFAULT_RESOLUTION_WEIGHT = 1.0


def ray_angles(points: torch.Tensor, virtual_centre: torch.Tensor, source_centres: torch.Tensor) -> torch.Tensor:
    """Angle (radians) at each point between the rays to the virtual camera and to each source.

    points: [h, w, 3] world points; virtual_centre: [3]; source_centres: [S, 3] -> [S, h, w]."""
    to_virtual = virtual_centre - points                                # [h, w, 3]
    to_sources = source_centres[:, None, None, :] - points[None]        # [S, h, w, 3]
    cross = torch.linalg.vector_norm(torch.cross(to_sources, to_virtual.expand_as(to_sources), dim=-1), dim=-1)
    dot = (to_sources * to_virtual).sum(-1)
    # atan2 of |a x b| and a . b is exact for small and for near-opposite angles, and is 0 (not
    # NaN) when a point coincides with a camera centre.
    return torch.atan2(cross, dot)


def lumigraph_weights(points: torch.Tensor, valid: torch.Tensor, virtual_centre, source_centres,
                      angle_scale_deg: float = DEFAULT_ANGLE_SCALE_DEG,
                      resolution_weight: float = DEFAULT_RESOLUTION_WEIGHT) -> tuple[torch.Tensor, torch.Tensor]:
    """points: [h, w, 3] world points of the virtual view's pixels; valid: [S, h, w] bool (the
    source's warp is trusted there); virtual_centre: [3]; source_centres: [S, 3].

    -> (weights [S, h, w, 1] summing to 1 over sources where any is valid, else 0;
        best [h, w, 1] the largest unnormalised weight, in [0, 1])."""
    if not (angle_scale_deg > 0 and resolution_weight >= 0):
        raise ValueError("angle_scale_deg must be > 0 and resolution_weight >= 0")
    dtype = points.dtype
    virtual_centre = torch.as_tensor(virtual_centre, dtype=dtype)
    source_centres = torch.as_tensor(source_centres, dtype=dtype).reshape(-1, 3)
    angles = ray_angles(points, virtual_centre, source_centres)
    dist_virtual = torch.linalg.vector_norm(virtual_centre - points, dim=-1)          # [h, w]
    dist_sources = torch.linalg.vector_norm(source_centres[:, None, None, :] - points[None], dim=-1)
    # A point at the virtual centre has no resolution to compare: ratio 1 (no penalty).
    ratio = torch.where(dist_virtual > 0, dist_sources / dist_virtual.clamp_min(1e-30), torch.ones_like(dist_sources))
    penalty = angles / math.radians(angle_scale_deg) + resolution_weight * (ratio - 1.0).clamp_min(0.0)
    raw = torch.exp(-penalty * penalty) * valid.to(dtype)                              # [S, h, w] in [0, 1]
    total = raw.sum(0)
    weights = torch.where(total > 0, raw / total.clamp_min(1e-30), torch.zeros_like(raw))
    return weights[..., None], raw.amax(0)[..., None]
