"""The photo budget (``--photo-memory``): bytes of decoded photos a photo store may hold
(inceptiongs.scene.photo_store), parsed from the flag, else a share of the free memory."""

from __future__ import annotations

import os
import re

from ..errors import InputError

PHOTO_MEMORY_ENV = "INCEPTIONGS_PHOTO_MEMORY"
_PHOTO_MEMORY: int | None = None          # bytes; None: default_budget()
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
PHOTO_MEMORY_HELP = ("bytes of decoded photos held in memory (e.g. 1G, 512M; default: all of them, at most a "
                     "quarter of the free memory; also $INCEPTIONGS_PHOTO_MEMORY); the rest are read from the "
                     "decoded-photo cache as needed")


def parse_memory(text: str, flag: str = "--photo-memory") -> int:
    """ "1G", "512M", "1.5G", "800000" -> bytes; InputError naming ``flag`` otherwise."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([KMGT]?)i?B?\s*", str(text), re.IGNORECASE)
    if match is None:
        raise InputError(f"{flag}: {text!r} is not a size (e.g. 1G, 512M or a number of bytes)")
    value = float(match.group(1)) * _UNITS[match.group(2).upper()]
    if value <= 0:
        raise InputError(f"{flag}: {text!r} must be more than 0 bytes")
    return int(value)


def set_photo_memory(nbytes: int | None) -> None:
    """The photo budget of the stores made from now on (None: default_budget)."""
    global _PHOTO_MEMORY
    _PHOTO_MEMORY = nbytes


def available_memory() -> int | None:
    """Bytes the system can still give (MemAvailable), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def default_budget(all_bytes: int) -> int:
    """All photos when they take at most a quarter of the free memory, else that quarter
    (the model, its optimiser and the renders need the rest)."""
    free = available_memory()
    return all_bytes if free is None else min(all_bytes, max(free // 4, 1))


def photo_memory() -> int | None:
    """The budget set by set_photo_memory (the flag), else $INCEPTIONGS_PHOTO_MEMORY (for every
    command, stage II's included), else None: default_budget."""
    if _PHOTO_MEMORY is not None:
        return _PHOTO_MEMORY
    text = os.environ.get(PHOTO_MEMORY_ENV)
    return None if not text else parse_memory(text, f"${PHOTO_MEMORY_ENV}")
