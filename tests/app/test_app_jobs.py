"""The viewer's jobs: each writes a folder of its own, Resume continues the open run, the
schedule is sized as the command line sizes it; the real app under Xvfb on the demo scene."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from inceptiongs.app.job_requests import bootstrap_job_for, resume_job_for, train_job_for
from inceptiongs.app.job_settings import VIEWER_EVAL_EVERY, JobSettings
from inceptiongs.app.jobs import Jobs
from inceptiongs.app.navigation import nearest_camera_index
from inceptiongs.app.pacing import wait_for_next_frame
from inceptiongs.app.runs import fresh_folder, new_bootstrap_dir, new_train_dir
from inceptiongs.app.settings import StatusLine
from inceptiongs.io.config_json import with_values
from inceptiongs.runs.config import FreeSpace, Output, TrainConfig
from inceptiongs.errors import InputError
from viewer_cases import opened, start_job


def test_fresh_folder_never_returns_an_existing_one(tmp_path):
    base = tmp_path / "runs" / "train"
    assert fresh_folder(base) == base
    base.mkdir(parents=True)
    assert fresh_folder(base) == tmp_path / "runs" / "train_2"
    (tmp_path / "runs" / "train_2").mkdir()
    (tmp_path / "runs" / "train_3").write_text("a file counts too")
    assert fresh_folder(base) == tmp_path / "runs" / "train_4"
    (tmp_path / "runs" / "scene").mkdir()  # a run of the scene at tmp_path/scene in the chosen runs folder
    assert new_train_dir(tmp_path / "scene", tmp_path / "runs") == tmp_path / "runs" / "scene_2"
    run = tmp_path / "runs" / "train"
    assert new_bootstrap_dir(run) == tmp_path / "runs" / "train_bootstrap"
    (tmp_path / "runs" / "train_bootstrap").mkdir()
    assert new_bootstrap_dir(run) == tmp_path / "runs" / "train_bootstrap_2"


def test_job_settings_size_the_schedule_as_the_command_line(tmp_path):
    from inceptiongs.commands.train import build_config

    settings = JobSettings(minutes=2.0, iterations=800, downscale=3, protocol="llff", strategy="mcmc")
    ours = settings.train_config(tmp_path)
    args = argparse.Namespace(scene=str(tmp_path), config=None, iterations=800, minutes=2.0, downscale=3,
                              protocol="llff", seed=0, strategy="mcmc", exclude_photos=None, device="auto")
    cli = build_config(args)
    # The same schedule as the command line; only evaluated more often, so the panel's curve has points.
    assert ours == with_values(cli, {"output.eval_every": VIEWER_EVAL_EVERY,
                                     "output.log_every": ours.output.log_every})
    assert ours.output.eval_every % ours.output.log_every == 0  # the trainer evaluates on logged steps only
    assert ours.densification.densify_until < 15_000 and ours.minutes == 2.0
    boot = JobSettings(bootstrap_minutes=1.5, bootstrap_iterations=40, k=2, l=3, prior_minutes=0.5).bootstrap_config()
    assert (boot.minutes, boot.iterations, boot.k, boot.l, boot.prior_minutes) == (1.5, 40, 2, 3, 0.5)
    assert JobSettings().bootstrap_config().k is None  # 0 in the dialog: the bootstrap's own default
    assert JobSettings().bootstrap_config().follow_outlook                 # as `inceptiongs bootstrap`
    assert not JobSettings(follow_outlook=False).bootstrap_config().follow_outlook
    with pytest.raises(InputError):
        JobSettings(downscale=0).train_config(tmp_path)


def test_job_settings_size_the_schedule_to_the_budget_by_default(tmp_path):
    """0 in "schedule iterations" is `inceptiongs train --minutes M` (sized, re-sized by the
    trainer); a typed length is `--iterations N` (fixed); no budget and 0: the default length."""
    from inceptiongs.commands.train import build_config
    from inceptiongs.runs.config import BUDGET_STEPS_PER_MINUTE_GUESS, TrainConfig

    def cli(minutes, iterations):
        return build_config(argparse.Namespace(scene=str(tmp_path), config=None, iterations=iterations,
                                               minutes=minutes, downscale=2, protocol="unstructured", seed=0,
                                               strategy="default", exclude_photos=None, device="auto"))

    def viewer(**fields):
        config = JobSettings(**fields).train_config(tmp_path)
        assert config.output.eval_every == VIEWER_EVAL_EVERY
        return dataclasses.replace(config, output=Output())

    sized = viewer(minutes=2.5)
    assert JobSettings().iterations == 0 and JobSettings().minutes is not None  # sized by default
    assert sized == cli(2.5, None)
    assert sized.size_to_minutes and sized.iterations == round(BUDGET_STEPS_PER_MINUTE_GUESS * 2.5)
    fixed = viewer(minutes=None, iterations=700)
    assert fixed == cli(None, 700) and not fixed.size_to_minutes and fixed.iterations == 700
    # A typed length with a budget stays fixed: the budget only stops it (as the viewer always did).
    capped = JobSettings(minutes=2.5, iterations=700).train_config(tmp_path)
    assert (capped.iterations, capped.minutes, capped.size_to_minutes) == (700, 2.5, False)
    unbounded = viewer(minutes=None)
    assert unbounded == cli(None, None) and unbounded.iterations == TrainConfig().iterations
    assert not unbounded.size_to_minutes


def test_plan_follows_the_stored_schedule_and_survives_bad_files(tmp_path):
    """The panel's end iteration follows RUN/config.json (re-read on change only); a missing,
    half-written or odd file keeps the plan it had."""
    from inceptiongs.app.live_training import LiveTraining
    from inceptiongs.app.progress import JobPlan, followed_plan, planned_iterations

    config = tmp_path / "config.json"
    assert planned_iterations(config) is None
    for text in ('{"iterations": 12', "[1, 2]", '{"iterations": "40"}', '{"iterations": 0}', '{"iterations": true}'):
        config.write_text(text)
        assert planned_iterations(config) is None, text
    config.write_text('{"iterations": 345, "minutes": 0.5}')
    assert planned_iterations(config) == 345
    plan = JobPlan(100, 140, 30.0, None, "training", config)
    assert followed_plan(plan, None) is plan and followed_plan(plan, 50) is plan  # unknown / before the start
    assert followed_plan(plan, 345).end_iteration == 345 and followed_plan(plan, 345).steps == 245

    config.unlink()
    run = LiveTraining(SimpleNamespace(), plan=plan)
    run.refresh_plan()
    assert run.plan.end_iteration == 140  # not written yet
    config.write_text('{"iterations": 2')  # half-written
    run.refresh_plan()
    assert run.plan.end_iteration == 140
    config.write_text('{"iterations": 260}')
    run.refresh_plan()
    assert run.plan.end_iteration == 260
    fixed = LiveTraining(SimpleNamespace(), plan=dataclasses.replace(plan, config=None))
    fixed.refresh_plan()
    assert fixed.plan.end_iteration == 140  # a fixed schedule never follows the file


def test_jobs_write_fresh_folders(tmp_path):
    from inceptiongs.io.flags import Flag, save_flags
    from inceptiongs.camera import Camera
    from inceptiongs.train.job import TrainJob

    run = tmp_path / "runs" / "train"
    run.mkdir(parents=True)
    (run / "config.json").write_text("{}")
    source = SimpleNamespace(kind="scene", path=tmp_path, scene=SimpleNamespace(root=tmp_path), work_dir=tmp_path,
                             run_dir=run, runs_dir=tmp_path / "runs")
    (tmp_path / "runs" / tmp_path.name).mkdir()
    job = train_job_for(source, JobSettings(iterations=100))
    assert isinstance(job, TrainJob) and job.run_dir == tmp_path / "runs" / f"{tmp_path.name}_2" and not job.resume
    flags_file = tmp_path / "flags.json"
    status = StatusLine()
    jobs = Jobs(SimpleNamespace(source=source), SimpleNamespace(file=flags_file, items=[]), status, lambda: None)
    assert jobs.run_dir == run
    jobs.start_bootstrap()
    assert jobs.training is None and "no flagged views" in status.text
    save_flags(flags_file, [Flag("flag 1", Camera("c", 64, 48, 50.0, 50.0, 32.0, 24.0, np.eye(4)), "")])
    (tmp_path / "runs" / "train_bootstrap").mkdir()
    job = bootstrap_job_for(run, flags_file)
    assert job.run_dir == run and job.targets_file == flags_file
    assert job.out_dir == tmp_path / "runs" / "train_bootstrap_2"
    with pytest.raises(InputError, match="trained run"):
        bootstrap_job_for(None, flags_file)
    bare = SimpleNamespace(kind="ply", path=tmp_path / "m.ply", scene=None, work_dir=tmp_path, run_dir=None)
    with pytest.raises(InputError, match="no scene"):
        train_job_for(bare)


# --- the real app ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory) -> Path:
    from demo_cases import copy_of_demo_scene

    return copy_of_demo_scene(tmp_path_factory.mktemp("viewer_jobs") / "scene")


def _wait(viewer, condition, seconds=120.0) -> None:
    deadline = time.time() + seconds
    while not condition() and time.time() < deadline:
        wait_for_next_frame(viewer)  # as run() does: the job gets the CPU between frames
        viewer.step()
    assert condition(), viewer.status


@pytest.mark.gl
def test_train_twice_then_resume_never_overwrites(xvfb, demo_scene):
    import glfw

    from viewer_cases import click_widget

    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.runs.checkpoint import latest_checkpoint, list_checkpoints

    with opened(Viewer, open_source(demo_scene), 900, 1000) as viewer:
        # Where `inceptiongs train SCENE` writes: ./runs/NAME in the current folder, not the scene.
        runs, name = Path.cwd() / "runs", demo_scene.name
        assert demo_scene not in runs.parents
        assert "sparse points" in viewer.title
        # A long schedule, stopped early: what a user does who trains "until it looks good".
        viewer.jobs.settings = JobSettings(minutes=None, iterations=2000, downscale=4, protocol="unstructured")
        viewer.jobs.start_training()
        assert viewer.jobs.out_dir == runs / name and str(runs / name) in viewer.title
        _wait(viewer, lambda: viewer.jobs.training.progress.iteration >= 10)
        viewer.jobs.training.stop()
        _wait(viewer, lambda: not viewer.jobs.training.alive)
        first = latest_checkpoint(runs / name)
        assert first is not None
        first_bytes = first.read_bytes()
        # A second "train" (its button, clicked) starts a new run beside the first, leaving it as it was.
        start_job(viewer, "train (new run)")
        assert viewer.jobs.out_dir == runs / f"{name}_2"
        assert f"{name}_2" in glfw.get_window_title(viewer.window)  # the real window's title
        _wait(viewer, lambda: viewer.jobs.training.progress.iteration >= 10)
        viewer.jobs.training.stop()
        _wait(viewer, lambda: not viewer.jobs.training.alive)
        assert first.read_bytes() == first_bytes
        stopped_at = list_checkpoints(runs / f"{name}_2")[-1][0]
        # Resume continues the open run (train_2) from its newest checkpoint, in the same folder.
        assert viewer.jobs.run_dir == runs / f"{name}_2"
        start_job(viewer, "resume")
        job = viewer.jobs.training.job
        assert job.resume and job.run_dir == runs / f"{name}_2"
        seen = []
        _wait(viewer, lambda: (seen.append(viewer.jobs.training.progress.iteration) or True)
              and viewer.jobs.training.progress.iteration > stopped_at)
        viewer.jobs.training.stop()
        _wait(viewer, lambda: not viewer.jobs.training.alive)
        assert viewer.jobs.training.error is None, viewer.jobs.training.error
        # A fresh run would show iteration 10 first; the resumed one starts past its checkpoint.
        assert min(i for i in seen if i > 0) > stopped_at
        assert sorted(p.name for p in runs.iterdir()) == [name, f"{name}_2"]
        viewer.step()
        assert "stopped" in viewer.title


@pytest.mark.gl
@pytest.mark.slow
def test_progress_shows_totals_psnr_curve_and_the_closing_line(xvfb, demo_scene, tmp_path):
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.io.images import write_png
    from viewer_cases import click_widget

    with opened(Viewer, open_source(demo_scene), 1200, 1000) as viewer:
        viewer.jobs.settings = JobSettings(minutes=None, iterations=70, downscale=4, protocol="unstructured")
        start_job(viewer, "train (new run)")
        plan = viewer.jobs.training.plan
        assert (plan.start_iteration, plan.end_iteration, plan.budget_s) == (0, 70, None)
        _wait(viewer, lambda: viewer.jobs.training.progress.iteration >= 30)
        assert viewer.jobs.training.elapsed_s > 0 and viewer.jobs.training.progress.iterations_per_second > 0
        _wait(viewer, lambda: not viewer.jobs.training.alive, 300)
        viewer.step()
        assert viewer.jobs.training.error is None, viewer.jobs.training.error
        psnr = viewer.jobs.training.progress.psnr
        assert psnr and all(len(iterations) >= 3 for iterations, _ in psnr.values())  # 0, 50, 70
        # The closing line replaced "training into ...": time, iteration and the final scores.
        assert viewer.status.startswith("training finished in ") and "at iteration 70" in viewer.status
        last = next(iter(psnr.values()))[1][-1]
        assert f"{last:.2f} dB" in viewer.status
        image = viewer.capture_window()
        write_png(tmp_path / "progress.png", image)
        # The plots' axes follow the data: every point lies inside the drawn ranges, and the
        # x range spans the run rather than sitting at its first point.
        limits = viewer.jobs.training.progress.plot_limits
        (x0, x1), (y0, y1) = limits["held-out PSNR"]
        for iterations, values in psnr.values():
            assert x0 <= min(iterations) and max(iterations) <= x1
            assert y0 <= min(values) and max(values) <= y1
        assert x1 - x0 >= 60
        (x0, x1), _ = limits["training loss"]
        assert x1 - x0 >= 40


@pytest.mark.gl
@pytest.mark.slow
def test_viewer_job_sized_to_its_budget_ends_decayed(xvfb, demo_scene, monkeypatch):
    """A viewer job with a budget and the default "schedule iterations" (0): the trainer re-sizes
    the schedule from its measured rate and re-saves config.json; the panel's plan follows it,
    and the run ends at the re-sized schedule's end (learning rate decayed), not a fraction of a
    fixed one. The first guess is made far too high (100 steps a second, no CPU here trains
    that fast), so the re-size happens on any machine: the case the viewer's old fixed
    5000-step schedule was, stopping at a few percent of it."""
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.runs.config import TrainConfig
    from inceptiongs.runs.checkpoint import list_checkpoints
    from inceptiongs.train.budget import BUDGET_FREEZE
    from viewer_cases import click_widget

    minutes = 0.1
    monkeypatch.setattr("inceptiongs.runs.config.BUDGET_STEPS_PER_MINUTE_GUESS", 6000)
    with opened(Viewer, open_source(demo_scene), 1100, 1000) as viewer:
        viewer.jobs.settings = JobSettings(minutes=minutes, downscale=4, protocol="unstructured")
        start_job(viewer, "train (new run)")
        job = viewer.jobs.training.job
        guess = job.config.iterations
        assert job.config.size_to_minutes and guess == round(6000 * minutes)
        assert viewer.jobs.training.plan.end_iteration == guess
        _wait(viewer, lambda: not viewer.jobs.training.alive, 180)
        viewer.step()
        assert viewer.jobs.training.error is None, viewer.jobs.training.error
        stored = TrainConfig.load(job.run_dir / "config.json")
        assert stored.iterations < guess / 2  # re-sized to the measured rate
        assert viewer.jobs.training.plan.end_iteration == stored.iterations
        # The milestones were re-sized with it (densification ends inside the run).
        assert stored.densification.densify_until < stored.iterations
        last = list_checkpoints(job.run_dir)[-1][0]
        assert last == viewer.jobs.training.progress.iteration
        # Decayed: the schedule's end, or (rate fell late in the run) within the frozen slack.
        assert last >= (1.0 - BUDGET_FREEZE) * stored.iterations, (last, stored.iterations)
        assert f"at iteration {last}" in viewer.status


@pytest.mark.gl
def test_scene_folder_opens_its_newest_model(xvfb, demo_scene):
    """A PLY saved in the work folder after the runs is what the scene opens next (and says so)."""
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer

    source = open_source(demo_scene)
    if source.run_dir is None:
        pytest.skip("needs the runs of test_train_twice_then_resume_never_overwrites (same module)")
    with opened(Viewer, source, 320, 240) as viewer:
        viewer.view.edit.select(np.arange(viewer.view.edit.count) % 2 == 0)
        viewer.editor.delete_selection()
        shown = viewer.view.edit.visible_arrays()["means"]
        saved = viewer.editor.saving.save_ply(source.work_dir / "edited.ply")
    with opened(Viewer, open_source(demo_scene), 320, 240) as reopened:
        assert reopened.view.source.model_path == saved and "edited.ply" in reopened.title
        assert reopened.jobs.run_dir is None and "edited.ply" in reopened.status
        np.testing.assert_allclose(reopened.view.edit.base["means"], shown, atol=1e-5)  # back in the shown frame
    time.sleep(0.05)
    # A run written to after the PLY is the newest again.
    (Path.cwd() / "runs" / f"{demo_scene.name}_2" / "notes.txt").write_text("newer than edited.ply")
    assert open_source(demo_scene).run_dir == Path.cwd() / "runs" / f"{demo_scene.name}_2"


@pytest.mark.gl
def test_scene_folder_finds_the_command_lines_runs(xvfb, demo_scene, tmp_path, monkeypatch):
    """`inceptiongs train SCENE` (no --out) writes ./runs/NAME in the current folder; the viewer
    opened on SCENE from that folder lists it with the viewer's own runs and, the newest, opens it."""
    import json

    from inceptiongs.app.sources import open_source
    from inceptiongs.cli import main
    from inceptiongs.app.viewer import Viewer

    from inceptiongs.app.runs import fresh_folder
    from inceptiongs.train.trainer import train

    # A run the viewer once kept in the scene's work folder (the cache), then the command line's, newer.
    work_dir = open_source(demo_scene).work_dir
    train(JobSettings(minutes=None, iterations=5, downscale=4).train_config(demo_scene),
          fresh_folder(work_dir / "runs" / "train"), progress=False)
    monkeypatch.chdir(tmp_path)
    assert main(["train", str(demo_scene), "--iterations", "10", "--downscale", "4", "--protocol", "unstructured"]) == 0
    cli_run = tmp_path / "runs" / demo_scene.name
    assert (cli_run / "model.ply").is_file()
    # A run of another scene whose folder name starts the same is not this scene's.
    stranger = tmp_path / "runs" / f"{demo_scene.name}_other"
    (stranger / "checkpoints").mkdir(parents=True)
    (stranger / "config.json").write_text(json.dumps({"scene": str(tmp_path / "elsewhere")}))
    with opened(Viewer, open_source(demo_scene), 640, 480) as viewer:
        runs = viewer.view.source.runs
        assert cli_run in runs and stranger not in runs
        assert any(work_dir in run.parents for run in runs), "the viewer's own runs are listed too"
        assert runs[-1] == cli_run and viewer.jobs.run_dir == cli_run  # the newest is the one opened
        assert str(cli_run) in viewer.title and str(cli_run) in viewer.status
        shown = viewer.view.edit.base["means"].copy()
        older = runs[0]
        viewer.jobs.open_run(older)  # what the panel's "runs of this scene" list does
        assert viewer.jobs.run_dir == older and str(older) in viewer.title
        means = viewer.view.edit.base["means"]
        assert means.shape != shown.shape or not np.allclose(means, shown)
        viewer.step()
        assert "runs of this scene" in viewer.ui.rects  # the list is in the Training panel
    monkeypatch.chdir(demo_scene.parent)  # from elsewhere, the command line's ./runs is not looked at
    assert cli_run not in open_source(demo_scene).runs


