"""Wire-frame camera frustums as line segments (pure numpy; drawn by app.lines)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from inceptiongs.camera import Camera


def frustum_segments(camera: Camera, depth: float) -> np.ndarray:
    """Line segments [8, 2, 3] in world space: 4 edges from the centre to the image corners at
    camera z = ``depth``, and the 4 sides of that image rectangle."""
    corners_px = np.array([[0.0, 0.0], [camera.width, 0.0], [camera.width, camera.height],
                           [0.0, camera.height]])
    rays = np.stack([(corners_px[:, 0] - camera.cx) / camera.fx,
                     (corners_px[:, 1] - camera.cy) / camera.fy, np.ones(4)], axis=1)
    points_camera = rays * depth
    world = (points_camera - camera.world_to_camera[:3, 3]) @ camera.rotation  # R^T (p - t)
    center = camera.center
    spokes = [(center, world[i]) for i in range(4)]
    rim = [(world[i], world[(i + 1) % 4]) for i in range(4)]
    return np.array(spokes + rim, np.float64)


def segments_for_cameras(cameras: list[Camera], depth: float) -> np.ndarray:
    """[8 * len(cameras), 2, 3] (an empty [0, 2, 3] for no cameras)."""
    if not cameras:
        return np.zeros((0, 2, 3))
    return np.concatenate([frustum_segments(c, depth) for c in cameras])


def away_from(cameras: list[Camera], eye: np.ndarray, min_distance: float) -> list[int]:
    """Indices of the cameras whose centre is farther than ``min_distance`` from ``eye`` [3]: a
    frustum drawn around the eye (the camera one stands at, or a neighbour a step away) has its
    lines across the whole window, so those are left out until the eye moves away."""
    return [i for i, c in enumerate(cameras) if np.linalg.norm(c.center - eye) > min_distance]


# Training frustums are drawn this deep relative to the median distance between a camera and
# its nearest neighbour: neighbours' frustums touch rather than overlap into a solid clump.
FRUSTUM_SPACING_FRACTION = 0.5
# At most this many training frustums are drawn (a capture of hundreds of photos is thinned to
# cameras spread over the whole path, farthest-point order); the rest add only clutter.
MAX_DRAWN_FRUSTUMS = 60


def nearest_spacing(centers: np.ndarray) -> float | None:
    """Median distance [scene units] from each of ``centers`` [N, 3] to its nearest other one;
    None for fewer than 2 or when all coincide."""
    centers = np.asarray(centers, np.float64)
    if len(centers) < 2:
        return None
    distances = np.linalg.norm(centers[:, None, :] - centers[None, :, :], axis=2)
    np.fill_diagonal(distances, np.inf)
    nearest = distances.min(axis=1)
    nearest = nearest[nearest > 1e-9]  # duplicates (a rig's cameras at one place) say nothing
    return float(np.median(nearest)) if len(nearest) else None


def spread_subset(centers: np.ndarray, limit: int) -> list[int]:
    """Up to ``limit`` indices into ``centers`` [N, 3] spread over all of them: farthest-point
    order from the first camera, returned sorted. All of them when N <= limit."""
    centers = np.asarray(centers, np.float64)
    if len(centers) <= limit:
        return list(range(len(centers)))
    chosen = [0]
    distance = np.linalg.norm(centers - centers[0], axis=1)
    while len(chosen) < limit:
        index = int(np.argmax(distance))
        chosen.append(index)
        distance = np.minimum(distance, np.linalg.norm(centers - centers[index], axis=1))
    return sorted(chosen)


def drawn_training_frustums(cameras: list[Camera], fallback_depth: float,
                            keep: set[int] = frozenset()) -> tuple[list[int], float]:
    """Which training cameras to draw (thinned to MAX_DRAWN_FRUSTUMS, the indices in ``keep``
    always kept) and the frustum depth: FRUSTUM_SPACING_FRACTION of the drawn ones' nearest
    spacing, ``fallback_depth`` when there is no spacing (one camera)."""
    if not cameras:
        return [], fallback_depth
    centers = np.stack([c.center for c in cameras])
    indices = sorted(set(spread_subset(centers, MAX_DRAWN_FRUSTUMS)) | set(keep))
    spacing = nearest_spacing(centers[indices])
    return indices, fallback_depth if spacing is None else FRUSTUM_SPACING_FRACTION * spacing


@dataclass
class TrainingFrustums:
    """drawn_training_frustums, chosen once per camera list and poorly fit set: the overlays are
    drawn every frame, the thinning runs over all the cameras. ``key``: what ``chosen`` was made for."""

    key: tuple | None = None
    chosen: tuple[list[int], float] = field(default_factory=lambda: ([], 1.0))

    def for_cameras(self, cameras: list[Camera], poorly_fit, fallback_depth: float) -> tuple[list[int], float]:
        """(indices to draw, frustum depth) for ``cameras``, those whose photo is among
        ``poorly_fit`` (image names) always drawn."""
        key = (id(cameras), len(cameras), tuple(sorted(poorly_fit)), fallback_depth if len(cameras) < 2 else None)
        if self.key != key:
            keep = {i for i, c in enumerate(cameras) if c.name in poorly_fit}
            self.chosen = drawn_training_frustums(cameras, fallback_depth, keep)
            self.key = key
        return self.chosen
