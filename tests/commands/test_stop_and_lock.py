"""Stop means save (Ctrl+C and SIGTERM during `train`), and one writer per run folder."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.runs.lock import LOCK_INFO_FILE, run_folder_lock
from inceptiongs.live import JobControl
from demo_cases import copy_of_demo_scene
from inceptiongs.stop_signals import stop_on_signals
from inceptiongs.runs.checkpoint import list_checkpoints


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return copy_of_demo_scene(tmp_path_factory.mktemp("stop") / "scene")


def test_first_signal_asks_to_stop_the_second_interrupts_and_handlers_come_back():
    before = signal.getsignal(signal.SIGTERM)
    control, said = JobControl(), []
    control.listening.set()                 # the job's loop has begun
    with pytest.raises(KeyboardInterrupt):
        with stop_on_signals(control, said.append) as request:
            os.kill(os.getpid(), signal.SIGTERM)
            assert control.stop.is_set() and request.signum == signal.SIGTERM
            assert request.exit_status == 143 and len(said) == 1 and "SIGTERM" in said[0]
            os.kill(os.getpid(), signal.SIGINT)   # again: quit now
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_signal_during_the_set_up_stops_at_once_with_its_status():
    """Before the job's loop listens (its set-up) there is nothing to save: the first signal
    raises at once, saying so, with the shell's status for it; the CLI prints nothing more."""
    from inceptiongs.stop_signals import StoppedDuringSetup

    control, said = JobControl(), []
    with pytest.raises(StoppedDuringSetup) as stopped:
        with stop_on_signals(control, said.append):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)                  # the handler runs at the next bytecode: never reached
            raise AssertionError("the set-up went on after SIGTERM")
    assert stopped.value.exit_status == 143 and control.stop.is_set()
    assert said == ["SIGTERM: stopping during the set-up (nothing to save yet)"]


def test_train_stopped_during_its_set_up_exits_at_once_and_the_same_command_starts_again(tmp_path, scene,
                                                                                           monkeypatch, capsys):
    """`train` whose set-up is interrupted (here: a SIGTERM while it reads the scene) exits 143
    with one line and no traceback; what it left is resumable: --resume trains the whole run."""
    from inceptiongs.train import trainer

    real_load, signals_left = trainer.load_scene, [1]

    def load_then_signal(*args, **kwargs):
        scene_loaded = real_load(*args, **kwargs)
        if signals_left.pop() if signals_left else 0:
            os.kill(os.getpid(), signal.SIGTERM)
        return scene_loaded

    run = tmp_path / "run"
    command = ["train", str(scene), "--out", str(run), "--iterations", "4", "--downscale", "4"]
    monkeypatch.setattr(trainer, "load_scene", load_then_signal)     # the name the trainer's set-up calls
    assert main(command) == 143
    err = capsys.readouterr().err
    assert "SIGTERM: stopping during the set-up (nothing to save yet)" in err and "Traceback" not in err, err
    assert not (run / "model.ply").exists() and not (run / LOCK_INFO_FILE).exists()
    status = main(command + (["--resume"] if (run / "config.json").exists() else []))
    assert status == 0 and (run / "model.ply").is_file(), capsys.readouterr().err


def test_a_second_writer_is_refused_naming_the_holder(tmp_path, scene):
    run = tmp_path / "run"
    with run_folder_lock(run):
        assert (run / LOCK_INFO_FILE).read_text().strip() == str(os.getpid())
        with pytest.raises(InputError, match=rf"in use by pid {os.getpid()}"):
            with run_folder_lock(run):
                pass
        status = main(["train", str(scene), "--out", str(run), "--iterations", "2", "--downscale", "4"])
        assert status == 2
        assert not (run / "config.json").exists()     # refused before writing anything
    assert not run.exists()   # made by the lock, left empty: removed again
    with run_folder_lock(run):   # free once released
        pass


def test_reading_a_run_another_job_still_trains_says_so(tmp_path, scene, capsys):
    """eval (and every command that opens a run) on a run in progress reads its newest checkpoint:
    it says so, naming the job and the step, instead of scoring a half-trained model unsaid."""
    run = tmp_path / "run"
    assert main(["train", str(scene), "--out", str(run), "--iterations", "2", "--downscale", "4"]) == 0
    (run / "model.ply").unlink()     # as while it trains: checkpoints only
    step = list_checkpoints(run)[-1][1].name
    capsys.readouterr()
    with run_folder_lock(run):
        assert main(["eval", str(run)]) == 0
        err = capsys.readouterr().err
        assert f"still being trained by pid {os.getpid()}" in err and step in err
        for _, path in list_checkpoints(run):
            path.unlink()
        assert main(["eval", str(run)]) == 2
        assert f"still being trained by pid {os.getpid()} and no checkpoint written yet" in capsys.readouterr().err


