"""Level of detail in the window: a model of millions of Gaussians drawn as a cut of its LOD tree.

A frame cannot draw every Gaussian of a large model in time (5M on two cores: ~3 s), so above
LOD_MIN_GAUSSIANS the window draws a cut of the model's hierarchy (inceptiongs/lod):

- while the camera moves, the finest cut within a splat *budget* (greedy_budget_cut_nodes),
  the budget following the moving render's own time so it stays near MOVING_TARGET_MS
  (:func:`next_budget`), at the reduced size the window picks for any moving frame
  (drawing.next_moving_scale);
- once the camera is still, the cut at SETTLED_GRANULARITY_PX (nodes merged only where their
  whole footprint is under a pixel), drawn at full size: the settled frame, within a fraction
  of a grey level of the full render (tests/app/test_app_detail.py);
- "full detail always" (ViewSettings.full_detail) draws every Gaussian, as small models are.

The moving cuts are blended towards their parents near the threshold (inceptiongs.lod.blend),
so a node crossing it fades into its children instead of popping; the settled cut is drawn as
it is (under a pixel, a blend hides nothing).

The hierarchy is built (or read from the cache, keyed by the model's content) and the cuts are
chosen on one worker thread, so the window keeps answering while a 5M model builds (~30 s the
first time, ~1.5 s from the cache): the newest request replaces an unanswered one. Until the
hierarchy is ready a fixed random PREVIEW_COUNT of the Gaussians is drawn, and the panel says so.

A job's snapshots change the model several times a minute: a hierarchy is built only for a
model that has rested a second (drawing.MODEL_STILL_SECONDS); until then a fixed random
PREVIEW_COUNT of the newest snapshot is drawn ("live snapshot" in the panel).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
import torch

from inceptiongs.renderer.layout import texels_per_gaussian

LOD_MIN_GAUSSIANS = 500_000
SETTLED_GRANULARITY_PX = 1.0
# The moving cut's render (preprocess, sort, compositing) is held near this; the rest of a
# frame (the panel, the swap, the worker's cut on the other core) does not depend on the budget,
# and a budget chasing it fell to its minimum for nothing.
MOVING_TARGET_MS = 25.0
BUDGET_START = 100_000
BUDGET_MIN = 20_000
BUDGET_MAX = 2_000_000
# One frame moves the budget by at most this factor either way: one frame slowed by other work
# on the machine must not halve the detail, nor one fast frame double it.
BUDGET_STEP_MAX = 1.5
PREVIEW_COUNT = 200_000
MOVING_CUT_INTERVAL = 0.2
PACK_CHUNK = 262_144


# Bytes the window keeps per Gaussian besides the model's own arrays: the LOD tree (every
# leaf copied in Morton order plus a third as many parents, 4 x (11 + 3 K) bytes each, with 16
# bytes of links and radius; an unedited model is then shown from those leaves and its own
# arrays freed, so the estimate errs on the safe side) and, for each Gaussian drawn, the
# renderer's: the packed Gaussians (16 x (3 + ceil(3 K / 4)) bytes; a texture for the quad
# paths), the preprocess output (64), then its copy as a texture for the quad paths (64) or
# the CPU compositing's per-splat terms (60), and the depth order (8).
TREE_LINK_BYTES = 16
GL_SPLAT_BYTES = 64 + 64 + 8


def model_bytes_per_gaussian(sh_coefficients: int) -> int:
    """A Gaussian's float32 arrays: mean, log-scales, quaternion, opacity and K SH colours."""
    return 4 * (3 + 3 + 4 + 1 + 3 * sh_coefficients)


def gl_bytes_per_gaussian(sh_coefficients: int) -> int:
    """GL memory per Gaussian drawn (on llvmpipe this is system memory too)."""
    return 16 * texels_per_gaussian(sh_coefficients) + GL_SPLAT_BYTES


