"""The imgui panels: view, inspect, flags, training, edit. Each panel reads and changes the one
object it edits (view.View, flags.FlagBook, jobs.Jobs, editing.Editor) through its public
methods; draw_panels hands each its object. What the panels remember between frames (widget
rectangles, the help overlay) is the viewer's settings.PanelState, passed as ``ui``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from imgui_bundle import imgui

from . import detail as level_of_detail
from .drawing import POORLY_FIT_COLOR, SELECTION_COLOR
from .gizmo import GIZMO_MODES
from .job_requests import why_no_training
from .job_settings import SIZED_TO_BUDGET
from .notifications import draw_notification
from .plots import draw_plots
from .textfit import middle_ellipsis
from .verdict import draw_verdict, outlook_before_repair
from .navigation import UP_AXES, nearest_camera_index, up_axis_name, up_label
from .progress import eta_seconds, format_duration
from .run_list import choose_runs_folder
from .camera_path_panel import draw_camera_path
from .capabilities import NO_CAMERAS, bootstrap_unavailable, mode_unavailable
from .runs import can_resume, new_train_dir, resume_blocked_reason, runs_folder
from inceptiongs.runs.config import STRATEGY_NAMES, FreeSpace, schedule_length
from inceptiongs.train.view_fit import POOR_FIT_MARGIN_DB

from .settings import EDIT_TOOLS, KEY_BINDINGS, MAX_TRAINING_UTILISATION, PHOTO_VIEWS, RENDER_MODES

TOOL_LINE_WIDTH = 2.0
PANEL_MARGIN = 10
PANEL_WIDTH = 400
PANEL_MIN_WIDTH = 300
# A widget beside a long label keeps at least this width (its label may then wrap the panel).
MIN_ITEM_WIDTH = 60
# A job button that cannot run here: grey on grey, unlike the live buttons' blue.
OFF_BUTTON_COLOR = (0.27, 0.27, 0.28)
OFF_TEXT_COLOR = (0.55, 0.55, 0.55)
# The question a job button asks before anything runs (draw_job_question), and its answers.
JOB_QUESTION = "start a job?"
START_JOB = "start the job"
DO_NOT_START = "do not start"
QUESTION_WIDTH = 560.0



def draw_tool_feedback(view, controls) -> None:
    """What the edit tool will select, drawn over the scene: the rectangle being dragged, the
    brush circle at the cursor, the lasso's path. controls: the input.InputController."""
    tool = view.settings.edit_tool
    cursor = controls.last_cursor
    if tool == "none" or cursor is None:
        return
    draw = imgui.get_foreground_draw_list()
    color = imgui.get_color_u32(imgui.ImVec4(*SELECTION_COLOR, 1.0))
    dragging = controls.dragging_button is not None and controls.drag_start is not None
    if tool in ("rectangle", "visible rectangle") and dragging:
        (x0, y0), (x1, y1) = controls.drag_start, cursor
        draw.add_rect(imgui.ImVec2(min(x0, x1), min(y0, y1)), imgui.ImVec2(max(x0, x1), max(y0, y1)), color,
                      0.0, TOOL_LINE_WIDTH)
    elif tool == "brush":
        # The brush radius is in framebuffer pixels; the cursor in window pixels.
        scale = view.pixels.to_framebuffer(1.0, 1.0)[0]
        draw.add_circle(imgui.ImVec2(*cursor), view.settings.brush_radius / max(scale, 1e-6), color, 0,
                        TOOL_LINE_WIDTH)
    elif tool == "lasso" and dragging and controls.lasso:
        points = [imgui.ImVec2(x, y) for x, y in controls.lasso + [cursor]]
        draw.add_polyline(points, color, TOOL_LINE_WIDTH, 0)


def draw_panels(viewer) -> None:
    width, height = imgui.get_io().display_size
    view, ui = viewer.view, viewer.ui
    draw_tool_feedback(view, viewer.input)
    if not view.settings.show_panel:  # Tab hid it: the scene, the tools' outlines, the notification
        draw_job_question(ui, viewer.jobs)
        draw_notification(ui, viewer.status_line, panel_shown=False)
        if ui.show_help:
            _help(ui)
        return
    # The panel follows the window: full height, a width the user may drag, never past the
    # window; long lines wrap instead of clipping. (Set just before its begin: set before the
    # help's, they moved the help onto the hidden panel's place.)
    imgui.set_next_window_pos(imgui.ImVec2(PANEL_MARGIN, PANEL_MARGIN), imgui.Cond_.always)
    imgui.set_next_window_size_constraints(
        imgui.ImVec2(min(PANEL_MIN_WIDTH, width - 2 * PANEL_MARGIN), height - 2 * PANEL_MARGIN),
        imgui.ImVec2(max(width - 2 * PANEL_MARGIN, 1), height - 2 * PANEL_MARGIN))
    imgui.set_next_window_size(imgui.ImVec2(PANEL_WIDTH, height - 2 * PANEL_MARGIN), imgui.Cond_.first_use_ever)
    imgui.begin("InceptionGS")
    _stats(ui, viewer.stats, view.edit, viewer.last_gl_error)
    _detail(ui, view, viewer.drawing)
    if imgui.small_button("keys and mouse (H)"):
        ui.show_help = not ui.show_help
    if _header(ui, "View", imgui.TreeNodeFlags_.default_open) and _view(ui, view):
        viewer.save_screenshot()
    if _header(ui, "Inspect", imgui.TreeNodeFlags_.default_open) and _inspect(ui, view, viewer.drawing):
        viewer.flags.suggest(viewer.drawing)
    if _header(ui, "Flags", imgui.TreeNodeFlags_.default_open):
        _flags(ui, viewer.flags)
    if _header(ui, "Training", imgui.TreeNodeFlags_.default_open):
        _training(ui, viewer.jobs)
    if _header(ui, "Edit"):
        _edit(ui, viewer.editor)
    if _header(ui, "Camera path"):
        draw_camera_path(ui, viewer.paths)
    ui.layout = _layout()
    imgui.end()
    draw_job_question(ui, viewer.jobs)
    draw_notification(ui, viewer.status_line, panel_shown=True)
    if ui.show_help:
        _help(ui)


