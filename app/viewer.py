"""The desktop viewer/editor: owns the window, the GL renderer and the state objects of one
source, and runs the frame loop.

The state is in a few objects, each changed by the panel and the input that edit it:
:class:`view.View` (camera, render settings, the model shown), :class:`flags.FlagBook`,
:class:`editing.Editor` (selection, crop box, saving) and :class:`jobs.Jobs` (the live job, the
open run). One frame (:meth:`Viewer.step`): poll events -> move the camera -> take the newest
training snapshot -> draw the splats (drawing.py) -> overlays -> panels (panels.py); whether a
frame is drawn at all is pacing.py's. Input arrives through :class:`input.InputController`, whose
handlers are the window's GLFW callbacks."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import glfw
import moderngl
import numpy as np

from inceptiongs.camera import Camera
from inceptiongs.io import flags as flag_io
from inceptiongs.io.images import write_image

from . import closing as closing_question
from .camera_path import PathEditor
from .closing import Closing
from .drawing import FrameDrawer
from .editing import Editor
from .flags import FlagBook
from .images import visualize
from .input import InputController
from .jobs import Jobs
from .moving import SelectionMover
from .pacing import shown_state, wait_for_next_frame
from .runs import fresh_file, saved_dir, window_title
from .settings import GL_MODE_NAMES, FrameStats, PanelState, StatusLine
from .sources import PointsWorker, ViewerSource
from .verdict import release_retired, render_verdict_images
from .view import View
from .window import create_imgui, create_window, destroy_imgui

def read_framebuffer(screen: moderngl.Framebuffer, width: int, height: int) -> np.ndarray:
    """The window's back buffer before the swap -> [H, W, 3] float in [0, 1], row 0 = top."""
    data = screen.read(viewport=(0, 0, width, height), components=3, alignment=1)
    image = np.frombuffer(data, np.uint8).reshape(height, width, 3)[::-1]
    return image.astype(np.float32) / 255.0


def panel_guess(with_ui: bool, width: int) -> float:
    """The window pixels the panel will cover at the left of a window ``width`` wide before it is
    first drawn (its default width; none without a UI), so the first view frames the scene beside it."""
    if not with_ui:
        return 0.0
    from .panels import PANEL_MARGIN, PANEL_WIDTH  # noqa: PLC0415 (imgui only with a UI)

    return float(min(PANEL_WIDTH + PANEL_MARGIN, 0.6 * width))


