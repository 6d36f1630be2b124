"""--minutes without --iterations: the schedule is sized to the budget from the measured step rate."""

from __future__ import annotations

import argparse
import json
import math

import pytest

from inceptiongs.commands import train as train_command
from inceptiongs.errors import InputError
from demo_cases import copy_of_demo_scene
from inceptiongs.io.config_json import with_values
from inceptiongs.runs.config import Densification, TrainConfig, short_run_schedule, sized_schedule
from inceptiongs.train.budget import budget_iterations
from inceptiongs.train.trainer import train


def _args(*argv: str):
    parser = argparse.ArgumentParser()
    train_command.add_arguments(parser)
    return parser.parse_args(["/some/scene", *argv])


def test_minutes_alone_sizes_the_schedule_and_the_strategy_is_recorded():
    config = train_command.build_config(_args("--minutes", "3", "--strategy", "mcmc"))
    assert config.size_to_minutes and config.minutes == 3 and config.strategy == "mcmc"
    assert config.iterations == 210            # the first plan; the trainer re-sizes it
    assert config.densification == short_run_schedule(TrainConfig(iterations=210)).densification
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
    config = short_run_schedule(with_values(TrainConfig(iterations=3000), {"losses.lambda_dssim": 0.3}))
    resized = sized_schedule(config, 600)
    assert resized == short_run_schedule(with_values(TrainConfig(iterations=600), {"losses.lambda_dssim": 0.3}))
    assert resized.losses.lambda_dssim == 0.3 and resized.densification.densify_until == 300


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return copy_of_demo_scene(tmp_path_factory.mktemp("budget") / "scene")


def test_a_sized_run_shrinks_an_impossible_schedule_to_its_budget(tmp_path, demo_scene):
    scene = demo_scene
    # 5000 steps in 2.4 seconds is out of reach on any machine: the trainer must re-size.
    config = short_run_schedule(with_values(
        TrainConfig(scene=str(scene), downscale=4, protocol="unstructured", iterations=5000, minutes=0.04,
                    size_to_minutes=True, pgsr=False),
        {"output.eval_every": 10_000, "output.checkpoint_every": 10_000}))
    messages = []
    result = train(config, tmp_path / "run", progress=False, log=messages.append)
    stored = json.loads((tmp_path / "run" / "config.json").read_text())
    assert any("schedule re-sized from 5000" in m for m in messages)
    assert stored["iterations"] < 1000 and stored["densification"]["densify_until"] < 500
    assert result.iteration <= stored["iterations"]


def test_step_cost_line_is_fitted_from_two_counts_and_falls_back_to_proportional():
    from inceptiongs.train.budget import affordable_count, fit_step_cost

    fixed, per = fit_step_cost([(1_000, 0.3 + 1e-4 * 1_000), (5_000, 0.3 + 1e-4 * 5_000)])
    assert fixed == pytest.approx(0.3) and per == pytest.approx(1e-4)
    assert affordable_count((fixed, per), 1.3) == pytest.approx(10_000, abs=1)
    # One count only (or counts too close): all cost per Gaussian, the smallest budget.
    assert fit_step_cost([(2_000, 0.4)]) == pytest.approx((0.0, 0.4 / 2_000))
    assert fit_step_cost([(2_000, 0.4), (2_050, 0.8)]) == pytest.approx((0.0, 0.8 / 2_050))
    # A noisy line with a negative fixed part is not trusted either.
    assert fit_step_cost([(1_000, 1.0), (2_000, 3.0)]) == pytest.approx((0.0, 3.0 / 2_000))


def test_a_growing_plan_is_sized_at_its_mean_cost():
    from inceptiongs.train.budget import BUDGET_FILL, growing_budget_iterations, mean_planned_count

    assert mean_planned_count(1_000, 1_000, 50, 100) == 1_000
    assert mean_planned_count(1_000, 8_000, 0, 100) == 1_000          # the window is over: no growth
    ramp = mean_planned_count(1_000, 8_000, 100, 100)
    assert 1_000 < ramp < 4_500                                       # an exponential ramp's mean
    assert ramp == pytest.approx(7_000 / math.log(8.0))
    cost = (0.0, 1e-3)                                                # 1 s a step at 1 000 Gaussians
    flat = growing_budget_iterations(0, cost, 1_000, 1_000, 0.5, 1_000.0)
    assert flat == int(1_000 * BUDGET_FILL)
    grown = growing_budget_iterations(0, cost, 1_000, 8_000, 0.5, 1_000.0)
    # Half the run on the ramp, half at 8 000: the plan's time is its length at the mean cost.
    mean = mean_planned_count(1_000, 8_000, int(0.5 * grown), grown)
    assert grown < flat / 3
    assert grown * 1e-3 * mean == pytest.approx(1_000 * BUDGET_FILL, rel=0.02)


