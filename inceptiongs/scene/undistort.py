"""Lens undistortion to a pinhole camera (OpenCV distortion models, COLMAP's pixel convention).

Two lens families: OpenCV's standard model (coefficients k1, k2, p1, p2[, k3, k4, k5, k6] as a
plain array; COLMAP SIMPLE_RADIAL/RADIAL/OPENCV/FULL_OPENCV) and OpenCV's fisheye model
(:class:`Fisheye`, k1..k4 on the angle theta = atan(r); COLMAP and nerfstudio OPENCV_FISHEYE).

Pixel (i, j) is the continuous point (i + 0.5, j + 0.5) here and in COLMAP, while cv2.remap
indexes pixel centres at integers; the maps below are built in our convention and shifted by
0.5 only at the cv2 boundary, so undistortion adds no half-pixel offset.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import Camera

# Newton iterations for inverting the distortion (quadratic convergence: a handful suffice
# for any lens COLMAP fits; extra ones cost little since only border points are inverted).
_NEWTON_ITERATIONS = 20
# Finite-difference step for the 2x2 Jacobian of the distortion (normalised coordinates).
_JACOBIAN_STEP = 1e-6
# Below this |det J| the distortion folds over; the step falls back to the plain residual.
_DET_MIN = 1e-12


@dataclass(frozen=True, eq=False)
class Fisheye:
    """OpenCV's fisheye model: theta = atan(r), theta_d = theta (1 + k1 theta^2 + k2 theta^4 +
    k3 theta^6 + k4 theta^8), distorted point = (theta_d / r) * (x, y). k: [4] float64."""

    k: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "k", np.asarray(self.k, np.float64).reshape(4))


def distortion_key(dist) -> bytes:
    """Bytes that identify a lens model and its coefficients (for cache keys)."""
    if isinstance(dist, Fisheye):
        return b"fisheye" + dist.k.astype("<f8").tobytes()
    return np.asarray(dist, "<f8").tobytes()


def _distort_fisheye(xy: np.ndarray, k: np.ndarray) -> np.ndarray:
    """OpenCV fisheye distortion of normalised points [..., 2] (cv2.fisheye.distortPoints)."""
    r = np.linalg.norm(xy, axis=-1)
    theta = np.arctan(r)
    t2 = theta * theta
    theta_d = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
    # theta_d / r -> 1 as r -> 0 (theta ~ r); the guard keeps the centre from dividing 0 by 0.
    safe_r = np.where(r > 1e-12, r, 1.0)
    factor = np.where(r > 1e-12, theta_d / safe_r, 1.0)
    return xy * factor[..., None]


def _coefficients(dist: np.ndarray) -> np.ndarray:
    """Pad to the 8 OpenCV rational-model coefficients (k1, k2, p1, p2, k3, k4, k5, k6)."""
    out = np.zeros(8)
    out[: len(dist)] = dist
    return out


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV distortion (standard or :class:`Fisheye`) to normalised image points.
    xy: [..., 2] -> [..., 2]."""
    if isinstance(dist, Fisheye):
        return _distort_fisheye(np.asarray(xy, np.float64), dist.k)
    k1, k2, p1, p2, k3, k4, k5, k6 = _coefficients(dist)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    # The rational denominator is 1 + O(r^2) and positive for any lens OpenCV can calibrate
    # within the image; it is not guarded further.
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def _jacobian_det(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """det of d distort / d xy at xy [..., 2] (central differences) -> [...]."""
    dx = np.array([_JACOBIAN_STEP, 0.0])
    dy = np.array([0.0, _JACOBIAN_STEP])
    jx = (distort_normalized(xy + dx, dist) - distort_normalized(xy - dx, dist)) / (2 * _JACOBIAN_STEP)
    jy = (distort_normalized(xy + dy, dist) - distort_normalized(xy - dy, dist)) / (2 * _JACOBIAN_STEP)
    return jx[..., 0] * jy[..., 1] - jy[..., 0] * jx[..., 1]


def undistort_normalized(xy_distorted: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Invert :func:`distort_normalized` by Newton's method. [..., 2] -> [..., 2]."""
    target = np.asarray(xy_distorted, np.float64)
    xy = target.copy()
    dx = np.array([_JACOBIAN_STEP, 0.0])
    dy = np.array([0.0, _JACOBIAN_STEP])
    with np.errstate(over="ignore", invalid="ignore"):  # diverging points are detected by the caller
        for _ in range(_NEWTON_ITERATIONS):
            residual = distort_normalized(xy, dist) - target
            jx = (distort_normalized(xy + dx, dist) - distort_normalized(xy - dx, dist)) / (2 * _JACOBIAN_STEP)
            jy = (distort_normalized(xy + dy, dist) - distort_normalized(xy - dy, dist)) / (2 * _JACOBIAN_STEP)
            det = jx[..., 0] * jy[..., 1] - jy[..., 0] * jx[..., 1]
            ok = np.abs(det) > _DET_MIN
            safe_det = np.where(ok, det, 1.0)
            step_x = (jy[..., 1] * residual[..., 0] - jy[..., 0] * residual[..., 1]) / safe_det
            step_y = (-jx[..., 1] * residual[..., 0] + jx[..., 0] * residual[..., 1]) / safe_det
            step = np.where(ok[..., None], np.stack([step_x, step_y], -1), residual)
            xy = xy - step
    return xy


def undistorted_camera(camera: Camera, dist: np.ndarray) -> Camera:
    """The pinhole camera (same size) whose image holds only valid undistorted pixels.

    The focal lengths are chosen so that every pixel of the undistorted image comes from
    inside the distorted image (no black borders); the principal point is kept.
    """
    w, h = camera.width, camera.height
    # Sample the border of the distorted image and find the normalised extent it covers.
    t = np.linspace(0.0, 1.0, 64)
    border = np.concatenate([
        np.stack([t * w, np.zeros_like(t)], 1), np.stack([t * w, np.full_like(t, h)], 1),
        np.stack([np.zeros_like(t), t * h], 1), np.stack([np.full_like(t, w), t * h], 1)])
    normalized = np.stack([(border[:, 0] - camera.cx) / camera.fx, (border[:, 1] - camera.cy) / camera.fy], 1)
    ideal = undistort_normalized(normalized, dist)
    # Where the model cannot reach a border pixel (a strong radial term folds over before
    # the image corner) Newton does not converge; such points set no limit.
    converged = np.all(np.abs(distort_normalized(ideal, dist) - normalized) < 1e-6, axis=1)
    converged &= np.all(np.isfinite(ideal), axis=1)
    # Past the fold the model maps outward rays back inward; a root there (on the far side of
    # the fold, or mirrored through the centre) is not the pixel's ray.
    converged &= np.sum(ideal * normalized, axis=1) >= 0
    converged &= _jacobian_det(np.where(np.isfinite(ideal), ideal, 0.0), dist) > 0

    def limit(mask: np.ndarray, axis: int, reduce, fallback: float) -> float:
        values = ideal[mask & converged, axis]
        return float(reduce(values)) if len(values) else fallback

    # The largest rectangle around the principal point inside the undistorted border: on
    # each side the innermost undistorted border point limits it.
    left = limit(border[:, 0] == 0, 0, np.max, -camera.cx / camera.fx)
    right = limit(border[:, 0] == w, 0, np.min, (w - camera.cx) / camera.fx)
    top = limit(border[:, 1] == 0, 1, np.max, -camera.cy / camera.fy)
    bottom = limit(border[:, 1] == h, 1, np.min, (h - camera.cy) / camera.fy)
    # Keep the principal point and pick per axis the smallest focal length whose image
    # rectangle [-cx / f, (w - cx) / f] stays inside that region on both sides. The sides lie
    # on opposite signs of 0 for any camera whose principal point is inside the image; the
    # guard only keeps a degenerate one from dividing by zero.
    scale_x = max(camera.cx / max(-left, 1e-12), (w - camera.cx) / max(right, 1e-12))
    scale_y = max(camera.cy / max(-top, 1e-12), (h - camera.cy) / max(bottom, 1e-12))
    return Camera(camera.name, w, h, float(scale_x), float(scale_y), camera.cx, camera.cy,
                  camera.world_to_camera)


def undistort_image(image: np.ndarray, distorted: Camera, dist: np.ndarray, pinhole: Camera) -> np.ndarray:
    """Resample image [H, W, C] taken by ``distorted`` into the ``pinhole`` camera's image."""
    u, v = np.meshgrid(np.arange(pinhole.width) + 0.5, np.arange(pinhole.height) + 0.5)
    xy = np.stack([(u - pinhole.cx) / pinhole.fx, (v - pinhole.cy) / pinhole.fy], -1)
    xd = distort_normalized(xy, dist)
    map_x = (xd[..., 0] * distorted.fx + distorted.cx - 0.5).astype(np.float32)
    map_y = (xd[..., 1] * distorted.fy + distorted.cy - 0.5).astype(np.float32)
    return cv2.remap(image, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
