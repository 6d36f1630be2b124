"""The view sampler (refine.ViewSampler): every virtual view of a spread-out pool is refined."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from inceptiongs.bootstrap.config import BootstrapConfig
from inceptiongs.bootstrap.refine import RESTART_RATIO, ViewSampler, restart_view
from inceptiongs.bootstrap.virtual_views import flag_of, pool_view_name


def _pool(count: int, spacing: float, flags: int | None = None) -> list:
    """``count`` views on the x axis ``spacing`` scene units apart, all looking the same way;
    with ``flags``, named as the pool names them, view i made for flag i % flags."""
    views = []
    for i in range(count):
        world_to_camera = np.eye(4)
        world_to_camera[0, 3] = -spacing * i          # centre at x = spacing * i
        name = f"v{i:02d}" if flags is None else pool_view_name(1, i % flags, f"v{i:02d}")
        views.append(SimpleNamespace(name=name, camera=SimpleNamespace(world_to_camera=world_to_camera)))
    return views


def _flat_loss(index: int, world_to_camera: torch.Tensor) -> torch.Tensor:
    # The same L1 at every pose: no drift, only the chain's noise moves it.
    return 0.1 + 0.0 * world_to_camera[:3, 3].sum()


def test_every_view_of_a_pool_spread_over_units_is_refined():
    """Twenty views 0.5 units apart (flags along a street): the chain moves ~0.03 units a step,
    so without its restarts it stays on the first views; with them each view is chosen within
    a few passes, and no view is chosen far more often than the least chosen one."""
    pool, sampler = _pool(20, 0.5), ViewSampler(seed=0)
    chosen = [sampler.choose(pool, _flat_loss, BootstrapConfig()).index for _ in range(80)]
    assert set(chosen) == set(range(20)), sorted(set(chosen))
    assert max(sampler.visits.values()) <= RESTART_RATIO * min(sampler.visits.values()) + 2, sampler.visits


def _pull_to_the_origin(index: int, world_to_camera: torch.Tensor) -> torch.Tensor:
    # L1 grows towards x = 0, steeply: the drift carries any pose to the first view in one step.
    return 0.1 + 100.0 / (1.0 + world_to_camera[0, 3] ** 2)


def test_a_drift_towards_one_view_does_not_take_every_step():
    """A steep L1 towards view 0 (the Langevin drift would bring the chain back to it from
    anywhere): the view a restart picks is the one refined, so every view still is."""
    pool, sampler = _pool(10, 0.5), ViewSampler(seed=0)
    chosen = [sampler.choose(pool, _pull_to_the_origin, BootstrapConfig()).index for _ in range(40)]
    assert set(chosen) == set(range(10)), chosen
    assert max(sampler.visits.values()) <= RESTART_RATIO * min(sampler.visits.values()) + 2, sampler.visits


@pytest.mark.parametrize("sampling", ["langevin", "uniform"])
def test_the_sampler_counts_each_views_choices(sampling):
    """The visits are what the summary reports as view_use and what a checkpoint keeps."""
    pool, sampler = _pool(5, 0.5), ViewSampler(seed=1)
    chosen = [sampler.choose(pool, _flat_loss, BootstrapConfig(sampling=sampling)).index for _ in range(30)]
    assert sampler.visits == {pool[i].name: chosen.count(i) for i in set(chosen)}
    assert sum(sampler.visits.values()) == 30


def test_restart_view_keeps_the_chain_until_a_view_is_refined_too_often():
    assert restart_view(2, [1, 1, 3, 1]) == 2            # 3 <= 2 * 1 + 1: the chain stays
    assert restart_view(2, [1, 0, 4, 1]) == 1            # 4 > 2 * 0 + 1: the least refined view, first of ties
    assert restart_view(0, [0, 0, 0]) == 0               # nothing chosen yet: the chain stays where it starts
    assert restart_view(3, [5, 2, 2, 7]) == 1            # 7 > 2 * 2 + 1: the first of the two least refined


def test_restart_view_balances_flags_not_the_views_of_one_flag():
    flags = ["t0", "t0", "t1", "t1"]
    assert restart_view(0, [9, 0, 0, 0], ["t0"] * 4) == 0     # one flag: the chain is never restarted
    assert restart_view(0, [2, 1, 1, 0], flags) == 0          # flags 3 and 1: 3 <= 2 * 1 + 1
    assert restart_view(0, [4, 2, 1, 1], flags) == 2          # 6 > 2 * 2 + 1: flag t1's least refined view
    assert restart_view(0, [3, 3, 2, 0], flags) == 3


def test_flag_of_reads_the_pool_name():
    assert flag_of(pool_view_name(2, 7, "virtual_s0003_t01of03")) == "t7"
    assert flag_of(pool_view_name(1, 7, "target")) == flag_of(pool_view_name(3, 7, "virtual_s0001_t02of02"))
    assert flag_of("photo_0001") == "photo_0001"                 # not a pool name: its own flag


def test_one_flag_keeps_its_chain_where_the_drift_takes_it():
    """One flag with ten views and a drift to view 0: no restart spreads its steps over the
    others (the demo's single flag lost 0.14-0.18 dB when they were balanced too)."""
    pool, sampler = _pool(10, 0.5, flags=1), ViewSampler(seed=0)
    chosen = [sampler.choose(pool, _pull_to_the_origin, BootstrapConfig()).index for _ in range(40)]
    assert chosen.count(0) > 20, chosen


def test_every_flag_of_a_spread_out_pool_is_refined():
    """Twenty views of five flags, 0.5 units apart, with a drift to view 0: each flag is
    refined, no flag far more often than the least refined one."""
    pool, sampler = _pool(20, 0.5, flags=5), ViewSampler(seed=0)
    for _ in range(60):
        sampler.choose(pool, _pull_to_the_origin, BootstrapConfig())
    per_flag = {}
    for name, count in sampler.visits.items():
        per_flag[flag_of(name)] = per_flag.get(flag_of(name), 0) + count
    assert len(per_flag) == 5, per_flag
    assert max(per_flag.values()) <= RESTART_RATIO * min(per_flag.values()) + 2, per_flag
