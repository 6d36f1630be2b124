"""Drawing one frame's picture: the splats into the scene texture (at reduced size while the
camera or the model moves, full size once still, nothing when nothing changed), the torch
reference comparison, and the world-space overlays (cameras, flags, crop box, selection).

The drawer owns GL resources, render caching and the coverage colouring; what to draw is read
from the view.View it is given (settings, camera, model), and the flags and photo fit drawn over it."""

from __future__ import annotations

import time

import moderngl
import numpy as np

from inceptiongs.constants import sh_degree_from_count
from inceptiongs.evaluation.metrics import psnr

from .coverage_mode import COUNTING_SLICE_S, CoverageMode
from . import detail as level_of_detail
from .detail import (BUDGET_START, SETTLED_GRANULARITY_PX, DetailWorker, camera_key, detail_state, next_budget,
                     preview_arrays)
from .editing import box_handles
from .block_cells import CELL_COLOR
from .frustums import TrainingFrustums, away_from, segments_for_cameras
from .gizmo import gizmo_handles, gizmo_segments
from .images import compose_photo, visualize
from .navigation import nearest_camera_index
from .overlay import OverlayRenderer, SceneTexture
from .points import point_colours, render_points
from .reference import ReferenceWorker, error_heatmap, side_by_side
from .settings import GL_MODE_NAMES

# While the camera moves the splats are drawn at a reduced resolution; the full frame follows
# once it has been still for STILL_SECONDS (the "refine when still" rule of the frame-rate
# target). The size follows the renders' cost (next_moving_scale): a step of MOVING_SCALE_STEP
# down after a render over MOVING_BUDGET_MS, a step up after one under MOVING_GROW_SHARE of it,
# between MOVING_SCALE_MIN and the full size. A step down that barely helped (the smaller size
# costs over MOVING_SHRINK_GAIN of the larger: the render is sort-bound, its cost is per Gaussian)
# is not taken, or taken back: the image is not made blocky for nothing.
MOVING_SCALE_MIN = 0.25
MOVING_SCALE_MAX = 1.0
MOVING_SCALE_STEP = 0.125
MOVING_RENDER_SCALE = 0.5  # the first moving render's
MOVING_BUDGET_MS = 40.0
MOVING_GROW_SHARE = 0.6
MOVING_SHRINK_GAIN = 0.85
# Each size's cost is a running mean (this weight for the newest render): one render slowed by
# other work on the machine does not move the size.
MOVING_COST_WEIGHT = 0.5
STILL_SECONDS = 0.15
# A model that changed less than MODEL_STILL_SECONDS ago is drawn at the moving size too (a
# training view updates at reduced resolution) and refined once the job pauses, stops or goes
# quiet.
MODEL_STILL_SECONDS = 1.0
# The torch reference renders at most this many pixels wide (it runs on the CPU).
REFERENCE_MAX_WIDTH = 320
TRAINING_COLOR = (0.2, 0.6, 1.0)
POORLY_FIT_COLOR = (1.0, 0.65, 0.0)  # training photos the open run fits poorly (view_fit.json)
FLAG_COLOR = (1.0, 0.3, 0.2)
SELECTED_FLAG_COLOR = (1.0, 0.9, 0.1)
CROP_COLOR = (0.3, 1.0, 0.3)
CROP_HANDLE_SIZE = 9.0  # pixels: the face handles one drags
# Flags and training cameras closer to the current camera than this many frustum depths are not
# drawn (frustums.away_from): around the eye their lines run across the whole window.
FLAG_HIDE_DISTANCE = 4.0
SELECTION_COLOR = (1.0, 0.2, 0.9)
# The gizmo's x, y, z handles, coloured as the usual axis colours; the tips drawn large to grab.
GIZMO_COLORS = np.array([[1.0, 0.25, 0.25], [0.3, 1.0, 0.3], [0.35, 0.5, 1.0]])
GIZMO_HANDLE_SIZE = 14.0


