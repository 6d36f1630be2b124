"""The viewer driven only as a user drives it ("each item has an Xvfb test driving the
real app"): keys, mouse drags, panel combos and checkboxes, each an event as GLFW delivers it
(through the window's callbacks and imgui's GLFW backend), the result read from the app."""

from __future__ import annotations

import time

import glfw
from pathlib import Path

import numpy as np
import pytest

from inceptiongs.app.pacing import training_frame_wait
from viewer_cases import (choose, click_at, click_widget, open_grid_viewer, open_viewer, opened, press_key,
                          scroll_panel_to, start_job, type_into, write_grid_model, write_table_model)

pytestmark = pytest.mark.gl


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

    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 700) as viewer:
        viewer.view.settings.show_training_cameras = False
        viewer.step()
        press_key(viewer, glfw.KEY_4)
        assert viewer.view.settings.mode == "opacity"
        alpha = viewer.render_image()
        assert alpha.max() > 0.9 and np.allclose(alpha[..., 0], alpha[..., 2])  # the alpha image, grey
        choose(viewer, "mode (1-6)", "normal")
        assert viewer.view.settings.mode == "normal"
        press_key(viewer, glfw.KEY_1)
        press_key(viewer, glfw.KEY_F12)
        shots = list((Path.cwd() / "runs" / "model_saved").glob("view-*.png"))  # beside the runs, not the cache
        assert len(shots) == 1, viewer.status
        assert read_png(shots[0]).shape == (700, 900, 3)  # the window's size, the scene alone


def test_orbit_key_and_drag_stay_level_and_the_up_combo_turns_the_world(xvfb, tmp_path):
    with opened(open_viewer, write_table_model(tmp_path / "table.ply"), 900, 700) as viewer:
        viewer.step()
        np.testing.assert_array_equal(viewer.view.up, [0, 0, 1])
        press_key(viewer, glfw.KEY_O)
        assert viewer.view.settings.orbit
        before = viewer.view.nav.rotation.copy()
        distance = np.linalg.norm(viewer.view.nav.center - viewer.view.nav.pivot)
        _drag(viewer, (600, 350), (800, 350))  # right of the panel: orbit left-right
        assert np.abs(viewer.view.nav.rotation - before).max() > 0.1, "the drag should orbit the camera"
        assert abs(viewer.view.nav.rotation[0] @ viewer.view.up) < 1e-6  # the horizon stays level: no tumbling
        assert np.linalg.norm(viewer.view.nav.center - viewer.view.nav.pivot) == pytest.approx(distance, rel=1e-6)
        choose(viewer, "up, from the model", "-Z")
        np.testing.assert_array_equal(viewer.view.up, [0, 0, -1])
        assert viewer.view.up_source == "chosen"


def test_edit_panel_tool_combo_crop_checkbox_and_delete_key(xvfb, tmp_path):
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 1000) as viewer:
        viewer.step()
        click_widget(viewer, "Edit")
        choose(viewer, "tool (left mouse)", "brush")
        assert viewer.view.settings.edit_tool == "brush"
        assert viewer.view.settings.crop_min is None
        click_widget(viewer, "crop box (drag its handles)")
        assert viewer.view.settings.crop_enabled
        lo, hi = np.array(viewer.view.settings.crop_min), np.array(viewer.view.settings.crop_max)
        assert lo[0] < -0.9 and hi[0] > 0.9 and hi[2] - lo[2] < 1.5  # fitted to the grid, not +-1
        # Rectangle over the right half of the window, the Delete key, then Ctrl+Z.
        click_widget(viewer, "crop box (drag its handles)")  # the box off again
        choose(viewer, "tool (left mouse)", "rectangle")
        total = viewer.view.edit.count
        _drag(viewer, (480, 5), (895, 995))
        selected = int(viewer.view.edit.selected.sum())
        assert 0 < selected < total
        press_key(viewer, glfw.KEY_DELETE)
        assert viewer.view.edit.count == total - selected
        press_key(viewer, glfw.KEY_Z, glfw.MOD_CONTROL)
        assert viewer.view.edit.count == total


