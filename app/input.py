"""Keyboard and mouse -> viewer actions. The handlers have GLFW's callback signatures and are
registered as the window's callbacks, so tests inject events exactly as GLFW delivers them.

The controller keeps only input state (keys held, the drag in progress, the last click); what
an event does is a public method of the object it acts on: the viewer's view (camera, render
settings), flags, editor, or the viewer itself (screenshot)."""

from __future__ import annotations

import math
import time

import glfw
import numpy as np

from .capabilities import mode_unavailable
from .settings import RENDER_MODES
from .window import ui_under_cursor, ui_wants_keyboard, ui_wants_mouse

# Two left presses within this time and this many pixels form a double-click.
DOUBLE_CLICK_SECONDS = 0.35
DOUBLE_CLICK_PIXELS = 4.0
# The lasso takes a new corner once the cursor has moved this far from the last one.
LASSO_STEP_PIXELS = 3.0


def grab_depth(view, x: float, y: float) -> float:
    """The camera depth a pan started at window position (x, y) of ``view`` (view.View) keeps
    under the cursor: the surface there, else the pivot's depth, else the fly speed (a step ahead)."""
    px, py = view.pixels.to_framebuffer(x, y)
    depth = view.renderer.pick_depth(view.current_camera(), int(px), int(py))
    if depth is None:
        depth = view.nav.pivot_depth()
    return depth if depth > 1e-6 else view.nav.speed


