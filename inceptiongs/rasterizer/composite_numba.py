"""Numba-compiled CPU fast path of the per-pixel compositing stage.

Implements exactly the composite contract of :mod:`inceptiongs.rasterizer.composite` (the torch
reference): front-to-back alpha blending of projected 2-D Gaussians, with the alpha rules,
skip rules and stop rule read from :mod:`inceptiongs.constants`. Forward and backward are
``@njit(parallel=True)`` kernels with a ``prange`` over 16x16 tiles; the public entry point
:func:`composite_numba` wraps them in a :class:`torch.autograd.Function`.

Precision: whatever the input dtype, every kernel computes in float64 (inputs are cast once,
O(M)); outputs and gradients are cast back to the input dtype. So float32 inputs give the
float64 result of those (float32-rounded) inputs, rounded to float32: within 1e-4 of the float64
reference in the tests, and unlike a float32 evaluation it does not lose needle-thin footprints
whose power a*dx^2 + c*dy^2 + 2b*dx*dy cancels catastrophically in float32.
Along a row span of a wide footprint (conic a < RECURRENCE_CONIC_MAX) exp(-power) is stepped
from the span's first pixel by two multiplications per pixel instead of one exp() each (spans
are clipped to a 16-pixel tile, so the drift is ~1e-14 relative); the backward steps through
the same spans in the same way, so both passes see bit-identical alphas and take the same
decisions. Roughly 20 % of the forward + backward time was exp().

Determinism: the backward writes one gradient row per (tile, Gaussian) entry, each owned by
the single thread that handles the tile, and reduces the rows in a fixed order. Results do
not depend on the number of threads or on which thread took which tile.

Memory: O(pixels) per-pixel state plus O(entries) for the (tile, Gaussian) list and its
gradient rows ((6 + C) float64 each); never pixels x Gaussians.

Difference from the torch reference, by design: a Gaussian whose mean is not finite is never
binned (it contributes nothing) instead of spreading NaN over the whole image.
"""

from __future__ import annotations

import contextlib
import math

import numba
import numpy as np
import torch
from numba import njit, prange
from torch.autograd.function import once_differentiable

from inceptiongs.constants import ALPHA_MAX, ALPHA_MIN, RECURRENCE_CONIC_MAX, TILE_SIZE, TRANSMITTANCE_MIN

