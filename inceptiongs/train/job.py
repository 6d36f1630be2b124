"""Training as a job the viewer runs on a thread (see inceptiongs.live and app/live_training)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path

from ..live import SnapshotBox
from .config import TrainConfig


@dataclass
class JobControl:
    """Set ``pause`` to pause (clear to continue); set ``stop`` to checkpoint and return."""

    pause: threading.Event = field(default_factory=threading.Event)
    stop: threading.Event = field(default_factory=threading.Event)


@dataclass
class TrainJob:
    """Stage-I training publishing a snapshot (numpy copies) every ``snapshot_every`` steps."""

    config: TrainConfig
    run_dir: Path
    resume: bool = False
    snapshot_every: int = 10

    def run(self, box: SnapshotBox, control: JobControl) -> None:
        from .trainer import train

        latest_iteration = 0

        def publish(iteration: int, gaussians, metrics: dict) -> None:
            nonlocal latest_iteration
            latest_iteration = iteration
            # numpy() copies on this thread, so the viewer never sees tensors being updated.
            box.publish(iteration, gaussians.numpy(), metrics)

        def log(message: str) -> None:
            box.publish(latest_iteration, None, {}, message)

        result = train(self.config, self.run_dir, resume=self.resume, progress=False, control=control,
                       on_snapshot=publish, snapshot_every=self.snapshot_every, log=log)
        state = "finished" if result.finished else "stopped (checkpoint written)"
        box.publish(result.iteration, None, dict(result.last_eval),
                    f"training {state} at iteration {result.iteration}")