def _header(ui, label: str, flags: int = 0) -> bool:
    """imgui.collapsing_header, its rectangle kept under its label (a test opens it with a click)."""
    opened = imgui.collapsing_header(label, flags)
    _remember(ui, label)
    return opened


def _layout() -> dict:
    """Where the panel is and how far its widgets reach, in window pixels: "rect" (x0, y0, x1, y1)
    of the panel, "visible_right" (the x its widgets may use up to: the work area, left of the
    scrollbar) and "content_right" (the furthest x any widget or text reached this frame). A
    widget running past the visible width would be cut off: content_right > visible_right."""
    window = imgui.internal.get_current_window()
    pos, size = window.pos, window.size
    return {"rect": (pos.x, pos.y, pos.x + size.x, pos.y + size.y), "visible_right": window.work_rect.max.x,
            "content_right": window.dc.cursor_max_pos.x}


def _help(ui) -> None:
    """The key bindings, over the middle of the window (H / F1, Esc or its close button hides
    it); opaque: the panel's text showing through made both unreadable."""
    width, height = imgui.get_io().display_size
    imgui.set_next_window_pos(imgui.ImVec2(width * 0.5, height * 0.5), imgui.Cond_.always, imgui.ImVec2(0.5, 0.5))
    imgui.set_next_window_bg_alpha(1.0)
    # Never wider or taller than the window: the actions wrap in their column instead.
    imgui.set_next_window_size_constraints(imgui.ImVec2(0, 0), imgui.ImVec2(max(width - 2 * PANEL_MARGIN, 1),
                                                                           max(height - 2 * PANEL_MARGIN, 1)))
    opened, ui.show_help = imgui.begin("keys and mouse (H / F1)", True, imgui.WindowFlags_.always_auto_resize)
    pos, size = imgui.get_window_pos(), imgui.get_window_size()
    ui.rects["help"] = (pos.x, pos.y, pos.x + size.x, pos.y + size.y)
    if opened and imgui.begin_table("bindings", 2):
        keys_width = max(imgui.calc_text_size(keys).x for keys, _ in KEY_BINDINGS)
        actions_width = max(imgui.calc_text_size(action).x for _, action in KEY_BINDINGS)
        room = width - 2 * PANEL_MARGIN - keys_width - 4 * imgui.get_style().window_padding.x
        imgui.table_setup_column("keys", imgui.TableColumnFlags_.width_fixed, keys_width)
        imgui.table_setup_column("action", imgui.TableColumnFlags_.width_fixed, max(min(actions_width, room), 60.0))
        for keys, action in KEY_BINDINGS:
            imgui.table_next_row()
            imgui.table_next_column()
            imgui.text(keys)
            imgui.table_next_column()
            imgui.text_wrapped(action)
        imgui.end_table()
    imgui.end()


def _button(ui, label: str) -> bool:
    """imgui.button, its window rectangle kept in ui.rects[label] (x0, y0, x1, y1): a
    test clicks it there with mouse events as GLFW delivers them."""
    pressed = imgui.button(label)
    _remember(ui, label)
    return pressed


def _fit(label: str) -> None:
    """The next widget as wide as the panel leaves beside its label (imgui's default, 65 % of the
    panel, pushed long labels past its edge), at least MIN_ITEM_WIDTH."""
    shown = label.split("##")[0]
    label_width = imgui.calc_text_size(shown).x + imgui.get_style().item_inner_spacing.x if shown else 0.0
    imgui.set_next_item_width(max(imgui.get_content_region_avail().x - label_width, MIN_ITEM_WIDTH))


def _same_line_if_fits(label: str, frame: bool = True) -> None:
    """Put the button ``label`` (frame=False: the text) on the line of the last widget when it
    fits before the panel's edge, else start a new line (a fixed row of buttons ran past a
    narrow panel)."""
    style = imgui.get_style()
    width = imgui.calc_text_size(label).x + (2 * style.frame_padding.x if frame else 0.0)
    right = imgui.get_item_rect_max().x + style.item_spacing.x + width
    if right <= imgui.internal.get_current_window().work_rect.max.x:
        imgui.same_line()


