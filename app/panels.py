"""The imgui panels: view, inspect, flags, training, edit. Each panel reads and changes the
Viewer's state through its public methods; nothing here owns state of its own."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui, implot

from .drawing import POORLY_FIT_COLOR, SELECTION_COLOR
from .jobs import SIZED_TO_BUDGET, start_bootstrap
from .navigation import UP_AXES, up_axis_name, up_label
from .progress import eta_seconds, format_duration
from .runs import can_resume, resume_blocked_reason
from inceptiongs.train.config import STRATEGY_NAMES, TrainConfig, schedule_length
from inceptiongs.train.view_fit import POOR_FIT_MARGIN_DB

from .settings import EDIT_TOOLS, KEY_BINDINGS, MAX_TRAINING_UTILISATION, PHOTO_VIEWS, RENDER_MODES

TOOL_LINE_WIDTH = 2.0
PANEL_MARGIN = 10
PANEL_WIDTH = 400
PANEL_MIN_WIDTH = 300
# A widget beside a long label keeps at least this width (its label may then wrap the panel).
MIN_ITEM_WIDTH = 60

# Series with fewer points than this are drawn with a marker at each point (a bootstrap's curve
# starts with its single first evaluation, which a line alone does not show).
SHORT_SERIES_POINTS = 4
# The job's logged terms worth a curve, grouped by unit: (plot title, y label, metric names).
PLOTS = (("training loss", "loss", ("loss", "l1")),
         ("Gaussians", "count", ("num_gaussians",)))


def draw_tool_feedback(viewer) -> None:
    """What the edit tool will select, drawn over the scene: the rectangle being dragged, the
    brush circle at the cursor, the lasso's path."""
    tool, controls = viewer.settings.edit_tool, viewer.input
    cursor = controls.last_cursor
    if tool == "none" or cursor is None:
        return
    draw = imgui.get_foreground_draw_list()
    color = imgui.get_color_u32(imgui.ImVec4(*SELECTION_COLOR, 1.0))
    dragging = controls.dragging_button is not None and controls.drag_start is not None
    if tool == "rectangle" and dragging:
        (x0, y0), (x1, y1) = controls.drag_start, cursor
        draw.add_rect(imgui.ImVec2(min(x0, x1), min(y0, y1)), imgui.ImVec2(max(x0, x1), max(y0, y1)), color,
                      0.0, TOOL_LINE_WIDTH)
    elif tool == "brush":
        # The brush radius is in framebuffer pixels; the cursor in window pixels.
        scale = viewer.window_to_framebuffer(1.0, 1.0)[0]
        draw.add_circle(imgui.ImVec2(*cursor), viewer.settings.brush_radius / max(scale, 1e-6), color, 0,
                        TOOL_LINE_WIDTH)
    elif tool == "lasso" and dragging and controls.lasso:
        points = [imgui.ImVec2(x, y) for x, y in controls.lasso + [cursor]]
        draw.add_polyline(points, color, TOOL_LINE_WIDTH, 0)


def draw_panels(viewer) -> None:
    width, height = imgui.get_io().display_size
    # The panel follows the window: full height, a width the user may drag, never past the
    # window; long lines wrap instead of clipping.
    imgui.set_next_window_pos(imgui.ImVec2(PANEL_MARGIN, PANEL_MARGIN), imgui.Cond_.always)
    imgui.set_next_window_size_constraints(
        imgui.ImVec2(min(PANEL_MIN_WIDTH, width - 2 * PANEL_MARGIN), height - 2 * PANEL_MARGIN),
        imgui.ImVec2(max(width - 2 * PANEL_MARGIN, 1), height - 2 * PANEL_MARGIN))
    imgui.set_next_window_size(imgui.ImVec2(PANEL_WIDTH, height - 2 * PANEL_MARGIN), imgui.Cond_.first_use_ever)
    draw_tool_feedback(viewer)
    if not viewer.settings.show_panel:  # Tab hid it: the scene and the tools' outlines only
        if viewer.show_help:
            _help(viewer)
        return
    imgui.begin("InceptionGS")
    _stats(viewer)
    if imgui.small_button("keys and mouse (H)"):
        viewer.show_help = not viewer.show_help
    if _header(viewer, "View", imgui.TreeNodeFlags_.default_open):
        _view(viewer)
    if _header(viewer, "Inspect", imgui.TreeNodeFlags_.default_open):
        _inspect(viewer)
    if _header(viewer, "Flags", imgui.TreeNodeFlags_.default_open):
        _flags(viewer)
    if _header(viewer, "Training", imgui.TreeNodeFlags_.default_open):
        _training(viewer)
    if _header(viewer, "Edit"):
        _edit(viewer)
    if viewer.status:
        imgui.separator()
        imgui.text_wrapped(viewer.status)
    viewer.panel_layout = _layout()
    imgui.end()
    if viewer.show_help:
        _help(viewer)


