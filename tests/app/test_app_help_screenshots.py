"""Help and screenshots: the bindings in --help and in the window (H / F1), the
screenshot in the format its extension names, a run's screenshot at the window's size."""

from __future__ import annotations

import subprocess
import sys

import glfw
import numpy as np
import pytest

from inceptiongs.app.settings import KEY_BINDINGS
from inceptiongs.app.pacing import is_idle, wait_for_next_frame
from viewer_cases import open_grid_viewer, opened, write_grid_model


def test_help_lists_every_binding():
    result = subprocess.run([sys.executable, "-m", "inceptiongs.app.main", "--help"], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 0
    for keys, action in KEY_BINDINGS:
        assert keys in result.stdout and action in result.stdout, keys


@pytest.mark.gl
def test_h_shows_the_help_overlay(xvfb, tmp_path):
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 800, 600) as viewer:
        viewer.step()
        before = viewer.capture_window()
        viewer.input.on_key(viewer.window, glfw.KEY_H, 0, glfw.PRESS, 0)
        assert viewer.ui.show_help
        viewer.step()  # imgui sizes an auto-resizing window on its first frame, shows it on the next
        during = viewer.capture_window()
        # A window over the middle of the screen (right of the panel: x > 420).
        middle = np.s_[200:400, 430:560]
        assert np.abs(during[middle] - before[middle]).mean() > 0.05
        viewer.input.on_key(viewer.window, glfw.KEY_F1, 0, glfw.PRESS, 0)
        assert not viewer.ui.show_help
        after = viewer.capture_window()
        assert np.abs(after[middle] - before[middle]).mean() < 0.01


@pytest.mark.gl
def test_f12_writes_the_format_of_the_extension_at_window_size(xvfb, tmp_path):
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 400, 300, with_ui=False) as viewer:
        viewer.step()
        jpeg = viewer.save_screenshot(tmp_path / "x.jpg")
        png = viewer.save_screenshot(tmp_path / "x.png")
    assert jpeg.read_bytes()[:3] == b"\xff\xd8\xff"        # JPEG data, not PNG data named .jpg
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from inceptiongs.io.images import read_png
    assert read_png(jpeg).shape == (300, 400, 3)


def test_a_run_screenshot_defaults_to_the_window_size(tmp_path):
    from inceptiongs.app.screenshot import DEFAULT_SIZE, screenshot_camera
    from inceptiongs.camera import Camera
    from types import SimpleNamespace

    training = Camera("train", 96, 72, 80.0, 80.0, 48.0, 36.0, np.eye(4))
    source = SimpleNamespace(cameras=[training], gaussians={"means": np.zeros((1, 3))})
    camera = screenshot_camera(source, None, None)
    assert (camera.width, camera.height) == (960, 720) and camera.height <= DEFAULT_SIZE[1]
    assert camera.fx == pytest.approx(800.0)  # the same view, scaled
    assert screenshot_camera(source, None, (64, 48)).width == 64  # --size still decides


def test_unknown_screenshot_format_is_one_line_error(tmp_path, capfd, monkeypatch):
    """The viewer's main() in this process, its stderr read at the fd (the whole process's one
    line on a bad input is tested in test_app_viewer.test_bad_source_is_one_line_error_exit_2)."""
    from inceptiongs.app.main import main

    model = write_grid_model(tmp_path / "model.ply")
    monkeypatch.delenv("DISPLAY", raising=False)
    capfd.readouterr()
    assert main([str(model), "--screenshot", str(tmp_path / "x.gif")]) == 2
    lines = capfd.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "x.gif" in lines[0] and "unknown image format" in lines[0]


@pytest.mark.gl
def test_the_help_appears_at_once_in_an_idle_window(xvfb, tmp_path):
    """As run() draws: an idle window sleeps up to 2 s between frames, and imgui shows the help
    window on the frame after the key (it sizes it first); the frames after an input event come
    at once, so the help shows within a fraction of a second, not up to 2 s later."""
    import time

    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 800, 600) as viewer:
        viewer.step()
        deadline = time.perf_counter() + 10
        while not is_idle(viewer) and time.perf_counter() < deadline:
            viewer.step()
        assert is_idle(viewer)
        before = viewer.capture_window()
        viewer.input.on_key(viewer.window, glfw.KEY_H, 0, glfw.PRESS, 0)
        viewer.input.on_key(viewer.window, glfw.KEY_H, 0, glfw.RELEASE, 0)
        began = time.perf_counter()
        frames = viewer.stats.frames
        while time.perf_counter() - began < 0.5:  # run()'s loop for half a second
            wait_for_next_frame(viewer)
            viewer.step()
        assert viewer.stats.frames >= frames + 2, "the frames after the key should not wait"
        during = viewer.capture_window()
        middle = np.s_[200:400, 430:560]
        assert np.abs(during[middle] - before[middle]).mean() > 0.05
