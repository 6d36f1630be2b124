"""Splat editing without GL: selection by screen rectangle, brush, thresholds and crop box,
delete with undo/redo, and the arrays the renderer should show. Pure numpy.

Edits never touch the loaded arrays: an :class:`EditState` keeps a boolean ``alive`` mask
[N] over them, and undo/redo swap masks, so any number of edits costs N bytes each.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from inceptiongs.camera import Camera
from inceptiongs.constants import NEAR_PLANE, OPACITY_LOGIT_ABS_MAX, LOG_SCALE_MAX, LOG_SCALE_MIN


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
        return int(self.alive.sum())

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

    def _restore(self, entry) -> None:
        alive, selected = entry
        if not np.array_equal(alive, self.alive):
            self.version += 1
        self.alive, self.selected = alive, selected

    def undo(self) -> bool:
        """Take back the last deletion, crop or selection change."""
        if not self.undo_stack:
            return False
        self.redo_stack.append((self.alive, self.selected.copy()))
        self._restore(self.undo_stack.pop())
        return True

    def redo(self) -> bool:
        if not self.redo_stack:
            return False
        self.undo_stack.append((self.alive, self.selected.copy()))
        self._restore(self.redo_stack.pop())
        return True

    def visible_arrays(self) -> dict:
        """The alive Gaussians, keyed like Gaussians.numpy()."""
        if self.alive.all():
            return self.base
        return {key: value[self.alive] for key, value in self.base.items()}
