"""The one size check made before any image or framebuffer is allocated (render, viewer
screenshot/window, camera JSON): pixels and estimated memory against what is available.

A request that cannot fit is refused with one line (InputError: exit status 2), instead of a
numpy/torch allocation error with a traceback many seconds later.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..constants import IMAGE_SIDE_MAX, RENDER_BYTES_PER_PIXEL
from ..errors import InputError


def available_memory_bytes() -> int | None:
    """Memory the system can give this process now (Linux MemAvailable), else the physical
    total, else None when neither can be read."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def _gib(count: float) -> str:
    return f"{count / 2**30:.1f} GiB"


def check_image_size(width: int, height: int, source: str,
                     bytes_per_pixel: int = RENDER_BYTES_PER_PIXEL, available: int | None = None) -> None:
    """InputError '<source>: ...' unless a width x height image fits: both sides in
    1..IMAGE_SIDE_MAX and width * height * bytes_per_pixel within the available memory.
    ``available`` (bytes) defaults to :func:`available_memory_bytes`."""
    if width < 1 or height < 1:
        raise InputError(f"{source}: image size {width}x{height} must be positive")
    if width > IMAGE_SIDE_MAX or height > IMAGE_SIDE_MAX:
        raise InputError(f"{source}: image size {width}x{height} is too large (at most {IMAGE_SIDE_MAX} "
                         "pixels a side)")
    available = available_memory_bytes() if available is None else available
    needed = int(width) * int(height) * bytes_per_pixel
    if available is not None and needed > available:
        raise InputError(f"{source}: image size {width}x{height} needs about {_gib(needed)} of memory, "
                         f"only {_gib(available)} available")


def check_allocation(needed: int, source: str, what: str, available: int | None = None) -> None:
    """InputError '<source>: <what> needs about N GiB of memory, only M GiB available' when
    ``needed`` bytes cannot fit: declared sizes (vertex or point counts of a file) are checked
    before anything of that size is allocated."""
    available = available_memory_bytes() if available is None else available
    if available is not None and needed > available:
        raise InputError(f"{source}: {what} needs about {_gib(needed)} of memory, only {_gib(available)} available")
