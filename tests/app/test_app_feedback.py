"""Feedback a user sees in the real window, driven with events as GLFW delivers them: the
notification area that stays in view and is never stale, the bootstrap's verdict in the
Training panel, plots that do not magnify noise, and the small things (Esc, Ctrl+Q, an opaque
help, figures that keep their units, paths shortened in the middle, a press over the panel
that never reaches the scene)."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import glfw
import numpy as np
import pytest

from viewer_cases import (click_at, click_widget, flag_a_view, open_edit_section, open_grid_viewer, opened, press_key,
                          scroll_panel_to, start_job, synthetic_gaussians, wait_for_job_end, write_grid_model)

pytestmark = pytest.mark.gl


def _frames(viewer, count: int = 3) -> None:
    for _ in range(count):
        viewer.step()


def _press(viewer, x: float, y: float, button=glfw.MOUSE_BUTTON_LEFT) -> None:
    """A move, a press and a release at (x, y) with no frame between, as one poll delivers a
    quick click (xdotool's "mousemove click")."""
    viewer.input.on_cursor(viewer.window, x, y)
    viewer.input.on_mouse_button(viewer.window, button, glfw.PRESS, 0)
    viewer.input.on_mouse_button(viewer.window, button, glfw.RELEASE, 0)


def _region(image: np.ndarray, rect) -> np.ndarray:
    x0, y0, x1, y1 = (int(round(v)) for v in rect)
    return image[max(y0, 0):y1, max(x0, 0):x1]


def _inside_window(viewer, rect) -> bool:
    width, height = glfw.get_window_size(viewer.window)
    x0, y0, x1, y1 = rect
    return 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height


# --- the notification area ------------------------------------------------------------------------

def test_a_right_click_flag_is_answered_in_view_and_no_message_goes_stale(xvfb, tmp_path):
    """The status sat at the bottom of the scrolling panel (below a 480-pixel window: no visible
    change after a right-click), kept naming a deleted flag, and said "deleted; N Gaussians
    left" after Ctrl+Z had brought them back."""
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 1000, 480) as viewer:
        viewer.status = ""
        _frames(viewer)
        viewer.input.on_cursor(viewer.window, 520, 240)       # the mouse over the scene, right of the panel
        _frames(viewer)
        before = viewer.capture_window()
        _press(viewer, 520, 240, glfw.MOUSE_BUTTON_RIGHT)
        after = viewer.capture_window()                       # the very next frame
        assert [f.name for f in viewer.flags.items] == ["flag 1"], viewer.status
        rect = viewer.ui.rects["notification"]
        assert rect is not None and _inside_window(viewer, rect), rect
        assert "'flag 1'" in viewer.status
        assert np.abs(_region(after, rect) - _region(before, rect)).mean() > 0.05  # drawn at once
        click_widget(viewer, "View")
        click_widget(viewer, "Inspect")
        click_widget(viewer, "flag 1/delete")
        assert viewer.flags.items == [] and "flag 1" not in viewer.status
        # Select a quarter of the grid, delete it, undo: the message follows each state.
        viewer.view.settings.edit_tool = "rectangle"
        total = viewer.view.edit.count
        viewer.input.on_cursor(viewer.window, 520, 20)
        viewer.step()
        viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.PRESS, 0)
        viewer.input.on_cursor(viewer.window, 995, 475)
        viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.RELEASE, 0)
        viewer.step()
        assert 0 < int(viewer.view.edit.selected.sum()) < total
        press_key(viewer, glfw.KEY_DELETE)
        assert viewer.status.startswith("deleted;") and viewer.view.edit.count < total
        press_key(viewer, glfw.KEY_Z, glfw.MOD_CONTROL)
        assert viewer.view.edit.count == total
        assert not viewer.status.startswith("deleted") and f"{total} Gaussians" in viewer.status, viewer.status
        viewer.step()
        assert viewer.ui.rects["notification"] is not None and _inside_window(viewer, viewer.ui.rects["notification"])


