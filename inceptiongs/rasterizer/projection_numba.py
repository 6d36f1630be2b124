"""Numba-compiled CPU fast path of :func:`inceptiongs.rasterizer.projection.project`.

Same rules, same float64 arithmetic per Gaussian, one fused loop instead of ~60 vectorised torch
ops over N (each of which streams [N, 3, 3] float64 tensors through memory, forward and
backward). At fern's 136k Gaussians: 160 ms forward + backward in torch, 45 ms here, of a ~1 s
training step (docs/training.md, "Speed"); benchmarks/bench_torch_rasterizer.py times the
renderer with every fast path ("numba") against the torch reference ("torch").

Scope (what :func:`project_numba` differentiates): ``camera_means``, ``means2d`` and ``conics``
with respect to means, log-scales and quaternions, and ``opacities`` (computed by torch, so
autograd handles the sigmoid). ``cov2d``, ``extents`` and ``radii`` carry no gradient: the
renderer uses them only to bin and to report footprints (it detaches ``extents``). A pose that
requires grad (stage II's Langevin view sampling) takes the torch path (the "auto" rule of
:mod:`inceptiongs.rasterizer.backend`, applied in :func:`inceptiongs.rasterizer.projection.project`).

The backward recomputes the forward quantities of each Gaussian (O(1) each) instead of storing
[N, 2, 3] intermediates, and hand-codes the chain rule of the torch reference, including its
clamp and where() rules: a clamped log-scale, a clamped view ratio or an out-of-range depth
passes no gradient; a degenerate quaternion (norm < QUAT_NORM_MIN) is the identity and gets none;
a culled Gaussian's conic divides by 1, not by its determinant. A row with no incoming gradient
(every Gaussian the renderer culled) gets exactly zero without the chain rule; the reference
reaches finite values there too (it feeds a non-finite centre through as the origin). Tests
compare both directions with the torch reference (tests/rasterizer/test_projection_numba.py).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange
from torch.autograd.function import once_differentiable

from ..camera import Camera
from ..constants import (ALPHA_MIN, DET_MIN, DILATION_PX, FAR_PLANE, LOG_SCALE_MAX,
                         LOG_SCALE_MIN, NEAR_PLANE, QUAT_NORM_MIN)
from .composite_numba import as_float64



# Rows per parallel task (and per scratch allocation).
_CHUNK = 1024


@njit(cache=True)
def _clamp(x, lo, hi):
    """torch.clamp: NaN stays NaN (so culling sees it as not finite)."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@njit(cache=True)
def unit_quat(q0, q1, q2, q3):
    """(w, x, y, z, norm used, degenerate) as quat_to_rotation: below QUAT_NORM_MIN the identity."""
    norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    if not (norm >= QUAT_NORM_MIN):
        return 1.0, 0.0, 0.0, 0.0, 1.0, True
    return q0 / norm, q1 / norm, q2 / norm, q3 / norm, norm, False


@njit(cache=True)
def rotation_into(w, x, y, z, r):
    """Rotation matrix of a unit quaternion into r [3, 3] (camera.unit_quat_to_rotation's formula)."""
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def _screen_rows(pose, rotation, scales, jxx, jxz, jyy, jyz, a, m0, m1):
    """a = W R diag(s) [3, 3]; m0, m1: the rows of M = J a [2, 3] (J has zeros at xy and yx)."""
    for i in range(3):
        for j in range(3):
            a[i, j] = (pose[i, 0] * rotation[0, j] + pose[i, 1] * rotation[1, j]
                       + pose[i, 2] * rotation[2, j]) * scales[j]
    for j in range(3):
        m0[j] = jxx * a[0, j] + jxz * a[2, j]
        m1[j] = jyy * a[1, j] + jyz * a[2, j]


