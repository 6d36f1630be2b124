"""The desktop viewer/editor: a GLFW window, the GL splat renderer, imgui-bundle panels.

One frame (:meth:`Viewer.step`): poll events -> move the camera -> take the newest training
snapshot -> draw the splats into the scene texture (at reduced size while the camera moves,
full size once it stops, nothing when nothing changed) -> blit -> overlays -> panels.
Input handlers are plain methods (``on_key``, ``on_mouse_button``, ...) registered as GLFW
callbacks, so tests can inject events exactly as GLFW would deliver them.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import glfw
import moderngl
import numpy as np

from inceptiongs.camera import Camera
from inceptiongs.constants import sh_degree_from_count
from inceptiongs.errors import InputError
from inceptiongs.gaussians import Gaussians
from inceptiongs.renderer.context import unbind_current_egl

from inceptiongs.io import flags as flag_io

from . import editing, flags as flagging
from .frustums import segments_for_cameras
from inceptiongs.evaluation.metrics import psnr
from inceptiongs.io.images import write_png

from .coverage_mode import CoverageMode
from .images import visualize
from .live_training import LiveTraining
from .navigation import NavigationState, default_view, estimate_up
from .overlay import OverlayRenderer, SceneTexture
from .reference import ReferenceWorker, error_heatmap, side_by_side
from .sources import ViewerSource

GL_REQUIRED = (4, 3)
RENDER_MODES = ("rgb", "depth", "normal", "opacity", "reference", "coverage")
# The viewer's mode names -> the GL renderer's.
# "coverage" draws splats recoloured by their view counts (app/coverage_mode.py) as rgb.
GL_MODE_NAMES = {"rgb": "rgb", "depth": "depth", "normal": "normal", "opacity": "alpha", "coverage": "rgb"}
# Resolution factors while the camera moves, largest first; the full frame follows once it
# has been still for STILL_SECONDS (the "refine when still" rule of the frame-rate target).
# Each moving render picks the next factor from the last one's splat time: a smaller factor
# when it overran MOVING_BUDGET_MS, a larger one when it took under half of it. A few fixed
# sizes rather than a continuous factor, so the scene texture is not reallocated every frame.
MOVING_RENDER_SCALES = (0.5, 0.375, 0.25)
MOVING_RENDER_SCALE = MOVING_RENDER_SCALES[0]
MOVING_BUDGET_MS = 40.0
STILL_SECONDS = 0.15
# While a job trains, its snapshots replace the model at most this often: each one costs a
# re-render, and the job publishes faster than software GL can draw them. A model that
# changed less than MODEL_STILL_SECONDS ago is drawn at the moving size too (a training view
# updates at reduced resolution) and refined once the job pauses, stops or goes quiet.
TRAINING_REFRESH_SECONDS = 0.3
MODEL_STILL_SECONDS = 1.0
# run() sleeps in glfw.wait_events_timeout for up to this long when nothing is changing
# (no motion, no refine pending, no job): an idle window costs no frames.
IDLE_WAIT_SECONDS = 0.5
# The torch reference renders at most this many pixels wide (it runs on the CPU).
REFERENCE_MAX_WIDTH = 320
# Two left presses within this time and this many pixels form a double-click.
DOUBLE_CLICK_SECONDS = 0.35
DOUBLE_CLICK_PIXELS = 4.0
TRAINING_COLOR = (0.2, 0.6, 1.0)
FLAG_COLOR = (1.0, 0.3, 0.2)
SELECTED_FLAG_COLOR = (1.0, 0.9, 0.1)
CROP_COLOR = (0.3, 1.0, 0.3)
SELECTION_COLOR = (1.0, 0.2, 0.9)


class WindowError(RuntimeError):
    """No window / no GL 4.3 context; the message says what was found."""


def create_window(width: int, height: int, title: str, visible: bool = True):
    """A GLFW window with a GL 4.3 core context made current. Raises WindowError naming the GL
    version that could be had when 4.3 core cannot."""
    unbind_current_egl()  # an EGL context left current blocks GLX on this thread
    if not glfw.init():
        raise WindowError("could not initialise GLFW (no display? set DISPLAY or run under Xvfb)")
    glfw.window_hint(glfw.VISIBLE, glfw.TRUE if visible else glfw.FALSE)
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, GL_REQUIRED[0])
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, GL_REQUIRED[1])
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, glfw.TRUE)
    window = glfw.create_window(width, height, title, None, None)
    if window:
        glfw.make_context_current(window)
        return window
    raise WindowError(f"no OpenGL {GL_REQUIRED[0]}.{GL_REQUIRED[1]} core context could be created; "
                      f"found: {_probe_gl_version()}")


def _probe_gl_version() -> str:
    """What GL a default (unversioned) context gives, for the error message."""
    glfw.default_window_hints()
    glfw.window_hint(glfw.VISIBLE, glfw.FALSE)
    window = glfw.create_window(16, 16, "probe", None, None)
    if not window:
        return "no OpenGL context at all"
    glfw.make_context_current(window)
    try:
        ctx = moderngl.create_context()
        info = f"OpenGL {ctx.info.get('GL_VERSION', '?')} ({ctx.info.get('GL_RENDERER', '?')})"
        ctx.release()
    except Exception as exc:  # noqa: BLE001 - only feeding an error message
        info = f"an unusable context ({exc})"
    glfw.destroy_window(window)
    return info


@dataclass
class ViewSettings:
    mode: str = "rgb"
    reference_view: str = "heat-map"  # or "side by side"
    sh_degree_cap: int = 3
    splat_scale: float = 1.0
    background: tuple = (0.0, 0.0, 0.0)
    show_training_cameras: bool = True
    show_flags: bool = True
    orbit: bool = False
    edit_tool: str = "none"  # "none" | "rectangle" | "brush"
    brush_radius: float = 30.0
    selection_mode: str = "replace"
    crop_enabled: bool = False
    crop_min: list = field(default_factory=lambda: [-1.0, -1.0, -1.0])
    crop_max: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    max_opacity: float = 0.05
    min_size: float = 0.5


@dataclass
class FrameStats:
    frame_ms: float = 0.0
    fps: float = 0.0
    sort_ms: float = 0.0
    draw_ms: float = 0.0
    rendered_scale: float = 1.0
    frames: int = 0
    splat_renders: int = 0


class Viewer:
    """Owns the window, GL resources and all UI state for one source."""

    def __init__(self, source: ViewerSource, width: int = 1280, height: int = 720, visible: bool = True,
                 job_factory=None, with_ui: bool = True) -> None:
        from inceptiongs.renderer.splats import SplatRenderer  # noqa: PLC0415 (GL only after a context exists)

        self.source = source
        self.window = create_window(width, height, f"InceptionGS — {source.path.name}", visible)
        self.ctx = moderngl.create_context()
        self.renderer = SplatRenderer(self.ctx)
        self.overlay = OverlayRenderer(self.ctx)
        self.scene_texture = SceneTexture(self.ctx)
        self.settings = ViewSettings()
        self.stats = FrameStats()
        self.edit = editing.EditState(source.gaussians)
        self.model_version = 1
        self.uploaded_version = None
        self.cameras = source.cameras
        self.up = estimate_up(self.cameras)
        self.nav = self._initial_view()
        self.home = self.nav.copy()
        self.camera_index = 0 if self.cameras else -1
        self.flags_file = flag_io.flags_path(source.work_dir)
        self.status = "; ".join(source.notes)
        try:
            self.flags = flag_io.load_flags(self.flags_file)
        except InputError as exc:
            self.flags, self.status = [], f"flags not loaded: {exc}"
        self.selected_flag = -1
        self.last_gl_error: str | None = None
        self.job_factory = job_factory
        self.training: LiveTraining | None = None
        self.reference = None  # ReferenceWorker, made when the reference mode is first used
        self.coverage = CoverageMode()  # counts computed when the coverage mode is first drawn
        self.reference_psnr: float | None = None
        self._keys_down: set[int] = set()
        self._last_render_key = None
        self._moving_level = 0  # index into MOVING_RENDER_SCALES
        self._last_snapshot_time = -1e9  # when a job's snapshot last replaced the model
        self._last_motion = -1e9
        self._last_frame_time = time.perf_counter()
        self._drag_start = None
        self._last_cursor = None
        self._last_click = (-1e9, 0.0, 0.0)
        self._dragging_button = None
        self._frame_times: list[float] = []
        self.with_ui = with_ui
        self.imgui_impl = None
        if with_ui:
            self._init_imgui()
        self._install_callbacks()

    # --- setup -------------------------------------------------------------------------------
    def _initial_view(self) -> NavigationState:
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

    def _init_imgui(self) -> None:
        from imgui_bundle import imgui, implot  # noqa: PLC0415
        from imgui_bundle.python_backends.glfw_backend import GlfwRenderer  # noqa: PLC0415

        imgui.create_context()
        implot.create_context()
        imgui.get_io().set_ini_filename("")  # no imgui.ini littering the working folder
        self.imgui_impl = GlfwRenderer(self.window, attach_callbacks=False)

    def _install_callbacks(self) -> None:
        glfw.set_key_callback(self.window, self.on_key)
        glfw.set_char_callback(self.window, self.on_char)
        glfw.set_mouse_button_callback(self.window, self.on_mouse_button)
        glfw.set_cursor_pos_callback(self.window, self.on_cursor)
        glfw.set_scroll_callback(self.window, self.on_scroll)

    @property
    def framebuffer_size(self) -> tuple[int, int]:
        width, height = glfw.get_framebuffer_size(self.window)
        return max(width, 1), max(height, 1)

    def current_camera(self, scale: float = 1.0) -> Camera:
        width, height = self.framebuffer_size
        camera = self.nav.camera(width, height)
        return camera if scale == 1.0 else camera.scaled(1.0 / scale)

    # --- imgui capture helpers -----------------------------------------------------------------
    def _ui_wants_mouse(self) -> bool:
        if self.imgui_impl is None:
            return False
        from imgui_bundle import imgui  # noqa: PLC0415
        return imgui.get_io().want_capture_mouse

    def _ui_wants_keyboard(self) -> bool:
        if self.imgui_impl is None:
            return False
        from imgui_bundle import imgui  # noqa: PLC0415
        return imgui.get_io().want_capture_keyboard

    # --- input -------------------------------------------------------------------------------
    def on_key(self, window, key, scancode, action, mods) -> None:
        if self.imgui_impl is not None:
            self.imgui_impl.keyboard_callback(window, key, scancode, action, mods)
        if action == glfw.RELEASE:
            self._keys_down.discard(key)
            return
        if self._ui_wants_keyboard():
            return
        if action == glfw.PRESS:
            self._keys_down.add(key)
        if action != glfw.PRESS:
            return
        ctrl = bool(mods & glfw.MOD_CONTROL)
        if key == glfw.KEY_F and not ctrl:
            self.flag_current_view()
        elif key == glfw.KEY_Z and ctrl:
            self.undo()
        elif key == glfw.KEY_Y and ctrl:
            self.redo()
        elif key == glfw.KEY_DELETE:
            self.delete_selection()
        elif key == glfw.KEY_N or key == glfw.KEY_PAGE_DOWN:
            self.snap_to_camera(self.camera_index + 1)
        elif key == glfw.KEY_P or key == glfw.KEY_PAGE_UP:
            self.snap_to_camera(self.camera_index - 1)
        elif key == glfw.KEY_R and not ctrl:
            self.reset_view()
        elif key == glfw.KEY_T:
            self.settings.show_training_cameras = not self.settings.show_training_cameras
        elif key == glfw.KEY_O:
            self.settings.orbit = not self.settings.orbit
        elif key == glfw.KEY_F12:
            self.save_screenshot()
        elif glfw.KEY_1 <= key <= glfw.KEY_1 + len(RENDER_MODES) - 1:
            self.settings.mode = RENDER_MODES[key - glfw.KEY_1]

    def on_char(self, window, codepoint) -> None:
        if self.imgui_impl is not None:
            self.imgui_impl.char_callback(window, codepoint)

    def on_scroll(self, window, x_offset, y_offset) -> None:
        if self.imgui_impl is not None:
            self.imgui_impl.scroll_callback(window, x_offset, y_offset)
        if self._ui_wants_mouse():
            return
        if self.settings.orbit:
            self.nav.zoom(y_offset)
        else:
            self.nav.scale_speed(y_offset)
        self._moved()

    def on_cursor(self, window, x, y) -> None:
        if self.imgui_impl is not None:
            self.imgui_impl.io.add_mouse_pos_event(x, y)
        previous, self._last_cursor = self._last_cursor, (x, y)
        if previous is None or self._dragging_button is None:
            return
        dx, dy = x - previous[0], y - previous[1]
        if self._dragging_button == glfw.MOUSE_BUTTON_LEFT:
            tool = self.settings.edit_tool
            if tool == "brush":
                self.brush_select(x, y)
            elif tool == "rectangle":
                pass  # the rectangle is applied on release
            elif self.settings.orbit:
                self.nav.orbit(dx, dy)
                self._moved()
            else:
                self.nav.look(dx, dy)
                self._moved()
        elif self._dragging_button == glfw.MOUSE_BUTTON_MIDDLE:
            self.nav.fly(np.array([-dx, -dy, 0.0]), seconds=0.01)
            self._moved()

    def on_mouse_button(self, window, button, action, mods) -> None:
        if self.imgui_impl is not None:
            self.imgui_impl.io.add_mouse_button_event(button, action == glfw.PRESS)
        x, y = glfw.get_cursor_pos(window) if self._last_cursor is None else self._last_cursor
        if action == glfw.RELEASE:
            if (button == glfw.MOUSE_BUTTON_LEFT and self._dragging_button == button
                    and self.settings.edit_tool == "rectangle" and self._drag_start is not None):
                self.rectangle_select(self._drag_start, (x, y))
            self._dragging_button = None
            return
        if self._ui_wants_mouse():
            return
        self._last_cursor = (x, y)
        if button == glfw.MOUSE_BUTTON_RIGHT:
            self.flag_view_at_pixel(x, y)
            return
        self._dragging_button = button
        self._drag_start = (x, y)
        if button == glfw.MOUSE_BUTTON_LEFT:
            then, px, py = self._last_click
            now = time.perf_counter()
            if now - then < DOUBLE_CLICK_SECONDS and math.hypot(x - px, y - py) < DOUBLE_CLICK_PIXELS:
                self.set_pivot_at_pixel(x, y)
                now = -1e9  # a third click starts a new pair
            elif self.settings.edit_tool == "brush":
                self.brush_select(x, y)
            self._last_click = (now, x, y)

    def _moved(self) -> None:
        self._last_motion = time.perf_counter()

    def _update_fly(self, seconds: float) -> None:
        keys = self._keys_down
        # Camera axes: x right (D), y down (E lowers, Q raises), z forward (W).
        direction = np.array([
            (glfw.KEY_D in keys) - (glfw.KEY_A in keys),
            (glfw.KEY_E in keys) - (glfw.KEY_Q in keys),
            (glfw.KEY_W in keys) - (glfw.KEY_S in keys),
        ], np.float64)
        if np.any(direction):
            boost = 4.0 if (glfw.KEY_LEFT_SHIFT in keys or glfw.KEY_RIGHT_SHIFT in keys) else 1.0
            self.nav.fly(direction, seconds, boost)
            self._moved()

    # --- screen-space helpers ----------------------------------------------------------------
    def _window_to_framebuffer(self, x: float, y: float) -> tuple[float, float]:
        window_w, window_h = glfw.get_window_size(self.window)
        fb_w, fb_h = self.framebuffer_size
        return x * fb_w / max(window_w, 1), y * fb_h / max(window_h, 1)

    def pick_point(self, x: float, y: float) -> np.ndarray | None:
        """World point [3] of the surface under window position (x, y), None if empty."""
        px, py = self._window_to_framebuffer(x, y)
        camera = self.current_camera()
        depth = self.renderer.pick_depth(camera, int(px), int(py))
        if depth is None:
            return None
        return flagging.unproject_pixel(camera, int(px), int(py), depth)

    # --- actions -----------------------------------------------------------------------------
    def snap_to_camera(self, index: int) -> None:
        if not self.cameras:
            return
        self.camera_index = index % len(self.cameras)
        camera = self.cameras[self.camera_index]
        speed, pivot = self.nav.speed, self.nav.pivot
        self.nav = NavigationState.from_camera(camera, up=self.up, speed=speed, pivot=pivot)
        self._moved()

    def reset_view(self) -> None:
        self.nav = self.home.copy()
        self._moved()

    def set_pivot_at_pixel(self, x: float, y: float) -> None:
        point = self.pick_point(x, y)
        if point is None:
            self.status = "double-click: no surface under the cursor"
            return
        self.nav.pivot = point
        self.settings.orbit = True
        self.status = "orbit pivot set"

    def _save_flags(self) -> None:
        flag_io.save_flags(self.flags_file, self.flags)

    def flag_current_view(self) -> None:
        name = flagging.unique_flag_name(self.flags)
        self.flags.append(flagging.flag_camera(self.current_camera(), name))
        self._save_flags()
        self.status = f"flagged the current view as {name!r}"

    def flag_view_at_pixel(self, x: float, y: float) -> None:
        point = self.pick_point(x, y)
        if point is None:
            self.status = "right-click: no surface under the cursor, nothing flagged"
            return
        name = flagging.unique_flag_name(self.flags)
        self.flags.append(flagging.flag_aimed_at(self.current_camera(), point, name))
        self._save_flags()
        self.status = f"flagged a view aimed at {np.round(point, 3).tolist()} as {name!r}"

    def rename_flag(self, index: int, name: str) -> None:
        flag = self.flags[index]
        self.flags[index] = flag_io.Flag(name, flag.camera.with_pose(flag.camera.world_to_camera, name),
                                          flag.created)
        self._save_flags()

    def delete_flag(self, index: int) -> None:
        del self.flags[index]
        self._save_flags()

    def jump_to_flag(self, index: int) -> None:
        self.nav = NavigationState.from_camera(self.flags[index].camera, up=self.up, speed=self.nav.speed,
                                               pivot=self.nav.pivot)
        self._moved()

    def _projected_means(self):
        return editing.project_means(self.edit.base["means"], self.current_camera())

    def rectangle_select(self, corner_a, corner_b) -> None:
        pixels, _ = self._projected_means()
        a = self._window_to_framebuffer(*corner_a)
        b = self._window_to_framebuffer(*corner_b)
        self.edit.select(editing.select_rectangle(pixels, a, b), self.settings.selection_mode)

    def brush_select(self, x: float, y: float) -> None:
        pixels, _ = self._projected_means()
        center = self._window_to_framebuffer(x, y)
        mode = "add" if self.settings.selection_mode == "replace" else self.settings.selection_mode
        self.edit.select(editing.select_brush(pixels, center, self.settings.brush_radius), mode)

    def threshold_select(self) -> None:
        base = self.edit.base
        mask = editing.select_thresholds(base["opacity_logits"], base["log_scales"],
                                         self.settings.max_opacity, self.settings.min_size)
        self.edit.select(mask, self.settings.selection_mode)

    def delete_selection(self) -> None:
        if self.edit.delete_selected():
            self.status = f"deleted; {self.edit.count} Gaussians left"

    def apply_crop(self) -> None:
        if self.edit.crop(np.array(self.settings.crop_min), np.array(self.settings.crop_max)):
            self.status = f"cropped; {self.edit.count} Gaussians left"

    def undo(self) -> None:
        self.edit.undo()

    def redo(self) -> None:
        self.edit.redo()

    def save_ply(self, path: str | Path) -> Path:
        """Write the shown Gaussians (atomic). Models of a scene are stored in the scene's
        original frame, like the trainer's model.ply."""
        from inceptiongs.io.ply import write_ply  # noqa: PLC0415

        gaussians = Gaussians.from_numpy(self.edit.visible_arrays())
        scene = self.source.scene
        if scene is not None:  # everything shown for a scene or run is in its normalised frame
            gaussians = scene.normalization.gaussians_to_original(gaussians)
        write_ply(gaussians, path)
        self.status = f"saved {len(gaussians)} Gaussians to {path}"
        return Path(path)

    def render_image(self, camera: Camera | None = None) -> np.ndarray:
        """The scene alone (no UI) at ``camera`` (default: the current view), [H, W, 3] RGB."""
        self._upload_model()
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
        write_png(path, self.render_image())
        self.status = f"screenshot saved to {path}"
        return path

    # --- live training -------------------------------------------------------------------------
    def start_training(self) -> None:
        if self.job_factory is None:
            self.status = "no training job available for this source"
            return
        if self.training is not None and self.training.alive:
            return
        try:
            job = self.job_factory(self.source)
        except Exception as exc:  # noqa: BLE001 - a job that cannot be built is shown, not fatal
            self.status = f"training could not start: {type(exc).__name__}: {exc}"
            return
        self.training = LiveTraining(job)
        self.training.start()

    def _take_snapshot(self) -> None:
        if self.training is None:
            return
        now = time.perf_counter()
        # Throttled while the job runs; once it has ended its last snapshot is taken at once.
        if now - self._last_snapshot_time < TRAINING_REFRESH_SECONDS and self.training.alive:
            return
        gaussians = self.training.poll_gaussians()
        if gaussians is not None:
            self._last_snapshot_time = now
            # A new model replaces the edit state: edits are for models at rest.
            self.edit = editing.EditState(gaussians)
            self.model_version += 1

    # --- drawing -------------------------------------------------------------------------------
    def _upload_model(self) -> None:
        model = (self.model_version, self.edit.version)
        coverage = self.settings.mode == "coverage"
        version = model + (("coverage",) if coverage else ())
        if version != self.uploaded_version:
            arrays = self.edit.visible_arrays()
            if coverage:
                # Depth for the occlusion test comes from the model as it is (its own colours).
                self.renderer.set_gaussians(arrays, version=hash(model) & 0x7FFFFFFF)
                arrays = self.coverage.update(arrays, self.cameras, self._depth_of, model)
            self.renderer.set_gaussians(arrays, version=hash(version) & 0x7FFFFFFF)
            self.uploaded_version = version

    def _depth_of(self, camera: Camera) -> np.ndarray:
        """The uploaded model's camera depth [h, w] at ``camera`` (0 = no surface)."""
        return self.renderer.render(camera, "depth")[..., 0]

    def suggest_flags(self, k: int | None = None) -> list[str]:
        """Flag the k cameras whose content the other cameras see least (coverage mode's
        suggestion); returns the new flags' names."""
        from .coverage_mode import SUGGESTED_FLAGS  # noqa: PLC0415

        self.settings.mode, previous = "rgb", self.settings.mode
        self._upload_model()            # depth of the model itself, not of its coverage colours
        indices = self.coverage.suggest(self.edit.visible_arrays(), self.cameras, self._depth_of,
                                        SUGGESTED_FLAGS if k is None else k)
        self.settings.mode = previous
        names = []
        for index in indices:
            name = flagging.unique_flag_name(self.flags, prefix="scarce")
            self.flags.append(flagging.flag_camera(self.cameras[index], name))
            names.append(name)
        if names:
            self._save_flags()
        self.status = (f"flagged the scarcest views: {', '.join(self.cameras[i].name for i in indices)}"
                       if names else "no cameras to suggest flags from")
        return names

    def _draw_scene(self, screen: moderngl.Framebuffer) -> None:
        now = time.perf_counter()
        moving = (now - self._last_motion < STILL_SECONDS
                  or now - self._last_snapshot_time < MODEL_STILL_SECONDS)
        scale = MOVING_RENDER_SCALES[self._moving_level] if moving else 1.0
        self._upload_model()
        mode = self.settings.mode
        camera = self.current_camera(scale)
        key = (mode, self.settings.reference_view, scale, camera.width, camera.height,
               camera.world_to_camera.tobytes(), camera.fy, self.uploaded_version, self.settings.sh_degree_cap,
               self.settings.splat_scale, tuple(self.settings.background))
        if mode == "reference":
            self._draw_reference()
        elif key != self._last_render_key:
            if mode in ("rgb", "opacity", "coverage"):
                # Straight into the texture: draw() renders upright (GL row 0 = image bottom).
                target = self.scene_texture.ensure(camera.width, camera.height)
                self.renderer.draw(camera, GL_MODE_NAMES[mode], target, background=self.settings.background,
                                   sh_degree_cap=self.settings.sh_degree_cap,
                                   splat_scale=self.settings.splat_scale)
                self.scene_texture.flip_y = False
            else:
                # depth and normal need normalising for display: read back, map, upload.
                image = self.renderer.render(camera, GL_MODE_NAMES[mode], sh_degree_cap=self.settings.sh_degree_cap,
                                             splat_scale=self.settings.splat_scale)
                self.scene_texture.upload(visualize(image, mode))
            self.stats.sort_ms = float(self.renderer.timings.get("sort_ms", 0.0))
            self.stats.draw_ms = float(self.renderer.timings.get("draw_ms", 0.0))
            if moving:
                self._moving_level = next_moving_level(self._moving_level, sum(self.renderer.timings.values()))
            self.stats.rendered_scale = scale
            self.stats.splat_renders += 1
            self._last_render_key = key
        self.scene_texture.blit(screen)

    def _draw_reference(self) -> None:
        """GL and torch at the same reduced camera; the torch image comes from the worker."""
        camera = self.current_camera()
        if camera.width > REFERENCE_MAX_WIDTH:
            camera = camera.scaled(camera.width / REFERENCE_MAX_WIDTH)
        if self.reference is None:
            self.reference = ReferenceWorker()
        arrays = self.edit.visible_arrays()
        result = self.reference.result()
        request_key = (camera.world_to_camera.tobytes(), camera.width, self.uploaded_version,
                       self.settings.sh_degree_cap)
        if getattr(self, "_reference_request", None) != request_key:
            cap = min(self.settings.sh_degree_cap, sh_degree_from_count(arrays["sh"].shape[1]))
            self.reference.request(arrays, hash(self.uploaded_version), camera, self.settings.background, cap)
            self._reference_request = request_key
        if result is None:
            return
        gl = self.renderer.render(result.camera, mode="rgb", background=self.settings.background,
                                  sh_degree_cap=self.settings.sh_degree_cap, splat_scale=1.0)
        self.reference_psnr = float(psnr(gl.astype(np.float64), result.rgb.astype(np.float64)))
        if self.settings.reference_view == "heat-map":
            image = error_heatmap(gl, result.rgb)
        else:
            image = side_by_side(gl, result.rgb)
        self.scene_texture.upload(image)
        self._last_render_key = None

    def _draw_overlays(self, screen: moderngl.Framebuffer) -> None:
        camera = self.current_camera()
        screen.use()
        depth = max(self.nav.speed * 0.1, 1e-3)
        if self.settings.show_training_cameras and self.cameras:
            segments = segments_for_cameras(self.cameras, depth)
            self.overlay.draw_segments(camera, segments, np.tile(TRAINING_COLOR, (len(segments), 1)))
        if self.settings.show_flags and self.flags:
            segments = segments_for_cameras([f.camera for f in self.flags], depth * 1.5)
            colors = np.tile(FLAG_COLOR, (len(segments), 1))
            if 0 <= self.selected_flag < len(self.flags):
                colors[8 * self.selected_flag: 8 * self.selected_flag + 8] = SELECTED_FLAG_COLOR
            self.overlay.draw_segments(camera, segments, colors)
        if self.settings.crop_enabled:
            self.overlay.draw_segments(camera, box_segments(self.settings.crop_min, self.settings.crop_max),
                                       np.tile(CROP_COLOR, (12, 1)))
        if self.edit.selected.any():
            self.overlay.draw_points(camera, self.edit.base["means"][self.edit.selected], SELECTION_COLOR)

    def step(self) -> None:
        """One frame."""
        glfw.poll_events()
        now = time.perf_counter()
        seconds = min(now - self._last_frame_time, 0.25)  # a stalled frame must not teleport
        self._last_frame_time = now
        self._update_fly(seconds)
        self._take_snapshot()
        screen = self.ctx.detect_framebuffer(0)
        screen.use()
        width, height = self.framebuffer_size
        self.ctx.viewport = (0, 0, width, height)
        if self.scene_texture.texture is None:
            # Later frames skip this full-window pass: the scene blit overwrites every pixel.
            screen.clear(*self.settings.background, 1.0)
        self._draw_scene(screen)
        self._draw_overlays(screen)
        if self.imgui_impl is not None:
            from .panels import draw_panels  # noqa: PLC0415
            # PyOpenGL (used by imgui's backend) raises on any pending GL error, even one left
            # by an earlier draw; read it here (which clears it) and show it instead.
            error = self.ctx.error
            if error != "GL_NO_ERROR":
                self.last_gl_error = error
            self.imgui_impl.process_inputs()
            from imgui_bundle import imgui  # noqa: PLC0415
            imgui.new_frame()
            draw_panels(self)
            imgui.render()
            self.imgui_impl.render(imgui.get_draw_data())
        glfw.swap_buffers(self.window)
        self.stats.frames += 1
        self._frame_times.append(time.perf_counter() - now)
        if len(self._frame_times) > 30:
            self._frame_times.pop(0)
        mean = sum(self._frame_times) / len(self._frame_times)
        self.stats.frame_ms = 1000.0 * mean
        self.stats.fps = 1.0 / mean if mean > 0 else 0.0

    def should_close(self) -> bool:
        return bool(glfw.window_should_close(self.window))

    def is_idle(self) -> bool:
        """Nothing will change without an event: no motion or refine pending, no fly key
        held, no job running, no reference image awaited."""
        now = time.perf_counter()
        if now - self._last_motion < STILL_SECONDS + 0.1 or self._keys_down:
            return False
        if now - self._last_snapshot_time < MODEL_STILL_SECONDS + 0.1:
            return False  # the refine of the last snapshot is still to come
        if self.training is not None and self.training.alive:
            return False
        return self.settings.mode != "reference"

    def run(self) -> None:
        try:
            while not self.should_close():
                if self.is_idle():
                    glfw.wait_events_timeout(IDLE_WAIT_SECONDS)  # step() polls what arrived
                self.step()
        finally:
            self.close()

    def close(self) -> None:
        """Stop the job (it keeps its checkpoint), the reference worker, and the window."""
        if self.training is not None:
            self.training.stop(timeout=60.0)
        if self.reference is not None:
            self.reference.close()
        if self.imgui_impl is not None:
            self.imgui_impl.shutdown()
            self.imgui_impl = None
        if self.window is not None:
            self.renderer.release()
            self.overlay.release()
            self.scene_texture.release()
            glfw.destroy_window(self.window)
            self.window = None


def next_moving_level(level: int, splat_ms: float) -> int:
    """The MOVING_RENDER_SCALES index for the next moving frame, from the last one's splat
    time (preprocess + sort + draw ms): down a size over budget, up one under half of it."""
    if splat_ms > MOVING_BUDGET_MS:
        return min(level + 1, len(MOVING_RENDER_SCALES) - 1)
    if splat_ms < 0.5 * MOVING_BUDGET_MS:
        return max(level - 1, 0)
    return level


def box_segments(box_min, box_max) -> np.ndarray:
    """The 12 edges [12, 2, 3] of an axis-aligned box."""
    lo, hi = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
    corners = np.array([[(hi if (i >> k) & 1 else lo)[k] for k in range(3)] for i in range(8)])
    edges = [(i, i | (1 << k)) for i in range(8) for k in range(3) if not (i >> k) & 1]
    return np.array([(corners[a], corners[b]) for a, b in edges])
