"""The viewer leaves the CPU to the job: no frames while idle or paused, few while a job runs,
the reference comparison computed once per change. The real app under Xvfb, its own loop."""

from __future__ import annotations

import os
import time

import glfw
import pytest

from inceptiongs.app import pacing
from inceptiongs.app.pacing import MAX_TRAINING_WAIT_SECONDS, is_idle, training_frame_wait, wait_for_next_frame
from viewer_cases import MovingGridJob, open_viewer, opened, write_grid_model

pytestmark = pytest.mark.gl

# The tests that count the frames of idle loops shorten the idle wait (pacing.IDLE_WAIT_SECONDS,
# how long an idle loop sleeps before it looks again): what is checked is that a wait with no
# event and no change draws nothing, whatever its length. An idle loop of IDLE_CHECK_SECONDS holds
# at least one whole wait: a window that drew a frame every wait would draw at least one in it.
SHORT_IDLE_WAIT_SECONDS = 0.25
IDLE_CHECK_SECONDS = SHORT_IDLE_WAIT_SECONDS + 0.2


@pytest.fixture
def short_idle_waits(monkeypatch):
    monkeypatch.setattr(pacing, "IDLE_WAIT_SECONDS", SHORT_IDLE_WAIT_SECONDS)


def _loop(viewer, seconds: float) -> int:
    """The app's run() loop body for ``seconds``; returns the frames drawn."""
    frames, end = viewer.stats.frames, time.perf_counter() + seconds
    while time.perf_counter() < end:
        if wait_for_next_frame(viewer) is not False:  # False: nothing new to draw
            viewer.step()
    return viewer.stats.frames - frames


def _settle(viewer) -> None:
    """Let the last motion's / snapshot's refine happen."""
    deadline = time.perf_counter() + 10
    while not is_idle(viewer) and time.perf_counter() < deadline:
        viewer.step()
        time.sleep(0.05)


def test_idle_and_paused_cost_no_frames_and_a_running_job_few(xvfb, tmp_path, short_idle_waits):
    job = MovingGridJob()
    with opened(open_viewer, write_grid_model(tmp_path / "model.ply"), job_factory=lambda source: job) as viewer:
        viewer.step()
        _settle(viewer)
        assert _loop(viewer, 1.2) <= 2  # waits for events
        viewer.jobs.start_training()
        viewer.jobs.training_utilisation = 0.98  # the viewer draws ~2 % of the time
        assert not is_idle(viewer)
        for _ in range(3):
            viewer.step()  # a frame-time estimate
        wait = training_frame_wait(viewer.stats.frame_ms, viewer.jobs.training_utilisation)
        assert wait == pytest.approx(min(viewer.stats.frame_ms / 1000 * 49, MAX_TRAINING_WAIT_SECONDS), rel=1e-6)
        running = _loop(viewer, 1.5)
        assert 1 <= running <= 1.5 / wait + 2, (running, wait)
        assert viewer.view.model_version > 1  # the job's snapshots still reach the screen
        viewer.jobs.training.pause()
        _settle(viewer)
        assert is_idle(viewer) and viewer.jobs.training.alive
        steps = job.steps
        assert _loop(viewer, 1.2) <= 2
        assert job.steps == steps


def test_reference_mode_computes_its_comparison_once_per_change(xvfb, tmp_path, short_idle_waits):
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
        assert is_idle(viewer)
        assert _loop(viewer, 1.2) <= 2 and not calls  # nothing re-rendered while nothing changes
        viewer.view.settings.reference_view = "side by side"  # a change: one new comparison
        for _ in range(3):
            viewer.step()
        assert len(calls) == 1


def _cursor_to(viewer, x: float, y: float) -> None:
    """Move the X pointer (a warp, as xdotool's mousemove): GLFW delivers the motion, and the
    enter or leave, as events of the next wait."""
    glfw.set_cursor_pos(viewer.window, x, y)
    viewer.step()


def test_paused_stopped_and_finished_jobs_draw_no_frames_with_the_mouse_inside_or_outside(xvfb, tmp_path,
                                                                                          short_idle_waits):
    """Idle means idle: once the refine is done, nothing changes and nothing is drawn, whatever
    the job's state and wherever the mouse is; each of these cost a frame every wait before."""
    job = MovingGridJob()
    with opened(open_viewer, write_grid_model(tmp_path / "model.ply"), 800, 600,
                job_factory=lambda source: job) as viewer:
        viewer.step()
        viewer.jobs.start_training()
        _loop(viewer, 1.0)
        viewer.jobs.training.pause()
        for x, y in ((500, 300), (-200, -200)):  # inside (over the scene), outside the window
            _cursor_to(viewer, x, y)
            _settle(viewer)
            _loop(viewer, 0.5)  # the events of the move itself
            assert _loop(viewer, IDLE_CHECK_SECONDS) == 0, ("paused", x, y)
        steps = job.steps
        viewer.jobs.training.stop(timeout=10)
        _loop(viewer, 0.5)
        assert not viewer.jobs.training.alive and job.steps == steps
        _settle(viewer)
        _loop(viewer, 0.5)  # the closing line and the last snapshot's refine are drawn
        assert _loop(viewer, IDLE_CHECK_SECONDS) == 0, "stopped"
        rss = _rss_bytes()
        assert _loop(viewer, IDLE_CHECK_SECONDS) == 0 and _rss_bytes() - rss < 8e6  # no memory growth


def test_an_event_while_idle_draws_a_frame(xvfb, tmp_path, short_idle_waits):
    with opened(open_viewer, write_grid_model(tmp_path / "model.ply")) as viewer:
        viewer.step()
        _settle(viewer)
        assert _loop(viewer, 2 * IDLE_CHECK_SECONDS) == 0
        viewer.status = "a new line"  # a change the panel shows, without an event
        assert _loop(viewer, 2 * IDLE_CHECK_SECONDS) == 1  # one frame, then idle again for the waits after it
        glfw.set_window_size(viewer.window, 700, 500)  # a resize is an event: answered at once
        assert _loop(viewer, 0.3) >= 1


def _rss_bytes() -> int:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def test_the_benchmark_reports_idle_and_paused_cpu_and_memory(xvfb, short_idle_waits, monkeypatch, capsys):
    """benchmarks/bench_viewer.py --idle: its main() in this process (the app's loop it measures
    runs with the short idle wait); the rows' figures are the benchmark's to judge, here: every
    row is there and says what it measured."""
    import importlib.util
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_viewer.py"
    spec = importlib.util.spec_from_file_location("bench_viewer", script)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    monkeypatch.setattr(sys, "argv", [str(script), "--idle", "--idle-seconds", "0.3", "--settle-seconds", "0.2",
                                      "--size", "640x480", "--ply", "/nonexistent.ply"])
    capsys.readouterr()
    assert bench.main() == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if " CPU " in line]
    names = {(line.split("mouse")[0].strip(), line.split("mouse")[1].split()[0]) for line in rows}
    assert names == {(name, where) for name in ("idle, no job", "job paused", "job stopped")
                     for where in ("inside", "outside")}, out
    for line in rows:
        assert "frames in 0.3 s" in line and "memory" in line, line
