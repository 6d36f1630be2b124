"""Sparse (or triangulated) points drawn as points: squares a few pixels wide at any distance,
nearest in front, in every render mode and in every picture of them (the window, F12,
``--screenshot``), so a screenshot is what the window shows. As splats they blurred into large
discs near the camera (bonsai in depth mode, fern's whole screenshot).

The size follows how many points the view holds: a few pixels where they are dense (bonsai's
51,545), larger where they are few (fern's ~2,200), so they read as the scene's shape, not as
black. Pure numpy: no GL."""

from __future__ import annotations

import math

import numpy as np

from inceptiongs.camera import Camera
from inceptiongs.constants import FAR_PLANE, NEAR_PLANE, SH_C0, SH_OFFSET

# Point squares are POINT_DENSITY * sqrt(pixels per visible point) wide, between these sizes.
POINT_DENSITY = 0.35
MIN_POINT_PIXELS = 2
MAX_POINT_PIXELS = 6


def point_colours(arrays: dict) -> np.ndarray:
    """[N, 3] in [0, 1]: the points' colours (the splats' view-independent colour)."""
    return np.clip(arrays["sh"][:, 0, :] * SH_C0 + SH_OFFSET, 0.0, 1.0).astype(np.float32)


def project_points(means: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """means: [N, 3] -> (columns [M], rows [M], depth [M], indices [M]): the pixel (int), camera
    z and index into ``means`` of each point inside the image and between the renderers' near
    and far planes."""
    world_to_camera = np.asarray(camera.world_to_camera, np.float64)
    points = np.asarray(means, np.float64) @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    z = points[:, 2]
    kept = np.flatnonzero((z >= NEAR_PLANE) & (z <= FAR_PLANE))
    z_kept = z[kept]   # >= NEAR_PLANE > 0: the divisions are safe
    columns = np.floor(camera.fx * points[kept, 0] / z_kept + camera.cx).astype(np.int64)
    rows = np.floor(camera.fy * points[kept, 1] / z_kept + camera.cy).astype(np.int64)
    inside = (columns >= 0) & (columns < camera.width) & (rows >= 0) & (rows < camera.height)
    return columns[inside], rows[inside], z_kept[inside], kept[inside]


def point_size(visible: int, width: int, height: int) -> int:
    """The squares' width in pixels for ``visible`` points in a width x height image."""
    pixels_each = width * height / max(visible, 1)   # >= 1 visible: no division by 0
    return int(np.clip(round(POINT_DENSITY * math.sqrt(pixels_each)), MIN_POINT_PIXELS, MAX_POINT_PIXELS))


def render_points(means: np.ndarray, colours: np.ndarray, camera: Camera, mode: str = "rgb",
                  background=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The points (means [N, 3], colours [N, 3]) seen by ``camera`` as squares (point_size), the
    nearest point in front, in the layout of SplatRenderer.render for ``mode``: rgb [H, W, 3]
    over ``background``; depth [H, W, 1] camera z (0 where no point); normal [H, W, 3] the
    direction back to the camera (a point has no surface; splats' normals face the camera too);
    alpha [H, W, 1] 1 where a point is, else 0."""
    width, height = int(camera.width), int(camera.height)
    columns, rows, depth, index = project_points(means, camera)
    size = point_size(len(index), width, height)
    nearest = np.argsort(depth, kind="stable")
    columns, rows, depth, index = columns[nearest], rows[nearest], depth[nearest], index[nearest]
    # Each point's square: offsets -size//2 .. around its pixel, the point's entries side by side
    # so the flattened order stays nearest first (np.unique keeps each pixel's first: the nearest).
    offsets = np.arange(size) - (size - 1) // 2
    dx, dy = np.meshgrid(offsets, offsets)
    x = columns[:, None] + dx.ravel()[None, :]
    y = rows[:, None] + dy.ravel()[None, :]
    owner = np.broadcast_to(np.arange(len(index))[:, None], x.shape)
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    pixel = (y * width + x)[inside]
    pixel, first = np.unique(pixel, return_index=True)
    owner = owner[inside][first]
    channels = 1 if mode in ("depth", "alpha") else 3
    out = np.zeros((height * width, channels), np.float32)
    if mode == "rgb":
        out[:] = np.asarray(background, np.float32).reshape(1, 3)
        out[pixel] = np.asarray(colours, np.float32)[index[owner]]
    elif mode == "depth":
        out[pixel, 0] = depth[owner]
    elif mode == "normal":
        world_to_camera = np.asarray(camera.world_to_camera, np.float64)
        toward = -(np.asarray(means, np.float64)[index[owner]] @ world_to_camera[:3, :3].T + world_to_camera[:3, 3])
        # depth >= NEAR_PLANE: the vector to the camera is never 0 long.
        out[pixel] = (toward / np.linalg.norm(toward, axis=1, keepdims=True)).astype(np.float32)
    elif mode == "alpha":
        out[pixel, 0] = 1.0
    else:
        raise ValueError(f"unknown mode {mode!r}")
    return out.reshape(height, width, channels)
