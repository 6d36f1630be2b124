"""Numba fast paths of the three [N, C] free-space tests (:mod:`.free_space`, whose torch versions
are the reference): every Gaussian against every training camera.

Each test flags a Gaussian only within a bounded distance of a camera centre (its ``reach``:
the near bound widened by the image's corner ray, the camera ball, the Gaussian's own 3-sigma
extent), so the loops visit only the cameras whose centre's x lies within that reach of the
Gaussian's x: the cameras are sorted by x once per call and two binary searches find the window
(bench_free_space: 2,625 cameras along a street, 8 s -> 0.2 s a call at 200,000 Gaussians).

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


@njit(cache=True)
def _window(sorted_x, x, reach):                              # pragma: no cover - compiled
    """(first, last): the range of ascending ``sorted_x`` within ``reach`` of ``x`` (empty for a
    NaN x: both searches land past the end)."""
    return np.searchsorted(sorted_x, x - reach), np.searchsorted(sorted_x, x + reach, side="right")


@njit(parallel=True, cache=True)
def _before_near_bound_kernel(means, rotations, translations, near, intrinsics, centre_x, reach, out):
    """means [N, 3]; rotations [C, 3, 3], translations [C, 3] (world to camera); near [C];
    intrinsics [C, 6] (fx, fy, cx, cy, width, height); centre_x [C] ascending (the cameras sorted
    by it); reach: no camera flags a Gaussian farther than this from its centre; writes out [N] bool."""
    for n in prange(means.shape[0]):
        mx = means[n, 0]
        my = means[n, 1]
        mz = means[n, 2]
        first, last = _window(centre_x, mx, reach)
        for c in range(first, last):
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
    """means [N, 3], log_scales [N, 3], quats [N, 4] (w, x, y, z), centers [C, 3] sorted by x;
    writes out [N] bool: some centre within ``sigmas`` Mahalanobis of the Gaussian."""
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
        # Only centres within sqrt(reach_sq) of the mean in x can pass the pre-test below.
        first, last = _window(centers[:, 0], means[n, 0], math.sqrt(reach_sq) * (1.0 + 1e-9))
        for c in range(first, last):
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


@njit(parallel=True, cache=True)
def _near_a_camera_kernel(means, centers, radii, reach, out):
    """means [N, 3], centers [C, 3] sorted by x, radii [C], reach >= every radius; writes out [N]
    bool: the centre lies closer than some camera's radius to that camera's centre."""
    for n in prange(means.shape[0]):
        first, last = _window(centers[:, 0], means[n, 0], reach)
        for c in range(first, last):
            d0 = means[n, 0] - centers[c, 0]
            d1 = means[n, 1] - centers[c, 1]
            d2 = means[n, 2] - centers[c, 2]
            if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) < radii[c]:   # False for NaN
                out[n] = True
                break


def near_a_camera_numba(means: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """float64 means [N, 3], centers [C, 3], radii [C] -> [N] bool (see free_space.near_a_camera)."""
    out = np.zeros(means.shape[0], np.bool_)
    if means.shape[0] == 0 or centers.shape[0] == 0:
        return out
    order = np.argsort(centers[:, 0], kind="stable")
    _near_a_camera_kernel(means, np.ascontiguousarray(centers[order]), np.ascontiguousarray(radii[order]),
                          window_half_width(radii), out)
    return out


def before_near_bound_numba(means: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                            near: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """float64 means [N, 3], rotations [C, 3, 3], translations [C, 3], near [C], intrinsics
    [C, 6] (fx, fy, cx, cy, width, height) -> [N] bool (see free_space.before_near_bound)."""
    out = np.zeros(means.shape[0], np.bool_)
    if means.shape[0] == 0 or rotations.shape[0] == 0:
        return out
    # A flagged centre has 0 < z < near and projects inside the image, so |x| / z and |y| / z are
    # at most the image's widest half-angles' tangents: it lies within near x sqrt(1 + a^2 + b^2)
    # of the camera centre (-R^T t).
    fx, fy, cx, cy, width, height = intrinsics.T
    a = np.maximum(np.abs(cx), np.abs(width - cx)) / np.abs(fx)
    b = np.maximum(np.abs(cy), np.abs(height - cy)) / np.abs(fy)
    reach = near * np.sqrt(1.0 + a * a + b * b)
    centre_x = -np.einsum("cij,ci->cj", rotations, translations)[:, 0]
    order = np.argsort(centre_x, kind="stable")
    _before_near_bound_kernel(means, *(np.ascontiguousarray(t[order]) for t in (rotations, translations, near,
                                                                               intrinsics, centre_x)),
                              window_half_width(reach), out)
    return out


def window_half_width(reach: np.ndarray) -> float:
    """The cameras' window half-width from their reaches [C]: the largest, widened far past the
    rounding of the distances it bounds (a rotation orthonormal only to float32 precision
    included), so it may only let extra cameras into the exact test; infinite (every camera)
    when a reach is not finite."""
    if not np.isfinite(reach).all():
        return np.inf
    return float(reach.max()) * (1.0 + 1e-5) + 1e-9


def contains_camera_numba(means: np.ndarray, log_scales: np.ndarray, quats: np.ndarray, centers: np.ndarray,
                          sigmas: float) -> np.ndarray:
    """float64 means [N, 3], log_scales [N, 3], quats [N, 4], centers [C, 3] -> [N] bool
    (see free_space.contains_camera)."""
    out = np.zeros(means.shape[0], np.bool_)
    if means.shape[0] == 0 or centers.shape[0] == 0:
        return out
    centers = np.ascontiguousarray(centers[np.argsort(centers[:, 0], kind="stable")])
    _contains_camera_kernel(means, log_scales, quats, centers, float(sigmas), out)
    return out
