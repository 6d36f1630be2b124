"""--device auto|cpu|cuda: the one choice of rasterizer a command makes (train, render, eval), and
the torch device of the prior's commands (prior, generate, eval --generated)."""

from __future__ import annotations

from ..constants import DEVICES


def add_device_argument(parser, default: str | None = "auto") -> None:
    """Add --device; ``default`` None means "the run's own device" (commands reading a run)."""
    parser.add_argument("--device", choices=DEVICES, default=default,
                        help="where to render: cpu (numba), cuda (gsplat: pip install 'inceptiongs[cuda]') "
                             "or auto (cuda when usable)" + ("" if default else "; default: the run's device"))


def chosen_rasterizer(device: str):
    """(the rasterizer for ``device``, the line saying what "auto" chose and why, else None).
    InputError (exit 2) when cuda is asked for and unusable. The caller prints the line once
    the work has started, so an error that follows stays the only line."""
    from ..rasterizer.interface import device_line, select_rasterizer

    name, rasterizer, why = select_rasterizer(device)
    return rasterizer, (device_line(name, rasterizer, why) if device == "auto" else None)


def add_torch_device_argument(parser, what: str = "") -> None:
    """Add --device for a command that runs torch models itself (the prior): auto by default."""
    parser.add_argument("--device", choices=DEVICES, default="auto",
                        help=f"torch device{what}: cpu, cuda, or auto (cuda when torch sees a GPU; default)")


def torch_device(device: str | None):
    """The torch.device for ``device`` "auto" (or None), "cpu" or "cuda". InputError (exit 2, one
    line) when cuda is asked for and torch sees no GPU: torch's own error is a traceback."""
    import torch

    from ..errors import InputError
    from ..rasterizer.interface import cuda_missing

    if device in (None, "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        what, how = cuda_missing()
        raise InputError(f"--device cuda: {what} ({how})")
    return torch.device(device)
