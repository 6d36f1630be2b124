"""A GPU out of memory during training stops with one line naming the step, what was kept and what
to change; nothing is saved after it (a step cut short may have changed part of the model), and
the newest checkpoint stays resumable. The out-of-memory error is raised by a stand-in step, so
this runs on any machine."""

from __future__ import annotations

import pytest
import torch

from inceptiongs import cli
from inceptiongs.errors import DeviceMemoryError
from inceptiongs.scene.courtyard import write_courtyard_scene
from inceptiongs.train import trainer
from inceptiongs.runs.checkpoint import list_checkpoints
from inceptiongs.runs.config import Output, TrainConfig, short_run_schedule


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return write_courtyard_scene(tmp_path_factory.mktemp("oom") / "scene", size="tiny", seed=0)


def _fail_at(monkeypatch, failing_step: int) -> None:
    real_step = trainer.train_step

    def step(number, *args, **kwargs):
        if number == failing_step:
            raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB")
        return real_step(number, *args, **kwargs)

    monkeypatch.setattr(trainer, "train_step", step)


def test_out_of_memory_keeps_the_newest_checkpoint_and_says_what_to_change(scene, tmp_path, monkeypatch):
    _fail_at(monkeypatch, 13)
    config = short_run_schedule(TrainConfig(scene=str(scene), protocol="unstructured", iterations=40, device="cpu",
                                            output=Output(checkpoint_every=5, eval_every=1000)))
    run_dir = tmp_path / "run"
    with pytest.raises(DeviceMemoryError) as caught:
        trainer.train(config, run_dir, progress=False, log=lambda _: None)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"{run_dir}: the GPU ran out of memory at step 13 with ")
    assert "kept: step_0000010.pt (--resume continues from it)" in message
    assert "--downscale" in message and "--strategy mcmc" in message
    assert [step for step, _ in list_checkpoints(run_dir)][-1] == 10     # nothing written after the failure
    assert not (run_dir / "model.ply").exists()


def test_the_command_line_prints_one_line_and_exits_2(scene, tmp_path, monkeypatch, capsys):
    _fail_at(monkeypatch, 3)
    code = cli.main(["train", str(scene), "--out", str(tmp_path / "run"), "--iterations", "20",
                     "--protocol", "unstructured", "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith("error: ") and "ran out of memory at step 3" in err[-1] and "no checkpoint yet" in err[-1]
    assert not any("Traceback" in line for line in err)