# --- the bootstrap's verdict ----------------------------------------------------------------------

def _write_summary(folder: Path, run: Path, baseline: bool, initial: dict, last: dict, seconds: float = 30.0) -> None:
    """RUN2/bootstrap/summary.json: a bootstrap or baseline of ``run`` from iteration 100 that ran
    ``seconds`` (the same for both: the baseline is the same-time one)."""
    (folder / "bootstrap").mkdir(parents=True, exist_ok=True)
    data = {"run": str(run), "baseline": baseline, "start_iteration": 100, "iteration": 160, "wall_s": seconds,
            "initial_eval": initial, "last_eval": last}
    (folder / "bootstrap" / "summary.json").write_text(json.dumps(data), encoding="utf-8")


def _scores(scarce: float, covered: float) -> dict:
    return {"scarce_psnr": scarce, "covered_psnr": covered, "all_psnr": 0.5 * (scarce + covered)}


class FakeBootstrap:
    """Stands in for the bootstrap job: publishes the grid moved, then writes the summary the
    real one writes (RUN2/bootstrap/summary.json) into out_dir."""

    def __init__(self, run_dir: Path, out_dir: Path) -> None:
        self.run_dir, self.out_dir = run_dir, out_dir

    def run(self, box, control):
        box.publish(1, synthetic_gaussians(shift=0.4), {"loss": 0.5})
        time.sleep(0.1)
        _write_summary(self.out_dir, self.run_dir, False, _scores(20.20, 22.30), _scores(20.90, 22.35))


def test_the_bootstrap_ends_with_its_verdict_flagged_view_before_after_and_baseline(xvfb, tmp_path, monkeypatch):
    """It ended with "held-out PSNR covered 22.30 dB": no value before, none for the flagged
    view, none for the same time spent on the photos alone."""
    import inceptiongs.app.job_requests as jobs_module

    run, out = tmp_path / "run", tmp_path / "run_bootstrap"
    run.mkdir()
    _write_summary(tmp_path / "run_baseline", run, True, _scores(20.20, 22.30), _scores(20.40, 22.33))
    monkeypatch.setattr(jobs_module, "bootstrap_job_for", lambda *args, **kwargs: FakeBootstrap(run, out))
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 1000) as viewer:
        # The window shows the run the stand-in repairs (a bare PLY offers no bootstrap: capabilities.py).
        viewer.jobs.run_dir = run
        flag_a_view(viewer)                                    # the flagged view, the button below the edge
        from inceptiongs.app.verdict import Verdict

        stale = Verdict(tmp_path / "earlier_result", None, _scores(10.0, 11.0), _scores(10.5, 11.0))
        viewer.jobs.set_verdict(stale)
        start_job(viewer, "Bootstrap flagged views")
        assert viewer.jobs.verdict is not stale      # an earlier result's verdict goes when the job starts
        wait_for_job_end(viewer)
        _frames(viewer)
        verdict = viewer.jobs.verdict
        assert verdict is not None and verdict.baseline_dir == tmp_path / "run_baseline"
        assert "held-out scarce views: better by 0.50 dB than the same-time baseline" in viewer.status, viewer.status
        # The flagged view from stage I (the grid where it was) and from the result (moved).
        (shown,) = verdict.images
        assert shown.name == "flag 1" and shown.before.shape == shown.after.shape
        assert np.abs(shown.before - shown.after).mean() > 0.02
        assert shown.before.max() > 0.2 and shown.after.max() > 0.2
        # In the panel: the table and both images, inside the window (scrolled to, as a user would).
        scroll_panel_to(viewer, "verdict")
        rect = viewer.ui.rects["verdict"]
        assert _inside_window(viewer, rect) and rect[3] - rect[1] > shown.before.shape[0]
        window = viewer.capture_window()
        assert _region(window, rect).std() > 0.05


