"""Synthetic scenes with known cameras, points and lens distortion, for the scene I/O tests.

Images show a bright Gaussian blob where each known 3-D point projects (through the lens
distortion when there is one), so a loaded scene can be checked by finding the blobs again.
Distorted projections use cv2.projectPoints, an implementation independent of
inceptiongs.scene.undistort.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from inceptiongs.camera import Camera, look_at

# Far from the origin on purpose: normalisation must make this harmless.
WORLD_OFFSET = np.array([1000.0, -500.0, 200.0])
WIDTH, HEIGHT = 120, 90
BLOB_SIGMA = 1.2


def known_points() -> np.ndarray:
    """[20, 3] points on a tilted 5 x 4 grid around WORLD_OFFSET."""
    u, v = np.meshgrid(np.linspace(-1.6, 1.6, 5), np.linspace(-1.1, 1.1, 4))
    points = np.stack([u.ravel(), v.ravel(), 0.3 * u.ravel()], axis=1)
    return points + WORLD_OFFSET


def known_cameras(count: int = 4, fx: float = 60.0, fy: float = 61.0, cx: float = 61.0,
                  cy: float = 44.0) -> list[Camera]:
    cameras = []
    for k in range(count):
        angle = -0.3 + 0.6 * k / max(count - 1, 1)
        eye = WORLD_OFFSET + np.array([3.2 * np.sin(angle), 0.4 * k - 0.5, -3.2 * np.cos(angle)])
        pose = look_at(eye, WORLD_OFFSET, up=(0.0, -1.0, 0.0))
        cameras.append(Camera(f"view_{k:02d}.png", WIDTH, HEIGHT, fx, fy, cx, cy, pose))
    return cameras


def project(camera: Camera, points: np.ndarray, dist=None) -> np.ndarray:
    """Continuous pixel coordinates [P, 2] (pixel (i, j) is the point (i + 0.5, j + 0.5)).
    dist: OpenCV coefficients, a Fisheye (cv2.fisheye.projectPoints) or None."""
    from inceptiongs.scene.undistort import Fisheye

    rvec, _ = cv2.Rodrigues(camera.world_to_camera[:3, :3])
    if isinstance(dist, Fisheye):
        pixels, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), rvec,
                                              np.ascontiguousarray(camera.world_to_camera[:3, 3]).reshape(3, 1),
                                              camera.intrinsics, dist.k.reshape(4, 1))
        return pixels.reshape(-1, 2)
    coefficients = np.zeros(8) if dist is None else np.pad(np.asarray(dist, float), (0, 8 - len(dist)))
    pixels, _ = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, camera.world_to_camera[:3, 3],
                                  camera.intrinsics, coefficients)
    return pixels.reshape(-1, 2)


def blob_image(pixels: np.ndarray, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """uint8 [H, W, 3] image with a Gaussian blob at each continuous pixel position."""
    j, i = np.mgrid[0:height, 0:width] + 0.5
    image = np.zeros((height, width))
    for x, y in pixels:
        image += np.exp(-((i - x) ** 2 + (j - y) ** 2) / (2 * BLOB_SIGMA ** 2))
    gray = np.round(255 * np.clip(image, 0, 1)).astype(np.uint8)
    return np.repeat(gray[:, :, None], 3, axis=2)


def blob_centroids(image: np.ndarray, expected: np.ndarray, radius: int = 4) -> np.ndarray:
    """Intensity-weighted centroids [P, 2] of image [H, W, 3] in windows around ``expected``;
    NaN for blobs whose window is not entirely inside the image."""
    gray = image.mean(axis=2)
    out = []
    for x, y in expected:
        i0, j0 = int(np.floor(x)), int(np.floor(y))
        if not (radius <= i0 < gray.shape[1] - radius and radius <= j0 < gray.shape[0] - radius):
            out.append([np.nan, np.nan])
            continue
        window = gray[j0 - radius:j0 + radius + 1, i0 - radius:i0 + radius + 1]
        jj, ii = np.mgrid[j0 - radius:j0 + radius + 1, i0 - radius:i0 + radius + 1] + 0.5
        total = window.sum()
        out.append([np.sum(window * ii) / total, np.sum(window * jj) / total])
    return np.array(out)


def write_images(folder: Path, cameras: list[Camera], dists: list[np.ndarray | None]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    points = known_points()
    for camera, dist in zip(cameras, dists):
        cv2.imwrite(str(folder / camera.name), blob_image(project(camera, points, dist)))
