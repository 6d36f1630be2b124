"""A stopped bootstrap keeps its work: stop saves the model, the summary and a checkpoint, in that
order; `--resume` continues it; `--overwrite` says what it discards; a full disk still leaves
the model."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from inceptiongs.bootstrap import loop as bootstrap_loop
from inceptiongs.bootstrap.config import BootstrapConfig
from inceptiongs.bootstrap.runner import check_output_folder, resolve_targets, run_bootstrap
from inceptiongs.bootstrap.stage1 import load_stage1
from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.io.atomic import OutputError
from inceptiongs.live import JobControl
from inceptiongs.runs.checkpoint import list_checkpoints
from train_cases import tiny_demo_run

STEPS = 12


@pytest.fixture(scope="module")
def stage1(tmp_path_factory) -> Path:
    return tiny_demo_run(tmp_path_factory.mktemp("resume"))


def _config(**overrides) -> BootstrapConfig:
    # The default supervision (no prior), small: every step logged, no checkpoint but the final one;
    # virtual steps from the start although the tiny stage I still rises fast (its outlook not followed).
    base = BootstrapConfig(seed=2, iterations=STEPS, k=2, l=2, log_every=1, save_views=0, checkpoint_every=1000,
                           regenerate_every=0, follow_outlook=False)
    return dataclasses.replace(base, **overrides)


def _targets(run: Path):
    loaded = load_stage1(run)
    return resolve_targets(loaded.scene, loaded.split, None, None, 1)


class _StopAt:
    def __init__(self, iteration: int):
        self.iteration, self.control = iteration, JobControl()

    def __call__(self, iteration, gaussians, record) -> None:
        if iteration >= self.iteration:
            self.control.stop.set()


def _stopped(stage1: Path, out: Path, at: int):
    stopper = _StopAt(at)
    result = run_bootstrap(stage1, out, _targets(stage1), _config(), control=stopper.control, progress=False,
                           on_snapshot=stopper, snapshot_every=1)
    return result


def test_a_stopped_bootstrap_saves_and_resumes_where_it_stopped(stage1, tmp_path):
    out = tmp_path / "boot"
    stopped = _stopped(stage1, out, at=stage1_start(stage1) + 5)
    assert not stopped.finished and stopped.iteration == stopped.start_iteration + 5
    assert (out / "model.ply").is_file()                                   # stop means save
    assert list_checkpoints(out)[-1][0] == stopped.iteration
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert summary["stopped"] is True and summary["iteration"] == stopped.iteration
    with pytest.raises(InputError, match="--resume"):
        check_output_folder(out, overwrite=False)
    # Resumed with no targets given: they come from RUN2/bootstrap/targets.json.
    resumed = run_bootstrap(stage1, out, None, _config(), progress=False, resume=True)
    assert resumed.finished and resumed.iteration == stopped.start_iteration + STEPS
    assert resumed.virtual_views > 0
    steps = [json.loads(line)["iteration"] for line in (out / "metrics.jsonl").read_text().splitlines()
             if "loss" in json.loads(line)]
    assert steps == list(range(stopped.start_iteration + 1, stopped.start_iteration + STEPS + 1))  # each once
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert summary["resumed_at"] == stopped.iteration and summary["stopped"] is False
    # The sampler's visits went into the checkpoint: view_use counts the virtual steps of both parts.
    virtual = [line for line in (out / "metrics.jsonl").read_text().splitlines()
               if json.loads(line).get("kind") == "virtual"]
    assert sum(summary["view_use"].values()) == len(virtual) > 0
    check_output_folder(out, overwrite=True)
    with pytest.raises(InputError, match="already holds a result"):   # a finished one: nothing to resume
        check_output_folder(out, overwrite=False)


def stage1_start(stage1: Path) -> int:
    return int(json.loads((stage1 / "config.json").read_text())["iterations"])


def test_overwrite_says_which_checkpoint_it_discards(stage1, tmp_path):
    out = tmp_path / "boot"
    _stopped(stage1, out, at=stage1_start(stage1) + 2)
    logged: list[str] = []
    run_bootstrap(stage1, out, _targets(stage1), _config(iterations=2), progress=False, overwrite=True,
                  log=logged.append)
    assert any("discarding" in line and "--resume" in line for line in logged), logged


def test_a_full_disk_at_the_checkpoint_still_leaves_the_model_and_summary(stage1, tmp_path, monkeypatch):
    def no_space(*args, **kwargs):
        raise OutputError(f"{tmp_path}: no space left on device")

    monkeypatch.setattr(bootstrap_loop, "save_checkpoint", no_space)
    out = tmp_path / "boot"
    with pytest.raises(OutputError, match="no space"):
        run_bootstrap(stage1, out, _targets(stage1), _config(iterations=3), progress=False)
    assert (out / "model.ply").is_file()
    assert json.loads((out / "bootstrap" / "summary.json").read_text())["iteration"] > 0


def test_resume_without_a_checkpoint_is_one_line(stage1, tmp_path, capsys):
    status = main(["bootstrap", str(stage1), "--out", str(tmp_path / "nothing"), "--resume"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "no bootstrap checkpoint" in err[0]
    assert not (tmp_path / "nothing").exists()


def test_a_bootstrap_stopped_before_its_first_step_saves_a_checkpoint_resume_continues(stage1, tmp_path):
    """Ctrl+C in the first seconds (while the bootstrap still prepares) used to save no checkpoint
    while the line said it had: `--resume` then found none and a plain rerun wanted --overwrite."""
    out = tmp_path / "boot"
    control = JobControl()
    control.stop.set()   # the stop arrives before the first step
    stopped = run_bootstrap(stage1, out, _targets(stage1), _config(), control=control, progress=False)
    assert not stopped.finished and stopped.iteration == stopped.start_iteration
    assert list_checkpoints(out) and list_checkpoints(out)[-1][0] == stopped.start_iteration
    resumed = run_bootstrap(stage1, out, None, _config(), progress=False, resume=True)
    assert resumed.finished and resumed.iteration == stopped.start_iteration + STEPS


def test_a_bootstrap_killed_before_its_first_save_can_simply_be_run_again(stage1, tmp_path):
    """kill -9 in the first seconds leaves RUN2/bootstrap/ and the input scores but no model and
    no checkpoint: nothing to resume, so a plain rerun starts again instead of asking for --overwrite."""
    out = tmp_path / "boot"
    (out / "bootstrap").mkdir(parents=True)
    (out / "config.json").write_text("{}")
    (out / "metrics.jsonl").write_text('{"iteration": 0}\n')
    check_output_folder(out, overwrite=False)        # no InputError
    with pytest.raises(InputError, match="without --resume"):
        from inceptiongs.bootstrap.runner import resumable
        resumable(out)


def test_a_resume_that_makes_no_step_keeps_the_scores_it_stopped_with(stage1, tmp_path):
    """`bootstrap --resume --minutes M` with M already spent makes no step; its summary said the
    input's scores were the result ("scarce 19.34 -> 19.34 dB" for a model that scored 19.63)."""
    out = tmp_path / "boot"
    stopped = _stopped(stage1, out, at=stage1_start(stage1) + 5)
    before = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert before["last_eval"] != before["initial_eval"]       # the stop scored the model it saved
    control = JobControl()
    control.stop.set()                                          # nothing left to do: no step
    resumed = run_bootstrap(stage1, out, None, _config(), control=control, progress=False, resume=True)
    assert resumed.iteration == stopped.iteration
    after = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert after["last_eval"] == before["last_eval"], (after["last_eval"], before["last_eval"])
    assert resumed.last_eval == before["last_eval"]
    # A new budget already spent is said, not left to read from an unchanged iteration count.
    logged: list[str] = []
    again = run_bootstrap(stage1, out, None, _config(minutes=before["wall_s"] / 120.0), progress=False, resume=True,
                          log=logged.append)
    assert again.iteration == stopped.iteration
    assert any("was spent before it stopped" in line and "no step will be made" in line for line in logged), logged
