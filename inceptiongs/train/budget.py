"""Sizing a run to a time budget: how many steps fit, and how large MCMC may grow in them.

A step's cost grows about linearly with the Gaussian count (projection, sorting and compositing
are per Gaussian; the image-sized losses are a fixed part): t(N) = fixed + per_gaussian * N.
The trainer measures the rate at checks through the budget and fits that line to them. A
growing model needs its growth in the sizing: sized at today's rate its later steps cost many
times more and the schedule ends undecayed (MCMC on the statuette: 493 of 945 steps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# Time-budget sizing (``size_to_minutes``): the first step rate is measured after this many
# steps, then the schedule is re-checked every BUDGET_CHECK_FRACTION of the budget and re-sized
# when the steps the recent rate predicts differ from the planned ones by more than
# BUDGET_RESIZE_TOLERANCE; the plan fills BUDGET_FILL of the time left (the rate falls as the
# model grows) and is frozen in the last BUDGET_FREEZE of the budget (a late re-size would
# jump the decayed learning rate).
BUDGET_CALIBRATION_STEPS = 10
BUDGET_CHECK_FRACTION = 0.1
BUDGET_RESIZE_TOLERANCE = 0.25
BUDGET_FILL = 0.95
BUDGET_FREEZE = 0.15
# A run sized to a time budget grows until a step costs this many times a step of the model it
# started the run with (by the fitted cost line): more Gaussians, but still about 1/3 of
# the steps the first model's rate promised. Without it fern's densification reached 300k
# Gaussians (the 374k budget of the 5 618 steps planned at the first rate) at 0.35 steps/s.
BUDGET_COST_RATIO = 4.0
# Two rate checks closer in count than this say nothing about the slope of the cost line.
COST_FIT_MIN_COUNT_RATIO = 1.1


def budget_iterations(step: int, planned: int, rate: float, remaining_s: float) -> int | None:
    """The schedule length that fits ``remaining_s`` seconds at ``rate`` steps/s after ``step``,
    or None when the ``planned`` length is within BUDGET_RESIZE_TOLERANCE of it."""
    return far_off(step, planned, step + max(1, int(rate * remaining_s * BUDGET_FILL)))


def far_off(step: int, planned: int, wanted: int) -> int | None:
    """``wanted`` when its steps left differ from the ``planned`` ones by more than
    BUDGET_RESIZE_TOLERANCE, else None (keep the plan: small re-sizes only jitter the schedule)."""
    left_planned = max(planned - step, 1)
    if abs((wanted - step) - left_planned) <= BUDGET_RESIZE_TOLERANCE * left_planned:
        return None
    return wanted


def fit_step_cost(points: list[tuple[float, float]]) -> tuple[float, float]:
    """(fixed s, s per Gaussian) of t(N) = fixed + per_gaussian * N from (count, s/step) ``points``
    (oldest first, at least one, seconds > 0): the line through the newest point and the newest
    earlier one with a clearly different count. Without such a pair, or when the line comes out
    with a negative part (noise), all of the cost is taken as per-Gaussian: the steepest growth,
    so the smallest budget (the safe side)."""
    count, seconds = points[-1]
    proportional = (0.0, seconds / max(count, 1))
    for other_count, other_seconds in reversed(points[:-1]):
        ratio = max(count, other_count) / max(min(count, other_count), 1)
        if ratio >= COST_FIT_MIN_COUNT_RATIO:
            slope = (seconds - other_seconds) / (count - other_count)   # counts differ: no 0 division
            fixed = seconds - slope * count
            return (fixed, slope) if slope > 0 and fixed >= 0 else proportional
    return proportional


@dataclass
class RateWindow:
    """The Gaussian counts of the steps since the last rate check. A rate measured over a window
    in which the model grew belongs to the window's mean count: on the cost line the window's time
    is steps x (fixed + per_gaussian x mean count). Taken at the count the window ended with, a
    growing model's steps look cheap: fern's first window (30k -> 122k Gaussians, 2.02 steps/s,
    after about 4.4 at 30k) put about a quarter of a step's cost in the fixed part, and the line
    afforded about 250k Gaussians (the schedule's cap, 140k, stopped it)."""
    count_sum: float = 0.0
    steps: int = 0

    def add(self, count: int) -> None:
        self.count_sum += count
        self.steps += 1

    def mean_count(self, current: int) -> float:
        """The window's mean count (``current`` when no step was counted)."""
        return self.count_sum / self.steps if self.steps else float(current)


def affordable_count(cost: tuple[float, float], step_seconds: float) -> int:
    """The Gaussian count whose step takes ``step_seconds`` on the cost line (>= 1)."""
    fixed, per_gaussian = cost
    return max(1, int((step_seconds - fixed) / max(per_gaussian, 1e-12)))   # slope > 0 by construction


def mean_planned_count(count: int, budget: int, growth_steps: int, steps: int) -> float:
    """Mean count over the next ``steps`` when it grows geometrically from ``count`` to ``budget``
    over the first ``growth_steps`` of them and then stays (the mean of an exponential ramp is
    (B - N) / ln(B / N))."""
    steps = max(steps, 1)
    growth_steps = min(max(growth_steps, 0), steps)
    if budget <= count * (1.0 + 1e-9) or growth_steps == 0:   # no growth: ln(B/N) ~ 0 is not divided by
        return float(count)
    ramp = (budget - count) / math.log(budget / count)
    return (ramp * growth_steps + budget * (steps - growth_steps)) / steps


def growing_budget_iterations(step: int, cost: tuple[float, float], count: int, budget: int,
                              growth_fraction: float, remaining_s: float) -> int:
    """The schedule length whose remaining steps fit ``remaining_s`` (times BUDGET_FILL) when the
    count grows from ``count`` to ``budget`` until ``growth_fraction`` of the schedule and then
    stays: the length is a fixed point (the growth window scales with it), found by iteration
    from the no-growth length; each pass moves it less as the mean cost it implies settles."""
    fixed, per_gaussian = cost
    seconds = remaining_s * BUDGET_FILL
    length = step + max(1, int(seconds / (fixed + per_gaussian * count)))
    for _ in range(8):
        steps = max(length - step, 1)
        growth_steps = max(0, int(growth_fraction * length) - step)
        mean = mean_planned_count(count, budget, growth_steps, steps)
        length = step + max(1, int(seconds / (fixed + per_gaussian * mean)))
    return length
