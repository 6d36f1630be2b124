"""Moment matching: Gaussians <-> covariances, and the merge of consecutive groups into parents.

Everything here is numpy float64 over flat arrays (no per-Gaussian Python). Covariances are
kept as their six distinct entries [n, 6] = (xx, xy, xz, yy, yz, zz).

The merge weight of a Gaussian is w = opacity * s_a * s_b, the product of its two largest
scales: 2 pi w is the integral of its opacity over the plane seen face-on, i.e. how much of
the screen it covers. The product of the two largest scales (a surface proxy), not of all
three (a volume proxy), because stage I trains planar Gaussians whose third scale is nearly
zero: a volume weight would give every flat splat almost no say in its parent.
"""

from __future__ import annotations

import numpy as np

from ..camera import unit_quat_to_rotation
from ..constants import LOG_SCALE_MAX, LOG_SCALE_MIN, OPACITY_LOGIT_ABS_MAX, QUAT_NORM_MIN, SIGMA_EXTENT_MAX

# A parent's opacity is W / (s_a s_b) (its weight equals its children's); it is clamped into
# [LOD_OPACITY_MIN, LOD_OPACITY_MAX] so the logit log(o / (1 - o)) is finite: the upper bound
# is below 1 (a parent of overlapping opaque children would ask for o > 1, which no Gaussian
# can give: it then keeps less weight than its children), the lower bound equals the
# smallest opacity the model's logit clamp can express.
LOD_OPACITY_MAX = 0.999
LOD_OPACITY_MIN = float(1.0 / (1.0 + np.exp(OPACITY_LOGIT_ABS_MAX)))
# Eigenvalues of a merged covariance below this (rounding can make them ~0 or slightly
# negative) are raised to it before sqrt/log: it is the variance of the smallest scale the
# rasterizer's log-scale clamp allows.
VARIANCE_MIN = float(np.exp(2.0 * LOG_SCALE_MIN))
# Group weights are floored here before dividing: w >= LOD_OPACITY_MIN * exp(2 LOG_SCALE_MIN)
# ~ 1e-39 for any model, so the floor (far below that, far above float64's tiny) only guards
# against non-finite input.
WEIGHT_MIN = 1e-300


def scales_of(log_scales: np.ndarray) -> np.ndarray:
    """[n, 3] log scales -> scales, with the rasterizer's clamp (so squares stay finite)."""
    return np.exp(np.clip(log_scales.astype(np.float64), LOG_SCALE_MIN, LOG_SCALE_MAX))


def opacities_of(logits: np.ndarray) -> np.ndarray:
    """[n] logits -> opacities in (0, 1), with the rasterizer's clamp."""
    clipped = np.clip(logits.astype(np.float64), -OPACITY_LOGIT_ABS_MAX, OPACITY_LOGIT_ABS_MAX)
    return 1.0 / (1.0 + np.exp(-clipped))


def rotations_of(quats: np.ndarray) -> np.ndarray:
    """[n, 4] (w, x, y, z), any norm -> [n, 3, 3]; near-zero quaternions become the identity
    (the rasterizer's rule), so no division by ~0."""
    q = quats.astype(np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    degenerate = ~(norm[:, 0] >= QUAT_NORM_MIN)
    q = np.where(degenerate[:, None], np.array([1.0, 0.0, 0.0, 0.0]), q / np.maximum(norm, QUAT_NORM_MIN))
    return unit_quat_to_rotation(q[:, 0], q[:, 1], q[:, 2], q[:, 3], np.stack)


def covariances_of(log_scales: np.ndarray, quats: np.ndarray) -> np.ndarray:
    """Sigma = R diag(s^2) R^T as [n, 6] (xx, xy, xz, yy, yz, zz) float64."""
    rotation = rotations_of(quats)
    variances = scales_of(log_scales) ** 2
    # Sigma_jk = sum_a R_ja R_ka s_a^2, entry by entry: numpy's batched 3x3 matmul is slow.
    return np.stack([(rotation[:, j, :] * rotation[:, k, :] * variances).sum(axis=1)
                     for j, k in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))], axis=1)


def full_matrices(cov6: np.ndarray) -> np.ndarray:
    """[n, 6] -> symmetric [n, 3, 3]."""
    xx, xy, xz, yy, yz, zz = cov6.T
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)


def surface_weights(log_scales: np.ndarray, opacity_logits: np.ndarray) -> np.ndarray:
    """[n] merge weights opacity * (product of the two largest scales); see the module doc."""
    scales = np.sort(scales_of(log_scales), axis=1)
    return opacities_of(opacity_logits) * scales[:, 1] * scales[:, 2]


