"""What a supervision works on and returns: it turns a :class:`ViewContext` (one virtual view,
its fill, the photos to warp in, the model's depth and render) into a :class:`ViewSupervision`
(I* [H, W, 3], its trusted-pixel mask M [H, W, 1], a report). supervise.py holds the default
blend; a variant may supply another (variants.Variant.supervise).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import torch

from ..camera import Camera
from .config import BootstrapConfig
from .warp import DEFAULT_DELTA


@dataclass
class ViewContext:
    """What one virtual view's I* is made from.

    fill: [H, W, 3] float32 in [0, 1], what the pixels no photo covers keep (the prior's image,
    or the render); sources: training view indices whose ``photos`` ([H, W, 3]) are warped in;
    render_depth(camera) -> [H, W, 1] the model's surface depth at any camera (0: none);
    render_rgb(camera) -> [H, W, 3] the model's render (None: ``fill`` stands in for it);
    source_depth() -> [H, W, 1] the view's depth splatted from the training views
    (source_depth.py; asked for only when ``config.virtual_depth`` is not "render")."""

    config: BootstrapConfig
    camera: Camera
    fill: torch.Tensor
    sources: Sequence[int]
    cameras: Sequence[Camera]
    photos: dict
    render_depth: Callable[[Camera], torch.Tensor]
    render_rgb: Callable[[Camera], torch.Tensor] | None = None
    source_depth: Callable[[], torch.Tensor] | None = None

    def __post_init__(self) -> None:
        self.fill = torch.as_tensor(self.fill, dtype=torch.float32)   # benchmarks and tests pass numpy

    @property
    def delta(self) -> float:
        return DEFAULT_DELTA if self.config.delta is None else self.config.delta

    def render(self) -> torch.Tensor:
        """[H, W, 3] the model's render at the view."""
        return self.render_rgb(self.camera) if self.render_rgb is not None else self.fill

    def own_depth(self) -> torch.Tensor:
        return self.render_depth(self.camera)

    def placing_depth(self) -> torch.Tensor:
        """The depth the photos are placed with: the splatted one unless ``virtual_depth`` is "render"."""
        if self.config.virtual_depth == "render" or self.source_depth is None:
            return self.own_depth()
        return self.source_depth()


@dataclass
class ViewSupervision:
    """I* [H, W, 3] in [0, 1], M [H, W, 1] and the report: "agreement_db" (the warps' agreement
    margin against the render: agreement.py; None when not measurable) and, where the photos
    were placed with more than the render's depth, "depth" ("sources", "both" or "render")."""

    image: torch.Tensor
    mask: torch.Tensor
    report: dict = field(default_factory=dict)
