"""Numba-compiled CPU fast path of :func:`inceptiongs.rasterizer.sh.sh_to_color`.

One fused loop per Gaussian builds the basis, the colour and (backward) the gradients with
respect to the coefficients and the view direction, where the torch reference builds [M, K]
basis and [M, K, 3] product tensors and runs a batched 1 x K by K x 3 matmul (slow on the CPU
for tiny matrices). Reads the input arrays in place (no float64 copy: the [M, K, 3] copies cost more than the
arithmetic) and accumulates in float64 scalars; outputs are in the input dtype.
The direction gradient is the analytic derivative of each basis function (written out below);
tests/rasterizer/test_sh_numba.py compares both directions with torch autograd.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange
from torch.autograd.function import once_differentiable

from ..constants import SH_C0, SH_C1, SH_C2, SH_C3, SH_OFFSET

_CHUNK = 1024
C20, C21, C22, C23, C24 = SH_C2
C30, C31, C32, C33, C34, C35, C36 = SH_C3


@njit(cache=True)
def basis_into(x, y, z, count, out):
    """The real SH basis (sh.sh_basis's order and signs) up to ``count`` terms into out."""
    out[0] = SH_C0
    if count > 1:
        out[1] = -SH_C1 * y
        out[2] = SH_C1 * z
        out[3] = -SH_C1 * x
    if count > 4:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = C20 * x * y
        out[5] = C21 * y * z
        out[6] = C22 * (2.0 * zz - xx - yy)
        out[7] = C23 * x * z
        out[8] = C24 * (xx - yy)
    if count > 9:
        out[9] = C30 * y * (3.0 * xx - yy)
        out[10] = C31 * x * y * z
        out[11] = C32 * y * (4.0 * zz - xx - yy)
        out[12] = C33 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
        out[13] = C34 * x * (4.0 * zz - xx - yy)
        out[14] = C35 * z * (xx - yy)
        out[15] = C36 * x * (xx - 3.0 * yy)


@njit(cache=True)
def _basis_gradient(x, y, z, count, gk):
    """d loss / d (x, y, z) given gk[k] = d loss / d basis_k: the basis functions' derivatives."""
    gx = gy = gz = 0.0
    if count > 1:
        gy -= SH_C1 * gk[1]
        gz += SH_C1 * gk[2]
        gx -= SH_C1 * gk[3]
    if count > 4:
        gx += C20 * y * gk[4]
        gy += C20 * x * gk[4]
        gy += C21 * z * gk[5]
        gz += C21 * y * gk[5]
        gx -= 2.0 * C22 * x * gk[6]
        gy -= 2.0 * C22 * y * gk[6]
        gz += 4.0 * C22 * z * gk[6]
        gx += C23 * z * gk[7]
        gz += C23 * x * gk[7]
        gx += 2.0 * C24 * x * gk[8]
        gy -= 2.0 * C24 * y * gk[8]
    if count > 9:
        xx, yy, zz = x * x, y * y, z * z
        gx += 6.0 * C30 * x * y * gk[9]
        gy += C30 * (3.0 * xx - 3.0 * yy) * gk[9]
        gx += C31 * y * z * gk[10]
        gy += C31 * x * z * gk[10]
        gz += C31 * x * y * gk[10]
        gx -= 2.0 * C32 * x * y * gk[11]
        gy += C32 * (4.0 * zz - xx - 3.0 * yy) * gk[11]
        gz += 8.0 * C32 * y * z * gk[11]
        gx -= 6.0 * C33 * x * z * gk[12]
        gy -= 6.0 * C33 * y * z * gk[12]
        gz += C33 * (6.0 * zz - 3.0 * xx - 3.0 * yy) * gk[12]
        gx += C34 * (4.0 * zz - 3.0 * xx - yy) * gk[13]
        gy -= 2.0 * C34 * x * y * gk[13]
        gz += 8.0 * C34 * x * z * gk[13]
        gx += 2.0 * C35 * x * z * gk[14]
        gy -= 2.0 * C35 * y * z * gk[14]
        gz += C35 * (xx - yy) * gk[14]
        gx += C36 * (3.0 * xx - 3.0 * yy) * gk[15]
        gy -= 6.0 * C36 * x * y * gk[15]
    return gx, gy, gz


@njit(parallel=True, cache=True)
def _forward_kernel(sh, directions, count, colour):
    m = sh.shape[0]
    for chunk in prange((m + _CHUNK - 1) // _CHUNK):
        basis = np.empty(16)
        for i in range(chunk * _CHUNK, min(m, (chunk + 1) * _CHUNK)):
            basis_into(directions[i, 0], directions[i, 1], directions[i, 2], count, basis)
            for c in range(3):
                raw = SH_OFFSET
                for k in range(count):
                    raw += basis[k] * sh[i, k, c]
                colour[i, c] = 0.0 if raw < 0.0 else raw  # clamp_min(raw, 0); NaN stays NaN, as in torch


@njit(parallel=True, cache=True)
def _backward_kernel(sh, directions, count, g_colour, g_sh, g_directions):
    m = sh.shape[0]
    for chunk in prange((m + _CHUNK - 1) // _CHUNK):
        basis = np.empty(16)
        g_basis = np.empty(16)
        for i in range(chunk * _CHUNK, min(m, (chunk + 1) * _CHUNK)):
            x, y, z = directions[i, 0], directions[i, 1], directions[i, 2]
            basis_into(x, y, z, count, basis)
            g_basis[:count] = 0.0
            for c in range(3):
                raw = SH_OFFSET
                for k in range(count):
                    raw += basis[k] * sh[i, k, c]
                # clamp_min(raw, 0) passes the gradient where raw >= 0 (as torch.clamp_min).
                g = g_colour[i, c] if raw >= 0.0 else 0.0
                for k in range(count):
                    g_sh[i, k, c] = basis[k] * g
                    g_basis[k] += sh[i, k, c] * g
            gx, gy, gz = _basis_gradient(x, y, z, count, g_basis)
            g_directions[i, 0] = gx
            g_directions[i, 1] = gy
            g_directions[i, 2] = gz


def _array(tensor: torch.Tensor) -> np.ndarray:
    """A numpy view (no copy, any dtype and strides: the kernels read it in float64)."""
    return tensor.detach().cpu().numpy()


class _ShColourFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, sh, directions, count):
        sh_np, dir_np = _array(sh), _array(directions)
        colour = np.empty((sh_np.shape[0], 3), sh_np.dtype)
        _forward_kernel(sh_np, dir_np, count, colour)
        ctx.save_for_backward(sh, directions)
        ctx.count = count
        return torch.from_numpy(colour).to(sh.device)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_colour):
        sh, directions = ctx.saved_tensors
        sh_np, dir_np = _array(sh), _array(directions)
        g_sh = np.zeros(sh_np.shape, sh_np.dtype)
        g_directions = np.empty(dir_np.shape, dir_np.dtype)
        _backward_kernel(sh_np, dir_np, ctx.count, _array(g_colour), g_sh, g_directions)
        needs = ctx.needs_input_grad
        device = g_colour.device
        return (torch.from_numpy(g_sh).to(device) if needs[0] else None,
                torch.from_numpy(g_directions).to(device) if needs[1] else None,
                None)


def sh_to_color_numba(sh: torch.Tensor, directions: torch.Tensor, count: int) -> torch.Tensor:
    """sh: [M, K, 3], directions: [M, 3] unit, count = (degree + 1)^2 <= K -> colour [M, 3]
    (max(sum_k basis_k sh_k + SH_OFFSET, 0)); differentiable w.r.t. sh and directions."""
    return _ShColourFunction.apply(sh, directions, int(count))
