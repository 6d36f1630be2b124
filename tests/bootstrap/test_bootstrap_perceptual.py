"""The perceptual distance of the virtual-view loss: MS-SSIM-G and the LPIPS branch."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from inceptiongs.bootstrap.perceptual import (LPIPS_NAME, PERCEPTUAL_NAME, perceptual_distance,
                                              perceptual_name)


def _texture(h=48, w=64, seed=0) -> torch.Tensor:
    """A smooth random texture with edges: [h, w, 3] in [0, 1]."""
    gen = torch.Generator().manual_seed(seed)
    coarse = torch.rand(1, 3, h // 8, w // 8, generator=gen)
    smooth = F.interpolate(coarse, size=(h, w), mode="bilinear", align_corners=False)
    stripes = (torch.arange(w) // 6 % 2).float().expand(h, w)
    return (0.7 * smooth[0].permute(1, 2, 0) + 0.3 * stripes[..., None]).clamp(0, 1)


def _blur(image: torch.Tensor, sigma: float) -> torch.Tensor:
    radius = int(3 * sigma) + 1
    x = torch.arange(-radius, radius + 1, dtype=image.dtype)
    taps = torch.exp(-x ** 2 / (2 * sigma ** 2))
    taps = taps / taps.sum()
    batch = image.permute(2, 0, 1)[:, None]
    batch = F.conv2d(F.pad(batch, (radius, radius, 0, 0), mode="replicate"), taps.view(1, 1, 1, -1))
    batch = F.conv2d(F.pad(batch, (0, 0, radius, radius), mode="replicate"), taps.view(1, 1, -1, 1))
    return batch[:, 0].permute(1, 2, 0)


def test_zero_for_identical_images_and_named_honestly():
    image = _texture()
    assert float(perceptual_distance(image, image.clone())) == pytest.approx(0.0, abs=1e-6)
    assert perceptual_name() == PERCEPTUAL_NAME == "MS-SSIM-G"
    assert "LPIPS" not in PERCEPTUAL_NAME


def test_grows_with_blur_and_noise():
    image = _texture()
    blur = [float(perceptual_distance(image, _blur(image, s))) for s in (0.7, 1.5, 3.0)]
    assert 0 < blur[0] < blur[1] < blur[2]
    gen = torch.Generator().manual_seed(1)
    noise = torch.randn(image.shape, generator=gen)
    noisy = [float(perceptual_distance(image, (image + s * noise).clamp(0, 1))) for s in (0.02, 0.06, 0.2)]
    assert 0 < noisy[0] < noisy[1] < noisy[2]
    # Symmetric, and a different image is farther than a slightly blurred copy.
    other = _texture(seed=5)
    assert float(perceptual_distance(image, other)) > blur[0]
    assert float(perceptual_distance(image, other)) == pytest.approx(float(perceptual_distance(other, image)))


@pytest.mark.parametrize("case", ["different", "identical", "flat"])
def test_gradients_are_finite(case):
    target = _texture()
    if case == "flat":
        target = torch.full_like(target, 0.4)
    start = {"different": _blur(target, 1.5), "identical": target.clone(), "flat": target.clone()}[case]
    pred = start.clone().requires_grad_(True)
    perceptual_distance(pred, target).backward()
    assert torch.isfinite(pred.grad).all()
    if case == "different":
        assert pred.grad.abs().sum() > 0
        # A small step against the gradient lowers the distance.
        with torch.no_grad():
            stepped = pred - 0.02 * pred.grad / pred.grad.abs().max()
        assert float(perceptual_distance(stepped, target)) < float(perceptual_distance(start, target))


class _FakeLpips(torch.nn.Module):
    """Stands in for LPIPS weights: mean squared difference of 3x3 pooled images."""

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return ((F.avg_pool2d(pred, 3) - F.avg_pool2d(target, 3)) ** 2).mean().reshape(1, 1, 1, 1)


def test_lpips_branch_uses_the_callable(tmp_path):
    seen = []

    def spy(pred, target):
        seen.append((pred.shape, float(pred.min()), float(pred.max())))
        return torch.tensor([[0.123]])

    image = _texture()
    value = perceptual_distance(image, _blur(image, 1.0), lpips=spy)
    assert float(value) == pytest.approx(0.123) and value.ndim == 0
    assert seen[0][0] == (1, 3, 48, 64)
    assert seen[0][1] < -0.3 and seen[0][2] > 0.3  # rescaled to [-1, 1]
    assert perceptual_name(spy) == LPIPS_NAME

    # A network as the bootstrap loads user weights; differentiable.
    network = _FakeLpips()
    pred = _blur(image, 1.0).requires_grad_(True)
    value = perceptual_distance(pred, image, lpips=network)
    expected = ((F.avg_pool2d(pred.permute(2, 0, 1)[None] * 2 - 1, 3)
                 - F.avg_pool2d(image.permute(2, 0, 1)[None] * 2 - 1, 3)) ** 2).mean()
    assert float(value.detach()) == pytest.approx(float(expected.detach()))
    assert float(value.detach()) != pytest.approx(float(perceptual_distance(pred.detach(), image)))
    value.backward()
    assert torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0


def test_bad_shapes():
    with pytest.raises(ValueError):
        perceptual_distance(torch.zeros(20, 20, 3), torch.zeros(20, 21, 3))
    with pytest.raises(ValueError, match="window"):
        perceptual_distance(torch.zeros(8, 8, 3), torch.zeros(8, 8, 3))