def _header(viewer, label: str, flags: int = 0) -> bool:
    """imgui.collapsing_header, its rectangle kept under its label (a test opens it with a click)."""
    opened = imgui.collapsing_header(label, flags)
    _remember(viewer, label)
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


def _help(viewer) -> None:
    """The key bindings, over the middle of the window (H / F1 or its close button hides it)."""
    width, height = imgui.get_io().display_size
    imgui.set_next_window_pos(imgui.ImVec2(width * 0.5, height * 0.5), imgui.Cond_.always, imgui.ImVec2(0.5, 0.5))
    imgui.set_next_window_bg_alpha(0.92)
    opened, viewer.show_help = imgui.begin("keys and mouse (H / F1)", True, imgui.WindowFlags_.always_auto_resize)
    if opened:
        if imgui.begin_table("bindings", 2):
            for keys, action in KEY_BINDINGS:
                imgui.table_next_row()
                imgui.table_next_column()
                imgui.text(keys)
                imgui.table_next_column()
                imgui.text(action)
            imgui.end_table()
    imgui.end()


def _button(viewer, label: str) -> bool:
    """imgui.button, its window rectangle kept in viewer.ui_rects[label] (x0, y0, x1, y1): a
    test clicks it there with mouse events as GLFW delivers them."""
    pressed = imgui.button(label)
    _remember(viewer, label)
    return pressed


def _fit(label: str) -> None:
    """The next widget as wide as the panel leaves beside its label (imgui's default, 65 % of the
    panel, pushed long labels past its edge), at least MIN_ITEM_WIDTH."""
    shown = label.split("##")[0]
    label_width = imgui.calc_text_size(shown).x + imgui.get_style().item_inner_spacing.x if shown else 0.0
    imgui.set_next_item_width(max(imgui.get_content_region_avail().x - label_width, MIN_ITEM_WIDTH))


def _same_line_if_fits(label: str) -> None:
    """Put the button ``label`` on the line of the last widget when it fits before the panel's
    edge, else start a new line (a fixed row of buttons ran past a narrow panel)."""
    style = imgui.get_style()
    width = imgui.calc_text_size(label).x + 2 * style.frame_padding.x
    right = imgui.get_item_rect_max().x + style.item_spacing.x + width
    if right <= imgui.internal.get_current_window().work_rect.max.x:
        imgui.same_line()


def _combo(viewer, label: str, current: int, items: list) -> tuple[bool, int]:
    """imgui.combo sized by _fit, its frame kept under ``label`` and, while open, each choice under
    "label/choice" (_remember): a test opens it and picks a choice with mouse clicks as a user
    does. -> (changed, chosen index)."""
    _fit(label)
    items = [str(item) for item in items]
    opened = imgui.begin_combo(label, items[current] if 0 <= current < len(items) else "")
    _remember(viewer, label)
    changed, chosen = False, current
    if opened:
        for index, item in enumerate(items):
            imgui.push_id(index)
            if imgui.selectable(item, index == current)[0]:
                changed, chosen = index != current, index
            _remember(viewer, f"{label}/{item}")
            imgui.pop_id()
        imgui.end_combo()
    return changed, chosen


def _remember(viewer, label: str) -> None:
    """Keep the last widget's window rectangle in viewer.ui_rects[label] (x0, y0, x1, y1); for a
    field with +/- buttons it spans field, buttons and label, the field at its left end."""
    low, high = imgui.get_item_rect_min(), imgui.get_item_rect_max()
    viewer.ui_rects[label] = (low.x, low.y, high.x, high.y)


