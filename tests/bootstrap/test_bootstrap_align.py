"""align.align_warp: a warp that lands a few pixels off is moved back onto the render; a large
shift is left untrusted; holes in the warp stay holes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.bootstrap.experimental.align import MIN_SIZE_PX, align_warp
from inceptiongs.bootstrap.warp import WarpResult


def _texture(h: int = 96, w: int = 128, seed: int = 0) -> np.ndarray:
    """Smooth random texture [h, w, 3] in [0, 1] (blobs a few pixels wide: flow can lock on)."""
    import cv2
    rng = np.random.default_rng(seed)
    noise = rng.random((h, w, 3)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0) * 4.0 - 1.5, 0.0, 1.0)


def _shifted(image: np.ndarray, dx: int, dy: int) -> np.ndarray:
    return np.roll(np.roll(image, dy, axis=0), dx, axis=1)


def _warp(image: np.ndarray, mask: np.ndarray | None = None) -> WarpResult:
    mask = np.ones(image.shape[:2] + (1,), np.float32) if mask is None else mask
    return WarpResult(torch.from_numpy(image * mask), torch.from_numpy(mask))


def _error(a: torch.Tensor, b: np.ndarray, mask: torch.Tensor) -> float:
    keep = mask[..., 0].numpy() > 0
    return float(np.abs(a.numpy() - b)[keep].mean())


def test_a_small_shift_is_undone():
    render = _texture()
    warp = _warp(_shifted(render, 2, -1))
    aligned = align_warp(torch.from_numpy(render), warp, max_shift_px=3.0)
    inner = (slice(6, -6), slice(6, -6))  # the rolled border wraps around: judge the interior
    before = np.abs(warp.image.numpy() - render)[inner].mean()
    after = np.abs(aligned.image.numpy() - render)[inner][aligned.mask.numpy()[inner][..., 0] > 0].mean()
    assert float(aligned.mask.numpy()[inner].mean()) > 0.9
    assert after < 0.25 * before


def test_a_shift_beyond_the_limit_is_untrusted():
    render = _texture(seed=1)
    warp = _warp(_shifted(render, 8, 0))
    aligned = align_warp(torch.from_numpy(render), warp, max_shift_px=3.0)
    inner = (slice(12, -12), slice(12, -12))
    assert float(aligned.mask.numpy()[inner].mean()) < 0.2


def test_holes_stay_holes_and_trusted_colours_come_from_the_warp():
    render = _texture(seed=2)
    mask = np.ones(render.shape[:2] + (1,), np.float32)
    mask[30:60, 40:80] = 0.0
    photo = np.clip(render * 0.8 + 0.1, 0, 1)  # the photo's own colours, not the render's
    aligned = align_warp(torch.from_numpy(render), _warp(photo, mask), max_shift_px=3.0)
    m = aligned.mask.numpy()[..., 0]
    assert m[32:58, 42:78].max() == 0.0  # nothing inside the hole is trusted
    assert float(np.abs(aligned.image.numpy()[..., :][m > 0] - photo[m > 0]).mean()) < 0.02
    assert np.all(aligned.image.numpy()[m == 0] == 0.0)


def test_tiny_images_and_empty_warps_come_back_unchanged():
    small = _texture(MIN_SIZE_PX - 1, 40)
    warp = _warp(small)
    assert align_warp(torch.from_numpy(small), warp) is warp
    render = _texture()
    empty = _warp(render, np.zeros(render.shape[:2] + (1,), np.float32))
    assert align_warp(torch.from_numpy(render), empty) is empty
    with pytest.raises(ValueError):
        align_warp(torch.from_numpy(render), _warp(render), max_shift_px=0.0)