def test_the_panel_keeps_the_jobs_closing_line_when_the_status_moves_on(xvfb, tmp_path, monkeypatch):
    """Under "job writes: RUN_bootstrap" the panel drew whatever the status line said last: after
    the bootstrap a saved video's "video saved to .../video_1.mp4" stood there as if the job had
    written it, and the job's result (time, scores, verdict) was gone."""
    import inceptiongs.app.job_requests as jobs_module
    from inceptiongs.app import panels

    run, out = tmp_path / "run", tmp_path / "run_bootstrap"
    run.mkdir()
    monkeypatch.setattr(jobs_module, "bootstrap_job_for", lambda *args, **kwargs: FakeBootstrap(run, out))
    drawn: list[str] = []
    real_text_wrapped = panels.imgui.text_wrapped

    def recording(text, *args):
        drawn.append(str(text))
        return real_text_wrapped(text, *args)

    monkeypatch.setattr(panels.imgui, "text_wrapped", recording)
    with opened(open_grid_viewer, write_grid_model(tmp_path / "closing.ply"), 900, 1000) as viewer:
        viewer.jobs.run_dir = run
        flag_a_view(viewer)
        start_job(viewer, "Bootstrap flagged views")
        wait_for_job_end(viewer)
        closing = viewer.status
        assert " finished in " in closing and "saved in" in closing, closing
        viewer.input.on_cursor(viewer.window, 700, 500)
        _frames(viewer)
        press_key(viewer, glfw.KEY_F)                    # a later action: the status line moves on
        assert viewer.status.startswith("flagged the current view"), viewer.status
        drawn.clear()
        _frames(viewer)
        assert closing in drawn, drawn                   # still under the job in the panel
        assert viewer.status not in drawn, drawn         # said in the notification area, not as the job's


def test_a_job_started_under_the_verdicts_images_does_not_end_the_viewer(xvfb, tmp_path, monkeypatch):
    """The statuette's bootstrap result opened, its verdict's before / after images in view, and
    "run the same-time baseline" answered with "start the job": starting the job let the images'
    GL textures go inside the frame whose draw data still named them, imgui's backend bound a
    released texture (GLError 1282, glBindTexture) and the viewer ended with a traceback, its
    baseline stopped at step 0."""
    import inceptiongs.app.job_requests as jobs_module

    run, out = tmp_path / "run", tmp_path / "run_bootstrap"
    run.mkdir()
    monkeypatch.setattr(jobs_module, "bootstrap_job_for", lambda *args, **kwargs: FakeBootstrap(run, out))
    with opened(open_grid_viewer, write_grid_model(tmp_path / "restart.ply"), 900, 1200) as viewer:
        viewer.jobs.run_dir = run
        flag_a_view(viewer)
        start_job(viewer, "Bootstrap flagged views")
        wait_for_job_end(viewer)
        _frames(viewer)
        (shown,) = viewer.jobs.verdict.images
        assert shown.textures, "the verdict's images are drawn from GL textures"
        scroll_panel_to(viewer, "Bootstrap flagged views")
        rect = viewer.ui.rects["verdict"]
        assert _inside_window(viewer, rect), rect     # the images are drawn in the frame of the click
        start_job(viewer, "Bootstrap flagged views")  # the frame that starts it draws, and renders
        assert viewer.jobs.training is not None and viewer.jobs.verdict is None
        _frames(viewer)
        assert not shown.textures


