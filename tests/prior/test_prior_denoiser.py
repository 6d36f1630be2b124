"""UNet + ControlNet-style branch: shapes, the zero-initialised branch, gradients."""

from __future__ import annotations

import pytest
import torch

from inceptiongs.prior.controlnet import ConditionalDenoiser
from inceptiongs.prior.unet import UNet, UNetConfig, timestep_embedding


pytestmark = pytest.mark.usefixtures("one_torch_thread")


TINY = UNetConfig(image_channels=3, base_width=8, channel_mults=(1, 2, 2), time_dim=16)


def _inputs(batch=2, size=16, cond_channels=12, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(batch, 3, size, size, generator=g)
    cond = torch.randn(batch, cond_channels, size, size, generator=g)
    t = torch.randint(0, 1000, (batch,), generator=g)
    return x, t, cond


def test_unet_shapes_and_size_check():
    unet = UNet(TINY)
    x, t, _ = _inputs(size=20)
    assert unet(x, t).shape == x.shape
    with pytest.raises(ValueError):
        unet(torch.zeros(1, 3, 18, 20), t[:1])  # 18 is not a multiple of 4


def test_timestep_embedding_distinguishes_timesteps():
    emb = timestep_embedding(torch.tensor([0, 1, 500, 999]), 32)
    assert emb.shape == (4, 32)
    assert torch.isfinite(emb).all()
    assert torch.cdist(emb, emb).fill_diagonal_(1.0).min() > 0.1


def test_zero_initialised_branch_leaves_output_unchanged_at_step_0():
    torch.manual_seed(0)
    model = ConditionalDenoiser(TINY, cond_channels=12)
    x, t, cond = _inputs()
    with torch.no_grad():
        plain = model(x, t, None)
        conditioned = model(x, t, cond)
        other_condition = model(x, t, cond * 5.0 + 1.0)
    assert torch.equal(plain, conditioned)
    assert torch.equal(plain, other_condition)
    # The branch started as an exact copy of the UNet's encoder (ControlNet's initialisation).
    for (name, a), (_, b) in zip(model.unet.encoder.named_parameters(), model.control.encoder.named_parameters()):
        assert torch.equal(a, b), name


def test_branch_learns_after_one_step():
    # The zero convs get gradients at step 0 (their inputs are non-zero), so one optimiser
    # step makes the output depend on the condition.
    torch.manual_seed(0)
    model = ConditionalDenoiser(TINY, cond_channels=12)
    x, t, cond = _inputs()
    loss = (model(x, t, cond) - torch.randn_like(x)).pow(2).mean()
    loss.backward()
    zero_conv_grad = sum(float(c.weight.grad.abs().sum()) for c in model.control.zero_convs)
    assert zero_conv_grad > 0
    torch.optim.SGD(model.parameters(), lr=0.1).step()
    with torch.no_grad():
        assert not torch.allclose(model(x, t, None), model(x, t, cond))


def test_condition_shape_is_checked():
    model = ConditionalDenoiser(TINY, cond_channels=12)
    x, t, cond = _inputs()
    with pytest.raises(ValueError):
        model(x, t, cond[:, :5])
