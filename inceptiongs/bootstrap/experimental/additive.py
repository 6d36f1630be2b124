"""The additive virtual mode (the variant "additive", off by default): a photo step whose
gradient also holds a virtual view's loss, instead of a virtual step in place of a photo step.
Measured only with the informative pixels and the geometry term (docs/bootstrap.md), neither of
which beats the default alternating blend.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, ClassVar

from ..variants import Variant


def additive_step(virtual_loss: Callable[[], tuple], photo_step: Callable[[], dict]) -> dict:
    """A photo step whose gradient also holds a virtual view's loss: the virtual loss
    (``virtual_loss()`` -> (loss, render outputs, record): refine.virtual_loss as the loop hands
    it over) is back-propagated first (gradients accumulate in the parameters' .grad), then
    ``photo_step`` (the stage-I trainer's step) adds its own and takes the one Adam step, which
    zeroes them. The photos lose no step; the virtual view costs one render and backward."""
    total, _, record = virtual_loss()
    total.backward()
    virtual_record = {f"virtual_{key}" if not key.startswith("virtual_") else key: value
                      for key, value in record.items()}
    record = photo_step()
    record.update(virtual_record, kind="additive", virtual_total=float(total.detach()))
    return record


@dataclass(frozen=True)
class Additive(Variant):
    """A virtual slot's step is a photo step carrying the virtual view's loss."""

    NAME: ClassVar[str] = "additive"

    def take_step(self, virtual_loss: Callable[[], tuple], photo_step: Callable[[], dict]) -> dict:
        return additive_step(virtual_loss, photo_step)