def test_plots_do_not_magnify_noise_count_in_integers_and_ignore_the_mouse(xvfb, tmp_path):
    """A PSNR axis spanning 22.22-22.30 made 0.08 dB of noise look like large swings, the
    Gaussians axis read "94683.4 / 94683.2", and hovering the loss plot's x axis painted a
    solid block."""
    from inceptiongs.app.progress import JobPlan

    metrics = tmp_path / "metrics.jsonl"
    lines = [{"iteration": i, "wall_s": float(i), "all_psnr": 22.22 + 0.01 * (i % 9),
              "covered_psnr": 22.22 + 0.01 * (i % 9), "scarce_psnr": 20.0 + 0.01 * (i % 5)} for i in range(0, 100, 10)]
    metrics.write_text("\n".join(json.dumps(line) for line in lines) + "\n", encoding="utf-8")

    class SteadyJob:
        def run(self, box, control):
            step = 0
            while not control.stop.is_set():
                if control.pause.is_set():
                    time.sleep(0.01)
                    continue
                step += 1
                box.publish(step, None, {"loss": 4.6 + 0.01 * (step % 3), "l1": 0.08 + 0.002 * (step % 4),
                                         "num_gaussians": 94683})
                time.sleep(0.02)

    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 1000) as viewer:
        viewer.jobs.factory = lambda source: SteadyJob()
        _frames(viewer)
        for header in ("View", "Inspect", "Flags"):
            click_widget(viewer, header)
        start_job(viewer, "train (new run)")
        viewer.jobs.training.plan = JobPlan(metrics=metrics)
        viewer.jobs.training.refresh_scores(force=True)
        time.sleep(0.3)
        _frames(viewer, 6)
        limits = viewer.jobs.training.progress.plot_limits
        (_, _), (low, high) = limits["held-out PSNR"]
        assert high - low >= 1.0 and low <= 20.0 and high >= 22.30
        (_, _), (low, high) = limits["Gaussians"]
        assert high - low >= 10 and low < 94683 < high
        # The L1 (about 0.08) has an axis of its own: on the loss's (about 4.6) it was a flat line.
        (_, _), (low, high) = limits["training loss"]
        assert low < 4.6 < high and low > 1.0
        (_, _), (low, high) = limits["training loss (right)"]
        assert low < 0.08 and 0.086 < high < 0.5
        x0, y0, x1, y1 = viewer.ui.rects["plot area/training loss"]
        frame = viewer.ui.rects["plot/training loss"]
        assert _inside_window(viewer, frame)
        click_widget(viewer, "pause")
        assert viewer.jobs.training.control.pause.is_set() and "paused at iteration" in viewer.status
        _frames(viewer, 4)
        viewer.input.on_cursor(viewer.window, 0.5 * (x0 + x1), min(frame[3], y1 + 30) - 4)
        _frames(viewer, 2)
        away = viewer.capture_window()
        viewer.input.on_cursor(viewer.window, 0.5 * (x0 + x1), y1 + 6)   # over the x axis's tick labels
        _frames(viewer, 2)
        hovered = viewer.capture_window()
        axis = (x0, y1, x1, min(frame[3], y1 + 20))
        assert np.abs(_region(hovered, axis) - _region(away, axis)).max() < 0.02


def test_plot_ranges_have_a_minimum_span_and_all_is_drawn_under_the_groups():
    from inceptiongs.app.plots import axis_range, drawing_order, min_span

    low, high = axis_range([22.22, 22.30], min_span("dB", np.array([22.22, 22.30])))
    assert high - low == pytest.approx(1.0) and low < 22.22 and high > 22.30
    low, high = axis_range([10.0, 30.0], 1.0)                # wide data: its span plus a margin
    assert low < 10.0 and high > 30.0 and high - low < 25.0
    assert min_span("count", np.array([94683.0])) >= 10 * 189
    names = [name for name, _ in drawing_order([("scarce", 0), ("covered", 0), ("all", 0)])]
    assert names == ["all", "scarce", "covered"]


# --- the small things -----------------------------------------------------------------------------

