"""The Training panel's curves (held-out PSNR, loss, Gaussian count) drawn with implot, and the
axis ranges they are drawn over (pure, tested without a window).

Each plot's y range spans the data with a margin and at least a minimum span for its unit, so
0.08 dB of evaluation noise does not fill the plot like a large swing; counts and iterations are
labelled as integers; the legend sits above the plot, outside it, each entry readable; the
plots take no mouse input (implot's hover highlight, drag and box selection painted blocks over
a plot that only shows data)."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui, implot

# Series with fewer points than this are drawn with a marker at each point (a bootstrap's curve
# starts with its single first evaluation, which a line alone does not show).
SHORT_SERIES_POINTS = 4
# The job's logged terms worth a curve, grouped by unit: (plot title, y label, metric names, names
# on a right-hand axis of their own). The photometric L1 (about 0.1) beside a loss that holds the
# regularisers (about 5) drew a flat line on the loss's axis.
PLOTS = (("training loss", "loss", ("loss",), ("l1",)),
         ("Gaussians", "count", ("num_gaussians",), ()))
# What a curve is called in its legend (else its metric's name).
LEGEND_NAMES = {"num_gaussians": "Gaussians", "l1": "L1 (right axis)"}
RIGHT_AXIS_LABEL = "L1"
# Minimum y span per unit: an absolute one (PSNR differences under about a dB are noise to the
# eye), and for counts and losses a fraction of the values' size as well.
MIN_SPAN_DB = 1.0
MIN_SPAN_COUNT = 10.0
MIN_SPAN_FRACTION = 0.02       # of the largest |value|: counts in the tens of thousands
MIN_SPAN_LOSS_FRACTION = 0.2   # losses: their own scale, whatever it is
MIN_X_SPAN = 10.0              # iterations: a single evaluation still gets an axis
MARGIN_FRACTION = 0.08         # of the data's span, on each side
INTEGER_UNITS = ("count",)
# Drawn first (under the others): the all-views curve is close to the covered one, which it hid.
DRAWN_FIRST = ("all",)
# Curves drawn with a marker at every point, so one lying on "all" still shows.
MARKED = ("scarce", "covered")
# Frame heights, pixels: title, the legend row above the plot, the axes' labels and the area.
PSNR_PLOT_HEIGHT = 200
PLOT_HEIGHT = 160
PLOT_FLAGS = (implot.Flags_.no_inputs | implot.Flags_.no_menus | implot.Flags_.no_box_select
              | implot.Flags_.no_mouse_text)
AXIS_FLAGS = implot.AxisFlags_.no_highlight | implot.AxisFlags_.no_menus


def min_span(unit: str, values: np.ndarray) -> float:
    """The least y span a plot in ``unit`` shows (values: [N] its finite data)."""
    size = float(np.max(np.abs(values))) if len(values) else 0.0
    if unit == "dB":
        return MIN_SPAN_DB
    if unit in INTEGER_UNITS:
        return max(MIN_SPAN_COUNT, MIN_SPAN_FRACTION * size)
    return max(MIN_SPAN_LOSS_FRACTION * size, 1e-6)


def axis_range(values, least_span: float) -> tuple[float, float]:
    """(low, high) around ``values`` [N]: their extent plus MARGIN_FRACTION of it on each side,
    widened about its middle to ``least_span`` when narrower; (0, least_span) for no values."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return 0.0, least_span
    low, high = float(values.min()), float(values.max())
    pad = MARGIN_FRACTION * (high - low)
    low, high = low - pad, high + pad
    if high - low < least_span:
        middle = 0.5 * (low + high)
        low, high = middle - 0.5 * least_span, middle + 0.5 * least_span
    return low, high


def drawing_order(series: list) -> list:
    """series [(name, data)] with DRAWN_FIRST names moved to the front (drawn underneath)."""
    return sorted(series, key=lambda item: item[0] not in DRAWN_FIRST)


