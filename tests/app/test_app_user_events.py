"""The viewer driven only as a user drives it (issue 19's "each item has an Xvfb test driving the
real app"): keys, mouse drags, panel combos and checkboxes, each an event as GLFW delivers it
(through the window's callbacks and imgui's GLFW backend), the result read from the app."""

from __future__ import annotations

from contextlib import contextmanager

import glfw
import numpy as np
import pytest

from viewer_cases import (choose, click_widget, open_grid_viewer, open_viewer, press_key, write_grid_model,
                          write_table_model)

pytestmark = pytest.mark.gl


@contextmanager
def _opened(opener, *args):
    """The real app opened by ``opener(*args)``, closed afterwards whatever happens."""
    viewer = opener(*args)
    try:
        yield viewer
    finally:
        viewer.close()


def _drag(viewer, start, end, steps: int = 6, button=glfw.MOUSE_BUTTON_LEFT) -> None:
    viewer.input.on_cursor(viewer.window, *start)
    viewer.step()  # imgui sees the cursor leave the panel before the press, as between a user's events
    viewer.input.on_mouse_button(viewer.window, button, glfw.PRESS, 0)
    for t in np.linspace(0, 1, steps)[1:]:
        viewer.input.on_cursor(viewer.window, *(np.add(start, t * np.subtract(end, start))))
        viewer.step()
    viewer.input.on_mouse_button(viewer.window, button, glfw.RELEASE, 0)
    viewer.step()


def test_mode_keys_mode_combo_and_f12(xvfb, tmp_path):
    from inceptiongs.io.images import read_png

    with _opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 700) as viewer:
        viewer.settings.show_training_cameras = False
        viewer.step()
        press_key(viewer, glfw.KEY_4)
        assert viewer.settings.mode == "opacity"
        alpha = viewer.render_image()
        assert alpha.max() > 0.9 and np.allclose(alpha[..., 0], alpha[..., 2])  # the alpha image, grey
        choose(viewer, "mode (1-6)", "normal")
        assert viewer.settings.mode == "normal"
        press_key(viewer, glfw.KEY_1)
        press_key(viewer, glfw.KEY_F12)
        shots = list((viewer.source.work_dir / "screenshots").glob("view-*.png"))
        assert len(shots) == 1, viewer.status
        assert read_png(shots[0]).shape == (700, 900, 3)  # the window's size, the scene alone


def test_orbit_key_and_drag_stay_level_and_the_up_combo_turns_the_world(xvfb, tmp_path):
    with _opened(open_viewer, write_table_model(tmp_path / "table.ply"), 900, 700) as viewer:
        viewer.step()
        np.testing.assert_array_equal(viewer.up, [0, 0, 1])
        press_key(viewer, glfw.KEY_O)
        assert viewer.settings.orbit
        before = viewer.nav.rotation.copy()
        distance = np.linalg.norm(viewer.nav.center - viewer.nav.pivot)
        _drag(viewer, (600, 350), (800, 350))  # right of the panel: orbit left-right
        assert np.abs(viewer.nav.rotation - before).max() > 0.1, "the drag should orbit the camera"
        assert abs(viewer.nav.rotation[0] @ viewer.up) < 1e-6  # the horizon stays level: no tumbling
        assert np.linalg.norm(viewer.nav.center - viewer.nav.pivot) == pytest.approx(distance, rel=1e-6)
        choose(viewer, "up, from the model", "-Z")
        np.testing.assert_array_equal(viewer.up, [0, 0, -1])
        assert viewer.up_source == "chosen"


def test_edit_panel_tool_combo_crop_checkbox_and_delete_key(xvfb, tmp_path):
    with _opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 1000) as viewer:
        viewer.step()
        click_widget(viewer, "Edit")
        choose(viewer, "tool (left mouse)", "brush")
        assert viewer.settings.edit_tool == "brush"
        assert viewer.settings.crop_min is None
        click_widget(viewer, "crop box (drag its handles)")
        assert viewer.settings.crop_enabled
        lo, hi = np.array(viewer.settings.crop_min), np.array(viewer.settings.crop_max)
        assert lo[0] < -0.9 and hi[0] > 0.9 and hi[2] - lo[2] < 1.5  # fitted to the grid, not +-1
        # Rectangle over the right half of the window, the Delete key, then Ctrl+Z.
        click_widget(viewer, "crop box (drag its handles)")  # the box off again
        choose(viewer, "tool (left mouse)", "rectangle")
        total = viewer.edit.count
        _drag(viewer, (480, 5), (895, 995))
        selected = int(viewer.edit.selected.sum())
        assert 0 < selected < total
        press_key(viewer, glfw.KEY_DELETE)
        assert viewer.edit.count == total - selected
        press_key(viewer, glfw.KEY_Z, glfw.MOD_CONTROL)
        assert viewer.edit.count == total


def test_the_jobs_share_of_the_cpu_is_a_slider_the_user_drags(xvfb, tmp_path):
    """The training-utilisation setting (as nerfview's): a click at the slider's left end sets its
    minimum, and the viewer then leaves the job less time between frames."""
    from viewer_cases import MovingGridJob

    job = MovingGridJob()
    with _opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 700) as viewer:
        viewer.job_factory = lambda source: job
        viewer.step()
        click_widget(viewer, "train (new run)")
        for _ in range(3):
            viewer.step()
        default_wait = viewer.training_frame_wait()
        x0, y0, _, y1 = viewer.ui_rects["job's share of the CPU"]
        _drag(viewer, (x0 + 40, 0.5 * (y0 + y1)), (x0 - 30, 0.5 * (y0 + y1)))  # to the left end
        assert viewer.settings.training_utilisation == pytest.approx(0.5)
        assert viewer.training_frame_wait() < default_wait
