"""Sparse points for scenes that come without any (LLFF): triangulated from the training
photos with their known poses.

Every 3DGS pipeline starts from a structure-from-motion cloud; random Gaussians need
hundreds of steps (and many densifications) to find the surfaces that a few thousand
triangulated points give at step 0. With the poses known nothing has to be estimated but
the points themselves:

1. SIFT features in every training view;
2. each view matched against its nearest views (Lowe's ratio test), every match kept only
   if it lies on the epipolar line that the known poses predict;
3. matches chained into tracks (connected components over (view, keypoint)); a track that
   sees one view twice is ambiguous and dropped;
4. each track triangulated by linear least squares (DLT) over all its observations, in
   normalised camera coordinates, and kept when it is in front of every camera, reprojects
   within a pixel bound everywhere and has enough parallax to fix its depth.

The result is cached in the scene's work folder, keyed by the views, poses, images and
settings, so a second run starts at once.

Photos are read one at a time (``photo(slot)``, e.g. from the photo store): one pass for the
cache key, one for the features, one for the points' colours. Between passes only the
features are kept (keypoints, and the descriptors until the matching is done), so no more
than one photo is held however many views there are.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from ..io.atomic import atomic_write_bytes
from ..camera import Camera
from ..constants import NEAR_PLANE
from ..errors import InputError
from .neighbours import neighbour_views

_CACHE_VERSION = 1


@dataclass(frozen=True)
class TriangulationConfig:
    max_features: int = 6000         # SIFT keypoints per view
    contrast_threshold: float = 0.01  # SIFT (OpenCV default 0.04)
    ratio: float = 0.8               # Lowe's ratio test, among epipolar candidates
    pair_neighbours: int = 6         # each view is matched with this many nearest views
    pair_max_angle_deg: float = 45.0  # SIFT matching fails beyond large viewpoint changes
    epipolar_px: float = 1.5         # max distance of a match to its predicted epipolar line
    reprojection_px: float = 1.5     # max reprojection error in every observing view
    min_angle_deg: float = 1.0       # parallax below this leaves the depth undetermined
    min_points: int = 500            # fewer -> the caller falls back to random points


# --- geometry (pure) ------------------------------------------------------------------------

def skew(v: np.ndarray) -> np.ndarray:
    """v: [3] -> [3, 3] with skew(v) @ w = cross(v, w)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def fundamental_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """F [3, 3] with x_b^T F x_a = 0 for pixel points (this project's continuous convention)."""
    a_to_b = cam_b.world_to_camera @ cam_a.camera_to_world
    essential = skew(a_to_b[:3, 3]) @ a_to_b[:3, :3]
    return np.linalg.inv(cam_b.intrinsics).T @ essential @ np.linalg.inv(cam_a.intrinsics)


