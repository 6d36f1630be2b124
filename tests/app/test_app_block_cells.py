"""The coverage mode of a run trained in blocks draws each block's cell (RUN/blocks.json) as an
outline on the ground, in the real window (Xvfb)."""

from __future__ import annotations

import json

import glfw
import numpy as np
import pytest

from demo_cases import copy_of_demo_scene
from viewer_cases import opened, press_key

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def blocks_run(tmp_path_factory):
    """A 6-step run of the demo scene with a 4-cell plan written as `train --blocks` writes it."""
    from inceptiongs.app.job_settings import JobSettings
    from inceptiongs.evaluation.protocols import Split
    from inceptiongs.scene.loader import load_scene
    from inceptiongs.train.blocks import PLAN_FILE, BlockPlan
    from inceptiongs.train.partition import balanced_cells, ground_plane
    from inceptiongs.train.trainer import train

    root = tmp_path_factory.mktemp("blocks")
    scene_dir = copy_of_demo_scene(root / "scene")
    run = root / "run"
    train(JobSettings(minutes=None, iterations=6, downscale=4).train_config(scene_dir), run, progress=False)
    scene = load_scene(scene_dir)
    split = Split.load(run / "split.json", scene.cameras)
    cameras = [scene.cameras[i] for i in split.train]
    plane = ground_plane(cameras)
    coords = plane.coordinates(np.stack([c.camera_to_world[:3, 3] for c in cameras]))
    cells = balanced_cells(coords, np.zeros((0, 2)), 4)
    plan = BlockPlan(plane, cells, [0.0] * 4, [[] for _ in cells], [0] * 4)
    (run / PLAN_FILE).write_text(json.dumps(plan.to_json()), encoding="utf-8")
    return run, plan


def _cyan(image: np.ndarray) -> np.ndarray:
    """[H, W] bool: pixels of the cells' colour (block_cells.CELL_COLOR)."""
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    return (r < 0.45) & (g > 0.7) & (b > 0.8)


def test_coverage_mode_outlines_the_cells_of_a_run_trained_in_blocks(xvfb, blocks_run):
    from inceptiongs.app.block_cells import cell_outline_segments
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer

    run, plan = blocks_run
    with opened(Viewer, open_source(run), 900, 700) as viewer:
        viewer.view.settings.show_panel = False
        viewer.view.settings.show_training_cameras = False
        viewer.view.settings.show_flags = False
        viewer.step()
        rgb = viewer.capture_window()
        press_key(viewer, glfw.KEY_6)
        assert viewer.view.settings.mode == "coverage"
        viewer.step()
        coverage = viewer.capture_window()
        # Drawn in the coverage mode only, and in the cells' colour.
        assert _cyan(coverage).mean() > 5 * _cyan(rgb).mean() + 1e-4, (_cyan(coverage).mean(), _cyan(rgb).mean())
        view = viewer.view
        segments = view.block_cells.of_model(view.source, view.model_version, view.edit.base["means"], view.up,
                                             view.status)
        assert segments.shape == (16, 2, 3)
    # The outlines: each cell's four sides, in the plane's coordinates the cell's own (outer
    # sides at the model's extent), all at one height along the plane's normal.
    means = np.random.default_rng(0).normal(size=(500, 3))
    segments = cell_outline_segments(plan, means, plan.plane.up)
    heights = (segments.reshape(-1, 3) - plan.plane.origin) @ plan.plane.up
    assert np.ptp(heights) < 1e-9
    for index, cell in enumerate(plan.cells):
        corners = plan.plane.coordinates(segments[4 * index:4 * index + 4, 0])
        for side, value in ((0, cell.u0), (0, cell.u1), (1, cell.v0), (1, cell.v1)):
            if abs(value) < 1e8:
                assert np.isclose(corners[:, side], value).sum() == 2, (index, side, value)
