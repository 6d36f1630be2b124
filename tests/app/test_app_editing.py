"""Editing you can see: the rectangle, brush circle and lasso drawn while the tool is
used, selections in undo/redo, no flag lines across the window. The real app under Xvfb, events
injected as GLFW delivers them."""

from __future__ import annotations

import glfw
import numpy as np
import pytest

from viewer_cases import open_grid_viewer, opened, write_grid_model

pytestmark = pytest.mark.gl


def _magenta(image: np.ndarray) -> np.ndarray:
    """Where the tool outline (the selection colour 1.0, 0.2, 0.9) is drawn."""
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    return (r > 0.8) & (g < 0.45) & (b > 0.7)


def _press(viewer, x, y, button=glfw.MOUSE_BUTTON_LEFT):
    viewer.input.on_cursor(viewer.window, x, y)
    viewer.input.on_mouse_button(viewer.window, button, glfw.PRESS, 0)


def _release(viewer, button=glfw.MOUSE_BUTTON_LEFT):
    viewer.input.on_mouse_button(viewer.window, button, glfw.RELEASE, 0)


@pytest.fixture()
def viewer(xvfb, tmp_path):
    viewer = open_grid_viewer(write_grid_model(tmp_path / "model.ply"))
    viewer.view.settings.show_training_cameras = False
    # Step left so the grid sits right of the panel (which covers x < ~410).
    viewer.view.nav.center = viewer.view.nav.center - 1.3 * viewer.view.nav.rotation[0]
    viewer.step()
    yield viewer
    viewer.close()


def test_rectangle_is_drawn_while_dragging_and_its_selection_undoes(viewer):
    viewer.view.settings.edit_tool = "rectangle"
    _press(viewer, 450, 120)
    viewer.input.on_cursor(viewer.window, 600, 330)
    magenta = _magenta(viewer.capture_window())
    assert magenta[119:122, 470:580].any(axis=0).mean() > 0.9   # the top edge, end to end
    assert magenta[200:300, 598:603].any(axis=1).mean() > 0.9   # the right edge
    assert not magenta[200:300, 480:570].any()                   # nothing inside it
    _release(viewer)
    selected = viewer.view.edit.selected.copy()
    assert selected.any()
    viewer.input.on_key(viewer.window, glfw.KEY_Z, 0, glfw.PRESS, glfw.MOD_CONTROL)
    assert not viewer.view.edit.selected.any()  # the selection is an undo step
    viewer.input.on_key(viewer.window, glfw.KEY_Y, 0, glfw.PRESS, glfw.MOD_CONTROL)
    np.testing.assert_array_equal(viewer.view.edit.selected, selected)


def test_brush_circle_follows_the_cursor(viewer):
    viewer.view.settings.edit_tool = "brush"
    viewer.view.settings.brush_radius = 40.0
    viewer.input.on_cursor(viewer.window, 520, 240)
    magenta = _magenta(viewer.capture_window())
    for dx, dy in ((40, 0), (-40, 0), (0, 40), (0, -40)):
        assert magenta[240 + dy - 2: 240 + dy + 3, 520 + dx - 2: 520 + dx + 3].any(), (dx, dy)
    assert not magenta[225:256, 505:536].any()  # the inside stays clear


def test_lasso_is_drawn_and_selects_what_it_encloses(viewer):
    from inceptiongs.app import editing

    viewer.view.settings.edit_tool = "lasso"
    corners = [(430, 100), (630, 100), (630, 380), (430, 380)]
    _press(viewer, *corners[0])
    for x, y in corners[1:]:
        viewer.input.on_cursor(viewer.window, x, y)
    magenta = _magenta(viewer.capture_window())
    assert magenta[98:103, 450:610].any(axis=0).mean() > 0.9  # the first side of the path
    _release(viewer)
    pixels, _ = viewer.editor.projected_means()
    expected = editing.select_rectangle(pixels, corners[0], corners[2])
    assert expected.any()
    np.testing.assert_array_equal(viewer.view.edit.selected, expected)


def test_a_flag_made_here_draws_no_lines_across_the_window(viewer):
    viewer.input.on_key(viewer.window, glfw.KEY_F, 0, glfw.PRESS, 0)
    # A nudge (a fraction of the flag's drawn size): its frustum is around the eye.
    nav = viewer.view.nav
    nav.center = nav.center + 0.02 * nav.rotation[0] - 0.01 * nav.rotation[2]
    image = viewer.capture_window()
    flag_red = (image[..., 0] > 0.9) & (np.abs(image[..., 1] - 0.3) < 0.1) & (np.abs(image[..., 2] - 0.2) < 0.1)
    assert flag_red[:, 420:].sum() < 20
    # Step back and left: the flag stands ahead, right of the panel, and is drawn.
    nav.center = nav.center - 2.0 * nav.rotation[2] - 0.8 * nav.rotation[0]
    flag_red = (lambda im: (im[..., 0] > 0.9) & (np.abs(im[..., 1] - 0.3) < 0.1))(viewer.capture_window())
    assert flag_red[:, 420:].sum() >= 20


def test_crop_box_fits_the_model_and_its_handles_drag(xvfb, tmp_path):
    from inceptiongs.app.editing import box_handles, project_means
    from viewer_cases import open_viewer, write_table_model

    with opened(open_viewer, write_table_model(tmp_path / "table.ply"), 900, 600) as viewer:
        viewer.view.settings.show_training_cameras = False
        nav = viewer.view.nav
        nav.center = nav.center - 1.2 * nav.rotation[0]  # the model right of the panel
        viewer.editor.enable_crop()
        lo, hi = np.array(viewer.view.settings.crop_min), np.array(viewer.view.settings.crop_max)
        # Fitted to the table (x, y in [-1, 1], z in [0, 0.5]), not a fixed +-1 cube.
        assert -1.2 < lo[0] < -0.8 and 0.8 < hi[0] < 1.2 and -0.1 < lo[2] < 0.05 and 0.4 < hi[2] < 0.6
        handles, _ = project_means(box_handles(lo, hi), viewer.view.current_camera())
        image = viewer.capture_window()
        x, y = handles[5]  # the top face's handle: drawn as a green square
        patch = image[int(y) - 2: int(y) + 3, int(x) - 2: int(x) + 3]
        assert ((patch[..., 1] > 0.8) & (patch[..., 0] < 0.5)).any()
        # Drag the top face's handle up by 40 px: the box grows upward, nothing else moves.
        _press(viewer, x, y)
        assert viewer.input.crop_handle == 5
        viewer.input.on_cursor(viewer.window, x, y - 40)
        _release(viewer)
        new_lo, new_hi = np.array(viewer.view.settings.crop_min), np.array(viewer.view.settings.crop_max)
        assert new_hi[2] > hi[2] + 0.05
        np.testing.assert_allclose(new_lo, lo)
        np.testing.assert_allclose(new_hi[:2], hi[:2])
        assert not viewer.view.edit.selected.any()  # grabbing a handle did not look around or select
