"""Compositing of the preprocessed splats on the CPU cores, for software GL (llvmpipe).

On llvmpipe the "GPU" is the same two CPU cores, and its fragment pipeline is the wrong tool
for splats: every fragment of every quad is rasterised, even one the depth test rejects
(measured ~3 ns per fragment rejected, ~5-10 ns shaded), and blending cannot stop a pixel
early. A 1280x720 view of donut.ply covers ~94 M quad fragments while the front-to-back
stop rule needs only ~14 M Gaussian-pixel evaluations; compute shaders do not help either
(llvmpipe scalarises every buffer or texture load of a per-pixel loop). So on software GL the
renderer preprocesses on the CPU cores too (renderer/preprocess_numba.py: projection, SH,
culling, the preprocess shader's rules) and composites here:

* Gaussian-major inside horizontal bands of rows: each band walks the visible Gaussians
  front to back and, per row of a Gaussian's footprint, only the pixel span where
  alpha >= ALPHA_MIN can hold (the exact roots of the row's quadratic, widened so rounding
  can never drop a pixel: the per-pixel test still decides);
* per pixel exactly the compositing contract of the torch rasterizer and of the fragment
  shader (``shaders/splat_draw.frag``): power < 0 or alpha < ALPHA_MIN skip, alpha capped
  at ALPHA_MAX, stop before the Gaussian that would take the transmittance below
  TRANSMITTANCE_MIN; a finished pixel costs one load and a branch afterwards;
* bands interleaved over the threads, so a scene in the middle of the image loads all cores;
* a band keeps a count of live pixels per block of BLOCK_COLS columns: a Gaussian whose
  columns only cover finished blocks is passed over without setting up its rows (behind a
  surface that stopped, most of a dense scene is);
* a band's running sums and transmittance are float64 while it is composited and written to
  the float32 image when it is done: float32 storage cost a conversion pair per value per
  pixel, the single largest item of the pixel loop (measured: the donut frame ~25% slower).

The result has the fragment path's layout: [H, W, 4] float32, rgb = sum of T * alpha * value,
a = transmittance, negated once the pixel stopped; row 0 = image top (pixel y).
"""

from __future__ import annotations

import math

import numpy as np
from numba import get_num_threads, njit, prange

from inceptiongs.constants import ALPHA_MAX, ALPHA_MIN, RECURRENCE_CONIC_MAX, TRANSMITTANCE_MIN
from inceptiongs.rasterizer.numba_spans import next_pixel_ratio, row_span

# Rows per band: small enough that bands balance over threads, large enough that walking
# the Gaussian list once per band stays cheap (the walk is O(bands x Gaussians)).
BAND_ROWS = 16
# Relative slack added to a footprint's level when computing its pixel spans. Only a
# shortcut bound: far above float64 rounding, and every pixel in a span takes the exact test.
SPAN_SLACK = 1e-6
# Columns per block of the per-band live-pixel counts.
BLOCK_COLS = 16


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
def _next_alive(skip, base, x):
    """Smallest column >= x of the row starting at skip[base] whose pixel has not finished
    (width if none). skip[base + x] == x for a live pixel; a finished pixel points further
    right. Path halving keeps a run of finished pixels one or two hops long."""
    while skip[np.uint64(base + x)] != x:
        following = skip[np.uint64(base + skip[np.uint64(base + x)])]
        skip[np.uint64(base + x)] = following
        x = following
    return x


