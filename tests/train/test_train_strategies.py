"""3DGS-MCMC relocation and noise, DropGaussian's opacity compensation."""

from __future__ import annotations

import math

import pytest
import torch

import train_cases as tc
from inceptiongs.gaussians import Gaussians
from inceptiongs.rasterizer.rasterize import render
from inceptiongs.runs.config import TrainConfig
from inceptiongs.train.optim import make_optimizer, params_from_gaussians
from inceptiongs.train.strategy import (MCMC_NOISE_K, MCMC_NOISE_X0, drop_gaussians, drop_rate, grow, mcmc_noise,
                                        relocate, relocation_correction)


def _logit(p: float) -> float:
    return math.log(p / (1 - p))


def _model(opacities: list[float]) -> Gaussians:
    n = len(opacities)
    g = torch.Generator().manual_seed(0)
    means = torch.randn(n, 3, generator=g)
    log_scales = torch.log(torch.rand(n, 3, generator=g) * 0.1 + 0.01)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1)
    opacity = torch.tensor([_logit(o) for o in opacities])
    return Gaussians(means, log_scales, quats, opacity, torch.randn(n, 4, 3, generator=g))


def _stepped(params):
    optimizer = make_optimizer(params, TrainConfig(), 1.0)
    sum((t * t).sum() for t in params.values()).backward()
    optimizer.step()
    return optimizer


def test_relocation_correction_keeps_the_stacked_opacity():
    opacity = torch.tensor([0.3, 0.8, 0.95, 0.5], dtype=torch.float64)
    scales = torch.ones(4, 3, dtype=torch.float64)
    copies = torch.tensor([1, 2, 3, 7])
    new_o, new_s = relocation_correction(opacity, scales, copies)
    # N copies at the same place composite to the source's opacity: 1 - (1 - o')^N = o.
    torch.testing.assert_close(1 - (1 - new_o) ** copies.double(), opacity)
    torch.testing.assert_close(new_o[0], opacity[0])                          # one copy: unchanged
    torch.testing.assert_close(new_s[0], scales[0])
    assert torch.all(new_s[1:] < 1.0) and torch.all(new_s[1:] > 0.0)        # copies shrink
    # The paper's scale for two copies: s o / (2 o' - o'^2 / sqrt 2).
    o2 = new_o[1]
    torch.testing.assert_close(new_s[1, 0], 0.8 / (2 * o2 - o2 ** 2 / math.sqrt(2)))


def test_mcmc_relocation_keeps_the_count_and_moves_dead_gaussians_onto_live_ones():
    opacities = [0.8, 0.001, 0.6, 0.002, 0.003, 0.7]
    model = _model(opacities)
    params = params_from_gaussians(model)
    optimizer = _stepped(params)
    before = {k: v.detach().clone() for k, v in params.items()}
    dead = torch.sigmoid(params["opacity_logits"].detach()) <= 0.005
    assert dead.tolist() == [False, True, False, True, True, False]
    carried = {"tag": torch.arange(6.0)}
    moved = relocate(params, optimizer, dead, torch.Generator().manual_seed(3), carried)
    assert moved == 3 and params["means"].shape[0] == 6
    live = [0, 2, 5]
    opacity = torch.sigmoid(params["opacity_logits"].detach())
    for row in (1, 3, 4):
        # The dead row now sits on a live source, with the source's shape and colour ...
        source = [j for j in live if torch.equal(params["means"].detach()[row], before["means"][j])]
        assert len(source) == 1
        j = source[0]
        assert torch.equal(params["sh_dc"].detach()[row], before["sh_dc"][j])
        assert carried["tag"][row] == j
        # ... and the N copies of that source (source included) share the corrected opacity.
        n = 1 + sum(torch.equal(params["means"].detach()[r], before["means"][j]) for r in (1, 3, 4))
        source_opacity = float(torch.sigmoid(before["opacity_logits"][j]))
        expected = 1 - (1 - source_opacity) ** (1 / n)
        assert abs(float(opacity[row]) - expected) < 1e-5
        assert abs(float(opacity[j]) - expected) < 1e-5
        new_s = relocation_correction(torch.tensor([source_opacity], dtype=torch.float64),
                                      before["log_scales"][j:j + 1].double().exp(), torch.tensor([n]))[1]
        torch.testing.assert_close(params["log_scales"].detach()[row].double().exp(), new_s[0], rtol=1e-5, atol=0)
        # Moved rows and their sources restart their Adam moments.
        assert torch.all(optimizer.state[params["means"]]["exp_avg"][[row, j]] == 0)
    assert torch.all(opacity > 0.005)
    # Untouched rows keep everything.
    untouched = [j for j in live if torch.equal(params["opacity_logits"].detach()[j], before["opacity_logits"][j])]
    for j in untouched:
        assert torch.equal(params["log_scales"].detach()[j], before["log_scales"][j])


