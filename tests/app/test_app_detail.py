"""Level of detail in the window (app/detail.py): a large model is drawn as a cut of its tree,
budgeted while the camera moves, the 1-pixel cut once it is still, every Gaussian on request.

The real app under Xvfb on a ground plane of 40,000 small Gaussians running from the camera to
the horizon (the far ones are sub-pixel, so a cut merges them); the threshold for "large" is
lowered to 10,000 so the model builds its tree in a second."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from inceptiongs.app import detail
from inceptiongs.app.navigation import NavigationState
from inceptiongs.app.pacing import is_idle, wait_for_next_frame
from inceptiongs.camera import Camera, look_at
from inceptiongs.evaluation.metrics import psnr
from inceptiongs.gaussians import Gaussians
from viewer_cases import click_widget, open_viewer, opened, scroll_panel_to

SIDE = 200  # Gaussians per side of the ground plane


def ground_plane(side: int = SIDE) -> dict:
    """side^2 small flat Gaussians on the plane y = 1 over x in [-4, 4], z in [1.5, 200], in a
    colour ramp along both axes. Arrays as Gaussians.numpy()."""
    xs, zs = np.meshgrid(np.linspace(-4, 4, side), np.geomspace(1.5, 200, side))
    n = xs.size
    means = np.stack([xs.ravel(), np.ones(n), zs.ravel()], 1).astype(np.float32)
    size = math.log(0.6 * 8.0 / side)   # as wide as the rows are apart near the camera
    log_scales = np.tile(np.float32([size, math.log(1e-3), size]), (n, 1))
    rgb = np.stack([0.5 + 0.4 * np.sin(xs.ravel() * 2.0), 0.5 + 0.4 * np.cos(zs.ravel() * 0.5),
                    np.full(n, 0.4)], 1)
    return {"means": means, "log_scales": log_scales, "quats": np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
            "opacity_logits": np.full(n, 3.0, np.float32),
            "sh": ((rgb - 0.5) / 0.28209479177387814)[:, None, :].astype(np.float32)}


def street_camera(width: int, height: int) -> Camera:
    """Standing above the plane near its front edge, looking along it to the horizon."""
    pose = look_at(np.array([0.0, 0.4, 0.0]), np.array([0.0, 0.9, 12.0]), np.array([0.0, -1.0, 0.0]))
    focal = 0.8 * width
    return Camera("street", width, height, focal, focal, width / 2, height / 2, pose)


@pytest.fixture
def large_model(tmp_path, monkeypatch):
    from inceptiongs.io.ply import write_ply

    monkeypatch.setattr(detail, "LOD_MIN_GAUSSIANS", 10_000)
    path = tmp_path / "ground.ply"
    write_ply(Gaussians.from_numpy(ground_plane()), path)
    return path


def _run_until(viewer, done, seconds: float = 60.0) -> None:
    """The app's own loop until ``done()`` holds (fails after ``seconds``)."""
    deadline = time.perf_counter() + seconds
    while not done():
        assert time.perf_counter() < deadline, f"not reached in {seconds} s: {viewer.drawing.drawn}"
        if wait_for_next_frame(viewer):
            viewer.step()


def _settled(viewer) -> bool:
    key = viewer.drawing.last_render_key
    return "settled" in viewer.drawing.drawn[2] and key is not None and key[2] == 1.0


def _look_down_the_street(viewer) -> None:
    width, height = viewer.view.pixels.framebuffer_size
    viewer.view.nav = NavigationState.from_camera(street_camera(width, height), speed=1.0)
    viewer.view.moved()


