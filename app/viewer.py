"""The desktop viewer/editor: owns one source's state and wires the window, input, drawing
and panels together.

One frame (:meth:`Viewer.step`): poll events -> move the camera -> take the newest training
snapshot -> draw the splats (drawing.py) -> overlays -> panels (panels.py). Input arrives
through :class:`input.InputController`, whose handlers are the window's GLFW callbacks."""

from __future__ import annotations

import time
from pathlib import Path

import glfw
import moderngl
import numpy as np

from inceptiongs.camera import Camera, pose_distance
from inceptiongs.errors import InputError
from inceptiongs.gaussians import Gaussians
from inceptiongs.io import flags as flag_io
from inceptiongs.io.images import write_image
from inceptiongs.train.view_fit import read_poorly_fit

from . import editing, flags as flagging
from .coverage_mode import SUGGESTED_FLAGS, CoverageMode
from .drawing import MODEL_STILL_SECONDS, STILL_SECONDS, FrameDrawer
from .images import visualize
from .input import InputController
from .jobs import JobSettings, resume_job_for, train_job_for
from .live_training import LiveTraining
from .navigation import NavigationState, default_view, estimate_up, framed, leveled, model_up
from .progress import closing_line, final_scores, format_duration, plan_of
from .runs import describe_model, run_dir_of
from .settings import GL_MODE_NAMES, MAX_TRAINING_UTILISATION, FrameStats, ViewSettings
from .sources import PointsWorker, ViewerSource, open_scene_run
from .window import create_imgui, create_window, destroy_imgui

# While a job trains, its snapshots replace the model at most this often: each one costs a
# re-render, and the job publishes faster than software GL can draw them.
TRAINING_REFRESH_SECONDS = 0.3
# run() sleeps in glfw.wait_events_timeout for up to this long when nothing is changing
# (no motion, no refine pending, no running job, no reference image awaited): an idle window
# costs no frames. Any input event ends the wait at once; the timeout only refreshes the
# panel's figures now and then.
IDLE_WAIT_SECONDS = 2.0
# A crop-box handle is grabbed within this many pixels of the cursor.
CROP_HANDLE_PIXELS = 12.0
# After any input event the viewer draws frames for this long before it may sleep: imgui shows
# some answers a frame or two later (the help window, sized on its first frame, appears on the
# next; an opened combo; a hover), which an idle wait of up to IDLE_WAIT_SECONDS held back.
UI_SETTLE_SECONDS = 0.25
# While a job runs the viewer waits at most this long between frames (its snapshots show).
MAX_TRAINING_WAIT_SECONDS = 0.5


def read_framebuffer(screen: moderngl.Framebuffer, width: int, height: int) -> np.ndarray:
    """The window's back buffer before the swap -> [H, W, 3] float in [0, 1], row 0 = top."""
    data = screen.read(viewport=(0, 0, width, height), components=3, alignment=1)
    image = np.frombuffer(data, np.uint8).reshape(height, width, 3)[::-1]
    return image.astype(np.float32) / 255.0


