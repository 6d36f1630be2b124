"""Opening a run folder: its model (or newest checkpoint), its scene and its config."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import InputError
from ..gaussians import gaussians_from_params
from .checkpoint import latest_checkpoint, load_newest_checkpoint
from .config import TrainConfig
from .lock import writer_of
from .frames import to_normalized_frame


def load_run(run_dir: str | Path, warn=None):
    """RUN -> (Gaussians in the normalised frame (float32, CPU), Scene, TrainConfig).

    The final model.ply when training finished, else the newest checkpoint; of a run another job
    is still training, a line through ``warn`` (default: stderr) says that it reads a checkpoint of
    a run in progress (and which).
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
    writer = writer_of(run_dir)
    say = warn or (lambda line: print(f"note: {line}", file=sys.stderr))
    if model.is_file():
        if writer:   # a stopped run resumed: its model.ply is the one it stopped with
            say(f"{run_dir}: still being trained by {writer}; reading the model.ply it saved before")
        return to_normalized_frame(read_model(model), scene.normalization), scene, config
    if latest_checkpoint(run_dir) is None:
        if writer:   # a run being trained: say when there will be something to open
            raise InputError(f"{run_dir}: still being trained by {writer} and no checkpoint written yet (one "
                             f"every {config.output.checkpoint_every} steps, model.ply at the end); open it "
                             f"again then")
        raise InputError(f"{run_dir}: run has neither model.ply nor a checkpoint")
    path, payload = load_newest_checkpoint(run_dir, warn=warn)
    if writer:
        say(f"{run_dir}: still being trained by {writer}; reading its newest checkpoint, {path.name} "
            f"(iteration {payload.get('iteration', '?')} of {config.iterations})")
    return gaussians_from_params(payload["params"]).detach(), scene, config
