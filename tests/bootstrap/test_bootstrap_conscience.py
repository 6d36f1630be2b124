"""The conscience: the virtual views' weight falls when the nearest photos get worse, and only then."""

from __future__ import annotations

import torch

from inceptiongs.bootstrap.conscience import BACKOFF, MIN_SCALE, Conscience


def test_scale_backs_off_above_the_tolerance_and_recovers_below_half_of_it():
    c = Conscience(tolerance=0.1)
    assert c.update(0, 1.0) == 1.0 and c.baseline == 1.0
    assert c.update(25, 1.05) == 1.0              # within the tolerance: nothing changes
    assert c.update(50, 1.2) == BACKOFF           # 20 % worse: halved
    assert c.update(75, 1.2) == BACKOFF ** 2
    assert c.update(100, 1.07) == BACKOFF ** 2    # between half and full tolerance: held
    assert c.update(125, 1.0) == BACKOFF ** 2 * 1.25
    for step in range(150, 400, 25):
        c.update(step, 1.0)
    assert c.scale == 1.0
    for step in range(400, 2000, 25):
        c.update(step, 5.0)
    assert c.scale == MIN_SCALE and len(c.history) == 6 + 10 + 64


def refine(virtual_target: torch.Tensor, photo: torch.Tensor, start: torch.Tensor, conscience: Conscience | None,
           steps: int = 200, every: int = 10) -> tuple[torch.Tensor, float]:
    """A toy refinement: the 'model' is the image itself; real steps pull it to the photo of a
    neighbouring view that sees the same surface, virtual steps (weighted by the conscience) to
    the virtual target. -> (model, the virtual weight at the end)."""
    model = start.clone()
    for step in range(steps):
        if conscience is not None and step % every == 0:
            conscience.update(step, float((model - photo).abs().mean()))
        scale = conscience.scale if conscience is not None else 1.0
        if step % 2:
            model -= 0.1 * torch.sign(model - photo) * 0.05
        else:
            model -= 0.1 * scale * 2.0 * torch.sign(model - virtual_target) * 0.05
    return model, (conscience.scale if conscience is not None else 1.0)


def test_a_target_that_contradicts_the_photos_loses_its_weight_one_that_agrees_keeps_it():
    g = torch.Generator().manual_seed(0)
    photo = torch.rand(16, 16, 3, generator=g)
    start = (photo + 0.05 * torch.randn(16, 16, 3, generator=g)).clamp(0, 1)  # a converged stage I
    _, agreeing = refine(photo, photo, start, Conscience())
    assert agreeing == 1.0
    contradicting_target = 1.0 - photo
    guarded, scale = refine(contradicting_target, photo, start, Conscience())
    unguarded, _ = refine(contradicting_target, photo, start, None)
    assert scale < 0.75  # backed off until the photos stop getting worse
    assert float((guarded - photo).abs().mean()) < 0.5 * float((unguarded - photo).abs().mean())
