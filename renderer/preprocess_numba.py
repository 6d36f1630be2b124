"""The preprocess pass of ``shaders/splat_preprocess.vert`` on the CPU cores, for the CPU
compositing (software GL).

On llvmpipe the shader pass needs the packed Gaussians uploaded into a texture and its output
read back: for the 3.7M splats of a settled 5M overview, 0.58 s of upload before a 0.55 s pass,
and three copies of 64 bytes a splat in memory (the packed texture, the output buffer, its
read-back). Here the same rules run in parallel on the packed texels the CPU already holds,
straight into the array the compositor reads (about as fast as llvmpipe's pass, with neither
the upload nor the copies). Arithmetic is float64 (the shader's is float32), rounded to float32 on output; the
rules, their order and the constants are the shader's, so the outputs agree to float32
rounding and a Gaussian is culled by both or neither except within rounding of a threshold
(tests/renderer/test_preprocess_numba.py compares them on the same texels).

Output per Gaussian, as the shader's transform feedback writes it: [screen x, y, major axis
x, y], [conic a, b, c, opacity (0: culled)], [value rgb, camera z], [minor axis x, y, 0, 0].
"""

from __future__ import annotations

import functools
import math
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit

from inceptiongs.constants import (ALPHA_MIN, DET_MIN, DILATION_PX, FAR_PLANE, FRUSTUM_CLAMP_MARGIN,
                                   LOG_SCALE_MAX, LOG_SCALE_MIN, NEAR_PLANE, OPACITY_LOGIT_ABS_MAX,
                                   QUAT_NORM_MIN, SH_OFFSET)

from inceptiongs.rasterizer.sh_numba import basis_into

from .layout import BASE_TEXELS, MODES

MODE_RGB, MODE_NORMAL = MODES["rgb"], MODES["normal"]
# A thread's smallest share of a frame (fewer Gaussians run on the calling thread alone).
MIN_SHARE = 16_384
# Below this the view direction of a mean at the camera centre is not normalised (the shader's 1e-30).
_DIRECTION_MIN = 1e-30


@njit(cache=True)
def _sh_channel(texels, g, coefficients, basis, channel):
    """One channel of the SH colour + SH_OFFSET, clamped at 0: the basis against the packed
    coefficients (channel-interleaved: coefficient k's r, g, b in a row)."""
    v = 0.0
    for k in range(coefficients):
        flat = 3 * k + channel
        v += basis[k] * np.float64(texels[g, BASE_TEXELS + flat // 4, flat % 4])
    return max(v + SH_OFFSET, 0.0)


@njit(cache=True)
def _turn(rotation, row, a0, a1, a2):
    return rotation[row, 0] * a0 + rotation[row, 1] * a1 + rotation[row, 2] * a2


@njit(cache=True)
def _axes(w, x, y, z):
    """The rotation of the quaternion (w, x, y, z) as its three columns (the Gaussian's axes in
    the model frame), flattened; the norm is clamped, so a zero quaternion is the identity."""
    w, x, y, z = np.float64(w), np.float64(x), np.float64(y), np.float64(z)
    norm = max(math.sqrt(w * w + x * x + y * y + z * z), QUAT_NORM_MIN)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
            2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
            2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))


@njit(cache=True)
def _footprint_axes(a, b, c, det, level):
    """The footprint ellipse's major axis (unit u0, u1) and its semi-axes sqrt(level * lambda)
    from the eigenvalues of the dilated cov2d [[a, b], [b, c]] (det its determinant)."""
    lambda1 = 0.5 * (a + c) + math.sqrt(max(0.25 * (a - c) * (a - c) + b * b, 0.0))
    lambda2 = det / lambda1   # lambda1 >= DILATION_PX > 0
    u0, u1 = (lambda1 - c, b) if a >= c else (b, lambda1 - a)
    length = math.sqrt(u0 * u0 + u1 * u1)
    if length > 0.0:
        u0, u1 = u0 / length, u1 / length
    else:
        u0, u1 = 1.0, 0.0   # a circle: any axis
    return u0, u1, math.sqrt(level * lambda1), math.sqrt(level * max(lambda2, 0.0))


