"""Densification during the refinement (the variant "densify", off by default): the continued
stage-I schedule densifies the Gaussians over the middle of the refinement instead of freezing
their number (refine.continuation_config).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

from ..variants import Variant

# Densification during refinement: after this fraction of the refinement steps (the virtual
# views' gradients first need to accumulate), until this fraction (the last steps settle).
DENSIFY_START_FRACTION = 0.1
DENSIFY_END_FRACTION = 0.7


@dataclass(frozen=True)
class Densify(Variant):
    """The refinement densifies the Gaussians between 10 % and 70 % of its steps (the default
    continuation freezes their number)."""

    NAME: ClassVar[str] = "densify"

    def continued_schedule(self, schedule, stage1, start: int, steps: int):
        """``schedule`` (the continuation, runs.config.TrainConfig) with a densification window over
        the middle of the ``steps`` (>= 1) after ``start``, at stage I's interval or finer."""
        every = max(1, min(stage1.densification.densify_every, steps // 6))
        return dataclasses.replace(schedule, densification=dataclasses.replace(
            schedule.densification, densify_every=every,
            densify_from=start + max(1, int(steps * DENSIFY_START_FRACTION)),
            densify_until=start + max(2, int(steps * DENSIFY_END_FRACTION))))
