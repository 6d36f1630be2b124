"""Which implementation of a rasterizer stage runs: the torch reference or its numba fast path.

Every stage (projection, SH colour, composite) takes ``backend`` = "torch", "numba" or "auto"
with the same meaning: "numba" always takes the fast path (ImportError when numba is not
installed), "auto" takes it for CPU tensors when numba imports and the stage allows it here.
"""

from __future__ import annotations

import importlib.util
from functools import lru_cache

import torch

BACKENDS = ("auto", "torch", "numba")


@lru_cache(maxsize=1)
def numba_installed() -> bool:
    return importlib.util.find_spec("numba") is not None


def use_numba(backend: str, stage: str, tensor: torch.Tensor, auto_allowed: bool = True) -> bool:
    """Whether ``stage`` runs its numba path for ``tensor``'s inputs. Raises ValueError for an
    unknown backend and ImportError for "numba" without numba; ``auto_allowed`` False keeps
    "auto" on torch (a case the fast path does not cover)."""
    if backend not in BACKENDS:
        raise ValueError(f"{stage} backend must be auto, torch or numba, got {backend!r}")
    if backend == "torch":
        return False
    if backend == "numba":
        if not numba_installed():
            raise ImportError(f"{stage} backend 'numba' needs the numba package (pip install numba)")
        return True
    return auto_allowed and tensor.device.type == "cpu" and numba_installed()
