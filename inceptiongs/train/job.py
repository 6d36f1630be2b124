"""Training as a job the viewer runs on a thread (see inceptiongs.live and app/live_training)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..live import JobControl, JobPublisher, SnapshotBox
from .config import TrainConfig

__all__ = ["JobControl", "TrainJob"]


@dataclass
class TrainJob:
    """Stage-I training publishing a snapshot (numpy copies) every ``snapshot_every`` steps."""

    config: TrainConfig
    run_dir: Path
    resume: bool = False
    snapshot_every: int = 10

    def run(self, box: SnapshotBox, control: JobControl) -> None:
        from .trainer import train

        out = JobPublisher(box)
        result = train(self.config, self.run_dir, resume=self.resume, progress=False, control=control,
                       on_snapshot=out.snapshot, snapshot_every=self.snapshot_every, log=out.log)
        state = "finished" if result.finished else "stopped (checkpoint written)"
        box.publish(result.iteration, None, dict(result.last_eval),
                    f"training {state} at iteration {result.iteration}")
