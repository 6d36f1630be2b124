"""`inceptiongs train --prior`: prior steps alternate with stage-I steps through the trainer's
after_step hook, and the prior is checkpointed with the run."""

from __future__ import annotations

import json

import pytest

from inceptiongs.cli import main
from demo_cases import copy_of_demo_scene
from inceptiongs.prior.joint import JointPrior
from inceptiongs.prior.trainer import read_prior_checkpoint

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.slow
def test_train_with_prior_alternates_and_checkpoints(tmp_path):
    scene = copy_of_demo_scene(tmp_path / "scene")
    run = tmp_path / "run"
    assert main(["train", str(scene), "--out", str(run), "--downscale", "4", "--iterations", "4",
                 "--protocol", "unstructured", "--prior", "2"]) == 0
    payload = read_prior_checkpoint(run)
    assert payload["step"] == 2 and len(payload["losses"]) == 2  # steps 2 and 4
    assert payload["backend"] == "tiny" and payload["train_s"] > 0
    # The prior trained on the training views only: split.json existed before its first step.
    split = json.loads((run / "split.json").read_text())
    assert split["train"] and split.get("scarce_test") is not None
    assert (run / "model.ply").is_file()

    assert main(["train", str(scene), "--out", str(tmp_path / "r2"), "--prior", "0"]) == 2
    assert main(["train", str(scene), "--out", str(tmp_path / "r3"), "--prior", "--prior-backend", "sd"]) == 2


def test_joint_prior_steps_on_schedule_with_the_latest_gaussians(tmp_path, monkeypatch):
    class Recorder:
        """Stands in for PriorTrainer: counts steps, remembers the Gaussians it stepped on."""
        def __init__(self):
            self.step_count, self.seen, self.gaussians = 0, [], None

        def step(self):
            self.step_count += 1
            self.seen.append(self.gaussians)
            return 0.0

    saved = []
    joint = JointPrior(tmp_path, scene=None, new_prior=None, every=3, log_every=0)
    joint.trainer = Recorder()
    monkeypatch.setattr("inceptiongs.prior.joint.save_prior", lambda run_dir, trainer: saved.append(trainer.step_count))
    for step in range(1, 11):
        joint(step, f"gaussians@{step}", checkpointed=step % 4 == 0)
    joint.finish()
    assert joint.trainer.seen == ["gaussians@3", "gaussians@6", "gaussians@9"]
    assert saved == [1, 2, 3]  # at steps 4 and 8 (1 and 2 prior steps by then), and at the end
    with pytest.raises(ValueError):
        JointPrior(tmp_path, scene=None, new_prior=None, every=0)