def test_the_jobs_share_of_the_cpu_is_a_slider_the_user_drags(xvfb, tmp_path):
    """The training-utilisation setting (as nerfview's): a click at the slider's left end sets its
    minimum, and the viewer then leaves the job less time between frames."""
    from viewer_cases import MovingGridJob

    job = MovingGridJob()
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 900, 700) as viewer:
        viewer.jobs.factory = lambda source: job
        viewer.step()
        start_job(viewer, "train (new run)")
        for _ in range(3):
            viewer.step()
        default_wait = training_frame_wait(viewer.stats.frame_ms, viewer.jobs.training_utilisation)
        x0, y0, _, y1 = viewer.ui.rects["job's share of the CPU"]
        _drag(viewer, (x0 + 40, 0.5 * (y0 + y1)), (x0 - 30, 0.5 * (y0 + y1)))  # to the left end
        assert viewer.jobs.training_utilisation == pytest.approx(0.5)
        assert training_frame_wait(viewer.stats.frame_ms, viewer.jobs.training_utilisation) < default_wait


def _collapse(viewer, *headers: str) -> None:
    """Close panel sections (a click on each header) so the ones below fit a small window."""
    for header in headers:
        click_widget(viewer, header)


def _hover(viewer, x: float, y: float) -> None:
    """The cursor to window position (x, y), then the frames imgui takes to see it there (it
    takes its queued events one kind per frame, as they arrive between a user's frames)."""
    viewer.input.on_cursor(viewer.window, x, y)
    for _ in range(3):
        viewer.step()


def _press(viewer, x: float, y: float, button=glfw.MOUSE_BUTTON_LEFT) -> None:
    """A press then a release of ``button`` at window position (x, y), no frame between."""
    viewer.input.on_cursor(viewer.window, x, y)
    viewer.input.on_mouse_button(viewer.window, button, glfw.PRESS, 0)
    viewer.input.on_mouse_button(viewer.window, button, glfw.RELEASE, 0)


def test_flag_list_go_rename_and_delete_by_clicks_and_typing(xvfb, tmp_path):
    from inceptiongs.io.flags import load_flags

    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 640, 480) as viewer:
        viewer.step()
        _collapse(viewer, "View", "Inspect")
        _hover(viewer, 450, 240)                            # the mouse over the scene, off the panel
        press_key(viewer, glfw.KEY_F)                       # flag 1 at the opening view
        first = viewer.view.nav.copy()
        _drag(viewer, (450, 240), (560, 200))               # look elsewhere
        press_key(viewer, glfw.KEY_F)                       # flag 2 there
        second = viewer.view.nav.copy()
        assert [f.name for f in viewer.flags.items] == ["flag 1", "flag 2"]
        assert np.abs(first.rotation - second.rotation).max() > 0.05
        click_widget(viewer, "flag 1/go")
        np.testing.assert_allclose(viewer.view.nav.rotation, first.rotation, atol=1e-6)
        np.testing.assert_allclose(viewer.view.nav.center, first.center, atol=1e-6)
        click_widget(viewer, "flag 2/go")
        np.testing.assert_allclose(viewer.view.nav.rotation, second.rotation, atol=1e-6)
        # Select flag 1 (a click on its name), type a new name into "rename", Enter.
        click_widget(viewer, "flag 1/name")
        assert viewer.flags.selected == 0
        type_into(viewer, "rename", "doorway")
        assert [f.name for f in viewer.flags.items] == ["doorway", "flag 2"]
        assert [f.name for f in load_flags(viewer.flags.file)] == ["doorway", "flag 2"]  # saved at once
        click_widget(viewer, "flag 2/name")
        type_into(viewer, "rename", "doorway")               # a name taken: refused, said why
        assert [f.name for f in viewer.flags.items] == ["doorway", "flag 2"] and "exists" in viewer.status
        # With flag 2 selected, deleting flag 1 keeps the selection on flag 2 (it moved up a row).
        click_widget(viewer, "flag 2/name")
        click_widget(viewer, "flag 1/delete")
        assert [f.name for f in viewer.flags.items] == ["flag 2"] and viewer.flags.selected == 0
        assert [f.name for f in load_flags(viewer.flags.file)] == ["flag 2"]
        click_widget(viewer, "flag 1/delete")                # the selected flag itself: no selection left
        assert viewer.flags.items == [] and viewer.flags.selected == -1
        assert load_flags(viewer.flags.file) == []


