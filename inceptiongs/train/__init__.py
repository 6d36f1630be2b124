"""Stage I: the PGSR-style planar 3DGS trainer.

Public entry points: :class:`TrainConfig`, :func:`train` (the loop), :func:`load_run`
(a finished or interrupted run folder -> Gaussians, Scene, config) and :class:`TrainJob`
(the loop on a viewer thread).
"""

from .config import TrainConfig
from .run_folder import load_run

__all__ = ["TrainConfig", "load_run", "train", "TrainJob", "JobControl"]


def __getattr__(name):
    # The loop pulls in the rasterizer; keep `import inceptiongs.train` cheap for readers
    # of run folders that only want load_run or the config.
    if name == "train":
        from .trainer import train
        return train
    if name in ("TrainJob", "JobControl"):
        from . import job
        return getattr(job, name)
    raise AttributeError(name)