def _combo(ui, label: str, current: int, items: list, disabled: set | frozenset = frozenset()) -> tuple[bool, int]:
    """imgui.combo sized by _fit, its frame kept under ``label`` and, while open, each choice under
    "label/choice" (_remember): a test opens it and picks a choice with mouse clicks as a user
    does. ``disabled``: indices shown greyed, not choosable. -> (changed, chosen index)."""
    _fit(label)
    items = [str(item) for item in items]
    opened = imgui.begin_combo(label, items[current] if 0 <= current < len(items) else "")
    _remember(ui, label)
    changed, chosen = False, current
    if opened:
        for index, item in enumerate(items):
            imgui.push_id(index)
            flags = imgui.SelectableFlags_.disabled if index in disabled else 0
            if imgui.selectable(item, index == current, flags)[0]:
                changed, chosen = index != current, index
            _remember(ui, f"{label}/{item}")
            imgui.pop_id()
        imgui.end_combo()
    return changed, chosen


def _remember(ui, label: str) -> None:
    """Keep the last widget's window rectangle in ui.rects[label] (x0, y0, x1, y1); for a
    field with +/- buttons it spans field, buttons and label, the field at its left end."""
    low, high = imgui.get_item_rect_min(), imgui.get_item_rect_max()
    ui.rects[label] = (low.x, low.y, high.x, high.y)


def _hint(text: str) -> None:
    """Greyed text that wraps at the panel's edge (text_disabled alone clips)."""
    imgui.push_text_wrap_pos(0.0)
    imgui.text_disabled(text)
    imgui.pop_text_wrap_pos()


def _flow(ui, key: str, parts: list[str]) -> None:
    """Texts side by side, each starting a new line only when it does not fit before the panel's
    edge: a figure stays with its unit ("12.3 ms" never breaks before "ms"). The parts are kept
    in ui.texts[key], each one's rectangle under "key/N" (N from 0)."""
    ui.texts[key] = list(parts)
    for number, part in enumerate(parts):
        if number:
            _same_line_if_fits(part, frame=False)
        imgui.text(part)
        _remember(ui, f"{key}/{number}")


def _path_line(ui, key: str, prefix: str, path, disabled: bool = False) -> None:
    """``prefix`` and ``path`` on one line, the path shortened in its middle to fit the panel
    (a wrapped path broke mid-word); hovering it shows the whole path. Kept under ``key``."""
    full = str(path)
    room = imgui.get_content_region_avail().x - imgui.calc_text_size(prefix).x
    shown = prefix + middle_ellipsis(full, room, lambda text: imgui.calc_text_size(text).x)
    (imgui.text_disabled if disabled else imgui.text)(shown)
    _remember(ui, key)
    if shown != prefix + full and imgui.is_item_hovered():
        imgui.set_tooltip(full)
        ui.tooltip = full


def _stats(ui, s, edit, gl_error: str | None) -> None:
    """The frame statistics (settings.FrameStats), the model's size, a GL error if one came."""
    figures = ([f"points {s.draw_ms:.1f} ms"] if s.drawn_by == "points"   # points need no sort (points.py)
               else [f"sort {s.sort_ms:.1f} ms", f"draw {s.draw_ms:.1f} ms"])
    # The panel is drawn inside the frame it times: the first frame has no rate yet, and an idle
    # window kept showing "0.0 FPS frame 0.0 ms" beside that frame's 6 s draw.
    rate = [f"{s.fps:.1f} FPS", f"frame {s.frame_ms:.1f} ms"] if s.frames else ["first frame"]
    _flow(ui, "stats", [*rate, *figures])
    _flow(ui, "model", [f"{edit.count} Gaussians", f"render scale {s.rendered_scale:.2f}"])
    if gl_error:
        imgui.text_colored(imgui.ImVec4(1, 0.6, 0.2, 1), f"GL reported {gl_error}")


def _detail(ui, view, drawing) -> None:
    """A large model's level of detail (detail.py): the splats drawn of the total and how they
    were chosen, and the "full detail always" switch."""
    if view.edit.count < level_of_detail.LOD_MIN_GAUSSIANS:
        return
    drawn, total, how = drawing.drawn
    _flow(ui, "detail", [f"drawn {drawn:,} / {total:,} splats", how])
    if drawing.detail is not None and drawing.detail.error:
        imgui.text_colored(imgui.ImVec4(1, 0.6, 0.2, 1), drawing.detail.error)
    _, view.settings.full_detail = imgui.checkbox("full detail always", view.settings.full_detail)
    _remember(ui, "full detail always")
    if imgui.is_item_hovered():
        imgui.set_tooltip("draw every Gaussian in every frame (slow on a model this large)")


