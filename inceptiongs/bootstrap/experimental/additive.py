"""The additive virtual mode (``virtual_mode="additive"``, off by default): a photo step whose
gradient also holds a virtual view's loss, instead of a virtual step in place of a photo step.
Measured only with the informative pixels and the geometry term (docs/bootstrap.md), neither of
which beats the default alternating blend.
"""

from __future__ import annotations

from typing import Callable

from ...runs.config import TrainConfig
from ..config import BootstrapConfig
from ..generation import VirtualTarget
from ..refine import ViewChoice, virtual_loss


def additive_step(step: int, state, data, train_config: TrainConfig, sh_max: int, view: VirtualTarget,
                  choice: ViewChoice, config: BootstrapConfig, rasterizer, photo_step: Callable[[], dict],
                  lpips=None, scale: float = 1.0) -> dict:
    """A photo step whose gradient also holds a virtual view's loss: the virtual loss is
    back-propagated first (gradients accumulate in the parameters' .grad), then ``photo_step``
    (the stage-I trainer's step) adds its own and takes the one Adam step, which zeroes them.
    The photos lose no step; the virtual view costs one render and backward."""
    total, _, record = virtual_loss(step, state, train_config, sh_max, view, choice, config, rasterizer, lpips,
                                    scale)
    total.backward()
    virtual_record = {f"virtual_{key}" if not key.startswith("virtual_") else key: value
                      for key, value in record.items()}
    record = photo_step()
    record.update(virtual_record, kind="additive", virtual_total=float(total.detach()))
    return record