def rotation_to_quats(rotations: np.ndarray) -> np.ndarray:
    """[n, 3, 3] proper rotations -> unit quaternions [n, 4] (w >= 0), Shepperd's method
    vectorised: each row pivots on its largest of (trace, m00, m11, m22), so the square root
    is of a number >= 1 and no branch divides by a small one."""
    m = rotations
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    pivot = np.argmax(np.stack([trace, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1), axis=1)
    q = np.empty((len(m), 4))
    diag_sign = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], np.float64)
    # 4 q_k^2 = 1 + sign . diag for the pivot component k; it is >= 1 at the pivot.
    s = 2.0 * np.sqrt(np.maximum(1.0 + np.einsum("nk,nk->n", diag_sign[pivot],
                                                 np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1)), 1.0))
    a = np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], 1)  # 4 w (x, y, z)
    b = np.stack([m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1]], 1)  # 4 (xy, xz, yz)
    for k in range(4):
        rows = pivot == k
        sk, ak, bk = s[rows], a[rows], b[rows]
        if k == 0:
            q[rows] = np.stack([0.25 * sk, ak[:, 0] / sk, ak[:, 1] / sk, ak[:, 2] / sk], 1)
        elif k == 1:
            q[rows] = np.stack([ak[:, 0] / sk, 0.25 * sk, bk[:, 0] / sk, bk[:, 1] / sk], 1)
        elif k == 2:
            q[rows] = np.stack([ak[:, 1] / sk, bk[:, 0] / sk, 0.25 * sk, bk[:, 2] / sk], 1)
        else:
            q[rows] = np.stack([ak[:, 2] / sk, bk[:, 1] / sk, bk[:, 2] / sk, 0.25 * sk], 1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)   # unit up to rounding: the norm is ~1
    return np.where(q[:, :1] < 0.0, -q, q)


def covariance_to_gaussian(cov6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[n, 6] covariances -> (log_scales [n, 3], quats [n, 4]) with Sigma = R diag(s^2) R^T."""
    values, vectors = np.linalg.eigh(full_matrices(cov6))   # ascending; columns are axes
    # eigh may return a reflection; flipping one axis keeps the same covariance.
    flip = np.linalg.det(vectors) < 0.0
    vectors[flip, :, 0] *= -1.0
    log_scales = 0.5 * np.log(np.maximum(values, VARIANCE_MIN))
    return log_scales, rotation_to_quats(vectors)


def bounding_radii(log_scales: np.ndarray) -> np.ndarray:
    """[n] radius of the sphere holding a Gaussian's footprint: SIGMA_EXTENT_MAX x its
    largest scale (beyond it no alpha reaches ALPHA_MIN)."""
    return SIGMA_EXTENT_MAX * scales_of(log_scales).max(axis=1)


def merge_groups(means: np.ndarray, covs: np.ndarray, weights: np.ndarray, sh: np.ndarray,
                 radii: np.ndarray, starts: np.ndarray) -> dict[str, np.ndarray]:
    """Moment-match each run ``[starts[g], starts[g+1])`` of children into one parent.

    means [n, 3], covs [n, 6] float64; weights [n] (w_i, see the module doc); sh [n, K, 3];
    radii [n] bounding radii; starts [m] ascending, starts[0] = 0. Returns for the m parents:
    means, covs, log_scales, quats, opacity_logits, sh, weights (the parent's own w after the
    opacity clamp), radii (a sphere holding every child's sphere and the parent's footprint).
    Parent mean = sum w_i mu_i / W; covariance = sum w_i (Sigma_i + d_i d_i^T) / W with
    d_i = mu_i - mu; SH = sum w_i sh_i / W; opacity = W / (s_a s_b), clamped.
    """
    group = np.repeat(np.arange(len(starts)), np.diff(np.append(starts, len(means))))
    total = np.maximum(np.add.reduceat(weights, starts), WEIGHT_MIN)   # W > 0: see WEIGHT_MIN
    share = weights / total[group]                                      # [n], sums to 1 per group
    mean = np.add.reduceat(share[:, None] * means, starts)
    offset = means - mean[group]
    spread = offset[:, [0, 0, 0, 1, 1, 2]] * offset[:, [0, 1, 2, 1, 2, 2]]
    cov = np.add.reduceat(share[:, None] * (covs + spread), starts)
    colour = np.add.reduceat(share.astype(sh.dtype)[:, None, None] * sh, starts)
    log_scales, quats = covariance_to_gaussian(cov)
    top_two = np.sort(np.exp(log_scales), axis=1)[:, 1:]
    area = top_two[:, 0] * top_two[:, 1]               # >= VARIANCE_MIN > 0: eigenvalues floored
    opacity = np.clip(total / area, LOD_OPACITY_MIN, LOD_OPACITY_MAX)
    reach = np.maximum.reduceat(np.linalg.norm(offset, axis=1) + radii, starts)
    return {
        "means": mean, "covs": cov, "log_scales": log_scales, "quats": quats,
        # opacity is inside [LOD_OPACITY_MIN, LOD_OPACITY_MAX], strictly inside (0, 1): log is finite.
        "opacity_logits": np.log(opacity / (1.0 - opacity)), "sh": colour,
        "weights": opacity * area, "radii": np.maximum(reach, bounding_radii(log_scales)),
    }
