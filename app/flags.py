"""Making flags in the viewer: names, the current view, a view aimed at a clicked point.
The flags.json format itself is the library's (:mod:`inceptiongs.io.flags`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from inceptiongs.camera import Camera, look_at
from inceptiongs.io.flags import Flag, now_iso


def unique_flag_name(flags: list[Flag], prefix: str = "flag") -> str:
    """The first "prefix N" (N = 1, 2, ...) not used by any flag."""
    used = {f.name for f in flags}
    n = 1
    while f"{prefix} {n}" in used:
        n += 1
    return f"{prefix} {n}"


def flag_camera(camera: Camera, name: str) -> Flag:
    """A flag for the current view as it is."""
    return Flag(name, replace(camera, name=name), now_iso())


def unproject_pixel(camera: Camera, x: float, y: float, depth: float) -> np.ndarray:
    """World point [3] at camera-space z ``depth`` on the ray through pixel (x, y), where
    (x, y) are pixel indices (the ray goes through the pixel centre, x + 0.5, y + 0.5)."""
    ray = np.array([(x + 0.5 - camera.cx) / camera.fx, (y + 0.5 - camera.cy) / camera.fy, 1.0])
    point_camera = ray * depth
    return camera.rotation.T @ (point_camera - camera.world_to_camera[:3, 3])


def flag_aimed_at(camera: Camera, target: np.ndarray, name: str) -> Flag:
    """A flag at ``camera``'s position and intrinsics, turned to look straight at ``target``
    [3] (keeping the camera's own up direction so the horizon does not jump)."""
    up = -camera.rotation[1]
    pose = look_at(camera.center, target, up)
    return Flag(name, camera.with_pose(pose, name=name), now_iso())
