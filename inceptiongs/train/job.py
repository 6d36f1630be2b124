"""Training as a job the viewer runs on a thread (an :class:`inceptiongs.live.Job`; see app/live_training)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..live import JobControl, JobPublisher, SnapshotBox
from ..runs.config import TrainConfig

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
        out.finish("training", result.iteration, result.finished, result.last_eval)