@njit(cache=True)
def _screen_covariance(ax0, ax1, ax2, ay0, ay1, ay2, az0, az1, az2, j00, j11, j02, j12):
    """The dilated cov2d (a, b, c) and its determinant from the scaled axes in the camera frame
    (a*, columns of W R diag(s)) and the EWA Jacobian's entries [[j00, 0, j02], [0, j11, j12]]
    (at the frustum-clamped mean)."""
    # Rows of T = J W R diag(s) (2 x 3): cov2d before dilation = T T^T.
    r00, r01, r02 = j00 * ax0 + j02 * ax2, j00 * ay0 + j02 * ay2, j00 * az0 + j02 * az2
    r10, r11, r12 = j11 * ax1 + j12 * ax2, j11 * ay1 + j12 * ay2, j11 * az1 + j12 * az2
    xx = r00 * r00 + r01 * r01 + r02 * r02
    xy = r00 * r10 + r01 * r11 + r02 * r12
    yy = r10 * r10 + r11 * r11 + r12 * r12
    # det(T T^T) by the Lagrange identity (never negative), then the dilation.
    c0, c1, c2 = r01 * r12 - r02 * r11, r02 * r10 - r00 * r12, r00 * r11 - r01 * r10
    det = c0 * c0 + c1 * c1 + c2 * c2 + DILATION_PX * (xx + yy) + DILATION_PX * DILATION_PX
    return xx + DILATION_PX, xy, yy + DILATION_PX, det


@njit(fastmath=False, cache=True, nogil=True)
def _preprocess_range(texels, start, stop, degree, rotation, translation, center, intrinsics, size, mode,
                      splat_scale, out):
    """Gaussians [start, stop) into out; no interpreter lock held, so threads split a frame."""
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    width, height = size[0], size[1]
    # The Jacobian's view ratios clamped to the field of view widened by FRUSTUM_CLAMP_MARGIN.
    widen_x = (FRUSTUM_CLAMP_MARGIN - 1.0) * 0.5 * width / fx
    widen_y = (FRUSTUM_CLAMP_MARGIN - 1.0) * 0.5 * height / fy
    lo_x, hi_x = -cx / fx - widen_x, (width - cx) / fx + widen_x
    lo_y, hi_y = -cy / fy - widen_y, (height - cy) / fy + widen_y
    basis = np.zeros(16)   # the SH basis of the Gaussian at hand
    for g in range(start, stop):
        for r in range(4):
            for c in range(4):
                out[g, r, c] = 0.0   # culled unless written below
        m0, m1, m2 = np.float64(texels[g, 0, 0]), np.float64(texels[g, 0, 1]), np.float64(texels[g, 0, 2])
        t0 = _turn(rotation, 0, m0, m1, m2) + translation[0]
        t1 = _turn(rotation, 1, m0, m1, m2) + translation[1]
        t2 = _turn(rotation, 2, m0, m1, m2) + translation[2]
        if not (t2 >= NEAR_PLANE and t2 <= FAR_PLANE):
            continue   # also rejects NaN
        logit = min(max(np.float64(texels[g, 0, 3]), -OPACITY_LOGIT_ABS_MAX), OPACITY_LOGIT_ABS_MAX)
        opacity = 1.0 / (1.0 + math.exp(-logit))
        if opacity < ALPHA_MIN:
            continue
        l0 = min(max(np.float64(texels[g, 1, 0]), LOG_SCALE_MIN), LOG_SCALE_MAX)
        l1 = min(max(np.float64(texels[g, 1, 1]), LOG_SCALE_MIN), LOG_SCALE_MAX)
        l2 = min(max(np.float64(texels[g, 1, 2]), LOG_SCALE_MIN), LOG_SCALE_MAX)
        s0, s1, s2 = math.exp(l0) * splat_scale, math.exp(l1) * splat_scale, math.exp(l2) * splat_scale
        x0, x1, x2, y0, y1, y2, z0, z1, z2 = _axes(texels[g, 2, 0], texels[g, 2, 1], texels[g, 2, 2], texels[g, 2, 3])
        # The axes turned into the camera frame (the normal mode's candidates too).
        wx0, wx1, wx2 = _turn(rotation, 0, x0, x1, x2), _turn(rotation, 1, x0, x1, x2), _turn(rotation, 2, x0, x1, x2)
        wy0, wy1, wy2 = _turn(rotation, 0, y0, y1, y2), _turn(rotation, 1, y0, y1, y2), _turn(rotation, 2, y0, y1, y2)
        wz0, wz1, wz2 = _turn(rotation, 0, z0, z1, z2), _turn(rotation, 1, z0, z1, z2), _turn(rotation, 2, z0, z1, z2)
        inv_z = 1.0 / t2   # t.z >= NEAR_PLANE > 0
        a, b, c, det = _screen_covariance(wx0 * s0, wx1 * s0, wx2 * s0, wy0 * s1, wy1 * s1, wy2 * s1,
                                          wz0 * s2, wz1 * s2, wz2 * s2, fx * inv_z, fy * inv_z,
                                          -fx * t2 * min(max(t0 * inv_z, lo_x), hi_x) * inv_z * inv_z,
                                          -fy * t2 * min(max(t1 * inv_z, lo_y), hi_y) * inv_z * inv_z)
        if not (det >= DET_MIN) or math.isinf(det):
            continue
        mx, my = fx * t0 * inv_z + cx, fy * t1 * inv_z + cy
        level = 2.0 * math.log(opacity / ALPHA_MIN)   # opacity >= ALPHA_MIN: level >= 0
        ex, ey = math.sqrt(level * a), math.sqrt(level * c)
        if mx + ex <= 0.0 or mx - ex >= width or my + ey <= 0.0 or my - ey >= height:
            continue
        if mode == MODE_RGB:
            d0, d1, d2 = m0 - center[0], m1 - center[1], m2 - center[2]
            length = max(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), _DIRECTION_MIN)
            d0, d1, d2 = d0 / length, d1 / length, d2 / length
            coefficients = (degree + 1) * (degree + 1)
            basis_into(d0, d1, d2, coefficients, basis)
            v0 = _sh_channel(texels, g, coefficients, basis, 0)
            v1 = _sh_channel(texels, g, coefficients, basis, 1)
            v2 = _sh_channel(texels, g, coefficients, basis, 2)
        elif mode == MODE_NORMAL:
            # Planar normal: the smallest-scale axis (first on ties), turned to face the camera.
            n0, n1, n2 = wx0, wx1, wx2
            smallest = l0
            if l1 < smallest:
                n0, n1, n2, smallest = wy0, wy1, wy2, l1
            if l2 < smallest:
                n0, n1, n2 = wz0, wz1, wz2
            flip = -1.0 if n0 * t0 + n1 * t1 + n2 * t2 > 0.0 else 1.0
            v0, v1, v2 = flip * n0, flip * n1, flip * n2
        else:
            v0 = v1 = v2 = t2
        u0, u1, major, minor = _footprint_axes(a, b, c, det, level)
        out[g, 0, 0] = mx
        out[g, 0, 1] = my
        out[g, 0, 2] = u0 * major
        out[g, 0, 3] = u1 * major
        out[g, 1, 0] = c / det
        out[g, 1, 1] = -b / det
        out[g, 1, 2] = a / det
        out[g, 1, 3] = opacity
        out[g, 2, 0] = v0
        out[g, 2, 1] = v1
        out[g, 2, 2] = v2
        out[g, 2, 3] = t2
        out[g, 3, 0] = -u1 * minor
        out[g, 3, 1] = u0 * minor




