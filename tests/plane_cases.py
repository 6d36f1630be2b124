"""An analytic textured plane seen by axis-aligned cameras (stage II's plane-sweep and geometry-term
tests): ground truth without a rasterizer."""

from __future__ import annotations

import numpy as np

from inceptiongs.camera import Camera

PLANE_Z = 5.0
WIDTH, HEIGHT, FOCAL = 64, 48, 60.0


def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Contrast left of x = 0.4, a flat grey right of it (no evidence there)."""
    pattern = 0.5 + 0.22 * np.sin(7.0 * x) * np.cos(5.5 * y) + 0.18 * np.sin(13.0 * x + 9.0 * y)
    return np.where(x < 0.4, pattern, 0.5)


def camera_at(name: str, centre) -> Camera:
    pose = np.eye(4)
    pose[:3, 3] = -np.asarray(centre, dtype=np.float64)  # identity rotation: looking along +z
    return Camera(name, WIDTH, HEIGHT, FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2, pose)


def plane_grey(camera: Camera) -> np.ndarray:
    """[HEIGHT, WIDTH] the plane z = PLANE_Z seen by an axis-aligned camera, texture evaluated per pixel centre."""
    u, v = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    centre = camera.center
    t = PLANE_Z - centre[2]
    return texture(centre[0] + (u - camera.cx) / camera.fx * t, centre[1] + (v - camera.cy) / camera.fy * t)