@njit(cache=True)
def _screen_geometry(i, means, log_scales, quats, pose, fx, fy, bounds, t, rotation, scales, a, m0, m1):
    """Row i's geometry, shared by the forward and the backward so both see the same numbers.

    Fills t (camera-space centre), rotation, scales, a = W R diag(s) and the rows m0, m1 of
    M = J a. Returns (in_range, z, ratio_x, ratio_y, clamped_x, clamped_y, unit quaternion
    w, x, y, z, its norm, degenerate, Jacobian entries jxx, jxz, jyy, jyz, xx, xy, yy (dilated),
    u = m0 x m1, det)."""
    lo_x, hi_x, lo_y, hi_y = bounds
    for k in range(3):
        t[k] = pose[k, 0] * means[i, 0] + pose[k, 1] * means[i, 1] + pose[k, 2] * means[i, 2] + pose[k, 3]
    z32 = np.float32(t[2])
    in_range = z32 >= NEAR_PLANE and z32 <= FAR_PLANE
    z = t[2] if in_range else 1.0
    ratio_x = t[0] / z
    ratio_y = t[1] / z
    clamped_x = _clamp(ratio_x, lo_x, hi_x)
    clamped_y = _clamp(ratio_y, lo_y, hi_y)
    w, x, y, zq, qnorm, degenerate = unit_quat(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3])
    rotation_into(w, x, y, zq, rotation)
    for j in range(3):
        scales[j] = math.exp(_clamp(log_scales[i, j], LOG_SCALE_MIN, LOG_SCALE_MAX))
    jxx, jxz, jyy, jyz = fx / z, -fx * clamped_x / z, fy / z, -fy * clamped_y / z
    _screen_rows(pose, rotation, scales, jxx, jxz, jyy, jyz, a, m0, m1)
    xx = m0[0] * m0[0] + m0[1] * m0[1] + m0[2] * m0[2]
    xy = m0[0] * m1[0] + m0[1] * m1[1] + m0[2] * m1[2]
    yy = m1[0] * m1[0] + m1[1] * m1[1] + m1[2] * m1[2]
    u0 = m0[1] * m1[2] - m0[2] * m1[1]
    u1 = m0[2] * m1[0] - m0[0] * m1[2]
    u2 = m0[0] * m1[1] - m0[1] * m1[0]
    # Lagrange identity, as the reference: never negative, no xx*yy - xy^2 cancellation.
    det = (u0 * u0 + u1 * u1 + u2 * u2) + DILATION_PX * (xx + yy) + DILATION_PX * DILATION_PX
    return (in_range, z, ratio_x, ratio_y, clamped_x, clamped_y, w, x, y, zq, qnorm, degenerate,
            jxx, jxz, jyy, jyz, xx + DILATION_PX, xy, yy + DILATION_PX, u0, u1, u2, det)