@pytest.mark.gl
def test_nearest_training_photo_blended_and_beside(xvfb, demo_scene):
    import cv2

    from inceptiongs.app.images import PHOTO_INSET_FRACTION
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer

    with opened(Viewer, open_source(demo_scene), 384, 288, with_ui=False) as viewer:
        viewer.view.settings.show_training_cameras = False
        viewer.view.snap_to_camera(3)
        time.sleep(0.2)  # still: the full-resolution frames follow
        viewer.step()
        photo = viewer.view.source.scene.load_image(3)
        assert nearest_camera_index(viewer.view.cameras, viewer.view.current_camera()) == 3
        render = viewer.capture_window()
        viewer.view.settings.photo, viewer.view.settings.photo_alpha = "blended", 1.0
        blended = viewer.capture_window()
        expected = cv2.resize(photo, (384, 288), interpolation=cv2.INTER_AREA)
        assert np.abs(blended - expected).mean() < 0.02           # the photo itself at weight 1
        assert np.abs(render - expected).mean() > np.abs(blended - expected).mean()
        viewer.view.settings.photo = "beside"
        beside = viewer.capture_window()
        inset_w = int(384 * PHOTO_INSET_FRACTION)
        inset_h = int(round(inset_w * photo.shape[0] / photo.shape[1]))
        inset = cv2.resize(photo, (inset_w, inset_h), interpolation=cv2.INTER_AREA)
        assert np.abs(beside[-inset_h:, -inset_w:] - inset).mean() < 0.02  # the photo in the corner
        np.testing.assert_allclose(beside[:100, :150], render[:100, :150], atol=2 / 255)  # the render elsewhere