def test_esc_closes_the_help_ctrl_q_quits_and_the_help_is_opaque(xvfb, tmp_path):
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 640, 480) as viewer:
        viewer.status = ""
        _frames(viewer)
        press_key(viewer, glfw.KEY_H)
        _frames(viewer)
        assert viewer.ui.show_help
        rect = viewer.ui.rects["help"]
        assert rect[0] < viewer.ui.layout["rect"][2]            # it lies over the panel
        with_panel = viewer.capture_window()
        press_key(viewer, glfw.KEY_TAB)                          # the panel away: the scene under the help
        _frames(viewer)
        without_panel = viewer.capture_window()
        inner = (rect[0] + 2, rect[1] + 24, rect[2] - 2, rect[3] - 2)
        assert np.abs(_region(with_panel, inner) - _region(without_panel, inner)).max() < 1.5 / 255
        press_key(viewer, glfw.KEY_ESCAPE)
        assert not viewer.ui.show_help and not viewer.should_close()
        press_key(viewer, glfw.KEY_Q, glfw.MOD_CONTROL)
        assert viewer.should_close()


def test_figures_keep_their_units_and_a_long_path_is_shortened_with_a_tooltip(xvfb, tmp_path, monkeypatch):
    deep = tmp_path.joinpath(*[f"a_rather_long_folder_name_{i}" for i in range(4)])
    deep.mkdir(parents=True)
    monkeypatch.chdir(deep)   # the flags go to ./runs/model_saved/flags.json: a long path from here
    with opened(open_grid_viewer, write_grid_model(deep / "model.ply"), 640, 480) as viewer:
        _frames(viewer)
        line = viewer.ui.rects["stats/0"][3] - viewer.ui.rects["stats/0"][1]
        for number in range(4):                                  # FPS, frame ms, sort ms, draw ms
            x0, y0, x1, y1 = viewer.ui.rects[f"stats/{number}"]
            assert y1 - y0 == pytest.approx(line) and x1 <= viewer.ui.layout["visible_right"] + 1
        assert len(str(viewer.flags.file)) > 80
        x0, y0, x1, y1 = viewer.ui.rects["flags file"]
        assert y1 - y0 == pytest.approx(line) and x1 <= viewer.ui.layout["visible_right"] + 1
        viewer.input.on_cursor(viewer.window, 0.5 * (x0 + x1), 0.5 * (y0 + y1))
        _frames(viewer, 4)
        assert viewer.ui.tooltip == str(viewer.flags.file)


def test_a_quick_click_on_the_crop_box_keeps_the_lasso_selection(xvfb, tmp_path):
    """The press of a click on the panel arrived in the poll that moved the cursor there, before
    imgui's next frame: the scene took it too, and the lasso's empty selection replaced the
    user's."""
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 1000) as viewer:
        _frames(viewer)
        click_widget(viewer, "Edit")
        viewer.view.settings.edit_tool = "lasso"
        path = [(450, 100), (880, 100), (880, 900), (450, 900)]
        viewer.input.on_cursor(viewer.window, *path[0])
        viewer.step()
        viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.PRESS, 0)
        for point in path[1:]:
            viewer.input.on_cursor(viewer.window, *point)
            viewer.step()
        viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.RELEASE, 0)
        _frames(viewer)
        selected = viewer.view.edit.selected.copy()
        assert 0 < selected.sum() < viewer.view.edit.count
        x0, y0, x1, y1 = viewer.ui.rects["crop box (drag its handles)"]
        _press(viewer, 0.5 * (x0 + x1), 0.5 * (y0 + y1))
        _frames(viewer)
        assert viewer.view.settings.crop_enabled
        np.testing.assert_array_equal(viewer.view.edit.selected, selected)


def _viewer_command(*args: str, env_drop: tuple = ()) -> "subprocess.CompletedProcess":
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in env_drop}
    return subprocess.run([sys.executable, "-m", "inceptiongs.app.main", *args], capture_output=True, text=True,
                          timeout=300, env=env)


def test_without_a_display_the_error_is_the_only_line(tmp_path):
    """pyGLFW printed its GLFWError warning (two lines) before the viewer's one-line error."""
    result = _viewer_command(str(write_grid_model(tmp_path / "model.ply")), env_drop=("DISPLAY", "WAYLAND_DISPLAY"))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: could not initialise GLFW"), result.stderr
    assert "DISPLAY" in lines[0]


