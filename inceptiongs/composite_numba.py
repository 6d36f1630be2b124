"""Numba-compiled CPU fast path of the per-pixel compositing stage.

Implements exactly the composite contract of :mod:`inceptiongs.composite` (the torch
reference): front-to-back alpha blending of projected 2-D Gaussians, with the alpha rules,
skip rules and stop rule read from :mod:`inceptiongs.constants`. Forward and backward are
``@njit(parallel=True)`` kernels with a ``prange`` over 16x16 tiles; the public entry point
:func:`composite_numba` wraps them in a :class:`torch.autograd.Function`.

Precision: whatever the input dtype, every kernel computes in float64 (inputs are cast once,
O(M)); outputs and gradients are cast back to the input dtype. So float32 inputs give the
float64 result rounded to float32, and the two dtypes take the same skip/stop decisions.

Determinism: the backward writes one gradient row per (tile, Gaussian) entry, each owned by
the single thread that handles the tile, and reduces the rows in a fixed order. Results do
not depend on the number of threads.

Difference from the torch reference, by design: a Gaussian whose mean is not finite is never
binned (it contributes nothing) instead of spreading NaN over the whole image.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange
from torch.autograd.function import once_differentiable

from inceptiongs.constants import ALPHA_MAX, ALPHA_MIN, TILE_SIZE, TRANSMITTANCE_MIN

# Columns of the packed per-Gaussian parameter table (rows in depth order).
_MX, _MY, _CA, _CB, _CC, _OPACITY, _POWER_CUT = range(7)
_PARAM_COLUMNS = 7
# Columns of the per-entry gradient rows before the value channels.
_GRAD_GEOMETRY_COLUMNS = 6  # d mean x, d mean y, d conic a, b, c, d opacity
# alpha < ALPHA_MIN  <=>  power > log(opacity / ALPHA_MIN). Pixels whose power exceeds that
# cut by this margin are skipped without calling exp(); the margin (far above the rounding
# error of log/exp in float64) keeps the shortcut from ever changing a decision, because
# pixels inside the margin still take the exact alpha < ALPHA_MIN test.
_POWER_CUT_MARGIN = 1e-9


# --------------------------------------------------------------------------------------
# binning


@njit(cache=True)
def _pixel_range(mean: float, extent: float, size: int) -> tuple[int, int]:
    """Inclusive pixel index range [lo, hi] whose centres (i + 0.5) may lie within
    mean +- extent, clamped to [0, size - 1]; lo > hi when it misses the image.

    Widened by one pixel on each side so float rounding can never drop a covered pixel
    (extra pixels are harmless: the per-pixel alpha test decides). A non-finite extent
    covers the whole axis, which is always correct."""
    if not (extent >= 0.0 and extent < math.inf):
        return 0, size - 1
    lo = mean - extent - 0.5
    hi = mean + extent - 0.5
    if lo > size or hi < -1.0:
        return 1, 0
    # Clamp in float before converting, so huge values cannot overflow the int cast.
    lo = max(lo, 0.0)
    hi = min(hi, size - 1.0)
    lo_i = max(int(math.floor(lo)) - 1, 0)
    hi_i = min(int(math.ceil(hi)) + 1, size - 1)
    return lo_i, hi_i


@njit(cache=True)
def _bin_tiles(params, extents_sorted, width, height, tiles_x, tiles_y):
    """Counting sort of (tile, Gaussian) pairs by tile, Gaussians already in depth order.

    params: [M, 7] float64 (rows in depth order); extents_sorted: [M, 2].
    Returns tile_offsets [tiles + 1] int64 and entries [E] int64 (row of params); the
    entries of tile t are entries[tile_offsets[t]:tile_offsets[t + 1]], front to back."""
    m = params.shape[0]
    n_tiles = tiles_x * tiles_y
    rects = np.empty((m, 4), np.int64)  # tile x0, x1, y0, y1 (inclusive); x0 > x1 = none
    counts = np.zeros(n_tiles + 1, np.int64)
    for r in range(m):
        rects[r, 0] = 1
        rects[r, 1] = 0
        rects[r, 2] = 1
        rects[r, 3] = 0
        mx = params[r, _MX]
        my = params[r, _MY]
        # Opacity below ALPHA_MIN can never reach alpha >= ALPHA_MIN (power >= 0 there),
        # and a non-finite mean has no pixel to bin into.
        if not (params[r, _OPACITY] >= ALPHA_MIN) or not (math.isfinite(mx) and math.isfinite(my)):
            continue
        px0, px1 = _pixel_range(mx, extents_sorted[r, 0], width)
        py0, py1 = _pixel_range(my, extents_sorted[r, 1], height)
        if px0 > px1 or py0 > py1:
            continue
        rects[r, 0] = px0 // TILE_SIZE
        rects[r, 1] = px1 // TILE_SIZE
        rects[r, 2] = py0 // TILE_SIZE
        rects[r, 3] = py1 // TILE_SIZE
        for ty in range(rects[r, 2], rects[r, 3] + 1):
            for tx in range(rects[r, 0], rects[r, 1] + 1):
                counts[ty * tiles_x + tx + 1] += 1
    offsets = np.cumsum(counts)
    cursor = offsets[:-1].copy()
    entries = np.empty(offsets[-1], np.int64)
    for r in range(m):  # rows ascend in depth order, so each tile's list is front to back
        for ty in range(rects[r, 2], rects[r, 3] + 1):
            for tx in range(rects[r, 0], rects[r, 1] + 1):
                t = ty * tiles_x + tx
                entries[cursor[t]] = r
                cursor[t] += 1
    return offsets, entries


# --------------------------------------------------------------------------------------
# per-pixel kernels


@njit(cache=True, inline="always")
def _power(params, r, px, py):
    """Gaussian exponent at pixel centre (px, py) and the offsets dx, dy."""
    dx = px - params[r, _MX]
    dy = py - params[r, _MY]
    power = 0.5 * (params[r, _CA] * dx * dx + params[r, _CC] * dy * dy) + params[r, _CB] * dx * dy
    return power, dx, dy


@njit(parallel=True, fastmath=False, cache=True)
def _forward_kernel(params, values, offsets, entries, width, height, tiles_x, image, final_t, walk):
    """Front-to-back blend per pixel.

    params [M, 7], values [M, C] (rows in depth order). Writes image [H, W, C],
    final_t [H, W] (transmittance after the last Gaussian added) and walk [H, W] (entries of
    the tile list to replay in the backward: up to and including the last one added)."""
    n_tiles = offsets.shape[0] - 1
    channels = values.shape[1]
    for t in prange(n_tiles):
        start = offsets[t]
        end = offsets[t + 1]
        ty = t // tiles_x
        tx = t - ty * tiles_x
        x0 = tx * TILE_SIZE
        y0 = ty * TILE_SIZE
        x1 = min(x0 + TILE_SIZE, width)
        y1 = min(y0 + TILE_SIZE, height)
        acc = np.empty(channels)
        for y in range(y0, y1):
            py = y + 0.5
            for x in range(x0, x1):
                px = x + 0.5
                trans = 1.0
                acc[:] = 0.0
                count = 0
                for e in range(start, end):
                    r = entries[e]
                    power, dx, dy = _power(params, r, px, py)
                    if power < 0.0 or power > params[r, _POWER_CUT]:
                        continue
                    alpha = min(ALPHA_MAX, params[r, _OPACITY] * math.exp(-power))
                    if alpha < ALPHA_MIN:
                        continue
                    after = trans * (1.0 - alpha)
                    if after < TRANSMITTANCE_MIN:
                        break
                    weight = trans * alpha
                    for ch in range(channels):
                        acc[ch] += weight * values[r, ch]
                    trans = after
                    count = e - start + 1
                for ch in range(channels):
                    image[y, x, ch] = acc[ch]
                final_t[y, x] = trans
                walk[y, x] = count


@njit(parallel=True, fastmath=False, cache=True)
def _backward_kernel(params, values, offsets, entries, width, height, tiles_x, final_t, walk,
                     grad_image, grad_alpha, entry_grads):
    """Back-to-front replay per pixel, accumulating d loss / d parameters per tile entry.

    grad_image [H, W, C], grad_alpha [H, W]; entry_grads [E, 6 + C] (zeroed by the caller)
    gets, per entry: d mean x, d mean y, d conic a, b, c, d opacity, d values[C].

    With T_i the transmittance before Gaussian i and S_i the colour blended behind it:
        d image / d alpha_i = T_i v_i - S_i / (1 - alpha_i)
        d (1 - T_final) / d alpha_i = T_final / (1 - alpha_i)
    T_i is rebuilt from T_final by dividing by (1 - alpha), safe as alpha <= ALPHA_MAX < 1."""
    n_tiles = offsets.shape[0] - 1
    channels = values.shape[1]
    for t in prange(n_tiles):
        start = offsets[t]
        ty = t // tiles_x
        tx = t - ty * tiles_x
        x0 = tx * TILE_SIZE
        y0 = ty * TILE_SIZE
        x1 = min(x0 + TILE_SIZE, width)
        y1 = min(y0 + TILE_SIZE, height)
        behind = np.empty(channels)
        for y in range(y0, y1):
            py = y + 0.5
            for x in range(x0, x1):
                count = walk[y, x]
                if count == 0:
                    continue
                px = x + 0.5
                t_final = final_t[y, x]
                g_alpha = grad_alpha[y, x]
                trans = t_final
                behind[:] = 0.0
                for e in range(start + count - 1, start - 1, -1):
                    r = entries[e]
                    power, dx, dy = _power(params, r, px, py)
                    if power < 0.0 or power > params[r, _POWER_CUT]:
                        continue
                    gauss = math.exp(-power)
                    raw = params[r, _OPACITY] * gauss
                    alpha = min(ALPHA_MAX, raw)
                    if alpha < ALPHA_MIN:
                        continue
                    keep = 1.0 - alpha
                    trans = trans / keep  # transmittance in front of this Gaussian
                    weight = trans * alpha
                    d_alpha = g_alpha * t_final / keep
                    for ch in range(channels):
                        g = grad_image[y, x, ch]
                        v = values[r, ch]
                        entry_grads[e, _GRAD_GEOMETRY_COLUMNS + ch] += weight * g
                        d_alpha += g * (trans * v - behind[ch] / keep)
                        behind[ch] += weight * v
                    # min(ALPHA_MAX, raw) passes no gradient where it clamps (as torch.clamp).
                    if raw > ALPHA_MAX:
                        continue
                    entry_grads[e, 5] += d_alpha * gauss
                    d_power = -d_alpha * raw
                    ca = params[r, _CA]
                    cb = params[r, _CB]
                    cc = params[r, _CC]
                    # power depends on the mean through dx = px - mx, dy = py - my.
                    entry_grads[e, 0] -= d_power * (ca * dx + cb * dy)
                    entry_grads[e, 1] -= d_power * (cc * dy + cb * dx)
                    entry_grads[e, 2] += d_power * 0.5 * dx * dx
                    entry_grads[e, 3] += d_power * dx * dy
                    entry_grads[e, 4] += d_power * 0.5 * dy * dy


@njit(parallel=True, cache=True)
def _reduce_entry_grads(entries, entry_grads, n_rows):
    """Sum entry rows per Gaussian row: [E, K] -> [n_rows, K]. One thread per column, so no
    two threads write the same cell, and the order of additions is fixed."""
    columns = entry_grads.shape[1]
    out = np.zeros((n_rows, columns))
    for k in prange(columns):
        for e in range(entries.shape[0]):
            out[entries[e], k] += entry_grads[e, k]
    return out


# --------------------------------------------------------------------------------------
# torch glue


def _as_f64(tensor: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(tensor.detach().cpu().numpy(), dtype=np.float64)


def _pack_params(means2d: np.ndarray, conics: np.ndarray, opacities: np.ndarray) -> np.ndarray:
    """[M, 7] float64 table: mean x, y, conic a, b, c, opacity, power cut.

    The power cut is log(opacity / ALPHA_MIN) plus a margin (see _POWER_CUT_MARGIN); it is
    +inf where the opacity is not a positive finite number, so such rows always take the exact
    test. errstate: log of 0 or a negative opacity is expected here and replaced."""
    params = np.empty((means2d.shape[0], _PARAM_COLUMNS), np.float64)
    params[:, _MX:_MY + 1] = means2d
    params[:, _CA:_CC + 1] = conics
    params[:, _OPACITY] = opacities
    with np.errstate(divide="ignore", invalid="ignore"):
        cut = np.log(opacities / ALPHA_MIN) + _POWER_CUT_MARGIN
    params[:, _POWER_CUT] = np.where(np.isfinite(cut), cut, np.inf)
    return params


def _check_shapes(means2d, conics, opacities, values, depths, extents, width, height) -> None:
    m = means2d.shape[0]
    expected = {
        "means2d": (means2d, (m, 2)),
        "conics": (conics, (m, 3)),
        "opacities": (opacities, (m,)),
        "depths": (depths, (m,)),
        "extents": (extents, (m, 2)),
    }
    for name, (tensor, shape) in expected.items():
        if tuple(tensor.shape) != shape:
            raise ValueError(f"composite_numba: {name} has shape {tuple(tensor.shape)}, expected {shape}")
    if values.dim() != 2 or values.shape[0] != m:
        raise ValueError(f"composite_numba: values has shape {tuple(values.shape)}, expected ({m}, C)")
    if int(width) < 0 or int(height) < 0:
        raise ValueError(f"composite_numba: image size {width}x{height} is negative")


class _CompositeFunction(torch.autograd.Function):
    """Autograd wrapper; gradients flow to means2d, conics, opacities and values."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, values, depths, extents, width, height):
        width = int(width)
        height = int(height)
        dtype = values.dtype
        device = values.device
        channels = values.shape[1]
        # Front-to-back order: ascending depth, ties by index (a stable sort).
        order = np.argsort(depths.detach().cpu().numpy(), kind="stable")
        params = _pack_params(_as_f64(means2d), _as_f64(conics), _as_f64(opacities))[order]
        values_sorted = _as_f64(values)[order]
        extents_sorted = _as_f64(extents)[order]
        tiles_x = -(-width // TILE_SIZE)
        tiles_y = -(-height // TILE_SIZE)
        offsets, entries = _bin_tiles(params, extents_sorted, width, height, tiles_x, tiles_y)

        image = np.zeros((height, width, channels), np.float64)
        final_t = np.ones((height, width), np.float64)
        walk = np.zeros((height, width), np.int64)
        if entries.shape[0] > 0:
            _forward_kernel(params, values_sorted, offsets, entries, width, height, tiles_x,
                            image, final_t, walk)

        ctx.state = (order, params, values_sorted, offsets, entries, width, height, tiles_x, final_t, walk)
        ctx.input_dtypes = (means2d.dtype, conics.dtype, opacities.dtype, values.dtype)
        image_t = torch.from_numpy(image).to(device=device, dtype=dtype)
        alpha_t = torch.from_numpy(1.0 - final_t).unsqueeze(-1).to(device=device, dtype=dtype)
        return image_t, alpha_t

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_image, grad_alpha):
        order, params, values_sorted, offsets, entries, width, height, tiles_x, final_t, walk = ctx.state
        m = params.shape[0]
        channels = values_sorted.shape[1]
        device = grad_image.device if grad_image is not None else grad_alpha.device
        g_image = (np.zeros((height, width, channels)) if grad_image is None else _as_f64(grad_image))
        g_alpha = (np.zeros((height, width)) if grad_alpha is None else _as_f64(grad_alpha)[..., 0].copy())

        entry_grads = np.zeros((entries.shape[0], _GRAD_GEOMETRY_COLUMNS + channels), np.float64)
        if entries.shape[0] > 0:
            _backward_kernel(params, values_sorted, offsets, entries, width, height, tiles_x,
                             final_t, walk, g_image, g_alpha, entry_grads)
        per_row = _reduce_entry_grads(entries, entry_grads, m)
        # Rows are in depth order; scatter back to the caller's Gaussian order.
        grads = np.empty_like(per_row)
        grads[order] = per_row

        dt_means, dt_conics, dt_opac, dt_values = ctx.input_dtypes
        needs = ctx.needs_input_grad

        def out(columns, dtype, need):
            if not need:
                return None
            return torch.from_numpy(np.ascontiguousarray(columns)).to(device=device, dtype=dtype)

        return (
            out(grads[:, 0:2], dt_means, needs[0]),
            out(grads[:, 2:5], dt_conics, needs[1]),
            out(grads[:, 5], dt_opac, needs[2]),
            out(grads[:, _GRAD_GEOMETRY_COLUMNS:], dt_values, needs[3]),
            None,
            None,
            None,
            None,
        )


def composite_numba(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    values: torch.Tensor,
    depths: torch.Tensor,
    extents: torch.Tensor,
    width: int,
    height: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Blend projected Gaussians front to back (the composite contract), on the CPU via numba.

    means2d [M, 2] pixel coords (x = column, y = row), conics [M, 3] (a, b, c) of the inverse
    2-D covariance, opacities [M] in (0, 1), values [M, C], depths [M] (sort key), extents
    [M, 2] half-sizes of a box containing every pixel where alpha >= ALPHA_MIN (binning
    only). Returns image [H, W, C] (no background) and alpha [H, W, 1], in values' dtype and
    on its device. Differentiable w.r.t. means2d, conics, opacities and values."""
    _check_shapes(means2d, conics, opacities, values, depths, extents, width, height)
    return _CompositeFunction.apply(means2d, conics, opacities, values, depths, extents, int(width), int(height))