def draw_plots(ui, progress) -> None:
    """One plot per unit (dB, loss, count) of a job's progress (live_training.TrainingProgress)."""
    draw_plot(ui, progress, "held-out PSNR", "dB", list(progress.psnr.items()), PSNR_PLOT_HEIGHT)
    for title, unit, names, right in PLOTS:
        series = [(name, progress.history[name]) for name in names if name in progress.history]
        right_series = [(name, progress.history[name]) for name in right if name in progress.history]
        draw_plot(ui, progress, title, unit, series, PLOT_HEIGHT, right_series)


def finite_values(series: list) -> np.ndarray:
    """The finite y values [M] of series [(name, ([x], [y]))]."""
    values = np.concatenate([np.asarray(ys, np.float64) for _, (_, ys) in series]) if series else np.zeros(0)
    return values[np.isfinite(values)]


def draw_plot(ui, progress, title: str, unit: str, series: list, height: float, right: list = ()) -> None:
    """series, right: [(name, ([x], [y]))], ``right`` on a right-hand axis with its own range.
    The limits drawn are kept in progress.plot_limits[title] ((x min, x max), (y min, y max))
    and, with ``right``, progress.plot_limits[title + " (right)"]; the plot's frame in
    ui.rects["plot/" + title], the area inside its axes in ui.rects["plot area/" + title]."""
    right = list(right)
    if not series or not implot.begin_plot(title, imgui.ImVec2(-1, height), PLOT_FLAGS):
        return
    xs_all = np.concatenate([np.asarray(xs, np.float64) for _, (xs, _) in series + right])
    finite = finite_values(series)
    x_range = axis_range(xs_all, MIN_X_SPAN)
    y_range = axis_range(finite, min_span(unit, finite))
    implot.setup_axes("iteration", unit, AXIS_FLAGS, AXIS_FLAGS)
    implot.setup_axis_limits(implot.ImAxis_.x1, *x_range, implot.Cond_.always)
    implot.setup_axis_limits(implot.ImAxis_.y1, *y_range, implot.Cond_.always)
    implot.setup_axis_format(implot.ImAxis_.x1, "%.0f")
    if unit in INTEGER_UNITS:
        implot.setup_axis_format(implot.ImAxis_.y1, "%.0f")
    if right:
        right_finite = finite_values(right)
        implot.setup_axis(implot.ImAxis_.y2, RIGHT_AXIS_LABEL, AXIS_FLAGS | implot.AxisFlags_.opposite)
        implot.setup_axis_limits(implot.ImAxis_.y2, *axis_range(right_finite, min_span(unit, right_finite)),
                                 implot.Cond_.always)
    implot.setup_legend(implot.Location_.north, implot.LegendFlags_.outside | implot.LegendFlags_.horizontal)
    for axis, drawn in ((implot.ImAxis_.y1, drawing_order(series)), (implot.ImAxis_.y2, right)):
        for name, (xs, ys) in drawn:
            implot.set_axes(implot.ImAxis_.x1, axis)
            spec = implot.Spec()
            if len(xs) < SHORT_SERIES_POINTS or name in MARKED:
                spec.marker, spec.marker_size = implot.Marker_.circle, 3.0
            if name in DRAWN_FIRST:
                spec.line_weight = 1.0
            implot.plot_line(LEGEND_NAMES.get(name, name), np.asarray(xs, np.float64), np.asarray(ys, np.float64),
                             spec)
    limits = implot.get_plot_limits(implot.ImAxis_.x1, implot.ImAxis_.y1)
    progress.plot_limits[title] = ((limits.x.min, limits.x.max), (limits.y.min, limits.y.max))
    if right:
        limits = implot.get_plot_limits(implot.ImAxis_.x1, implot.ImAxis_.y2)
        progress.plot_limits[title + " (right)"] = ((limits.x.min, limits.x.max), (limits.y.min, limits.y.max))
    pos, size = implot.get_plot_pos(), implot.get_plot_size()
    ui.rects["plot area/" + title] = (pos.x, pos.y, pos.x + size.x, pos.y + size.y)
    implot.end_plot()
    low, high = imgui.get_item_rect_min(), imgui.get_item_rect_max()  # the frame: axes and legend too
    ui.rects["plot/" + title] = (low.x, low.y, high.x, high.y)