def test_a_sized_run_grows_only_to_what_its_time_affords(tmp_path, demo_scene, monkeypatch):
    """The budget the fitted step-cost line affords reaches the config and caps the growth. The line
    is fixed here (all cost per Gaussian: 4x a first step's cost affords 4x its count) so the
    figure does not depend on how fast this machine is: measured on the demo's small images, the
    fixed part of a step can dominate, and what 4x affords then reaches the schedule's own cap."""
    import inceptiongs.train.trainer as trainer_module

    monkeypatch.setattr(trainer_module, "fit_step_cost", lambda points: (0.0, 1e-5))
    scene = demo_scene
    config = short_run_schedule(with_values(
        TrainConfig(scene=str(scene), downscale=4, protocol="unstructured", iterations=5000, minutes=0.05,
                    size_to_minutes=True, pgsr=False, strategy="mcmc"),
        {"output.eval_every": 10_000, "output.checkpoint_every": 10_000}))
    messages = []
    result = train(config, tmp_path / "run", progress=False, log=messages.append)
    stored = json.loads((tmp_path / "run" / "config.json").read_text())
    budget = stored["densification"]["max_gaussians"]
    unbudgeted = sized_schedule(with_values(TrainConfig(**stored),
                                            {"densification.max_gaussians": Densification.max_gaussians}),
                                stored["iterations"]).densification.max_gaussians
    assert any("grows to at most" in m for m in messages), messages
    assert budget < unbudgeted
    assert result.num_gaussians <= budget


def test_a_rate_measured_while_the_model_grew_is_fitted_at_the_window_mean_count():
    """A model growing geometrically between two checks, on a known cost line: the rate of the
    window belongs to its mean count, and the line fitted that way is the true one; attributed
    to the count the window ended with (as before) it comes out flat and affords far more."""
    from inceptiongs.train.budget import RateWindow, affordable_count, fit_step_cost

    fixed, per = 0.05, 4e-6                                  # fern-like: 0.17 s at 30k, 0.54 at 122k
    cost = lambda n: fixed + per * n                         # noqa: E731
    first = RateWindow()
    for _ in range(10):
        first.add(30_000)
    second = RateWindow()
    counts = [int(30_000 * 4.0 ** (i / 300)) for i in range(1, 301)]   # 30k -> 120k in 300 steps
    for n in counts:
        second.add(n)
    seconds = sum(cost(n) for n in counts) / len(counts)     # what the clock measures over the window
    points = [(first.mean_count(30_000), cost(30_000)), (second.mean_count(counts[-1]), seconds)]
    assert fit_step_cost(points) == pytest.approx((fixed, per), rel=1e-6)
    budget = affordable_count((fixed, per), 4 * cost(30_000))
    assert budget == pytest.approx(4 * 30_000 + 3 * fixed / per, abs=1)
    end_points = [(30_000, cost(30_000)), (counts[-1], seconds)]
    stale = fit_step_cost(end_points)
    assert stale[1] < 0.8 * per and affordable_count(stale, 4 * cost(30_000)) > 1.2 * budget
    assert RateWindow().mean_count(7) == 7.0                 # an empty window: the current count


def test_a_slow_first_step_does_not_end_a_sized_run_early(tmp_path, demo_scene, monkeypatch):
    """The first step of a process may compile the CPU kernels (seconds on a cold cache): a rate
    measured over it sized a 3-minute run to 26 steps, over after 39 s. The rate is measured from
    the first step's end, and a schedule that ends with much of the budget left is re-planned."""
    import time

    import inceptiongs.train.trainer as trainer_module

    real_step, calls = trainer_module.train_step, []

    def slow_first(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            time.sleep(3.0)   # as a cold kernel cache costs
        return real_step(*args, **kwargs)

    monkeypatch.setattr(trainer_module, "train_step", slow_first)
    budget_s = 9.0
    config = short_run_schedule(with_values(
        TrainConfig(scene=str(demo_scene), downscale=4, protocol="unstructured", iterations=40,
                    minutes=budget_s / 60.0, size_to_minutes=True, pgsr=False),
        {"output.eval_every": 10_000, "output.checkpoint_every": 10_000}))
    train(config, tmp_path / "run", progress=False, log=lambda line: None)
    last = json.loads((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()[-1])
    # It trains into the last quarter of its budget, however slow this machine is.
    assert last["train_s"] >= 0.75 * budget_s, last


def test_the_sizer_looks_again_when_the_schedule_ends_with_budget_left():
    from inceptiongs.train.trainer import ScheduleSizer

    sizer = ScheduleSizer.starting(TrainConfig(iterations=26, size_to_minutes=True, minutes=3.0), 180.0, 0, 0.0)
    assert not sizer.due(5, 30.0)                 # neither the calibration steps nor a slice have passed
    assert sizer.ended_early(26, 39.0) and sizer.due(26, 39.0)   # the schedule ended at 39 s of 180
    assert not sizer.ended_early(25, 39.0)        # not ended
    assert not sizer.ended_early(26, 150.0)       # ended within a quarter of the budget: it ends
    sizer.warmed_up(1, 3.0)
    assert sizer.rate_mark == (1, 3.0) and sizer.next_check[0] == 11
