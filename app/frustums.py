"""Wire-frame camera frustums as line segments (pure numpy; drawn by app.lines)."""

from __future__ import annotations

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
