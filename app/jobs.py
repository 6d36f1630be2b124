"""Which background job the viewer runs for a source: stage-I training for a scene, stage-II
bootstrapping of the flagged views for a trained run. Built when the user presses the button,
so flags made during the session count."""

from __future__ import annotations

import time
from pathlib import Path

from inceptiongs.errors import InputError

# A viewer-started training run: a CPU-sized schedule (the CLI's default when only a time
# budget is given); the user watches it and stops it when it looks good.
VIEWER_TRAIN_ITERATIONS = 5000


def run_dir_of(source) -> Path | None:
    """The stage-I run folder a source shows (a run, or a scene opened at its newest run)."""
    if source.kind == "run" and (Path(source.path) / "config.json").is_file():
        return Path(source.path)
    model = getattr(source, "model_path", None)
    if model is not None and (Path(model).parent / "config.json").is_file():
        return Path(model).parent
    return None


def train_job_for(source):
    """A new stage-I run of the source's scene in <scene work dir>/runs/viewer-<time>."""
    from inceptiongs.train.config import TrainConfig, short_run_schedule
    from inceptiongs.train.job import TrainJob

    if source.scene is None:
        raise InputError(f"{source.path}: no scene to train (open a scene folder)")
    config = short_run_schedule(TrainConfig(scene=str(Path(source.scene.root).resolve()),
                                            iterations=VIEWER_TRAIN_ITERATIONS))
    run_dir = Path(source.work_dir) / "runs" / time.strftime("viewer-%Y%m%d-%H%M%S")
    return TrainJob(config=config, run_dir=run_dir)


def bootstrap_job_for(source, flags_file: Path, config=None):
    """Stage II of the source's run on the views flagged in ``flags_file`` (config: a
    BootstrapConfig, default the command line's defaults)."""
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.job import BootstrapJob
    from inceptiongs.io.flags import read_flag_cameras

    run_dir = run_dir_of(source)
    if run_dir is None:
        raise InputError(f"{source.path}: bootstrapping needs a trained run (train first)")
    if not Path(flags_file).is_file() or not read_flag_cameras(flags_file):
        raise InputError("no flagged views: flag the bad views first (F or right-click)")
    return BootstrapJob(run_dir=run_dir, targets_file=Path(flags_file), config=config or BootstrapConfig())


def default_job(source, flags_file: Path):
    """Bootstrap for a run with flags, else stage-I training of the scene."""
    if run_dir_of(source) is not None and Path(flags_file).is_file() and read_flags_count(flags_file):
        return bootstrap_job_for(source, flags_file)
    return train_job_for(source)


def read_flags_count(flags_file: Path) -> int:
    from inceptiongs.io.flags import read_flag_cameras

    try:
        return len(read_flag_cameras(flags_file))
    except InputError:
        return 0


def start_bootstrap(viewer, config=None) -> None:
    """The viewer's "Bootstrap" action: run stage II on the flagged views as the live job."""
    from .live_training import LiveTraining

    if viewer.training is not None and viewer.training.alive:
        viewer.status = "a job is running: stop it before bootstrapping"
        return
    try:
        job = bootstrap_job_for(viewer.source, viewer.flags_file, config)
    except Exception as exc:  # noqa: BLE001 - shown in the status line, never fatal
        viewer.status = f"bootstrap could not start: {exc}"
        return
    viewer.training = LiveTraining(job)
    viewer.training.start()
    viewer.status = f"bootstrapping {len(viewer.flags)} flagged view(s) of {job.run_dir}"
