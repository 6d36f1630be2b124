"""Keyboard and mouse -> viewer actions. The handlers have GLFW's callback signatures and are
registered as the window's callbacks, so tests inject events exactly as GLFW delivers them.

The controller keeps only input state (keys held, the drag in progress, the last click); what
an event does is a public method of the viewer it is given."""

from __future__ import annotations

import math
import time

import glfw
import numpy as np

from .settings import RENDER_MODES
from .window import ui_wants_keyboard, ui_wants_mouse

# Two left presses within this time and this many pixels form a double-click.
DOUBLE_CLICK_SECONDS = 0.35
DOUBLE_CLICK_PIXELS = 4.0
# The lasso takes a new corner once the cursor has moved this far from the last one.
LASSO_STEP_PIXELS = 3.0


class InputController:
    """GLFW callbacks for one viewer."""

    def __init__(self, viewer) -> None:
        self.viewer = viewer
        self.keys_down: set[int] = set()
        self.last_event = -1e9  # perf_counter() of the last input event (Viewer.is_idle)
        self.drag_start = None
        self.last_cursor = None
        self.last_click = (-1e9, 0.0, 0.0)
        self.dragging_button = None
        self.lasso: list[tuple[float, float]] = []  # the lasso being drawn (window positions)
        self.crop_handle: int | None = None  # the crop-box face being dragged

    def install(self, window) -> None:
        glfw.set_key_callback(window, self.on_key)
        glfw.set_char_callback(window, self.on_char)
        glfw.set_mouse_button_callback(window, self.on_mouse_button)
        glfw.set_cursor_pos_callback(window, self.on_cursor)
        glfw.set_scroll_callback(window, self.on_scroll)

    def on_key(self, window, key, scancode, action, mods) -> None:
        self.last_event = time.perf_counter()
        viewer = self.viewer
        if viewer.imgui_impl is not None:
            viewer.imgui_impl.keyboard_callback(window, key, scancode, action, mods)
        if action == glfw.RELEASE:
            self.keys_down.discard(key)
            return
        if ui_wants_keyboard(viewer.imgui_impl):
            return
        if action == glfw.PRESS:
            self.keys_down.add(key)
        if action != glfw.PRESS:
            return
        ctrl = bool(mods & glfw.MOD_CONTROL)
        if key == glfw.KEY_F and not ctrl:
            viewer.flag_current_view()
        elif key == glfw.KEY_Z and ctrl:
            viewer.undo()
        elif key == glfw.KEY_Y and ctrl:
            viewer.redo()
        elif key == glfw.KEY_DELETE:
            viewer.delete_selection()
        elif key == glfw.KEY_N or key == glfw.KEY_PAGE_DOWN:
            viewer.snap_to_camera(viewer.camera_index + 1)
        elif key == glfw.KEY_P or key == glfw.KEY_PAGE_UP:
            viewer.snap_to_camera(viewer.camera_index - 1)
        elif key == glfw.KEY_R and not ctrl:
            viewer.reset_view()
        elif key == glfw.KEY_HOME:
            viewer.frame_model()
        elif key == glfw.KEY_TAB:
            viewer.settings.show_panel = not viewer.settings.show_panel
        elif key in (glfw.KEY_H, glfw.KEY_F1):
            viewer.show_help = not viewer.show_help
        elif key == glfw.KEY_T:
            viewer.settings.show_training_cameras = not viewer.settings.show_training_cameras
        elif key == glfw.KEY_O:
            viewer.settings.orbit = not viewer.settings.orbit
        elif key == glfw.KEY_F12:
            viewer.save_screenshot()
        elif glfw.KEY_1 <= key <= glfw.KEY_1 + len(RENDER_MODES) - 1:
            viewer.settings.mode = RENDER_MODES[key - glfw.KEY_1]

    def on_char(self, window, codepoint) -> None:
        self.last_event = time.perf_counter()
        if self.viewer.imgui_impl is not None:
            self.viewer.imgui_impl.char_callback(window, codepoint)

    def on_scroll(self, window, x_offset, y_offset) -> None:
        self.last_event = time.perf_counter()
        viewer = self.viewer
        if viewer.imgui_impl is not None:
            viewer.imgui_impl.scroll_callback(window, x_offset, y_offset)
        if ui_wants_mouse(viewer.imgui_impl):
            return
        if viewer.settings.orbit:
            viewer.nav.zoom(y_offset)
        else:
            viewer.nav.scale_speed(y_offset)
        viewer.moved()

    def on_cursor(self, window, x, y) -> None:
        self.last_event = time.perf_counter()
        viewer = self.viewer
        if viewer.imgui_impl is not None:
            viewer.imgui_impl.io.add_mouse_pos_event(x, y)
        previous, self.last_cursor = self.last_cursor, (x, y)
        if previous is None or self.dragging_button is None:
            return
        dx, dy = x - previous[0], y - previous[1]
        if self.dragging_button == glfw.MOUSE_BUTTON_LEFT:
            tool = viewer.settings.edit_tool
            if self.crop_handle is not None:
                viewer.drag_crop_handle(self.crop_handle, previous, (x, y))
            elif tool == "brush":
                viewer.brush_select(x, y, stroke_start=False)
            elif tool == "rectangle":
                pass  # the rectangle is applied on release (the panels draw it meanwhile)
            elif tool == "lasso":
                last = self.lasso[-1] if self.lasso else (math.inf, math.inf)
                if math.hypot(x - last[0], y - last[1]) >= LASSO_STEP_PIXELS:
                    self.lasso.append((x, y))
            elif viewer.settings.orbit:
                viewer.nav.orbit(dx, dy)
                viewer.moved()
            else:
                viewer.nav.look(dx, dy)
                viewer.moved()
        elif self.dragging_button == glfw.MOUSE_BUTTON_MIDDLE:
            viewer.nav.fly(np.array([-dx, -dy, 0.0]), seconds=0.01)
            viewer.moved()

    def on_mouse_button(self, window, button, action, mods) -> None:
        self.last_event = time.perf_counter()
        viewer = self.viewer
        if viewer.imgui_impl is not None:
            viewer.imgui_impl.io.add_mouse_button_event(button, action == glfw.PRESS)
        x, y = glfw.get_cursor_pos(window) if self.last_cursor is None else self.last_cursor
        if action == glfw.RELEASE:
            if (button == glfw.MOUSE_BUTTON_LEFT and self.dragging_button == button and self.drag_start is not None
                    and self.crop_handle is None):
                if viewer.settings.edit_tool == "rectangle":
                    viewer.rectangle_select(self.drag_start, (x, y))
                elif viewer.settings.edit_tool == "lasso":
                    viewer.lasso_select(self.lasso + [(x, y)])
            self.lasso = []
            self.crop_handle = None
            self.dragging_button = None
            return
        if ui_wants_mouse(viewer.imgui_impl):
            return
        self.last_cursor = (x, y)
        if button == glfw.MOUSE_BUTTON_RIGHT:
            viewer.flag_view_at_pixel(x, y)
            return
        self.dragging_button = button
        self.drag_start = (x, y)
        if button == glfw.MOUSE_BUTTON_LEFT:
            self.crop_handle = viewer.crop_handle_at(x, y)  # a handle wins over tools and looking
            if self.crop_handle is not None:
                return
            then, px, py = self.last_click
            now = time.perf_counter()
            if now - then < DOUBLE_CLICK_SECONDS and math.hypot(x - px, y - py) < DOUBLE_CLICK_PIXELS:
                viewer.set_pivot_at_pixel(x, y)
                now = -1e9  # a third click starts a new pair
            elif viewer.settings.edit_tool == "brush":
                viewer.brush_select(x, y)
            elif viewer.settings.edit_tool == "lasso":
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
            self.viewer.nav.fly(direction, seconds, boost)
            self.viewer.moved()