def test_an_empty_folder_is_named_once_in_a_flat_message(tmp_path):
    """"PATH: neither a scene folder (PATH: no recognisable scene (expected ...)) nor ..." named
    the folder twice, one message nested in another."""
    empty = tmp_path / "empty"
    empty.mkdir()
    result = _viewer_command(str(empty))
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert line.count(str(empty)) == 1 and "((" not in line and ")) " not in line, line
    assert "no recognisable scene" in line and ".ply" in line


def test_a_folder_inside_a_run_names_the_run_to_open(tmp_path):
    """RUN/bootstrap (the folder a user may drop instead of the run) was read as a run for its
    config.json, and refused with "unknown key 'agreement_min_db'; docs/train_options.md lists
    the keys"; RUN/checkpoints said "no recognisable scene". Both name the run to open."""
    run = tmp_path / "run_bootstrap"
    for folder in ("bootstrap", "checkpoints"):
        (run / folder).mkdir(parents=True)
    (run / "config.json").write_text("{}")
    (run / "split.json").write_text("{}")
    (run / "bootstrap" / "config.json").write_text('{"agreement_min_db": -1.0}')
    for inner in (run / "bootstrap", run / "checkpoints"):
        result = _viewer_command(str(inner))
        assert result.returncode == 2
        (line,) = result.stderr.strip().splitlines()
        assert f"inside the run {run}" in line and f"inceptiongs-viewer {run}" in line, line
        assert "unknown key" not in line and "no recognisable scene" not in line, line


@pytest.mark.slow
def test_a_screenshot_of_an_llff_scene_without_points_waits_for_them(tmp_path):
    """`inceptiongs-viewer fern/ --screenshot x.png` wrote an all-black image, taken before the
    points the viewer triangulates on a thread existed."""
    from conftest import require_data
    from inceptiongs.io.images import read_png

    fern = require_data("fern")
    out = tmp_path / "fern.png"
    result = _viewer_command(str(fern), "--screenshot", str(out), "--size", "320x240")
    assert result.returncode == 0, result.stderr
    image = read_png(out)
    assert (image.max(axis=2) > 0.05).mean() > 0.05  # the points cover part of the view


@pytest.mark.slow
def test_an_opened_bootstrap_result_shows_its_verdict_and_its_target_before_and_after(xvfb, tmp_path):
    """A result of `inceptiongs bootstrap` (not the viewer's job) opened later: the scores of
    stage I, the result and the same-time baseline beside it, and j* rendered from both models."""
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.runner import baseline_run, resolve_targets, run_bootstrap
    from inceptiongs.evaluation.protocols import Split
    from inceptiongs.runs.load import load_run
    from train_cases import tiny_demo_run

    run = tiny_demo_run(tmp_path, iterations=10, densification={"densify_from": 1000},
                        pgsr_terms={"normal_from": 1000},
                        output={"log_every": 5, "eval_every": 10, "checkpoint_every": 10})
    _, scene, _ = load_run(run)
    targets = resolve_targets(scene, Split.load(run / "split.json", scene.cameras), None, None, 1)
    config = BootstrapConfig(iterations=6, k=1, l=2, ddim_steps=1, prior="untrained", log_every=1, save_views=0)
    run_bootstrap(run, tmp_path / "run_bootstrap", targets, config, progress=False)
    # The same-time baseline: the bootstrap's wall time, as `inceptiongs demo` gives it.
    seconds = json.loads((tmp_path / "run_bootstrap" / "bootstrap" / "summary.json").read_text())["wall_s"]
    baseline_run(run, tmp_path / "run_baseline", seconds / 60.0, 100_000, seed=0, progress=False)
    with opened(Viewer, open_source(tmp_path / "run_bootstrap"), 900, 1000) as viewer:
        _frames(viewer)
        verdict = viewer.jobs.verdict
        assert verdict is not None and verdict.stage1_run.resolve() == run.resolve()
        assert verdict.baseline_dir == tmp_path / "run_baseline" and verdict.baseline
        (shown,) = verdict.images
        assert shown.name == targets[0].name and shown.before.max() > 0.1
        assert np.abs(shown.before - shown.after).mean() > 1e-3  # the refined model renders differently
        # What stage I's curve said before the bootstrap started, as the bootstrap recorded it.
        recorded = json.loads((tmp_path / "run_bootstrap" / "bootstrap" / "summary.json").read_text())["outlook"]
        assert verdict.outlook == recorded["line"] and recorded["verdict"] in ("repair", "train longer",
                                                                               "nothing to repair", "unknown")
        scroll_panel_to(viewer, "verdict")
        assert _inside_window(viewer, viewer.ui.rects["verdict"])


