"""The notification area: the status line's message (settings.StatusLine) drawn over the top of
the scene, right of the panel, where it stays in view however far the panel is scrolled. A
message is replaced whenever the state it names changes (a flag made or deleted, an undo, a
job's end); a new one is drawn highlighted for a moment so a right-click's answer is seen at
once."""

from __future__ import annotations

import time

from imgui_bundle import imgui

# Gap between the area and the panel or the window's edge, pixels.
MARGIN = 10
# The area is at most this wide (long messages wrap inside it), and never narrower than
# MIN_WIDTH: with less room right of the panel it sits over the panel's bottom instead.
MAX_WIDTH = 640
MIN_WIDTH = 220
# A new message is drawn on a highlighted background for this long.
FRESH_SECONDS = 2.5
BACKGROUND = (0.08, 0.08, 0.10, 0.92)
FRESH_BACKGROUND = (0.16, 0.30, 0.52, 0.96)


def area_position(window_size: tuple[float, float], panel_rect: tuple | None) -> tuple[float, float, float, bool]:
    """Where the area goes: (x, y, width, at_bottom). Right of the panel (panel_rect: its window
    rectangle x0, y0, x1, y1; None when hidden) at the window's top when MIN_WIDTH fits there,
    else over the panel's bottom left (at_bottom: y is the area's bottom edge)."""
    width, height = window_size
    left = MARGIN if panel_rect is None else panel_rect[2] + MARGIN
    room = width - left - MARGIN
    if room >= MIN_WIDTH:
        return left, MARGIN, min(room, MAX_WIDTH), False
    return 2 * MARGIN, height - 2 * MARGIN, max(min(width - 4 * MARGIN, MAX_WIDTH), 1.0), True


def draw_notification(ui, status, panel_shown: bool) -> None:
    """The area with ``status``'s text (settings.StatusLine), nothing when it is empty; its
    window rectangle kept in ui.rects["notification"] (None while nothing shows)."""
    text = status.text
    if not text:
        ui.rects["notification"] = None
        return
    panel = ui.layout.get("rect") if panel_shown else None
    x, y, width, at_bottom = area_position(tuple(imgui.get_io().display_size), panel)
    # Sized from the text here, not auto-resized: imgui hides an auto-resizing window on the
    # frame it reappears, and the answer to a click must show on the very next frame.
    padding = imgui.get_style().window_padding
    wrap = width - 2 * padding.x
    text_size = imgui.calc_text_size(text, False, wrap)
    size = imgui.ImVec2(min(text_size.x, wrap) + 2 * padding.x + 1,
                        min(text_size.y + 2 * padding.y, imgui.get_io().display_size.y / 3))
    imgui.set_next_window_pos(imgui.ImVec2(x, y), imgui.Cond_.always, imgui.ImVec2(0.0, 1.0 if at_bottom else 0.0))
    imgui.set_next_window_size(size, imgui.Cond_.always)
    fresh = time.perf_counter() - status.changed_at < FRESH_SECONDS
    imgui.push_style_color(imgui.Col_.window_bg, imgui.ImVec4(*(FRESH_BACKGROUND if fresh else BACKGROUND)))
    flags = (imgui.WindowFlags_.no_decoration | imgui.WindowFlags_.no_inputs | imgui.WindowFlags_.no_focus_on_appearing
             | imgui.WindowFlags_.no_nav | imgui.WindowFlags_.no_saved_settings)
    imgui.begin("##notification", None, flags)
    imgui.push_text_wrap_pos(imgui.get_cursor_pos_x() + wrap)
    imgui.text_unformatted(text)
    imgui.pop_text_wrap_pos()
    pos, size = imgui.get_window_pos(), imgui.get_window_size()
    ui.rects["notification"] = (pos.x, pos.y, pos.x + size.x, pos.y + size.y)
    imgui.end()
    imgui.pop_style_color()

