"""The FID feature extractor a user gives by path on the command line (TorchScript: it runs
code, so no run, scene or config ever names it; LPIPS weights are plain tensors, lpips_net)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import torch

from ..errors import InputError


def load_torchscript(path: str | Path, what: str) -> Callable:
    """A user-given TorchScript network (LPIPS or FID feature extractor), in eval mode."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} weights file does not exist")
    try:
        module = torch.jit.load(str(path), map_location="cpu")
    except (RuntimeError, ValueError, OSError) as exc:
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: not a TorchScript {what} network ({first_line})") from None
    return module.eval()