def test_mcmc_growth_appends_corrected_copies():
    params = params_from_gaussians(_model([0.9, 0.5, 0.2]))
    optimizer = _stepped(params)
    carried = {"tag": torch.arange(3.0)}
    assert grow(params, optimizer, 2, torch.Generator().manual_seed(0), carried) == 2
    assert params["means"].shape[0] == 5 and carried["tag"].shape[0] == 5
    for row in (3, 4):
        source = int(carried["tag"][row])
        assert torch.equal(params["means"].detach()[row], params["means"].detach()[source])
        assert torch.equal(params["opacity_logits"].detach()[row], params["opacity_logits"].detach()[source])
    assert optimizer.state[params["means"]]["exp_avg"].shape == (5, 3)


def test_mcmc_noise_moves_transparent_gaussians_and_leaves_opaque_ones():
    params = params_from_gaussians(_model([0.99, 0.001]))
    before = params["means"].detach().clone()
    mcmc_noise(params, position_lr=1e-3, noise_lr=5e5, generator=torch.Generator().manual_seed(0))
    moved = (params["means"].detach() - before).norm(dim=-1)
    assert moved[1] > 1e-3 and moved[0] < 1e-6 * moved[1]


def test_mcmc_noise_follows_the_covariance_of_a_rotated_needle():
    """Noise = Sigma eta scaled by the gate and the rates: its second moment is c^2 Sigma^2, with
    Sigma = R S^2 R^T. A needle along x rotated 90 degrees about z moves along y."""
    model = _model([0.001])
    model.log_scales[:] = torch.log(torch.tensor([[0.5, 0.05, 0.1]]))
    half = math.sqrt(0.5)
    model.quats[:] = torch.tensor([[half, 0.0, 0.0, half]])        # 90 degrees about z: x -> y
    params = params_from_gaussians(model)
    start = params["means"].detach().clone()
    generator = torch.Generator().manual_seed(1)
    draws = []
    for _ in range(4000):
        params["means"].data.copy_(start)
        mcmc_noise(params, position_lr=1e-3, noise_lr=5e5, generator=generator)
        draws.append((params["means"].detach() - start)[0].double())
    noise = torch.stack(draws)                                        # [4000, 3]
    moment = noise.T @ noise / len(draws)
    gate = 1.0 / (1.0 + math.exp(-MCMC_NOISE_K * ((1.0 - 0.001) - MCMC_NOISE_X0)))
    c = gate * 5e5 * 1e-3
    sigma = torch.diag(torch.tensor([0.05 ** 2, 0.5 ** 2, 0.1 ** 2], dtype=torch.float64))   # in world axes
    expected = c * c * sigma @ sigma
    assert torch.allclose(moment, expected, rtol=0.1, atol=0.02 * float(expected.max())), (moment, expected)


def test_dropgaussian_expected_opacity_equals_the_undropped_one():
    camera = tc.ring_cameras(1)[0]
    # Overlapping Gaussians at different depths in front of the camera; o / (1 - r) stays below 1.
    model = tc.concat(*(tc.blob((camera.center * (1 - d / tc.RING_RADIUS)).tolist(), 0.25, opacity=o)
                        for d, o in ((1.5, 0.5), (2.0, 0.4), (2.5, 0.6))))
    with torch.no_grad():
        full = render(model, camera, outputs=("alpha",))["alpha"]
        rate = 0.3
        generator = torch.Generator().manual_seed(0)
        draws = [render(drop_gaussians(model, rate, generator), camera, outputs=("alpha",))["alpha"]
                 for _ in range(600)]
    mean = torch.stack(draws).mean(0)
    assert float(full.max()) > 0.5
    assert not torch.equal(draws[0], full)                   # a single draw does drop
    # Independent drops: E[prod(1 - m a / (1 - r))] = prod(1 - a), pixel for pixel.
    assert float((mean - full).abs().max()) < 0.03
    assert abs(float(mean.mean() - full.mean())) < 0.005


def test_drop_rate_rises_to_its_maximum_over_the_run():
    assert drop_rate(0, 100, 0.1) == 0.0
    assert drop_rate(50, 100, 0.1) == pytest.approx(0.05)
    assert drop_rate(100, 100, 0.1) == pytest.approx(0.1)


def test_mcmc_growth_reaches_the_budget_within_a_short_window():
    from inceptiongs.train.strategy import growth_rate

    assert growth_rate(1000, 1000, 0.05, 10) == 0.0
    assert growth_rate(90_000, 100_000, 0.05, 100) == 0.05            # the paper's rate is enough
    rate = growth_rate(3_000, 100_000, 0.05, 10)
    assert 3_000 * (1 + rate) ** 10 == pytest.approx(100_000)


def test_mcmc_growth_per_relocation_is_capped_when_the_window_shrinks():
    from inceptiongs.train.strategy import MCMC_MAX_GROWTH, growth_rate

    # Two relocations left to go from 6 649 to 100 000 would need x3.9 each.
    assert growth_rate(6_649, 100_000, 0.05, 2) == MCMC_MAX_GROWTH
    assert growth_rate(6_649, 7_000, 0.05, 2) < MCMC_MAX_GROWTH