def next_moving_scale(scale: float, costs: dict) -> float:
    """The render scale for the next moving frame after a render at ``scale``; ``costs``:
    {scale: running mean of the render's ms (preprocess + sort + draw)} (the constants above)."""
    current = costs.get(scale)
    if current is None:
        return scale
    down, up = round(scale - MOVING_SCALE_STEP, 6), round(scale + MOVING_SCALE_STEP, 6)
    smaller, larger = costs.get(down), costs.get(up)
    if current > MOVING_BUDGET_MS:
        if larger is not None and up <= MOVING_SCALE_MAX and current > MOVING_SHRINK_GAIN * larger:
            return up  # the step down bought little: back to the sharper size
        if down < MOVING_SCALE_MIN - 1e-9 or (smaller is not None and smaller > MOVING_SHRINK_GAIN * current):
            return scale
        return down
    if current < MOVING_GROW_SHARE * MOVING_BUDGET_MS and up <= MOVING_SCALE_MAX + 1e-9:
        # Safe when even all of the cost grew with the pixels; else only if the larger size's
        # own cost (a running mean, maybe of a first slow render) is within budget.
        if current * (up / scale) ** 2 <= MOVING_BUDGET_MS or larger is None or larger <= MOVING_BUDGET_MS:
            return up
    return scale


def add_render_cost(costs: dict, scale: float, milliseconds: float) -> None:
    """Fold one render's ``milliseconds`` at ``scale`` into ``costs`` (MOVING_COST_WEIGHT)."""
    old = costs.get(scale)
    costs[scale] = milliseconds if old is None else (1 - MOVING_COST_WEIGHT) * old + MOVING_COST_WEIGHT * milliseconds


def frustum_colors(cameras: list, poorly_fit) -> np.ndarray:
    """[8 per camera, 3]: each training camera's frustum segments in TRAINING_COLOR, or
    POORLY_FIT_COLOR when its photo is among ``poorly_fit`` (image names)."""
    rows = [POORLY_FIT_COLOR if camera.name in poorly_fit else TRAINING_COLOR for camera in cameras]
    return np.repeat(np.asarray(rows, np.float64).reshape(-1, 3), 8, axis=0)


def box_segments(box_min, box_max) -> np.ndarray:
    """The 12 edges [12, 2, 3] of an axis-aligned box."""
    lo, hi = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
    corners = np.array([[(hi if (i >> k) & 1 else lo)[k] for k in range(3)] for i in range(8)])
    edges = [(i, i | (1 << k)) for i in range(8) for k in range(3) if not (i >> k) & 1]
    return np.array([(corners[a], corners[b]) for a, b in edges])