@njit(parallel=True, cache=True)
def _forward_kernel(means, log_scales, quats, opacities, alpha_min, pose, fx, fy, cx, cy, width, height, bounds,
                    t_out, means2d, cov2d, conics, extents, visible, radii):
    n = means.shape[0]
    for chunk in prange((n + _CHUNK - 1) // _CHUNK):
        # Scratch per chunk of rows: allocating it per row costs more than the arithmetic.
        rotation = np.empty((3, 3))
        a = np.empty((3, 3))
        scales = np.empty(3)
        m0 = np.empty(3)
        m1 = np.empty(3)
        t = np.empty(3)
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            (in_range, _, ratio_x, ratio_y, _, _, _, _, _, _, _, _, _, _, _, _, xx, xy, yy, _, _, _,
             det) = _screen_geometry(i, means, log_scales, quats, pose, fx, fy, bounds, t, rotation, scales, a, m0, m1)
            for k in range(3):
                t_out[i, k] = t[k]
            mx = fx * ratio_x + cx
            my = fy * ratio_y + cy
            means2d[i, 0] = mx
            means2d[i, 1] = my
            cov2d[i, 0] = xx
            cov2d[i, 1] = xy
            cov2d[i, 2] = yy
            opacity = opacities[i]
            # log(0) = -inf and log(<0) = NaN as numpy gives them; max() keeps NaN out of the clamp
            # only where the reference would (clamp_min(NaN) is NaN), so test it explicitly.
            if opacity > 0.0:
                level = max(math.log(opacity / ALPHA_MIN), 0.0)
            elif opacity == 0.0:
                level = 0.0
            else:
                level = math.nan
            ext_x = math.sqrt(2.0 * level * xx) if 2.0 * level * xx >= 0.0 else math.nan
            ext_y = math.sqrt(2.0 * level * yy) if 2.0 * level * yy >= 0.0 else math.nan
            extents[i, 0] = ext_x
            extents[i, 1] = ext_y
            keep = (in_range and det >= DET_MIN and math.isfinite(det) and opacity >= alpha_min
                    and math.isfinite(mx) and math.isfinite(my) and math.isfinite(ext_x) and math.isfinite(ext_y)
                    and mx + ext_x > 0.0 and mx - ext_x < width and my + ext_y > 0.0 and my - ext_y < height)
            visible[i] = keep
            safe_det = det if keep else 1.0
            conics[i, 0] = yy / safe_det
            conics[i, 1] = -xy / safe_det
            conics[i, 2] = xx / safe_det
            radii[i] = int(math.ceil(max(ext_x, ext_y))) if keep else 0


@njit(parallel=True, cache=True)
def _backward_kernel(means, log_scales, quats, visible, pose, fx, fy, bounds,
                     g_t, g_means2d, g_conics, g_means, g_log_scales, g_quats):
    """d loss / d (means, log_scales, quats) from d loss / d (t, means2d, conics), by row."""
    n = means.shape[0]
    lo_x, hi_x, lo_y, hi_y = bounds
    for chunk in prange((n + _CHUNK - 1) // _CHUNK):
        # Scratch per chunk of rows: allocating it per row costs more than the arithmetic.
        rotation = np.empty((3, 3))
        a = np.empty((3, 3))
        scales = np.empty(3)
        m0 = np.empty(3)
        m1 = np.empty(3)
        t = np.empty(3)
        ga_rows = np.empty((3, 3))
        g_rot = np.empty((3, 3))
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            if (g_t[i, 0] == 0.0 and g_t[i, 1] == 0.0 and g_t[i, 2] == 0.0 and g_means2d[i, 0] == 0.0
                    and g_means2d[i, 1] == 0.0 and g_conics[i, 0] == 0.0 and g_conics[i, 1] == 0.0
                    and g_conics[i, 2] == 0.0):
                # Nothing flows in (the renderer culled it): zero, without the chain rule, so a
                # culled row with a non-finite mean cannot turn 0 * inf into NaN.
                for k in range(3):
                    g_means[i, k] = 0.0
                    g_log_scales[i, k] = 0.0
                for k in range(4):
                    g_quats[i, k] = 0.0
                continue
            (in_range, z, ratio_x, ratio_y, clamped_x, clamped_y, w, x, y, zq, qnorm, degenerate,
             jxx, jxz, jyy, jyz, xx, xy, yy, u0, u1, u2, det) = _screen_geometry(
                i, means, log_scales, quats, pose, fx, fy, bounds, t, rotation, scales, a, m0, m1)

            # conics = (yy, -xy, xx) / safe_det; safe_det = det on visible rows, else the constant 1.
            ga, gb, gc = g_conics[i, 0], g_conics[i, 1], g_conics[i, 2]
            safe_det = det if visible[i] else 1.0
            g_yy = ga / safe_det
            g_xy = -gb / safe_det
            g_xx = gc / safe_det
            g_det = -(ga * yy - gb * xy + gc * xx) / (safe_det * safe_det) if visible[i] else 0.0
            # det = |u|^2 + D (xx0 + yy0) + D^2, xx = xx0 + D, yy = yy0 + D
            g_xx += DILATION_PX * g_det
            g_yy += DILATION_PX * g_det
            gu0, gu1, gu2 = 2.0 * g_det * u0, 2.0 * g_det * u1, 2.0 * g_det * u2
            # u = m0 x m1: d/dm0 = m1 x gu, d/dm1 = gu x m0; xx0 = m0.m0, yy0 = m1.m1, xy = m0.m1.
            gm0_0 = (m1[1] * gu2 - m1[2] * gu1) + 2.0 * g_xx * m0[0] + g_xy * m1[0]
            gm0_1 = (m1[2] * gu0 - m1[0] * gu2) + 2.0 * g_xx * m0[1] + g_xy * m1[1]
            gm0_2 = (m1[0] * gu1 - m1[1] * gu0) + 2.0 * g_xx * m0[2] + g_xy * m1[2]
            gm1_0 = (gu1 * m0[2] - gu2 * m0[1]) + 2.0 * g_yy * m1[0] + g_xy * m0[0]
            gm1_1 = (gu2 * m0[0] - gu0 * m0[2]) + 2.0 * g_yy * m1[1] + g_xy * m0[1]
            gm1_2 = (gu0 * m0[1] - gu1 * m0[0]) + 2.0 * g_yy * m1[2] + g_xy * m0[2]
            # M = J a: dJ = dM a^T, da = J^T dM.
            g_jxx = gm0_0 * a[0, 0] + gm0_1 * a[0, 1] + gm0_2 * a[0, 2]
            g_jxz = gm0_0 * a[2, 0] + gm0_1 * a[2, 1] + gm0_2 * a[2, 2]
            g_jyy = gm1_0 * a[1, 0] + gm1_1 * a[1, 1] + gm1_2 * a[1, 2]
            g_jyz = gm1_0 * a[2, 0] + gm1_1 * a[2, 1] + gm1_2 * a[2, 2]
            for j in range(3):
                gmj0 = gm0_0 if j == 0 else (gm0_1 if j == 1 else gm0_2)
                gmj1 = gm1_0 if j == 0 else (gm1_1 if j == 1 else gm1_2)
                ga_rows[0, j] = jxx * gmj0
                ga_rows[1, j] = jyy * gmj1
                ga_rows[2, j] = jxz * gmj0 + jyz * gmj1
            # a = W B with B = R diag(s): dB = W^T da; dR_kj = dB_kj s_j; ds_j = sum_k dB_kj R_kj.
            for j in range(3):
                g_s = 0.0
                for k in range(3):
                    g_b = pose[0, k] * ga_rows[0, j] + pose[1, k] * ga_rows[1, j] + pose[2, k] * ga_rows[2, j]
                    g_rot[k, j] = g_b * scales[j]
                    g_s += g_b * rotation[k, j]
                ls = log_scales[i, j]
                g_log_scales[i, j] = g_s * scales[j] if (ls >= LOG_SCALE_MIN and ls <= LOG_SCALE_MAX) else 0.0
            if degenerate:
                for k in range(4):
                    g_quats[i, k] = 0.0
            else:
                gw = 2.0 * (-zq * g_rot[0, 1] + y * g_rot[0, 2] + zq * g_rot[1, 0] - x * g_rot[1, 2]
                            - y * g_rot[2, 0] + x * g_rot[2, 1])
                gx = 2.0 * (y * g_rot[0, 1] + zq * g_rot[0, 2] + y * g_rot[1, 0] - 2.0 * x * g_rot[1, 1]
                            - w * g_rot[1, 2] + zq * g_rot[2, 0] + w * g_rot[2, 1] - 2.0 * x * g_rot[2, 2])
                gy = 2.0 * (-2.0 * y * g_rot[0, 0] + x * g_rot[0, 1] + w * g_rot[0, 2] + x * g_rot[1, 0]
                            + zq * g_rot[1, 2] - w * g_rot[2, 0] + zq * g_rot[2, 1] - 2.0 * y * g_rot[2, 2])
                gz = 2.0 * (-2.0 * zq * g_rot[0, 0] - w * g_rot[0, 1] + x * g_rot[0, 2] + w * g_rot[1, 0]
                            - 2.0 * zq * g_rot[1, 1] + y * g_rot[1, 2] + x * g_rot[2, 0] + y * g_rot[2, 1])
                # unit = q / |q|: d q = (d unit - unit (unit . d unit)) / |q|
                dot = w * gw + x * gx + y * gy + zq * gz
                g_quats[i, 0] = (gw - w * dot) / qnorm
                g_quats[i, 1] = (gx - x * dot) / qnorm
                g_quats[i, 2] = (gy - y * dot) / qnorm
                g_quats[i, 3] = (gz - zq * dot) / qnorm

            # J = [[fx/z, 0, -fx cx'/z], [0, fy/z, -fy cy'/z]], cx' = clamp(t.x / z); means2d = f t/z + c.
            g_clamped_x = -fx / z * g_jxz
            g_clamped_y = -fy / z * g_jyz
            g_ratio_x = fx * g_means2d[i, 0] + (g_clamped_x if (ratio_x >= lo_x and ratio_x <= hi_x) else 0.0)
            g_ratio_y = fy * g_means2d[i, 1] + (g_clamped_y if (ratio_y >= lo_y and ratio_y <= hi_y) else 0.0)
            g_z = (-(fx * g_jxx + fy * g_jyy) / (z * z) + fx * clamped_x / (z * z) * g_jxz
                   + fy * clamped_y / (z * z) * g_jyz - (g_ratio_x * t[0] + g_ratio_y * t[1]) / (z * z))
            gt0 = g_t[i, 0] + g_ratio_x / z
            gt1 = g_t[i, 1] + g_ratio_y / z
            gt2 = g_t[i, 2] + (g_z if in_range else 0.0)
            for k in range(3):
                g_means[i, k] = pose[0, k] * gt0 + pose[1, k] * gt1 + pose[2, k] * gt2


class _ProjectFunction(torch.autograd.Function):
    """Outputs t [N, 3], means2d [N, 2], conics [N, 3] (differentiable) and cov2d [N, 3],
    extents [N, 2], visible [N], radii [N] (not), in the model's dtype (visible bool, radii int64)."""

    @staticmethod
    def forward(ctx, means, log_scales, quats, opacities, pose, camera, bounds):
        n = means.shape[0]
        arrays = (as_float64(means), as_float64(log_scales), as_float64(quats))
        pose64 = np.ascontiguousarray(pose, dtype=np.float64)
        fx, fy = float(camera.fx), float(camera.fy)
        bounds = tuple(float(b) for b in bounds)
        t = np.empty((n, 3))
        means2d = np.empty((n, 2))
        cov2d = np.empty((n, 3))
        conics = np.empty((n, 3))
        extents = np.empty((n, 2))
        visible = np.empty(n, np.bool_)
        radii = np.empty(n, np.int64)
        # The reference compares opacities in their own dtype with ALPHA_MIN rounded to it.
        alpha_min = float(torch.tensor(ALPHA_MIN, dtype=opacities.dtype))
        _forward_kernel(*arrays, as_float64(opacities), alpha_min, pose64, fx, fy, float(camera.cx), float(camera.cy),
                        int(camera.width), int(camera.height), bounds, t, means2d, cov2d, conics, extents, visible,
                        radii)
        ctx.state = (arrays, pose64, fx, fy, bounds, visible)
        ctx.dtypes = (means.dtype, log_scales.dtype, quats.dtype)
        dtype, device = means.dtype, means.device
        outputs = [torch.from_numpy(a).to(device=device, dtype=dtype) for a in (t, means2d, conics, cov2d, extents)]
        outputs += [torch.from_numpy(visible).to(device), torch.from_numpy(radii).to(device)]
        ctx.mark_non_differentiable(*outputs[3:])
        return tuple(outputs)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_t, g_means2d, g_conics, *_unused):
        arrays, pose64, fx, fy, bounds, visible = ctx.state
        n = arrays[0].shape[0]

        def incoming(grad, columns):
            return np.zeros((n, columns)) if grad is None else as_float64(grad)

        g_means = np.empty((n, 3))
        g_log_scales = np.empty((n, 3))
        g_quats = np.empty((n, 4))
        _backward_kernel(*arrays, visible, pose64, fx, fy, bounds, incoming(g_t, 3), incoming(g_means2d, 2),
                         incoming(g_conics, 3), g_means, g_log_scales, g_quats)
        needs = ctx.needs_input_grad
        device = (g_t if g_t is not None else g_means2d if g_means2d is not None else g_conics).device
        grads = [torch.from_numpy(g).to(device=device, dtype=dtype) if need else None
                 for g, dtype, need in zip((g_means, g_log_scales, g_quats), ctx.dtypes, needs[:3])]
        return (*grads, None, None, None, None)


def project_numba(means: torch.Tensor, log_scales: torch.Tensor, quats: torch.Tensor, opacities: torch.Tensor,
                  world_to_camera: np.ndarray, camera: Camera, bounds: tuple[float, float, float, float]):
    """The projection of N Gaussians (means [N, 3], log_scales [N, 3], quats [N, 4]; opacities [N]
    already activated, used only to size footprints and cull) through a fixed pose
    world_to_camera [4, 4] (no gradient) and ``camera``'s intrinsics; ``bounds`` are the view
    ratios the Jacobian is clamped to (projection.view_ratio_bounds).

    Returns (t, means2d, conics, cov2d, extents, visible, radii) as in
    :class:`inceptiongs.rasterizer.projection.Projection`; only the first three are differentiable."""
    return _ProjectFunction.apply(means, log_scales, quats, opacities.detach(), world_to_camera, camera, bounds)
