"""The agreement gate (agreement.py): photos that agree with each other outvote a render that
disagrees with them; misplaced photos that only the render reconciles do not."""

from __future__ import annotations

import torch

from inceptiongs.bootstrap.agreement import MIN_COMMON_PIXELS, agreement_margin_db, masked_psnr
from inceptiongs.bootstrap.warp import WarpResult


def textured(height: int = 48, width: int = 64, shift: int = 0) -> torch.Tensor:
    """[h, w, 3] a smooth texture, moved ``shift`` pixels to the right (a misplaced warp)."""
    y, x = torch.meshgrid(torch.arange(height, dtype=torch.float32), torch.arange(width, dtype=torch.float32),
                          indexing="ij")
    x = x - shift
    grey = 0.5 + 0.3 * torch.sin(0.45 * x) * torch.cos(0.3 * y)
    return torch.stack([grey, 0.8 * grey, 0.6 * grey + 0.1], -1)


def warp(image: torch.Tensor, mask: torch.Tensor | None = None) -> WarpResult:
    mask = torch.ones(*image.shape[:2], 1) if mask is None else mask
    return WarpResult(image=image * mask, mask=mask)


def test_photos_that_agree_outvote_a_wrong_render():
    truth = textured()
    noise = torch.Generator().manual_seed(0)
    photos = [warp((truth + 0.01 * torch.randn(truth.shape, generator=noise)).clamp(0, 1)) for _ in range(3)]
    wrong_render = torch.full_like(truth, 0.5)                       # a blur: the mush of a far-off model
    margin = agreement_margin_db(wrong_render, photos)
    assert margin is not None and margin > 10.0


def test_misplaced_photos_lose_to_a_render_that_sits_between_them():
    truth = textured()
    photos = [warp(textured(shift=s)) for s in (-2, 2, 4)]           # each placed wrongly, differently
    margin = agreement_margin_db(truth, photos)
    assert margin is not None and margin < -1.0                      # left out at the default threshold


def test_no_overlap_no_verdict_and_the_pixel_floor():
    truth = textured()
    left = torch.zeros(48, 64, 1)
    left[:, :32] = 1
    assert agreement_margin_db(truth, [warp(truth, left), warp(truth, 1 - left)]) is None   # no common pixel
    assert agreement_margin_db(truth, [warp(truth)]) is None                               # one source
    few = torch.zeros(48, 64, dtype=torch.bool)
    few.view(-1)[:MIN_COMMON_PIXELS - 1] = True
    assert masked_psnr(truth, truth, few) is None
    few.view(-1)[MIN_COMMON_PIXELS - 1] = True
    assert masked_psnr(truth, truth, few) == 100.0                   # identical: the MSE floor, not inf