def _hint(text: str) -> None:
    """Greyed text that wraps at the panel's edge (text_disabled alone clips)."""
    imgui.push_text_wrap_pos(0.0)
    imgui.text_disabled(text)
    imgui.pop_text_wrap_pos()


def _stats(viewer) -> None:
    s = viewer.stats
    imgui.text_wrapped(f"{s.fps:5.1f} FPS  frame {s.frame_ms:5.1f} ms  sort {s.sort_ms:5.1f} ms  "
                       f"draw {s.draw_ms:5.1f} ms")
    imgui.text_wrapped(f"{viewer.edit.count} Gaussians  render scale {s.rendered_scale:.2f}")
    if viewer.last_gl_error:
        imgui.text_colored(imgui.ImVec4(1, 0.6, 0.2, 1), f"GL reported {viewer.last_gl_error}")


def _view(viewer) -> None:
    nav = viewer.nav
    _fit("field of view")
    changed, fov = imgui.slider_float("field of view", nav.fov_y_deg, 5.0, 150.0)
    if changed:
        nav.set_fov(fov)
        viewer.moved()
    _, viewer.settings.orbit = imgui.checkbox("orbit (O; double-click sets the pivot)", viewer.settings.orbit)
    _, viewer.settings.show_training_cameras = imgui.checkbox("training cameras (T)",
                                                              viewer.settings.show_training_cameras)
    imgui.same_line()
    _, viewer.settings.show_flags = imgui.checkbox("flags", viewer.settings.show_flags)
    imgui.text(f"speed {nav.speed:.3g} (scroll; Shift x4)")
    names = list(UP_AXES)
    current = up_axis_name(viewer.up)
    labels = names if current is not None else names + [up_label(viewer.up)]
    changed, index = _combo(viewer, f"up, {viewer.up_source}", names.index(current) if current else len(names),
                            labels)
    if changed and index < len(names):
        viewer.set_up(UP_AXES[names[index]])
    if _button(viewer, "frame the model (Home)"):
        viewer.frame_model()
    _same_line_if_fits("reset view (R)")
    if _button(viewer, "reset view (R)"):
        viewer.reset_view()
    if viewer.cameras:
        _same_line_if_fits("< prev (P)")
        if _button(viewer, "< prev (P)"):
            viewer.snap_to_camera(viewer.camera_index - 1)
        _same_line_if_fits("next (N) >")
        if _button(viewer, "next (N) >"):
            viewer.snap_to_camera(viewer.camera_index + 1)
        names = [c.name for c in viewer.cameras]
        changed, index = _combo(viewer, "camera", max(viewer.camera_index, 0), names)
        if changed:
            viewer.snap_to_camera(index)
    if _button(viewer, "screenshot (F12)"):
        viewer.save_screenshot()


def _inspect(viewer) -> None:
    settings = viewer.settings
    changed, index = _combo(viewer, f"mode (1-{len(RENDER_MODES)})", RENDER_MODES.index(settings.mode),
                            list(RENDER_MODES))
    if changed:
        settings.mode = RENDER_MODES[index]
    if settings.mode == "coverage":
        _coverage(viewer)
    if settings.mode == "reference":
        views = ["heat-map", "side by side"]
        changed, index = _combo(viewer, "show", views.index(settings.reference_view), views)
        if changed:
            settings.reference_view = views[index]
        worker = viewer.drawing.reference
        if worker is not None and worker.error:
            imgui.text_colored(imgui.ImVec4(1, 0.3, 0.3, 1), f"reference failed: {worker.error}")
        elif viewer.drawing.reference_psnr is not None:
            imgui.text(f"GL vs torch PSNR {viewer.drawing.reference_psnr:.2f} dB"
                       + (" (updating...)" if worker is not None and worker.busy else ""))
        else:
            imgui.text("torch reference rendering...")
    if viewer.cameras and viewer.source.scene is not None:
        views = list(PHOTO_VIEWS)
        changed, index = _combo(viewer, "training photo", views.index(settings.photo), views)
        if changed:
            settings.photo = views[index]
        if settings.photo != "off":
            nearest = viewer.nearest_camera_index(viewer.current_camera())
            _hint(f"nearest training camera: {viewer.cameras[nearest].name}")
            if settings.photo == "blended":
                _fit("photo weight")
                _, settings.photo_alpha = imgui.slider_float("photo weight", settings.photo_alpha, 0.0, 1.0)
    _fit("SH degree cap")
    _, settings.sh_degree_cap = imgui.slider_int("SH degree cap", settings.sh_degree_cap, 0, 3)
    _fit("splat scale")
    _, settings.splat_scale = imgui.slider_float("splat scale", settings.splat_scale, 0.05, 2.0)
    settings.splat_scale = max(settings.splat_scale, 0.05)