def window_bytes(count: int, sh_coefficients: int) -> int:
    """Memory the window needs beyond the model for ``count`` Gaussians: the LOD tree when the
    model is large, and the GL buffers of the most it draws at once (every Gaussian, at worst)."""
    tree = 0
    if count >= LOD_MIN_GAUSSIANS:
        tree = (count * 4 // 3) * (model_bytes_per_gaussian(sh_coefficients) + TREE_LINK_BYTES)
    return tree + count * gl_bytes_per_gaussian(sh_coefficients)


def check_window_memory(source_path, count: int, sh_coefficients: int, available: int | None = None) -> None:
    """io.limits.check_allocation for what the window adds to the model, its one line ending
    with what to do instead."""
    from inceptiongs.errors import InputError  # noqa: PLC0415
    from inceptiongs.io.limits import check_allocation  # noqa: PLC0415

    try:
        check_allocation(window_bytes(count, sh_coefficients), str(source_path),
                         f"showing {count:,} Gaussians", available)
    except InputError as error:
        raise InputError(f"{error}; close other programs, or render views offscreen with "
                         "`inceptiongs render --lod-budget 2000000`") from None


@dataclass
class Cut:
    """The Gaussians one frame draws. packed: (texels, anchor, degree) as
    renderer.splats.pack_gaussians gives them (packed on the worker, not in the frame; None once
    uploaded), ``count``
    of them, of ``total`` in the model; settled: the still camera's fine cut; camera_key: the pose and
    size it was chosen for; serial: increases with every cut of the worker."""

    serial: int
    packed: tuple
    count: int
    total: int
    settled: bool
    camera_key: bytes
    budget: int | None


def next_budget(budget: int, render_ms: float, target_ms: float | None = None) -> int:
    """The splat budget for the next moving cut after a render of ``render_ms`` drawn with
    ``budget`` splats (target: MOVING_TARGET_MS unless given): proportional (the render's cost
    grows about linearly with its splats), moved by at most BUDGET_STEP_MAX, within
    [BUDGET_MIN, BUDGET_MAX]."""
    target_ms = MOVING_TARGET_MS if target_ms is None else target_ms
    if not (render_ms > 0.0 and np.isfinite(render_ms)):
        return budget   # no cost measured (a cached frame): nothing to learn
    ratio = min(max(target_ms / render_ms, 1.0 / BUDGET_STEP_MAX), BUDGET_STEP_MAX)
    return int(min(max(budget * ratio, BUDGET_MIN), BUDGET_MAX))


def pack_nodes(hierarchy, nodes: np.ndarray, chunk: int | None = None, weights: np.ndarray | None = None) -> tuple:
    """renderer.splats.pack_gaussians of the tree's ``nodes`` [S] into one texel array, holding
    no gathered copy of a cut of millions (gathering it whole first took 3 x the memory): nodes
    drawn as they are in one pass straight from the tree (renderer.pack_numba), nodes blended
    towards their parents (``weights`` [S], lod.blend) ``chunk`` (default PACK_CHUNK) at a
    time. The anchor is the cut's float64 centroid, as pack_gaussians would choose."""
    from inceptiongs.constants import sh_degree_from_count  # noqa: PLC0415
    from inceptiongs.lod.blend import blended_arrays, sibling_counts  # noqa: PLC0415
    from inceptiongs.renderer.pack_numba import pack_rows, rows_centroid  # noqa: PLC0415
    from inceptiongs.renderer.splats import pack_gaussians  # noqa: PLC0415

    chunk = PACK_CHUNK if chunk is None else chunk
    count = len(nodes)
    degree = sh_degree_from_count(hierarchy.sh.shape[1])
    anchor = rows_centroid(hierarchy.means, nodes)
    anchor = anchor if np.all(np.isfinite(anchor)) else np.zeros(3)
    if weights is None or not (weights < 1.0).any():
        # The nodes as they are: packed straight from the tree in one pass (no gathered copies).
        return pack_rows(hierarchy.arrays(), nodes, anchor), anchor, degree
    texels = np.empty((count, texels_per_gaussian(hierarchy.sh.shape[1]), 4), np.float32)
    siblings = sibling_counts(hierarchy, nodes)
    for start in range(0, count, chunk):
        part_nodes = nodes[start:start + chunk]
        arrays = blended_arrays(hierarchy, part_nodes, weights[start:start + chunk], siblings[start:start + chunk])
        part, _, _ = pack_gaussians(arrays, anchor=anchor)
        texels[start:start + len(part)] = part
    return texels, anchor, degree


def camera_key(camera) -> bytes:
    """What a cut depends on: pose, focal lengths and size."""
    return camera.world_to_camera.tobytes() + np.array([camera.fx, camera.fy, camera.width, camera.height],
                                                       np.float64).tobytes()


def preview_arrays(arrays: dict, count: int | None = None, seed: int = 0) -> dict:
    """A fixed random ``count`` (default PREVIEW_COUNT) of the Gaussians (all when fewer), in their order."""
    count = PREVIEW_COUNT if count is None else count
    total = len(arrays["means"])
    if total <= count:
        return arrays
    # One uniform draw per Gaussian (a choice without replacement permutes all N: 0.5 s at 5M),
    # slightly more kept than asked and the first ``count`` of them taken.
    rng = np.random.default_rng(seed)
    keep = np.flatnonzero(rng.random(total) < min(1.0, 1.05 * count / total))[:count]
    if len(keep) < count:   # a small model's draw came short: the exact choice is cheap there
        keep = np.sort(rng.choice(total, count, replace=False))
    return {name: values[keep] for name, values in arrays.items()}


def share_tree_leaves(view, hierarchy) -> bool:
    """Show the LOD tree's leaves (the same Gaussians in Morton order, inceptiongs.lod) as the
    model of ``view`` (view.View), so its arrays are held once, not twice (280 MB at 5M). Only for
    an unedited model: deletions and selections are masks in the model's order. -> whether it was
    done."""
    from inceptiongs.lod.hierarchy import GAUSSIAN_FIELDS  # noqa: PLC0415 - only large models need it

    from .editing import EditState  # noqa: PLC0415

    edit = view.edit
    leaves = hierarchy.leaf_count
    if (set(edit.base) != set(GAUSSIAN_FIELDS) or edit.version != 0 or edit.undo_stack
            or not edit.alive.all() or edit.selected.any()
            or leaves != len(edit.alive) or edit.base["means"] is getattr(view, "shared_means", None)):
        return False
    shared = {name: getattr(hierarchy, name)[:leaves] for name in edit.base}
    view.edit = EditState(shared)
    view.source.gaussians = shared
    view.shared_means = shared["means"]
    return True


class DetailWorker:
    """The hierarchy of the model shown and its cuts, made on one daemon thread.

    set_model() hands a model over (its hierarchy is built or loaded); request() asks for the cut
    of a camera; latest() is the newest cut made for the current model. ``progress`` (0..1) and
    ``error`` describe the build."""

    def __init__(self) -> None:
        self._lock = threading.Condition()
        self._model: tuple | None = None   # (version, arrays) to build for
        self._request: tuple | None = None  # (version, camera, settled, budget)
        self._closed = False
        self._serial = 0
        self.version = None          # the model the hierarchy below belongs to
        self.hierarchy = None
        self.progress = 0.0
        self.error: str | None = None
        self.build_seconds: float | None = None
        self.from_cache = False
        self._cut: Cut | None = None
        self._working = False  # the thread is building or cutting
        self._building = None  # the model version whose tree the thread is building
        self._thread = threading.Thread(target=self._run, name="level-of-detail", daemon=True)
        self._thread.start()

    # --- the window's side ------------------------------------------------------------------------
    def set_model(self, version, arrays: dict) -> None:
        """Build (or load) the hierarchy of ``arrays`` for model ``version``; the old cut is dropped."""
        with self._lock:
            queued = None if self._model is None else self._model[0]
            if version in (queued, self._building, self.version):
                return
            self._model, self._request, self._cut = (version, arrays), None, None
            self.hierarchy, self.version, self.progress, self.error = None, None, 0.0, None
            self._lock.notify()

    @property
    def ready(self) -> bool:
        return self.hierarchy is not None

    def request(self, version, camera, settled: bool, budget: int) -> None:
        """Ask for the cut of ``camera`` (the settled one, or the moving one within ``budget``)."""
        with self._lock:
            self._request = (version, camera, settled, int(budget))
            self._lock.notify()

    def latest(self, version) -> Cut | None:
        with self._lock:
            return self._cut if self.version == version else None

    @property
    def cut_serial(self) -> int | None:
        """The newest cut's serial, whatever model it was made for (None before the first)."""
        with self._lock:
            return None if self._cut is None else self._cut.serial

    @property
    def busy(self) -> bool:
        """A build or a cut is under way or waiting (the window is not idle)."""
        with self._lock:
            return self._model is not None or self._request is not None or self._working

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._lock.notify()

    # --- the thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._lock:
                while not self._closed and self._model is None and (self._request is None or self.hierarchy is None):
                    self._lock.wait()
                if self._closed:
                    return
                model, self._model = self._model, None
                self._building = None if model is None else model[0]
                request = None if model is not None else self._request
                if request is not None:
                    self._request = None
                self._working = True
            try:
                if model is not None:
                    self._build(*model)
                elif request is not None:
                    self._make_cut(*request)
            finally:
                with self._lock:
                    self._working, self._building = False, None

    def _build(self, version, arrays: dict) -> None:
        from inceptiongs.gaussians import Gaussians  # noqa: PLC0415 - only large models need it
        from inceptiongs.lod.cache import load_or_build  # noqa: PLC0415

        start = time.perf_counter()

        def progress(fraction: float) -> None:
            self.progress = fraction

        try:
            gaussians = Gaussians(**{name: torch.from_numpy(np.ascontiguousarray(values))
                                     for name, values in arrays.items()})
            hierarchy, cached = load_or_build(gaussians, progress=progress)
        except (MemoryError, ValueError, OSError) as error:
            with self._lock:
                if self._model is None:
                    self.error = f"level of detail unavailable: {error}"
            return
        with self._lock:
            if self._model is not None:
                return   # another model came meanwhile: this hierarchy is for nothing shown
            self.hierarchy, self.version, self.progress = hierarchy, version, 1.0
            self.build_seconds, self.from_cache = time.perf_counter() - start, cached

    def _make_cut(self, version, camera, settled: bool, budget: int) -> None:
        from inceptiongs.lod.blend import blend_weights  # noqa: PLC0415
        from inceptiongs.lod.cut import cut_nodes, greedy_budget_cut_nodes  # noqa: PLC0415

        hierarchy = self.hierarchy
        if hierarchy is None or version != self.version:
            return
        if settled:
            # Drawn as they are: a node under a pixel changes nothing a blend would hide, and
            # blending 1.5M of the 3.7M nodes of a 5M overview's settled cut took 1.1 s.
            nodes = cut_nodes(hierarchy, camera, SETTLED_GRANULARITY_PX)
            weights = None
        else:
            # Blended towards their parents near the threshold: the next moving cut does not pop.
            nodes = greedy_budget_cut_nodes(hierarchy, camera, budget)
            weights = blend_weights(hierarchy, camera, nodes)   # at the budget cut's own granularity
        packed = pack_nodes(hierarchy, nodes, weights=weights)
        with self._lock:
            if version != self.version:
                return
            self._serial += 1
            self._cut = Cut(self._serial, packed, len(nodes), hierarchy.leaf_count, settled,
                            camera_key(camera), None if settled else budget)


def detail_state(worker: "DetailWorker | None") -> tuple:
    """What of the LOD ``worker`` can change the picture with no event (its tree ready, its
    progress, its newest cut, its error; () without one): a frame compares it with what the last
    frame saw."""
    if worker is None:
        return ()
    return (worker.ready, round(worker.progress, 2), worker.cut_serial, worker.error)
