"""Real spherical-harmonics colour, the standard 3DGS basis and sign convention.

Only the bands up to the requested degree are evaluated: a degree-0 model costs one
multiply-add per channel, and the higher-band basis functions are never built.
"""

from __future__ import annotations

import torch

from .backend import use_numba
from ..constants import SH_C0, SH_C1, SH_C2, SH_C3, SH_MAX_DEGREE, SH_OFFSET, sh_coeff_count


def sh_basis(directions: torch.Tensor, degree: int) -> torch.Tensor:
    """directions: [N, 3] unit vectors -> basis values [N, (degree + 1)^2]."""
    if not 0 <= degree <= SH_MAX_DEGREE:
        raise ValueError(f"SH degree must be in 0..{SH_MAX_DEGREE}, got {degree}")
    n = directions.shape[0]
    terms = [torch.full((n,), SH_C0, dtype=directions.dtype, device=directions.device)]
    if degree >= 1:
        x, y, z = directions.unbind(-1)
        terms += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        terms += [
            SH_C2[0] * xy,
            SH_C2[1] * yz,
            SH_C2[2] * (2.0 * zz - xx - yy),
            SH_C2[3] * xz,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        terms += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(terms, dim=-1)


def sh_to_color(sh: torch.Tensor, directions: torch.Tensor, degree: int, backend: str = "auto") -> torch.Tensor:
    """sh: [N, K, 3] (K >= (degree + 1)^2), directions: [N, 3] unit -> colour [N, 3].

    colour = max(sum_k basis_k * sh_k + SH_OFFSET, 0); coefficients beyond ``degree`` are
    ignored (that is how a degree cap is applied). backend: "torch" (below), "numba"
    (:mod:`.sh_numba`, one fused CPU loop) or "auto" (numba for CPU tensors when it imports
    and the degree is above 0: a degree-0 colour is one multiply-add here already).
    """
    fast = use_numba(backend, "SH", sh, auto_allowed=degree > 0)
    count = sh_coeff_count(degree)
    if sh.shape[1] < count:
        raise ValueError(f"SH degree {degree} needs {count} coefficients, model has {sh.shape[1]}")
    if fast:
        from .sh_numba import sh_to_color_numba
        return sh_to_color_numba(sh, directions, count)
    basis = sh_basis(directions, degree)  # [N, count]
    colour = torch.einsum("nk,nkc->nc", basis, sh[:, :count])
    return torch.clamp_min(colour + SH_OFFSET, 0.0)
