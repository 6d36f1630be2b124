"""The round plan: what a bootstrap will do, fixed before its first step.

The rounds' targets, the refinement steps per round, the stage-I iteration the refinement
continues from, and the outlook's photo-first time (outlook.py: with ``follow_outlook`` the loop
takes photo steps until then). Pure values and functions; the loop (loop.py) only reads them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from .outlook import Outlook
from .targets import Target, round_targets


@dataclass(frozen=True)
class RoundPlan:
    """rounds: each round's targets (empty for the same-time baseline, which has none); steps:
    refinement steps per round; start: the stage-I iteration the refinement continues from;
    photo_until_s: the bootstrap's wall second (its own clock, carried through a resume) before
    which every step is a photo step (0: none; inf: all)."""

    rounds: tuple[tuple[Target, ...], ...]
    steps: int
    start: int
    baseline: bool
    photo_until_s: float = 0.0


def plan_rounds(targets: Sequence[Target] | None, rounds: int, steps: int, start: int) -> RoundPlan:
    """The plan without the outlook: ``targets`` dealt over the ``rounds`` (None: the same-time
    baseline, rounds without targets), ``steps`` per round from iteration ``start``."""
    dealt = round_targets(targets, rounds) if targets is not None else [[] for _ in range(rounds)]
    return RoundPlan(tuple(tuple(goal) for goal in dealt), steps, start, targets is None)


def photo_first_s(outlook: Outlook) -> float:
    """The photo-first time the outlook asks for (outlook.py): every step on the photos when
    there is nothing to repair, photo steps first while stage I's curve still rises fast (all of
    them when it does not say for how long), none otherwise."""
    if outlook.verdict == "nothing to repair":
        return math.inf
    if outlook.verdict == "train longer":
        wait = outlook.photo_first_min
        return math.inf if wait is None else 60.0 * wait
    return 0.0


def following_line(photo_until_s: float) -> str:
    """The log line of a plan that follows the outlook with a photo-first time > 0."""
    return "the loop follows the outlook: " + (
        "no virtual views, every step on the photos" if math.isinf(photo_until_s) else
        f"photo steps until {photo_until_s / 60.0:.1f} min, then virtual views") \
        + " (follow_outlook: false makes virtual views from the start)"


@dataclass(frozen=True)
class ResumePoint:
    """Where a resumed bootstrap continues: the (0-based) round, the steps left of it (None: all
    of it) and the rounds already done."""

    first_round: int
    steps_left: int | None
    rounds_done: int


def resume_point(plan: RoundPlan, iteration: int, round_number: int) -> ResumePoint:
    """The point of a checkpoint taken at ``iteration`` in (1-based) round ``round_number``."""
    round_number = min(max(int(round_number), 1), len(plan.rounds))
    done = iteration - plan.start - (round_number - 1) * plan.steps
    if done >= plan.steps:   # the round had ended: the next one starts
        return ResumePoint(round_number, None, round_number)
    return ResumePoint(round_number - 1, plan.steps - max(done, 0), round_number - 1)