def _coverage(viewer) -> None:
    """Colour bar of the coverage mode and the flag suggestion."""
    from inceptiongs.evaluation.coverage import ramp_colours

    vmax = viewer.coverage.vmax
    imgui.text(f"views seeing each splat: 0 (dark) .. {vmax:.0f}+ (bright)")
    for step, colour in enumerate(ramp_colours(np.linspace(0, vmax, 6), vmax)):
        imgui.color_button(f"##bar{step}", imgui.ImVec4(*colour.tolist(), 1.0), 0, imgui.ImVec2(24, 12))
        imgui.same_line(0, 0)
    imgui.new_line()
    if _button(viewer, "suggest flags (the 3 scarcest views)"):
        viewer.suggest_flags()


def _flags(viewer) -> None:
    if _button(viewer, "flag this view (F)"):
        viewer.flag_current_view()
    _hint("right-click: flag a view aimed at the point")
    _hint(str(viewer.flags_file))
    # Each row's widgets are kept under "flag N/name", "flag N/go", "flag N/delete" (N from 1).
    for index, flag in enumerate(list(viewer.flags)):
        imgui.push_id(f"flag{index}")
        row = f"flag {index + 1}"
        if imgui.selectable(flag.name, viewer.selected_flag == index, size=imgui.ImVec2(140, 0))[0]:
            viewer.selected_flag = index
        _remember(viewer, f"{row}/name")
        imgui.same_line()
        go = imgui.small_button("go")
        _remember(viewer, f"{row}/go")
        if go:
            viewer.jump_to_flag(index)
        imgui.same_line()
        delete = imgui.small_button("delete")
        _remember(viewer, f"{row}/delete")
        if delete:
            viewer.delete_flag(index)
            imgui.pop_id()
            break
        imgui.pop_id()
    if 0 <= viewer.selected_flag < len(viewer.flags):
        flag = viewer.flags[viewer.selected_flag]
        _fit("rename")
        changed, name = imgui.input_text("rename", flag.name, imgui.InputTextFlags_.enter_returns_true)
        _remember(viewer, "rename")
        if changed and name.strip():
            viewer.rename_flag(viewer.selected_flag, name.strip())


def _training(viewer) -> None:
    run = viewer.training
    imgui.text_wrapped(f"open run: {viewer.run_dir or '(none: train first)'}")
    _runs(viewer)
    _poorly_fit(viewer)
    if run is None or not run.alive:
        _job_settings(viewer)
        if _button(viewer, "train (new run)"):
            viewer.start_training()
        blocked = resume_blocked_reason(viewer.run_dir)
        if can_resume(viewer.run_dir) or blocked is not None:
            _same_line_if_fits("resume")
            imgui.begin_disabled(blocked is not None)  # shown, greyed, with the reason: not hidden
            if _button(viewer, "resume"):
                viewer.resume_training()
            imgui.end_disabled()
            if blocked is not None and imgui.is_item_hovered(imgui.HoveredFlags_.allow_when_disabled):
                imgui.set_tooltip(blocked)
        _same_line_if_fits("Bootstrap flagged views")
        if _button(viewer, "Bootstrap flagged views"):
            start_bootstrap(viewer)
        if blocked is not None:
            _hint(f"no resume here: {blocked}")
            _remember(viewer, "why no resume")
    else:
        if run.control.pause.is_set():
            if _button(viewer, "continue"):
                run.resume()
        elif _button(viewer, "pause"):
            run.pause()
        _same_line_if_fits("stop")
        if _button(viewer, "stop"):
            run.control.stop.set()
    if run is None:
        return
    settings = viewer.settings
    _fit("job's share of the CPU")
    _, settings.training_utilisation = imgui.slider_float("job's share of the CPU", settings.training_utilisation,
                                                          0.5, MAX_TRAINING_UTILISATION, "%.2f")
    _remember(viewer, "job's share of the CPU")
    if viewer.job_out_dir is not None:
        imgui.text_wrapped(f"job writes: {viewer.job_out_dir}")
    _progress(viewer, run)
    _plots(run.progress)