def preprocess_splats(texels: np.ndarray, sh_degree: int, camera, mode: int, splat_scale: float,
                      out: np.ndarray | None = None) -> np.ndarray:
    """texels [N, 3 + S, 4] float32 as pack_gaussians gives them; sh_degree: the bands to
    evaluate (<= the packed degree); camera: the anchor-relative gl_camera.ShaderCamera;
    mode: layout.MODES' number (depth and alpha: the camera z is the value) -> [N, 4, 4] float32
    (``out`` when its shape fits)."""
    n = texels.shape[0]
    if out is None or out.shape != (n, 4, 4):
        out = np.empty((n, 4, 4), np.float32)
    arguments = (int(sh_degree), np.ascontiguousarray(camera.rotation, np.float64),
                 np.ascontiguousarray(camera.translation, np.float64), np.ascontiguousarray(camera.center, np.float64),
                 np.asarray(camera.intrinsics, np.float64), np.asarray(camera.size, np.float64), int(mode),
                 float(splat_scale), out)
    # Threads over contiguous shares, each in compiled code without the interpreter lock:
    # numba's parallel=True lowering of this loop took ~25 s to compile on first use, this ~5 s.
    shares = max(1, min(_threads(), n // MIN_SHARE))
    bounds = np.linspace(0, n, shares + 1).astype(np.int64)
    if shares == 1:
        _preprocess_range(texels, 0, n, *arguments)
    else:
        list(_pool().map(lambda i: _preprocess_range(texels, bounds[i], bounds[i + 1], *arguments), range(shares)))
    return out


def _threads() -> int:
    return max(1, numba.get_num_threads())


@functools.lru_cache(maxsize=1)
def _pool() -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=_threads(), thread_name_prefix="preprocess")