@njit(cache=True, inline="always")
def _blend(image, skip, live, pixel, base, x, alpha, value_r, value_g, value_b):
    """Composite one Gaussian at one live pixel (image index ``pixel``, column x); True if
    the stop rule finished the pixel."""
    if not (alpha >= ALPHA_MIN):
        return False
    alpha = min(alpha, ALPHA_MAX)
    p = np.uint64(pixel)
    trans = image[p + np.uint64(3)]
    following = trans * (1.0 - alpha)
    if following < TRANSMITTANCE_MIN:
        image[p + np.uint64(3)] = -trans
        skip[np.uint64(base + x)] = x + 1  # finished: later spans hop over it
        live[x // BLOCK_COLS] -= 1
        return True
    weight = trans * alpha
    image[p] += weight * value_r
    image[p + np.uint64(1)] += weight * value_g
    image[p + np.uint64(2)] += weight * value_b
    image[p + np.uint64(3)] = following
    return False


# The two pixel-loop helpers take arrays but never allocate: without the runtime's reference
# counting (_nrt=False) a call costs no atomic increments on its array arguments, which made
# a per-span call twice as slow as the loop itself.
@njit(cache=True, nogil=True, _nrt=False)
def _stepped_run(image, skip, live, pixel0, base, x, x1, gaussian, ratio, step_factor, opacity,
                 value_r, value_g, value_b):
    """Composite the run of live pixels from x (<= x1) on, exp(-power) stepped along the row:
    power is quadratic in x, so the ratio of neighbours is itself geometric (factor
    step_factor). Returns the column after the run: x1 + 1, or a finished pixel to hop from.
    Kept apart from the row set-up so its few values stay in registers."""
    while True:
        finished = _blend(image, skip, live, pixel0 + 4 * x, base, x, opacity * gaussian,
                          value_r, value_g, value_b)
        x += 1
        if finished or x > x1 or skip[np.uint64(base + x)] != x:
            return x
        gaussian *= ratio
        ratio *= step_factor


@njit(cache=True, nogil=True, _nrt=False)
def _composite_row(image, skip, live, pixel0, base, x0, x1, mx, dy, ca, cb, cc, opacity,
                   value_r, value_g, value_b, stepping, step_factor):
    """One Gaussian over the columns x0..x1 of one row, x0 live: image[pixel0 + 4 x ...] is
    the row's pixel x, skip[base + x] its skip pointer."""
    x = x0
    while x <= x1:
        dx = x + 0.5 - mx
        power = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
        if not (power >= 0.0):
            # Negative only by rounding (the conic is positive definite): skipped, as by
            # the fragment shader and torch; NaN likewise.
            x = _next_alive(skip, base, x + 1)
            continue
        gaussian = math.exp(-power)
        if stepping:
            # Within a span |ca (x + 1/2 - centre)| <= sqrt(ca level) + 2 ca < 15: no overflow.
            ratio = next_pixel_ratio(ca, cb, dx, dy)
            x = _stepped_run(image, skip, live, pixel0, base, x, x1, gaussian, ratio, step_factor,
                             opacity, value_r, value_g, value_b)
        else:
            _blend(image, skip, live, pixel0 + 4 * x, base, x, opacity * gaussian,
                   value_r, value_g, value_b)
            x += 1
        if x <= x1:
            x = _next_alive(skip, base, x)


@njit(parallel=True, cache=True, nogil=True)  # nogil: a training thread keeps running
def _composite(splats, order, width, height, threads, out):
    """splats: [N, 4, 4] float32 preprocess output (screen: mean x, y, major axis; conic a, b,
    c, opacity; value rgb, z; minor axis). order: [M] int64 visible Gaussians front to back.
    out: [H, W, 4] float32, overwritten (see module docstring)."""
    m = order.shape[0]
    blocks = (width + BLOCK_COLS - 1) // BLOCK_COLS
    # Per Gaussian, in draw order so the band walks read memory sequentially: row range,
    # range of column blocks, and the terms of its row spans and pixel test: the float32 values
    # as the preprocess wrote them (exact in float64 when read; half the bytes of float64
    # copies, 130 MB less at 3.7M splats) and the span cut, computed in float64.
    y_lo = np.empty(m, np.int32)
    y_hi = np.empty(m, np.int32)
    block_lo = np.empty(m, np.int32)
    block_hi = np.empty(m, np.int32)
    terms = np.empty((m, 9), np.float32)
    cuts = np.empty(m)
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
        # Columns likewise (cov_xx = cc / det), widened as the row spans are; NaN: all.
        extent_x = math.sqrt(level * cc / det)
        lo = max(mx - extent_x - 0.5, -1.0)
        hi = min(mx + extent_x - 0.5, width + 0.0)
        if not (lo <= hi):
            lo = -1.0
            hi = width + 0.0
        block_lo[k] = max(int(math.floor(lo)) - 1, 0) // BLOCK_COLS
        block_hi[k] = min(int(math.ceil(hi)) + 1, width - 1) // BLOCK_COLS
        terms[k, 0] = splats[g, 0, 0]
        terms[k, 1] = splats[g, 0, 1]
        terms[k, 2] = splats[g, 1, 0]
        terms[k, 3] = splats[g, 1, 1]
        terms[k, 4] = splats[g, 1, 2]
        terms[k, 5] = splats[g, 1, 3]
        terms[k, 6] = splats[g, 2, 0]
        terms[k, 7] = splats[g, 2, 1]
        terms[k, 8] = splats[g, 2, 2]
        # Row spans (below) cut power at level / 2: level is twice the power bound.
        cuts[k] = 0.5 * level
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
    band_list = np.empty(band_start[bands], np.int32)   # m < 2^31: indices into the draw order
    for k in range(m):
        if y_lo[k] <= y_hi[k]:
            for band in range(y_lo[k] // BAND_ROWS, y_hi[k] // BAND_ROWS + 1):
                band_list[band_fill[band]] = k
                band_fill[band] += 1
    image = out.reshape(-1)  # rows of 4 width floats; a band's rows are contiguous
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
        # The band's running sums and T in float64 (no conversions in the pixel loop),
        # written to the float32 image when the band is done.
        acc = np.empty(4 * width * BAND_ROWS)
        for p in range(0, 4 * width * (row1 - row0), 4):
            acc[p] = 0.0
            acc[p + 1] = 0.0
            acc[p + 2] = 0.0
            acc[p + 3] = 1.0
        # Skip pointers, one row of width + 1 per image row (width: the sentinel "no live
        # pixel further right"), and the live pixels per block of BLOCK_COLS columns, so a
        # Gaussian over finished blocks only is passed over whole.
        skip = np.empty(BAND_ROWS * (width + 1), np.int32)
        for row in range(BAND_ROWS):
            for x in range(width + 1):
                skip[row * (width + 1) + x] = x
        live = np.empty(blocks, np.int32)
        for b in range(blocks):
            live[b] = (min(width, (b + 1) * BLOCK_COLS) - b * BLOCK_COLS) * (row1 - row0)
        for entry in range(band_start[band], band_start[band + 1]):
            k = band_list[entry]
            reaches_live = False
            for b in range(block_lo[k], block_hi[k] + 1):
                if live[b] > 0:
                    reaches_live = True
                    break
            if not reaches_live:
                continue
            mx = np.float64(terms[k, 0])
            my = np.float64(terms[k, 1])
            ca = np.float64(terms[k, 2])
            cb = np.float64(terms[k, 3])
            cc = np.float64(terms[k, 4])
            cut = cuts[k]
            # The per-pixel recurrence is used where its factors stay far from float64
            # over/underflow; its relative drift over n pixels is ~n^2 * 1e-16.
            step_factor = math.exp(-ca)
            recurrence = ca < RECURRENCE_CONIC_MAX
            for y in range(max(y_lo[k], row0), min(y_hi[k] + 1, row1)):
                dy = y + 0.5 - my
                # Conservative span (the per-pixel test decides); NaN terms give the whole row
                # without the recurrence.
                x0, x1, parabola = row_span(ca, cb, cc, cut, mx, dy, 0, width - 1)
                if x0 > x1:
                    continue
                stepping = recurrence and parabola
                base = (y - row0) * (width + 1)
                x0 = _next_alive(skip, base, x0)
                if x0 > x1:
                    continue  # every pixel of the span has finished: no call
                _composite_row(acc, skip, live, 4 * width * (y - row0), base, x0, x1,
                               mx, dy, ca, cb, cc, np.float64(terms[k, 5]), np.float64(terms[k, 6]),
                               np.float64(terms[k, 7]), np.float64(terms[k, 8]), stepping, step_factor)
        base = 4 * width * row0
        for p in range(4 * width * (row1 - row0)):
            image[base + p] = acc[p]


def composite_splats(splats: np.ndarray, order: np.ndarray, width: int, height: int,
                     out: np.ndarray | None = None) -> np.ndarray:
    """splats: [N, 4, 4] float32 (the preprocess output); order: [M] indices of the visible
    Gaussians front to back. Returns [H, W, 4] float32: rgb = sum T alpha value, a = final
    transmittance, negated where the stop rule finished the pixel. ``out`` is reused when
    its shape fits."""
    if out is None or out.shape != (height, width, 4) or out.dtype != np.float32 \
            or not out.flags.c_contiguous:
        out = np.empty((height, width, 4), np.float32)
    _composite(np.ascontiguousarray(splats, np.float32).reshape(-1, 4, 4),
               np.ascontiguousarray(order, np.int64), int(width), int(height), get_num_threads(), out)
    return out


@njit(parallel=True, cache=True, nogil=True)
def _colour_over(raw, background, out):
    """out[y, x] = raw[y, x, :3] + |raw[y, x, 3]| * background (T is negated once stopped)."""
    for y in prange(raw.shape[0]):
        for x in range(raw.shape[1]):
            trans = abs(raw[y, x, 3])
            for c in range(3):
                out[y, x, c] = raw[y, x, c] + trans * background[c]


def colour_over_background(raw: np.ndarray, background) -> np.ndarray:
    """raw: [H, W, 4] float32 as composite_splats returns it; background: 3 floats. Returns a
    new [H, W, 3] float32: colour + T * background. (numpy's strided copy of the rgb planes
    alone takes ~9 ms at 1280x720 here, this ~2 ms on two threads.)"""
    out = np.empty(raw.shape[:2] + (3,), np.float32)
    _colour_over(raw, np.asarray(background, np.float32).reshape(3), out)
    return out