class Viewer:
    """Owns the window, GL resources and all UI state for one source."""

    def __init__(self, source: ViewerSource, width: int = 1280, height: int = 720, visible: bool = True,
                 job_factory=None, with_ui: bool = True) -> None:
        from inceptiongs.renderer.splats import SplatRenderer  # noqa: PLC0415 (GL only after a context exists)

        self.source = source
        self.window = create_window(width, height, f"InceptionGS — {source.path.name}", visible)
        self.ctx = moderngl.create_context()
        self.renderer = SplatRenderer(self.ctx)
        self.drawing = FrameDrawer(self.ctx, self.renderer)
        self.coverage = CoverageMode()  # counts computed when the coverage mode is first drawn
        self.settings = ViewSettings()
        self.stats = FrameStats()
        self.edit = editing.EditState(source.gaussians)
        self.model_version = 1
        self.cameras = source.cameras
        # Up: the cameras' mean up, else the model's dominant plane; the View panel may change it.
        self.up = estimate_up(self.cameras) if self.cameras else model_up(source.gaussians["means"])
        self.up_source = "from the cameras" if self.cameras else "from the model"
        self.nav = self.initial_view()
        self.home = self.nav.copy()
        self.camera_index = 0 if self.cameras else -1
        self.flags_file = flag_io.flags_path(source.work_dir)
        self.status = "; ".join(source.notes)
        try:
            self.flags = flag_io.load_flags(self.flags_file)
        except InputError as exc:
            self.flags, self.status = [], f"flags not loaded: {exc}"
        self.selected_flag = -1
        self.save_path = str(source.work_dir / "edited.ply")  # the Edit panel's "file" field
        self.last_gl_error: str | None = None
        self.job_factory = job_factory  # source -> job; None: the job dialog's stage-I training
        self.job_settings = JobSettings()
        self.training: LiveTraining | None = None
        self.run_dir = run_dir_of(source)  # the open run: what Resume continues, Bootstrap repairs
        # The open run's training photos it fits poorly (image name -> PSNR, worst first): their
        # frustums are drawn apart and the Training panel steps through them.
        self.poorly_fit: dict[str, float] = {}
        self.poorly_fit_shown = -1  # which of them "next poorly fit photo" went to last
        self.read_view_fit()
        self.job_out_dir: Path | None = None  # where the current (or last) job writes
        self.job_reported = False  # the closing line of the last job has replaced the status
        self.show_help = False  # the key-bindings overlay (H / F1)
        self.fold_job_settings = False  # panels.py closes the job dialog once a job has started
        self.ui_rects: dict[str, tuple] = {}  # panel button -> where it was last drawn (panels.py)
        self.panel_layout: dict = {}  # the panel's rectangle and how far its widgets reach (panels.py)
        self._photo_cache: tuple[int | None, np.ndarray | None] = (None, None)
        self.capture_requested = False  # step() keeps the whole window's pixels (UI included)
        self.captured: np.ndarray | None = None
        self.last_snapshot_time = -1e9  # when a job's snapshot last replaced the model
        self.last_motion = -1e9
        self._last_frame_time = time.perf_counter()
        self._frame_times: list[float] = []
        self.with_ui = with_ui
        self.imgui_impl = create_imgui(self.window) if with_ui else None
        self.points_worker = PointsWorker(source.scene.root) if source.points_pending else None
        self.input = InputController(self)
        self.input.install(self.window)
        self.update_title()

    # --- setup -------------------------------------------------------------------------------
    def initial_view(self) -> NavigationState:
        width, height = self.framebuffer_size
        means = self.source.gaussians["means"]
        if self.cameras:
            first = self.cameras[0]
            centers = np.stack([c.center for c in self.cameras])
            spread = float(np.linalg.norm(centers.max(0) - centers.min(0))) if len(centers) > 1 else 1.0
            nav = NavigationState.from_camera(first, up=self.up, speed=max(spread * 0.5, 1e-3))
            nav.pivot = np.median(means, axis=0) if len(means) else nav.pivot
            return nav
        return default_view(means, width, height, up=self.up)

    @property
    def framebuffer_size(self) -> tuple[int, int]:
        width, height = glfw.get_framebuffer_size(self.window)
        return max(width, 1), max(height, 1)

    def current_camera(self, scale: float = 1.0) -> Camera:
        width, height = self.framebuffer_size
        camera = self.nav.camera(width, height)
        return camera if scale == 1.0 else camera.scaled(1.0 / scale)

    def moved(self) -> None:
        """The camera changed: draw at the moving size until it has been still a moment."""
        self.last_motion = time.perf_counter()

    # --- screen-space helpers ----------------------------------------------------------------
    def window_to_framebuffer(self, x: float, y: float) -> tuple[float, float]:
        window_w, window_h = glfw.get_window_size(self.window)
        fb_w, fb_h = self.framebuffer_size
        return x * fb_w / max(window_w, 1), y * fb_h / max(window_h, 1)

    def pick_point(self, x: float, y: float) -> np.ndarray | None:
        """World point [3] of the surface under window position (x, y), None if empty."""
        px, py = self.window_to_framebuffer(x, y)
        camera = self.current_camera()
        depth = self.renderer.pick_depth(camera, int(px), int(py))
        if depth is None:
            return None
        return flagging.unproject_pixel(camera, int(px), int(py), depth)

    # --- training photos ------------------------------------------------------------------------
    def nearest_camera_index(self, camera: Camera) -> int | None:
        """The training camera closest to ``camera`` (centre distance + viewing angle), or None."""
        if not self.cameras:
            return None
        distances = [pose_distance(camera.world_to_camera, c.world_to_camera) for c in self.cameras]
        return int(np.argmin(distances))

    def training_photo(self, index: int) -> np.ndarray | None:
        """The photo of training camera ``index`` [H, W, 3] in [0, 1] (the last one is kept), or
        None when the source has no scene photos or the file cannot be read."""
        if self.source.scene is None:
            return None
        if self._photo_cache[0] != index:
            try:
                self._photo_cache = (index, self.source.scene.load_image(index))
            except (InputError, OSError) as exc:
                self.status = f"training photo not shown: {exc}"
                self._photo_cache = (index, None)
        return self._photo_cache[1]

    # --- navigation actions ------------------------------------------------------------------
    def snap_to_camera(self, index: int) -> None:
        if not self.cameras:
            return
        self.camera_index = index % len(self.cameras)
        camera = self.cameras[self.camera_index]
        speed, pivot = self.nav.speed, self.nav.pivot
        self.nav = NavigationState.from_camera(camera, up=self.up, speed=speed, pivot=pivot)
        self.moved()

    def reset_view(self) -> None:
        self.nav = self.home.copy()
        self.moved()

    def set_up(self, up) -> None:
        """A new world up [3] (the View panel's +-X/Y/Z): the view and home are re-levelled."""
        self.up = np.asarray(up, np.float64)
        self.up_source = "chosen"
        if self.cameras:
            self.nav = leveled(self.nav, self.up)
            self.home = leveled(self.home, self.up)
        else:  # no camera to keep: the home view is the default view for the new up
            self.home = self.initial_view()
            self.nav = self.home.copy()
        self.moved()

    def frame_model(self) -> None:
        """Fit the view to the model's robust bounds, looking the same way; pivot at its centre."""
        width, height = self.framebuffer_size
        self.nav = framed(self.nav, self.edit.visible_arrays()["means"], width / height)
        self.moved()

    def set_pivot_at_pixel(self, x: float, y: float) -> None:
        point = self.pick_point(x, y)
        if point is None:
            self.status = "double-click: no surface under the cursor"
            return
        self.nav.pivot = point
        self.settings.orbit = True
        self.status = "orbit pivot set"

    # --- flags -------------------------------------------------------------------------------
    def suggest_flags(self, k: int | None = None) -> list[str]:
        """Flag the k cameras whose content the other cameras see least (the coverage mode's
        suggestion); returns the new flags' names."""
        self.settings.mode, previous = "rgb", self.settings.mode
        self.drawing.upload_model(self)  # depth of the model itself, not of its coverage colours
        indices = self.coverage.suggest(self.edit.visible_arrays(), self.cameras, self.drawing.depth_of,
                                        SUGGESTED_FLAGS if k is None else k)
        self.settings.mode = previous
        names = []
        for index in indices:
            name = flagging.unique_flag_name(self.flags, prefix="scarce")
            self.flags.append(flagging.flag_camera(self.cameras[index], name))
            names.append(name)
        if names:
            self.save_flags()
        self.status = (f"flagged the scarcest views: {', '.join(self.cameras[i].name for i in indices)}"
                       if names else "no cameras to suggest flags from")
        return names

    def save_flags(self) -> None:
        flag_io.save_flags(self.flags_file, self.flags)

    def flag_current_view(self) -> None:
        name = flagging.unique_flag_name(self.flags)
        self.flags.append(flagging.flag_camera(self.current_camera(), name))
        self.save_flags()
        self.status = f"flagged the current view as {name!r}"

    def flag_view_at_pixel(self, x: float, y: float) -> None:
        point = self.pick_point(x, y)
        if point is None:
            self.status = "right-click: no surface under the cursor, nothing flagged"
            return
        name = flagging.unique_flag_name(self.flags)
        self.flags.append(flagging.flag_aimed_at(self.current_camera(), point, name))
        self.save_flags()
        self.status = f"flagged a view aimed at {np.round(point, 3).tolist()} as {name!r}"

    def rename_flag(self, index: int, name: str) -> None:
        """Rename flag ``index``, unless another flag has that name (the bootstrap names its
        targets and their files after the flags: two of one name would mix up)."""
        if any(other.name == name for number, other in enumerate(self.flags) if number != index):
            self.status = f"not renamed: a flag named {name!r} exists"
            return
        flag = self.flags[index]
        self.flags[index] = flag_io.Flag(name, flag.camera.with_pose(flag.camera.world_to_camera, name),
                                          flag.created)
        self.save_flags()

    def delete_flag(self, index: int) -> None:
        """Delete flag ``index``; the selection stays on the flag it was on (none if deleted)."""
        del self.flags[index]
        if self.selected_flag == index:
            self.selected_flag = -1
        elif self.selected_flag > index:
            self.selected_flag -= 1  # the selected flag moved up one row
        self.save_flags()

    def jump_to_flag(self, index: int) -> None:
        self.nav = NavigationState.from_camera(self.flags[index].camera, up=self.up, speed=self.nav.speed,
                                               pivot=self.nav.pivot)
        self.moved()

    # --- selection and editing ---------------------------------------------------------------
    def projected_means(self):
        return editing.project_means(self.edit.base["means"], self.current_camera())

    def rectangle_select(self, corner_a, corner_b) -> None:
        pixels, _ = self.projected_means()
        a = self.window_to_framebuffer(*corner_a)
        b = self.window_to_framebuffer(*corner_b)
        self.edit.select(editing.select_rectangle(pixels, a, b), self.settings.selection_mode)

    def lasso_select(self, points) -> None:
        """points: the lasso's window positions [(x, y), ...] (closed implicitly)."""
        pixels, _ = self.projected_means()
        polygon = np.array([self.window_to_framebuffer(x, y) for x, y in points]).reshape(-1, 2)
        self.edit.select(editing.select_lasso(pixels, polygon), self.settings.selection_mode)

    def brush_select(self, x: float, y: float, stroke_start: bool = True) -> None:
        """One dab of the brush; a drag's later dabs join its first one's undo step."""
        pixels, _ = self.projected_means()
        center = self.window_to_framebuffer(x, y)
        mode = "add" if self.settings.selection_mode == "replace" else self.settings.selection_mode
        self.edit.select(editing.select_brush(pixels, center, self.settings.brush_radius), mode,
                         record=stroke_start)

    def threshold_select(self) -> None:
        base = self.edit.base
        mask = editing.select_thresholds(base["opacity_logits"], base["log_scales"],
                                         self.settings.max_opacity, self.settings.min_size)
        self.edit.select(mask, self.settings.selection_mode)

    def delete_selection(self) -> None:
        if self.edit.delete_selected():
            self.status = f"deleted; {self.edit.count} Gaussians left"

    def fit_crop_box(self) -> None:
        """The crop box around the model's robust bounds (2-98 % of the shown means, 5 % margin)."""
        means = self.edit.visible_arrays()["means"]
        if len(means) == 0:
            return
        lo, hi = np.percentile(means, [2, 98], axis=0)
        margin = 0.05 * (hi - lo)
        self.settings.crop_min, self.settings.crop_max = (lo - margin).tolist(), (hi + margin).tolist()

    def enable_crop(self, enabled: bool = True) -> None:
        """Show the crop box; the first time, fitted to the model (not a fixed +-1)."""
        if enabled and self.settings.crop_min is None:
            self.fit_crop_box()
        self.settings.crop_enabled = enabled and self.settings.crop_min is not None

    def crop_handle_at(self, x: float, y: float) -> int | None:
        """The crop-box handle (editing.box_handles index) within CROP_HANDLE_PIXELS of window
        position (x, y), nearest first; None when the box is hidden or none is that close."""
        if not self.settings.crop_enabled:
            return None
        pixels, _ = editing.project_means(editing.box_handles(self.settings.crop_min, self.settings.crop_max),
                                          self.current_camera())
        distance = np.hypot(*(pixels - np.array(self.window_to_framebuffer(x, y))).T)
        distance = np.where(np.isnan(distance), np.inf, distance)
        best = int(np.argmin(distance))
        return best if distance[best] <= CROP_HANDLE_PIXELS else None

    def drag_crop_handle(self, handle: int, start, end) -> None:
        """Move a crop face by the mouse motion start -> end (window positions) projected on the
        face's axis as the screen shows it."""
        settings = self.settings
        point = editing.box_handles(settings.crop_min, settings.crop_max)[handle]
        axis = np.eye(3)[handle // 2]
        step = max(float(np.max(np.subtract(settings.crop_max, settings.crop_min))) * 0.01, 1e-6)
        pixels, _ = editing.project_means(np.stack([point, point + axis * step]), self.current_camera())
        screen_axis = (pixels[1] - pixels[0]) / step  # pixels per scene unit along the axis
        length2 = float(screen_axis @ screen_axis)
        if not np.isfinite(length2) or length2 < 1e-9:
            return  # the axis points at the eye: no screen direction to drag along
        motion = np.subtract(self.window_to_framebuffer(*end), self.window_to_framebuffer(*start))
        settings.crop_min, settings.crop_max = editing.drag_box_face(
            settings.crop_min, settings.crop_max, handle, float(motion @ screen_axis) / length2)

    def apply_crop(self) -> None:
        if self.edit.crop(np.array(self.settings.crop_min), np.array(self.settings.crop_max)):
            self.status = f"cropped; {self.edit.count} Gaussians left"

    def undo(self) -> None:
        self.edit.undo()

    def redo(self) -> None:
        self.edit.redo()

    # --- saving ------------------------------------------------------------------------------
    def save_ply(self, path: str | Path) -> Path:
        """Write the shown Gaussians (atomic). Models of a scene are stored in the scene's
        original frame, like the trainer's model.ply."""
        from inceptiongs.io.ply import write_ply  # noqa: PLC0415

        scene = self.source.scene
        path = Path(path).expanduser()
        if scene is not None and Path(scene.root).resolve() in [path.resolve(), *path.resolve().parents]:
            raise InputError(f"{path}: inside the scene folder {scene.root}, which is input and never written; "
                             f"save elsewhere (the default is the work folder {self.source.work_dir})")
        gaussians = Gaussians.from_numpy(self.edit.visible_arrays())
        if scene is not None:  # everything shown for a scene or run is in its normalised frame
            gaussians = scene.normalization.gaussians_to_original(gaussians)
        write_ply(gaussians, path)
        self.status = f"saved {len(gaussians)} Gaussians to {path}"
        return Path(path)

    def render_image(self, camera: Camera | None = None) -> np.ndarray:
        """The scene alone (no UI) at ``camera`` (default: the current view), [H, W, 3] RGB."""
        self.drawing.upload_model(self)
        camera = camera or self.current_camera()
        mode = self.settings.mode if self.settings.mode != "reference" else "rgb"
        image = self.renderer.render(camera, mode=GL_MODE_NAMES[mode], background=self.settings.background,
                                     sh_degree_cap=self.settings.sh_degree_cap,
                                     splat_scale=self.settings.splat_scale)
        return visualize(image, mode)

    def save_screenshot(self, path: str | Path | None = None) -> Path:
        if path is None:
            stamp = time.strftime("%Y%m%d-%H%M%S")
            path = self.source.work_dir / "screenshots" / f"view-{stamp}.png"
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_image(path, self.render_image())  # at window size, in the extension's format
        self.status = f"screenshot saved to {path}"
        return path

    def capture_window(self) -> np.ndarray:
        """Draw one frame and return the window as shown, panels included: [H, W, 3] float."""
        self.capture_requested = True
        self.step()
        return self.captured

    # --- the scene's runs ----------------------------------------------------------------------
    def open_run(self, run_dir: Path) -> None:
        """Show another run of the open scene (the Training panel's list): its model replaces the
        shown one, and it becomes the open run (Resume, Bootstrap). Not while a job runs."""
        if self.training is not None and self.training.alive:
            self.status = "a job is running: stop it before opening another run"
            return
        source = self.source
        try:
            opened = open_scene_run(source.path, source.work_dir, source.runs, Path(run_dir))
        except (InputError, OSError) as exc:
            self.status = f"run not opened: {exc}"
            return
        self.source, self.training, self.job_out_dir = opened, None, None
        self.edit = editing.EditState(opened.gaussians)
        self.model_version += 1
        self.run_dir = run_dir_of(opened)
        self.status = f"opened run {run_dir}"
        self.read_view_fit()
        self.update_title()
        self.moved()

    def read_view_fit(self) -> None:
        """The open run's poorly fit training photos (RUN/view_fit.json; none without one)."""
        self.poorly_fit, self.poorly_fit_shown = {}, -1
        if self.run_dir is None:
            return
        try:
            self.poorly_fit = read_poorly_fit(self.run_dir)
        except InputError as exc:
            self.status = f"photo fit report not read: {exc}"

    def next_poorly_fit_photo(self) -> None:
        """Stand at the next poorly fit training photo's camera (worst first, then around)."""
        indices = {camera.name: i for i, camera in enumerate(self.cameras)}
        names = [name for name in self.poorly_fit if name in indices]
        if not names:
            return
        self.poorly_fit_shown = (self.poorly_fit_shown + 1) % len(names)
        name = names[self.poorly_fit_shown]
        self.snap_to_camera(indices[name])
        self.status = (f"{name}: training photo {self.poorly_fit_shown + 1} of {len(names)} the model fits "
                       f"poorly ({self.poorly_fit[name]:.1f} dB)")

    # --- live training -------------------------------------------------------------------------
    def start_training(self) -> None:
        """A new stage-I run (the job dialog's settings) in a fresh run folder."""
        if self.training is not None and self.training.alive:
            return
        try:
            job = (self.job_factory(self.source) if self.job_factory is not None
                   else train_job_for(self.source, self.job_settings))
        except Exception as exc:  # noqa: BLE001 - a job that cannot be built is shown, not fatal
            self.status = f"training could not start: {type(exc).__name__}: {exc}"
            return
        out_dir = getattr(job, "run_dir", None)
        self.start_job(job, out_dir, f"training into {out_dir}" if out_dir else "training")

    def resume_training(self) -> None:
        """Continue the open run from its newest checkpoint."""
        if self.training is not None and self.training.alive:
            return
        try:
            job = resume_job_for(self.run_dir, self.job_settings)
        except Exception as exc:  # noqa: BLE001 - shown in the status line
            self.status = f"resume could not start: {exc}"
            return
        self.start_job(job, job.run_dir, f"resuming {job.run_dir}")

    def start_job(self, job, out_dir: Path | None, message: str) -> None:
        """Run ``job`` live; its folder becomes the open run (Resume and Bootstrap use it)."""
        self.training = LiveTraining(job, plan=plan_of(job))
        self.training.start()
        self.fold_job_settings = True  # the dialog closes: the job's progress is what to watch
        self.job_reported = False
        self.job_out_dir = Path(out_dir) if out_dir is not None else None
        if self.job_out_dir is not None:
            self.run_dir = self.job_out_dir
            if self.source.kind == "scene" and self.job_out_dir not in self.source.runs:
                self.source.runs.append(self.job_out_dir)  # the panel's list of the scene's runs
        self.status = message
        self.update_title()

    def report_job_end(self) -> None:
        """Replace the running status with the closing line: time, iteration, final scores."""
        run = self.training
        run.refresh_scores(force=True)
        run.refresh_plan()
        self.job_reported = True
        if run.error:
            self.status = f"{run.plan.kind} failed after {format_duration(run.elapsed_s)}: {run.error}"
            return
        self.status = closing_line(run.plan.kind, run.state, run.elapsed_s, run.progress.iteration,
                                   final_scores(run.progress.psnr), self.job_out_dir)
        if self.job_out_dir is not None and self.job_out_dir == self.run_dir:
            self.read_view_fit()  # a finished run has just written its report

    def update_title(self) -> None:
        """The window names the model shown: the file, or the job folder it comes from."""
        if self.training is not None and self.job_out_dir is not None:
            shown = f"{self.job_out_dir} ({self.training.state})"
        else:
            shown = describe_model(self.source, self.run_dir)
        self.title = f"InceptionGS — {shown}"
        self.title_state = None if self.training is None else self.training.state
        glfw.set_window_title(self.window, self.title)

    def take_points(self) -> None:
        """Show the triangulated points of a scene without sparse points once they are in."""
        worker = self.points_worker
        if worker is None or not worker.done:
            return
        self.points_worker = None
        splats, self.status = worker.result
        if splats is not None and self.training is None:
            self.edit = editing.EditState(splats)
            self.model_version += 1
            self.moved()

    def take_snapshot(self) -> None:
        if self.training is None:
            return
        if self.training.state != self.title_state:
            self.update_title()  # running -> paused -> finished shows in the title
        self.training.refresh_scores()
        self.training.refresh_plan()  # the end of a schedule the trainer re-sized to its budget
        now = time.perf_counter()
        # Throttled while the job runs; once it has ended its last snapshot is taken at once.
        if now - self.last_snapshot_time < TRAINING_REFRESH_SECONDS and self.training.alive:
            return
        ended = not self.training.alive  # read before the poll: the job's last publish is then in
        gaussians = self.training.poll_gaussians()
        if gaussians is not None:
            self.last_snapshot_time = now
            # A new model replaces the edit state: edits are for models at rest.
            self.edit = editing.EditState(gaussians)
            self.model_version += 1
        if ended and not self.job_reported:
            self.report_job_end()

    # --- the frame loop --------------------------------------------------------------------------
    def step(self) -> None:
        """One frame."""
        glfw.poll_events()
        now = time.perf_counter()
        seconds = min(now - self._last_frame_time, 0.25)  # a stalled frame must not teleport
        self._last_frame_time = now
        self.input.update_fly(seconds)
        self.take_points()
        self.take_snapshot()
        screen = self.ctx.detect_framebuffer(0)
        screen.use()
        width, height = self.framebuffer_size
        self.ctx.viewport = (0, 0, width, height)
        if self.drawing.scene_texture.texture is None:
            # Later frames skip this full-window pass: the scene blit overwrites every pixel.
            screen.clear(*self.settings.background, 1.0)
        self.drawing.draw_scene(self, screen)
        self.drawing.draw_overlays(self, screen)
        if self.imgui_impl is not None:
            self.draw_ui()
        if self.capture_requested:
            self.captured = read_framebuffer(screen, width, height)
            self.capture_requested = False
            # moderngl's read of the window sets the read buffer to a colour attachment, which GL
            # refuses for the default framebuffer (the pixels still come from the back buffer):
            # drop that error so it is neither shown nor raised by imgui's PyOpenGL later.
            _ = self.ctx.error
        glfw.swap_buffers(self.window)
        self.stats.frames += 1
        self._frame_times.append(time.perf_counter() - now)
        if len(self._frame_times) > 30:
            self._frame_times.pop(0)
        mean = sum(self._frame_times) / len(self._frame_times)
        self.stats.frame_ms = 1000.0 * mean
        self.stats.fps = 1.0 / mean if mean > 0 else 0.0

    def draw_ui(self) -> None:
        from imgui_bundle import imgui  # noqa: PLC0415 (no imgui unless there is a UI)

        from .panels import draw_panels  # noqa: PLC0415

        self.note_gl_error()
        self.imgui_impl.process_inputs()
        imgui.new_frame()
        draw_panels(self)
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

    def is_idle(self) -> bool:
        """Nothing will change without an event: no motion or refine pending, no fly key
        held, no job running, no reference image awaited."""
        now = time.perf_counter()
        if now - self.last_motion < STILL_SECONDS + 0.1 or self.input.keys_down:
            return False
        if now - self.input.last_event < UI_SETTLE_SECONDS:
            return False  # imgui answers some input on a later frame (a window it sizes first, a hover)
        if now - self.last_snapshot_time < MODEL_STILL_SECONDS + 0.1:
            return False  # the refine of the last snapshot is still to come
        if self.job_running():
            return False  # a paused job is idle: it publishes nothing
        if self.points_worker is not None:
            return False  # the triangulated points are to come
        return self.settings.mode != "reference" or self.drawing.reference_settled()

    def job_running(self) -> bool:
        """A job is training now (started, not paused, not ended)."""
        return self.training is not None and self.training.alive and not self.training.control.pause.is_set()

    def training_frame_wait(self) -> float:
        """Seconds to leave to a running job after a frame (ViewSettings.training_utilisation)."""
        share = min(max(self.settings.training_utilisation, 0.0), MAX_TRAINING_UTILISATION)
        return min(self.stats.frame_ms / 1000.0 * share / (1.0 - share), MAX_TRAINING_WAIT_SECONDS)

    def wait_for_next_frame(self) -> None:
        """Sleep until input arrives or the next frame is due; step() polls what arrived."""
        if self.is_idle():
            glfw.wait_events_timeout(IDLE_WAIT_SECONDS)
        elif self.job_running() and time.perf_counter() - self.last_motion >= STILL_SECONDS:
            glfw.wait_events_timeout(self.training_frame_wait())  # a moving camera gets every frame
        elif self.points_worker is not None and time.perf_counter() - self.last_motion >= STILL_SECONDS:
            glfw.wait_events_timeout(MAX_TRAINING_WAIT_SECONDS)  # the points' thread needs the CPU

    def run(self) -> None:
        try:
            while not self.should_close():
                self.wait_for_next_frame()
                self.step()
        finally:
            self.close()

    def close(self) -> None:
        """Stop the job (it keeps its checkpoint), the reference worker, and the window."""
        if self.training is not None:
            self.training.stop(timeout=60.0)
        self.drawing.close()
        if self.imgui_impl is not None:
            self.note_gl_error()  # PyOpenGL in imgui's shutdown raises on an error left pending
            destroy_imgui(self.imgui_impl)
            self.imgui_impl = None
        if self.window is not None:
            self.renderer.release()
            self.drawing.release()
            glfw.destroy_window(self.window)
            self.window = None