def test_the_verdict_sentence_reads_as_a_comparison():
    from inceptiongs.app.verdict import Verdict, verdict_line

    flat = _scores(20.00, 22.00)
    same = Verdict(Path("boot"), None, flat, _scores(20.02, 22.00), seconds=90.0)
    assert verdict_line(same).startswith("held-out scarce views: about the same as stage I (+0.02 dB); no same-time baseline "
                                         "(stage I continued on the photos alone for 1 min 30 s) was run")
    worse = Verdict(Path("boot"), None, flat, _scores(19.00, 22.00), baseline=_scores(19.50, 22.00))
    assert verdict_line(worse) == ("held-out scarce views: worse by 0.50 dB than the same-time baseline; it scored below "
                                   "stage I (20.00 -> 19.00 dB)")
    # No virtual step ran (the loop followed the outlook): the change is stage I trained longer.
    photos_only = Verdict(Path("boot"), None, flat, _scores(19.54, 22.00), virtual_steps=0)
    assert verdict_line(photos_only) == ("held-out scarce views: worse by 0.46 dB than stage I; no same-time baseline (stage I "
                                         "continued on the photos alone for the bootstrap's time) was run; no "
                                         "virtual step ran (the loop followed the outlook, or every view was left "
                                         "out), so this is stage I trained longer")
    assert "extra training alone" in verdict_line(dataclasses.replace(photos_only, virtual_steps=3))


def test_a_stage_i_run_says_its_repair_outlook_before_a_bootstrap_starts(xvfb, tmp_path):
    """The bootstrap's outlook (nothing to repair / train longer / worth a repair) was only printed
    once a bootstrap had started; the Training panel now says it under the button."""
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.verdict import outlook_before_repair
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.bootstrap.outlook import run_outlook
    from train_cases import tiny_demo_run

    run = tiny_demo_run(tmp_path, iterations=10, densification={"densify_from": 1000},
                        pgsr_terms={"normal_from": 1000},
                        output={"log_every": 5, "eval_every": 5, "checkpoint_every": 10})
    expected = run_outlook(run).line
    assert outlook_before_repair(run) == expected and outlook_before_repair(None) is None
    with opened(Viewer, open_source(run), 900, 1000) as viewer:
        _frames(viewer)
        scroll_panel_to(viewer, "repair outlook")
        assert _inside_window(viewer, viewer.ui.rects["repair outlook"])
    (run / "bootstrap").mkdir()
    assert outlook_before_repair(run) is None      # a bootstrap's result: its verdict speaks instead


def _relative_luminance(rgb) -> float:
    """WCAG relative luminance of an sRGB colour in [0, 1]."""
    linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in rgb]
    return 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]


