"""Joint stage-I + prior training (`inceptiongs train --prior`): one prior step every N trainer steps.

JointPrior is the stage-I trainer's ``after_step`` hook. The prior trainer is made at the first
prior step (the trainer has written RUN/split.json by then, so the prior sees the training
views only), or resumed from RUN/prior/prior.pt; its G-buffer patches are rendered from the
Gaussians of the step that just ran, so the prior follows the geometry as it changes. It is
checkpointed whenever the stage-I trainer checkpoints, and at the end (`finish`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..gaussians import Gaussians
from ..scene.photo_store import photo_tensor
from .trainer import CHECKPOINT_NAME, PriorTrainer, prior_dir, resume_trainer, save_prior


def training_views(run_dir: Path, scene) -> list[int]:
    """Indices of the run's training views (RUN/split.json; every view when there is none)."""
    from ..evaluation.protocols import Split

    split_path = Path(run_dir) / "split.json"
    if not split_path.is_file():
        return list(range(len(scene.cameras)))
    return list(Split.load(split_path, scene.cameras).train)


@dataclass
class JointPrior:
    """after_step(step, gaussians, checkpointed) hook. new_prior(gaussians) -> a fresh prior
    (used when RUN has no prior checkpoint, or always with restart=True)."""

    run_dir: Path
    scene: object
    new_prior: Callable[[Gaussians], object]
    every: int = 10
    log_every: int = 20
    restart: bool = False
    device: object = None
    trainer: PriorTrainer | None = None

    def __post_init__(self) -> None:
        if self.every < 1:
            raise ValueError(f"prior step interval must be >= 1, got {self.every}")

    def _start(self, gaussians: Gaussians) -> PriorTrainer:
        views = training_views(self.run_dir, self.scene)
        cameras = [self.scene.cameras[i] for i in views]
        load_image = lambda k: photo_tensor(self.scene, views[k]).numpy()  # noqa: E731  (the photo cache)
        if (prior_dir(self.run_dir) / CHECKPOINT_NAME).is_file() and not self.restart:
            return resume_trainer(self.run_dir, gaussians, cameras, load_image, device=self.device)
        (prior_dir(self.run_dir) / "metrics.jsonl").unlink(missing_ok=True)
        return PriorTrainer(self.new_prior(gaussians), gaussians, cameras, load_image)

    def __call__(self, step: int, gaussians: Gaussians, checkpointed: bool) -> None:
        if step % self.every == 0:
            if self.trainer is None:
                self.trainer = self._start(gaussians)
            self.trainer.gaussians = gaussians
            self.trainer.step()
            if self.log_every and self.trainer.step_count % self.log_every == 0:
                self.trainer.log(self.run_dir, {"stage1_iteration": step}, last=self.log_every)
        if checkpointed and self.trainer is not None:
            save_prior(self.run_dir, self.trainer)

    def finish(self) -> Path | None:
        """Checkpoint the prior (after the stage-I loop ends); None when no prior step ran."""
        if self.trainer is None:
            return None
        return save_prior(self.run_dir, self.trainer)