def _poorly_fit(viewer) -> None:
    """The open run's training photos it fits poorly (view_fit.json): how many, and a button that
    steps through them (their frustums are drawn in POORLY_FIT_COLOR)."""
    if not viewer.poorly_fit:
        return
    worst = ", ".join(f"{name} {psnr:.1f} dB" for name, psnr in list(viewer.poorly_fit.items())[:3])
    imgui.text_colored(imgui.ImVec4(*POORLY_FIT_COLOR, 1.0),
                       f"{len(viewer.poorly_fit)} training photos fit poorly (orange frustums)")
    _remember(viewer, "poorly fit photos")
    if imgui.is_item_hovered():
        imgui.set_tooltip(f"more than {POOR_FIT_MARGIN_DB:g} dB below the run's median training photo: they "
                          f"disagree with the others (moved objects, wrong poses, exposure changes) or show what "
                          f"no other photo sees. Worst: {worst}")
    if _button(viewer, "next poorly fit photo"):
        viewer.next_poorly_fit_photo()
    settings = viewer.job_settings
    leave_out = bool(settings.exclude_photos) and set(settings.exclude_photos) == set(viewer.poorly_fit)
    changed, leave_out = imgui.checkbox("leave them out of the next run", leave_out)
    _remember(viewer, "leave them out of the next run")
    if changed:
        settings.exclude_photos = list(viewer.poorly_fit) if leave_out else []


def _runs(viewer) -> None:
    """The scene's runs (its jobs' and the command line's ./runs/NAME), newest last; choosing one
    shows it and makes it the open run."""
    runs = viewer.source.runs
    if not runs:
        return
    names = [f"{run.name}  ({run.parent})" for run in runs]
    current = runs.index(viewer.run_dir) if viewer.run_dir in runs else -1
    changed, index = _combo(viewer, "runs of this scene", current, names)
    if changed and 0 <= index < len(runs) and runs[index] != viewer.run_dir:
        viewer.open_run(runs[index])


