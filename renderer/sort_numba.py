"""The CPU compositing's front-to-back order in numba: :func:`.sorting.visible_depth_order`
without its [N] float64 and uint64 temporaries, and sorted in parallel.

The visible Gaussians come in ascending index order, so a *stable* sort by the float32 depth
alone gives the contract's order (depth, ties by index). Depths are >= NEAR_PLANE > 0, where a
float32's bits read as uint32 rise with the value: three passes of a stable 11-bit counting
sort (lowest bits first) sort them, each pass counted and scattered by every thread over its
own contiguous share of the input, in order, which keeps it stable. On 3.7M visible splats (two
shared cores) 0.14-0.23 s against 0.20-0.33 s for the numpy keys and sort, with the depths'
bits and the order, twice each (24 bytes a splat), instead of the numpy route's gathered means,
float64 depths and uint64 keys (about 80).
"""

from __future__ import annotations

import numpy as np
from numba import get_num_threads, njit, prange

# 11-bit digits, three passes over the 32 bits: 2,048 counters per thread stay in cache while
# the scatter writes (16-bit digits, two passes, scattered into 65,536 places and were slower).
_DIGIT_BITS = 11
_DIGITS = 1 << _DIGIT_BITS


@njit(parallel=True, fastmath=False, cache=True)
def _depths(relative_means, candidates, rotation_z, translation_z):
    """[C] float32 camera z of each candidate, computed in float64; -> (depths, all finite and > 0)."""
    depths = np.empty(len(candidates), np.float32)
    bad = 0
    for i in prange(len(candidates)):
        row = candidates[i]
        z = np.float32(np.float64(relative_means[row, 0]) * rotation_z[0]
                       + np.float64(relative_means[row, 1]) * rotation_z[1]
                       + np.float64(relative_means[row, 2]) * rotation_z[2] + translation_z)
        depths[i] = z
        if not (z > 0.0 and np.isfinite(z)):
            bad += 1
    return depths, bad == 0


@njit(parallel=True, cache=True)
def _stable_sort_by_bits(bits, values, shares):
    """values [C] reordered by bits [C] uint32, ascending and stable (module doc)."""
    n = len(bits)
    src_bits, src_values = bits.copy(), values.copy()
    dst_bits, dst_values = np.empty_like(bits), np.empty_like(values)
    bounds = np.linspace(0, n, shares + 1).astype(np.int64)
    for shift in range(0, 32, _DIGIT_BITS):
        counts = np.zeros((shares, _DIGITS), np.int64)
        for share in prange(shares):
            for i in range(bounds[share], bounds[share + 1]):
                counts[share, (src_bits[i] >> shift) & (_DIGITS - 1)] += 1
        total = 0   # exclusive prefix over (digit, share): where each share's run of a digit starts
        for digit in range(_DIGITS):
            for share in range(shares):
                count = counts[share, digit]
                counts[share, digit] = total
                total += count
        for share in prange(shares):
            for i in range(bounds[share], bounds[share + 1]):
                digit = (src_bits[i] >> shift) & (_DIGITS - 1)
                at = counts[share, digit]
                counts[share, digit] = at + 1
                dst_bits[at], dst_values[at] = src_bits[i], src_values[i]
        src_bits, dst_bits = dst_bits, src_bits
        src_values, dst_values = dst_values, src_values
    return src_values


def sorted_visible(relative_means: np.ndarray, candidates: np.ndarray, rotation_z: np.ndarray,
                   translation_z: float) -> np.ndarray | None:
    """candidates [C] ascending int -> [C] int64 in front-to-back order, or None when a depth is
    not finite and positive (the caller's general route then applies)."""
    candidates = np.asarray(candidates, np.int64)
    depths, ok = _depths(relative_means, candidates, np.asarray(rotation_z, np.float64), float(translation_z))
    if not ok:
        return None
    return _stable_sort_by_bits(depths.view(np.uint32), candidates, max(1, get_num_threads()))
