"""Opening a run folder: its model (or newest checkpoint), its scene and its config."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..gaussians import gaussians_from_params
from .checkpoint import latest_checkpoint, load_newest_checkpoint
from .config import TrainConfig
from .frames import to_normalized_frame
from .lock import run_folder_writer


def load_run(run_dir: str | Path):
    """RUN -> (Gaussians in the normalised frame (float32, CPU), Scene, TrainConfig).

    The final model.ply when training finished, else the newest checkpoint.
    """
    from ..io.models import read_model
    from ..scene.loader import load_scene

    run_dir = Path(run_dir)
    config_path = run_dir / "config.json"
    if not config_path.is_file():
        raise InputError(f"{run_dir}: not a run folder (no config.json)")
    config = TrainConfig.load(config_path)
    scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
    model = run_dir / "model.ply"
    if model.is_file():
        return to_normalized_frame(read_model(model), scene.normalization), scene, config
    if latest_checkpoint(run_dir) is None:
        writer = run_folder_writer(run_dir)
        if writer is not None:   # a run being trained: say when there will be something to open
            raise InputError(f"{run_dir}: still being trained by {writer} and no checkpoint written yet (one "
                             f"every {config.output.checkpoint_every} steps, model.ply at the end); open it "
                             f"again then")
        raise InputError(f"{run_dir}: run has neither model.ply nor a checkpoint")
    params = load_newest_checkpoint(run_dir)[1]["params"]
    return gaussians_from_params(params).detach(), scene, config
