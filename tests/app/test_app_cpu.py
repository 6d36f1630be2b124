"""The viewer leaves the CPU to the job: no frames while idle or paused, few while a job runs,
the reference comparison computed once per change. The real app under Xvfb, its own loop."""

from __future__ import annotations

import time

import pytest

from inceptiongs.app.viewer import MAX_TRAINING_WAIT_SECONDS
from viewer_cases import MovingGridJob, open_viewer, opened, write_grid_model

pytestmark = pytest.mark.gl


def _loop(viewer, seconds: float) -> int:
    """The app's run() loop body for ``seconds``; returns the frames drawn."""
    frames, end = viewer.stats.frames, time.perf_counter() + seconds
    while time.perf_counter() < end:
        viewer.wait_for_next_frame()
        viewer.step()
    return viewer.stats.frames - frames


def _settle(viewer) -> None:
    """Let the last motion's / snapshot's refine happen."""
    deadline = time.perf_counter() + 10
    while not viewer.is_idle() and time.perf_counter() < deadline:
        viewer.step()
        time.sleep(0.05)


def test_idle_and_paused_cost_no_frames_and_a_running_job_few(xvfb, tmp_path):
    job = MovingGridJob()
    with opened(open_viewer, write_grid_model(tmp_path / "model.ply"), job_factory=lambda source: job) as viewer:
        viewer.step()
        _settle(viewer)
        assert _loop(viewer, 1.2) <= 2  # waits for events (up to 2 s at a time)
        viewer.jobs.start_training()
        viewer.jobs.training_utilisation = 0.98  # the viewer draws ~2 % of the time
        assert not viewer.is_idle()
        for _ in range(3):
            viewer.step()  # a frame-time estimate
        wait = viewer.training_frame_wait()
        assert wait == pytest.approx(min(viewer.stats.frame_ms / 1000 * 49, MAX_TRAINING_WAIT_SECONDS), rel=1e-6)
        running = _loop(viewer, 1.5)
        assert 1 <= running <= 1.5 / wait + 2, (running, wait)
        assert viewer.view.model_version > 1  # the job's snapshots still reach the screen
        viewer.jobs.training.pause()
        _settle(viewer)
        assert viewer.is_idle() and viewer.jobs.training.alive
        steps = job.steps
        assert _loop(viewer, 1.2) <= 2
        assert job.steps == steps


def test_reference_mode_computes_its_comparison_once_per_change(xvfb, tmp_path):
    with opened(open_viewer, write_grid_model(tmp_path / "model.ply")) as viewer:
        viewer.view.settings.mode = "reference"
        deadline = time.perf_counter() + 60
        while not viewer.drawing.reference_settled() and time.perf_counter() < deadline:
            viewer.step()
        assert viewer.drawing.reference_settled() and viewer.drawing.reference_psnr > 30
        _settle(viewer)
        calls = []
        original = viewer.renderer.render
        viewer.renderer.render = lambda *a, **k: calls.append(1) or original(*a, **k)
        assert viewer.is_idle()
        assert _loop(viewer, 1.2) <= 2 and not calls  # nothing re-rendered while nothing changes
        viewer.view.settings.reference_view = "side by side"  # a change: one new comparison
        for _ in range(3):
            viewer.step()
        assert len(calls) == 1
