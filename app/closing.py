"""Closing the window while a job runs: no job is lost.

The close button with a job alive asks (stop and save / keep running in the background /
cancel). "Stop and save" stops the job through its control and keeps the window until the job's
final save (model.ply, then its last checkpoint) is written; "keep running" hides the window and
the process ends when the job does, one line saying where the results go. Ctrl+C and SIGTERM on
the viewer's process stop and save the job as they do the command line's (stop_signals.py); a
second one quits without waiting."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

from inceptiongs.live import JobControl

QUESTION = "a job is running"
STOP_AND_SAVE = "stop and save"
KEEP_RUNNING = "keep running in the background"
CANCEL = "cancel"
CHOICES = (STOP_AND_SAVE, KEEP_RUNNING, CANCEL)


def frame_loop_control() -> JobControl:
    """The window's stop control: its frame loop checks for a stop every frame, so it listens
    from the start (a signal asks to close and save, never quits at once)."""
    control = JobControl()
    control.listening.set()
    return control


@dataclass
class Closing:
    """state: "open" (no close asked), "asking" (the question shows), "stopping" (the job saves,
    then the window closes), "background" (window hidden, the job runs on), "closed".
    signals.stop: set by the first Ctrl+C / SIGTERM (stop_signals.stop_on_signals)."""

    state: str = "open"
    signals: JobControl = field(default_factory=frame_loop_control)
    stop_asked_at: float = 0.0   # perf_counter() of "stop and save" (the saving line counts from it)


def background_line(out_dir) -> str:
    """The one line printed when the window hides and the job runs on."""
    where = f"its results go to {out_dir}" if out_dir is not None else "it writes where it was started"
    return (f"the window is closed; the job keeps running in the background and {where}; this process ends "
            f"when it does (Ctrl+C stops it and saves)")


def choose(viewer, choice: str) -> None:
    """The user's answer to the question (CHOICES)."""
    import glfw  # noqa: PLC0415

    closing, jobs = viewer.closing, viewer.jobs
    if choice == CANCEL:
        closing.state = "open"
        viewer.status = "not closed: the job goes on"
    elif choice == STOP_AND_SAVE:
        stop_for_closing(viewer)
    elif choice == KEEP_RUNNING:
        closing.state = "background"
        glfw.hide_window(viewer.window)
        print(background_line(jobs.out_dir), file=sys.stderr, flush=True)


def stop_for_closing(viewer) -> None:
    """Stop the job (it saves model.ply and its checkpoint); the window closes once it has."""
    jobs = viewer.jobs
    viewer.closing.state = "stopping"
    viewer.closing.stop_asked_at = time.perf_counter()
    if jobs.alive:
        jobs.training.stop(timeout=0)  # asks and returns: the frames go on while it saves
        viewer.status = saving_line(jobs.out_dir, 0.0)


def saving_line(out_dir, seconds: float) -> str:
    """What the window says while the stopped job saves, before it closes."""
    where = f" in {out_dir}" if out_dir is not None else ""
    return (f"closing: saving the job's model.ply and a checkpoint{where} ({seconds:.0f} s); the window closes "
            "once they are on disk")


def keep_open(viewer) -> bool:
    """One look at the close button and the stop signals before a frame: whether the frame loop
    goes on. The close button with a job alive asks instead of closing."""
    import glfw  # noqa: PLC0415

    closing, jobs = viewer.closing, viewer.jobs
    if closing.signals.stop.is_set() and closing.state in ("open", "asking"):
        stop_for_closing(viewer)
    if closing.state == "stopping":
        if jobs.alive:   # frames until the job's final save is written, the seconds counted
            line = saving_line(jobs.out_dir, time.perf_counter() - closing.stop_asked_at)
            if line != viewer.status:
                viewer.status = line
        return jobs.alive
    if closing.state == "background":
        return False
    if closing.state == "asking" and not jobs.alive:
        closing.state = "closed"  # the job ended while the question showed: close as asked
        return False
    if not viewer.should_close():
        return True
    if not jobs.alive:
        return False
    glfw.set_window_should_close(viewer.window, False)
    closing.state = "asking"
    return True


def wait_in_background(viewer, poll_s: float = 0.5) -> None:
    """With the window hidden: wait for the job's end (a stop signal stops it: it saves), then
    say how it ended, as the window's closing line would have (time, iteration, scores, folder)."""
    jobs, closing = viewer.jobs, viewer.closing
    while jobs.alive:
        if closing.signals.stop.is_set() and not jobs.training.control.stop.is_set():
            jobs.training.stop(timeout=0)
        jobs.training.join(poll_s)
    if jobs.training is not None:
        # The hidden window's frame loop no longer folds the job's snapshots into its progress:
        # the last one (the final iteration) is folded in here, or the line says an old one.
        jobs.training.poll()
        jobs.report_job_end()
        print(f"the job in the background ended: {viewer.status}", file=sys.stderr, flush=True)


def draw_question(viewer) -> None:
    """The modal question (imgui), its buttons' rectangles kept in viewer.ui.rects so a test
    clicks them as a user does."""
    from imgui_bundle import imgui  # noqa: PLC0415

    if viewer.closing.state != "asking":
        return
    if not imgui.is_popup_open(QUESTION):
        imgui.open_popup(QUESTION)
    width, height = imgui.get_io().display_size
    imgui.set_next_window_pos(imgui.ImVec2(width * 0.5, height * 0.5), imgui.Cond_.always, imgui.ImVec2(0.5, 0.5))
    if not imgui.begin_popup_modal(QUESTION, None, imgui.WindowFlags_.always_auto_resize)[0]:
        return
    out_dir = viewer.jobs.out_dir
    imgui.text(f"{viewer.jobs.training.plan.kind} is running" + (f" into {out_dir}" if out_dir else "") + ".")
    imgui.text("Stop it and save (model.ply and a checkpoint), let it finish with the window closed, or go back?")
    chosen = None
    for index, choice in enumerate(CHOICES):
        if index:
            imgui.same_line()
        if imgui.button(choice):
            chosen = choice
        low, high = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        viewer.ui.rects[choice] = (low.x, low.y, high.x, high.y)
    if chosen is not None:
        imgui.close_current_popup()
        choose(viewer, chosen)
    imgui.end_popup()
