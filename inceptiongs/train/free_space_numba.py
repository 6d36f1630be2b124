"""Numba fast paths of the two [N, C] free-space tests (:mod:`.free_space`, whose torch versions are
the reference): every Gaussian against every training camera.

A loop per Gaussian over the cameras that stops at the first camera that flags it reads each
Gaussian once and writes one flag; the torch versions stream several [N, C] float64 tables
through memory (at 100k Gaussians and 200 cameras, ~0.3 s and ~1.4 s against tens of
milliseconds here, every maintenance step). The per-pair arithmetic is the reference's:
inputs are the same float64 values and each test is the same expression, so results agree
except where a value lands within rounding of a threshold.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..constants import LOG_SCALE_MAX, LOG_SCALE_MIN
from ..rasterizer.projection_numba import rotation_into, unit_quat


@njit(parallel=True, cache=True)
def _before_near_bound_kernel(means, rotations, translations, near, intrinsics, out):
    """means [N, 3]; rotations [C, 3, 3], translations [C, 3] (world to camera); near [C];
    intrinsics [C, 6] (fx, fy, cx, cy, width, height); writes out [N] bool."""
    for n in prange(means.shape[0]):
        mx = means[n, 0]
        my = means[n, 1]
        mz = means[n, 2]
        for c in range(rotations.shape[0]):
            z = rotations[c, 2, 0] * mx + rotations[c, 2, 1] * my + rotations[c, 2, 2] * mz + translations[c, 2]
            if not (z > 0.0 and z < near[c]):  # also False for NaN
                continue
            x = rotations[c, 0, 0] * mx + rotations[c, 0, 1] * my + rotations[c, 0, 2] * mz + translations[c, 0]
            y = rotations[c, 1, 0] * mx + rotations[c, 1, 1] * my + rotations[c, 1, 2] * mz + translations[c, 1]
            u = intrinsics[c, 0] * x / z + intrinsics[c, 2]   # z > 0 here
            v = intrinsics[c, 1] * y / z + intrinsics[c, 3]
            if u >= 0.0 and u < intrinsics[c, 4] and v >= 0.0 and v < intrinsics[c, 5]:
                out[n] = True
                break


@njit(parallel=True, cache=True)
def _contains_camera_kernel(means, log_scales, quats, centers, sigmas, out):
    """means [N, 3], log_scales [N, 3], quats [N, 4] (w, x, y, z), centers [C, 3]; writes
    out [N] bool: some centre within ``sigmas`` Mahalanobis of the Gaussian."""
    limit = sigmas * sigmas
    for n in prange(means.shape[0]):
        s0 = min(max(log_scales[n, 0], LOG_SCALE_MIN), LOG_SCALE_MAX)  # clamped: exp stays finite
        s1 = min(max(log_scales[n, 1], LOG_SCALE_MIN), LOG_SCALE_MAX)
        s2 = min(max(log_scales[n, 2], LOG_SCALE_MIN), LOG_SCALE_MAX)
        # The Mahalanobis distance is at least |d| / (largest scale): farther centres are skipped
        # before the rotation is built. The pre-test is widened far beyond its rounding error.
        reach_sq = (sigmas * math.exp(max(s0, max(s1, s2)))) ** 2 * (1.0 + 1e-9)
        rotation = np.empty((0, 0))   # built at the first centre within reach (most have none)
        rotation_ready = False
        for c in range(centers.shape[0]):
            d0 = centers[c, 0] - means[n, 0]
            d1 = centers[c, 1] - means[n, 1]
            d2 = centers[c, 2] - means[n, 2]
            if not (d0 * d0 + d1 * d1 + d2 * d2 < reach_sq):  # also skips NaN
                continue
            if not rotation_ready:  # the renderer's rotation (a too-short quaternion: the identity)
                w, x, y, z, _, _ = unit_quat(quats[n, 0], quats[n, 1], quats[n, 2], quats[n, 3])
                rotation = np.empty((3, 3))
                rotation_into(w, x, y, z, rotation)
                rotation_ready = True
            # (R^T d) / s
            l0 = (rotation[0, 0] * d0 + rotation[1, 0] * d1 + rotation[2, 0] * d2) * math.exp(-s0)
            l1 = (rotation[0, 1] * d0 + rotation[1, 1] * d1 + rotation[2, 1] * d2) * math.exp(-s1)
            l2 = (rotation[0, 2] * d0 + rotation[1, 2] * d1 + rotation[2, 2] * d2) * math.exp(-s2)
            if l0 * l0 + l1 * l1 + l2 * l2 < limit:
                out[n] = True
                break


def before_near_bound_numba(means: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                            near: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """float64 means [N, 3], rotations [C, 3, 3], translations [C, 3], near [C], intrinsics
    [C, 6] (fx, fy, cx, cy, width, height) -> [N] bool (see free_space.before_near_bound)."""
    out = np.zeros(means.shape[0], np.bool_)
    _before_near_bound_kernel(means, rotations, translations, near, intrinsics, out)
    return out


def contains_camera_numba(means: np.ndarray, log_scales: np.ndarray, quats: np.ndarray, centers: np.ndarray,
                          sigmas: float) -> np.ndarray:
    """float64 means [N, 3], log_scales [N, 3], quats [N, 4], centers [C, 3] -> [N] bool
    (see free_space.contains_camera)."""
    out = np.zeros(means.shape[0], np.bool_)
    _contains_camera_kernel(means, log_scales, quats, centers, float(sigmas), out)
    return out
