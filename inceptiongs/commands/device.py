"""--device auto|cpu|cuda: the one choice of rasterizer a command makes (train, render, eval)."""

from __future__ import annotations

import sys

from ..constants import DEVICES


def add_device_argument(parser, default: str | None = "auto") -> None:
    """Add --device; ``default`` None means "the run's own device" (commands reading a run)."""
    parser.add_argument("--device", choices=DEVICES, default=default,
                        help="where to render: cpu (numba), cuda (gsplat: pip install 'inceptiongs[cuda]') "
                             "or auto (cuda when usable)" + ("" if default else "; default: the run's device"))


def chosen_rasterizer(device: str):
    """The rasterizer for ``device`` (InputError, exit 2, when cuda is asked for and unusable);
    "auto" says on stderr, in one line, what it chose and why."""
    from ..rasterizer.interface import device_line, select_rasterizer

    name, rasterizer, why = select_rasterizer(device)
    if device == "auto":
        print(device_line(name, rasterizer, why), file=sys.stderr)
    return rasterizer
