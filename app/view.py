"""What the window shows and from where: the open source and its model (deletions and selection
over it: editing.EditState), the camera (navigation.NavigationState) with its home view and world
up, the training camera last stepped to, and the render settings (settings.ViewSettings).

The View panel, the Inspect panel, the mouse and the fly keys change this object; the drawing
reads it. Camera maths lives in navigation.py; this is the state it acts on."""

from __future__ import annotations

import time

import numpy as np

from inceptiongs.camera import Camera

from . import flags as flagging
from .block_cells import BlockCellOutlines
from .editing import EditState
from .navigation import NavigationState, estimate_up, framed, leveled, model_up, opening_view
from .settings import StatusLine, ViewSettings
from .training_photos import TrainingPhotoCache
from .window import WindowPixels


def scene_points(source) -> np.ndarray | None:
    """The sparse points [P, 3] of the scene ``source`` shows (normalised frame, as its cameras),
    or None (a bare model, a scene without points): Home leaves the sky shell out by them."""
    points = getattr(getattr(source, "scene", None), "points", None)
    return None if points is None or len(points) == 0 else np.asarray(points, np.float64)


class View:
    """The camera on one window and the model it shows. ``window``: the GLFW window (its sizes);
    ``renderer``: the splat renderer (depth under the cursor); ``status``: the status line."""

    def __init__(self, source, window, renderer, status: StatusLine, covered_left: float = 0.0) -> None:
        self.window, self.renderer, self.status = window, renderer, status
        self.pixels = WindowPixels(window)
        # Window pixels the panel covers at the window's left (Home and the first view avoid them).
        self.covered_left = covered_left
        self.settings = ViewSettings()
        self.source = source
        self.edit = EditState(source.gaussians)  # the model shown, with its deletions and selection
        self.model_version = 1  # changes whenever another model replaces the shown one
        # The model shown is sparse (or triangulated) points, drawn as small screen-space points.
        self.shows_points = bool(getattr(source, "sparse_points", False))
        # The means of the LOD tree's leaves when the model shown is them (detail.share_tree_leaves).
        self.shared_means: np.ndarray | None = None
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
        self.photos = TrainingPhotoCache()  # the photo views' training photo
        self.block_cells = BlockCellOutlines()  # the coverage mode's cell outlines of the open run

    # --- the model shown -----------------------------------------------------------------------
    def show_model(self, gaussians: dict, points: bool = False) -> None:
        """A new model (a job's snapshot, the triangulated points: ``points``) replaces the shown
        one: edits are for models at rest, so its edit state starts afresh."""
        self.edit = EditState(gaussians)
        self.model_version += 1
        self.shows_points = points

    def show_source(self, source) -> None:
        """Another source of the same scene (a run opened from the Training panel) is shown."""
        self.source = source
        self.show_model(source.gaussians, points=bool(getattr(source, "sparse_points", False)))

    # --- the camera ----------------------------------------------------------------------------
    def initial_view(self) -> NavigationState:
        """Where the window opens (navigation.opening_view), beside the panel."""
        width, height = self.pixels.framebuffer_size
        covered, _ = self.pixels.to_framebuffer(self.covered_left, 0.0)
        return opening_view(self.cameras, self.edit.base["means"], self.up, width, height, covered,
                            getattr(self.source, "saved_camera", None), scene_points(self.source))

    def open_at_model(self) -> None:
        """A model arrived for a window opened without one (triangulated points): unless the
        user moved meanwhile, open where it is (initial_view) and make that the home view."""
        if np.allclose(self.nav.world_to_camera, self.home.world_to_camera):  # not moved meanwhile
            self.nav = self.initial_view()
            self.home = self.nav.copy()
            self.moved()

    def current_camera(self, scale: float = 1.0) -> Camera:
        width, height = self.pixels.framebuffer_size
        camera = self.nav.camera(width, height)
        return camera if scale == 1.0 else camera.scaled(1.0 / scale)

    def moved(self) -> None:
        """The camera changed: draw at the moving size until it has been still a moment."""
        self.last_motion = time.perf_counter()

    def pick_point(self, x: float, y: float) -> np.ndarray | None:
        """World point [3] of the surface under window position (x, y), None if empty."""
        px, py = self.pixels.to_framebuffer(x, y)
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
        width, height = self.pixels.framebuffer_size
        covered, _ = self.pixels.to_framebuffer(self.covered_left, 0.0)
        self.nav = framed(self.nav, self.edit.visible_arrays()["means"], width, height, covered, self.cameras,
                          scene_points(self.source))
        self.moved()

    def pan(self, dx: float, dy: float, depth: float) -> None:
        """A drag of (dx, dy) window pixels slides the view so the point grabbed at ``depth``
        stays under the cursor."""
        fb_dx, fb_dy = self.pixels.to_framebuffer(dx, dy)  # the camera's focal is in framebuffer pixels
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