def epipolar_distance(f: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """Symmetric point-to-epipolar-line distance in pixels. x_a, x_b: [M, 2] -> [M] (the
    larger of the two views' distances)."""
    ha = np.concatenate([x_a, np.ones((len(x_a), 1))], 1)
    hb = np.concatenate([x_b, np.ones((len(x_b), 1))], 1)
    line_b = ha @ f.T            # lines in view b
    line_a = hb @ f              # lines in view a
    residual = np.abs(np.sum(hb * line_b, 1))
    # A line's normal (a, b) vanishes only for a point at the epipole itself; the floor
    # makes such a match's distance huge (rejected) instead of dividing by zero.
    norm_b = np.maximum(np.hypot(line_b[:, 0], line_b[:, 1]), 1e-12)
    norm_a = np.maximum(np.hypot(line_a[:, 0], line_a[:, 1]), 1e-12)
    return np.maximum(residual / norm_b, residual / norm_a)


def triangulate_tracks(poses: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """DLT for tracks of equal length.

    poses: [T, V, 3, 4] world-to-camera [R | t] of each observation; rays: [T, V, 2]
    normalised image coordinates (K^-1 applied). Returns points [T, 3]; rows whose
    homogeneous w is ~0 (a point at infinity) are NaN so the filters drop them.
    """
    x = rays[..., 0:1] * poses[..., 2, :] - poses[..., 0, :]     # [T, V, 4]
    y = rays[..., 1:2] * poses[..., 2, :] - poses[..., 1, :]
    system = np.concatenate([x, y], 1)                           # [T, 2V, 4]
    _, _, vt = np.linalg.svd(system)
    homogeneous = vt[:, -1]                                      # [T, 4]
    w = homogeneous[:, 3:4]
    finite = np.abs(w) > 1e-12
    return np.where(finite, homogeneous[:, :3] / np.where(finite, w, 1.0), np.nan)


def connected_labels(count: int, edges: np.ndarray) -> np.ndarray:
    """Connected components of a graph with ``count`` nodes and edges [E, 2] (int) ->
    labels [count] (each component labelled by its smallest node)."""
    labels = np.arange(count)
    if len(edges) == 0:
        return labels
    a, b = edges[:, 0], edges[:, 1]
    while True:
        low = np.minimum(labels[a], labels[b])
        updated = labels.copy()
        np.minimum.at(updated, a, low)
        np.minimum.at(updated, b, low)
        updated = updated[updated]  # pointer jumping: follow labels to their roots
        if np.array_equal(updated, labels):
            return labels
        labels = updated


# --- pipeline -------------------------------------------------------------------------------

PhotoReader = Callable[[int], np.ndarray]   # slot -> [H, W, 3] float in [0, 1] (array or CPU tensor)


def photo_reader(images) -> PhotoReader:
    """A list or mapping of photos, or a function slot -> photo, as slot -> [H, W, 3] float32
    (the photo is read when asked: a mapping such as the photo store keeps what it keeps)."""
    read = images if callable(images) and not isinstance(images, (Sequence, Mapping)) else images.__getitem__
    return lambda slot: np.asarray(read(slot), dtype=np.float32)


@dataclass
class _Features:
    pixels: np.ndarray        # [K, 2] continuous pixel coordinates
    descriptors: np.ndarray   # [K, 128] float32 (integers 0..255 as OpenCV's SIFT writes them)


def detect(image: np.ndarray, max_features: int, contrast_threshold: float = 0.01) -> _Features:
    """image: [H, W, 3] float in [0, 1] -> SIFT keypoints and descriptors."""
    grey = cv2.cvtColor(np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    # A low contrast threshold: small photos (LLFF at 1/8) give only ~1000 keypoints with
    # the default, and the epipolar filter removes the weak matches this admits.
    sift = cv2.SIFT_create(nfeatures=max_features, contrastThreshold=contrast_threshold)
    keypoints, descriptors = sift.detectAndCompute(grey, None)
    if descriptors is None:
        return _Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32))
    # OpenCV puts pixel centres at integers; this project at +0.5.
    pixels = np.array([k.pt for k in keypoints], dtype=np.float64) + 0.5
    return _Features(pixels, descriptors.astype(np.float32))


def _compact(features: _Features) -> _Features:
    """The same features with their descriptors as uint8 when that is exact (OpenCV's SIFT
    rounds every entry to an integer in 0..255): a quarter of the memory per view."""
    small = features.descriptors.astype(np.uint8)
    if np.array_equal(small, features.descriptors):
        return _Features(features.pixels, small)
    return features


def match_pair(feat_a: _Features, feat_b: _Features, cam_a: Camera, cam_b: Camera,
               config: TriangulationConfig) -> np.ndarray:
    """Guided matching: [M, 2] indices (a, b).

    With the poses known, a match can only lie near its epipolar line, so the nearest
    descriptor is searched among those candidates only; the ratio test and a mutual-best
    check then run on the same candidates. This finds several times more correct matches
    than an unguided ratio test, whose second-best neighbour is often a far-away repeat.
    """
    if len(feat_a.pixels) < 2 or len(feat_b.pixels) < 2:
        return np.zeros((0, 2), np.int64)
    da = np.asarray(feat_a.descriptors, dtype=np.float32)
    db = np.asarray(feat_b.descriptors, dtype=np.float32)
    # Squared descriptor distances [Ka, Kb] (clamped: rounding can make them a hair negative).
    distance = np.maximum((da * da).sum(1)[:, None] + (db * db).sum(1)[None, :] - 2.0 * da @ db.T, 0.0)
    off_line = _epipolar_distance_matrix(fundamental_matrix(cam_a, cam_b), feat_a.pixels, feat_b.pixels)
    distance[off_line >= config.epipolar_px] = np.inf
    order = np.argsort(distance, axis=1)[:, :2]
    rows = np.arange(len(da))
    best, second = distance[rows, order[:, 0]], distance[rows, order[:, 1]]
    # Ratio on distances (not squared): d1 < r d2  <=>  d1^2 < r^2 d2^2; inf second = unique.
    passes = np.isfinite(best) & (best < config.ratio ** 2 * second)
    mutual = np.argmin(distance, axis=0)[order[:, 0]] == rows
    keep = passes & mutual
    return np.stack([rows[keep], order[keep, 0]], 1).astype(np.int64)


def _epipolar_distance_matrix(f: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """Distance of every b point to every a point's epipolar line and back: [Ka, Kb] pixels."""
    ha = np.concatenate([x_a, np.ones((len(x_a), 1))], 1)
    hb = np.concatenate([x_b, np.ones((len(x_b), 1))], 1)
    line_b = ha @ f.T                                   # [Ka, 3] lines in view b
    line_a = hb @ f                                     # [Kb, 3] lines in view a
    residual = np.abs(line_b @ hb.T)                    # [Ka, Kb] = |x_b^T F x_a|
    # Floors as in epipolar_distance: a point at the epipole gets a huge distance.
    norm_b = np.maximum(np.hypot(line_b[:, 0], line_b[:, 1]), 1e-12)[:, None]
    norm_a = np.maximum(np.hypot(line_a[:, 0], line_a[:, 1]), 1e-12)[None, :]
    return np.maximum(residual / norm_b, residual / norm_a)


def _tracks(features: list[_Features], matches: dict[tuple[int, int], np.ndarray]
            ) -> list[np.ndarray]:
    """Chain pairwise matches into tracks. Returns a list of [L, 2] (view slot, keypoint)
    arrays; tracks seeing a view twice are dropped (inconsistent matches)."""
    offsets = np.cumsum([0] + [len(f.pixels) for f in features])
    edges = [np.stack([offsets[a] + m[:, 0], offsets[b] + m[:, 1]], 1) for (a, b), m in matches.items() if len(m)]
    if not edges:
        return []
    edges = np.concatenate(edges)
    labels = connected_labels(int(offsets[-1]), edges)
    nodes = np.unique(edges)
    nodes = nodes[np.argsort(labels[nodes], kind="stable")]
    groups = np.split(nodes, np.nonzero(np.diff(labels[nodes]))[0] + 1)
    tracks = []
    for group in groups:
        slots = np.searchsorted(offsets, group, side="right") - 1
        if len(group) < 2 or len(np.unique(slots)) != len(slots):
            continue
        tracks.append(np.stack([slots, group - offsets[slots]], 1))
    return tracks


def _filtered_tracks(tracks: list[np.ndarray], features: list[_Features], cameras: list[Camera],
                     config: TriangulationConfig) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The tracks that pass every check, grouped by length: per group (points [T, 3], slots
    [T, L], rows [T, L], cols [T, L]), rows/cols the observations' pixel indices (>= 0)."""
    poses = np.stack([c.world_to_camera[:3] for c in cameras])            # [V, 3, 4]
    k_inv = np.stack([np.linalg.inv(c.intrinsics) for c in cameras])      # [V, 3, 3]
    centers = np.stack([c.center for c in cameras])
    min_cos = math.cos(math.radians(config.min_angle_deg))
    kept = []
    by_length: dict[int, list[np.ndarray]] = {}
    for track in tracks:
        by_length.setdefault(len(track), []).append(track)
    for length, group in by_length.items():
        tr = np.stack(group)                                              # [T, L, 2]
        slots, keys = tr[..., 0], tr[..., 1]
        pixels = np.stack([features[s].pixels[k] for s, k in zip(slots.ravel(), keys.ravel())]).reshape(len(tr), length, 2)
        homogeneous = np.concatenate([pixels, np.ones(pixels.shape[:2] + (1,))], -1)
        rays = np.einsum("tvij,tvj->tvi", k_inv[slots], homogeneous)[..., :2]
        points = triangulate_tracks(poses[slots], rays)                   # [T, 3]
        camera_points = np.einsum("tvij,tj->tvi", poses[slots][..., :3], points) + poses[slots][..., 3]
        z = camera_points[..., 2]
        in_front = np.all(z > NEAR_PLANE, 1)
        # z > NEAR_PLANE where it matters; elsewhere the row is rejected by in_front anyway.
        safe_z = np.where(z > NEAR_PLANE, z, 1.0)
        fx = np.array([c.fx for c in cameras])[slots]
        fy = np.array([c.fy for c in cameras])[slots]
        cx = np.array([c.cx for c in cameras])[slots]
        cy = np.array([c.cy for c in cameras])[slots]
        projected = np.stack([fx * camera_points[..., 0] / safe_z + cx, fy * camera_points[..., 1] / safe_z + cy], -1)
        error = np.linalg.norm(projected - pixels, axis=-1).max(1)
        # Parallax: the widest angle between two viewing rays of the track.
        directions = points[:, None, :] - centers[slots]
        directions /= np.maximum(np.linalg.norm(directions, axis=-1, keepdims=True), 1e-12)
        cosines = np.einsum("tai,tbi->tab", directions, directions).min((1, 2))
        keep = np.isfinite(points).all(1) & in_front & (error < config.reprojection_px) & (cosines < min_cos)
        if not keep.any():
            continue
        rows = np.clip(pixels[keep, :, 1].astype(np.int64), 0, None)
        cols = np.clip(pixels[keep, :, 0].astype(np.int64), 0, None)
        kept.append((points[keep], slots[keep], rows, cols))
    return kept


def _track_colours(kept: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], photo: PhotoReader
                   ) -> list[np.ndarray]:
    """Per group of _filtered_tracks: the mean colour [T, 3] of each track's observations, the
    photos read one at a time (each photo once, in slot order)."""
    samples = [np.zeros(slots.shape + (3,), np.float32) for _, slots, _, _ in kept]   # [T, L, 3]
    for slot in np.unique(np.concatenate([slots.ravel() for _, slots, _, _ in kept])):
        image = photo(int(slot))
        for (_, slots, rows, cols), sample in zip(kept, samples):
            seen = slots == slot
            if seen.any():   # a keypoint on the last row/column edge is clamped into the image
                sample[seen] = image[np.minimum(rows[seen], image.shape[0] - 1),
                                     np.minimum(cols[seen], image.shape[1] - 1)]
        del image
    return [sample.mean(1) for sample in samples]


def triangulate_points(cameras: list[Camera], images,
                       config: TriangulationConfig = TriangulationConfig()
                       ) -> tuple[np.ndarray, np.ndarray]:
    """cameras (known poses) and their photos [H, W, 3] in [0, 1] (a list, or a function
    slot -> photo called once per photo and pass: see photo_reader) -> points [P, 3] in the
    cameras' frame and colours [P, 3] uint8."""
    photo = photo_reader(images)
    features = [_compact(detect(photo(slot), config.max_features, config.contrast_threshold))
                for slot in range(len(cameras))]
    neighbours = neighbour_views(cameras, list(range(len(cameras))), config.pair_neighbours,
                                 config.pair_max_angle_deg)
    pairs = sorted({(min(a, b), max(a, b)) for a, nbs in neighbours.items() for b in nbs})
    matches = {(a, b): match_pair(features[a], features[b], cameras[a], cameras[b], config) for a, b in pairs}
    features = [_Features(f.pixels, f.descriptors[:0]) for f in features]   # the descriptors are done with
    kept = _filtered_tracks(_tracks(features, matches), features, cameras, config)
    if not kept:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    colours = np.clip(np.concatenate(_track_colours(kept, photo)) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return np.concatenate([points for points, _, _, _ in kept]), colours


def _cache_key(cameras: list[Camera], photo: PhotoReader, config: TriangulationConfig) -> str:
    digest = hashlib.sha256(json.dumps({"version": _CACHE_VERSION, "config": asdict(config)}).encode())
    for slot, camera in enumerate(cameras):
        digest.update(camera.name.encode())
        digest.update(np.asarray([camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy],
                                 np.float64).tobytes())
        digest.update(np.asarray(camera.world_to_camera, np.float64).round(9).tobytes())
        digest.update(np.ascontiguousarray(photo(slot)[::7, ::7], np.float32).tobytes())   # the photo goes at once
    return digest.hexdigest()[:20]


def cached_triangulation(work_dir, cameras: list[Camera], images,
                         config: TriangulationConfig = TriangulationConfig()
                         ) -> tuple[np.ndarray, np.ndarray, bool]:
    """triangulate_points, cached as work_dir/sparse_init/KEY.npz. Returns (points, colours,
    came_from_cache). A cache that cannot be read is recomputed; one that cannot be written is
    skipped (the points are still returned). images: as for triangulate_points."""
    from pathlib import Path

    path = Path(work_dir) / "sparse_init" / f"{_cache_key(cameras, photo_reader(images), config)}.npz"
    if path.is_file():
        try:
            with np.load(path) as stored:
                return stored["points"], stored["colors"], True
        except (OSError, ValueError, KeyError):
            pass
    points, colours = triangulate_points(cameras, images, config)
    buffer = io.BytesIO()
    np.savez(buffer, points=points, colors=colours)
    try:
        atomic_write_bytes(path, buffer.getvalue())
    except InputError:  # OutputError: a full or read-only cache only costs speed
        pass
    return points, colours, False


def training_points(scene, views: list[int], images, enabled: bool, log,
                    config: TriangulationConfig = TriangulationConfig()
                    ) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """The points to initialise from: the scene's own, else (when ``enabled``) points
    triangulated from the training views ``views`` (never the held-out ones), else none
    (random initialisation). images: index -> [H, W, 3] tensor or array in [0, 1], a mapping
    (the photo store) or a function; read one photo at a time.
    Returns (points [P, 3], colours [P, 3] uint8 or None, triangulated); logs what it did."""
    if len(scene.points) > 0 or not enabled:
        return scene.points, scene.point_colors, False
    if len(views) < 2:
        log("no sparse points and fewer than 2 training views: nothing to triangulate")
        return scene.points, scene.point_colors, False
    cameras = [scene.cameras[i] for i in views]
    read = photo_reader(images)
    photos = lambda slot: read(views[slot])   # noqa: E731
    try:
        work_dir = scene.work_dir
    except Exception:  # noqa: BLE001  (no writable work folder: compute without a cache)
        work_dir = None
    if work_dir is None:
        points, colours, cached = (*triangulate_points(cameras, photos, config), False)
    else:
        points, colours, cached = cached_triangulation(work_dir, cameras, photos, config)
    if len(points) < config.min_points:
        log(f"scene has no sparse points; triangulation from {len(views)} training views found only "
            f"{len(points)} (< {config.min_points}): random initialisation")
        return scene.points, scene.point_colors, False
    log(f"scene has no sparse points: triangulated {len(points)} from {len(views)} training views "
        f"with the known poses{' (cached)' if cached else ''}")
    return points, colours, True
