"""The panel's "Camera path" section (camera_path.PathEditor): keyframes from the current view,
their list (select, earlier/later, delete, time), fps and video size, preview, save and render.
Each widget's rectangle is kept in ui.rects under its label, so a test clicks it as a user does."""

from __future__ import annotations

from imgui_bundle import imgui

from .camera_path import poll_render, render_unavailable, start_render


def _keep(ui, label: str) -> None:
    low, high = imgui.get_item_rect_min(), imgui.get_item_rect_max()
    ui.rects[label] = (low.x, low.y, high.x, high.y)


def _button(ui, label: str, disabled: str | None = None) -> bool:
    """A button kept under ``label``; greyed with ``disabled`` as its tooltip when that is given."""
    imgui.begin_disabled(disabled is not None)
    pressed = imgui.button(label)
    imgui.end_disabled()
    _keep(ui, label)
    if disabled is not None and imgui.is_item_hovered(imgui.HoveredFlags_.allow_when_disabled):
        imgui.set_tooltip(disabled)
    return pressed and disabled is None


def draw_camera_path(ui, paths) -> None:
    """The section's widgets (call it under the panel's "Camera path" header)."""
    poll_render(paths)
    if _button(ui, "add keyframe (current view)"):
        paths.add_keyframe()
    for index, key in enumerate(paths.keyframes):
        label = f"keyframe {index + 1}  at {key.time_s:.2f} s##key{index}"
        if imgui.selectable(label, index == paths.selected)[0]:
            paths.go_to(index)
        _keep(ui, f"keyframe {index + 1}")
    index = paths.selected
    if 0 <= index < len(paths.keyframes):
        imgui.set_next_item_width(120)
        changed, time_s = imgui.input_float("time s##keyframe", paths.keyframes[index].time_s, 0.5, 1.0, "%.2f")
        _keep(ui, "time s")
        if changed:
            paths.set_time(index, time_s)
        if _button(ui, "earlier", None if index > 0 else "already first"):
            paths.move(index, -1)
        imgui.same_line()
        if _button(ui, "later", None if index + 1 < len(paths.keyframes) else "already last"):
            paths.move(index, +1)
        imgui.same_line()
        if _button(ui, "delete keyframe"):
            paths.delete(index)
    imgui.set_next_item_width(120)
    _, paths.fps = imgui.input_float("fps##path", paths.fps, 1.0, 10.0, "%.0f")
    _keep(ui, "fps")
    paths.fps = float(min(max(paths.fps, 1.0), 240.0))
    imgui.set_next_item_width(160)
    _, size = imgui.input_int2("video size##path", paths.size)
    _keep(ui, "video size")
    paths.size = [max(int(size[0]), 2), max(int(size[1]), 2)]
    too_few = None if len(paths.keyframes) >= 2 else "add at least 2 keyframes"
    if _button(ui, "stop preview" if paths.preview_started is not None else "preview", too_few):
        paths.toggle_preview()
    imgui.same_line()
    if _button(ui, "save path", too_few):
        paths.save()
    imgui.same_line()
    if _button(ui, "render video", render_unavailable(paths)):
        start_render(paths)
    render = paths.render
    if render is not None and render.running():
        fraction = render.done / render.total if render.total else 0.0
        imgui.progress_bar(fraction, imgui.ImVec2(-1, 0), f"frame {render.done} / {render.total or '?'}")
        _keep(ui, "video progress")
    for what, path in (("path", paths.saved), ("video", paths.video)):
        if path is not None:
            imgui.push_text_wrap_pos(0.0)
            imgui.text_disabled(f"last {what}: {path}")
            imgui.pop_text_wrap_pos()