def _job_settings(viewer) -> None:
    """The job dialog: the command lines' main settings. Each field's rectangle is kept under its
    label (_remember), so a test can click into it and type as a user does."""
    settings = viewer.job_settings
    if viewer.fold_job_settings:  # a job started: its progress, then its closing line, show first
        imgui.set_next_item_open(False, imgui.Cond_.always)
        viewer.fold_job_settings = False
    opened = imgui.tree_node("job settings")
    _remember(viewer, "job settings")
    if not opened:
        return
    imgui.text_disabled("stage I (train)")
    settings.minutes = _optional_minutes(viewer, "time budget min", "time budget", settings.minutes, 3.0)
    _fit("schedule iterations")
    _, settings.iterations = imgui.input_int("schedule iterations", settings.iterations, 100, 1000)
    _remember(viewer, "schedule iterations")
    settings.iterations = max(settings.iterations, SIZED_TO_BUDGET)
    _hint(_schedule_hint(settings))
    _fit("downscale")
    _, settings.downscale = imgui.input_int("downscale", settings.downscale)
    _remember(viewer, "downscale")
    settings.downscale = max(settings.downscale, 1)
    protocols = ["none", "unstructured", "llff"]
    changed, index = _combo(viewer, "held-out views", protocols.index(settings.protocol), protocols)
    if changed:
        settings.protocol = protocols[index]
    changed, index = _combo(viewer, "strategy", STRATEGY_NAMES.index(settings.strategy), list(STRATEGY_NAMES))
    if changed:
        settings.strategy = STRATEGY_NAMES[index]
    sky_on = TrainConfig.sky_shell if settings.sky_shell is None else settings.sky_shell
    changed, sky_on = imgui.checkbox("sky shell (far backdrop)", sky_on)
    _remember(viewer, "sky shell")
    if imgui.is_item_hovered():
        imgui.set_tooltip("far Gaussians where the photos show no sparse point: a place for the sky")
    if changed:
        settings.sky_shell = sky_on
    imgui.text_disabled("stage II (bootstrap)")
    settings.bootstrap_minutes = _optional_minutes(viewer, "bootstrap budget min", "bootstrap budget",
                                                   settings.bootstrap_minutes, 4.0)
    _fit("refinement steps")
    _, settings.bootstrap_iterations = imgui.input_int("refinement steps", settings.bootstrap_iterations, 10, 100)
    _remember(viewer, "refinement steps")
    settings.bootstrap_iterations = max(settings.bootstrap_iterations, 1)
    _fit("K nearest views (0: default)")
    _, settings.k = imgui.input_int("K nearest views (0: default)", settings.k)
    _remember(viewer, "K nearest views (0: default)")
    _fit("L poses each (0: default)")
    _, settings.l = imgui.input_int("L poses each (0: default)", settings.l)
    _remember(viewer, "L poses each (0: default)")
    settings.k, settings.l = max(settings.k, 0), max(settings.l, 0)
    _fit("prior min (if none)")
    _, settings.prior_minutes = imgui.input_float("prior min (if none)", settings.prior_minutes, 0.5, 1.0, "%.1f")
    _remember(viewer, "prior min (if none)")
    settings.prior_minutes = _minutes_typed(settings.prior_minutes)
    imgui.tree_pop()


def _schedule_hint(settings) -> str:
    """What "schedule iterations" does with the value it holds (as `inceptiongs train`)."""
    if settings.iterations != SIZED_TO_BUDGET:
        return "a fixed schedule (0: sized to the budget)"
    if settings.minutes is None:
        return f"0: the default {schedule_length(None, None)[0]} steps (no budget)"
    return (f"0: sized to the budget (first guess {schedule_length(None, settings.minutes)[0]} steps, "
            "re-sized from the measured rate)")


def _optional_minutes(viewer, key: str, checkbox: str, minutes, default: float):
    """A budget that can be switched off (None: run the whole schedule): the checkbox, then the
    minutes labelled "min" beside it (its rectangle kept under ``key``)."""
    changed, on = imgui.checkbox(checkbox, minutes is not None)
    _remember(viewer, checkbox)
    if changed:
        minutes = default if on else None
    if minutes is not None:
        imgui.same_line()
        label = f"min##{key}"  # the checkbox names the budget; "##": a widget id of its own
        _fit(label)
        _, minutes = imgui.input_float(label, minutes, 0.5, 1.0, "%.1f")
        _remember(viewer, key)
        minutes = _minutes_typed(minutes)
    return minutes


def _minutes_typed(value: float) -> float:
    """imgui's float fields hold float32: a typed 0.7 reads back 0.699999988. Rounded to the
    hundredth (0.6 s, finer than any budget needs) the configs store what the user typed."""
    return max(round(float(value), 2), 0.1)


def _progress(viewer, run) -> None:
    progress, plan = run.progress, run.plan
    if not run.alive and viewer.job_reported:
        imgui.text_wrapped(viewer.status)  # the closing line: time, iteration, final scores
    else:
        done = progress.iteration - plan.start_iteration
        total = plan.steps
        label = f"{run.state}: iteration {progress.iteration}"
        if total:
            label += f" / {plan.end_iteration}"
            if plan.config is not None:
                label += " (sized to the budget)"
            imgui.progress_bar(min(max(done / total, 0.0), 1.0), imgui.ImVec2(-1, 0), f"{done} / {total} steps")
        imgui.text(label)
        eta = eta_seconds(progress.iteration, plan, progress.iterations_per_second, run.elapsed_s)
        budget = "" if plan.budget_s is None else f" of {format_duration(plan.budget_s)}"
        imgui.text_wrapped(f"elapsed {format_duration(run.elapsed_s)}{budget}  ETA {format_duration(eta)}  "
                   f"{progress.iterations_per_second:.2f} it/s")
        imgui.text(f"{progress.gaussian_count} Gaussians")
        if progress.message:
            imgui.text_wrapped(progress.message)
    if run.error:
        imgui.text_colored(imgui.ImVec4(1, 0.3, 0.3, 1), f"job failed: {run.error}")