from .numba_spans import next_pixel_ratio, row_span

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
    (extra pixels are harmless: the per-pixel alpha test decides). A NaN, infinite or negative extent
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
def bin_tiles(params, extents_sorted, width, height, tiles_x, tiles_y):
    """Counting sort of (tile, Gaussian) pairs by tile, Gaussians already in depth order.

    params: [M, 7] float64 (rows in depth order); extents_sorted: [M, 2].
    Returns
      pixel_rects [M, 4] int64: inclusive pixel box x0, x1, y0, y1 of each row (x0 > x1: none),
      tile_offsets [tiles + 1] int64 and entries [E] int64 (rows of params): the entries of
      tile t are entries[tile_offsets[t]:tile_offsets[t + 1]], front to back."""
    m = params.shape[0]
    n_tiles = tiles_x * tiles_y
    rects = np.empty((m, 4), np.int64)
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
        rects[r, 0] = px0
        rects[r, 1] = px1
        rects[r, 2] = py0
        rects[r, 3] = py1
        for ty in range(py0 // TILE_SIZE, py1 // TILE_SIZE + 1):
            for tx in range(px0 // TILE_SIZE, px1 // TILE_SIZE + 1):
                counts[ty * tiles_x + tx + 1] += 1
    offsets = np.cumsum(counts)
    cursor = offsets[:-1].copy()
    entries = np.empty(offsets[-1], np.int64)
    for r in range(m):  # rows ascend in depth order, so each tile's list is front to back
        if rects[r, 0] > rects[r, 1]:
            continue
        for ty in range(rects[r, 2] // TILE_SIZE, rects[r, 3] // TILE_SIZE + 1):
            for tx in range(rects[r, 0] // TILE_SIZE, rects[r, 1] // TILE_SIZE + 1):
                t = ty * tiles_x + tx
                entries[cursor[t]] = r
                cursor[t] += 1
    return rects, offsets, entries


# --------------------------------------------------------------------------------------
# per-pixel kernels
#
# Both kernels run Gaussian-major inside a tile: for each of the tile's Gaussians, front to
# back (forward) or back to front (backward), visit only the pixels of its box within the
# tile, keeping each pixel's running state in tile-local arrays. Neighbouring pixels take
# the same branches, and pixels outside the box are never evaluated. The per-pixel order of
# operations is exactly the sequential contract, so forward and backward take identical
# decisions (same expressions, same float64 arithmetic).


@njit(cache=True, inline="always")
def _tile_box(rects, r, x0, x1, y0, y1):
    """Pixel box of row r clipped to the tile [x0, x1) x [y0, y1): inclusive bounds."""
    return max(rects[r, 0], x0), min(rects[r, 1], x1 - 1), max(rects[r, 2], y0), min(rects[r, 3], y1 - 1)


@njit(cache=True, inline="always")
def _exp_along_span(stepping, first, power, ca, cb, mx, dy, x, gauss, ratio, step_factor):
    """(exp(-power) at pixel x, factor to the next pixel). Not stepping: exp() directly. At
    the span's first pixel: exp() and exp(-(power(x + 1) - power(x))). Further on: the
    previous pixel's value times its factor, the factor times exp(-a)."""
    if not stepping:
        return math.exp(-power), ratio
    if first:
        return math.exp(-power), next_pixel_ratio(ca, cb, (x + 0.5) - mx, dy)
    return gauss * ratio, ratio * step_factor


@njit(parallel=True, fastmath=False, cache=True)
def _forward_kernel(params, values, rects, offsets, entries, tile_order, width, height, tiles_x,
                    image, final_t, walk):
    """Front-to-back blend per pixel.

    params [M, 7], values [M, C] (rows in depth order), rects [M, 4]. Writes image [H, W, C],
    final_t [H, W] (transmittance after the last Gaussian added) and walk [H, W] (how many
    entries of the tile list the backward must replay: up to the last one added)."""
    channels = values.shape[1]
    for i in prange(tile_order.shape[0]):
        t = tile_order[i]
        start = offsets[t]
        n = offsets[t + 1] - start
        if n == 0:
            continue  # image, final_t and walk already hold the empty-pixel values
        ty = t // tiles_x
        tx = t - ty * tiles_x
        x0 = tx * TILE_SIZE
        y0 = ty * TILE_SIZE
        x1 = min(x0 + TILE_SIZE, width)
        y1 = min(y0 + TILE_SIZE, height)
        tile_pixels = (x1 - x0) * (y1 - y0)
        trans = np.ones((TILE_SIZE, TILE_SIZE))
        acc = np.zeros((TILE_SIZE, TILE_SIZE, channels))
        count = np.zeros((TILE_SIZE, TILE_SIZE), np.int64)
        finished = np.zeros((TILE_SIZE, TILE_SIZE), np.bool_)
        # Finished pixels per tile row: a row whose pixels have all stopped is skipped whole
        # (each row's exp stepping restarts at its span, so skipping it changes no other row).
        row_finished = np.zeros(TILE_SIZE, np.int64)
        row_width = x1 - x0
        n_finished = 0
        for k in range(n):
            r = entries[start + k]
            bx0, bx1, by0, by1 = _tile_box(rects, r, x0, x1, y0, y1)
            mx = params[r, _MX]
            my = params[r, _MY]
            ca = params[r, _CA]
            cb = params[r, _CB]
            cc = params[r, _CC]
            opacity = params[r, _OPACITY]
            cut = params[r, _POWER_CUT]
            step_factor = math.exp(-ca)
            for y in range(by0, by1 + 1):
                ly = y - y0
                if row_finished[ly] == row_width:
                    continue
                dy = (y + 0.5) - my
                sx0, sx1, parabola = row_span(ca, cb, cc, cut, mx, dy, bx0, bx1)
                stepping = parabola and ca < RECURRENCE_CONIC_MAX
                gauss = 0.0
                ratio = 0.0
                for x in range(sx0, sx1 + 1):
                    dx = (x + 0.5) - mx
                    power = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    # At every pixel, finished or not, so the backward (which steps the same
                    # way) sees identical values.
                    gauss, ratio = _exp_along_span(stepping, x == sx0, power, ca, cb, mx, dy, x,
                                                   gauss, ratio, step_factor)
                    lx = x - x0
                    if finished[ly, lx]:
                        continue
                    if power < 0.0 or power > cut:
                        continue
                    alpha = min(ALPHA_MAX, opacity * gauss)
                    if alpha < ALPHA_MIN:
                        continue
                    before = trans[ly, lx]
                    after = before * (1.0 - alpha)
                    if after < TRANSMITTANCE_MIN:
                        finished[ly, lx] = True
                        row_finished[ly] += 1
                        n_finished += 1
                        continue
                    weight = before * alpha
                    for ch in range(channels):
                        acc[ly, lx, ch] += weight * values[r, ch]
                    trans[ly, lx] = after
                    count[ly, lx] = k + 1
            if n_finished == tile_pixels:
                break
        for y in range(y0, y1):
            for x in range(x0, x1):
                for ch in range(channels):
                    image[y, x, ch] = acc[y - y0, x - x0, ch]
                final_t[y, x] = trans[y - y0, x - x0]
                walk[y, x] = count[y - y0, x - x0]


@njit(parallel=True, fastmath=False, cache=True)
def _backward_kernel(params, values, rects, offsets, entries, tile_order, width, height, tiles_x, final_t, walk,
                     grad_image, grad_alpha, entry_grads):
    """Back-to-front replay per pixel, writing d loss / d parameters per tile entry.

    grad_image [H, W, C], grad_alpha [H, W]; entry_grads [E, 6 + C] gets, per entry: d mean x,
    d mean y, d conic a, b, c, d opacity, d values[C] (summed over the tile's pixels).

    With T_i the transmittance before Gaussian i and S_i the colour blended behind it:
        d image / d alpha_i = T_i v_i - S_i / (1 - alpha_i)
        d (1 - T_final) / d alpha_i = T_final / (1 - alpha_i)
    T_i is rebuilt from T_final by dividing by (1 - alpha), safe as alpha <= ALPHA_MAX < 1."""
    channels = values.shape[1]
    for i in prange(tile_order.shape[0]):
        t = tile_order[i]
        start = offsets[t]
        n = offsets[t + 1] - start
        if n == 0:
            continue
        ty = t // tiles_x
        tx = t - ty * tiles_x
        x0 = tx * TILE_SIZE
        y0 = ty * TILE_SIZE
        x1 = min(x0 + TILE_SIZE, width)
        y1 = min(y0 + TILE_SIZE, height)
        trans = np.empty((TILE_SIZE, TILE_SIZE))
        behind = np.zeros((TILE_SIZE, TILE_SIZE, channels))
        # Entries a row must replay: up to its pixels' longest walk; rows past it are skipped.
        row_walk = np.zeros(TILE_SIZE, np.int64)
        for y in range(y0, y1):
            for x in range(x0, x1):
                trans[y - y0, x - x0] = final_t[y, x]
                row_walk[y - y0] = max(row_walk[y - y0], walk[y, x])
        replay = 0
        for ly in range(y1 - y0):
            replay = max(replay, row_walk[ly])
        grad_values = np.empty(channels)
        for k in range(replay - 1, -1, -1):
            r = entries[start + k]
            bx0, bx1, by0, by1 = _tile_box(rects, r, x0, x1, y0, y1)
            mx = params[r, _MX]
            my = params[r, _MY]
            ca = params[r, _CA]
            cb = params[r, _CB]
            cc = params[r, _CC]
            opacity = params[r, _OPACITY]
            cut = params[r, _POWER_CUT]
            step_factor = math.exp(-ca)
            g_mx = 0.0
            g_my = 0.0
            g_a = 0.0
            g_b = 0.0
            g_c = 0.0
            g_opacity = 0.0
            grad_values[:] = 0.0
            for y in range(by0, by1 + 1):
                ly = y - y0
                if k >= row_walk[ly]:
                    continue  # every pixel of this row was finished before entry k
                dy = (y + 0.5) - my
                sx0, sx1, parabola = row_span(ca, cb, cc, cut, mx, dy, bx0, bx1)
                stepping = parabola and ca < RECURRENCE_CONIC_MAX
                gauss = 0.0
                ratio = 0.0
                for x in range(sx0, sx1 + 1):
                    dx = (x + 0.5) - mx
                    power = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    gauss, ratio = _exp_along_span(stepping, x == sx0, power, ca, cb, mx, dy, x,
                                                   gauss, ratio, step_factor)  # as the forward
                    if k >= walk[y, x]:
                        continue  # this pixel was finished before entry k
                    lx = x - x0
                    if power < 0.0 or power > cut:
                        continue
                    raw = opacity * gauss
                    alpha = min(ALPHA_MAX, raw)
                    if alpha < ALPHA_MIN:
                        continue
                    inv_keep = 1.0 / (1.0 - alpha)  # <= 1 / (1 - ALPHA_MAX) = 100
                    before = trans[ly, lx] * inv_keep  # transmittance in front of this Gaussian
                    trans[ly, lx] = before
                    weight = before * alpha
                    d_alpha = grad_alpha[y, x] * final_t[y, x] * inv_keep
                    for ch in range(channels):
                        g = grad_image[y, x, ch]
                        v = values[r, ch]
                        grad_values[ch] += weight * g
                        d_alpha += g * (before * v - behind[ly, lx, ch] * inv_keep)
                        behind[ly, lx, ch] += weight * v
                    # min(ALPHA_MAX, raw) passes no gradient where it clamps (as torch.clamp).
                    if raw > ALPHA_MAX:
                        continue
                    g_opacity += d_alpha * gauss
                    d_power = -d_alpha * raw
                    # power depends on the mean through dx = px - mx, dy = py - my.
                    g_mx -= d_power * (ca * dx + cb * dy)
                    g_my -= d_power * (cc * dy + cb * dx)
                    g_a += d_power * 0.5 * dx * dx
                    g_b += d_power * dx * dy
                    g_c += d_power * 0.5 * dy * dy
            e = start + k
            entry_grads[e, 0] = g_mx
            entry_grads[e, 1] = g_my
            entry_grads[e, 2] = g_a
            entry_grads[e, 3] = g_b
            entry_grads[e, 4] = g_c
            entry_grads[e, 5] = g_opacity
            for ch in range(channels):
                entry_grads[e, _GRAD_GEOMETRY_COLUMNS + ch] = grad_values[ch]


@njit(cache=True)
def _reduce_entry_grads(entries, entry_grads, n_rows):
    """Sum entry rows per Gaussian row: [E, K] -> [n_rows, K], in entry order (deterministic).

    One sequential pass reading whole rows: the sum is memory-bound, and a column-parallel
    pass would stream the [E, K] table once per column."""
    columns = entry_grads.shape[1]
    out = np.zeros((n_rows, columns))
    for e in range(entries.shape[0]):
        r = entries[e]
        for k in range(columns):
            out[r, k] += entry_grads[e, k]
    return out


# --------------------------------------------------------------------------------------
# torch glue


def _busy_tiles_heaviest_first(offsets: np.ndarray) -> np.ndarray:
    """Tiles holding at least one entry, most entries first (stable): [busy] int64.

    With the dynamic chunks of _tile_scheduling this is longest-job-first scheduling, so a
    scene whose Gaussians crowd one part of the image still keeps every thread busy (numba's
    default hands each thread one contiguous block of tiles)."""
    counts = np.diff(offsets)
    order = np.argsort(-counts, kind="stable")
    return np.ascontiguousarray(order[counts[order] > 0], dtype=np.int64)


@contextlib.contextmanager
def _tile_scheduling():
    """Hand tiles to threads one at a time as they free up (a tile is ~1e4-1e6 operations,
    far above the cost of taking the next one)."""
    previous = numba.set_parallel_chunksize(1)
    try:
        yield
    finally:
        numba.set_parallel_chunksize(previous)


def as_float64(tensor: torch.Tensor) -> np.ndarray:
    """A contiguous float64 numpy copy of ``tensor`` (detached, on the CPU): what the kernels read."""
    return np.ascontiguousarray(tensor.detach().cpu().numpy(), dtype=np.float64)


def pack_params(means2d: np.ndarray, conics: np.ndarray, opacities: np.ndarray) -> np.ndarray:
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
        params = pack_params(as_float64(means2d), as_float64(conics), as_float64(opacities))[order]
        values_sorted = as_float64(values)[order]
        extents_sorted = as_float64(extents)[order]
        tiles_x = -(-width // TILE_SIZE)
        tiles_y = -(-height // TILE_SIZE)
        rects, offsets, entries = bin_tiles(params, extents_sorted, width, height, tiles_x, tiles_y)
        tile_order = _busy_tiles_heaviest_first(offsets)

        image = np.zeros((height, width, channels), np.float64)
        final_t = np.ones((height, width), np.float64)
        walk = np.zeros((height, width), np.int64)
        if entries.shape[0] > 0:
            with _tile_scheduling():
                _forward_kernel(params, values_sorted, rects, offsets, entries, tile_order, width, height,
                                tiles_x, image, final_t, walk)

        ctx.state = (order, params, values_sorted, rects, offsets, entries, tile_order, width, height, tiles_x,
                     final_t, walk)
        ctx.input_dtypes = (means2d.dtype, conics.dtype, opacities.dtype, values.dtype)
        image_t = torch.from_numpy(image).to(device=device, dtype=dtype)
        alpha_t = torch.from_numpy(1.0 - final_t).unsqueeze(-1).to(device=device, dtype=dtype)
        return image_t, alpha_t

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_image, grad_alpha):
        (order, params, values_sorted, rects, offsets, entries, tile_order, width, height, tiles_x, final_t,
         walk) = ctx.state
        m = params.shape[0]
        channels = values_sorted.shape[1]
        device = grad_image.device if grad_image is not None else grad_alpha.device
        g_image = (np.zeros((height, width, channels)) if grad_image is None else as_float64(grad_image))
        g_alpha = (np.zeros((height, width)) if grad_alpha is None else as_float64(grad_alpha)[..., 0].copy())

        entry_grads = np.zeros((entries.shape[0], _GRAD_GEOMETRY_COLUMNS + channels), np.float64)
        if entries.shape[0] > 0:
            with _tile_scheduling():
                _backward_kernel(params, values_sorted, rects, offsets, entries, tile_order, width, height,
                                 tiles_x, final_t, walk, g_image, g_alpha, entry_grads)
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
