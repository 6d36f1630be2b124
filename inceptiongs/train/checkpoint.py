"""Checkpoints: everything the loop needs to continue exactly where it stopped.

RUN/checkpoints/step_XXXXXXX.pt holds the parameters, the Adam state, the densification
statistics, the iteration, the elapsed wall time and every random state the loop draws
from, so a resumed run with the same seed repeats the uninterrupted one. Written
atomically: a kill mid-write leaves the previous checkpoint intact.
"""

from __future__ import annotations

import io
import re
import sys
from pathlib import Path

import torch

from ..io.atomic import atomic_write_bytes
from ..errors import InputError

_NAME = re.compile(r"^step_(\d{7,})\.pt$")


def checkpoint_path(run_dir: Path, iteration: int) -> Path:
    return Path(run_dir) / "checkpoints" / f"step_{iteration:07d}.pt"


def list_checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """[(iteration, path)] sorted by iteration; temp files of interrupted writes are ignored."""
    folder = Path(run_dir) / "checkpoints"
    if not folder.is_dir():
        return []
    found = []
    for path in folder.iterdir():
        match = _NAME.match(path.name)
        if match:
            found.append((int(match.group(1)), path))
    return sorted(found)


def latest_checkpoint(run_dir: Path) -> Path | None:
    found = list_checkpoints(run_dir)
    return found[-1][1] if found else None


def save_checkpoint(run_dir: Path, iteration: int, payload: dict, keep: int) -> Path:
    """Write ``payload`` (tensors, dicts, numbers) atomically; keep the newest ``keep``."""
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    path = checkpoint_path(run_dir, iteration)
    atomic_write_bytes(path, buffer.getvalue())
    for _, old in list_checkpoints(run_dir)[:-max(keep, 1)]:
        old.unlink(missing_ok=True)
    return path


def load_newest_checkpoint(run_dir: Path, warn=None) -> tuple[Path, dict]:
    """The newest checkpoint that loads: (path, payload). A corrupt newest one (a disk that
    filled or a file damaged after its atomic write) falls back to the previous kept one, with
    a warning line through ``warn`` (default: stderr). InputError when none loads."""
    found = list_checkpoints(run_dir)
    if not found:
        raise InputError(f"{run_dir}: no checkpoint")
    if warn is None:
        def warn(message: str) -> None:
            print(f"warning: {message}", file=sys.stderr)
    first_error = None
    for _, path in reversed(found):
        try:
            payload = load_checkpoint(path)
        except InputError as exc:
            first_error = first_error or exc
            warn(f"{exc}; trying the previous checkpoint")
            continue
        return path, payload
    raise first_error


def load_checkpoint(path: Path) -> dict:
    try:
        # Our own files hold numpy RNG states (plain dicts/ints) besides tensors.
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # a truncated or foreign file: name it, one line
        raise InputError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {exc})") from None
    if not isinstance(payload, dict) or "iteration" not in payload or "params" not in payload:
        raise InputError(f"{path}: not an InceptionGS training checkpoint")
    return payload