@pytest.mark.gl
def test_a_large_model_is_drawn_as_a_cut_that_settles_on_the_full_render(xvfb, large_model, monkeypatch):
    monkeypatch.setattr(detail, "BUDGET_MAX", 8_000)   # this small model's frames are fast: keep a cut
    with opened(open_viewer, large_model, 480, 360) as viewer:
        total = SIDE * SIDE
        viewer.step()
        _look_down_the_street(viewer)
        _run_until(viewer, lambda: _settled(viewer))
        drawn, shown_total, how = viewer.drawing.drawn
        assert shown_total == total and how.startswith("settled")
        assert drawn < 0.8 * total   # the sub-pixel far end is merged
        assert viewer.ui.texts["detail"] == [f"drawn {drawn:,} / {total:,} splats", how]
        # The unedited model is held once: the tree's leaves are the model shown (Morton order).
        tree = viewer.drawing.detail.hierarchy
        shown = viewer.view.edit.base
        assert np.shares_memory(shown["means"], tree.means) and viewer.view.source.gaussians is shown
        original = ground_plane()
        for name in ("means", "sh"):
            rows = lambda a: np.sort(a.reshape(len(a), -1).view(np.dtype((np.void, a[0].nbytes))).ravel())  # noqa: E731
            assert np.array_equal(rows(np.ascontiguousarray(shown[name])), rows(original[name]))
        settled = viewer.renderer.render(viewer.view.current_camera(), "rgb").astype(np.float64)

        # Moving: a budgeted cut at the moving size, the budget in the panel.
        budgets = []
        for _ in range(12):
            viewer.view.nav.orbit(10.0, 0.0)
            viewer.view.moved()
            viewer.step()
            time.sleep(0.02)   # the worker's cut for this camera
            budgets.append(viewer.drawing.drawn)
        moving = [d for d in budgets if d[2].startswith("budget")]
        assert moving, budgets
        count, _, how = moving[-1]
        assert count <= int(how.split()[1].replace(",", "")) <= 8_000
        assert viewer.ui.texts["detail"][0] == f"drawn {viewer.drawing.drawn[0]:,} / {total:,} splats"

        # Still again at the first camera: the settled frame, then every Gaussian on request.
        _look_down_the_street(viewer)
        _run_until(viewer, lambda: _settled(viewer))
        again = viewer.renderer.render(viewer.view.current_camera(), "rgb").astype(np.float64)
        assert np.array_equal(again, settled)   # the cut depends on the camera only
        scroll_panel_to(viewer, "full detail always")
        click_widget(viewer, "full detail always")
        assert viewer.view.settings.full_detail
        _run_until(viewer, lambda: viewer.drawing.drawn == (total, total, "full detail")
                   and viewer.drawing.last_render_key is not None and viewer.drawing.last_render_key[2] == 1.0)
        full = viewer.renderer.render(viewer.view.current_camera(), "rgb").astype(np.float64)
        assert viewer.renderer.count == total
        click_widget(viewer, "full detail always")   # off again: the settled cut comes back
        _run_until(viewer, lambda: _settled(viewer) and viewer.renderer.count == drawn)
        assert psnr(settled, full) >= 40.0
        assert np.abs(settled - full).max() > 0.0   # it is a cut, not the model itself


@pytest.mark.gl
def test_the_window_draws_a_preview_while_the_tree_builds(xvfb, large_model, monkeypatch):
    built = []
    real_build = detail.DetailWorker._build

    def slow_build(self, version, arrays):
        time.sleep(1.0)   # a model of millions: the tree takes a while
        built.append(version)
        real_build(self, version, arrays)

    monkeypatch.setattr(detail.DetailWorker, "_build", slow_build)
    monkeypatch.setattr(detail, "PREVIEW_COUNT", 5_000)
    with opened(open_viewer, large_model, 480, 360) as viewer:
        viewer.step()
        drawn, total, how = viewer.drawing.drawn
        assert (drawn, total) == (5_000, SIDE * SIDE) and how.startswith("preview, building the tree")
        assert not is_idle(viewer)   # the tree is to come
        began = time.perf_counter()
        _run_until(viewer, lambda: _settled(viewer))
        assert built and time.perf_counter() - began >= 0.5


@pytest.mark.gl
def test_small_models_and_the_coverage_mode_draw_every_gaussian(xvfb, large_model, monkeypatch):
    with opened(open_viewer, large_model, 320, 240) as viewer:
        viewer.view.settings.full_detail = True
        viewer.step()
        assert viewer.drawing.detail is None and viewer.renderer.count == SIDE * SIDE
    monkeypatch.setattr(detail, "LOD_MIN_GAUSSIANS", SIDE * SIDE + 1)
    with opened(open_viewer, large_model, 320, 240) as viewer:
        viewer.step()
        assert viewer.drawing.detail is None and viewer.drawing.drawn[2] == "full detail"
        assert "detail" not in viewer.ui.texts   # no LOD line for a model that needs none


class _PlaneJob:
    """A stand-in training job on the large plane: publishes it nudged a little each step."""

    def run(self, box, control):
        step, plane = 0, ground_plane()
        while not control.stop.is_set():
            step += 1
            moved = dict(plane, means=plane["means"] + np.float32([0.001 * step, 0.0, 0.0]))
            box.publish(step, moved, {"loss": 1.0 / step})
            time.sleep(0.1)


@pytest.mark.gl
def test_a_running_job_shows_a_subset_of_its_snapshots_and_the_tree_follows_when_it_stops(
        xvfb, large_model, monkeypatch):
    monkeypatch.setattr(detail, "PREVIEW_COUNT", 4_000)
    job = _PlaneJob()
    with opened(open_viewer, large_model, 480, 360, job_factory=lambda source: job) as viewer:
        viewer.step()
        _look_down_the_street(viewer)
        viewer.jobs.start_training()
        _run_until(viewer, lambda: viewer.view.model_version >= 3 and viewer.drawing.drawn[2] == "live snapshot")
        assert viewer.drawing.drawn[:2] == (4_000, SIDE * SIDE) and viewer.renderer.count == 4_000
        viewer.jobs.training.stop(timeout=30)
        version = viewer.view.model_version
        _run_until(viewer, lambda: _settled(viewer))
        # The tree of the last snapshot (one more may arrive as the job stops).
        assert viewer.drawing.detail.version[0] == viewer.view.model_version >= version