class Viewer:
    """Owns the window, GL resources and the state objects for one source: ``view``, ``flags``,
    ``editor``, ``jobs`` (see the module's docstring); ``ui``: what the panels remember."""

    def __init__(self, source: ViewerSource, width: int = 1280, height: int = 720, visible: bool = True,
                 job_factory=None, with_ui: bool = True, window=None, imgui_impl=None) -> None:
        """``window`` and ``imgui_impl``: a window (its context current) and its imgui, already
        showing (loading.open_with_progress opens them first); None: made here."""
        from inceptiongs.renderer.splats import SplatRenderer  # noqa: PLC0415 (GL only after a context exists)

        self.window = window if window is not None else create_window(width, height,
                                                                      f"InceptionGS — {source.path.name}", visible)
        self.ctx = moderngl.create_context()
        self.renderer = SplatRenderer(self.ctx)
        self.drawing = FrameDrawer(self.ctx, self.renderer)
        self.stats = FrameStats()
        self.status_line = StatusLine("; ".join(source.notes))
        self.view = View(source, self.window, self.renderer, self.status_line, panel_guess(with_ui, width))
        # The user's flags are their work: beside the runs (./runs/NAME_saved), not in the cache.
        self.flags = FlagBook(saved_dir(source, source.runs_dir) / flag_io.FLAGS_FILE_NAME, self.view,
                              self.status_line, earlier=flag_io.flags_path(source.work_dir))
        self.editor = Editor(self.view, self.status_line)
        self.mover = SelectionMover(self.view, self.status_line)  # the gizmo tool
        self.paths = PathEditor(self.view, self.status_line)  # keyframes, preview, video (camera_path.py)
        # job_factory: source -> job; None: the job dialog's stage-I training.
        self.jobs = Jobs(self.view, self.flags, self.status_line, self.update_title, job_factory)
        self.ui = PanelState()
        self.closing = Closing()  # the close button / a stop signal with a job alive (closing.py)
        self.last_gl_error: str | None = None
        self.title_state: str | None = None  # the job state the window title names
        self.capture_requested = False  # step() keeps the whole window's pixels (UI included)
        self.captured: np.ndarray | None = None
        self._last_frame_time = time.perf_counter()
        self.drawn_state: tuple | None = None  # pacing.shown_state when the last frame was drawn
        self.imgui_impl = imgui_impl if imgui_impl is not None else (create_imgui(self.window) if with_ui else None)
        self.points_worker = PointsWorker(source.scene.root) if source.points_pending else None
        self.input = InputController(self)
        self.input.install(self.window)
        self.update_title()

    @property
    def status(self) -> str:
        """The status line's text (the answer to the last action)."""
        return self.status_line.text

    @status.setter
    def status(self, text: str) -> None:
        self.status_line.text = text

    def update_title(self) -> None:
        """The window names the model shown: the file, or the job folder it comes from."""
        jobs = self.jobs
        self.title = window_title(self.view.source, jobs.run_dir, jobs.training, jobs.out_dir)
        self.title_state = None if jobs.training is None else jobs.training.state
        glfw.set_window_title(self.window, self.title)

    def take_points(self) -> None:
        """Show the triangulated points of a scene without sparse points once they are in."""
        worker = self.points_worker
        if worker is None or not worker.done:
            return
        self.points_worker = None
        splats, self.status = worker.result
        if splats is not None and self.jobs.training is None:
            self.view.show_model(splats, points=True)
            self.view.open_at_model()
            self.view.moved()

    # --- pictures --------------------------------------------------------------------------------
    def render_image(self, camera: Camera | None = None) -> np.ndarray:
        """The scene alone (no UI) at ``camera`` (default: the current view), [H, W, 3] RGB."""
        settings = self.view.settings
        camera = camera or self.view.current_camera()
        if self.view.shows_points:   # points as the window draws them (drawing.points_image)
            return self.drawing.points_image(self.view, camera)
        self.drawing.upload_model(self.view)
        mode = settings.mode if settings.mode != "reference" else "rgb"
        image = self.renderer.render(camera, mode=GL_MODE_NAMES[mode], background=settings.background,
                                     sh_degree_cap=settings.sh_degree_cap, splat_scale=settings.splat_scale)
        return visualize(image, mode)

    def save_screenshot(self, path: str | Path | None = None) -> Path:
        """The scene at window size (render_image) to ``path`` (default: view-<time>.png beside
        the runs), never over an existing file (two in one second: view-<time>_2.png)."""
        if path is None:
            stamp = time.strftime("%Y%m%d-%H%M%S")
            source = self.view.source
            path = saved_dir(source, source.runs_dir) / f"view-{stamp}.png"  # beside the runs, not in the cache
        path = fresh_file(Path(path))
        path.parent.mkdir(parents=True, exist_ok=True)
        write_image(path, self.render_image())  # at window size, in the extension's format
        self.status = f"screenshot saved to {path}"
        return path

    def capture_window(self) -> np.ndarray:
        """Draw one frame and return the window as shown, panels included: [H, W, 3] float."""
        self.capture_requested = True
        self.step()
        return self.captured

    # --- the frame loop --------------------------------------------------------------------------
    def step(self) -> None:
        """One frame."""
        glfw.poll_events()
        now = time.perf_counter()
        seconds = min(now - self._last_frame_time, 0.25)  # a stalled frame must not teleport
        self._last_frame_time = now
        self.input.update_fly(seconds)
        self.paths.update()
        self.status_line.check()   # a message whose state has gone is cleared before it is drawn
        self.take_points()
        if self.jobs.training is not None and self.jobs.training.state != self.title_state:
            self.update_title()  # running -> paused -> finished shows in the title
        self.jobs.take_snapshot()
        if self.jobs.verdict_images_due and render_verdict_images(self.jobs, self.view, self.renderer, self.ctx):
            self.drawing.uploaded_version = None  # the shown model goes back to the renderer next draw
        screen = self.ctx.detect_framebuffer(0)
        screen.use()
        width, height = self.view.pixels.framebuffer_size
        self.ctx.viewport = (0, 0, width, height)
        if self.drawing.scene_texture.texture is None:
            # Later frames skip this full-window pass: the scene blit overwrites every pixel.
            screen.clear(*self.view.settings.background, 1.0)
        self.drawing.draw_scene(self.view, self.stats, self.jobs.last_snapshot_time, screen)
        self.drawing.draw_overlays(self.view, self.flags, self.jobs.poorly_fit.psnr, screen, self.mover.pivot_and_length())
        if self.imgui_impl is not None:
            self.draw_ui()
        release_retired(self.jobs.retired_textures)   # drawn by the frame just rendered, if at all
        if self.capture_requested:
            self.captured = read_framebuffer(screen, width, height)
            self.capture_requested = False
            # moderngl's read of the window sets the read buffer to a colour attachment, which GL
            # refuses for the default framebuffer (the pixels still come from the back buffer):
            # drop that error so it is neither shown nor raised by imgui's PyOpenGL later.
            _ = self.ctx.error
        glfw.swap_buffers(self.window)
        self.stats.add_frame(time.perf_counter() - now)
        self.drawn_state = shown_state(self)

    def draw_ui(self) -> None:
        from imgui_bundle import imgui  # noqa: PLC0415 (no imgui unless there is a UI)

        from .panels import draw_panels  # noqa: PLC0415

        self.note_gl_error()
        self.imgui_impl.process_inputs()
        imgui.new_frame()
        draw_panels(self)
        closing_question.draw_question(self)
        rect = self.ui.layout.get("rect") if self.view.settings.show_panel else None
        self.view.covered_left = float(rect[2]) if rect else 0.0  # Home frames the part right of it
        imgui.render()
        self.imgui_impl.render(imgui.get_draw_data())

    def note_gl_error(self) -> None:
        """PyOpenGL (used by imgui's backend) raises on any pending GL error, even one left by
        an earlier draw; read it here (which clears it) and show it in the panel instead."""
        error = self.ctx.error
        if error != "GL_NO_ERROR":
            self.last_gl_error = error

    def should_close(self) -> bool:
        return bool(glfw.window_should_close(self.window))

    def run_frame(self) -> bool:
        """One turn of the frame loop: the close button and stop signals are looked at
        (closing.py), then a frame is drawn unless an idle wait saw nothing change. -> whether
        the loop goes on."""
        if not closing_question.keep_open(self):
            return False
        if wait_for_next_frame(self):
            self.step()
        return True

    def run(self) -> int:
        """The frame loop until the window closes (and a job kept in the background ends).
        -> the exit status: 0, or 128 + the number of the signal that stopped it (130, 143)."""
        from inceptiongs.stop_signals import stop_on_signals  # noqa: PLC0415

        def say(line: str) -> None:
            if self.jobs.alive:  # the signal's line is about the job; without one it just closes
                print(line, file=sys.stderr, flush=True)

        wait_for_job = True
        with stop_on_signals(self.closing.signals, say) as request:
            try:
                while self.run_frame():
                    pass
                if self.closing.state == "background":
                    closing_question.wait_in_background(self)
            except KeyboardInterrupt:  # a second signal: quit without waiting for the save
                wait_for_job = False
                raise
            finally:
                self.close(wait_for_job)
        return request.exit_status

    def close(self, wait_for_job: bool = True) -> None:
        """Stop the job (it saves its model and checkpoint), the reference worker, and the window."""
        if self.jobs.training is not None:
            self.jobs.training.stop(timeout=60.0 if wait_for_job else 0)
        self.drawing.close()
        self.paths.close()
        self.jobs.set_verdict(None)  # its GL textures
        release_retired(self.jobs.retired_textures)
        if self.imgui_impl is not None:
            self.note_gl_error()  # PyOpenGL in imgui's shutdown raises on an error left pending
            destroy_imgui(self.imgui_impl)
            self.imgui_impl = None
        if self.window is not None:
            self.renderer.release()
            self.drawing.release()
            glfw.destroy_window(self.window)
            self.window = None
