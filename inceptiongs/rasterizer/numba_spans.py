"""The per-row pieces both CPU compositors share (the differentiable one in
:mod:`.composite_numba` and the GL renderer's display compositor in
``renderer/cpu_composite.py``): which pixels of a row a Gaussian can reach, and the factor that
steps exp(-power) from one pixel to the next without calling exp() per pixel.

For a fixed row, power(dx) = 0.5 a dx^2 + b dy dx + 0.5 c dy^2 (a, b, c the conic; dx, dy from
the mean to the pixel centre). It is quadratic in dx, so exp(-power) of neighbouring pixels has
the ratio exp(-(a (dx + 1/2) + b dy)), itself shrinking by exp(-a) per pixel.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, inline="always")
def row_span(ca, cb, cc, cut, mx, dy, bx0, bx1):
    """Inclusive pixel columns of one row that may satisfy power <= cut, within [bx0, bx1].

    For a fixed row, power(dx) = 0.5 a dx^2 + b dy dx + 0.5 c dy^2 is a parabola in dx when
    a > 0, below the cut between the roots dx = (-b dy +- sqrt(D)) / a with
    D = 2 a cut - (a c - b^2) dy^2. The span is only a shortcut: every pixel in it still takes
    the exact test, so it is made conservative -- D is raised by a bound far above its
    rounding error and the span is widened by one pixel each side. Rows where the parabola
    form does not apply (a <= 0, non-finite terms) keep the whole box row. The third value is
    True only for a parabola span: there power stays within about the cut at every pixel,
    which the exp() recurrence of the kernels relies on."""
    if not (ca > 0.0 and cut < math.inf):
        return bx0, bx1, False
    dy2 = dy * dy
    disc = 2.0 * ca * cut - (ca * cc - cb * cb) * dy2
    disc += 1e-12 * ((abs(ca * cc) + cb * cb) * dy2 + abs(2.0 * ca * cut))
    if disc != disc:
        return bx0, bx1, False  # NaN terms: let the exact per-pixel test decide, as the contract does
    if disc < 0.0:
        return 1, 0, False  # the row lies wholly beyond the cut
    half = math.sqrt(disc) / ca
    centre = mx - cb * dy / ca
    lo = centre - half - 0.5  # pixel index i has its centre at i + 0.5
    hi = centre + half - 0.5
    if not (lo < math.inf and hi > -math.inf):
        return bx0, bx1, False
    if lo > bx1 or hi < bx0:
        return 1, 0, False
    return (max(bx0, int(math.floor(max(lo, bx0 - 1.0))) - 1),
            min(bx1, int(math.ceil(min(hi, bx1 + 1.0))) + 1), True)


@njit(cache=True, inline="always")
def next_pixel_ratio(ca, cb, dx, dy):
    """exp(-(power(dx + 1) - power(dx))) = exp(-(a (dx + 1/2) + b dy)): exp(-power) at the next
    pixel is this pixel's value times it; the next ratio is this one times exp(-a). Within a row
    span |a (dx + 1/2)| stays bounded (see the callers), so the exp cannot overflow there."""
    return math.exp(-(ca * (dx + 0.5) + cb * dy))
