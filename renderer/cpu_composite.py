"""Compositing of the preprocessed splats on the CPU cores, for software GL (llvmpipe).

On llvmpipe the "GPU" is the same two CPU cores, and its fragment pipeline is the wrong tool
for splats: every fragment of every quad is rasterised, even one the depth test rejects
(measured ~3 ns per fragment rejected, ~5-10 ns shaded), and blending cannot stop a pixel
early. A 1280x720 view of donut.ply covers ~94 M quad fragments while the front-to-back
stop rule needs only ~14 M Gaussian-pixel evaluations; compute shaders do not help either
(llvmpipe scalarises every buffer or texture load of a per-pixel loop). So on software GL the
renderer keeps GL for the preprocess pass (projection, SH, culling) and composites here:

* Gaussian-major inside horizontal bands of rows: each band walks the visible Gaussians
  front to back and, per row of a Gaussian's footprint, only the pixel span where
  alpha >= ALPHA_MIN can hold (the exact roots of the row's quadratic, widened so rounding
  can never drop a pixel: the per-pixel test still decides);
* per pixel exactly the compositing contract of the torch rasterizer and of the fragment
  shader (``shaders/splat_draw.frag``): power < 0 or alpha < ALPHA_MIN skip, alpha capped
  at ALPHA_MAX, stop before the Gaussian that would take the transmittance below
  TRANSMITTANCE_MIN; a finished pixel costs one load and a branch afterwards;
* bands interleaved over the threads, so a scene in the middle of the image loads all cores.

The result has the fragment path's layout: [H, W, 4] float32, rgb = sum of T * alpha * value,
a = transmittance, negated once the pixel stopped; row 0 = image top (pixel y).
"""

from __future__ import annotations

import math

import numpy as np
from numba import get_num_threads, njit, prange

from inceptiongs.constants import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN

# Rows per band: small enough that bands balance over threads, large enough that walking
# the Gaussian list once per band stays cheap (the walk is O(bands x Gaussians)).
BAND_ROWS = 16
# Relative slack added to a footprint's level when computing its pixel spans. Only a
# shortcut bound: far above float64 rounding, and every pixel in a span takes the exact test.
SPAN_SLACK = 1e-6
# Conic x-coefficients (1 / pixels^2) up to which exp(-power) is stepped along a row by two
# multiplications instead of one exp() per pixel; beyond, footprints are a few pixels wide.
RECURRENCE_CONIC_MAX = 4.0


@njit(cache=True, inline="always")
def _footprint(conic_a, conic_b, conic_c, opacity):
    """(twice the level 2 L, det of the conic) of power <= L = log(opacity / ALPHA_MIN);
    level 0 when the Gaussian cannot reach ALPHA_MIN anywhere."""
    if not (opacity >= ALPHA_MIN and conic_a > 0.0):
        return 0.0, 0.0
    level = 2.0 * math.log(opacity / ALPHA_MIN)  # opacity >= ALPHA_MIN > 0
    level = level * (1.0 + SPAN_SLACK) + SPAN_SLACK
    det = conic_a * conic_c - conic_b * conic_b
    if not (det > 0.0 and level < math.inf and det < math.inf):
        return 0.0, 0.0
    return level, det


@njit(cache=True, inline="always")
def _next_alive(skip, y, x):
    """Smallest column >= x of row y whose pixel has not finished (width if none).

    skip[y, x] == x for a live pixel; a finished pixel points further right. Path halving
    keeps a run of finished pixels one or two hops long, so spans over surfaces that
    stopped long ago cost almost nothing."""
    while skip[y, x] != x:
        following = skip[y, skip[y, x]]
        skip[y, x] = following
        x = following
    return x


