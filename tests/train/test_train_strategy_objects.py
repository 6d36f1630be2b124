"""The strategies as objects: one registry of names, each strategy holding its own sections of the
config (old flat config.json files migrate on load), and the hooks a training step calls."""

from __future__ import annotations

import argparse
import json
import math
from types import SimpleNamespace

import pytest
import torch

from inceptiongs.commands import train as train_command
from inceptiongs.errors import InputError
from inceptiongs.gaussians import Gaussians
from inceptiongs.runs.config import (FLAT_KEYS, STRATEGY_NAMES, STRATEGY_OPTIONS, Densification, DropGaussianOptions,
                                     MCMCOptions, TrainConfig)
from inceptiongs.train.optim import make_optimizer, params_from_gaussians, position_learning_rate
from inceptiongs.train.strategies import (STRATEGIES, DefaultStrategy, DropGaussianStrategy, MCMCStrategy,
                                          strategy_for)
from inceptiongs.train.strategy import drop_gaussians


def _model(opacities: list[float], seed: int = 0) -> Gaussians:
    n = len(opacities)
    g = torch.Generator().manual_seed(seed)
    logits = torch.tensor([math.log(o / (1 - o)) for o in opacities])
    return Gaussians(torch.randn(n, 3, generator=g), torch.log(torch.rand(n, 3, generator=g) * 0.1 + 0.01),
                     torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1), logits,
                     torch.randn(n, 1, 3, generator=g))


def _state(opacities: list[float]):
    params = params_from_gaussians(_model(opacities))
    return SimpleNamespace(params=params, optimizer=make_optimizer(params, TrainConfig(), 1.0),
                           generator=torch.Generator().manual_seed(1))


def test_the_registry_the_config_and_the_command_line_name_the_same_strategies():
    parser = argparse.ArgumentParser()
    train_command.add_arguments(parser)
    choices = next(a.choices for a in parser._actions if "--strategy" in a.option_strings)
    assert list(choices) == list(STRATEGIES) == list(STRATEGY_NAMES) == list(STRATEGY_OPTIONS)
    for name, cls in STRATEGIES.items():
        assert cls.NAME == name
        options = STRATEGY_OPTIONS[name]
        assert isinstance(cls().densification, Densification)   # every strategy holds the densification section
        if options is not None:   # and its own options, which the config holds by the strategy's name
            assert isinstance(cls().options, options)
            assert isinstance(getattr(TrainConfig(), name), options)


def test_strategy_for_builds_the_named_strategy_with_the_configs_options():
    window = Densification(densify_until=123, max_gaussians=456)
    default = strategy_for(TrainConfig(densification=window))
    assert isinstance(default, DefaultStrategy) and default.densification == window
    mcmc = strategy_for(TrainConfig(strategy="mcmc", mcmc=MCMCOptions(noise_lr=7.0, growth=0.2), densification=window))
    assert isinstance(mcmc, MCMCStrategy) and mcmc.options == MCMCOptions(noise_lr=7.0, growth=0.2)
    assert mcmc.densification == window
    drop = strategy_for(TrainConfig(strategy="dropgaussian", dropgaussian=DropGaussianOptions(rate_max=0.3)))
    assert isinstance(drop, DropGaussianStrategy) and drop.options.rate_max == 0.3


def test_an_old_flat_config_json_loads_into_the_nested_options(tmp_path):
    expected = TrainConfig(scene="/x", strategy="mcmc", iterations=77,
                           mcmc=MCMCOptions(noise_lr=1e4, opacity_reg=0.02, scale_reg=0.03, dead_opacity=0.01,
                                            growth=0.1),
                           dropgaussian=DropGaussianOptions(rate_max=0.25))
    flat = expected.to_json_dict()
    del flat["mcmc"], flat["dropgaussian"]
    for key in ("mcmc_noise_lr", "mcmc_opacity_reg", "mcmc_scale_reg", "mcmc_dead_opacity", "mcmc_growth",
                "drop_rate_max"):
        strategy, option = FLAT_KEYS[key].split(".")
        flat[key] = getattr(getattr(expected, strategy), option)
    (tmp_path / "config.json").write_text(json.dumps(flat))
    assert TrainConfig.load(tmp_path / "config.json") == expected
    # Written again, the options are nested and load back the same.
    expected.save(tmp_path / "new.json")
    written = json.loads((tmp_path / "new.json").read_text())
    assert written["mcmc"]["growth"] == 0.1 and "mcmc_growth" not in written
    assert TrainConfig.load(tmp_path / "new.json") == expected
    assert TrainConfig(**written) == expected


def test_a_flat_file_without_strategy_keys_gets_the_defaults(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"strategy": "dropgaussian", "drop_rate_max": 0.05}))
    config = TrainConfig.load(tmp_path / "config.json")
    assert config.dropgaussian.rate_max == 0.05 and config.mcmc == MCMCOptions()


