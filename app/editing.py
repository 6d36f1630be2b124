"""Splat editing without GL: selection by screen rectangle, brush, thresholds and crop box,
delete with undo/redo, and the arrays the renderer should show. Pure numpy, but for
:class:`Editor`, the Edit panel's and the edit tools' actions on the view's model.

Edits never touch the loaded arrays: an :class:`EditState` keeps a boolean ``alive`` mask
[N] over them, and undo/redo swap masks, so any number of edits costs N bytes each.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from inceptiongs.camera import Camera
from inceptiongs.constants import NEAR_PLANE, OPACITY_LOGIT_ABS_MAX, LOG_SCALE_MAX, LOG_SCALE_MIN

from .saving import EditSaver

# A crop-box handle is grabbed within this many pixels of the cursor.
CROP_HANDLE_PIXELS = 12.0
# "visible rectangle": a Gaussian counts as seen when its mean lies no deeper than the rendered
# surface at its pixel by this share of that depth, or by this many of its own sizes.
VISIBLE_DEPTH_SHARE = 0.03
VISIBLE_EXTENT_SIGMAS = 2.0


def project_means(means: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """means: [N, 3] -> (pixels [N, 2] continuous (x = column, y = row), depth [N] camera z).
    Points at or behind the near plane get pixel NaN (they project nowhere)."""
    rotation = camera.rotation
    translation = camera.world_to_camera[:3, 3]
    points = np.asarray(means, np.float64) @ rotation.T + translation
    depth = points[:, 2]
    in_front = depth > NEAR_PLANE
    # Dividing only where z > NEAR_PLANE > 0, so the division is safe.
    safe_z = np.where(in_front, depth, 1.0)
    pixels = np.stack([camera.fx * points[:, 0] / safe_z + camera.cx,
                       camera.fy * points[:, 1] / safe_z + camera.cy], axis=1)
    pixels[~in_front] = np.nan
    return pixels, depth


def select_rectangle(pixels: np.ndarray, corner_a: tuple[float, float],
                     corner_b: tuple[float, float]) -> np.ndarray:
    """pixels: [N, 2] -> bool [N]: inside the screen rectangle spanned by two corners
    (any order). NaN pixels (behind the camera) are never selected."""
    x0, x1 = sorted((corner_a[0], corner_b[0]))
    y0, y1 = sorted((corner_a[1], corner_b[1]))
    with np.errstate(invalid="ignore"):
        return ((pixels[:, 0] >= x0) & (pixels[:, 0] <= x1) &
                (pixels[:, 1] >= y0) & (pixels[:, 1] <= y1))


def select_visible(pixels: np.ndarray, depth: np.ndarray, extent: np.ndarray, surface: np.ndarray,
                   origin: tuple[int, int]) -> np.ndarray:
    """The Gaussians seen at their pixel, not hidden behind a surface there.
    pixels: [N, 2] framebuffer positions; depth: [N] camera z; extent: [N] each Gaussian's
    largest size (scene units); surface: [h, w] the rendered depth of a window of the frame
    whose top-left pixel is ``origin`` (x, y), 0 where nothing was drawn -> bool [N]: inside
    the window and no deeper than the surface at its pixel by more than
    max(VISIBLE_DEPTH_SHARE * surface, VISIBLE_EXTENT_SIGMAS * extent) (a Gaussian on the
    surface has its mean up to about its size behind the blended depth)."""
    height, width = surface.shape
    selected = np.zeros(len(pixels), bool)
    with np.errstate(invalid="ignore"):
        column = np.floor(pixels[:, 0] - origin[0])
        row = np.floor(pixels[:, 1] - origin[1])
        inside = (column >= 0) & (column < width) & (row >= 0) & (row < height) & (depth > NEAR_PLANE)
    index = np.flatnonzero(inside)
    seen = surface[row[index].astype(int), column[index].astype(int)]
    slack = np.maximum(VISIBLE_DEPTH_SHARE * seen, VISIBLE_EXTENT_SIGMAS * extent[index])
    selected[index] = (seen > 0) & (depth[index] <= seen + slack)
    return selected


def select_brush(pixels: np.ndarray, center: tuple[float, float], radius: float) -> np.ndarray:
    """pixels: [N, 2] -> bool [N]: within ``radius`` pixels of ``center``."""
    offset = pixels - np.asarray(center, np.float64)
    with np.errstate(invalid="ignore"):
        return (offset ** 2).sum(axis=1) <= radius * radius


def select_lasso(pixels: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """pixels: [N, 2], polygon: [M, 2] screen points (closed implicitly) -> bool [N]: inside by
    the even-odd rule. Fewer than 3 corners enclose nothing; NaN pixels are never inside."""
    polygon = np.asarray(polygon, np.float64)
    inside = np.zeros(len(pixels), bool)
    if len(polygon) < 3:
        return inside
    x, y = pixels[:, 0], pixels[:, 1]
    for (x0, y0), (x1, y1) in zip(polygon, np.roll(polygon, -1, axis=0)):
        if y0 == y1:
            continue  # a horizontal edge crosses no horizontal ray (and would divide by 0)
        with np.errstate(invalid="ignore"):
            spans = (y0 > y) != (y1 > y)
            crossing = x < x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= spans & crossing
    return inside


def box_handles(box_min, box_max) -> np.ndarray:
    """The 6 face centres [6, 3] of a box, in the order -x, +x, -y, +y, -z, +z (handle k moves
    face k: axis k // 2, the max side when k is odd)."""
    lo, hi = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
    center = 0.5 * (lo + hi)
    handles = np.repeat(center[None], 6, axis=0)
    for k in range(6):
        handles[k, k // 2] = (hi if k % 2 else lo)[k // 2]
    return handles


def drag_box_face(box_min, box_max, handle: int, amount: float) -> tuple[list, list]:
    """Move face ``handle`` (box_handles order) by ``amount`` along its axis; the face stops at
    the opposite one (a box never turns inside out)."""
    lo, hi = [float(v) for v in box_min], [float(v) for v in box_max]
    axis = handle // 2
    if handle % 2:
        hi[axis] = max(hi[axis] + amount, lo[axis])
    else:
        lo[axis] = min(lo[axis] + amount, hi[axis])
    return lo, hi


def sigmoid_opacity(opacity_logits: np.ndarray) -> np.ndarray:
    """[N] logits -> opacities in (0, 1); clamped like the renderers so exp() cannot overflow."""
    logits = np.clip(opacity_logits.astype(np.float64), -OPACITY_LOGIT_ABS_MAX, OPACITY_LOGIT_ABS_MAX)
    return 1.0 / (1.0 + np.exp(-logits))


def splat_size(log_scales: np.ndarray) -> np.ndarray:
    """[N, 3] log scales -> [N] largest axis standard deviation (scene units)."""
    return np.exp(np.clip(log_scales.astype(np.float64), LOG_SCALE_MIN, LOG_SCALE_MAX)).max(axis=1)


def select_thresholds(opacity_logits: np.ndarray, log_scales: np.ndarray,
                      max_opacity: float | None = None, min_size: float | None = None) -> np.ndarray:
    """bool [N]: Gaussians fainter than ``max_opacity`` or larger than ``min_size`` (the usual
    clean-up targets: near-transparent haze and huge floaters). None disables a test."""
    selected = np.zeros(len(opacity_logits), bool)
    if max_opacity is not None:
        selected |= sigmoid_opacity(opacity_logits) < max_opacity
    if min_size is not None:
        selected |= splat_size(log_scales) > min_size
    return selected


def inside_box(means: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """means: [N, 3] -> bool [N], inside the axis-aligned box (bounds inclusive)."""
    return np.all((means >= np.asarray(box_min)) & (means <= np.asarray(box_max)), axis=1)


def combine_selection(current: np.ndarray, new: np.ndarray, mode: str) -> np.ndarray:
    """mode "replace" | "add" | "subtract"; masks are bool [N]."""
    if mode == "add":
        return current | new
    if mode == "subtract":
        return current & ~new
    if mode == "replace":
        return new.copy()
    raise ValueError(f"unknown selection mode {mode!r}")


@dataclass
class RowsEdit:
    """One undo step of a move: ``rows`` int [K] and their values before and after
    (key -> [K, ...])."""

    rows: np.ndarray
    before: dict
    after: dict


@dataclass
class EditState:
    """Deletions over fixed base arrays. ``alive``: bool [N]; ``selected``: bool [N] (only
    alive Gaussians can be selected). ``version`` changes whenever the shown set changes."""

    base: dict
    alive: np.ndarray = None
    selected: np.ndarray = None
    undo_stack: list = field(default_factory=list)
    redo_stack: list = field(default_factory=list)
    version: int = 0

    def __post_init__(self) -> None:
        n = len(self.base["means"])
        if self.alive is None:
            self.alive = np.ones(n, bool)
        if self.selected is None:
            self.selected = np.zeros(n, bool)

    @property
    def count(self) -> int:
        """The alive Gaussians; counted once per mask (``alive`` is replaced, never changed in
        place): the panel and the drawing ask several times a frame, and at 5M a count is 3 ms."""
        counted = self.__dict__.get("_counted")
        if counted is None or counted[0] is not self.alive:
            counted = (self.alive, int(self.alive.sum()))
            self.__dict__["_counted"] = counted
        return counted[1]

    def select(self, mask: np.ndarray, mode: str = "replace", record: bool = True) -> None:
        """Change the selection; ``record``: as one undo step (a brush stroke records its first
        dab only, so one undo takes back the whole stroke)."""
        new = combine_selection(self.selected, mask, mode) & self.alive
        if record and not np.array_equal(new, self.selected):
            self._push()
        self.selected = new

    def clear_selection(self) -> None:
        self.selected[:] = False

    def _push(self) -> None:
        """Remember the current (alive, selected) for undo; a new change forgets the redos."""
        self.undo_stack.append((self.alive, self.selected.copy()))
        self.redo_stack.clear()

    def _apply(self, new_alive: np.ndarray) -> bool:
        if np.array_equal(new_alive, self.alive):
            return False
        self._push()
        self.alive = new_alive
        self.selected = self.selected & self.alive
        self.version += 1
        return True

    def delete_selected(self) -> bool:
        """Remove the selection; True when something was deleted."""
        return self._apply(self.alive & ~self.selected)

    def crop(self, box_min: np.ndarray, box_max: np.ndarray) -> bool:
        """Keep only Gaussians whose mean lies inside the box."""
        return self._apply(self.alive & inside_box(self.base["means"], box_min, box_max))

    def _restore(self, entry, undoing: bool) -> None:
        if isinstance(entry, RowsEdit):
            self.set_rows(entry.rows, entry.before if undoing else entry.after)
            return
        alive, selected = entry
        if not np.array_equal(alive, self.alive):
            self.version += 1
        self.alive, self.selected = alive, selected

    def undo(self) -> bool:
        """Take back the last deletion, crop or selection change."""
        if not self.undo_stack:
            return False
        entry = self.undo_stack.pop()
        self.redo_stack.append(entry if isinstance(entry, RowsEdit) else (self.alive, self.selected.copy()))
        self._restore(entry, undoing=True)
        return True

    def redo(self) -> bool:
        if not self.redo_stack:
            return False
        entry = self.redo_stack.pop()
        self.undo_stack.append(entry if isinstance(entry, RowsEdit) else (self.alive, self.selected.copy()))
        self._restore(entry, undoing=False)
        return True

    def set_rows(self, rows: np.ndarray, values: dict) -> None:
        """Write ``values`` (key -> [K, ...]) into ``rows`` (int [K]) of the base arrays, copying
        each changed array first: the loaded arrays may be shared (the LOD hierarchy), so they
        are never written in place. No undo step: see :meth:`commit_rows`."""
        base = dict(self.base)
        for key, value in values.items():
            array = base[key].copy()
            array[rows] = value
            base[key] = array
        self.base = base
        self.version += 1

    def commit_rows(self, rows: np.ndarray, before: dict) -> bool:
        """Record the change of ``rows`` from ``before`` (key -> [K, ...]) to their values now as
        one undo step; False (nothing recorded) when nothing changed."""
        after = {key: self.base[key][rows].copy() for key in before}
        if all(np.array_equal(before[key], after[key]) for key in before):
            return False
        self.undo_stack.append(RowsEdit(rows, before, after))
        self.redo_stack.clear()
        return True

    def transform_selected(self, values: dict, rows: np.ndarray) -> bool:
        """Replace ``rows`` with ``values`` as one undo step (the keyboard's moves)."""
        before = {key: self.base[key][rows].copy() for key in values}
        self.set_rows(rows, values)
        return self.commit_rows(rows, before)

    def visible_arrays(self) -> dict:
        """The alive Gaussians, keyed like Gaussians.numpy()."""
        if self.alive.all():
            return self.base
        return {key: value[self.alive] for key, value in self.base.items()}


def edit_state_line(verb: str, edit: EditState) -> str:
    """"undone; 1200 Gaussians shown, 3 selected": what ``edit`` shows after ``verb``."""
    return f"{verb}; {edit.count} Gaussians shown, {int(edit.selected.sum())} selected"


class Editor:
    """Selection, deletion, crop box and saving on the model a view.View shows (its EditState
    ``view.edit``; the tool, selection mode and crop box are in ``view.settings``). Positions
    are window pixels, as the mouse gives them. ``status``: the status line; ``saving``: the
    "file" field and "save PLY" (saving.EditSaver)."""

    def __init__(self, view, status) -> None:
        self.view, self.status = view, status
        self.saving = EditSaver(view, status)

    def projected_means(self):
        return project_means(self.view.edit.base["means"], self.view.current_camera())

    def rectangle_select(self, corner_a, corner_b, visible_only: bool = False) -> None:
        """Select inside the rectangle: every Gaussian there (straight through the model), or with
        ``visible_only`` only those seen: the model's depth is rendered for the rectangle's
        pixels and a Gaussian behind that surface is left out."""
        view = self.view
        pixels, depth = self.projected_means()
        a, b = view.pixels.to_framebuffer(*corner_a), view.pixels.to_framebuffer(*corner_b)
        if not visible_only:
            view.edit.select(select_rectangle(pixels, a, b), view.settings.selection_mode)
            return
        camera = view.current_camera()
        x0, y0 = max(int(np.floor(min(a[0], b[0]))), 0), max(int(np.floor(min(a[1], b[1]))), 0)
        x1 = min(int(np.ceil(max(a[0], b[0]))), camera.width)
        y1 = min(int(np.ceil(max(a[1], b[1]))), camera.height)
        mask = np.zeros(len(pixels), bool)
        if x1 > x0 and y1 > y0:
            surface = view.renderer.render(camera.cropped(x0, y0, x1 - x0, y1 - y0), mode="depth")[..., 0]
            # log scales are clamped on load; the min keeps exp finite for any array handed in
            extent = np.exp(np.minimum(view.edit.base["log_scales"].max(axis=1), LOG_SCALE_MAX))
            mask = select_visible(pixels, depth, extent, surface, (x0, y0))
        view.edit.select(mask, view.settings.selection_mode)
        self.status.text = f"{int(view.edit.selected.sum())} visible Gaussians selected"

    def lasso_select(self, points) -> None:
        """points: the lasso's window positions [(x, y), ...] (closed implicitly)."""
        pixels, _ = self.projected_means()
        polygon = np.array([self.view.pixels.to_framebuffer(x, y) for x, y in points]).reshape(-1, 2)
        self.view.edit.select(select_lasso(pixels, polygon), self.view.settings.selection_mode)

    def brush_select(self, x: float, y: float, stroke_start: bool = True) -> None:
        """One dab of the brush; a drag's later dabs join its first one's undo step."""
        settings = self.view.settings
        pixels, _ = self.projected_means()
        center = self.view.pixels.to_framebuffer(x, y)
        mode = "add" if settings.selection_mode == "replace" else settings.selection_mode
        self.view.edit.select(select_brush(pixels, center, settings.brush_radius), mode, record=stroke_start)

    def threshold_select(self) -> None:
        base, settings = self.view.edit.base, self.view.settings
        mask = select_thresholds(base["opacity_logits"], base["log_scales"], settings.max_opacity,
                                 settings.min_size)
        self.view.edit.select(mask, settings.selection_mode)

    def delete_selection(self) -> None:
        if self.view.edit.delete_selected():
            self.say_edit_state(f"deleted; {self.view.edit.count} Gaussians left")

    def undo(self) -> None:
        """Undo the last edit; the status then says what is shown (a "deleted; N left" kept
        after the undo would name a state that is gone)."""
        if self.view.edit.undo():
            self.say_edit_state(edit_state_line("undone", self.view.edit))
        else:
            self.status.text = "nothing to undo"

    def redo(self) -> None:
        if self.view.edit.redo():
            self.say_edit_state(edit_state_line("redone", self.view.edit))
        else:
            self.status.text = "nothing to redo"

    def say_edit_state(self, text: str) -> None:
        """A message about the edit state (counts shown, selected): it goes once the model or
        the selection changes ("0 selected" stayed while the panel counted a new selection)."""
        edit = self.view.edit
        state = (edit.alive, int(edit.selected.sum()))
        view = self.view
        self.status.say(text, holds=lambda: view.edit is edit and edit.alive is state[0]
                        and int(edit.selected.sum()) == state[1])

    # --- the crop box --------------------------------------------------------------------------
    def fit_crop_box(self) -> None:
        """The crop box around the model's robust bounds (2-98 % of the shown means, 5 % margin)."""
        means = self.view.edit.visible_arrays()["means"]
        if len(means) == 0:
            return
        lo, hi = np.percentile(means, [2, 98], axis=0)
        margin = 0.05 * (hi - lo)
        self.view.settings.crop_min, self.view.settings.crop_max = (lo - margin).tolist(), (hi + margin).tolist()

    def enable_crop(self, enabled: bool = True) -> None:
        """Show the crop box; the first time, fitted to the model (not a fixed +-1)."""
        settings = self.view.settings
        if enabled and settings.crop_min is None:
            self.fit_crop_box()
        settings.crop_enabled = enabled and settings.crop_min is not None

    def crop_handle_at(self, x: float, y: float) -> int | None:
        """The crop-box handle (box_handles index) within CROP_HANDLE_PIXELS of window position
        (x, y), nearest first; None when the box is hidden or none is that close."""
        settings = self.view.settings
        if not settings.crop_enabled:
            return None
        pixels, _ = project_means(box_handles(settings.crop_min, settings.crop_max), self.view.current_camera())
        distance = np.hypot(*(pixels - np.array(self.view.pixels.to_framebuffer(x, y))).T)
        distance = np.where(np.isnan(distance), np.inf, distance)
        best = int(np.argmin(distance))
        return best if distance[best] <= CROP_HANDLE_PIXELS else None

    def drag_crop_handle(self, handle: int, start, end) -> None:
        """Move a crop face by the mouse motion start -> end (window positions) projected on the
        face's axis as the screen shows it."""
        settings, view = self.view.settings, self.view
        point = box_handles(settings.crop_min, settings.crop_max)[handle]
        axis = np.eye(3)[handle // 2]
        step = max(float(np.max(np.subtract(settings.crop_max, settings.crop_min))) * 0.01, 1e-6)
        pixels, _ = project_means(np.stack([point, point + axis * step]), view.current_camera())
        screen_axis = (pixels[1] - pixels[0]) / step  # pixels per scene unit along the axis
        length2 = float(screen_axis @ screen_axis)
        if not np.isfinite(length2) or length2 < 1e-9:
            return  # the axis points at the eye: no screen direction to drag along
        motion = np.subtract(view.pixels.to_framebuffer(*end), view.pixels.to_framebuffer(*start))
        settings.crop_min, settings.crop_max = drag_box_face(
            settings.crop_min, settings.crop_max, handle, float(motion @ screen_axis) / length2)

    def apply_crop(self) -> None:
        settings = self.view.settings
        if self.view.edit.crop(np.array(settings.crop_min), np.array(settings.crop_max)):
            self.say_edit_state(f"cropped; {self.view.edit.count} Gaussians left")
