"""The run folder shared with evaluation and the viewer.

RUN/config.json (resolved TrainConfig), RUN/split.json, RUN/checkpoints/step_*.pt,
RUN/model.ply (final model in the scene's ORIGINAL frame), RUN/metrics.jsonl.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import torch

from ..io.atomic import append_line, atomic_write_text
from ..io.paths import contained_path, read_small_text
from ..errors import InputError
from ..gaussians import Gaussians
from .checkpoint import latest_checkpoint, load_newest_checkpoint
from .config import TrainConfig


def _log_scale_factor(scale: float) -> float:
    if not scale > 0 or not math.isfinite(scale):
        raise ValueError(f"scene normalisation scale must be positive and finite, got {scale}")
    return math.log(scale)


def to_original_frame(gaussians: Gaussians, normalization) -> Gaussians:
    """Normalised frame (x_n = (x - c) s) -> original: x = x_n / s + c; log scales - log s.

    Uses ``normalization.gaussians_to_original`` when the scene module provides it.
    """
    if hasattr(normalization, "gaussians_to_original"):
        return normalization.gaussians_to_original(gaussians)
    scale = float(normalization.scale)
    center = torch.as_tensor(normalization.center, dtype=gaussians.dtype)
    return Gaussians(gaussians.means / scale + center, gaussians.log_scales - _log_scale_factor(scale),
                     gaussians.quats, gaussians.opacity_logits, gaussians.sh)


def to_normalized_frame(gaussians: Gaussians, normalization) -> Gaussians:
    if hasattr(normalization, "gaussians_to_normalized"):
        return normalization.gaussians_to_normalized(gaussians)
    scale = float(normalization.scale)
    center = torch.as_tensor(normalization.center, dtype=gaussians.dtype)
    return Gaussians((gaussians.means - center) * scale, gaussians.log_scales + _log_scale_factor(scale),
                     gaussians.quats, gaussians.opacity_logits, gaussians.sh)


def append_metrics(run_dir: Path, record: dict) -> None:
    """One JSON line per call (appended and flushed; a torn last line is dropped on resume)."""
    append_line(Path(run_dir) / "metrics.jsonl", json.dumps(record))


def truncate_metrics(run_dir: Path, last_iteration: int) -> None:
    """Keep only records up to ``last_iteration`` (the resumed checkpoint): the steps after
    it will be run again and logged again."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.exists():
        return
    kept = []
    # Through the read guard: a run may come from someone else (no symlink out, a log's size).
    for line in read_small_text(contained_path(run_dir, "metrics.jsonl", str(run_dir)), "metrics log").splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # the line a kill cut in half
        if isinstance(record, dict) and record.get("iteration", 0) <= last_iteration:
            kept.append(line)
    atomic_write_text(path, "".join(line + "\n" for line in kept))


def logged_iterations(run_dir: Path) -> set[int]:
    """The iterations metrics.jsonl already holds a record for (torn lines skipped)."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.is_file():
        return set()
    found = set()
    for line in read_small_text(contained_path(run_dir, "metrics.jsonl", str(run_dir)), "metrics log").splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(record, dict) and isinstance(record.get("iteration"), int):
            found.add(record["iteration"])
    return found


# Files whose presence means a folder holds a result the user has not asked to lose.
RESULT_FILES = ("model.ply", "config.json", "metrics.jsonl", "checkpoints")


def holds_result(folder: str | Path) -> bool:
    """Whether ``folder`` holds a run or bootstrap result (a model, a log or checkpoints)."""
    folder = Path(folder)
    return folder.is_dir() and any((folder / name).exists() for name in RESULT_FILES)


def next_free_folder(folder: str | Path) -> Path:
    """``folder`` if it holds no result, else the first of FOLDER_2, FOLDER_3, ... that
    holds none: a new result never lands on an old one."""
    folder = Path(folder)
    if not holds_result(folder):
        return folder
    index = 2
    while holds_result(folder.with_name(f"{folder.name}_{index}")):
        index += 1
    return folder.with_name(f"{folder.name}_{index}")


# `inceptiongs train` without --out writes ./runs/NAME (NAME: the scene folder's name), in the
# current folder, never in the scene's; `inceptiongs bootstrap` then writes NAME_bootstrap beside it.
CLI_RUNS_FOLDER = "runs"


def default_run_dir(scene: str | Path, cwd: str | Path | None = None) -> Path:
    """./runs/NAME for the scene folder (or transforms.json file) ``scene``: in ``cwd`` (default:
    the current folder), never in the scene's."""
    resolved = Path(scene).resolve()
    name = resolved.parent.name if resolved.is_file() else resolved.name
    return Path(cwd if cwd is not None else Path.cwd()) / CLI_RUNS_FOLDER / (name or "scene")


# The user's own work beside the runs (saved PLYs, screenshots, the viewer's flags): ./runs/NAME_saved.
SAVED_SUFFIX = "_saved"


def default_saved_dir(scene_root: str | Path, cwd: str | Path | None = None) -> Path:
    """./runs/NAME_saved: where the viewer keeps what a user made of a scene (its flags.json, saved
    PLYs, screenshots) and where `inceptiongs bootstrap` looks for those flags."""
    run = default_run_dir(scene_root, cwd)
    return run.with_name(run.name + SAVED_SUFFIX)


def is_run_of(run_dir: str | Path, scene_root: str | Path) -> bool:
    """Whether ``run_dir`` is a run (config.json with a model or checkpoints) of the scene at
    ``scene_root``: its config names that scene. An unreadable config is not a run of anything."""
    run_dir = Path(run_dir)
    if not ((run_dir / "model.ply").is_file() or (run_dir / "checkpoints").is_dir()):
        return False
    try:
        scene = json.loads(read_small_text(contained_path(run_dir, "config.json", str(run_dir)),
                                           "run config")).get("scene")
    except (OSError, ValueError, AttributeError, InputError):
        return False
    return isinstance(scene, str) and Path(scene).resolve() == Path(scene_root).resolve()


def cli_run_dirs(scene_root: str | Path, cwd: str | Path | None = None) -> list[Path]:
    """The runs the command line wrote for a scene with its default folders: ./runs/NAME,
    NAME_2 ..., NAME_bootstrap ... (every folder of ./runs whose name starts with NAME and whose
    config names this scene), sorted by name."""
    default = default_run_dir(scene_root, cwd)
    if not default.parent.is_dir():
        return []
    return sorted(folder for folder in default.parent.iterdir()
                  if folder.is_dir() and folder.name.startswith(default.name) and is_run_of(folder, scene_root))


def load_run(run_dir: str | Path):
    """RUN -> (Gaussians in the normalised frame (float32, CPU), Scene, TrainConfig).

    The final model.ply when training finished, else the newest checkpoint.
    """
    from ..io.ply import read_ply
    from ..scene.loader import load_scene

    run_dir = Path(run_dir)
    config_path = run_dir / "config.json"
    if not config_path.is_file():
        raise InputError(f"{run_dir}: not a run folder (no config.json)")
    config = TrainConfig.load(config_path)
    scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
    model = run_dir / "model.ply"
    if model.is_file():
        return to_normalized_frame(read_ply(model), scene.normalization), scene, config
    if latest_checkpoint(run_dir) is None:
        raise InputError(f"{run_dir}: run has neither model.ply nor a checkpoint")
    from .optim import gaussians_from_params
    params = load_newest_checkpoint(run_dir)[1]["params"]
    return gaussians_from_params(params).detach(), scene, config