def _view(ui, view) -> bool:
    """Camera, overlays, world up, training cameras; True when "screenshot" was pressed."""
    nav = view.nav
    _fit("field of view")
    changed, fov = imgui.slider_float("field of view", nav.fov_y_deg, 5.0, 150.0)
    if changed:
        nav.set_fov(fov)
        view.moved()
    _, view.settings.orbit = imgui.checkbox("orbit (O; double-click sets the pivot)", view.settings.orbit)
    _, view.settings.show_training_cameras = imgui.checkbox("training cameras (T)",
                                                            view.settings.show_training_cameras)
    imgui.same_line()
    _, view.settings.show_flags = imgui.checkbox("flags", view.settings.show_flags)
    imgui.text(f"speed {nav.speed:.3g} (scroll; Shift x4)")
    names = list(UP_AXES)
    current = up_axis_name(view.up)
    labels = names if current is not None else names + [up_label(view.up)]
    changed, index = _combo(ui, f"up, {view.up_source}", names.index(current) if current else len(names),
                            labels)
    if changed and index < len(names):
        view.set_up(UP_AXES[names[index]])
    if _button(ui, "frame the model (Home)"):
        view.frame_model()
    _same_line_if_fits("reset view (R)")
    if _button(ui, "reset view (R)"):
        view.reset_view()
    if view.cameras:
        _same_line_if_fits("< prev (P)")
        if _button(ui, "< prev (P)"):
            view.snap_to_camera(view.camera_index - 1)
        _same_line_if_fits("next (N) >")
        if _button(ui, "next (N) >"):
            view.snap_to_camera(view.camera_index + 1)
        names = [c.name for c in view.cameras]
        changed, index = _combo(ui, "camera", max(view.camera_index, 0), names)
        if changed:
            view.snap_to_camera(index)
    return _button(ui, "screenshot (F12)")


def _inspect(ui, view, drawing) -> bool:
    """Render mode, the reference comparison (drawing: the FrameDrawer), training photo, SH cap
    and splat scale; True when the coverage mode's "suggest flags" was pressed."""
    settings = view.settings
    suggest = False
    off = {i: mode_unavailable(mode, view.source) for i, mode in enumerate(RENDER_MODES)}
    off = {i: reason for i, reason in off.items() if reason}
    changed, index = _combo(ui, f"mode (1-{len(RENDER_MODES)})", RENDER_MODES.index(settings.mode),
                            list(RENDER_MODES), set(off))
    if changed:
        settings.mode = RENDER_MODES[index]
        view.status.drop("mode")
    if off:  # greyed in the list above; one line says why
        _hint(f"{', '.join(RENDER_MODES[i] for i in off)}: off, {NO_CAMERAS}")
        _remember(ui, "why modes are off")
    if settings.mode == "coverage":
        suggest = _coverage(ui, drawing.coverage)
    if settings.mode == "reference":
        views = ["heat-map", "side by side"]
        changed, index = _combo(ui, "show", views.index(settings.reference_view), views)
        if changed:
            settings.reference_view = views[index]
        worker = drawing.reference
        if worker is not None and worker.error:
            imgui.text_colored(imgui.ImVec4(1, 0.3, 0.3, 1), f"reference failed: {worker.error}")
        elif drawing.reference_psnr is not None:
            imgui.text(f"GL vs torch PSNR {drawing.reference_psnr:.2f} dB"
                       + (" (updating...)" if worker is not None and worker.busy else ""))
        else:
            imgui.text("torch reference rendering...")
    if view.cameras and view.source.scene is not None:
        views = list(PHOTO_VIEWS)
        changed, index = _combo(ui, "training photo", views.index(settings.photo), views)
        if changed:
            settings.photo = views[index]
        if settings.photo != "off":
            nearest = nearest_camera_index(view.cameras, view.current_camera())
            _hint(f"nearest training camera: {view.cameras[nearest].name}")
            if settings.photo == "blended":
                _fit("photo weight")
                _, settings.photo_alpha = imgui.slider_float("photo weight", settings.photo_alpha, 0.0, 1.0)
    _fit("SH degree cap")
    _, settings.sh_degree_cap = imgui.slider_int("SH degree cap", settings.sh_degree_cap, 0, 3)
    _fit("splat scale")
    _, settings.splat_scale = imgui.slider_float("splat scale", settings.splat_scale, 0.05, 2.0)
    settings.splat_scale = max(settings.splat_scale, 0.05)
    return suggest


def _coverage(ui, coverage) -> bool:
    """Colour bar of the coverage mode (coverage_mode.CoverageMode); True when its flag
    suggestion was asked for."""
    from inceptiongs.evaluation.coverage import ramp_colours

    if coverage.counting is not None:   # CoverageMode: a slice of the cameras a frame
        done, total = coverage.counting
        imgui.text_wrapped(f"counting the views that see each splat: {done} / {total} (the model's own "
                           f"colours until then)")
        if coverage.arrays is None:   # no counts yet: a bar of nothing would read as "seen by none"
            return False
    vmax = coverage.vmax
    imgui.text(f"views seeing each splat: 0 (dark) .. {vmax:.0f}+ (bright)")
    for step, colour in enumerate(ramp_colours(np.linspace(0, vmax, 6), vmax)):
        imgui.color_button(f"##bar{step}", imgui.ImVec4(*colour.tolist(), 1.0), 0, imgui.ImVec2(24, 12))
        imgui.same_line(0, 0)
    imgui.new_line()
    return _button(ui, "suggest flags (the 3 scarcest views)")


