"""The geometry term at virtual views (the variant "geometry", off by default): 1 - NCC of the
view's source photos mapped through the rendered depth and planar normal (multiview.py), added
to a virtual view's loss; with ``colour`` off it is the only loss there and no I* is built.
Measured against the same-time baseline: +0.08 / +0.15 dB (scarce / covered) on the objects
demo, -0.40 / -0.54 on the courtyard (docs/bootstrap.md), so it stays off.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, ClassVar, Sequence

import torch

from ...camera import Camera
from ...errors import InputError
from ..generation import VirtualTarget
from ..options import VARIANT, option
from ..variants import Variant
from .multiview import DEFAULT_SAMPLES, GeometrySource, geometry_loss


def geometry_sources(sources: Sequence[int], photos: dict, cameras: Sequence[Camera],
                     depth_of: Callable[[Camera], torch.Tensor]) -> list[GeometrySource]:
    """The term's sources: grey photos (NCC ignores colour balance; photos[i] [H, W, 3]) and the
    current depth of each (its visibility reference)."""
    return [GeometrySource(photos[i].float().mean(-1, keepdim=True), cameras[i], depth_of(cameras[i]))
            for i in sources]


@dataclass(frozen=True)
class Geometry(Variant):
    """The multi-view geometry term at virtual views: 1 - NCC of the view's source photos mapped
    through the rendered depth and planar normal (experimental/multiview.py), added to a virtual
    view's loss."""

    NAME: ClassVar[str] = "geometry"

    weight: float = option(0.15, "weight of the term (1 - NCC) against a virtual view's colour loss; stage I's "
                                 "lambda_ncc, PGSR's weight of the same measure, is 0.15", "weight", VARIANT)
    samples: int = option(DEFAULT_SAMPLES, "pixels per evaluation of the term", "pixels", VARIANT)
    colour: bool = option(True, "keep the colour loss at virtual views (I* or the informative blend); false: "
                                "only the geometry term, and no I* is built", role=VARIANT)

    def check(self, source: str, config) -> None:
        if not self.weight > 0:
            raise InputError(f"{source}: weight must be > 0 (the variant off: leave it out), got {self.weight}")
        if self.samples < 1:
            raise InputError(f"{source}: samples must be >= 1, got {self.samples}")

    def view_geometry(self, sources: Sequence[int], photos: dict, cameras: Sequence[Camera],
                      depth_of: Callable[[Camera], torch.Tensor]) -> list[GeometrySource]:
        return geometry_sources(sources, photos, cameras, depth_of)

    def colour_target(self) -> bool:
        return self.colour

    def render_outputs(self, view: VirtualTarget) -> tuple[str, ...]:
        return ("depth", "normal") if len(view.geometry) >= 2 else ()

    def extra_loss(self, out: dict, view: VirtualTarget, seed: int, step: int, scale: float):
        """(the weighted term, scaled by the conscience's ``scale``; None where no pair is
        valid, its record), or None for a view with fewer than two sources."""
        if len(view.geometry) < 2:
            return None
        term, record = geometry_loss(out, view, seed, self.samples, step)
        return (None if term is None else self.weight * scale * term), record
