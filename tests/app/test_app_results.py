"""A user's results under the real window (Xvfb, events as GLFW delivers them): jobs write where
the command line writes, the scene lists its runs from every place with their scores, closing
with a job alive loses nothing, a resume keeps its own plan and says it, a bare PLY offers only
what it can do."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import glfw
import numpy as np
import pytest

from inceptiongs.app.job_settings import JobSettings
from inceptiongs.app.pacing import wait_for_next_frame
from inceptiongs.errors import InputError
from inceptiongs.io.config_json import with_values
from viewer_cases import click_widget, opened, press_key, start_job, type_into


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory) -> Path:
    from demo_cases import copy_of_demo_scene

    return copy_of_demo_scene(tmp_path_factory.mktemp("viewer_results") / "scene")


def _viewer(scene, width=1000, height=1000, **kwargs):
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer

    return Viewer(open_source(scene, kwargs.pop("runs_dir", None)), width, height, **kwargs)


def _wait(viewer, condition, seconds=120.0) -> None:
    deadline = time.time() + seconds
    while not condition() and time.time() < deadline:
        wait_for_next_frame(viewer)
        viewer.step()
    assert condition(), viewer.status


def _stopped_run(scene: Path, run: Path, stop_at: int, minutes: float | None = None, iterations: int = 40) -> Path:
    """A stage-I run of ``scene`` stopped after ``stop_at`` steps (model.ply and a checkpoint)."""
    from inceptiongs.live import JobControl
    from inceptiongs.train.trainer import train

    config = with_values(JobSettings(minutes=None, iterations=iterations, downscale=4).train_config(scene),
                         {"minutes": minutes, "output.checkpoint_every": 2, "output.log_every": 2,
                          "output.eval_every": 2})
    control = JobControl()
    train(config, run, progress=False, control=control,
          after_step=lambda step, _g, _c: control.stop.set() if step >= stop_at else None)
    return run


# --- 1. one visible home for a user's results ------------------------------------------------------

@pytest.mark.gl
def test_jobs_and_saves_go_where_the_command_line_writes(xvfb, demo_scene, tmp_path, monkeypatch):
    """"train (new run)" writes ./runs/NAME in the current folder (runs.folder.default_run_dir,
    as `inceptiongs train SCENE`), never the cache; F12 and "save PLY" default to ./runs/NAME_saved;
    a runs folder typed into the panel takes the next run."""
    import glfw

    from inceptiongs.runs.folder import default_run_dir

    monkeypatch.chdir(tmp_path)
    with opened(_viewer, demo_scene) as viewer:
        cache = viewer.view.source.work_dir
        viewer.jobs.settings = JobSettings(minutes=None, iterations=2000, downscale=4)
        start_job(viewer, "train (new run)")
        run = viewer.jobs.out_dir
        assert run == default_run_dir(demo_scene) == tmp_path / "runs" / demo_scene.name
        assert cache not in run.parents
        _wait(viewer, lambda: viewer.jobs.training.progress.iteration >= 3)
        click_widget(viewer, "stop")
        _wait(viewer, lambda: not viewer.jobs.training.alive)
        assert (run / "model.ply").is_file()
        press_key(viewer, glfw.KEY_F12)
        shots = list((tmp_path / "runs" / f"{demo_scene.name}_saved").glob("view-*.png"))
        assert len(shots) == 1 and str(shots[0]) in viewer.status
        assert Path(viewer.editor.saving.path).parent == tmp_path / "runs" / f"{demo_scene.name}_saved"
        # The panel says where the next run goes, in full; a folder typed there takes it.
        viewer.step()
        assert "new run goes to" in viewer.ui.rects
        picked = tmp_path / "picked"
        type_into(viewer, "runs folder", str(picked))
        start_job(viewer, "train (new run)")
        assert viewer.jobs.out_dir == picked / demo_scene.name
        viewer.jobs.training.stop()
    assert not (cache / "runs").exists() or not any((cache / "runs").iterdir())


@pytest.mark.gl
def test_scene_lists_its_runs_from_every_place_newest_first_with_scores(xvfb, demo_scene, tmp_path, monkeypatch):
    """A run written with `--out ELSEWHERE/anything` is listed when the viewer is given
    `--runs ELSEWHERE`, beside ./runs/NAME's; newest first, each with its held-out scores; picking
    one from the list (mouse clicks) opens it."""
    from inceptiongs.app.main import main
    from viewer_cases import choose

    monkeypatch.chdir(tmp_path)
    older = _stopped_run(demo_scene, tmp_path / "runs" / demo_scene.name, stop_at=4)
    time.sleep(0.05)
    newer = _stopped_run(demo_scene, tmp_path / "elsewhere" / "my run", stop_at=4)
    with opened(_viewer, demo_scene, runs_dir=tmp_path / "elsewhere") as viewer:
        assert set(viewer.view.source.runs) >= {older, newer}
        assert viewer.jobs.run_dir == newer  # the newest opens
        viewer.step()
        labels = [viewer.jobs.run_labels.label(run) for run in reversed(viewer.view.source.runs)]
        assert labels[0].endswith(str(newer)) and " dB" in labels[0]  # newest first, in full, scored
        choose(viewer, "runs of this scene", viewer.jobs.run_labels.label(older))
        assert viewer.jobs.run_dir == older, viewer.status
    assert main([str(demo_scene), "--runs", str(older / "model.ply")]) == 2  # a file is no runs folder


def test_runs_beside_the_scene_folder_are_its_runs_too(tmp_path, monkeypatch):
    """`inceptiongs demo OUT` writes OUT/scene beside OUT/run and OUT/run_bootstrap: opening
    OUT/scene lists them (it said "no trained model yet"); a sibling run of another scene is not."""
    import json
    from types import SimpleNamespace

    from inceptiongs.app.sources import scene_runs

    monkeypatch.chdir(tmp_path)
    scene_root = tmp_path / "demo" / "scene"
    scene_root.mkdir(parents=True)
    for name, scene in (("run", scene_root), ("run_bootstrap", scene_root), ("other", tmp_path / "elsewhere")):
        run = tmp_path / "demo" / name
        run.mkdir()
        (run / "config.json").write_text(json.dumps({"scene": str(scene)}))
        (run / "model.ply").write_bytes(b"ply\n")
    runs = scene_runs(SimpleNamespace(root=scene_root, work_dir=tmp_path / "cache"))
    assert {run.name for run in runs} == {"run", "run_bootstrap"}


@pytest.mark.gl
def test_flags_are_kept_beside_the_runs_and_the_bootstrap_finds_them(xvfb, demo_scene, tmp_path, monkeypatch):
    """A user's flags are their work, not a cache: they go to ./runs/NAME_saved/flags.json (flags an
    older viewer kept in the cache are read there once), and `inceptiongs bootstrap` looks there."""
    from inceptiongs.app.flags import flag_camera
    from inceptiongs.bootstrap.runner import default_flag_files
    from inceptiongs.io import flags as flag_io
    from inceptiongs.scene.loader import load_scene

    monkeypatch.chdir(tmp_path)
    scene = load_scene(demo_scene)
    with opened(_viewer, demo_scene) as viewer:
        older = flag_io.flags_path(viewer.view.source.work_dir)
    visible = tmp_path / "runs" / f"{demo_scene.name}_saved" / "flags.json"
    older.parent.mkdir(parents=True, exist_ok=True)
    flag_io.save_flags(older, [flag_camera(scene.cameras[0], "from the cache")])
    with opened(_viewer, demo_scene) as viewer:
        assert [f.name for f in viewer.flags.items] == ["from the cache"] and viewer.flags.file == visible
        press_key(viewer, glfw.KEY_F)
    assert [f.name for f in flag_io.load_flags(visible)] == ["from the cache", "flag 1"]
    assert [f.name for f in flag_io.load_flags(older)] == ["from the cache"]        # the cache is left as it was
    assert default_flag_files(scene)[0].resolve() == visible.resolve()   # the command line's first place


# --- 4. no lost job ---------------------------------------------------------------------------------

@pytest.mark.gl
def test_closing_with_a_job_asks_and_stop_and_save_keeps_the_model(xvfb, demo_scene, tmp_path, monkeypatch):
    import glfw

    from inceptiongs.runs.checkpoint import latest_checkpoint

    monkeypatch.chdir(tmp_path)
    with opened(_viewer, demo_scene) as viewer:
        viewer.jobs.settings = JobSettings(minutes=None, iterations=3000, downscale=4)
        start_job(viewer, "train (new run)")
        run = viewer.jobs.out_dir
        _wait(viewer, lambda: viewer.jobs.training.progress.iteration >= 3)
        glfw.set_window_should_close(viewer.window, True)  # the window's close button
        assert viewer.run_frame()  # not closed: it asks
        viewer.step()
        assert "stop and save" in viewer.ui.rects and not viewer.should_close()
        click_widget(viewer, "cancel")
        assert viewer.closing.state == "open" and viewer.jobs.alive
        glfw.set_window_should_close(viewer.window, True)
        viewer.run_frame()
        click_widget(viewer, "stop and save")
        frames = 0
        while viewer.run_frame():
            frames += 1
            assert frames < 5000
        assert not viewer.jobs.alive and viewer.jobs.training.error is None
        assert (run / "model.ply").is_file() and latest_checkpoint(run) is not None


@pytest.mark.gl
def test_keep_running_hides_the_window_and_the_job_finishes(xvfb, demo_scene, tmp_path, monkeypatch, capsys):
    import glfw

    monkeypatch.chdir(tmp_path)
    with opened(_viewer, demo_scene) as viewer:
        viewer.jobs.settings = JobSettings(minutes=None, iterations=30, downscale=4)
        start_job(viewer, "train (new run)")
        run = viewer.jobs.out_dir
        glfw.set_window_should_close(viewer.window, True)
        assert viewer.run_frame()
        click_widget(viewer, "keep running in the background")
        assert not viewer.run_frame()
        assert not glfw.get_window_attrib(viewer.window, glfw.VISIBLE)
        lines = [line for line in capsys.readouterr().err.splitlines() if "background" in line]
        assert len(lines) == 1 and str(run) in lines[0]  # one line says where the results go
        from inceptiongs.app.closing import wait_in_background
        wait_in_background(viewer)
        assert viewer.jobs.training.state == "finished" and (run / "model.ply").is_file()
        ended = capsys.readouterr().err.strip().splitlines()[-1]
        # The hidden window polled no snapshot: the line still says the job's last iteration.
        assert ended.startswith("the job in the background ended:") and "at iteration 30;" in ended, ended


@pytest.mark.gl
def test_sigterm_on_the_viewer_stops_and_saves_the_job(xvfb, demo_scene, tmp_path, monkeypatch):
    import glfw

    from inceptiongs.runs.checkpoint import latest_checkpoint

    monkeypatch.chdir(tmp_path)
    viewer = _viewer(demo_scene)
    try:
        viewer.jobs.settings = JobSettings(minutes=None, iterations=3000, downscale=4)
        start_job(viewer, "train (new run)")
        run = viewer.jobs.out_dir
        _wait(viewer, lambda: viewer.jobs.training.progress.iteration >= 3)
        unhandled = []  # a viewer without its own handlers would leave the signal to this one
        previous = signal.signal(signal.SIGTERM, lambda *_: unhandled.append(True) or glfw.set_window_should_close(viewer.window, True))
        try:
            threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGTERM)).start()
            status = viewer.run()
        finally:
            signal.signal(signal.SIGTERM, previous)
        assert not unhandled and status == 128 + signal.SIGTERM
        assert viewer.jobs.training.state == "stopped"
        assert (run / "model.ply").is_file() and latest_checkpoint(run) is not None
    finally:
        if viewer.window is not None:
            viewer.close()


# --- 7. a resume keeps its plan and says it -------------------------------------------------------------

@pytest.mark.gl
def test_resume_keeps_the_runs_own_budget_and_the_bar_agrees(xvfb, demo_scene, tmp_path):
    from inceptiongs.runs.checkpoint import latest_checkpoint

    run = _stopped_run(demo_scene, tmp_path / "run", stop_at=4, minutes=0.5, iterations=40)
    stopped_at = int(latest_checkpoint(run).stem.split("_")[-1])
    with opened(_viewer, run) as viewer:
        assert viewer.jobs.settings.minutes != 0.5  # the dialog's budget is for new runs
        start_job(viewer, "resume")
        job = viewer.jobs.training.job
        assert (job.config.minutes, job.config.iterations) == (0.5, 40)
        plan = viewer.jobs.training.plan
        assert (plan.start_iteration, plan.end_iteration) == (stopped_at, 40)
        assert plan.budget_s < 30.0  # what the run's budget has left, not a new one
        assert f"at iteration {stopped_at} of 40 with its saved plan" in viewer.status
        _wait(viewer, lambda: viewer.jobs.training.progress.iteration > stopped_at)
        viewer.step()
        progress = viewer.jobs.training.progress
        assert progress.bar_text == f"iteration {progress.iteration} / 40"
        viewer.jobs.training.stop()


# --- 9. honest controls on a bare PLY ---------------------------------------------------------------

class _FailingJob:
    def run(self, box, control):
        raise InputError("broken.ply: not a Gaussian-splat PLY")


@pytest.mark.gl
def test_bare_ply_greys_out_what_needs_cameras_and_errors_are_one_line(xvfb, tmp_path):
    import glfw

    from viewer_cases import choose, write_grid_model

    model = write_grid_model(tmp_path / "grid.ply")
    with opened(_viewer, model, 900, 1000) as viewer:
        viewer.step()
        for key, mode in ((glfw.KEY_6, "coverage"), (glfw.KEY_5, "reference")):
            press_key(viewer, key)
            assert viewer.view.settings.mode == "rgb" and "no cameras" in viewer.status and mode in viewer.status
        choose(viewer, "mode (1-6)", "coverage")  # greyed in the list: the click does nothing
        assert viewer.view.settings.mode == "rgb"
        viewer.step()
        assert {"why modes are off", "why no training", "why no bootstrap"} <= set(viewer.ui.rects)
        start_job(viewer, "train (new run)")
        assert viewer.jobs.training is None
        viewer.jobs.start_training()  # the action itself answers with the command line's line
        assert "InputError" not in viewer.status and "no scene to train" in viewer.status
        viewer.flags.flag_current_view()
        start_job(viewer, "Bootstrap flagged views")
        assert viewer.jobs.training is None
    with opened(_viewer, model, 900, 1000, job_factory=lambda source: _FailingJob()) as viewer:
        viewer.jobs.start_training()
        _wait(viewer, lambda: not viewer.jobs.training.alive)
        viewer.step()
        assert viewer.jobs.training.error == "broken.ply: not a Gaussian-splat PLY"
        assert "InputError" not in viewer.status