def _flags(ui, flags) -> None:
    """The flags (flags.FlagBook): flag this view, each flag's row (go, delete), rename."""
    if _button(ui, "flag this view (F)"):
        flags.flag_current_view()
    _hint("right-click: flag a view aimed at the point")
    _path_line(ui, "flags file", "saved in ", flags.file, disabled=True)
    # Each row's widgets are kept under "flag N/name", "flag N/go", "flag N/delete" (N from 1).
    for index, flag in enumerate(list(flags.items)):
        imgui.push_id(f"flag{index}")
        row = f"flag {index + 1}"
        if imgui.selectable(flag.name, flags.selected == index, size=imgui.ImVec2(140, 0))[0]:
            flags.selected = index
        _remember(ui, f"{row}/name")
        imgui.same_line()
        go = imgui.small_button("go")
        _remember(ui, f"{row}/go")
        if go:
            flags.jump_to(index)
        imgui.same_line()
        delete = imgui.small_button("delete")
        _remember(ui, f"{row}/delete")
        if delete:
            flags.delete(index)
            imgui.pop_id()
            break
        imgui.pop_id()
    if 0 <= flags.selected < len(flags.items):
        flag = flags.items[flags.selected]
        _fit("rename")
        changed, name = imgui.input_text("rename", flag.name, imgui.InputTextFlags_.enter_returns_true)
        _remember(ui, "rename")
        if changed and name.strip():
            flags.rename(flags.selected, name.strip())


def _training(ui, jobs) -> None:
    """The open run, the scene's runs, the job dialog and buttons, the live job (jobs.Jobs)."""
    run = jobs.training
    no_run = "(none: train first)" if jobs.view.source.scene is not None else "(none: a bare model has no runs)"
    _path_line(ui, "open run", "open run: ", jobs.run_dir or no_run)
    _runs(ui, jobs)
    _poorly_fit(ui, jobs)
    if run is None or not run.alive:
        _job_settings(ui, jobs)
        no_training = why_no_training(jobs.view.source, jobs.factory)
        _job_button(ui, jobs, "train (new run)", "training", no_training)
        blocked = resume_blocked_reason(jobs.run_dir)
        if can_resume(jobs.run_dir) or blocked is not None:
            _same_line_if_fits("resume")
            _job_button(ui, jobs, "resume", "resume", blocked)  # shown, greyed, with the reason: not hidden
        _same_line_if_fits("Bootstrap flagged views")
        no_bootstrap = bootstrap_unavailable(jobs.view.source, jobs.run_dir)
        _job_button(ui, jobs, "Bootstrap flagged views", "bootstrap", no_bootstrap)
        outlook = outlook_before_repair(jobs.run_dir) if no_bootstrap is None else None
        if outlook is not None:   # before the user spends minutes on a repair (bootstrap/outlook.py)
            _hint(outlook)
            _remember(ui, "repair outlook")
        if blocked is not None:
            _hint(f"no resume here: {blocked}")
            _remember(ui, "why no resume")
        for reason, label in ((no_training, "why no training"), (no_bootstrap, "why no bootstrap")):
            if reason is not None:
                _hint(reason)
                _remember(ui, label)
    else:
        # Each button says what it did in the notification area: "training into ..." stayed
        # there through a pause.
        kind = run.plan.kind
        if run.control.pause.is_set():
            if _button(ui, "continue"):
                run.resume()
                jobs.status.text = f"{kind} continued"
        elif _button(ui, "pause"):
            run.pause()
            jobs.status.text = f"{kind} paused at iteration {run.progress.iteration} (continue to go on)"
        _same_line_if_fits("stop")
        if _button(ui, "stop"):
            run.control.stop.set()
            jobs.status.text = f"{kind} stopping: it saves its model and checkpoint"
    if run is None:
        if draw_verdict(ui, jobs.verdict):  # an opened bootstrap result
            jobs.ask("baseline")
        return
    _fit("job's share of the CPU")
    _, jobs.training_utilisation = imgui.slider_float("job's share of the CPU", jobs.training_utilisation,
                                                      0.5, MAX_TRAINING_UTILISATION, "%.2f")
    _remember(ui, "job's share of the CPU")
    if jobs.out_dir is not None:
        _path_line(ui, "job writes", "job writes: ", jobs.out_dir)
    _progress(jobs, run)
    if draw_verdict(ui, jobs.verdict, offer_baseline=not run.alive):
        jobs.ask("baseline")
    draw_plots(ui, run.progress)