class FrameDrawer:
    """GL drawing for one viewer: scene texture, overlays, the reference worker, the coverage
    mode's colours."""

    def __init__(self, ctx: moderngl.Context, renderer) -> None:
        self.ctx = ctx
        self.renderer = renderer
        self.overlay = OverlayRenderer(ctx)
        self.scene_texture = SceneTexture(ctx)
        self.uploaded_version = None
        self.reference = None  # ReferenceWorker, made when the reference mode is first used
        self.reference_psnr: float | None = None
        self.reference_request = None
        self.reference_shown = None  # (result, view) whose comparison the texture holds
        self.last_render_key = None
        self.moving_scale = MOVING_RENDER_SCALE  # the next moving render's (next_moving_scale)
        self.render_costs: dict[float, float] = {}  # scale -> running mean ms (add_render_cost)
        self.training_frustums = TrainingFrustums()  # which training cameras the overlays draw
        self.coverage = CoverageMode()  # counts computed when the coverage mode is first drawn
        self.detail: DetailWorker | None = None  # made when a large model is first shown (detail.py)
        self.detail_budget = BUDGET_START
        self.detail_seen: tuple = ()  # detail.detail_state when a frame last looked at the worker
        self._detail_requested = None  # the last cut asked for: (model, camera key, settled, budget)
        self._detail_requested_at = -1e9  # perf_counter() of that request
        self._detail_model = None  # the model last handed to the worker
        self.still_frame_owed = False  # the last frame was drawn for a moving camera or model
        self._preview: tuple | None = None  # (model, arrays): what a large model shows while its tree builds
        self._model_age = float("inf")  # seconds since a job's snapshot last replaced the model
        self.drawn = (0, 0, "")  # splats drawn, of the model's total, and how (the panel's LOD line)
        self.shown_arrays: dict | None = None  # what upload_model last handed over (coverage colours included)

    def upload_model(self, view, slice_s: float | None = None) -> None:
        """Hand the view's visible Gaussians to the renderer when they changed (recoloured by
        their view counts in the coverage mode). ``slice_s``: the coverage counts may take this
        long in this call (the window's frame: CoverageMode.update); meanwhile the model shows
        its own colours. None: counted to the end (a screenshot, a picture)."""
        model = (view.model_version, view.edit.version)
        coverage = view.settings.mode == "coverage"
        version = model + (("coverage",) if coverage else ())
        if version != self.uploaded_version:
            arrays = view.edit.visible_arrays()
            if coverage:
                # Depth for the occlusion test comes from the model as it is (its own colours).
                self.renderer.set_gaussians(arrays, version=hash(model) & 0x7FFFFFFF)
                coloured = self.coverage.update(arrays, view.cameras, self.depth_of, model, slice_s)
                if coloured is None:   # still counting: this frame shows the model's own colours
                    self.uploaded_version = model + ("counting",)
                    self.shown_arrays = arrays
                    return
                arrays = coloured
            self.renderer.set_gaussians(arrays, version=hash(version) & 0x7FFFFFFF)
            self.uploaded_version = version
            self.shown_arrays = arrays

    def detail_engaged(self, view, model_age: float) -> bool:
        """Whether this frame draws a large model by its level of detail (detail.py): a model of
        at least LOD_MIN_GAUSSIANS, in a mode that draws the splats as they are, unless the user
        asked for full detail. ``model_age``: seconds since a job's snapshot replaced the model."""
        settings = view.settings
        engaged = (view.edit.count >= level_of_detail.LOD_MIN_GAUSSIANS and not settings.full_detail
                   and not view.shows_points and settings.mode in ("rgb", "depth", "normal", "opacity"))
        self._model_age = model_age
        if not engaged:
            self.drawn = (view.edit.count, view.edit.count, "full detail")
        return engaged

    def upload_detail(self, view, moving: bool) -> str:
        """Hand the renderer what a large model shows (detail.py) -> "preview" (a subset while the
        tree builds or a job runs), "pending" (the cut for this frame is on its way: the frame
        keeps the last image) or "cut"."""
        model = (view.model_version, view.edit.version)
        if self.detail is None:
            self.detail = DetailWorker()
        self.detail_seen = detail_state(self.detail)
        if self._model_age < MODEL_STILL_SECONDS:
            # A job's snapshots come faster than a tree builds: a fixed subset of the newest one
            # is drawn, the tree is built once the model rests.
            self._upload_preview(view, model, "live snapshot")
            return "preview"
        if self._detail_model != model:   # visible_arrays() copies the model when some are deleted
            self.detail.set_model(model, view.edit.visible_arrays())
            self._detail_model = model
        camera = view.current_camera()
        total = view.edit.count
        if not self.detail.ready:
            self._upload_preview(view, model)
            return "preview"
        if self.detail.version == model:
            level_of_detail.share_tree_leaves(view, self.detail.hierarchy)
        key = camera_key(camera)
        wanted = (model, key, not moving, 0 if not moving else self.detail_budget)
        cut = self.detail.latest(model)
        have_settled = cut is not None and cut.settled and cut.camera_key == key
        # A moving camera asks for a new cut at most every MOVING_CUT_INTERVAL seconds: the worker
        # shares the two cores with the frame, and a cut a few degrees old still fits the view.
        due = not moving or time.perf_counter() - self._detail_requested_at >= level_of_detail.MOVING_CUT_INTERVAL
        if self._detail_requested != wanted and not have_settled and due:
            self.detail.request(model, camera, not moving, self.detail_budget)
            self._detail_requested, self._detail_requested_at = wanted, time.perf_counter()
        if cut is None:
            self._upload_preview(view, model)
            return "preview"
        if moving and cut.settled and self.uploaded_version == ("cut", model, cut.serial):
            # The camera started moving: drawing the fine cut again would hold the frame for
            # seconds; the last image stays until the first budgeted cut arrives.
            return "pending"
        version = ("cut", model, cut.serial)
        if self.uploaded_version != version:
            if cut.packed is None:
                # Uploaded once, then dropped (another model or mode was drawn since): made again.
                if self._detail_requested != ("again",) + wanted:
                    self.detail.request(model, camera, not moving, self.detail_budget)
                    self._detail_requested = ("again",) + wanted
                return "pending"
            self.renderer.set_packed(*cut.packed, version=hash(version) & 0x7FFFFFFF)
            self.uploaded_version = version
            cut.packed = None   # GL holds it now: a settled cut of millions is not kept twice
        how = f"settled cut ({SETTLED_GRANULARITY_PX:g} px)" if cut.settled else f"budget {cut.budget:,}"
        self.drawn = (cut.count, total, how)
        return "pending" if not moving and not have_settled else "cut"

    def _upload_preview(self, view, model, why: str | None = None) -> None:
        """While the tree builds or a job's snapshots change the model: a fixed random subset of
        the model (detail.preview_arrays); ``why``: the panel's word for it."""
        if self._preview is None or self._preview[0] != model:
            self._preview = (model, preview_arrays(view.edit.visible_arrays()))
        version = ("preview", model)
        if self.uploaded_version != version:
            self.renderer.set_gaussians(self._preview[1], version=hash(version) & 0x7FFFFFFF)
            self.uploaded_version = version
        if why is None:
            why = f"preview, building the tree {int(round(100 * self.detail.progress))} %"
        self.drawn = (len(self._preview[1]["means"]), view.edit.count, why)

    def detail_busy(self) -> bool:
        """The LOD worker is building or cutting, or made something no frame has drawn yet: a
        frame will follow without an event."""
        return self.detail is not None and (self.detail.busy or detail_state(self.detail) != self.detail_seen)

    def depth_of(self, camera) -> np.ndarray:
        """The uploaded model's camera depth [h, w] at ``camera`` (0 = no surface)."""
        return self.renderer.render(camera, "depth")[..., 0]

    def draw_scene(self, view, stats, model_changed_at: float, screen: moderngl.Framebuffer) -> None:
        """The splats of ``view`` into the scene texture and onto ``screen``; ``stats``: the
        FrameStats to fill; model_changed_at: perf_counter() of the last snapshot shown."""
        now = time.perf_counter()
        moving = (now - view.last_motion < STILL_SECONDS
                  or now - model_changed_at < MODEL_STILL_SECONDS)
        self.still_frame_owed = moving   # the frame after the motion stops refines (pacing.is_idle)
        points = view.shows_points and view.settings.mode != "reference"
        scale = self.moving_scale if moving and not points else 1.0  # points are cheap at any size
        detail = self.detail_engaged(view, now - model_changed_at)
        settings = view.settings
        mode = settings.mode
        if detail:
            shown = self.upload_detail(view, moving)
            if shown == "pending" and self.scene_texture.texture is not None:
                self.scene_texture.blit(screen)  # the cut to draw is on its way: the last frame stays
                return
            if shown == "preview":
                scale = self.moving_scale   # a stand-in: not worth the full size's time
        else:
            self.upload_model(view, COUNTING_SLICE_S)
        camera = view.current_camera(scale)
        photo_index = nearest_camera_index(view.cameras, camera) if settings.photo != "off" and mode == "rgb" else None
        key = (mode, settings.reference_view, scale, camera.width, camera.height,
               camera.world_to_camera.tobytes(), camera.fy, self.uploaded_version, settings.sh_degree_cap,
               settings.splat_scale, tuple(settings.background), settings.photo, settings.photo_alpha, photo_index)
        photo = view.photos.photo_of(view.source.scene, photo_index, view.status) if photo_index is not None else None
        if mode == "reference":
            self.draw_reference(view)
        elif key != self.last_render_key:
            self.reference_shown = None  # the texture is about to hold a splat render
            if points:
                self.draw_points(view, camera, photo, stats)
            elif photo is not None:
                # The render with the nearest training photo: composed on the CPU, then uploaded.
                image = self.renderer.render(camera, "rgb", background=settings.background,
                                             sh_degree_cap=settings.sh_degree_cap, splat_scale=settings.splat_scale)
                self.scene_texture.upload(compose_photo(image, photo, settings.photo, settings.photo_alpha))
            elif mode in ("rgb", "coverage"):
                # Straight into the texture: draw() renders upright (GL row 0 = image bottom).
                target = self.scene_texture.ensure(camera.width, camera.height)
                self.renderer.draw(camera, GL_MODE_NAMES[mode], target, background=settings.background,
                                   sh_degree_cap=settings.sh_degree_cap, splat_scale=settings.splat_scale)
                self.scene_texture.flip_y = False
            else:
                # depth and normal need normalising for display, and opacity must be the alpha
                # image itself (draw() would composite it like colour, over the background, with
                # the colour path's blending: a solid surface read as grey ~0.4): read back, map,
                # upload, exactly what F12 and `inceptiongs render --mode alpha` write.
                image = self.renderer.render(camera, GL_MODE_NAMES[mode], sh_degree_cap=settings.sh_degree_cap,
                                             splat_scale=settings.splat_scale)
                self.scene_texture.upload(visualize(image, mode))
            if not points:  # the points' own figures were set by draw_points
                stats.sort_ms = float(self.renderer.timings.get("sort_ms", 0.0))
                stats.draw_ms = float(self.renderer.timings.get("draw_ms", 0.0))
                stats.drawn_by = "splats"
            if mode in ("rgb", "coverage") and photo is None and not points:  # the splats drawn into the texture
                add_render_cost(self.render_costs, scale, sum(self.renderer.timings.values()))
                if moving:
                    self.moving_scale = next_moving_scale(scale, self.render_costs)
            if detail and moving and self.drawn[2].startswith("budget"):
                # From the splats this render drew: the cut in hand may be older and smaller than the budget.
                self.detail_budget = next_budget(self.drawn[0], sum(self.renderer.timings.values()))
            stats.rendered_scale = scale
            stats.splat_renders += 1
            self.last_render_key = key
        self.scene_texture.blit(screen)

    def points_image(self, view, camera) -> np.ndarray:
        """The shown points (sparse or triangulated) as points.render_points draws them, in the
        view's mode (coverage: their view-count colours), as displayable RGB [H, W, 3]: what the
        window shows and what F12 writes. The splats stay uploaded: picking reads them."""
        self.upload_model(view)
        settings = view.settings
        arrays = self.shown_arrays if self.shown_arrays is not None else view.edit.visible_arrays()
        mode = settings.mode if settings.mode != "reference" else "rgb"
        raw = render_points(arrays["means"], point_colours(arrays), camera, GL_MODE_NAMES[mode], settings.background)
        return visualize(raw, mode)

    def draw_points(self, view, camera, photo, stats) -> None:
        """The points into the scene texture (with the nearest training photo when one is
        shown); ``stats`` gets their drawing time, no sort (the frame figures name them)."""
        start = time.perf_counter()
        image = self.points_image(view, camera)
        if photo is not None:
            image = compose_photo(image, photo, view.settings.photo, view.settings.photo_alpha)
        self.scene_texture.upload(image)
        stats.sort_ms, stats.draw_ms = 0.0, 1e3 * (time.perf_counter() - start)
        stats.drawn_by = "points"

    def draw_reference(self, view) -> None:
        """GL and torch at the same reduced camera; the torch image comes from the worker. The
        comparison is computed once per new result (and view choice), then the texture is reused."""
        settings = view.settings
        camera = view.current_camera()
        if camera.width > REFERENCE_MAX_WIDTH:
            camera = camera.scaled(camera.width / REFERENCE_MAX_WIDTH)
        if self.reference is None:
            self.reference = ReferenceWorker()
        request_key = (camera.world_to_camera.tobytes(), camera.width, self.uploaded_version,
                       settings.sh_degree_cap)
        if self.reference_request != request_key:
            arrays = view.edit.visible_arrays()
            cap = min(settings.sh_degree_cap, sh_degree_from_count(arrays["sh"].shape[1]))
            self.reference.request(arrays, hash(self.uploaded_version), camera, settings.background, cap)
            self.reference_request = request_key
        result = self.reference.result()
        self.last_render_key = None  # the texture holds the comparison, not a splat render
        if result is None or self.reference_shown == (result, settings.reference_view):
            return
        gl = self.renderer.render(result.camera, mode="rgb", background=settings.background,
                                  sh_degree_cap=settings.sh_degree_cap, splat_scale=1.0)
        self.reference_psnr = float(psnr(gl.astype(np.float64), result.rgb.astype(np.float64)))
        if settings.reference_view == "heat-map":
            image = error_heatmap(gl, result.rgb)
        else:
            image = side_by_side(gl, result.rgb)
        self.scene_texture.upload(image)
        self.reference_shown = (result, settings.reference_view)

    def reference_settled(self) -> bool:
        """The reference mode has nothing left to draw until something changes."""
        worker = self.reference
        if worker is None or not worker.idle:
            return False
        return worker.error is not None or (self.reference_shown is not None
                                            and self.reference_shown[0] is worker.result())

    def draw_overlays(self, view, flag_book, poorly_fit, screen: moderngl.Framebuffer, gizmo=None) -> None:
        """Over the scene: training cameras (``poorly_fit``: image names drawn apart), the
        flags of ``flag_book`` (flags.FlagBook), the crop box, the selection and the gizmo
        (``gizmo``: (pivot [3], handle length) or None)."""
        settings, edit, flags = view.settings, view.edit, flag_book.items
        camera = view.current_camera()
        screen.use()
        drawn, depth = self.training_frustums.for_cameras(view.cameras, poorly_fit, max(view.nav.speed * 0.1, 1e-3))
        training = [drawn[i] for i in away_from([view.cameras[i] for i in drawn], camera.center,
                                                FLAG_HIDE_DISTANCE * depth)]
        if settings.show_training_cameras and training:
            shown_cameras = [view.cameras[i] for i in training]
            segments = segments_for_cameras(shown_cameras, depth)
            self.overlay.draw_segments(camera, segments, frustum_colors(shown_cameras, poorly_fit))
        # A flag made where the camera stands would be drawn around the eye, its lines across the
        # whole window: flags that close are left out until the camera moves away.
        shown = away_from([f.camera for f in flags], camera.center, FLAG_HIDE_DISTANCE * depth)
        if settings.show_flags and shown:
            segments = segments_for_cameras([flags[i].camera for i in shown], depth * 1.5)
            colors = np.tile(FLAG_COLOR, (len(segments), 1))
            if flag_book.selected in shown:
                slot = shown.index(flag_book.selected)
                colors[8 * slot: 8 * slot + 8] = SELECTED_FLAG_COLOR
            self.overlay.draw_segments(camera, segments, colors)
        cells = (view.block_cells.of_model(view.source, view.model_version, view.edit.base["means"], view.up, view.status)
                 if settings.mode == "coverage" else None)
        if cells is not None and len(cells):
            self.overlay.draw_segments(camera, cells, np.tile(CELL_COLOR, (len(cells), 1)))
        if settings.crop_enabled:
            self.overlay.draw_segments(camera, box_segments(settings.crop_min, settings.crop_max),
                                       np.tile(CROP_COLOR, (12, 1)))
            self.overlay.draw_points(camera, box_handles(settings.crop_min, settings.crop_max), CROP_COLOR,
                                     size=CROP_HANDLE_SIZE)
        if edit.selected.any():
            self.overlay.draw_points(camera, edit.base["means"][edit.selected], SELECTION_COLOR)
        if gizmo is not None:
            self.overlay.draw_segments(camera, gizmo_segments(*gizmo), GIZMO_COLORS)
            self.overlay.draw_points(camera, gizmo_handles(*gizmo), GIZMO_COLORS, size=GIZMO_HANDLE_SIZE)

    def close(self) -> None:
        """Stop the reference and LOD workers (no GL calls: safe without a current context)."""
        if self.reference is not None:
            self.reference.close()
        if self.detail is not None:
            self.detail.close()

    def release(self) -> None:
        self.overlay.release()
        self.scene_texture.release()