def test_scroll_zooms_towards_the_pivot_and_double_click_sets_it(xvfb, tmp_path):
    with opened(open_grid_viewer, write_grid_model(tmp_path / "model.ply"), 640, 480) as viewer:
        press_key(viewer, glfw.KEY_TAB)                      # no panel: the whole window is the scene
        viewer.step()
        viewer.input.on_cursor(viewer.window, 320, 240)
        viewer.step()
        # Without orbit, the wheel sets the fly speed; with orbit (O) it zooms to the pivot.
        speed = viewer.view.nav.speed
        viewer.input.on_scroll(viewer.window, 0.0, 2.0)
        assert viewer.view.nav.speed == pytest.approx(speed * 1.2 ** 2)
        press_key(viewer, glfw.KEY_O)
        pivot = viewer.view.nav.pivot.copy()
        distance = np.linalg.norm(viewer.view.nav.center - pivot)
        viewer.input.on_scroll(viewer.window, 0.0, 1.0)
        viewer.step()
        closer = np.linalg.norm(viewer.view.nav.center - pivot)
        assert closer == pytest.approx(distance * 0.85)
        viewer.input.on_scroll(viewer.window, 0.0, -2.0)
        assert np.linalg.norm(viewer.view.nav.center - pivot) > distance
        # Double-click on the grid (z = 0, in front of the layer at z = 0.6): the pivot jumps there.
        viewer.view.frame_model()
        viewer.step()
        camera = viewer.view.current_camera()
        target = np.array([0.5, 0.25, 0.0])
        x, y = _window_pixel(viewer, camera, target)
        before = viewer.view.nav.pivot.copy()
        _press(viewer, x, y)
        viewer.step()
        np.testing.assert_array_equal(viewer.view.nav.pivot, before)  # one click is no double-click
        _press(viewer, x, y)
        viewer.step()
        assert viewer.status == "orbit pivot set"
        assert abs(viewer.view.nav.pivot[2]) < 0.1 and np.linalg.norm(viewer.view.nav.pivot[:2] - target[:2]) < 0.15
        assert not np.allclose(viewer.view.nav.pivot, before)
        # A double-click on empty space leaves the pivot and says why.
        pivot = viewer.view.nav.pivot.copy()
        time.sleep(0.4)  # not a third click of the pair
        _press(viewer, 3, 3)
        _press(viewer, 3, 3)
        viewer.step()
        np.testing.assert_array_equal(viewer.view.nav.pivot, pivot)
        assert "no surface" in viewer.status


def _window_pixel(viewer, camera, point) -> tuple[float, float]:
    """Window position of world ``point`` [3] seen by ``camera`` (the current view)."""
    from inceptiongs.app.editing import project_means

    pixels, _ = project_means(np.asarray(point, np.float64)[None], camera)
    window_w, _ = glfw.get_window_size(viewer.window)
    scale = window_w / viewer.view.pixels.framebuffer_size[0]
    return float(pixels[0, 0] * scale), float(pixels[0, 1] * scale)


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    """The procedural demo scene (28 cameras, sparse points): a scene folder with cameras."""
    from demo_cases import copy_of_demo_scene

    return copy_of_demo_scene(tmp_path_factory.mktemp("user_events") / "scene")