def _job_button(ui, jobs, label: str, kind: str, off: str | None) -> None:
    """A button that asks for a job (jobs.ask: the question follows, nothing runs before
    "start the job"). ``off``: why it cannot run here; the button is then drawn grey (not the
    live buttons' blue dimmed, which read as live) and a click on it says why."""
    if off is None:
        if _button(ui, label):
            jobs.ask(kind)
        return
    grey = imgui.ImVec4(*OFF_BUTTON_COLOR, 1.0)
    for slot in (imgui.Col_.button, imgui.Col_.button_hovered, imgui.Col_.button_active):
        imgui.push_style_color(slot, grey)
    imgui.push_style_color(imgui.Col_.text, imgui.ImVec4(*OFF_TEXT_COLOR, 1.0))
    imgui.begin_disabled()
    _button(ui, label)
    imgui.end_disabled()
    imgui.pop_style_color(4)
    if imgui.is_item_hovered(imgui.HoveredFlags_.allow_when_disabled):
        imgui.set_tooltip(off)
        if imgui.is_mouse_clicked(imgui.MouseButton_.left):
            jobs.status.text = off


def draw_job_question(ui, jobs) -> None:
    """The question a job button asks (jobs.pending): what will run, where and for how long, with
    "start the job" and "do not start"; modal, so no other click lands meanwhile. The buttons'
    rectangles are kept in ui.rects under their labels."""
    if jobs.pending is None:
        return
    if not imgui.is_popup_open(JOB_QUESTION):
        imgui.open_popup(JOB_QUESTION)
    width, height = imgui.get_io().display_size
    imgui.set_next_window_pos(imgui.ImVec2(width * 0.5, height * 0.5), imgui.Cond_.always, imgui.ImVec2(0.5, 0.5))
    imgui.set_next_window_size_constraints(imgui.ImVec2(0, 0), imgui.ImVec2(min(QUESTION_WIDTH, width - 20),
                                                                           max(height - 20, 1)))
    if not imgui.begin_popup_modal(JOB_QUESTION, None, imgui.WindowFlags_.always_auto_resize)[0]:
        return
    imgui.push_text_wrap_pos(imgui.get_cursor_pos_x() + min(QUESTION_WIDTH, width - 20) - 30)
    imgui.text(jobs.pending.question)
    imgui.pop_text_wrap_pos()
    start = _button(ui, START_JOB)
    imgui.same_line()
    cancel = _button(ui, DO_NOT_START)
    pos, size = imgui.get_window_pos(), imgui.get_window_size()
    ui.rects[JOB_QUESTION] = (pos.x, pos.y, pos.x + size.x, pos.y + size.y)
    if start or cancel:
        imgui.close_current_popup()
        if start:
            jobs.confirm()
        else:
            jobs.cancel()
    imgui.end_popup()


def poorly_fit_line(count: int) -> str:
    """"1 training photo fits poorly (orange frustum)", "3 training photos fit poorly (...)"."""
    if count == 1:
        return "1 training photo fits poorly (orange frustum)"
    return f"{count} training photos fit poorly (orange frustums)"


def _poorly_fit(ui, jobs) -> None:
    """The open run's training photos it fits poorly (view_fit.json): how many, and a button that
    steps through them (their frustums are drawn in POORLY_FIT_COLOR)."""
    poorly_fit = jobs.poorly_fit.psnr
    if not poorly_fit:
        return
    worst = ", ".join(f"{name} {psnr:.1f} dB" for name, psnr in list(poorly_fit.items())[:3])
    line = poorly_fit_line(len(poorly_fit))
    imgui.text_colored(imgui.ImVec4(*POORLY_FIT_COLOR, 1.0), line)
    _remember(ui, "poorly fit photos")
    ui.texts["poorly fit photos"] = line
    if imgui.is_item_hovered():
        imgui.set_tooltip(f"more than {POOR_FIT_MARGIN_DB:g} dB below the run's median training photo: they "
                          f"disagree with the others (moved objects, wrong poses, exposure changes) or show what "
                          f"no other photo sees. Worst: {worst}")
    if _button(ui, "next poorly fit photo"):
        jobs.poorly_fit.next_photo(jobs.view, jobs.status)
    settings = jobs.settings
    leave_out = bool(settings.exclude_photos) and set(settings.exclude_photos) == set(poorly_fit)
    changed, leave_out = imgui.checkbox("leave them out of the next run", leave_out)
    _remember(ui, "leave them out of the next run")
    if changed:
        settings.exclude_photos = list(poorly_fit) if leave_out else []


def _runs(ui, jobs) -> None:
    """Where new runs go (shown in full, the folder editable, as --runs), then the scene's runs
    from every place runs are written, newest first, with their scores; choosing one shows it
    and makes it the open run."""
    source = jobs.view.source
    if source.scene is not None and source.kind == "scene":
        _fit("runs folder")
        changed, text = imgui.input_text("runs folder", str(runs_folder(source.runs_dir)),
                                         imgui.InputTextFlags_.enter_returns_true)
        _remember(ui, "runs folder")
        if changed and text.strip():
            jobs.status.text = choose_runs_folder(source, Path(text.strip()))
        _hint(f"a new run goes to {new_train_dir(source.scene.root, source.runs_dir)}")
        _remember(ui, "new run goes to")
    runs = list(reversed(source.runs))  # newest first
    if not runs:
        return
    names = [jobs.run_labels.label(run) for run in runs]
    current = runs.index(jobs.run_dir) if jobs.run_dir in runs else -1
    changed, index = _combo(ui, "runs of this scene", current, names)
    if changed and 0 <= index < len(runs) and runs[index] != jobs.run_dir:
        jobs.open_run(runs[index])