def _wait_for(predicate, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.2)
    return False


@pytest.mark.slow
@pytest.mark.parametrize("signum, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_stopped_train_saves_model_and_checkpoint_and_resumes(tmp_path, scene, signum, status, capsys):
    run = tmp_path / "run"
    command = [sys.executable, "-m", "inceptiongs", "train", str(scene), "--out", str(run), "--iterations", "2000",
               "--downscale", "4", "--protocol", "unstructured", "--seed", "0"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        # metrics.jsonl holds the initial evaluation, then a line per log_every steps.
        started = _wait_for(lambda: (run / "metrics.jsonl").is_file()
                            and len((run / "metrics.jsonl").read_text().splitlines()) >= 2, 240)
        assert started, "training did not start"
        process.send_signal(signum)
        out, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == status, err
    assert "Traceback" not in err and "Fatal" not in err and "*** " not in err, err
    assert "stopped at iteration" in err
    assert (run / "model.ply").is_file()
    checkpoints = list_checkpoints(run)
    assert checkpoints and 0 < checkpoints[-1][0] < 2000
    assert not (run / LOCK_INFO_FILE).exists()
    if signum == signal.SIGINT:   # --resume continues from the saved step (a minute's budget, stopped at once)
        capsys.readouterr()
        assert main(command[3:5] + ["--out", str(run), "--resume", "--minutes", "0.001"]) == 0
        assert f"resumed from step_{checkpoints[-1][0]:07d}" in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_during_a_bootstrap_saves_and_resume_continues(tmp_path, scene, capsys):
    from inceptiongs.runs.config import Output, PGSRTerms, TrainConfig
    from inceptiongs.train.trainer import train

    run, out = tmp_path / "run", tmp_path / "boot"
    train(TrainConfig(scene=str(scene), downscale=4, protocol="unstructured", seed=1, iterations=10,
                      output=Output(log_every=5, eval_every=10, checkpoint_every=10),
                      pgsr_terms=PGSRTerms(multiview_from=1000)), run, progress=False)
    command = [sys.executable, "-m", "inceptiongs", "bootstrap", str(run), "--out", str(out)]
    process = subprocess.Popen(command + ["--iterations", "5000"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        started = _wait_for(lambda: (out / "metrics.jsonl").is_file()
                            and len((out / "metrics.jsonl").read_text().splitlines()) >= 3, 240)
        assert started, "the bootstrap did not start"
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, err
    assert "Traceback" not in err and "stopped at iteration" in err and "--resume" in err
    assert (out / "model.ply").is_file() and list_checkpoints(out)
    stopped_at = list_checkpoints(out)[-1][0]
    # The same command again (in this process: the interrupted one was the separate process).
    capsys.readouterr()
    assert main(command[3:]) == 2 and "--resume" in capsys.readouterr().err     # refused, pointing at --resume
    assert main(command[3:] + ["--resume", "--minutes", "0.01"]) == 0
    assert f"resumed at step {stopped_at}" in capsys.readouterr().err


def test_opening_a_run_still_in_its_first_steps_says_it_is_being_trained(tmp_path, scene):
    """A run whose job holds its lock and has written neither a checkpoint nor model.ply yet (a
    user opening a `train` still running) is named as being trained, by whom, and when there will
    be something to open; once the job is gone the plain line stays (a stale .lock file is not a
    writer)."""
    from inceptiongs.runs.config import TrainConfig
    from inceptiongs.runs.load import load_run

    run = tmp_path / "run"
    with run_folder_lock(run):
        TrainConfig(scene=str(scene), downscale=4).save(run / "config.json")
        with pytest.raises(InputError, match=rf"still being trained by pid {os.getpid()} and no checkpoint written "
                                             r"yet \(one every 500 steps, model.ply at the end\)"):
            load_run(run)
    (run / LOCK_INFO_FILE).write_text("12345\n")   # what a killed job leaves
    with pytest.raises(InputError, match="run has neither model.ply nor a checkpoint"):
        load_run(run)
