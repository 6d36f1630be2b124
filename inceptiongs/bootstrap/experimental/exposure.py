"""Per-source exposure and white-balance correction: an affine colour map fitted on confident
pixels so the warped photos agree in colour before they are blended.

Photos of one capture differ in exposure and white balance; the Gaussians' colours are their
average. Blending an uncorrected bright photo next to a dark one leaves seams that the
refinement would faithfully learn. Per source, c' = A c + b (A [3, 3], b [3]) is fitted by
weighted least squares against a reference (the other photos' consensus, see
:func:`inceptiongs.bootstrap.experimental.photo_supervision.match_exposures`), with a ridge pulling A towards the
identity and b towards 0: with few or uninformative pixels the map stays (nearly) the identity
instead of inventing a colour cast.
"""

from __future__ import annotations

import torch

# Ridge strength per unit of total weight: negligible against thousands of good pixels,
# decisive against a handful.
DEFAULT_RIDGE = 1e-3
# Fewer trusted pixels than this: no fit, the identity.
MIN_PIXELS = 32


def fit_affine_colour(source: torch.Tensor, target: torch.Tensor, weights: torch.Tensor,
                      ridge: float = DEFAULT_RIDGE) -> tuple[torch.Tensor, torch.Tensor]:
    """source, target: [N, 3] colours; weights: [N] >= 0. -> (A [3, 3], b [3]) minimising
    sum_n w_n |A s_n + b - t_n|^2 + ridge * W (|A - I|^2 + |b|^2), W = sum of the weights."""
    source = source.to(torch.float64).reshape(-1, 3)
    target = target.to(torch.float64).reshape(-1, 3)
    weights = weights.to(torch.float64).reshape(-1).clamp_min(0.0)
    identity = torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
    total = float(weights.sum())
    if int((weights > 0).sum()) < MIN_PIXELS or not total > 0:
        return identity
    design = torch.cat([source, torch.ones_like(source[:, :1])], dim=1)             # [N, 4]
    weighted = design * weights[:, None]
    regulariser = ridge * total
    # Normal equations of the ridge problem; the ridge makes the matrix positive definite.
    normal = weighted.T @ design + regulariser * torch.eye(4, dtype=torch.float64)
    prior = torch.cat([torch.eye(3, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64)])  # [4, 3]
    rhs = weighted.T @ target + regulariser * prior
    solution = torch.linalg.solve(normal, rhs)                                      # [4, 3]
    return solution[:3].T.contiguous(), solution[3].contiguous()


def apply_affine_colour(image: torch.Tensor, matrix: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """image [..., 3] -> A image + b, clipped to [0, 1], in the image's dtype."""
    out = image.to(torch.float64) @ matrix.T + offset
    return out.clamp(0.0, 1.0).to(image.dtype)
