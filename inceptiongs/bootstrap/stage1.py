"""The stage-I run a bootstrap starts from, loaded once: config, scene, split, checkpoint, model."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from ..evaluation.protocols import Split
from ..gaussians import Gaussians
from ..scene.loader import Scene
from ..runs.checkpoint import latest_checkpoint, load_checkpoint
from ..runs.config import TrainConfig
from ..runs.load import load_run


@dataclass
class Stage1:
    """A stage-I run folder as the bootstrap reads it.

    ``payload`` is the newest checkpoint's content (None when the run has none: the bootstrap
    then starts from ``gaussians``, which are in the normalised scene frame)."""

    run_dir: Path
    config: TrainConfig
    scene: Scene
    split: Split
    payload: dict | None
    gaussians: Gaussians

    @property
    def train_cameras(self) -> list:
        return [self.scene.cameras[i] for i in self.split.train]


def load_stage1(run_dir: str | Path) -> Stage1:
    """RUN -> :class:`Stage1`; InputError (one line) when RUN is not a trained run folder."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: run folder does not exist")
    gaussians, scene, config = load_run(run_dir)
    split_path = run_dir / "split.json"
    if not split_path.is_file():
        raise InputError(f"{split_path}: the run has no split (was it trained by `inceptiongs train`?)")
    split = Split.load(split_path, scene.cameras)
    if not split.train:
        raise InputError(f"{split_path}: no training views")
    checkpoint = latest_checkpoint(run_dir)
    payload = load_checkpoint(checkpoint) if checkpoint is not None else None
    return Stage1(run_dir, config, scene, split, payload, gaussians)


def as_stage1(run: "Stage1 | str | Path") -> Stage1:
    """A loaded run as it is; a path is loaded."""
    return run if isinstance(run, Stage1) else load_stage1(run)