def test_n_and_p_keys_step_through_the_training_cameras(xvfb, demo_scene):
    with opened(open_viewer, demo_scene, 320, 240) as viewer:
        cameras = viewer.view.cameras
        assert len(cameras) > 2 and viewer.view.camera_index == 0
        press_key(viewer, glfw.KEY_N)
        viewer.step()
        assert viewer.view.camera_index == 1
        np.testing.assert_allclose(viewer.view.nav.center, cameras[1].center, atol=1e-9)
        # Its viewing direction too.
        np.testing.assert_allclose(viewer.view.nav.rotation[2], cameras[1].rotation[2], atol=1e-9)
        press_key(viewer, glfw.KEY_P)
        press_key(viewer, glfw.KEY_P)  # before the first: the last
        viewer.step()
        assert viewer.view.camera_index == len(cameras) - 1
        np.testing.assert_allclose(viewer.view.nav.center, cameras[-1].center, atol=1e-9)


def test_reference_and_coverage_modes_from_the_combo_and_suggest_flags(xvfb, demo_scene):
    from inceptiongs.io.flags import load_flags

    with opened(open_viewer, demo_scene, 640, 480) as viewer:
        viewer.step()
        _collapse(viewer, "View")
        choose(viewer, "mode (1-6)", "reference")
        assert viewer.view.settings.mode == "reference"
        deadline = time.time() + 60
        while viewer.drawing.reference_psnr is None and time.time() < deadline:
            viewer.step()
        # The torch reference of the same view came back and was compared with the GL picture.
        assert viewer.drawing.reference_psnr is not None and viewer.drawing.reference_psnr > 15
        choose(viewer, "mode (1-6)", "coverage")
        assert viewer.view.settings.mode == "coverage"
        viewer.step()
        assert viewer.drawing.coverage.vmax > 0  # the counts were computed for the drawn colours
        assert not viewer.flags.items
        click_widget(viewer, "suggest flags (the 3 scarcest views)")
        names = [f.name for f in viewer.flags.items]
        assert names == ["scarce 1", "scarce 2", "scarce 3"], viewer.status
        assert [f.name for f in load_flags(viewer.flags.file)] == names
        assert viewer.view.settings.mode == "coverage"  # the suggestion leaves the mode as it was
        # Each suggested flag is one of the training views, named in the status line.
        centers = [c.center for c in viewer.view.cameras]
        for flag in viewer.flags.items:
            assert min(np.linalg.norm(flag.camera.center - c) for c in centers) < 1e-6
        assert viewer.status.startswith("flagged the scarcest views")


