"""camera.project_points for a large cloud in one compiled pass (numba): the passes over every
training view before the first step (the sky shell's open cells, the free-space near bounds)
project every sparse point into every view, and numpy's temporaries made that P x C work cost
about 10 ms a view for 172,000 points (3,000 views: a minute a pass)."""

from __future__ import annotations

import numba
import numpy as np

from ..camera import Camera, project_points
from ..constants import NEAR_PLANE

# Below this many points numpy's pass is as fast and needs no compiled code.
COMPILED_FROM = 20_000


@numba.njit(cache=True, parallel=True)
def _project(points, rotation, translation, fx, fy, cx, cy, width, height, near):   # pragma: no cover - compiled
    p = points.shape[0]
    pixels = np.empty((p, 2))
    z = np.empty(p)
    inside = np.zeros(p, dtype=np.bool_)
    for i in numba.prange(p):
        x, y, w = points[i, 0], points[i, 1], points[i, 2]
        lx = x * rotation[0, 0] + y * rotation[0, 1] + w * rotation[0, 2] + translation[0]
        ly = x * rotation[1, 0] + y * rotation[1, 1] + w * rotation[1, 2] + translation[1]
        lz = x * rotation[2, 0] + y * rotation[2, 1] + w * rotation[2, 2] + translation[2]
        z[i] = lz
        front = lz > near
        safe_z = lz if front else 1.0                 # divided by only where in front (near > 0)
        u = fx * lx / safe_z + cx
        v = fy * ly / safe_z + cy
        pixels[i, 0] = u
        pixels[i, 1] = v
        inside[i] = front and u >= 0.0 and u < width and v >= 0.0 and v < height
    return pixels, z, inside


def project_cloud(points: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """camera.project_points (world points [P, 3] -> pixels [P, 2], depth z [P], inside [P]),
    compiled above COMPILED_FROM points; the two agree to rounding."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) < COMPILED_FROM:
        return project_points(points, camera)
    return _project(np.ascontiguousarray(points), np.ascontiguousarray(camera.rotation, np.float64),
                    np.ascontiguousarray(camera.world_to_camera[:3, 3], np.float64), float(camera.fx),
                    float(camera.fy), float(camera.cx), float(camera.cy), float(camera.width), float(camera.height),
                    float(NEAR_PLANE))