@pytest.mark.parametrize("content, message", [
    ({"drop_rate_max": 0.2, "dropgaussian": {"rate_max": 0.3}}, "drop_rate_max and dropgaussian.rate_max both"),
    ({"mcmc": {"noise_lr": 1.0, "cap": 5}}, "unknown key 'mcmc.cap'"),
    ({"mcmc": 3}, "mcmc must be an object"),
    ({"drop_rate_max": 1.0}, r"dropgaussian.rate_max must be in \[0, 1\)"),
    ({"mcmc": {"dead_opacity": -0.1}}, "mcmc.dead_opacity must be in"),
])
def test_bad_strategy_options_name_the_file(tmp_path, content, message):
    (tmp_path / "c.json").write_text(json.dumps(content))
    with pytest.raises(InputError, match=f"c.json: {message}"):
        TrainConfig.load(tmp_path / "c.json")


def test_dropgaussian_renders_a_dropped_copy_and_the_default_the_model_itself():
    model = _model([0.5] * 200)
    state = SimpleNamespace(generator=torch.Generator().manual_seed(3))
    assert DefaultStrategy().prepare_render(100, model, state, 100) is model
    drop = DropGaussianStrategy(options=DropGaussianOptions(rate_max=0.4))
    dropped = drop.prepare_render(100, model, state, 100)
    expected = drop_gaussians(model, 0.4, torch.Generator().manual_seed(3))
    assert torch.equal(dropped.opacity_logits, expected.opacity_logits)
    assert not torch.equal(dropped.opacity_logits, model.opacity_logits)
    # At step 0 the rate is 0: nothing dropped.
    assert drop.prepare_render(0, model, state, 100) is model


def test_mcmc_adds_its_weighted_regularisers_and_the_default_adds_nothing():
    state = _state([0.2, 0.6, 0.9])
    loss = torch.tensor(1.0)
    terms: dict = {}
    assert DefaultStrategy().add_loss_terms(loss, terms, state) is loss and not terms
    total = MCMCStrategy(options=MCMCOptions(opacity_reg=0.5, scale_reg=0.25)).add_loss_terms(loss, terms, state)
    opacity = float(torch.sigmoid(state.params["opacity_logits"].detach()).mean())
    scale = float(torch.exp(state.params["log_scales"].detach()).mean())
    assert float(terms["opacity_reg"].detach()) == pytest.approx(opacity)
    assert float(total.detach()) == pytest.approx(1.0 + 0.5 * opacity + 0.25 * scale)


def test_mcmc_noise_runs_within_the_schedule_only():
    config = TrainConfig(iterations=10)
    state = _state([0.001, 0.9])
    before = state.params["means"].detach().clone()
    MCMCStrategy().after_optimizer_step(11, state, 10, position_learning_rate(11, config, 1.0))   # stage II
    assert torch.equal(state.params["means"], before)
    MCMCStrategy().after_optimizer_step(5, state, 10, position_learning_rate(5, config, 1.0))
    moved = (state.params["means"].detach() - before).norm(dim=-1)
    assert moved[0] > 0 and moved[0] > 100 * moved[1]                 # the transparent one moves


def test_mcmc_relocates_and_grows_in_the_window_and_removes_the_dead_after_it():
    mcmc = MCMCStrategy(Densification(densify_until=500, densify_every=100, max_gaussians=40))
    opacities = [0.9, 0.001, 0.7, 0.5] * 5
    flags = torch.tensor([False, False, False, True] * 5)               # free-space flags
    state = _state(opacities)
    counts = mcmc.maintenance(100, state, 1.0, 1000, flags, {}, torch.zeros(1, 3))
    assert counts["relocated"] == 10 and counts["added"] > 0
    assert state.params["means"].shape[0] == 20 + counts["added"] <= 40
    assert float(torch.sigmoid(state.params["opacity_logits"].detach()).min()) > 0.005   # none left dead
    state = _state(opacities)
    counts = mcmc.maintenance(600, state, 1.0, 1000, flags, {}, torch.zeros(1, 3))
    assert counts == {"pruned": 10} and state.params["means"].shape[0] == 10


def test_the_opacity_reset_belongs_to_the_3dgs_strategies():
    window = Densification(densify_until=500, opacity_reset_every=100)
    for strategy, resets in ((DefaultStrategy(window), True), (DropGaussianStrategy(window), True),
                             (MCMCStrategy(window), False)):
        state = _state([0.9, 0.8])
        before = state.params["opacity_logits"].detach().clone()
        strategy.after_maintenance(200, state)
        assert (not torch.equal(state.params["opacity_logits"], before)) == resets, strategy
        state = _state([0.9, 0.8])
        strategy.after_maintenance(250, state)                          # not a reset step
        assert torch.equal(state.params["opacity_logits"], before)