@pytest.mark.gl
def test_typed_job_settings_reach_the_jobs(xvfb, demo_scene):
    """A user opens "job settings", clicks into its fields and types (key and char events as GLFW
    delivers them, through imgui's GLFW backend), then presses the buttons: the started jobs and
    their folders' config.json carry what was typed, not the dialog's defaults."""
    import glfw

    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.runs.config import TrainConfig
    from viewer_cases import click_widget, press_key, type_into

    with opened(Viewer, open_source(demo_scene), 1100, 1000) as viewer:
        defaults = JobSettings()
        typed = {"time budget min": "1.5", "schedule iterations": "700", "downscale": "3"}
        assert (defaults.minutes, defaults.iterations, defaults.downscale) != (1.5, 700, 3)
        viewer.step()
        click_widget(viewer, "View")  # closed: the Training panel's dialog and buttons fit the window
        click_widget(viewer, "job settings")  # open the dialog (a tree node, closed at first)
        for label, text in typed.items():
            type_into(viewer, label, text)
        assert (viewer.jobs.settings.minutes, viewer.jobs.settings.iterations, viewer.jobs.settings.downscale) == (
            1.5, 700, 3)
        click_widget(viewer, "sky shell")  # the checkbox flips the command line's default
        sky = not FreeSpace.sky_shell
        assert viewer.jobs.settings.sky_shell is sky
        start_job(viewer, "train (new run)")
        job = viewer.jobs.training.job
        assert (job.config.minutes, job.config.iterations, job.config.downscale, job.config.free_space.sky_shell) == (
            1.5, 700, 3, sky)
        _wait(viewer, lambda: (job.run_dir / "config.json").is_file() and viewer.jobs.training.progress.iteration >= 10)
        stored = TrainConfig.load(job.run_dir / "config.json")
        assert (stored.minutes, stored.iterations, stored.downscale, stored.free_space.sky_shell) == (1.5, 700, 3, sky)
        click_widget(viewer, "stop")
        _wait(viewer, lambda: not viewer.jobs.training.alive)
        assert viewer.jobs.training.error is None, viewer.jobs.training.error
        # The bootstrap's part of the dialog, then "Bootstrap flagged views" on the run just made.
        press_key(viewer, glfw.KEY_F)  # flag the current view
        assert viewer.flags.items, viewer.status
        viewer.ui.rects.clear()
        viewer.step()
        assert "refinement steps" not in viewer.ui.rects  # the dialog closed when the job started
        click_widget(viewer, "job settings")  # ... and the user opens it again
        boot = {"bootstrap budget min": "0.5", "refinement steps": "25", "K nearest views (0: default)": "2",
                "L poses each (0: default)": "3", "prior min (if none)": "0.7"}
        for label, text in boot.items():
            type_into(viewer, label, text)
        click_widget(viewer, "follow the outlook")      # virtual views from the first step, whatever it says
        assert viewer.jobs.settings.follow_outlook is False
        start_job(viewer, "Bootstrap flagged views")
        assert viewer.jobs.training is not None and viewer.jobs.training.job is not job, viewer.status
        config = viewer.jobs.training.job.config
        expected = (0.5, 25, 2, 3, 0.7, False)
        assert (config.minutes, config.iterations, config.k, config.l, config.prior_minutes,
                config.follow_outlook) == expected
        stored_file = viewer.jobs.training.job.out_dir / "bootstrap" / "config.json"
        _wait(viewer, stored_file.is_file)
        stored = BootstrapConfig.load(stored_file)
        assert (stored.minutes, stored.iterations, stored.k, stored.l, stored.prior_minutes,
                stored.follow_outlook) == expected
        viewer.jobs.training.stop()


