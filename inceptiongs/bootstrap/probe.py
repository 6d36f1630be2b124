"""The repair outlook measured when stage I's log cannot give it.

A run copied without its metrics.jsonl, a run of another tool, or a log without held-out scores
leaves the outlook (outlook.py) "unknown". Acting on "unknown" (virtual views from the first
step) was the largest loss measured on real captures: a scene still gaining fast from its photos
lost 1.5 dB against the same-time baseline. So the bootstrap measures what the log would have
said: the held-out views are scored at the start (the bootstrap does that anyway), a probe of photo
steps runs (kept: they are the baseline's steps, not wasted), the views are scored again, and the
outlook is read from those two points as from stage I's curve: the gap between the scarce and
covered views, and the scarce views' gain per minute of training. Until then every step is a
photo step. The probe needs both groups of held-out views; without them the outlook stays unknown
and the loop acts as before (and says so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .outlook import Outlook, outlook_from_curve

# The probe's share of the bootstrap: this fraction of its steps, or of its time budget when it
# has one, whichever ends first. It leaves 5/6 of the budget for what the outlook decides; the
# share is a chosen value, not tuned on a scene.
PROBE_SHARE = 1.0 / 6.0
MIN_PROBE_STEPS = 2


@dataclass(frozen=True)
class Probe:
    """until_step: the last probe step (inclusive); until_s: the bootstrap's wall second the probe
    ends at (math.inf: no time budget); start_train_s: the training clock when it began."""

    until_step: int
    until_s: float
    start_train_s: float = 0.0

    def over(self, step: int, wall_s: float) -> bool:
        """Whether the probe has ended before ``step`` at ``wall_s``."""
        return step > self.until_step or wall_s >= self.until_s


def plan_probe(start: int, total_steps: int, budget_s: float | None, now_s: float, train_s: float) -> Probe:
    """The probe of a bootstrap from ``start`` over ``total_steps`` steps (``budget_s``: its time
    budget, None: none; ``now_s``, ``train_s``: its wall and training clocks now)."""
    steps = max(MIN_PROBE_STEPS, math.ceil(PROBE_SHARE * total_steps))
    until_s = math.inf if budget_s is None else now_s + PROBE_SHARE * max(budget_s - now_s, 0.0)
    return Probe(start + steps, until_s, train_s)


def photo_until(plan, state) -> float:
    """The wall second before which the loop takes only photo steps: the plan's (the outlook read
    from stage I's log), or the one a probe measured (state.photo_until_s), math.inf while a probe runs."""
    if state.probe is not None:
        return math.inf
    return plan.photo_until_s if state.photo_until_s is None else state.photo_until_s


def can_probe(initial_scores: dict) -> bool:
    """Whether the held-out scores at the start have both groups the outlook compares."""
    return all(isinstance(initial_scores.get(k), (int, float)) and math.isfinite(initial_scores[k])
               for k in ("scarce_psnr", "covered_psnr"))


def measured_outlook(initial_scores: dict, probe_scores: dict, probe_train_s: float) -> Outlook:
    """The outlook from the held-out scores before (training second 0) and after the probe
    (``probe_train_s`` seconds of training later), with its line saying it was measured."""
    lines = [{**initial_scores, "train_s": 0.0}, {**probe_scores, "train_s": float(probe_train_s)}]
    outlook = outlook_from_curve(lines)
    return Outlook(outlook.verdict, f"{outlook.line} (measured: no curve in stage I's log, so a probe of "
                                    f"{probe_train_s:.0f} s of photo steps was scored)",
                   outlook.gap_db, outlook.scarce_db_per_min, outlook.covered_db_per_min, outlook.photo_first_min)
