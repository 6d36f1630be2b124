"""When the frame loop draws. A window where nothing changes sleeps until an event arrives; a
running job gets the share of the CPU the user gave it between frames; threads working for the
window (the points, a video, the level of detail) get time before their result is due. Each
function takes the viewer.Viewer whose loop it paces."""

from __future__ import annotations

import time

import glfw

from .drawing import MODEL_STILL_SECONDS, STILL_SECONDS
from .settings import MAX_TRAINING_UTILISATION

# The loop sleeps in glfw.wait_events_timeout for up to this long when nothing is changing
# (no motion, no refine pending, no running job, no reference image awaited). Any event (input,
# an expose, a resize) ends the wait at once and a frame follows; a wait that times out draws a
# frame only when what the panels show changed meanwhile (shown_state): an idle window, a
# paused, stopped or finished job included, draws no frames at all.
IDLE_WAIT_SECONDS = 1.0
# After any input event the viewer draws frames for this long before it may sleep: imgui shows
# some answers a frame or two later (the help window, sized on its first frame, appears on the
# next; an opened combo; a hover), which an idle wait of up to IDLE_WAIT_SECONDS held back.
UI_SETTLE_SECONDS = 0.25
# While a job runs the viewer waits at most this long between frames (its snapshots show).
MAX_TRAINING_WAIT_SECONDS = 0.5
# While the level-of-detail thread works and the camera is still, the loop looks this often
# whether its cut arrived (the settled frame follows it at once).
DETAIL_WAIT_SECONDS = 0.02


def is_idle(viewer) -> bool:
    """Nothing will change without an event: no motion or refine pending, no fly key
    held, no job running, no reference image awaited."""
    now = time.perf_counter()
    if now - viewer.view.last_motion < STILL_SECONDS + 0.1 or viewer.input.keys_down:
        return False
    if viewer.drawing.still_frame_owed:
        return False  # the last frame was a moving one: its refine is still to be drawn
    if now - viewer.input.last_event < UI_SETTLE_SECONDS:
        return False  # imgui answers some input on a later frame (a window it sizes first, a hover)
    if imgui_input_queued(viewer):
        return False  # keys typed faster than frames are drawn: imgui takes them over several
    if viewer.drawing.coverage.counting is not None:
        return False  # the coverage counts go on a slice a frame
    if now - viewer.jobs.last_snapshot_time < MODEL_STILL_SECONDS + 0.1:
        return False  # the refine of the last snapshot is still to come
    if viewer.jobs.running():
        return False  # a paused job is idle: it publishes nothing
    if viewer.points_worker is not None:
        return False  # the triangulated points are to come
    if viewer.paths.busy():
        return False  # a path preview flies, or a video's progress is to show
    if viewer.drawing.detail_busy():
        return False  # a level-of-detail tree or cut is to come
    return viewer.view.settings.mode != "reference" or viewer.drawing.reference_settled()


def imgui_input_queued(viewer) -> bool:
    """Whether imgui still holds input events for later frames: it trickles a frame's queued
    events (a key's press and release, the characters typed with it) over several frames, and an
    idle loop showed a field with half of what was typed until the next event."""
    impl = viewer.imgui_impl
    return impl is not None and len(impl.contexts[0].input_events_queue) > 0


def training_frame_wait(frame_ms: float, utilisation: float) -> float:
    """Seconds to leave to a running job after a frame of ``frame_ms`` milliseconds, for it to
    have the share ``utilisation`` (jobs.Jobs.training_utilisation) of the time."""
    # Capped below 1, so the share left to the viewer, 1 - share, is never 0.
    share = min(max(utilisation, 0.0), MAX_TRAINING_UTILISATION)
    return min(frame_ms / 1000.0 * share / (1.0 - share), MAX_TRAINING_WAIT_SECONDS)


def shown_state(viewer) -> tuple:
    """What the window shows that can change with no event: the status line, the title, the
    job's state and progress, the model shown, the points to come. An idle wait that times
    out with this unchanged has nothing new to draw."""
    run = viewer.jobs.training
    job = None if run is None else (run.state, run.progress.iteration, run.progress.gaussian_count,
                                    run.error, viewer.jobs.reported)
    return (viewer.status_line.text, viewer.title, job, viewer.view.model_version,
            viewer.points_worker is None, viewer.should_close())


def wait_for_next_frame(viewer) -> bool:
    """Sleep until input arrives or the next frame is due -> whether to draw it (Viewer.step
    polls what arrived). False only after an idle wait that saw no event and no change."""
    still = time.perf_counter() - viewer.view.last_motion >= STILL_SECONDS
    if is_idle(viewer):
        began = time.perf_counter()
        glfw.wait_events_timeout(IDLE_WAIT_SECONDS)
        return viewer.input.last_event >= began or shown_state(viewer) != viewer.drawn_state
    if viewer.jobs.running() and still:
        # A moving camera gets every frame.
        glfw.wait_events_timeout(training_frame_wait(viewer.stats.frame_ms, viewer.jobs.training_utilisation))
    elif viewer.points_worker is not None and still:
        glfw.wait_events_timeout(MAX_TRAINING_WAIT_SECONDS)  # the points' thread needs the CPU
    elif viewer.paths.render is not None and viewer.paths.render.running() and still:
        glfw.wait_events_timeout(MAX_TRAINING_WAIT_SECONDS)  # the video's child process needs the CPU
    elif viewer.drawing.detail_busy() and still:
        glfw.wait_events_timeout(DETAIL_WAIT_SECONDS)  # the LOD thread needs the CPU; its cut is soon due
    return True