@pytest.mark.gl
def test_resume_is_greyed_out_on_a_bootstrap_result_and_says_why(xvfb, demo_scene, tmp_path):
    """A bootstrap's result holds a stage-I config and checkpoints, so "resume" there would go on
    with stage-I training on the repaired model. Its button is shown disabled with the reason;
    clicked, nothing starts. The same click on the stage-I run it came from does resume."""
    import shutil

    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.runs.checkpoint import list_checkpoints
    from inceptiongs.train.trainer import train
    from viewer_cases import click_widget

    run = tmp_path / "run"
    config = dataclasses.replace(JobSettings(minutes=None, iterations=4, downscale=4).train_config(demo_scene),
                                 output=Output(checkpoint_every=2, log_every=2, eval_every=2))
    train(config, run, progress=False)
    assert list_checkpoints(run)
    # A bootstrap's result as run_bootstrap writes it: the run's files plus bootstrap/config.json.
    boot = tmp_path / "run_bootstrap"
    shutil.copytree(run, boot)
    (boot / "bootstrap").mkdir()
    BootstrapConfig().save(boot / "bootstrap" / "config.json")
    before = sorted(p.name for p in (boot / "checkpoints").iterdir())
    with opened(Viewer, open_source(boot), 900, 1000) as viewer:
        assert viewer.jobs.run_dir == boot
        viewer.step()
        assert "resume" in viewer.ui.rects and "why no resume" in viewer.ui.rects
        click_widget(viewer, "resume")
        for _ in range(3):
            viewer.step()
        assert viewer.jobs.training is None, "resume must not start stage-I training on a bootstrap result"
        assert sorted(p.name for p in (boot / "checkpoints").iterdir()) == before
        viewer.jobs.resume_training()  # the action itself refuses too, in the status line
        assert viewer.jobs.training is None and "bootstrap" in viewer.status
        with pytest.raises(InputError, match="bootstrap"):
            resume_job_for(boot)
    with opened(Viewer, open_source(run), 900, 1000) as viewer:
        viewer.step()
        assert "why no resume" not in viewer.ui.rects
        start_job(viewer, "resume")
        assert viewer.jobs.training is not None and viewer.jobs.training.job.resume, viewer.status
        viewer.jobs.training.stop()


