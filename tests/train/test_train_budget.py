"""--minutes without --iterations: the schedule is sized to the budget from the measured step rate."""

from __future__ import annotations

import argparse
import json

import pytest

from inceptiongs.commands import train as train_command
from inceptiongs.errors import InputError
from inceptiongs.scene.demo import write_demo_scene
from inceptiongs.train.config import TrainConfig, short_run_schedule, sized_schedule
from inceptiongs.train.trainer import budget_iterations, train


def _args(*argv: str):
    parser = argparse.ArgumentParser()
    train_command.add_arguments(parser)
    return parser.parse_args(["/some/scene", *argv])


def test_minutes_alone_sizes_the_schedule_and_the_strategy_is_recorded():
    config = train_command.build_config(_args("--minutes", "3", "--strategy", "mcmc"))
    assert config.size_to_minutes and config.minutes == 3 and config.strategy == "mcmc"
    assert config.iterations == 210            # the first plan; the trainer re-sizes it
    assert config.densify_until == short_run_schedule(TrainConfig(iterations=210)).densify_until
    fixed = train_command.build_config(_args("--iterations", "500"))
    assert not fixed.size_to_minutes and fixed.strategy == "default"
    with pytest.raises(InputError, match="strategy must be one of"):
        TrainConfig(strategy="adc").validate()


def test_budget_iterations_resizes_only_when_the_rate_is_far_off():
    # 2 steps/s for 100 s more after step 50: ~190 more steps (95 % of the time left).
    assert budget_iterations(50, 250, 2.0, 100.0) is None            # 200 planned: close enough
    assert budget_iterations(50, 1000, 2.0, 100.0) == 50 + 190
    assert budget_iterations(50, 60, 2.0, 100.0) == 240
    assert budget_iterations(50, 1000, 0.0, 100.0) == 51              # always at least one more step


def test_sized_schedule_rescales_the_milestones_from_the_defaults():
    config = short_run_schedule(TrainConfig(iterations=3000, lambda_dssim=0.3))
    resized = sized_schedule(config, 600)
    assert resized == short_run_schedule(TrainConfig(iterations=600, lambda_dssim=0.3))


def test_a_sized_run_shrinks_an_impossible_schedule_to_its_budget(tmp_path):
    scene = write_demo_scene(tmp_path / "scene", progress=False)
    # 5000 steps in 5 seconds is out of reach on any machine: the trainer must re-size.
    config = short_run_schedule(TrainConfig(scene=str(scene), downscale=4, protocol="unstructured", iterations=5000,
                                            minutes=0.08, size_to_minutes=True, pgsr=False, eval_every=10_000,
                                            checkpoint_every=10_000))
    messages = []
    result = train(config, tmp_path / "run", progress=False, log=messages.append)
    stored = json.loads((tmp_path / "run" / "config.json").read_text())
    assert any("schedule re-sized from 5000" in m for m in messages)
    assert stored["iterations"] < 1000 and stored["densify_until"] < 500
    assert result.iteration <= stored["iterations"]