def test_crop_to_box_fit_box_frame_model_and_save_ply(xvfb, tmp_path):
    from inceptiongs.io.ply import read_ply

    model = write_grid_model(tmp_path / "model.ply")
    with opened(open_grid_viewer, model, 640, 480) as viewer:
        viewer.step()
        _collapse(viewer, "View", "Inspect", "Flags", "Training")
        click_widget(viewer, "Edit")
        click_widget(viewer, "crop box (drag its handles)")
        total = viewer.view.edit.count
        full_box = np.array(viewer.view.settings.crop_max) - np.array(viewer.view.settings.crop_min)
        type_into(viewer, "max", "0")                        # the box's max x typed: 0
        assert viewer.view.settings.crop_max[0] == 0.0
        click_widget(viewer, "crop to box")
        kept = viewer.view.edit.visible_arrays()["means"]
        assert 0 < viewer.view.edit.count < total and kept[:, 0].max() <= 1e-6
        click_widget(viewer, "fit to the model")             # the box around what is left
        fitted = np.array(viewer.view.settings.crop_max) - np.array(viewer.view.settings.crop_min)
        assert fitted[0] < 0.7 * full_box[0] and viewer.view.settings.crop_max[0] < 0.1
        # Save PLY: typed file name, a valid PLY with what is shown; the model's folder untouched.
        out = tmp_path / "out" / "cropped.ply"
        out.parent.mkdir()
        scroll_panel_to(viewer, "save PLY")                    # the panel's end, below a 480-pixel window
        type_into(viewer, "file", str(out))
        click_widget(viewer, "save PLY")
        rects = viewer.ui.rects
        assert out.is_file(), (viewer.status, viewer.editor.saving.path, rects["file"], rects["save PLY"])
        saved = read_ply(out)
        assert len(saved) == viewer.view.edit.count, viewer.status
        np.testing.assert_allclose(saved.numpy()["means"], kept, atol=1e-6)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["model.ply", "out"]
        # "frame the model (Home)": the model's centre mid-window, every kept splat in view.
        click_widget(viewer, "View")
        viewer.view.nav.orbit(80.0, 30.0)
        click_widget(viewer, "frame the model (Home)")
        camera = viewer.view.current_camera()
        from inceptiongs.app.editing import project_means

        pixels, _ = project_means(kept, camera)
        assert np.all((pixels >= 0) & (pixels <= [camera.width, camera.height]))
        np.testing.assert_allclose(viewer.view.nav.pivot, np.median(kept, axis=0), atol=1e-6)


def test_save_ply_of_a_scene_goes_beside_its_runs_never_the_scene_folder(xvfb, demo_scene):
    from inceptiongs.io.ply import read_ply

    before = sorted(p.relative_to(demo_scene) for p in demo_scene.rglob("*"))
    with opened(open_viewer, demo_scene, 640, 480) as viewer:
        viewer.step()
        _collapse(viewer, "View", "Inspect", "Flags", "Training")
        click_widget(viewer, "Edit")
        click_widget(viewer, "save PLY")                     # the default file: ./runs/NAME_saved
        default = Path.cwd() / "runs" / f"{demo_scene.name}_saved" / "edited.ply"
        assert len(read_ply(default)) == viewer.view.edit.count, viewer.status
        assert demo_scene not in default.parents
        inside = demo_scene / "edited.ply"
        type_into(viewer, "file", str(inside))
        click_widget(viewer, "save PLY")
        assert not inside.exists()
        assert "scene folder" in viewer.status and str(inside) in viewer.status
    assert sorted(p.relative_to(demo_scene) for p in demo_scene.rglob("*")) == before


def test_demo_scene_opens_z_up_shown_as_plus_z_and_orbits_level(xvfb, demo_scene):
    """The demo scene is built z up (inceptiongs/scene/demo.py) with level cameras on part of a
    circle: its up control shows "+Z" (it showed "tilted": the cameras' mean up leaned 13 deg),
    and an orbit drag keeps the horizon level about +Z."""
    with opened(open_viewer, demo_scene, 640, 480) as viewer:
        viewer.step()
        np.testing.assert_array_equal(viewer.view.up, [0.0, 0.0, 1.0])
        click_widget(viewer, "up, from the cameras")           # open the control, as a user looks
        choices = [label.split("/", 1)[1] for label in viewer.ui.rects if label.startswith("up, from the cameras/")]
        assert sorted(choices) == sorted(["+X", "-X", "+Y", "-Y", "+Z", "-Z"]), choices  # no "tilted" entry
        click_at(viewer, 600, 300)                               # a click beside it closes the list
        _hover(viewer, 600, 300)
        press_key(viewer, glfw.KEY_O)
        assert viewer.view.settings.orbit
        before = viewer.view.nav.rotation.copy()
        _drag(viewer, (520, 300), (630, 300))
        assert np.abs(viewer.view.nav.rotation - before).max() > 0.1
        assert abs(viewer.view.nav.rotation[0] @ [0.0, 0.0, 1.0]) < 1e-6  # the camera's right axis stays level
