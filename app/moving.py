"""The gizmo tool: drag an axis handle at the selection's centre to translate, rotate or scale
the selected Gaussians (app/gizmo.py's transforms); one drag is one undo step, and a save
writes the moved Gaussians like any edit. No GL: the handles are drawn by drawing.py."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .editing import CROP_HANDLE_PIXELS, project_means
from .gizmo import GIZMO_SCREEN_SHARE, drag_amount, gizmo_handles, transform_rows

MOVED_KEYS = ("means", "quats", "log_scales")


@dataclass
class Drag:
    """A drag in progress: the handle ``axis``, the selected ``rows`` int [K] and their values
    when it began (key -> [K, ...]), the pivot [3], handle length and the start (window pixels)."""

    axis: int
    rows: np.ndarray
    before: dict
    pivot: np.ndarray
    length: float
    start: tuple


class SelectionMover:
    """The gizmo on ``view``'s selection; ``status``: the status line."""

    def __init__(self, view, status) -> None:
        self.view, self.status = view, status
        self.drag: Drag | None = None

    def pivot_and_length(self):
        """(pivot [3] the selection's mean position, handle length in scene units) or None when
        nothing is selected; during a drag, the drag's (the gizmo stays where it was grabbed)."""
        if self.drag is not None:
            return self.drag.pivot, self.drag.length
        edit = self.view.edit
        if self.view.settings.edit_tool != "gizmo" or not edit.selected.any():
            return None
        pivot = edit.base["means"][edit.selected].mean(axis=0, dtype=np.float64)
        _, depth = project_means(pivot[None], self.view.current_camera())
        # Behind the eye the depth is negative: fall back to the fly speed for a visible length.
        length = GIZMO_SCREEN_SHARE * float(depth[0]) if depth[0] > 1e-6 else self.view.nav.speed
        return pivot, max(length, 1e-6)

    def handle_at(self, x: float, y: float) -> int | None:
        """The axis (0 x, 1 y, 2 z) whose handle tip is within CROP_HANDLE_PIXELS of window
        position (x, y), nearest first; None when the gizmo is hidden or none is that close."""
        placed = self.pivot_and_length()
        if placed is None:
            return None
        pixels, _ = project_means(gizmo_handles(*placed), self.view.current_camera())
        distance = np.hypot(*(pixels - np.array(self.view.pixels.to_framebuffer(x, y))).T)
        distance = np.where(np.isnan(distance), np.inf, distance)
        best = int(np.argmin(distance))
        return best if distance[best] <= CROP_HANDLE_PIXELS else None

    def begin(self, axis: int, x: float, y: float) -> None:
        pivot, length = self.pivot_and_length()
        edit = self.view.edit
        rows = np.flatnonzero(edit.selected)
        self.drag = Drag(axis, rows, {key: edit.base[key][rows].copy() for key in MOVED_KEYS},
                         pivot, length, (x, y))

    def move_to(self, x: float, y: float) -> None:
        """Apply the whole drag from its start to (x, y) to the rows' values when it began (no
        drift from summing steps); the mouse motion is measured along the handle's screen axis."""
        drag, view = self.drag, self.view
        camera = view.current_camera()
        tip = drag.pivot + drag.length * np.eye(3)[drag.axis]
        pixels, _ = project_means(np.stack([drag.pivot, tip]), camera)
        screen_axis = (pixels[1] - pixels[0]) / drag.length  # pixels per scene unit along the axis
        motion = np.subtract(view.pixels.to_framebuffer(x, y), view.pixels.to_framebuffer(*drag.start))
        amount = drag_amount(screen_axis, motion)
        values = transform_rows(drag.before, np.arange(len(drag.rows)), view.settings.gizmo_mode, drag.axis,
                                amount, drag.pivot, drag.length)
        view.edit.set_rows(drag.rows, values)
        self.status.text = describe(view.settings.gizmo_mode, drag.axis, amount, drag.length, len(drag.rows))

    def end(self) -> None:
        """Finish the drag as one undo step."""
        drag, self.drag = self.drag, None
        if drag is not None:
            self.view.edit.commit_rows(drag.rows, drag.before)


def describe(mode: str, axis: int, amount: float, length: float, count: int) -> str:
    """The status line for a gizmo drag."""
    name = "xyz"[axis]
    if mode == "translate":
        return f"moved {count} Gaussians by {amount:+.4g} along {name}"
    if mode == "rotate":
        return f"rotated {count} Gaussians by {np.degrees(amount / length):+.1f} degrees about {name}"
    return f"scaled {count} Gaussians by x{float(np.exp(np.clip(amount / length, -7, 7))):.3g}"