def test_a_progress_bars_label_reads_on_its_fill(xvfb, tmp_path):
    """A bootstrap's bar read "iteration 1285 / 1305" in white on imgui's bright amber, a
    contrast of 1.9:1: the part over the fill was hard to read. WCAG's minimum for text is 4.5:1."""
    from imgui_bundle import imgui

    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 640, 480) as viewer:
        _frames(viewer, 1)
        style = imgui.get_style()
        fill, text = style.color_(imgui.Col_.plot_histogram), style.color_(imgui.Col_.text)
        lighter, darker = sorted((_relative_luminance((fill.x, fill.y, fill.z)),
                                  _relative_luminance((text.x, text.y, text.z))), reverse=True)
        assert (lighter + 0.05) / (darker + 0.05) >= 4.5, (fill, text)


def test_what_was_typed_shows_before_the_window_goes_idle(xvfb, tmp_path):
    """Typed fast into a field (xdotool, 30 ms a key, the viewer at 4 FPS), the "file" field
    showed "sert" of "/tmp/usertry2/exp/fromviewer.splat" until the mouse moved, 30 s later:
    imgui takes its queued input a little per frame, and the loop went idle with keys queued."""
    from inceptiongs.app.pacing import UI_SETTLE_SECONDS, is_idle

    with opened(open_grid_viewer, write_grid_model(tmp_path / "typing.ply"), 900, 1000) as viewer:
        click_widget(viewer, "Edit")
        scroll_panel_to(viewer, "file")
        x0, y0, x1, y1 = viewer.ui.rects["file"]
        click_at(viewer, x0 + 6, 0.5 * (y0 + y1))
        _frames(viewer)
        before = viewer.editor.saving.path
        typed = "abcdefgh"
        for char in typed:   # all in one poll, as GLFW hands them over after a slow frame
            key = glfw.KEY_A + ord(char) - ord("a")
            viewer.input.on_key(viewer.window, key, 0, glfw.PRESS, 0)
            viewer.input.on_char(viewer.window, ord(char))
            viewer.input.on_key(viewer.window, key, 0, glfw.RELEASE, 0)
        viewer.step()
        time.sleep(UI_SETTLE_SECONDS + 0.05)   # no further event: only what imgui still holds
        frames = 0
        while not is_idle(viewer) and frames < 200:
            viewer.step()
            frames += 1
        # Inserted where the click put the cursor (the field's left end), every key of it.
        assert viewer.editor.saving.path == typed + before, (viewer.editor.saving.path, frames)


def test_the_first_frame_says_so_instead_of_zero_fps(xvfb, tmp_path):
    """The window opened on the statuette read "0.0 FPS frame 0.0 ms sort 2409.8 ms draw 5994.9 ms"
    and, idle, kept it: the panel is drawn inside the frame it times, before any was counted."""
    from inceptiongs.app.settings import FrameStats

    with opened(open_grid_viewer, write_grid_model(tmp_path / "first.ply"), 640, 480) as viewer:
        viewer.stats = FrameStats()          # as when the window opens
        viewer.step()
        assert viewer.ui.texts["stats"][0] == "first frame", viewer.ui.texts["stats"]
        _frames(viewer, 2)
        shown = viewer.ui.texts["stats"]
        assert shown[0].endswith(" FPS") and shown[0] != "0.0 FPS" and shown[1].startswith("frame "), shown


def test_ctrl_q_quits_while_a_text_field_has_the_keys(xvfb, tmp_path):
    """Ctrl+Q did nothing while a text field had focus (the panel took every key)."""
    from inceptiongs.app.window import ui_wants_keyboard

    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 640, 480) as viewer:
        viewer.step()
        open_edit_section(viewer)
        scroll_panel_to(viewer, "save PLY")
        x0, y0, x1, y1 = viewer.ui.rects["file"]
        click_at(viewer, x0 + 6, 0.5 * (y0 + y1))
        _frames(viewer, 2)
        assert ui_wants_keyboard(viewer.imgui_impl)          # the field has the keys
        press_key(viewer, glfw.KEY_Q, glfw.MOD_CONTROL)
        assert viewer.should_close()
