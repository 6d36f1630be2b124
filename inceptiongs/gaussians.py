"""The Gaussian model: raw (unconstrained) parameters, as optimised and as stored in PLY.

Storage follows the standard 3DGS PLY: log scales, opacity logits, quaternions (w, x, y, z)
not necessarily normalised, SH coefficients with ``sh[:, 0]`` = f_dc and ``sh[:, 1:]`` the
f_rest bands. The SH degree is whatever the coefficients say: (degree + 1)^2 per channel.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from .constants import sh_degree_from_count


@dataclass
class Gaussians:
    """means: [N, 3]; log_scales: [N, 3]; quats: [N, 4] (w, x, y, z);
    opacity_logits: [N]; sh: [N, K, 3] with K = (degree + 1)^2."""

    means: torch.Tensor
    log_scales: torch.Tensor
    quats: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expected = {"means": (n, 3), "log_scales": (n, 3), "quats": (n, 4), "opacity_logits": (n,)}
        for name, shape in expected.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"Gaussians.{name}: expected shape {shape}, got "
                                 f"{tuple(getattr(self, name).shape)}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ValueError(f"Gaussians.sh: expected [N, K, 3], got {tuple(self.sh.shape)}")
        sh_degree_from_count(self.sh.shape[1])  # raises for K that is not (d+1)^2

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_count(self.sh.shape[1])

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def map(self, fn) -> "Gaussians":
        """A new Gaussians with ``fn`` applied to every tensor (e.g. ``.detach()``, indexing)."""
        return Gaussians(**{name: fn(t) for name, t in self.tensors().items()})

    def to(self, device=None, dtype=None) -> "Gaussians":
        return self.map(lambda t: t.to(device=device, dtype=dtype))

    def detach(self) -> "Gaussians":
        return self.map(lambda t: t.detach())

    def subset(self, index) -> "Gaussians":
        """Select Gaussians by boolean mask or integer index."""
        return self.map(lambda t: t[index])

    def numpy(self) -> dict[str, np.ndarray]:
        """Detached float32 numpy copies, e.g. for the GL renderer's upload."""
        return {name: t.detach().to("cpu", torch.float32).numpy() for name, t in self.tensors().items()}

    @staticmethod
    def from_numpy(arrays: dict[str, np.ndarray], device=None, dtype=torch.float32) -> "Gaussians":
        return Gaussians(**{f.name: torch.as_tensor(np.asarray(arrays[f.name]), dtype=dtype, device=device)
                            for f in fields(Gaussians)})

    @staticmethod
    def empty(sh_degree: int = 0, device=None, dtype=torch.float32) -> "Gaussians":
        k = (sh_degree + 1) ** 2
        z = lambda *s: torch.zeros(*s, device=device, dtype=dtype)  # noqa: E731
        return Gaussians(z(0, 3), z(0, 3), z(0, 4), z(0), z(0, k, 3))


def gaussians_from_params(params: dict[str, torch.Tensor]) -> Gaussians:
    """The dict as a Gaussians (differentiable: shares the graph with ``params``)."""
    sh = params["sh_dc"] if "sh_rest" not in params else torch.cat([params["sh_dc"], params["sh_rest"]], 1)
    return Gaussians(params["means"], params["log_scales"], params["quats"], params["opacity_logits"], sh)