def _job_settings(ui, jobs) -> None:
    """The job dialog: the command lines' main settings. Each field's rectangle is kept under its
    label (_remember), so a test can click into it and type as a user does."""
    settings = jobs.settings
    if jobs.fold_settings:  # a job started: its progress, then its closing line, show first
        imgui.set_next_item_open(False, imgui.Cond_.always)
        jobs.fold_settings = False
    opened = imgui.tree_node("job settings")
    _remember(ui, "job settings")
    if not opened:
        return
    imgui.text_disabled("stage I (train)")
    settings.minutes = _optional_minutes(ui, "time budget min", "time budget", settings.minutes, 3.0)
    _fit("schedule iterations")
    _, settings.iterations = imgui.input_int("schedule iterations", settings.iterations, 100, 1000)
    _remember(ui, "schedule iterations")
    settings.iterations = max(settings.iterations, SIZED_TO_BUDGET)
    _hint(_schedule_hint(settings))
    _fit("downscale")
    _, settings.downscale = imgui.input_int("downscale", settings.downscale)
    _remember(ui, "downscale")
    settings.downscale = max(settings.downscale, 1)
    protocols = ["none", "unstructured", "llff"]
    changed, index = _combo(ui, "held-out views", protocols.index(settings.protocol), protocols)
    if changed:
        settings.protocol = protocols[index]
    changed, index = _combo(ui, "strategy", STRATEGY_NAMES.index(settings.strategy), list(STRATEGY_NAMES))
    if changed:
        settings.strategy = STRATEGY_NAMES[index]
    sky_on = FreeSpace.sky_shell if settings.sky_shell is None else settings.sky_shell
    changed, sky_on = imgui.checkbox("sky shell (far backdrop)", sky_on)
    _remember(ui, "sky shell")
    if imgui.is_item_hovered():
        imgui.set_tooltip("far Gaussians where the photos show no sparse point: a place for the sky")
    if changed:
        settings.sky_shell = sky_on
    imgui.text_disabled("stage II (bootstrap)")
    settings.bootstrap_minutes = _optional_minutes(ui, "bootstrap budget min", "bootstrap budget",
                                                   settings.bootstrap_minutes, 4.0)
    _fit("refinement steps")
    _, settings.bootstrap_iterations = imgui.input_int("refinement steps", settings.bootstrap_iterations, 10, 100)
    _remember(ui, "refinement steps")
    settings.bootstrap_iterations = max(settings.bootstrap_iterations, 1)
    _fit("K nearest views (0: default)")
    _, settings.k = imgui.input_int("K nearest views (0: default)", settings.k)
    _remember(ui, "K nearest views (0: default)")
    _fit("L poses each (0: default)")
    _, settings.l = imgui.input_int("L poses each (0: default)", settings.l)
    _remember(ui, "L poses each (0: default)")
    settings.k, settings.l = max(settings.k, 0), max(settings.l, 0)
    _fit("prior min (if none)")
    _, settings.prior_minutes = imgui.input_float("prior min (if none)", settings.prior_minutes, 0.5, 1.0, "%.1f")
    _remember(ui, "prior min (if none)")
    settings.prior_minutes = _minutes_typed(settings.prior_minutes)
    _, settings.follow_outlook = imgui.checkbox("follow the outlook", settings.follow_outlook)
    _remember(ui, "follow the outlook")
    if imgui.is_item_hovered():
        imgui.set_tooltip("photo steps only when there is nothing to repair, and first while stage I still "
                          "gains more than 0.5 dB a minute; off: virtual views from the first step")
    imgui.tree_pop()


def _schedule_hint(settings) -> str:
    """What "schedule iterations" does with the value it holds (as `inceptiongs train`)."""
    if settings.iterations != SIZED_TO_BUDGET:
        return "a fixed schedule (0: sized to the budget)"
    if settings.minutes is None:
        return f"0: the default {schedule_length(None, None)[0]} steps (no budget)"
    return (f"0: sized to the budget (first guess {schedule_length(None, settings.minutes)[0]} steps, "
            "re-sized from the measured rate)")


def _optional_minutes(ui, key: str, checkbox: str, minutes, default: float):
    """A budget that can be switched off (None: run the whole schedule): the checkbox, then the
    minutes labelled "min" beside it (its rectangle kept under ``key``)."""
    changed, on = imgui.checkbox(checkbox, minutes is not None)
    _remember(ui, checkbox)
    if changed:
        minutes = default if on else None
    if minutes is not None:
        imgui.same_line()
        label = f"min##{key}"  # the checkbox names the budget; "##": a widget id of its own
        _fit(label)
        _, minutes = imgui.input_float(label, minutes, 0.5, 1.0, "%.1f")
        _remember(ui, key)
        minutes = _minutes_typed(minutes)
    return minutes