@pytest.mark.gl
def test_poorly_fit_photos_are_drawn_apart_and_stepped_through(xvfb, demo_scene, tmp_path):
    """A run's view_fit.json names the training photos it fits poorly: the viewer opened on the
    run draws their frustums orange and the Training panel's button stands at each, worst first.
    (Which photos the trainer reports is tested in tests/train/test_train_view_fit.py; here two
    of a real report's views are marked by hand.)"""
    import json

    from inceptiongs.app.drawing import POORLY_FIT_COLOR, TRAINING_COLOR, frustum_colors
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.train.trainer import train
    from inceptiongs.train.view_fit import VIEW_FIT_FILE
    from viewer_cases import click_widget

    run = tmp_path / "run"
    train(JobSettings(minutes=None, iterations=6, downscale=4).train_config(demo_scene), run, progress=False)
    report = json.loads((run / VIEW_FIT_FILE).read_text())  # the finished run wrote it
    assert len(report["views"]) >= 2
    first, second = report["views"][0], report["views"][1]
    first.update(psnr=9.0, poorly_fit=True)
    second.update(psnr=7.0, poorly_fit=True)
    (run / VIEW_FIT_FILE).write_text(json.dumps(report))
    with opened(Viewer, open_source(run), 900, 1000) as viewer:
        assert list(viewer.jobs.poorly_fit.psnr) == [second["name"], first["name"]]  # worst first
        colors = frustum_colors(viewer.view.cameras, viewer.jobs.poorly_fit.psnr)
        for index, camera in enumerate(viewer.view.cameras):
            expected = POORLY_FIT_COLOR if camera.name in (first["name"], second["name"]) else TRAINING_COLOR
            assert np.allclose(colors[8 * index:8 * index + 8], expected), camera.name
        viewer.step()
        assert "poorly fit photos" in viewer.ui.rects
        assert viewer.ui.texts["poorly fit photos"] == "2 training photos fit poorly (orange frustums)"
        click_widget(viewer, "next poorly fit photo")
        assert viewer.view.cameras[viewer.view.camera_index].name == second["name"]
        assert second["name"] in viewer.status and "7.0 dB" in viewer.status
        view = viewer.view
        np.testing.assert_allclose(view.nav.center, view.cameras[view.camera_index].center, atol=1e-9)
        click_widget(viewer, "next poorly fit photo")
        assert viewer.view.cameras[viewer.view.camera_index].name == first["name"]
        click_widget(viewer, "next poorly fit photo")  # around again
        assert viewer.view.cameras[viewer.view.camera_index].name == second["name"]
        # The next run from the panel can leave them out (train --exclude-photos).
        assert viewer.jobs.settings.exclude_photos == []
        click_widget(viewer, "leave them out of the next run")
        assert viewer.jobs.settings.exclude_photos == [second["name"], first["name"]]
        assert viewer.jobs.settings.train_config(demo_scene).exclude_photos == [second["name"], first["name"]]
        click_widget(viewer, "leave them out of the next run")
        assert viewer.jobs.settings.exclude_photos == []
    # One photo is "a photo", in the singular ("1 training photos" read wrong).
    second.update(poorly_fit=False)
    (run / VIEW_FIT_FILE).write_text(json.dumps(report))
    with opened(Viewer, open_source(run), 900, 1000) as viewer:
        viewer.step()
        assert viewer.ui.texts["poorly fit photos"] == "1 training photo fits poorly (orange frustum)"
    # A report that is not one: the viewer still opens, says which file, shows none.
    (run / VIEW_FIT_FILE).write_text("{not json")
    with opened(Viewer, open_source(run), 640, 480) as viewer:
        assert viewer.jobs.poorly_fit.psnr == {} and str(run / VIEW_FIT_FILE) in viewer.status
        viewer.step()
        assert "next poorly fit photo" not in viewer.ui.rects