class InputController:
    """GLFW callbacks for one viewer."""

    def __init__(self, viewer) -> None:
        self.viewer = viewer
        self.keys_down: set[int] = set()
        self.last_event = -1e9  # perf_counter() of the last input event (pacing.is_idle)
        self.drag_start = None
        self.last_cursor = None
        self.last_click = (-1e9, 0.0, 0.0)
        self.dragging_button = None
        self.lasso: list[tuple[float, float]] = []  # the lasso being drawn (window positions)
        self.crop_handle: int | None = None  # the crop-box face being dragged
        self.pan_depth = 1.0  # camera depth of the point a middle-drag grabbed

    def install(self, window) -> None:
        glfw.set_key_callback(window, self.on_key)
        glfw.set_char_callback(window, self.on_char)
        glfw.set_mouse_button_callback(window, self.on_mouse_button)
        glfw.set_cursor_pos_callback(window, self.on_cursor)
        glfw.set_scroll_callback(window, self.on_scroll)
        # Not input, but each needs a frame: an expose (the window's pixels lost), a resize, the
        # focus or the cursor entering or leaving (hover highlights).
        glfw.set_window_refresh_callback(window, lambda _window: self.note_event())
        glfw.set_framebuffer_size_callback(window, lambda _window, _w, _h: self.note_event())
        glfw.set_window_focus_callback(window, lambda _window, _focused: self.note_event())
        glfw.set_cursor_enter_callback(window, lambda _window, _entered: self.note_event())

    def note_event(self) -> None:
        """Something the next frame must show arrived (pacing.wait_for_next_frame draws it)."""
        self.last_event = time.perf_counter()

    def on_key(self, window, key, scancode, action, mods) -> None:
        self.last_event = time.perf_counter()
        viewer = self.viewer
        if viewer.imgui_impl is not None:
            viewer.imgui_impl.keyboard_callback(window, key, scancode, action, mods)
        if action == glfw.RELEASE:
            self.keys_down.discard(key)
            return
        if action == glfw.PRESS and key == glfw.KEY_Q and mods & glfw.MOD_CONTROL:
            glfw.set_window_should_close(viewer.window, True)   # Ctrl+Q quits from a text field too
            return
        if ui_wants_keyboard(viewer.imgui_impl):
            return
        if action == glfw.PRESS:
            self.keys_down.add(key)
        if action != glfw.PRESS:
            return
        self.key_pressed(key, bool(mods & glfw.MOD_CONTROL))

    def key_pressed(self, key: int, ctrl: bool) -> None:
        """What a key press does (KEY_BINDINGS), once the panel has not taken it."""
        viewer = self.viewer
        view, settings, editor = viewer.view, viewer.view.settings, viewer.editor
        if key == glfw.KEY_ESCAPE:
            viewer.ui.show_help = False  # Esc closes the help; it never quits (too easy to hit)
        elif key == glfw.KEY_Q and ctrl:
            glfw.set_window_should_close(viewer.window, True)  # as the window's close button
        elif key == glfw.KEY_F and not ctrl:
            viewer.flags.flag_current_view()
        elif key == glfw.KEY_Z and ctrl:
            editor.undo()
        elif key == glfw.KEY_Y and ctrl:
            editor.redo()
        elif key == glfw.KEY_DELETE:
            editor.delete_selection()
        elif key == glfw.KEY_N or key == glfw.KEY_PAGE_DOWN:
            view.snap_to_camera(view.camera_index + 1)
        elif key == glfw.KEY_P or key == glfw.KEY_PAGE_UP:
            view.snap_to_camera(view.camera_index - 1)
        elif key == glfw.KEY_R and not ctrl:
            view.reset_view()
        elif key == glfw.KEY_HOME:
            view.frame_model()
        elif key == glfw.KEY_TAB:
            settings.show_panel = not settings.show_panel
        elif key in (glfw.KEY_H, glfw.KEY_F1):
            viewer.ui.show_help = not viewer.ui.show_help
        elif key == glfw.KEY_T:
            settings.show_training_cameras = not settings.show_training_cameras
        elif key == glfw.KEY_O:
            settings.orbit = not settings.orbit
        elif key == glfw.KEY_F12:
            viewer.save_screenshot()
        elif glfw.KEY_1 <= key <= glfw.KEY_1 + len(RENDER_MODES) - 1:
            mode = RENDER_MODES[key - glfw.KEY_1]
            refused = mode_unavailable(mode, view.source)
            if refused is None:
                settings.mode = mode
                viewer.status_line.drop("mode")   # an earlier refusal is answered by this choice
            else:
                viewer.status_line.say(refused, topic="mode")

    def on_char(self, window, codepoint) -> None:
        self.last_event = time.perf_counter()
        if self.viewer.imgui_impl is not None:
            self.viewer.imgui_impl.char_callback(window, codepoint)

    def on_scroll(self, window, x_offset, y_offset) -> None:
        self.last_event = time.perf_counter()
        viewer = self.viewer
        if viewer.imgui_impl is not None:
            viewer.imgui_impl.scroll_callback(window, x_offset, y_offset)
        if ui_wants_mouse(viewer.imgui_impl) or (self.last_cursor is not None
                                                 and ui_under_cursor(viewer.imgui_impl, *self.last_cursor)):
            return
        view = viewer.view
        if view.settings.orbit:
            view.nav.zoom(y_offset)
        else:
            view.nav.scale_speed(y_offset)
        view.moved()

    def on_cursor(self, window, x, y) -> None:
        self.last_event = time.perf_counter()
        viewer = self.viewer
        if viewer.imgui_impl is not None:
            viewer.imgui_impl.io.add_mouse_pos_event(x, y)
        previous, self.last_cursor = self.last_cursor, (x, y)
        if previous is None or self.dragging_button is None:
            return
        dx, dy = x - previous[0], y - previous[1]
        view, editor = viewer.view, viewer.editor
        if self.dragging_button == glfw.MOUSE_BUTTON_LEFT:
            tool = view.settings.edit_tool
            if viewer.mover.drag is not None:
                viewer.mover.move_to(x, y)
            elif self.crop_handle is not None:
                editor.drag_crop_handle(self.crop_handle, previous, (x, y))
            elif tool == "brush":
                editor.brush_select(x, y, stroke_start=False)
            elif tool in ("rectangle", "visible rectangle", "gizmo"):
                pass  # the rectangle is applied on release (the panels draw it meanwhile)
            elif tool == "lasso":
                last = self.lasso[-1] if self.lasso else (math.inf, math.inf)
                if math.hypot(x - last[0], y - last[1]) >= LASSO_STEP_PIXELS:
                    self.lasso.append((x, y))
            elif view.settings.orbit:
                view.nav.orbit(dx, dy)
                view.moved()
            else:
                view.nav.look(dx, dy)
                view.moved()
        elif self.dragging_button == glfw.MOUSE_BUTTON_MIDDLE:
            view.pan(dx, dy, self.pan_depth)

    def on_mouse_button(self, window, button, action, mods) -> None:
        self.last_event = time.perf_counter()
        viewer = self.viewer
        if viewer.imgui_impl is not None:
            viewer.imgui_impl.io.add_mouse_button_event(button, action == glfw.PRESS)
        x, y = glfw.get_cursor_pos(window) if self.last_cursor is None else self.last_cursor
        view, editor = viewer.view, viewer.editor
        if action == glfw.RELEASE:
            if (button == glfw.MOUSE_BUTTON_LEFT and self.dragging_button == button and self.drag_start is not None
                    and self.crop_handle is None):
                if viewer.mover.drag is not None:
                    viewer.mover.end()
                elif view.settings.edit_tool in ("rectangle", "visible rectangle"):
                    editor.rectangle_select(self.drag_start, (x, y), view.settings.edit_tool == "visible rectangle")
                elif view.settings.edit_tool == "lasso":
                    editor.lasso_select(self.lasso + [(x, y)])
            self.lasso = []
            self.crop_handle = None
            self.dragging_button = None
            return
        if ui_wants_mouse(viewer.imgui_impl) or ui_under_cursor(viewer.imgui_impl, x, y):
            return
        self.last_cursor = (x, y)
        if button == glfw.MOUSE_BUTTON_RIGHT:
            viewer.flags.flag_view_at_pixel(x, y)
            return
        self.dragging_button = button
        self.drag_start = (x, y)
        if button == glfw.MOUSE_BUTTON_MIDDLE:
            self.pan_depth = grab_depth(view, x, y)  # the grabbed point stays under the cursor
        if button == glfw.MOUSE_BUTTON_LEFT:
            self.crop_handle = editor.crop_handle_at(x, y)  # a handle wins over tools and looking
            if self.crop_handle is not None:
                return
            axis = viewer.mover.handle_at(x, y)
            if axis is not None:
                viewer.mover.begin(axis, x, y)
                return
            then, px, py = self.last_click
            now = time.perf_counter()
            if now - then < DOUBLE_CLICK_SECONDS and math.hypot(x - px, y - py) < DOUBLE_CLICK_PIXELS:
                view.set_pivot_at_pixel(x, y)
                now = -1e9  # a third click starts a new pair
            elif view.settings.edit_tool == "brush":
                editor.brush_select(x, y)
            elif view.settings.edit_tool == "lasso":
                self.lasso = [(x, y)]
            self.last_click = (now, x, y)

    def update_fly(self, seconds: float) -> None:
        """Move the camera for the fly keys held over the last ``seconds``."""
        keys = self.keys_down
        # Camera axes: x right (D), y down (E lowers, Q raises), z forward (W).
        direction = np.array([
            (glfw.KEY_D in keys) - (glfw.KEY_A in keys),
            (glfw.KEY_E in keys) - (glfw.KEY_Q in keys),
            (glfw.KEY_W in keys) - (glfw.KEY_S in keys),
        ], np.float64)
        if np.any(direction):
            boost = 4.0 if (glfw.KEY_LEFT_SHIFT in keys or glfw.KEY_RIGHT_SHIFT in keys) else 1.0
            self.viewer.view.nav.fly(direction, seconds, boost)
            self.viewer.view.moved()
