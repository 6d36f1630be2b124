"""The CPU compositor of the GL renderer (renderer/cpu_composite.py) against a brute-force
evaluation of the compositing contract over every pixel, on hand-built projected splats:
wide footprints (long spans, where exp(-power) is stepped by the recurrence), needles, a
footprint far larger than the image, culled entries, and a stack opaque enough that the stop
rule finishes pixels (which later spans must hop over)."""

from __future__ import annotations

import numpy as np
import pytest

from inceptiongs.constants import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN

pytest.importorskip("numba")
from inceptiongs.renderer.cpu_composite import composite_splats  # noqa: E402

WIDTH, HEIGHT = 72, 53


def splat_rows(means, sigmas, angles, opacities, colours) -> np.ndarray:
    """[N, 4, 4] float32 in the preprocess layout: (mean x, y, -, -), (conic a, b, c,
    opacity), (rgb, z), (-). Covariance R diag(sigma^2) R^T plus the 0.3 px^2 dilation."""
    n = len(means)
    rows = np.zeros((n, 4, 4), np.float32)
    for i in range(n):
        c, s = np.cos(angles[i]), np.sin(angles[i])
        rotation = np.array([[c, -s], [s, c]])
        cov = rotation @ np.diag(np.square(sigmas[i])) @ rotation.T + 0.3 * np.eye(2)
        inverse = np.linalg.inv(cov)
        rows[i, 0, :2] = means[i]
        rows[i, 1] = (inverse[0, 0], inverse[0, 1], inverse[1, 1], opacities[i])
        rows[i, 2, :3] = colours[i]
    return rows


def brute_force(rows: np.ndarray, order: np.ndarray, width: int, height: int) -> np.ndarray:
    """The contract at every pixel centre, float64: [H, W, 4] like composite_splats."""
    x, y = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    rgb = np.zeros((height, width, 3))
    trans = np.ones((height, width))
    finished = np.zeros((height, width), bool)
    for g in order:
        (mx, my), (a, b, c, opacity) = rows[g, 0, :2].astype(np.float64), rows[g, 1].astype(np.float64)
        dx, dy = x - mx, y - my
        power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = np.minimum(ALPHA_MAX, opacity * np.exp(-np.maximum(power, 0.0)))
        hit = (power >= 0.0) & (alpha >= ALPHA_MIN) & ~finished
        following = trans * (1.0 - alpha)
        stop = hit & (following < TRANSMITTANCE_MIN)
        add = hit & ~stop
        rgb[add] += (trans * alpha)[add, None] * rows[g, 2, :3].astype(np.float64)
        trans = np.where(add, following, trans)
        finished |= stop
    return np.concatenate([rgb, np.where(finished, -trans, trans)[..., None]], axis=2)


def test_matches_the_contract_at_every_pixel():
    rng = np.random.default_rng(0)
    n = 300
    means = rng.uniform([-10, -10], [WIDTH + 10, HEIGHT + 10], (n, 2))
    sigmas = np.exp(rng.uniform(-1.0, 2.5, (n, 2)))  # ~0.4 to ~12 px
    sigmas[:20] = [[25.0, 18.0]] * 20  # wide: spans of 100+ px stepped by the recurrence
    sigmas[20:30] = [[40.0, 0.05]] * 10  # needles 800:1
    sigmas[30] = [2.0e4, 1.5e4]  # far larger than the image, centred outside it
    means[30] = [-500.0, 900.0]
    opacities = rng.uniform(0.05, 1.0, n)
    opacities[40:50] = 0.0  # culled by the preprocess pass
    opacities[50:150] = 0.999  # an opaque stack: the stop rule finishes many pixels
    rows = splat_rows(means, sigmas, rng.uniform(0, np.pi, n), opacities, rng.uniform(0, 1, (n, 3)))
    order = np.concatenate([np.arange(50, 150), np.arange(0, 50), np.arange(150, n)])
    order = order[rows[order, 1, 3] > 0]
    reference = brute_force(rows, order, WIDTH, HEIGHT)
    result = composite_splats(rows, order, WIDTH, HEIGHT)
    assert result.shape == (HEIGHT, WIDTH, 4) and result.dtype == np.float32
    finished = reference[..., 3] < 0
    assert 0.05 < finished.mean() < 0.95  # the stop rule really was exercised, and not everywhere
    np.testing.assert_array_equal(result[..., 3] < 0, finished)
    np.testing.assert_allclose(result, reference, atol=2e-5)


def test_empty_order_and_reuse_of_the_output_array():
    rows = splat_rows([[10.0, 10.0]], [[3.0, 3.0]], [0.0], [0.9], [[1.0, 0.5, 0.25]])
    empty = composite_splats(rows, np.zeros(0, np.int64), 16, 12)
    assert np.all(empty[..., :3] == 0.0) and np.all(empty[..., 3] == 1.0)
    out = np.full((12, 16, 4), 7.0, np.float32)
    again = composite_splats(rows, np.array([0]), 16, 12, out)
    assert again is out  # reused, and fully overwritten
    np.testing.assert_allclose(again, brute_force(rows, np.array([0]), 16, 12), atol=1e-6)
    assert again[10, 10, 0] > 0.5 and again[0, 15, 3] == pytest.approx(1.0, abs=1e-6)
