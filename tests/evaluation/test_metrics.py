"""PSNR and SSIM against hand-checked cases and an independent numpy SSIM."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inceptiongs.evaluation.metrics import psnr, ssim, ssim_map


def numpy_ssim(x: np.ndarray, y: np.ndarray, window: int = 11, sigma: float = 1.5) -> float:
    """Independent SSIM: explicit 2-D Gaussian window summed at every valid position
    (loops, no convolution), population statistics, Wang's constants, mean over channels."""
    half = window // 2
    grid = np.arange(window) - half
    kernel = np.exp(-(grid[:, None] ** 2 + grid[None, :] ** 2) / (2 * sigma**2))
    kernel /= kernel.sum()
    c1, c2 = 0.01**2, 0.03**2
    height, width, channels = x.shape
    values = []
    for c in range(channels):
        for i in range(height - window + 1):
            for j in range(width - window + 1):
                px = x[i:i + window, j:j + window, c]
                py = y[i:i + window, j:j + window, c]
                mx, my = (kernel * px).sum(), (kernel * py).sum()
                vx = (kernel * (px - mx) ** 2).sum()
                vy = (kernel * (py - my) ** 2).sum()
                cxy = (kernel * (px - mx) * (py - my)).sum()
                values.append((2 * mx * my + c1) * (2 * cxy + c2) / ((mx**2 + my**2 + c1) * (vx + vy + c2)))
    return float(np.mean(values))


def test_identical_images_psnr_inf_ssim_one():
    image = torch.rand(20, 24, 3, generator=torch.Generator().manual_seed(0))
    assert math.isinf(float(psnr(image, image))) and float(psnr(image, image)) > 0
    assert float(ssim(image, image)) == pytest.approx(1.0, abs=1e-6)


def test_psnr_of_constant_offset_is_analytic():
    # Every pixel off by d: MSE = d^2, PSNR = -20 log10(d).
    target = torch.full((16, 16, 3), 0.5, dtype=torch.float64)
    for d in (0.1, 0.01, 0.25):
        assert float(psnr(target + d, target)) == pytest.approx(-20 * math.log10(d), abs=1e-9)


def test_psnr_of_known_noise():
    # +-sigma noise (random signs): MSE is exactly sigma^2.
    rng = np.random.default_rng(1)
    target = torch.as_tensor(rng.uniform(0.2, 0.8, (32, 32, 3)))
    sigma = 0.05
    noisy = target + sigma * torch.as_tensor(rng.choice([-1.0, 1.0], size=(32, 32, 3)))
    assert float(psnr(noisy, target)) == pytest.approx(10 * math.log10(1 / sigma**2), abs=1e-9)


def test_psnr_mask_ignores_unmasked_pixels():
    target = torch.zeros(8, 8, 3, dtype=torch.float64)
    pred = target.clone()
    pred[:4] = 0.1   # error 0.1 in the top half
    pred[4:] = 0.9   # huge error in the bottom half, masked out
    mask = torch.zeros(8, 8, dtype=torch.bool)
    mask[:4] = True
    assert float(psnr(pred, target, mask)) == pytest.approx(20.0, abs=1e-9)
    assert float(psnr(pred, target, mask[..., None])) == pytest.approx(20.0, abs=1e-9)
    with pytest.raises(ValueError):
        psnr(pred, target, torch.zeros(8, 8, dtype=torch.bool))


def test_batch_layout_matches_single_images():
    gen = torch.Generator().manual_seed(2)
    a = torch.rand(2, 3, 18, 21, generator=gen)
    b = (a + 0.1 * torch.randn(2, 3, 18, 21, generator=gen)).clamp(0, 1)
    batch_psnr, batch_ssim = psnr(a, b), ssim(a, b)
    assert batch_psnr.shape == (2,) and batch_ssim.shape == (2,)
    for k in range(2):
        single_a, single_b = a[k].permute(1, 2, 0), b[k].permute(1, 2, 0)
        assert float(batch_psnr[k]) == pytest.approx(float(psnr(single_a, single_b)), rel=1e-5)
        assert float(batch_ssim[k]) == pytest.approx(float(ssim(single_a, single_b)), rel=1e-5)


@pytest.mark.parametrize("noise", [0.02, 0.2])
def test_ssim_matches_independent_numpy(noise):
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (19, 23, 3))
    # A structured image too, so the covariance term matters.
    x[:, :, 0] = np.linspace(0, 1, 23)[None, :]
    y = np.clip(x + noise * rng.standard_normal(x.shape), 0, 1)
    expected = numpy_ssim(x, y)
    got = float(ssim(torch.as_tensor(x), torch.as_tensor(y)))
    assert got == pytest.approx(expected, abs=1e-10)
    assert float(ssim(torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(y, dtype=torch.float32))) \
        == pytest.approx(expected, abs=1e-5)


def test_ssim_is_differentiable_and_gradcheck():
    gen = torch.Generator().manual_seed(4)
    target = torch.rand(12, 13, 1, dtype=torch.float64, generator=gen)
    pred = torch.rand(12, 13, 1, dtype=torch.float64, generator=gen).requires_grad_()
    assert torch.autograd.gradcheck(lambda p: ssim(p, target, window=5), (pred,))
    # Descending 1 - SSIM brings the images together.
    pred32 = torch.rand(16, 16, 3, generator=gen).requires_grad_()
    target32 = torch.rand(16, 16, 3, generator=gen)
    start = float(ssim(pred32.detach(), target32))
    optimizer = torch.optim.Adam([pred32], lr=0.02)
    for _ in range(30):
        optimizer.zero_grad()
        (1 - ssim(pred32, target32)).backward()
        optimizer.step()
    assert float(ssim(pred32.detach(), target32)) > start + 0.2


def test_ssim_rejects_bad_shapes():
    with pytest.raises(ValueError):
        ssim(torch.rand(8, 8, 3), torch.rand(8, 8, 3))  # smaller than the 11 window
    with pytest.raises(ValueError):
        ssim(torch.rand(16, 16, 3), torch.rand(16, 17, 3))
    assert ssim_map(torch.rand(16, 20, 3), torch.rand(16, 20, 3)).shape == (3, 6, 10)