def _plots(progress) -> None:
    """One plot per unit (dB, loss, count), axes refitted to the data every frame."""
    _plot(progress, "held-out PSNR", "dB", list(progress.psnr.items()), 150)
    for title, unit, names in PLOTS:
        _plot(progress, title, unit, [(name, progress.history[name]) for name in names if name in progress.history],
              120)


def _plot(progress, title: str, unit: str, series: list, height: float) -> None:
    """series: [(name, ([x], [y]))]. The limits drawn are kept in progress.plot_limits[title]
    ((x min, x max), (y min, y max)), so a test can check that the axes follow the data."""
    if not series or not implot.begin_plot(title, imgui.ImVec2(-1, height)):
        return
    fit = implot.AxisFlags_.auto_fit
    implot.setup_axes("iteration", unit, fit, fit)
    for name, (xs, ys) in series:
        spec = implot.Spec()
        if len(xs) < SHORT_SERIES_POINTS:  # a line needs two points: the first ones show as dots
            spec.marker, spec.marker_size = implot.Marker_.circle, 3.0
        implot.plot_line(name, np.asarray(xs, np.float64), np.asarray(ys, np.float64), spec)
    limits = implot.get_plot_limits()
    progress.plot_limits[title] = ((limits.x.min, limits.x.max), (limits.y.min, limits.y.max))
    implot.end_plot()


def _edit(viewer) -> None:
    settings = viewer.settings
    tools = list(EDIT_TOOLS)
    changed, index = _combo(viewer, "tool (left mouse)", tools.index(settings.edit_tool), tools)
    if changed:
        settings.edit_tool = tools[index]
    modes = ["replace", "add", "subtract"]
    changed, index = _combo(viewer, "selection", modes.index(settings.selection_mode), modes)
    if changed:
        settings.selection_mode = modes[index]
    if settings.edit_tool == "brush":
        _fit("brush radius px")
        _, settings.brush_radius = imgui.slider_float("brush radius px", settings.brush_radius, 2.0, 200.0)
    _fit("opacity below")
    _, settings.max_opacity = imgui.slider_float("opacity below", settings.max_opacity, 0.0, 1.0)
    _fit("or size above")
    _, settings.min_size = imgui.input_float("or size above", settings.min_size)
    if _button(viewer, "select by thresholds"):
        viewer.threshold_select()
    imgui.text(f"{int(viewer.edit.selected.sum())} selected")
    if _button(viewer, "delete (Del)"):
        viewer.delete_selection()
    _same_line_if_fits("undo (Ctrl+Z)")
    if _button(viewer, "undo (Ctrl+Z)"):
        viewer.undo()
    _same_line_if_fits("redo (Ctrl+Y)")
    if _button(viewer, "redo (Ctrl+Y)"):
        viewer.redo()
    changed, enabled = imgui.checkbox("crop box (drag its handles)", settings.crop_enabled)
    _remember(viewer, "crop box (drag its handles)")
    if changed:
        viewer.enable_crop(enabled)
    if settings.crop_enabled:
        _fit("min")
        _, settings.crop_min = imgui.input_float3("min", settings.crop_min)
        _remember(viewer, "min")  # x's field at its left end
        _fit("max")
        _, settings.crop_max = imgui.input_float3("max", settings.crop_max)
        _remember(viewer, "max")
        if _button(viewer, "crop to box"):
            viewer.apply_crop()
        _same_line_if_fits("fit to the model")
        if _button(viewer, "fit to the model"):
            viewer.fit_crop_box()
    _fit("file")
    _, viewer.save_path = imgui.input_text("file", viewer.save_path)
    _remember(viewer, "file")
    if _button(viewer, "save PLY"):
        try:
            viewer.save_ply(viewer.save_path)
        except Exception as exc:  # noqa: BLE001 - shown in the status line
            viewer.status = f"save failed: {exc}"
