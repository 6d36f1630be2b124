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
from .navigation import (NavigationState, default_view, estimate_up, forward_facing, framed, leveled, model_up,
                         statistics_sample)
from .settings import StatusLine, ViewSettings


class View:
    """The camera on one window and the model it shows. ``window``: the GLFW window (its sizes);
    ``renderer``: the splat renderer (depth under the cursor); ``status``: the status line."""

    def __init__(self, source, window, renderer, status: StatusLine, covered_left: float = 0.0) -> None:
        self.window, self.renderer, self.status = window, renderer, status
        # Window pixels the panel covers at the window's left (Home and the first view avoid them).
        self.covered_left = covered_left
        self.settings = ViewSettings()
        self.source = source
        self.edit = EditState(source.gaussians)  # the model shown, with its deletions and selection
        self.model_version = 1  # changes whenever another model replaces the shown one
        # The model shown is sparse (or triangulated) points, drawn as small screen-space points.
        self.shows_points = bool(getattr(source, "sparse_points", False))
        self.cameras = source.cameras
        # Up: the cameras' mean up, else the model's dominant plane; the View panel may change it.
        saved_up = getattr(source, "saved_up", None)
        if self.cameras:
            self.up, self.up_source = estimate_up(self.cameras), "from the cameras"
        elif saved_up is not None:   # a saved edit: the up it was edited with (sources.read_saved_view)
            self.up, self.up_source = saved_up, "as saved"
        else:
            self.up, self.up_source = model_up(source.gaussians["means"]), "from the model"
        self.nav = self.initial_view()
        self.home = self.nav.copy()
        self.camera_index = 0 if self.cameras else -1
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

    def block_cell_segments(self):
        """The open run's block cells as ground outlines [4 * C, 2, 3] (block_cells), None when it
        was not trained in blocks; read once per source and model."""
        from .block_cells import cell_outline_segments, read_block_plan  # noqa: PLC0415

        key = (id(self.source), self.model_version)
        if getattr(self, "_cells", (None, None))[0] != key:
            plan, problem = read_block_plan(getattr(self.source, "run_dir", None))
            if problem:
                self.status.text = problem
            segments = None if plan is None else cell_outline_segments(plan, self.edit.base["means"], self.up)
            self._cells = (key, segments)
        return self._cells[1]

    # --- the camera ----------------------------------------------------------------------------
    def initial_view(self) -> NavigationState:
        """Where the window opens: with cameras around the scene, framed on what they look at as
        Home frames it, seen from the first camera's heading (a capture's first camera may face
        away from the scene: bonsai's showed a black window); with cameras that all face one way
        (navigation.forward_facing: fern), or without a model yet, at the first camera, which
        looks at the scene as they all do; without cameras, navigation.default_view."""
        width, height = self.framebuffer_size
        means = self.edit.base["means"]
        if self.cameras:
            first = self.cameras[0]
            centers = np.stack([c.center for c in self.cameras])
            spread = float(np.linalg.norm(centers.max(0) - centers.min(0))) if len(centers) > 1 else 1.0
            nav = NavigationState.from_camera(first, up=self.up, speed=max(spread * 0.5, 1e-3))
            if len(means) == 0 or forward_facing(self.cameras):
                return nav
            covered, _ = self.window_to_framebuffer(self.covered_left, 0.0)
            return framed(nav, means, width, height, covered, self.cameras)
        saved = getattr(self.source, "saved_camera", None)
        if saved is not None:   # a saved edit reopens where it was seen when saved
            pivot = saved.center + saved.rotation[2] * _saved_pivot_distance(saved.center, means)
            return NavigationState.from_camera(saved, up=self.up, speed=default_view(means, width, height).speed,
                                               pivot=pivot)
        return default_view(means, width, height, up=self.up)

    def untouched(self) -> bool:
        """The camera is still where the window opened (the user has not moved it)."""
        return bool(np.allclose(self.nav.world_to_camera, self.home.world_to_camera))

    def open_at_model(self) -> None:
        """A model arrived for a window opened without one (triangulated points): unless the
        user moved meanwhile, open where it is (initial_view) and make that the home view."""
        if self.untouched():
            self.nav = self.initial_view()
            self.home = self.nav.copy()
            self.moved()

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


def _saved_pivot_distance(center: np.ndarray, means: np.ndarray) -> float:
    """How far ahead of a saved camera its orbit centre lies: the distance to the model's median
    (centre [3], means [N, 3]); 1 without a model. Floored so the pivot is never at the eye."""
    if len(means) == 0:
        return 1.0
    return max(float(np.linalg.norm(np.median(statistics_sample(means), axis=0) - center)), 1e-3)
