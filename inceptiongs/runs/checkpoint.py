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
import warnings
from pathlib import Path

import numpy as np
import torch

from ..io.atomic import atomic_write_bytes
from ..io.paths import check_read_inside_named_folder
from ..io.pickles import file_names_code
from ..errors import InputError
from .checkpoint_schema import checkpoint_problem

class UnsafeCheckpointError(InputError):
    """A checkpoint that names code to run: the run folder is refused as a whole (no fallback to
    an older checkpoint beside a planted one)."""


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
    """Write ``payload`` (tensors, dicts, numbers) atomically as plain data (numpy values become
    tensors or Python numbers, sets sorted lists) so that it loads with ``weights_only=True``;
    keep the newest ``keep``."""
    buffer = io.BytesIO()
    torch.save(plain_data(payload), buffer)
    path = checkpoint_path(run_dir, iteration)
    atomic_write_bytes(path, buffer.getvalue())
    for _, old in list_checkpoints(run_dir)[:-max(keep, 1)]:
        old.unlink(missing_ok=True)
    return path


def plain_data(value):
    """``value`` with numpy arrays as tensors, numpy scalars as Python numbers, tuples and sets
    as lists: what torch's weights-only loader accepts without any allow-listed class."""
    if isinstance(value, dict):
        return {key: plain_data(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain_data(item) for item in value]
    if isinstance(value, (set, frozenset)):
        return sorted(plain_data(item) for item in value)
    if isinstance(value, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(value))
    if isinstance(value, np.generic):
        return value.item()
    return value


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
        except UnsafeCheckpointError:
            raise
        except InputError as exc:
            first_error = first_error or exc
            warn(f"{exc}; trying the previous checkpoint")
            continue
        return path, payload
    raise first_error


def load_checkpoint(path: Path) -> dict:
    """The checkpoint at ``path``, loaded as data only (``weights_only=True``: a file that names
    any class or function outside torch's tensor types is refused, never run) and checked to
    hold what a resume needs. InputError naming the file otherwise."""
    path = Path(path)
    if path.is_symlink() and not path.exists():
        raise InputError(f"{path}: not a readable checkpoint (a dangling or looping symlink)")
    check_read_inside_named_folder(path)
    try:
        with warnings.catch_warnings():   # torch warns about pickle protocols of foreign files
            warnings.simplefilter("ignore")
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a truncated, foreign or crafted file: name it, one line
        if "Weights only load failed" in str(exc) and file_names_code(path, str(exc)):
            raise UnsafeCheckpointError(f"{path}: refused: it holds Python objects other than tensors and plain "
                                        f"data (loading it could run code; an InceptionGS checkpoint never "
                                        f"does)") from None
        detail = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        if "Weights only load failed" in detail:   # torch's advice to load it unsafely is not repeated
            detail = "the weights-only loader refused it"
        raise InputError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {detail[:200]})") from None
    problem = checkpoint_problem(payload)
    if problem is not None:
        raise InputError(f"{path}: not an InceptionGS training checkpoint ({problem})")
    return payload
