"""--device auto|cpu|cuda: the one choice of rasterizer a command makes (train, render, eval)."""

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