def _minutes_typed(value: float) -> float:
    """imgui's float fields hold float32: a typed 0.7 reads back 0.699999988. Rounded to the
    hundredth (0.6 s, finer than any budget needs) the configs store what the user typed."""
    return max(round(float(value), 2), 0.1)


def _progress(jobs, run) -> None:
    progress, plan = run.progress, run.plan
    if not run.alive and jobs.reported:
        imgui.text_wrapped(jobs.closing)  # the closing line: time, iteration, final scores
    else:
        done = progress.iteration - plan.start_iteration
        total = plan.steps
        # The bar counts iterations as the status and the trainer do ("iteration 410 / 1499"),
        # a resume's starting point named beside it.
        label = run.state + (f", resumed at iteration {plan.start_iteration}" if plan.resumed else "")
        progress.bar_text = f"iteration {progress.iteration}" + (f" / {plan.end_iteration}" if total else "")
        if total:
            if plan.config is not None:
                label += ", schedule sized to the budget"
            imgui.progress_bar(min(max(done / total, 0.0), 1.0), imgui.ImVec2(-1, 0), progress.bar_text)
        else:
            label += f": {progress.bar_text}"
        imgui.text_wrapped(label)
        eta = eta_seconds(progress.iteration, plan, progress.iterations_per_second, run.elapsed_s)
        budget = "" if plan.budget_s is None else f" of {format_duration(plan.budget_s)}"
        imgui.text_wrapped(f"elapsed {format_duration(run.elapsed_s)}{budget}  ETA {format_duration(eta)}  "
                   f"{progress.iterations_per_second:.2f} it/s")
        imgui.text(f"{progress.gaussian_count} Gaussians")
        if progress.message:
            imgui.text_wrapped(progress.message)
    if run.error:
        imgui.text_colored(imgui.ImVec4(1, 0.3, 0.3, 1), f"job failed: {run.error}")


def _edit(ui, editor) -> None:
    """The edit tools' settings, thresholds, delete / undo / redo, crop box, save (editing.Editor)."""
    settings, edit = editor.view.settings, editor.view.edit
    tools = list(EDIT_TOOLS)
    changed, index = _combo(ui, "tool (left mouse)", tools.index(settings.edit_tool), tools)
    if changed:
        settings.edit_tool = tools[index]
    modes = ["replace", "add", "subtract"]
    changed, index = _combo(ui, "selection", modes.index(settings.selection_mode), modes)
    if changed:
        settings.selection_mode = modes[index]
    if settings.edit_tool == "gizmo":  # what dragging a handle at the selection's centre does
        changed, index = _combo(ui, "gizmo drag", GIZMO_MODES.index(settings.gizmo_mode), list(GIZMO_MODES))
        if changed:
            settings.gizmo_mode = GIZMO_MODES[index]
    if settings.edit_tool == "brush":
        _fit("brush radius px")
        _, settings.brush_radius = imgui.slider_float("brush radius px", settings.brush_radius, 2.0, 200.0)
    _fit("opacity below")
    _, settings.max_opacity = imgui.slider_float("opacity below", settings.max_opacity, 0.0, 1.0)
    _fit("or size above")
    _, settings.min_size = imgui.input_float("or size above", settings.min_size)
    if _button(ui, "select by thresholds"):
        editor.threshold_select()
    imgui.text(f"{int(edit.selected.sum())} selected")
    if _button(ui, "delete (Del)"):
        editor.delete_selection()
    _same_line_if_fits("undo (Ctrl+Z)")
    if _button(ui, "undo (Ctrl+Z)"):
        editor.undo()
    _same_line_if_fits("redo (Ctrl+Y)")
    if _button(ui, "redo (Ctrl+Y)"):
        editor.redo()
    changed, enabled = imgui.checkbox("crop box (drag its handles)", settings.crop_enabled)
    _remember(ui, "crop box (drag its handles)")
    if changed:
        editor.enable_crop(enabled)
    if settings.crop_enabled:
        _fit("min")
        _, settings.crop_min = imgui.input_float3("min", settings.crop_min)
        _remember(ui, "min")  # x's field at its left end
        _fit("max")
        _, settings.crop_max = imgui.input_float3("max", settings.crop_max)
        _remember(ui, "max")
        if _button(ui, "crop to box"):
            editor.apply_crop()
        _same_line_if_fits("fit to the model")
        if _button(ui, "fit to the model"):
            editor.fit_crop_box()
    _fit("file")
    _, editor.saving.path = imgui.input_text("file", editor.saving.path)
    _remember(ui, "file")
    if _button(ui, "save PLY"):
        try:
            editor.saving.save_ply(editor.saving.path)
        except Exception as exc:  # noqa: BLE001 - shown in the status line
            editor.status.text = f"save failed: {exc}"
