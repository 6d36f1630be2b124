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


def device_memory_bytes(device=None) -> int | None:
    """Memory a torch ``device`` can give now: a CUDA device's free memory plus what torch holds
    there unused; anything else (cpu, None) the system's (:func:`available_memory_bytes`)."""
    if device is not None and getattr(device, "type", str(device).split(":")[0]) == "cuda":
        import torch  # noqa: PLC0415 (only a CUDA device needs torch here)

        try:
            free, _ = torch.cuda.mem_get_info(device)
            return int(free + torch.cuda.memory_reserved(device) - torch.cuda.memory_allocated(device))
        except (RuntimeError, AssertionError):
            return None
    return available_memory_bytes()


def _gib(count: float) -> str:
    if count >= 2**50:
        return f"{count / 2**50:.1f} PiB"
    if count >= 2**40:
        return f"{count / 2**40:.1f} TiB"
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


def check_allocation(needed: int, source: str, what: str, available: int | None = None, device=None) -> None:
    """InputError '<source>: <what> needs about N GiB of memory, only M GiB available' when
    ``needed`` bytes cannot fit: declared sizes (vertex or point counts of a file) are checked
    before anything of that size is allocated. ``available`` (bytes) defaults to what
    ``device`` (None: the system) has free (:func:`device_memory_bytes`)."""
    available = device_memory_bytes(device) if available is None else available
    if available is not None and needed > available:
        where = f" on {device}" if device is not None and str(device) != "cpu" else ""
        raise InputError(f"{source}: {what} needs about {_gib(needed)} of memory{where}, "
                         f"only {_gib(available)} available")
