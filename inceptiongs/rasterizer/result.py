"""RenderResult: what every rasterizer (inceptiongs.rasterizer.interface) returns."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch


@dataclass
class RenderResult:
    """What one render gives; an output nobody asked for is None.

    rgb [H, W, 3] (background blended), alpha [H, W, 1], depth [H, W, 1] (expected camera z, 0
    where uncovered), plane_depth [H, W, 1] (PGSR), normal [H, W, 3] (camera space), features
    [H, W, C]; means2d [N, 2] (gradient retained: the densifiers read ``means2d.grad``), radii
    [N] int64 (0 = culled). Reads like the reference's dict too (``out["rgb"]``, ``"rgb" in
    out``), so loss code written against either works unchanged.
    """

    means2d: torch.Tensor
    radii: torch.Tensor
    rgb: torch.Tensor | None = None
    alpha: torch.Tensor | None = None
    depth: torch.Tensor | None = None
    plane_depth: torch.Tensor | None = None
    normal: torch.Tensor | None = None
    features: torch.Tensor | None = None

    @classmethod
    def from_dict(cls, out: dict[str, torch.Tensor]) -> "RenderResult":
        return cls(**out)

    def keys(self) -> list[str]:
        return [f.name for f in dataclasses.fields(self) if getattr(self, f.name) is not None]

    def items(self) -> list[tuple[str, torch.Tensor]]:
        return [(name, getattr(self, name)) for name in self.keys()]

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self.keys()

    def __getitem__(self, name: str) -> torch.Tensor:
        if name not in self:
            raise KeyError(name)
        return getattr(self, name)

    def __setitem__(self, name: str, value: torch.Tensor) -> None:
        if name not in {f.name for f in dataclasses.fields(self)}:
            raise KeyError(name)
        setattr(self, name, value)

    def get(self, name: str, default=None):
        return getattr(self, name) if name in self else default
