"""Run folders: where they go, whether one holds a result, which runs belong to a scene.

RUN/config.json (resolved TrainConfig), RUN/split.json, RUN/checkpoints/step_*.pt,
RUN/model.ply (final model in the scene's ORIGINAL frame), RUN/metrics.jsonl.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError
from ..io.paths import contained_path, read_small_text


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