@njit(parallel=True, cache=True, nogil=True)  # nogil: a training thread keeps running
def _composite(splats, order, width, height, threads, out):
    """splats: [N, 4, 4] float32 preprocess output (screen: mean x, y, major axis; conic a, b,
    c, opacity; value rgb, z; minor axis). order: [M] int64 visible Gaussians front to back.
    out: [H, W, 4] float32, overwritten (see module docstring)."""
    m = order.shape[0]
    # Per Gaussian, in draw order so the band walks read memory sequentially: row range and
    # the float64 terms of its row spans and pixel test, and its value.
    y_lo = np.empty(m, np.int32)
    y_hi = np.empty(m, np.int32)
    terms = np.empty((m, 12))
    for k in prange(m):
        g = order[k]
        mx = np.float64(splats[g, 0, 0])
        my = np.float64(splats[g, 0, 1])
        ca = np.float64(splats[g, 1, 0])
        cb = np.float64(splats[g, 1, 1])
        cc = np.float64(splats[g, 1, 2])
        opacity = np.float64(splats[g, 1, 3])
        level, det = _footprint(ca, cb, cc, opacity)
        y_lo[k] = 1
        y_hi[k] = 0
        if level <= 0.0 or not (math.isfinite(mx) and math.isfinite(my)):
            continue
        # Rows: |dy| <= sqrt(level * cov_yy), cov_yy = ca / det (the conic's inverse).
        extent_y = math.sqrt(level * ca / det)
        lo = max(my - extent_y - 0.5, -1.0)
        hi = min(my + extent_y - 0.5, height + 0.0)
        if lo > hi:
            continue
        y_lo[k] = max(int(math.floor(lo)) - 1, 0)
        y_hi[k] = min(int(math.ceil(hi)) + 1, height - 1)
        terms[k, 0] = mx
        terms[k, 1] = my
        terms[k, 2] = ca
        terms[k, 3] = cb
        terms[k, 4] = cc
        terms[k, 5] = opacity
        terms[k, 6] = splats[g, 2, 0]
        terms[k, 7] = splats[g, 2, 1]
        terms[k, 8] = splats[g, 2, 2]
        # Row spans (below): centre mx - (cb / ca) dy, half-width sqrt(level / ca -
        # det / ca^2 dy^2); ca > 0. Overflow to inf gives NaN spans, handled there.
        terms[k, 9] = cb / ca
        terms[k, 10] = level / ca
        terms[k, 11] = det / ca / ca
    bands = (height + BAND_ROWS - 1) // BAND_ROWS
    # Per-band lists of Gaussians (counting sort by band, draw order kept within a band),
    # so a band walks only the Gaussians that reach it.
    band_start = np.zeros(bands + 1, np.int64)
    for k in range(m):
        if y_lo[k] <= y_hi[k]:
            for band in range(y_lo[k] // BAND_ROWS, y_hi[k] // BAND_ROWS + 1):
                band_start[band + 1] += 1
    for band in range(bands):
        band_start[band + 1] += band_start[band]
    band_fill = band_start[:-1].copy()
    band_list = np.empty(band_start[bands], np.int64)
    for k in range(m):
        if y_lo[k] <= y_hi[k]:
            for band in range(y_lo[k] // BAND_ROWS, y_hi[k] // BAND_ROWS + 1):
                band_list[band_fill[band]] = k
                band_fill[band] += 1
    threads = max(1, min(threads, bands))
    chunk = (bands + threads - 1) // threads
    # prange splits its range into contiguous chunks, one per thread; iteration i takes band
    # (i % chunk) * threads + i // chunk, so each thread gets every threads-th band.
    for i in prange(chunk * threads):
        band = (i % chunk) * threads + i // chunk
        if band >= bands:
            continue
        row0 = band * BAND_ROWS
        row1 = min(row0 + BAND_ROWS, height)
        # Band-local planes (one contiguous row per image row): the running sums and T.
        red = np.zeros((BAND_ROWS, width), np.float32)
        green = np.zeros((BAND_ROWS, width), np.float32)
        blue = np.zeros((BAND_ROWS, width), np.float32)
        transmittance = np.ones((BAND_ROWS, width), np.float32)
        skip = np.empty((BAND_ROWS, width + 1), np.int32)
        for row in range(BAND_ROWS):
            for x in range(width + 1):
                skip[row, x] = x  # width: the sentinel "no live pixel further right"
        for entry in range(band_start[band], band_start[band + 1]):
            k = band_list[entry]
            mx = terms[k, 0]
            my = terms[k, 1]
            ca = terms[k, 2]
            cb = terms[k, 3]
            cc = terms[k, 4]
            opacity = terms[k, 5]
            value_r = terms[k, 6]
            value_g = terms[k, 7]
            value_b = terms[k, 8]
            slope = terms[k, 9]
            half_squared = terms[k, 10]
            half_shrink = terms[k, 11]
            # The per-pixel recurrence is used where its factors stay far from float64
            # over/underflow; its relative drift over n pixels is ~n^2 * 1e-16.
            step_factor = math.exp(-ca)
            recurrence = ca < RECURRENCE_CONIC_MAX
            for y in range(max(y_lo[k], row0), min(y_hi[k] + 1, row1)):
                row = y - row0
                dy = y + 0.5 - my
                # Row span: ca dx^2 + 2 cb dy dx + cc dy^2 <= level, roots in dx.
                disc = half_squared - half_shrink * dy * dy
                if disc < 0.0:
                    continue
                half = math.sqrt(disc)
                centre = mx - slope * dy
                lo = centre - half - 0.5  # pixel x has its centre at x + 0.5
                hi = centre + half - 0.5
                stepping = recurrence
                if lo <= hi:
                    if hi < -1.0 or lo > width:
                        continue
                    # Clamped in float before the int conversion (huge spans), widened by
                    # one pixel so rounding cannot drop a pixel: the per-pixel test decides.
                    x0 = max(int(math.floor(max(lo, -1.0))) - 1, 0)
                    x1 = min(int(math.ceil(min(hi, width + 0.0))) + 1, width - 1)
                else:
                    # NaN from overflowing terms: the whole row, every pixel tested directly.
                    x0 = 0
                    x1 = width - 1
                    stepping = False
                x = _next_alive(skip, row, x0)
                previous = -2
                gaussian = 0.0
                ratio = 0.0
                while x <= x1:
                    if x == previous + 1 and stepping:
                        # exp(-power) one pixel right of the last: power is quadratic in x,
                        # so the ratio of neighbours is itself geometric (factor exp(-ca)).
                        gaussian *= ratio
                        ratio *= step_factor
                        previous = x
                    else:
                        dx = x + 0.5 - mx
                        power = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                        if not (power >= 0.0):
                            # Negative only by rounding (the conic is positive definite):
                            # skipped, as by the fragment shader and torch; NaN likewise.
                            x = _next_alive(skip, row, x + 1)
                            continue
                        gaussian = math.exp(-power)
                        if stepping:
                            # ca (dx + 1/2) + cb dy = power(x + 1) - power(x); within a span
                            # |ca (x + 1/2 - centre)| <= sqrt(ca level) + 2 ca < 15: no overflow.
                            ratio = math.exp(-(ca * (dx + 0.5) + cb * dy))
                            previous = x
                    alpha = opacity * gaussian
                    if alpha >= ALPHA_MIN:
                        alpha = min(alpha, ALPHA_MAX)
                        trans = np.float64(transmittance[row, x])
                        following = trans * (1.0 - alpha)
                        if following < TRANSMITTANCE_MIN:
                            transmittance[row, x] = -trans
                            skip[row, x] = x + 1  # finished: later spans hop over it
                        else:
                            weight = trans * alpha
                            red[row, x] += weight * value_r
                            green[row, x] += weight * value_g
                            blue[row, x] += weight * value_b
                            transmittance[row, x] = following
                    x = _next_alive(skip, row, x + 1)
        for y in range(row0, row1):
            for x in range(width):
                out[y, x, 0] = red[y - row0, x]
                out[y, x, 1] = green[y - row0, x]
                out[y, x, 2] = blue[y - row0, x]
                out[y, x, 3] = transmittance[y - row0, x]


def composite_splats(splats: np.ndarray, order: np.ndarray, width: int, height: int,
                     out: np.ndarray | None = None) -> np.ndarray:
    """splats: [N, 4, 4] float32 (the preprocess output); order: [M] indices of the visible
    Gaussians front to back. Returns [H, W, 4] float32: rgb = sum T alpha value, a = final
    transmittance, negated where the stop rule finished the pixel. ``out`` is reused when
    its shape fits."""
    if out is None or out.shape != (height, width, 4) or out.dtype != np.float32:
        out = np.empty((height, width, 4), np.float32)
    _composite(np.ascontiguousarray(splats, np.float32).reshape(-1, 4, 4),
               np.ascontiguousarray(order, np.int64), int(width), int(height), get_num_threads(), out)
    return out
