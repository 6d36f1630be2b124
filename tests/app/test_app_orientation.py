"""Orientation: the up axis from the cameras or the model's dominant plane, a level
horizon when orbiting, the +-X/Y/Z control, "frame the model" (Home). The real app under Xvfb."""

from __future__ import annotations

import numpy as np
import pytest

from inceptiongs.app.navigation import UP_AXES, model_up
from viewer_cases import open_viewer, opened, synthetic_table, write_table_model


def test_model_up_is_the_dominant_planes_normal():
    table = synthetic_table()["means"]
    np.testing.assert_array_equal(model_up(table), [0, 0, 1])
    # The same table stood on its side (the plane x = 0): +X; and in a y-down world: -Y.
    np.testing.assert_array_equal(model_up(table[:, [2, 0, 1]]), [1, 0, 0])
    np.testing.assert_array_equal(model_up(table[:, [0, 2, 1]] * [1, -1, 1]), [0, -1, 0])
    np.testing.assert_array_equal(model_up(np.zeros((2, 3))), [0, -1, 0])  # no plane: the default


def _red_and_grey_rows(image: np.ndarray) -> tuple[float, float]:
    red = (image[..., 0] > 0.5) & (image[..., 1] < 0.3)
    grey = (np.abs(image[..., 0] - image[..., 1]) < 0.05) & (image[..., 0] > 0.3)
    assert red.sum() > 20 and grey.sum() > 200
    return float(np.nonzero(red)[0].mean()), float(np.nonzero(grey)[0].mean())


@pytest.mark.gl
def test_a_model_without_cameras_opens_upright_and_orbits_level(xvfb, tmp_path):
    with opened(open_viewer, write_table_model(tmp_path / "table.ply"), 480, 360) as viewer:
        np.testing.assert_array_equal(viewer.view.up, [0, 0, 1])
        nav = viewer.view.nav
        up = viewer.view.up
        assert abs(nav.rotation[0] @ up) < 1e-9 and -nav.rotation[1] @ up > 0.3  # level, upright
        red_row, grey_row = _red_and_grey_rows(viewer.render_image())
        assert red_row < grey_row  # the block stands above the table
        np.testing.assert_allclose(nav.pivot, np.median(synthetic_table()["means"], axis=0), atol=1e-6)
        viewer.view.settings.orbit = True
        for _ in range(40):  # drag left-right around the model: no tumbling
            viewer.view.nav.orbit(25.0, 0.0)
        rotation, up = viewer.view.nav.rotation, viewer.view.up
        assert abs(rotation[0] @ up) < 1e-6 and -rotation[1] @ up > 0.3
        # The control: -Z turns the world over (the block hangs below the table).
        viewer.view.set_up(UP_AXES["-Z"])
        red_row, grey_row = _red_and_grey_rows(viewer.render_image())
        assert red_row > grey_row and viewer.view.up_source == "chosen"


@pytest.mark.gl
def test_home_key_frames_the_model(xvfb, tmp_path):
    import glfw

    with opened(open_viewer, write_table_model(tmp_path / "table.ply"), 480, 360, with_ui=False) as viewer:
        viewer.view.nav.center = viewer.view.nav.center - 30.0 * viewer.view.nav.rotation[2]  # far away: a dot
        forward = viewer.view.nav.rotation[2].copy()
        viewer.input.on_key(viewer.window, glfw.KEY_HOME, 0, glfw.PRESS, 0)
        viewer.input.on_key(viewer.window, glfw.KEY_HOME, 0, glfw.RELEASE, 0)
        np.testing.assert_allclose(viewer.view.nav.rotation[2], forward)  # same viewing direction
        coverage = viewer.render_image().max(axis=2) > 0.1
        rows, cols = np.nonzero(coverage)
        # The model fills the view without leaving it: its extent spans much of the narrower side.
        assert (rows.max() - rows.min()) > 0.5 * 360 or (cols.max() - cols.min()) > 0.5 * 480
        assert rows.min() > 0 and cols.min() > 0 and rows.max() < 359 and cols.max() < 479
