"""What the window shows and from where: the open source and its model (deletions and selection
over it: editing.EditState), the camera (navigation.NavigationState) with its home view and world
up, the training camera last stepped to, and the render settings (settings.ViewSettings).

The View panel, the Inspect panel, the mouse and the fly keys change this object; the drawing
reads it. Camera maths lives in navigation.py; this is the state it acts on."""

from __future__ import annotations

import time

import glfw
import numpy as np

from inceptiongs.camera import Camera, pose_distance
from inceptiongs.errors import InputError
from inceptiongs.lod.hierarchy import GAUSSIAN_FIELDS
from inceptiongs.scene.photo_store import photo_tensor

from . import flags as flagging
from .editing import EditState
from .navigation import NavigationState, default_view, estimate_up, framed, leveled, model_up, statistics_sample
from .settings import StatusLine, ViewSettings


class View:
    """The camera on one window and the model it shows. ``window``: the GLFW window (its sizes);
    ``renderer``: the splat renderer (depth under the cursor); ``status``: the status line."""

    def __init__(self, source, window, renderer, status: StatusLine) -> None:
        self.window, self.renderer, self.status = window, renderer, status
        self.settings = ViewSettings()
        self.source = source
        self.edit = EditState(source.gaussians)  # the model shown, with its deletions and selection
        self.model_version = 1  # changes whenever another model replaces the shown one
        # The model shown is sparse (or triangulated) points, drawn as small screen-space points.
        self.shows_points = bool(getattr(source, "sparse_points", False))
        self.cameras = source.cameras
        # Up: the cameras' mean up, else the model's dominant plane; the View panel may change it.
        self.up = estimate_up(self.cameras) if self.cameras else model_up(source.gaussians["means"])
        self.up_source = "from the cameras" if self.cameras else "from the model"
        self.nav = self.initial_view()
        self.home = self.nav.copy()
        self.camera_index = 0 if self.cameras else -1
        self.covered_left = 0.0  # window pixels the panel covers at the window's left (Home avoids them)
        self.last_motion = -1e9  # when the camera or the model last moved (drawing's moving size)
        self._photo_cache: tuple[int | None, np.ndarray | None] = (None, None)

    # --- the model shown -----------------------------------------------------------------------
    def show_model(self, gaussians: dict, points: bool = False) -> None:
        """A new model (a job's snapshot, the triangulated points: ``points``) replaces the shown
        one: edits are for models at rest, so its edit state starts afresh."""
        self.edit = EditState(gaussians)
        self.model_version += 1
        self.shows_points = points

    def share_tree_leaves(self, hierarchy) -> bool:
        """Show the LOD tree's leaves (the same Gaussians in Morton order, inceptiongs.lod) as the
        model, so its arrays are held once, not twice (280 MB at 5M). Only for an unedited model:
        deletions and selections are masks in the model's order. -> whether it was done."""
        edit = self.edit
        leaves = hierarchy.leaf_count
        if (set(edit.base) != set(GAUSSIAN_FIELDS) or edit.version != 0 or edit.undo_stack
                or not edit.alive.all() or edit.selected.any()
                or leaves != len(edit.alive) or edit.base["means"] is getattr(self, "_shared_means", None)):
            return False
        shared = {name: getattr(hierarchy, name)[:leaves] for name in edit.base}
        self.edit = EditState(shared)
        self.source.gaussians = shared
        self._shared_means = shared["means"]
        return True

    def show_source(self, source) -> None:
        """Another source of the same scene (a run opened from the Training panel) is shown."""
        self.source = source
        self.show_model(source.gaussians, points=bool(getattr(source, "sparse_points", False)))

    # --- the camera ----------------------------------------------------------------------------
    def initial_view(self) -> NavigationState:
        width, height = self.framebuffer_size
        means = self.source.gaussians["means"]
        if self.cameras:
            first = self.cameras[0]
            centers = np.stack([c.center for c in self.cameras])
            spread = float(np.linalg.norm(centers.max(0) - centers.min(0))) if len(centers) > 1 else 1.0
            nav = NavigationState.from_camera(first, up=self.up, speed=max(spread * 0.5, 1e-3))
            nav.pivot = np.median(statistics_sample(means), axis=0) if len(means) else nav.pivot
            return nav
        return default_view(means, width, height, up=self.up)

    @property
    def framebuffer_size(self) -> tuple[int, int]:
        width, height = glfw.get_framebuffer_size(self.window)
        return max(width, 1), max(height, 1)

    def current_camera(self, scale: float = 1.0) -> Camera:
        width, height = self.framebuffer_size
        camera = self.nav.camera(width, height)
        return camera if scale == 1.0 else camera.scaled(1.0 / scale)

    def moved(self) -> None:
        """The camera changed: draw at the moving size until it has been still a moment."""
        self.last_motion = time.perf_counter()

    def window_to_framebuffer(self, x: float, y: float) -> tuple[float, float]:
        window_w, window_h = glfw.get_window_size(self.window)
        fb_w, fb_h = self.framebuffer_size
        return x * fb_w / max(window_w, 1), y * fb_h / max(window_h, 1)

    def pick_point(self, x: float, y: float) -> np.ndarray | None:
        """World point [3] of the surface under window position (x, y), None if empty."""
        px, py = self.window_to_framebuffer(x, y)
        camera = self.current_camera()
        depth = self.renderer.pick_depth(camera, int(px), int(py))
        if depth is None:
            return None
        return flagging.unproject_pixel(camera, int(px), int(py), depth)

    # --- navigation actions --------------------------------------------------------------------
    def look_from(self, camera: Camera) -> None:
        """Stand at ``camera``'s pose, keeping the fly speed and the orbit pivot."""
        self.nav = NavigationState.from_camera(camera, up=self.up, speed=self.nav.speed, pivot=self.nav.pivot)
        self.moved()

    def snap_to_camera(self, index: int) -> None:
        if not self.cameras:
            return
        self.camera_index = index % len(self.cameras)
        self.look_from(self.cameras[self.camera_index])

    def reset_view(self) -> None:
        self.nav = self.home.copy()
        self.moved()

    def set_up(self, up) -> None:
        """A new world up [3] (the View panel's +-X/Y/Z): the view and home are re-levelled."""
        self.up = np.asarray(up, np.float64)
        self.up_source = "chosen"
        if self.cameras:
            self.nav = leveled(self.nav, self.up)
            self.home = leveled(self.home, self.up)
        else:  # no camera to keep: the home view is the default view for the new up
            self.home = self.initial_view()
            self.nav = self.home.copy()
        self.moved()

    def frame_model(self) -> None:
        """Fit the view to the scene (navigation.framed: what the cameras look at, the shell and
        far outliers left out) in the part of the window the panel leaves, looking the same way;
        pivot at its centre."""
        width, height = self.framebuffer_size
        covered, _ = self.window_to_framebuffer(self.covered_left, 0.0)
        self.nav = framed(self.nav, self.edit.visible_arrays()["means"], width, height, covered, self.cameras)
        self.moved()

    def grab_depth(self, x: float, y: float) -> float:
        """The camera depth a pan started at window position (x, y) keeps under the cursor: the
        surface there, else the pivot's depth, else the fly speed (a step ahead)."""
        px, py = self.window_to_framebuffer(x, y)
        depth = self.renderer.pick_depth(self.current_camera(), int(px), int(py))
        if depth is None:
            depth = self.nav.pivot_depth()
        return depth if depth > 1e-6 else self.nav.speed

    def pan(self, dx: float, dy: float, depth: float) -> None:
        """A drag of (dx, dy) window pixels slides the view so the point grabbed at ``depth``
        stays under the cursor."""
        fb_dx, fb_dy = self.window_to_framebuffer(dx, dy)  # the camera's focal is in framebuffer pixels
        self.nav.pan(fb_dx, fb_dy, depth, self.current_camera().fy)
        self.moved()

    def set_pivot_at_pixel(self, x: float, y: float) -> None:
        point = self.pick_point(x, y)
        if point is None:
            self.status.text = "double-click: no surface under the cursor"
            return
        self.nav.pivot = point
        self.settings.orbit = True
        self.status.text = "orbit pivot set"

    # --- training photos -----------------------------------------------------------------------
    def nearest_camera_index(self, camera: Camera) -> int | None:
        """The training camera closest to ``camera`` (centre distance + viewing angle), or None."""
        if not self.cameras:
            return None
        distances = [pose_distance(camera.world_to_camera, c.world_to_camera) for c in self.cameras]
        return int(np.argmin(distances))

    def training_photo(self, index: int) -> np.ndarray | None:
        """The photo of training camera ``index`` [H, W, 3] in [0, 1] (the last one is kept), or
        None when the source has no scene photos or the file cannot be read."""
        if self.source.scene is None:
            return None
        if self._photo_cache[0] != index:
            try:
                self._photo_cache = (index, photo_tensor(self.source.scene, index).numpy())
            except (InputError, OSError) as exc:
                self.status.text = f"training photo not shown: {exc}"
                self._photo_cache = (index, None)
        return self._photo_cache[1]
